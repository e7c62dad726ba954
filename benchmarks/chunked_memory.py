"""Memory of a long recording identified in memory vs reduced chunk by chunk (the fleet task's two paths).

One long production recording of the planar2 arm (pick-and-place cycles at 1 kHz,
simulated in closed loop as tests/support/simulated_fleet.py does) is identified by
the fleet task (IDIM: WLS and essential set) twice per length, on its first
N/4 samples and on all N:
- in memory: dynid.analysis.estimators.idim.identify_idim (the full-rate filtered
  signals and the decimated W are held);
- chunked: blocks of 50 000 samples, each decimated chunk reduced to its
  per-joint triangles and added up (dynid.analysis.estimators.streamed.reduce_stream,
  least_squares.Reduction); W never held.
Peak memory is tracemalloc's peak during the identification alone (the recording
itself, loaded first, is not counted: both paths need it). The chunked peak
should not grow with N; the in-memory one grows linearly. The two estimates of
the friction parameters are compared in units of σ (the streamed filter differs
from the whole-record one at the block joins by < 1e-5).
The last line is a JSON object with the figures.
Run from the repository root: python benchmarks/chunked_memory.py [--samples 1200000]
"""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
import argparse
import json
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "support"))      # simulated_fleet.py: the test fleet's recordings

import numpy as np


def measure(fn, *args):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn(*args)
    wall = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, peak / 1e6, wall


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_200_000, help="samples of the long recording (1 kHz)")
    ap.add_argument("--block", type=int, default=50_000)
    args = ap.parse_args()
    from simulated_fleet import simulate_recording

    from dynid.analysis.data.experiment import Experiment, load_experiment
    from dynid.analysis.fleet import task

    robot, bp = task._robot("planar2")
    fs = 1000.0
    moves = int(args.samples / (1.4 * fs)) + 2       # a move and its dwell last ~1.4 s
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = simulate_recording({"robot": "planar2", "seed": 11, "spread_seed": 12, "temperatures": [25.0, 25.0],
                                   "worn_joint": 0, "wear_now": 0.0, "fs": fs, "moves": moves,
                                   "path": str(Path(tmp) / "long.npz")})
        full = load_experiment(path, robot)
    t_sim = time.perf_counter() - t0
    n_total = min(args.samples, full.q.shape[0])
    print(f"simulated {full.q.shape[0]} samples ({full.q.shape[0] / fs / 60:.1f} min at 1 kHz) in {t_sim:.0f} s",
          flush=True)
    if n_total // 4 <= 4 * args.block:
        raise SystemExit(f"--samples {args.samples} is too short for blocks of {args.block}: both lengths "
                         f"must exceed the chunked path's threshold, 4 x block")
    warm = Experiment(t=full.t[:20_000], q=full.q[:20_000], tau=full.tau[:20_000], fs=full.fs, source=full.source)
    task._identify(warm, robot, bp, None, 10**12)        # imports and numba compilation out of the figures
    task._identify(warm, robot, bp, None, 4000)
    rows = []
    for n in (n_total // 4, n_total):
        exp = Experiment(t=full.t[:n], q=full.q[:n], tau=full.tau[:n], fs=full.fs, source=full.source)
        (w_mem, _, _), peak_mem, wall_mem = measure(task._identify, exp, robot, bp, None, 10**12)
        (w_chk, _, _), peak_chk, wall_chk = measure(task._identify, exp, robot, bp, None,
                                                    4 * args.block)
        fr = [k for k, nm in enumerate(w_mem.names) if nm.startswith(("Fv", "Fc"))]
        dz = float(np.max(np.abs(w_chk.chi[fr] - w_mem.chi[fr]) / w_mem.bse.to_numpy()[fr]))
        rows.append({"samples": n, "peak_mb_in_memory": round(peak_mem, 1), "peak_mb_chunked": round(peak_chk, 1),
                     "seconds_in_memory": round(wall_mem, 1), "seconds_chunked": round(wall_chk, 1),
                     "recording_mb": round((exp.q.nbytes + exp.tau.nbytes + exp.t.nbytes) / 1e6, 1),
                     "friction_max_diff_sigma": round(dz, 3)})
        print(f"{n} samples: peak {peak_mem:.1f} MB in memory ({wall_mem:.1f} s), {peak_chk:.1f} MB chunked "
              f"({wall_chk:.1f} s); the recording itself {rows[-1]['recording_mb']} MB; friction estimates "
              f"differ by at most {dz:.3f} sigma", flush=True)
    growth_mem = rows[1]["peak_mb_in_memory"] / rows[0]["peak_mb_in_memory"]
    growth_chk = rows[1]["peak_mb_chunked"] / rows[0]["peak_mb_chunked"]
    print(json.dumps({"block": args.block, "rows": rows,
                      "peak_ratio_in_memory_vs_chunked": round(rows[1]["peak_mb_in_memory"] / rows[1]["peak_mb_chunked"], 2),
                      "peak_growth_4x_samples_in_memory": round(growth_mem, 2),
                      "peak_growth_4x_samples_chunked": round(growth_chk, 2),
                      "simulate_seconds": round(t_sim, 1)}))


if __name__ == "__main__":
    main()
