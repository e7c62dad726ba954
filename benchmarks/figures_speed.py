"""CPU of the report figures: dynid's one-pass grid layout against matplotlib's constrained layout.

Draws report figures of the demo's size (the torque of a 20 s, 5 kHz six-joint recording
with a velocity dead zone, the residual PDFs, the %sigma bars) with `render_figure` as the
reports do (GridLayoutEngine, dynid.reports.figure_layout), and the same figures laid out
by matplotlib's constrained layout engine (the layout before issue 30), alternately in one
process; the figure is the ratio of the medians. The reference leaves out the old tick
thinning pass (a draw), so the ratio understates the saving. The issue-30 demo profile
(figures about a third of `dynid demo`'s CPU) is in the closing note.

The last line is a JSON object with `grid_cpu_s`, `constrained_cpu_s` (medians per set of
figures) and `ratio_cpu`.

Run from the repository root:

    python benchmarks/figures_speed.py [--repeats N]
"""
import argparse
import json
import statistics
import time

import numpy as np

from dynid.reports import figures as F


def figures(seed=0):
    """The demo-sized figures, each through render_figure."""
    rng = np.random.default_rng(seed)
    t = np.arange(100_000) / 5000.0
    qd = np.sin(np.outer(t, [0.7, 0.9, 1.1, 1.3, 1.7, 1.9]))
    tau = 20 * qd + rng.normal(0, 0.5, qd.shape)
    moving = np.abs(qd) > 0.05                       # the velocity dead zone: gaps on grey bands
    names = [f"j{j + 1}" for j in range(6)]
    F.torque_figure(t, tau, 0.98 * tau, names, mask=moving)
    F.residual_pdf_figure(rng.standard_normal((5000, 6)) * [1, 0.1, 0.01, 1e-3, 5, 50], names,
                          np.linspace(0.01, 0.9, 6))
    pnames = [f"P{k}" for k in range(40)]
    F.rel_std_bar_figure(pnames, 10.0 ** rng.uniform(-1, 3, 40))
    F.verdict_rel_std_figure(pnames, 10.0 ** rng.uniform(-1, 3, 40), 10.0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    grid_layout = F._grid_layout
    runs = {"grid": grid_layout, "constrained": lambda fig: None}   # None: keep matplotlib's engine
    figures()                                        # warm: imports, font cache
    times = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, layout in runs.items():
            F._grid_layout = layout
            try:
                t0 = time.process_time()
                figures()
                times[name].append(time.process_time() - t0)
            finally:
                F._grid_layout = grid_layout
            print(f"  {name:12s} CPU {times[name][-1]:6.2f} s", flush=True)
    med = {name: statistics.median(ts) for name, ts in times.items()}
    out = {"grid_cpu_s": round(med["grid"], 2), "constrained_cpu_s": round(med["constrained"], 2),
           "ratio_cpu": round(med["grid"] / med["constrained"], 3), "repeats": args.repeats}
    print(f"report figures: CPU {out['grid_cpu_s']} s with the grid layout, {out['constrained_cpu_s']} s with "
          f"matplotlib's constrained layout (ratio {out['ratio_cpu']}, median of {args.repeats})")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
