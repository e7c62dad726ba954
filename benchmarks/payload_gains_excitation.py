"""Drive gains of one seed against the loaded recordings' excitation and length (issue 28).

Which data fix the wrist gains: one seed's payload (benchmarks/payload.py), the benchmark's
unloaded recording (20 s), and loaded recordings built with `tests/support/payload_plant.wrist_reference`
under the excitation given by the options; each fit's error and stated 95 % half-width per
gain (%), with the rms of the payload's own torque on each joint along the loaded motion
(Pinocchio: loaded minus unloaded inverse dynamics on the true state, N m): the signal that
fixes each gain's scale (the torque noise is 0.2 N m per sample).
Results: benchmarks/results/payload_gains_excitation_probes.jsonl (seeds 2034, 2187, 2027, 416, and the
given payload 1,0,0,0.02,0.04,0.04,0.04 on seed 2100's trajectories).
Run from the repository root (niced): python benchmarks/payload_gains_excitation.py SEED
[--loaded-s 10 --n-loaded 2 --wrist-f0 0.4 --wrist-amplitude 0.6 --wrist-qd 0.7 --arm-amplitude 0.3 --arm-qd 0.5
--arm-f0 0.3 --payload 1,0,0,0.02,0.04,0.04,0.04]
"""
import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def payload_torque(base, loaded, rec):
    """rms over the recording of the payload's torque on each joint (N m) along the true motion."""
    import numpy as np
    import pinocchio as pin
    q, qd, qdd = rec["q_true"], rec["qd_true"], rec["qdd_true"]
    db, dl = base.model.createData(), loaded.model.createData()
    step = 10
    t = np.array([pin.rnea(loaded.model, dl, q[i], qd[i], qdd[i]) - pin.rnea(base.model, db, q[i], qd[i], qdd[i])
                  for i in range(0, len(q), step)])
    return np.sqrt((t ** 2).mean(axis=0))


def main():
    import numpy as np

    import dynid
    from dynid.analysis.data.experiment import Experiment
    from dynid.analysis.estimators.drive_gains import identify_drive_gains
    from tests.support import payload_plant as pp
    ap = argparse.ArgumentParser()
    ap.add_argument("seed", type=int)
    ap.add_argument("--loaded-s", type=float, default=10.0)
    ap.add_argument("--n-loaded", type=int, default=2)
    ap.add_argument("--unloaded-s", type=float, default=20.0)
    ap.add_argument("--wrist-f0", type=float, default=0.4)
    ap.add_argument("--wrist-amplitude", type=float, default=0.6)
    ap.add_argument("--wrist-qd", type=float, default=0.7)
    ap.add_argument("--arm-amplitude", type=float, default=0.3)
    ap.add_argument("--arm-qd", type=float, default=0.5)
    ap.add_argument("--arm-f0", type=float, default=None, help="arm fundamental, Hz (default 1 / duration)")
    ap.add_argument("--com", action="store_true")
    ap.add_argument("--same-unloaded", action="store_true",
                    help="the unloaded recording with the loaded excitation too")
    ap.add_argument("--payload", metavar="M,CX,CY,CZ,A,B,H",
                    help="a given payload instead of the seed's: mass kg, centre of mass m, box sides m (axis-aligned)")
    args = ap.parse_args()
    seed, rate = args.seed, 2000.0
    robot = dataclasses.replace(dynid.load_robot("tx40"), couplings=[])
    params, parts = pp.random_payload(np.random.default_rng(seed))
    if args.payload:
        m, cx, cy, cz, a, b, h = map(float, args.payload.split(","))
        c = np.array([cx, cy, cz])
        Ic = m / 12.0 * np.diag([b * b + h * h, a * a + h * h, a * a + b * b])
        I_o = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
        params = np.array([I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m])
        parts = dict(mass=m, com=c, inertia_com=Ic)
    base, loaded, _ = pp.tx40_payload_plant(params)
    kw = dict(wrist_f0=args.wrist_f0, wrist_amplitude=args.wrist_amplitude, wrist_qd_fraction=args.wrist_qd,
              arm_amplitude=args.arm_amplitude, qd_fraction=args.arm_qd,
              arm_f0=args.arm_f0)
    kt = np.random.default_rng(seed + 7).uniform(0.9, 1.1, 6)
    t0 = time.perf_counter()

    def one(plant, duration, s, **kw):
        ref = pp.wrist_reference(plant.limits, duration, rate, s, **kw)
        rec = pp.record(plant, ref, s, rate=rate)
        e = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"] / kt, fs=rate, source=str(s))
        return e, rec
    eu, _ = one(base, args.unloaded_s, 2 * seed + 1, **(kw if args.same_unloaded else {}))
    seeds = [2 * seed + 2] + [1_000_000 + 100 * seed + k for k in range(args.n_loaded - 1)]
    els, recs = zip(*[one(loaded, args.loaded_s, s, **kw) for s in seeds])
    ptau = payload_torque(base, loaded, recs[0])
    peak_qd = np.abs(recs[0]["qd_true"]).max(axis=0)
    peak_qdd = np.percentile(np.abs(recs[0]["qdd_true"]), 99, axis=0)
    rd = identify_drive_gains(eu, list(els), robot, mass=params[9], com=parts["com"] if args.com else None,
                              zoh=True)
    half = 1.959963984540054 * rd.factor_std / np.abs(rd.factor)
    print(json.dumps({"seed": seed, "mass": parts["mass"], "com_mm": (1e3 * parts["com"]).round(1).tolist(),
                      **{k: v for k, v in vars(args).items() if k != "seed"},
                      "err_pct": (100 * (rd.factor - kt) / kt).round(3).tolist(),
                      "half95_pct": (100 * half).round(3).tolist(),
                      "payload_tau_rms": ptau.round(4).tolist(), "peak_qd": peak_qd.round(2).tolist(),
                      "qdd_p99": peak_qdd.round(1).tolist(), "seconds": round(time.perf_counter() - t0, 1)}),
          flush=True)


if __name__ == "__main__":
    main()
