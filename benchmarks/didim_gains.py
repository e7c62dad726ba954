"""DIDIM with controller gains identified from the data, started from the robot file's a-priori values.

Issue 26's must-show: DIDIM, started from the bundled robot file's a-priori values
(`tx40.toml` [apriori], Table 2 of Gautier et al. 2010), converges with the gains
identified from the logged loop (`dynid identify --method didim --gains identify`) on
>= 95 % of >= 20 independent-plant seeds not used while developing, with controller gains
different from the robot file's, and its essential parameters lie within 2 % or 2 sigma
of IDIM's.

Plant: `tests/support/independent_plant.py` (Pinocchio TX40, Table 2 parameters, coupled
wrist, its own integrator and PID with velocity feed-forward at 5 kHz), as the coverage
campaign builds it (`benchmarks/coverage_independent.py`): 10-harmonic reference, torque
noise AR(1) at the logging rate (phi 0.9, 0.3 N m) and a small unmodelled position
ripple on joint 1; encoder noise 2e-5 rad. The controller gains differ from the robot
file's (a PD at wn = 60 rad/s) twice: the plant places a PID at wn = 150 rad/s
(`closed_loop_gains`) and each joint's Kp, Kd, Ki are then multiplied by one factor
drawn log-uniformly in [0.5, 2] (seeded by the seed; listed in each row). Logged at
`--log-every` ticks (default 5: 1 kHz) for `--duration` s (default 4, as the coverage campaign): smaller than a
user's recording so that 20 seeds fit on a shared 2-core machine.

Per seed: IDIM (dynid's default), the gains identified (`identify_gains`), then DIDIM
with that controller, no gain update (the actual gains are simulated), started from the
robot file's a-priori values (`chi0 = apriori`, base names as given, the rest zero);
this is what `--gains identify` runs except the start (the command starts from IDIM's
estimate). Reported: converged or not (and the stop reason), steps, v_s chosen,
seconds, IDIM's essential parameters within 2 % or 2 sigma of DIDIM's estimate of the
same parameter (sigma the larger of the two), the worst gain error.

    nice -n 10 python benchmarks/didim_gains.py --start 6000 --seeds 20 --workers 2 \
        --out benchmarks/results/didim_gains_seeds6000-6019.jsonl

Development used seeds 0-999; the last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from campaign_rows import append, resume

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

PHI = 0.9
NOISE = 0.3
RIPPLE = dict(joint=1, A=0.5, k=6.0)
GAIN_RANGE = (0.5, 2.0)


def ar1_noise(rng, shape, phi, std):
    """AR(1) noise along axis 0 (coefficient phi, marginal std std), stationary start."""
    from scipy.signal import lfilter
    e = rng.standard_normal(shape) * std * np.sqrt(1 - phi**2)
    x0 = rng.standard_normal(shape[1]) * std
    return lfilter([1.0], [1.0, -phi], e, axis=0, zi=(phi * x0)[None, :])[0]


def gain_factors(seed, n=6):
    """Per-joint factor on (Kp, Kd, Ki), log-uniform in GAIN_RANGE, from the seed."""
    rng = np.random.default_rng(20_000 + seed)
    lo, hi = np.log(GAIN_RANGE[0]), np.log(GAIN_RANGE[1])
    return np.exp(rng.uniform(lo, hi, n))


def recording(seed, duration=4.0, log_every=5, factors=True):
    """(experiment, plant recording, gain factors) of one seed."""
    import independent_plant as ip

    from dynid.analysis.data.experiment import Experiment
    plant = ip.tx40_plant("table2", coupled_wrist=True,
                          effects=[ip.position_ripple(RIPPLE["joint"], RIPPLE["A"], RIPPLE["k"])])
    rate = 5000.0
    ref = ip.multisine_reference(plant.limits, duration, rate, seed, n_harmonics=10)
    ctrl = ip.default_controller(plant, rate)
    f = gain_factors(seed, plant.n) if factors else np.ones(plant.n)
    ctrl = dataclasses.replace(ctrl, Kp=ctrl.Kp * f, Kd=ctrl.Kd * f, Ki=ctrl.Ki * f)
    rec = ip.simulate(plant, ctrl, ref, sensor=ip.Sensor(q_noise=2e-5, tau_noise=0.0),
                      log_every=log_every, seed=seed)
    rng = np.random.default_rng(10_000 + seed)
    tau = rec["tau"] + ar1_noise(rng, rec["tau"].shape, PHI, NOISE)
    exp = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=tau, fs=rec["rate"],
                     source=f"independent plant seed {seed}", name=f"didim-gains-{seed}")
    return exp, rec, f


def robot_pid():
    """tx40.toml with the controller's structure the plant has (PID, feed-forward); gains unknown."""
    import dynid
    robot = dynid.load_robot("tx40")
    robot.controller = dataclasses.replace(robot.controller, kind="pid", ki=np.zeros(6))
    return robot


