"""DIDIM with the automatic Coulomb width against DIDIM at a fixed width (issue 30, row DIDIM).

`v_s = "auto"` (the default) chooses the smooth-sign width of the simulated Coulomb friction
from the data (`dynid.analysis.estimators.didim._identify_auto_v_s`): DIDIM to convergence at
0.05 rad/s, a factor-2 walk scored by one warm-started Gauss-Newton step per width, a parabola
refinement in log v_s, then DIDIM at the chosen width. The reference run is DIDIM at a fixed
width equal to the one the search chose, from the same start: the same answer, without the
search. Ratio = median CPU time (`time.process_time`, the machine is shared) of the automatic
run over the fixed one's, each repeated `--repeat` times (default 3), in one process.

Case: the recording of `benchmarks/didim_gains.py` / `benchmarks/coverage_didim.py` (the
independent Pinocchio TX40 plant with friction `tanh(qd / 0.01)`, PID with feed-forward at
5 kHz logged at 1 kHz, 4 s, coloured torque noise, each joint's gains times a factor in
[0.5, 2]), DIDIM as `--gains identify` runs it: the gains identified from the logged loop, no
gain update, the robot file's a-priori values as the start, no essential set. Development
seed 5 by default (the held-out seeds 6100-6198 are not used).

`--case demo`: the DIDIM of `dynid demo --seed S` instead (the simulated TX40 of
`dynid.analysis.demo`, 20 s at 5 kHz, the robot file's gains, eq. (31)'s start, the gain update
for the first simulation only, DIDIM's default step limit, essential parameters): a start far from the
answer, which the fixed width must walk to at its own (more expensive) substeps.

    python benchmarks/didim_width.py [--case pid|demo] [--seed 5] [--repeat 3] [--profile] [--save out.json]

The simulation work (closed-loop simulations and their RK4 substeps, counted in one more pair of
runs) is printed beside the times: it does not depend on the machine's load. That pair also
splits each run's CPU time into the closed-loop simulations and the rest (the regressor and
its decimation per simulation, the WLS, the a-priori start's projection): the `floor` is the
ratio the automatic run would have if it cost nothing but its simulations beyond what the
fixed run costs, i.e. what a search that simulates the same widths cannot go below.

`--profile` prints the cProfile (CPU time) of one automatic run, `--save` writes the
estimates, the chosen width and its scan (to compare two versions of dynid: run this script
with each one's Python). BLAS runs single-threaded. The last line is a JSON object with
`ratio_auto_to_fixed_width` and the times.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks", ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))


def case(seed, duration):
    """(experiment, robot, keyword arguments of identify_didim) of one seed."""
    import didim_gains as dg

    from dynid.analysis.estimators.controller_gains import identify_gains
    from dynid.dynamics.base_parameters import base_parameters
    exp, _, _ = dg.recording(seed, duration)
    robot = dg.robot_pid()
    bp = base_parameters(robot)
    ctrl = identify_gains(exp, robot).controller(robot)
    kw = dict(bp=bp, controller=ctrl, chi0=dict(robot.apriori), update_gains=False, essential=False)
    return exp, robot, kw


def case_demo(seed):
    """(experiment, robot, keyword arguments of identify_didim) of `dynid demo --seed S`'s DIDIM."""
    from dynid.analysis.demo import demo_data
    robot, bp, _, exp, _ = demo_data(seed, 20.0)
    from dynid.analysis.estimators.didim import DEFAULT_MAX_ITER
    return exp, robot, dict(bp=bp, max_iter=DEFAULT_MAX_ITER, update_gains="initial")


