"""Controller gains identified from (qr, q, tau) on the independent closed-loop plant, over seeds.

    python benchmarks/controller_gains.py                  # seeds 3-8 and 11-16, 8 s at 5 kHz each
    python benchmarks/controller_gains.py --seeds 3 4 --duration 16
    python benchmarks/controller_gains.py --didim          # and DIDIM with them against IDIM

Data: ``tests/support/independent_plant.py`` (Pinocchio TX40 with the Table 2 parameters and the
coupled wrist, its own semi-implicit Euler integrator and PID with velocity feed-forward,
gains unknown to dynid), 10-harmonic reference, encoder noise 2e-5 rad, torque noise 0.2 N m.
Seeds 3-8 were used while developing the estimator (the velocity-lag column, the whitened
second pass); 11-16 were run once after, as held-out seeds, and are reported apart.

Per seed and gain: the relative error of
:func:`dynid.analysis.estimators.controller_gains.identify_gains` against the plant's gains and
its own %sigma; the same for the one-pass estimator (``whiten=False, velocity_lag=False``, the
previous default) in the same run. The last line is JSON, per seed group and kind: the worst
relative error, the share within 2 %, the rms of the z-scores (error / sigma; 1 for an
honest sigma) and the share within 2 sigma; the velocity lag found (us; the plant's state is
h/2 = 25 us behind the central derivative); and the time per identification as a ratio to
the plant simulation of the same seed.

``--didim``: per seed, IDIM and DIDIM with the identified gains (``gains="identify"``), with
DIDIM's Coulomb smoothing ``v_s`` chosen from the data (``"auto"``, the default), at the former
default 0.05 rad/s and at the plant's 0.01 (``--v-s`` selects which); per run the essential
parameters of IDIM within 2 % or 2 sigma of DIDIM's, the ones that are not, both torque
residuals, the v_s used and DIDIM's wall time.

    python benchmarks/controller_gains.py --didim --seeds 3 4 5 6 7 8 --v-s auto
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

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "tests" / "support"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))


def _stats(errs, sig):
    out = {}
    for kind in errs:
        e, s = np.abs(np.array(errs[kind])), np.array(sig[kind])
        out[kind] = {"max_abs_rel_error_percent": float(e.max()),
                     "max_abs_rel_error_percent_per_joint": [float(x) for x in e.max(axis=0)],
                     "within_2_percent": float((e < 2).mean()),
                     "z_rms": float(np.sqrt(np.mean((e / s) ** 2))),
                     "within_2_sigma": float((e < 2 * s).mean())}
    return out


def _didim_vs_idim(dynid, exp, robot, seed, v_s_values):
    """IDIM and DIDIM (identified gains, each v_s): agreement of the parameters."""
    idim = dynid.identify(exp, robot)
    row = {"seed": seed}
    for vs in v_s_values:
        t0 = time.perf_counter()
        d = dynid.identify(exp, robot, "didim", gains="identify", settings={"v_s": vs})
        wall = time.perf_counter() - t0
        off, total = [], 0
        for n in idim.names:
            if n in d.names:
                a, b = idim.params[n], d.params[n]
                s = max(idim.bse[n], d.bse[n])
                total += 1
                if abs(b - a) > max(0.02 * abs(a), 2 * s):
                    off.append(f"{n} {100 * (b - a) / abs(a):+.1f} % ({(b - a) / s:+.1f} sigma)")
        row[vs] = {"converged": bool(d.converged), "compared": total, "off": off,
                   "didim_rel_error": float(d.model.rel_error), "idim_rel_error": float(idim.model.rel_error),
                   "v_s_used": float(d.settings["v_s"]), "didim_wall_s": wall}
        print(f"{seed:>4} DIDIM v_s {vs} ({d.settings['v_s']:.3g}): {total - len(off)} of {total} within 2 % "
              f"or 2 sigma of IDIM {off}; torque residual {d.model.rel_error:.4f} (IDIM "
              f"{idim.model.rel_error:.4f}); {wall:.1f} s", flush=True)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5, 6, 7, 8, 11, 12, 13, 14, 15, 16])
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--didim", action="store_true", help="also DIDIM with the identified gains vs IDIM")
    ap.add_argument("--v-s", nargs="+", default=["auto", "0.05", "0.01"], dest="v_s",
                    help="DIDIM's v_s values with --didim: 'auto' or numbers (rad/s)")
    args = ap.parse_args()
    v_s_values = [v if v == "auto" else float(v) for v in args.v_s]
    import independent_plant as ip

    import dynid
    from dynid.analysis.data.experiment import Experiment
    from dynid.analysis.estimators.controller_gains import identify_gains
    plant = ip.tx40_plant("table2", coupled_wrist=True)
    robot = dynid.load_robot("tx40")
    robot.controller = dataclasses.replace(robot.controller, kind="pid", ki=np.zeros(6))
    variants = {"default": {}, "one_pass": {"whiten": False, "velocity_lag": False}}
    groups = {"development": [s for s in args.seeds if 3 <= s <= 8],
              "held_out": [s for s in args.seeds if not 3 <= s <= 8]}
    acc = {(v, grp): ({k: [] for k in ("Kp", "Kd", "Ki")}, {k: [] for k in ("Kp", "Kd", "Ki")})
           for v in variants for grp in groups}
    ratios, lags, didim_rows = [], [], []
    print(f"{'seed':>4} {'variant':>8} {'gain':>4} " + " ".join(f"{'j' + str(j + 1):>15}" for j in range(6)))
    for seed in args.seeds:
        grp = "development" if seed in groups["development"] else "held_out"
        t0 = time.perf_counter()
        rec = ip.run(plant, duration=args.duration, rate=5000.0, seed=seed,
                     sensor=ip.Sensor(q_noise=2e-5, tau_noise=0.2), n_harmonics=10)
        t_sim = time.perf_counter() - t0
        exp = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"], fs=5000.0,
                         source=f"independent plant, seed {seed}", name="plant")
        for v, kw in variants.items():
            t0 = time.perf_counter()
            g = identify_gains(exp, robot, **kw)
            if v == "default":
                ratios.append((time.perf_counter() - t0) / t_sim)
                note = next(x for x in g.notices if x.startswith("velocity lag"))
                lags.append([float(x) for x in note.split(":")[1].split(",")])
            errs, sig = acc[(v, grp)]
            for kind in errs:
                e = 100 * (g.gain(kind) / np.asarray(rec["gains"][kind]) - 1)
                s = np.array([g.rel_std[f"{kind}{j + 1}"] for j in range(6)])
                errs[kind].append(e)
                sig[kind].append(s)
                print(f"{seed:>4} {v:>8} {kind:>4} " + " ".join(f"{x:+6.2f} % ({y:4.2f})" for x, y in zip(e, s)),
                      flush=True)
        if args.didim:
            didim_rows.append(_didim_vs_idim(dynid, exp, robot, seed, v_s_values))
    print("cells: relative error of the gain (its %sigma)")
    out = {"seeds": args.seeds, "duration_s": args.duration,
           "identification_time_over_simulation": float(np.median(ratios)),
           "velocity_lag_us_median_per_joint": [float(x) for x in np.median(lags, axis=0)]}
    for v in variants:
        out[v] = {grp: _stats(*acc[(v, grp)]) for grp in groups if groups[grp]}
    if didim_rows:
        out["didim"] = {}
        for vs in v_s_values:
            block = {}
            for grp, seeds in groups.items():
                rows = [r for r in didim_rows if r["seed"] in seeds]
                if rows:
                    block[grp] = {"all_agree": int(sum(r[vs]["off"] == [] for r in rows)),
                                  "seeds": len(rows),
                                  "all_agree_share": float(np.mean([r[vs]["off"] == [] for r in rows]))}
            block["runs"] = [{"seed": r["seed"], **r[vs]} for r in didim_rows]
            out["didim"][f"v_s_{vs}"] = block
    print(json.dumps(out))


if __name__ == "__main__":
    main()