def agreement(idim, didim):
    """IDIM's essential parameters within 2 % or 2 sigma (the larger) of DIDIM's estimate."""
    off, total = [], 0
    d_names = list(didim.names)
    for k, n in enumerate(idim.names):
        if n not in d_names:
            continue
        total += 1
        a, b = float(idim.chi[k]), float(didim.chi[d_names.index(n)])
        s = max(float(idim.bse.to_numpy()[k]), float(didim.bse.to_numpy()[d_names.index(n)]))
        if abs(b - a) > max(0.02 * abs(a), 2 * s):
            off.append(f"{n} {a:.4g} vs {b:.4g} ({(b - a) / s:+.1f} sigma)")
    return off, total


def run_seed(seed, duration=4.0, log_every=5, start="apriori", v_s="auto"):
    from dynid.analysis.estimators.controller_gains import identify_gains
    from dynid.analysis.estimators.didim import identify_didim
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.dynamics.base_parameters import base_parameters
    t0 = time.time()
    exp, rec, f = recording(seed, duration, log_every)
    robot = robot_pid()
    bp = base_parameters(robot)
    row = {"seed": seed, "gain_factors": [float(x) for x in f], "sim_seconds": time.time() - t0}
    idim = identify_idim(exp, robot, bp=bp)
    g = identify_gains(exp, robot)
    err = [float(np.max(np.abs(g.gain(k) / rec["gains"][k] - 1))) for k in ("Kp", "Kd", "Ki")]
    row["gain_max_rel_error"] = max(err)
    ctrl = g.controller(robot)
    chi0 = dict(robot.apriori) if start == "apriori" else dict(zip(bp.names, idim.wls.chi))
    t1 = time.time()
    try:
        d = identify_didim(exp, robot, bp=bp, controller=ctrl, chi0=chi0, update_gains=False,
                           settings={"v_s": v_s})
    except Exception as exc:   # a run that stops with an error is a result, with its message
        row.update(converged=False, error=str(exc).splitlines()[0], didim_seconds=time.time() - t1,
                   seconds=time.time() - t0)
        return row
    row["didim_seconds"] = time.time() - t1
    row["converged"] = bool(d.converged)
    row["stop_reason"] = d.stop_reason
    row["steps"] = d.iterations
    row["v_s"] = float(d.settings["v_s"])
    row["step_lengths"] = [float(x) for x in d.history["step_length"]]
    off, total = agreement(idim.model, d.result)
    row["essential_compared"] = total
    row["essential_off"] = off
    row["rel_error_didim"] = float(d.result.rel_error)
    row["rel_error_idim"] = float(idim.model.rel_error)
    row["seconds"] = time.time() - t0
    return row


def headline(rows):
    n = len(rows)
    conv = [r for r in rows if r.get("converged")]
    agree = [r for r in conv if not r.get("essential_off")]
    return {"seeds": n, "converged": len(conv), "converged_fraction": len(conv) / n if n else None,
            "errors": sum("error" in r for r in rows),
            "essential_all_agree_seeds": len(agree),
            "essential_pairs": int(sum(r.get("essential_compared", 0) for r in conv)),
            "essential_pairs_off": int(sum(len(r.get("essential_off", [])) for r in conv)),
            "median_steps": float(np.median([r["steps"] for r in conv])) if conv else None,
            "median_didim_seconds": float(np.median([r["didim_seconds"] for r in rows])) if rows else None,
            "worst_gain_error": float(max(r["gain_max_rel_error"] for r in rows)) if rows else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--log-every", type=int, default=5)
    ap.add_argument("--from", dest="start_from", default="apriori", choices=("apriori", "idim"))
    ap.add_argument("--v-s", default="auto")
    ap.add_argument("--out", default=None, help="JSON lines, one per seed (appended; seeds done are skipped)")
    a = ap.parse_args(argv)
    v_s = a.v_s if a.v_s == "auto" else float(a.v_s)
    seeds = list(range(a.start, a.start + a.seeds))
    rows, seeds = resume(a.out, seeds)
    t0 = time.time()

    def record(row):
        rows.append(row)
        print(f"seed {row['seed']}: converged {row.get('converged')} steps {row.get('steps')} "
              f"v_s {row.get('v_s')} off {row.get('essential_off')} of {row.get('essential_compared')} "
              f"err {row.get('error', '')} stop {row.get('stop_reason', '')[:120]} "
              f"({row.get('didim_seconds', 0):.0f} s DIDIM, gains err {row['gain_max_rel_error']:.3f})",
              flush=True)
        append(a.out, row)

    args = (a.duration, a.log_every, a.start_from, v_s)
    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(a.workers) as ex:
            for row in ex.map(run_seed, seeds, *[[x] * len(seeds) for x in args]):
                record(row)
    else:
        for s in seeds:
            record(run_seed(s, *args))
    out = headline(rows)
    out.update({"first_seed": a.start, "duration_s": a.duration, "log_every": a.log_every,
                "start": a.start_from, "v_s": a.v_s, "gain_factor_range": GAIN_RANGE,
                "campaign_seconds": time.time() - t0})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