def timed(fn):
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("pid", "demo"), default="pid")
    ap.add_argument("--seed", type=int, default=None, help="default 5 (pid), 1 (demo)")
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="cProfile (CPU time) of one automatic run")
    ap.add_argument("--save", default=None, help="write the estimates and the chosen width to this JSON file")
    a = ap.parse_args(argv)

    import dynid
    from dynid.analysis.estimators.didim import identify_didim
    if a.seed is None:
        a.seed = 5 if a.case == "pid" else 1
    exp, robot, kw = case(a.seed, a.duration) if a.case == "pid" else case_demo(a.seed)
    print(f"dynid from {Path(dynid.__file__).resolve().parents[2]}; case {a.case}, seed {a.seed}, {exp.t.size} samples at "
          f"{exp.fs:g} Hz; BLAS threads {os.environ.get('OPENBLAS_NUM_THREADS')}", flush=True)
    identify_didim(exp, robot, settings={"v_s": 0.05}, **{**kw, "max_iter": 1})   # numba caches loaded

    def auto():
        return identify_didim(exp, robot, **kw)

    t_auto, t_fixed = [], []
    res_auto = res_fixed = None
    for i in range(a.repeat):
        # alternated, so that a change of the machine's load falls on both
        ta, res_auto = timed(auto)
        v_s = float(res_auto.settings["v_s"])
        tf, res_fixed = timed(lambda: identify_didim(exp, robot, settings={"v_s": v_s}, **kw))  # noqa: B023
        t_auto.append(ta)
        t_fixed.append(tf)
        print(f"repeat {i + 1}: auto {ta:.2f} s CPU ({res_auto.iterations} steps, v_s {v_s:.4g}, "
              f"{len(res_auto.settings['v_s_scan'])} widths scored), fixed {tf:.2f} s CPU "
              f"({res_fixed.iterations} steps)", flush=True)
    med_a, med_f = float(np.median(t_auto)), float(np.median(t_fixed))
    sig = res_auto.result.bse.to_numpy()
    d_sigma = float(np.max(np.abs(res_auto.chi - res_fixed.chi) / sig))
    h = res_auto.history
    print("automatic run, steps: " + ", ".join(f"v_s {v:.3g} ({int(n)} substeps)"
                                               for v, n in zip(h["v_s"], h["substeps"])))
    print("scan: " + ", ".join(f"{r['v_s']:.4g}: {r['rho_norm']:.6g}" for r in res_auto.settings["v_s_scan"]))
    print(f"auto {med_a:.2f} s CPU, fixed {med_f:.2f} s CPU (medians of {a.repeat}): ratio {med_a / med_f:.2f}; "
          f"largest |chi_auto - chi_fixed| = {d_sigma:.3g} sigma")
    # the work, independent of the machine's load: closed-loop simulations and their RK4 substeps
    # (one controller period of one simulation at 1 substep = 1 unit), counted in one more pair
    import dynid.analysis.estimators.didim as didim_module
    counted, sim_cpu = [], []
    plain = didim_module._simulate

    def counting(*args, **kwargs):
        t0 = time.process_time()
        out = plain(*args, **kwargs)
        sim_cpu.append(time.process_time() - t0)
        counted.append(int(out[4]))
        return out

    didim_module._simulate = counting
    try:
        c_auto, _ = timed(auto)
        n_auto, u_auto, s_auto = len(counted), sum(counted), sum(sim_cpu)
        counted.clear()
        sim_cpu.clear()
        c_fixed, _ = timed(lambda: identify_didim(exp, robot, settings={"v_s": float(res_auto.settings["v_s"])},
                                                  **kw))
        n_fixed, u_fixed, s_fixed = len(counted), sum(counted), sum(sim_cpu)
    finally:
        didim_module._simulate = plain
    floor = (s_auto + c_fixed - s_fixed) / c_fixed
    print(f"closed-loop simulations: auto {n_auto} ({u_auto} substep units), fixed {n_fixed} ({u_fixed}): "
          f"ratio of the simulation work {u_auto / u_fixed:.2f}")
    print(f"CPU split (that pair): auto {c_auto:.2f} s = simulations {s_auto:.2f} + rest {c_auto - s_auto:.2f}; "
          f"fixed {c_fixed:.2f} s = simulations {s_fixed:.2f} + rest {c_fixed - s_fixed:.2f}; floor of the "
          f"same simulations (auto's rest = fixed's) {floor:.2f}")
    if a.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile(time.process_time)
        pr.enable()
        auto()
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(30)
    if a.save:
        Path(a.save).write_text(json.dumps({
            "seed": a.seed, "names": list(res_auto.result.names), "chi_auto": res_auto.chi.tolist(),
            "bse_auto": sig.tolist(), "chi_fixed": res_fixed.chi.tolist(),
            "v_s": float(res_auto.settings["v_s"]), "v_s_scan": res_auto.settings["v_s_scan"],
            "steps_auto": res_auto.iterations, "steps_fixed": res_fixed.iterations,
            "converged": bool(res_auto.converged)}))
    print(json.dumps({
        "ratio_auto_to_fixed_width": round(med_a / med_f, 3), "auto_cpu_s": round(med_a, 3),
        "fixed_cpu_s": round(med_f, 3), "auto_cpu_runs_s": [round(x, 3) for x in t_auto],
        "fixed_cpu_runs_s": [round(x, 3) for x in t_fixed], "v_s": float(res_auto.settings["v_s"]),
        "widths_scored": len(res_auto.settings["v_s_scan"]), "simulations_auto": n_auto,
        "simulations_fixed": n_fixed, "substep_units_auto": u_auto, "substep_units_fixed": u_fixed,
        "ratio_simulation_work": round(u_auto / u_fixed, 3), "steps_auto": int(res_auto.iterations),
        "steps_fixed": int(res_fixed.iterations), "max_auto_minus_fixed_sigma": d_sigma,
        "simulation_cpu_auto_s": round(s_auto, 3), "rest_cpu_auto_s": round(c_auto - s_auto, 3),
        "simulation_cpu_fixed_s": round(s_fixed, 3), "rest_cpu_fixed_s": round(c_fixed - s_fixed, 3),
        "floor_ratio_same_simulations": round(floor, 3),
        "case": a.case, "seed": a.seed, "duration_s": a.duration if a.case == "pid" else 20.0, "repeat": a.repeat,
        "load_1min": round(os.getloadavg()[0], 2)}))


if __name__ == "__main__":
    main()
