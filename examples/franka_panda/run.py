"""Worked example: the Franka Emika Panda log of Gaz et al. (RA-L 2019), identified with dynid.

    python examples/franka_panda/run.py [--data DIR] [--out DIR] [--json FILE]

1. converts the log (``DIR/rbt_log``, one number per line) to a CSV on its original,
   irregular time stamps (``convert.py``) and writes ``experiment.toml`` beside it
   (``resample = true``: dynid interpolates onto a uniform 1 kHz grid);
2. identifies IDIM (OLS, per-joint WLS, essential parameters) on the first three
   quarters (t < t_end - 5.25 s), validates on the last quarter (5.25 s);
3. prints a table: base / essential counts, relative error ||tau - tau_hat|| / ||tau||
   on the identification data and on ALL held-out decimated samples (dynid's
   ``validate`` figure, which zeroes the velocity dead zone, is printed beside it),
   per-joint held-out RMS and MSE, the published MSE of Gaz et al., and Gaz et al.'s
   gravity + friction model (``gaz_model.py``) on the same held-out samples;
4. prints what dynid finds for the rotor inertias and the frictions, and compares the
   identified gravity parameters with the ones implied by Gaz et al.'s g(q).

The data are GPL-3.0 and not shipped: ``--data`` defaults to the first
``shared/data/franka-panda-gaz`` found in the parent directories of the repository.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:          # convert.py and gaz_model.py beside this file, also when imported
    sys.path.insert(0, str(HERE))

HOLDOUT = 5.25          # s: the last quarter of the 21.0 s recording
# Processing. The Welch spectrum of qd puts 99.99 % of the motion below 0.5 Hz; dynid's
# rules for a 1 Hz bandwidth give fc = 45 Hz and a 4 Hz decimation low-pass (nd = 100),
# which its automatic choice finds too (0.71 / 0.64 %, README). nd = 20 keeps the 4 Hz
# low-pass but 5x the samples (50 Hz): 158
# instead of 31 decimated held-out samples; the errors are the same within 0.01 %.
SETTINGS = {"fc_position": 45.0, "nd": 20, "f_decimation_cutoff": 4.0}
# Gaz et al., supplementary material, Table IV: validation torque MSE per joint (N m^2),
# on their own validation trajectories (not in the data folder).
PUBLISHED_MSE = [0.41, 1.03, 0.60, 0.42, 0.17, 0.040, 0.027]
CLI = ("dynid identify OUT/experiment.toml --robot panda --holdout 5.25 --fc 45 --nd 20 "
       "--decimation-cutoff 4")


def prepare(data_dir, out_dir):
    """Convert the log into OUT/panda.csv + OUT/experiment.toml; return the TOML path."""
    from convert import convert
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    convert(data_dir, out / "panda.csv")
    shutil.copyfile(HERE / "experiment.toml", out / "experiment.toml")
    return out / "experiment.toml"


def _errors(tau, tau_hat):
    import numpy as np
    res = tau - tau_hat
    return {"rel_error": float(np.linalg.norm(res) / np.linalg.norm(tau)),
            "rms": np.sqrt(np.mean(res ** 2, axis=0)).tolist(),
            "mse": np.mean(res ** 2, axis=0).tolist()}


def analyse(toml_path, data_dir, settings=None):
    """Identify on the first three quarters, validate on the last; return a dict of figures."""
    import numpy as np
    from gaz_model import GazModel

    from dynid.analysis.data.experiment import Experiment, load_experiment
    from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY, identify_idim
    from dynid.analysis.processing.observation import observe
    from dynid.analysis.processing.signals import derivatives
    from dynid.analysis.statistics.validation import validate
    from dynid.dynamics.base_parameters import base_regressor
    from dynid.dynamics.robot_file import load_robot

    settings = dict(SETTINGS if settings is None else settings)
    robot = load_robot("panda")
    exp = load_experiment(toml_path, robot)
    t_split = exp.t[-1] - HOLDOUT
    train, held = exp.segment(None, t_split), exp.segment(t_split, None)
    # the covariance `dynid identify` reports by default (the %σ below are its)
    res = identify_idim(train, robot, settings=settings, uncertainty=DEFAULT_UNCERTAINTY)
    val = validate(res, held, robot)            # dynid's figure (dead zone zeroed)

    # ALL held-out samples: the same processing without the velocity dead zone
    s_all = dict(res.settings, qd_threshold=[0.0] * robot.n_joints)
    obs = observe(held, robot, res.base, s_all)
    tau_d = obs.tau
    tau_hat = res.predict(obs.W)
    # the raw (resampled, not low-passed) torque at the same instants, for figures that
    # include what the 4 Hz decimation low-pass removes (sensor noise, vibration)
    idx = np.searchsorted(held.t, obs.t)
    tau_raw = held.tau[idx]

    def decimate(signal):
        """A full-rate (N, 7) torque through exactly the held-out processing (linear)."""
        e = Experiment(t=held.t, q=held.q, tau=signal, fs=held.fs)
        return observe(e, robot, res.base, s_all).tau

    # dynid's gravity + friction part (the essential model with qd, qdd -> gravity,
    # Fv qd + Fc sign(qd) from the filtered q), at full rate, then decimated
    chi = dict(zip(res.model.names, res.model.chi))
    der = derivatives(held.q, held.fs, res.settings["fc_position"], res.settings["order"])
    zero = np.zeros_like(der.q)
    grav_off = res.predict(base_regressor(robot, res.base, der.q, zero, zero))
    fric = np.column_stack([chi.get(f"Fv{j}", 0.0) * der.qd[:, j - 1]
                            + chi.get(f"Fc{j}", 0.0) * np.sign(der.qd[:, j - 1])
                            for j in range(1, robot.n_joints + 1)])
    dyn_gf_d = decimate(grav_off + fric)
    inertial_d = tau_hat - dyn_gf_d             # M qdd + C qd (+ Ia qdd) of dynid

    gaz = GazModel(Path(data_dir) / "model")
    g_gaz = gaz.gravity_vector(held.q)
    gaz_gf = g_gaz + gaz.friction_torque(held.qd)     # logged qd, as the robot has it
    gaz_gf_d = decimate(gaz_gf)

    # model against model: gravity torque on the held-out positions (full rate, edges cut)
    edge = int(res.settings["edge"])
    k = slice(edge, held.n_samples - edge)
    g_dyn = res.predict(base_regressor(robot, res.base, held.q[k], zero[k], zero[k]))
    off = np.array([chi.get(f"Off{j}", 0.0) for j in range(1, robot.n_joints + 1)])
    g_diff = (g_dyn - off) - g_gaz[k]

    # Gaz's g(q) as dynid base parameters: exact least squares on random postures
    rng = np.random.default_rng(0)
    qr = rng.uniform(-np.pi, np.pi, (400, robot.n_joints))
    Wg = base_regressor(robot, res.base, qr, np.zeros_like(qr), np.zeros_like(qr))
    A, y = Wg.reshape(-1, res.base.n_base), gaz.gravity_vector(qr).reshape(-1)
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    gaz_beta = {n: float(b) for n, b in zip(res.base.names, beta) if abs(b) > 1e-9}

    dead = next((n for n in val.notices if n.startswith("velocity dead zone")), "")
    pt = res.parameter_table()
    actuator = [{"name": n, "wls": float(pt.loc[n, "wls"]), "wls_rel_std": float(pt.loc[n, "wls_rel_std"]),
                 "essential": bool(pt.loc[n, "essential"]),
                 "essential_value": float(pt.loc[n, "essential_value"]),
                 "essential_rel_std": float(pt.loc[n, "essential_rel_std"])}
                for n in pt.index if n[:2] in ("Ia", "Fv", "Fc")]
    gravity_params = [{"name": n, "dynid": float(pt.loc[n, "wls"]),
                       "dynid_rel_std": float(pt.loc[n, "wls_rel_std"]), "gaz": gaz_beta[n]}
                      for n in gaz_beta]
    A_gaz = gaz.friction_parameters["A"]
    return {
        "settings": {k2: res.settings[k2] for k2 in ("fc_position", "nd", "f_decimation_cutoff",
                                                      "edge", "qd_threshold")},
        "n_raw": exp.n_samples, "fs": exp.fs, "t_split": float(t_split),
        "n_train_raw": train.n_samples, "n_held_raw": held.n_samples,
        "n_train": int(res.observation.n_samples), "n_held": int(len(obs.t)),
        "held_t": [float(obs.t[0]), float(obs.t[-1])],
        "n_base": res.base.n_base, "n_essential": len(res.model.names),
        "rel_error_identification": float(res.model.rel_error),
        "rel_error_identification_ols": float(res.ols.rel_error),
        "validate_rel_error": float(val.rel_error), "validate_n": int(len(val.t)),
        "validate_moving_rel_error": float(val.moving_rel_error), "uncertainty": res.uncertainty,
        "dead_zone": dead,
        "held_out": _errors(tau_d, tau_hat),
        "held_out_raw": _errors(tau_raw, tau_hat),
        "raw_above_lowpass_mse": np.mean((tau_raw - tau_d) ** 2, axis=0).tolist(),
        "gaz_gf": _errors(tau_d, gaz_gf_d),
        "gaz_gf_plus_dynid_inertial": _errors(tau_d, gaz_gf_d + inertial_d),
        "tau_rms_held": np.sqrt(np.mean(tau_d ** 2, axis=0)).tolist(),
        "inertial_rms_held": np.sqrt(np.mean(inertial_d ** 2, axis=0)).tolist(),
        "gravity_diff_rms": np.sqrt(np.mean(g_diff ** 2, axis=0)).tolist(),
        "gravity_fit_residual": float(np.linalg.norm(A @ beta - y) / np.linalg.norm(y)),
        "gravity_parameters": gravity_params,
        "actuator_parameters": actuator,
        "offsets": off.tolist(),
        "gaz_coulomb_equivalent": (A_gaz / 2).tolist(),
        "published_mse": PUBLISHED_MSE,
        "essential_names": list(res.model.names),
        "notices": list(res.notices),
    }


def _row(label, vals, fmt="{:8.3f}"):
    return f"  {label:<44}" + "".join(fmt.format(v) for v in vals)


def report(r):
    """The printed table (text)."""
    L = []
    s = r["settings"]
    L.append(f"Franka Panda (Gaz et al. 2019): {r['n_raw']} samples at {r['fs']:.0f} Hz after "
             f"resampling; identification t < {r['t_split']:.3f} s ({r['n_train_raw']} samples), "
             f"held out the last {HOLDOUT} s ({r['n_held_raw']} samples)")
    L.append(f"  processing: fc = {s['fc_position']:g} Hz, nd = {s['nd']}, decimation low-pass "
             f"{s['f_decimation_cutoff']:g} Hz, {s['edge']} samples cut at each end; decimated: "
             f"{r['n_train']} identification, {r['n_held']} held-out samples "
             f"(t = {r['held_t'][0]:.2f} ... {r['held_t'][1]:.2f} s)")
    L.append(f"  base parameters {r['n_base']}, essential {r['n_essential']}")
    L.append(f"  relative error ||tau - tau_hat|| / ||tau||: identification {100 * r['rel_error_identification']:.2f} % "
             f"(OLS, all base parameters: {100 * r['rel_error_identification_ols']:.2f} %)")
    L.append(f"  held-out, ALL {r['n_held']} decimated samples: {100 * r['held_out']['rel_error']:.2f} %   "
             f"(dynid validate(): all samples {100 * r['validate_rel_error']:.2f} %, moving samples only "
             f"{100 * r['validate_moving_rel_error']:.2f} %)")
    L.append(f"  Gaz et al. gravity + friction only, same samples: {100 * r['gaz_gf']['rel_error']:.1f} %; "
             f"completed with dynid's inertial + Coriolis part: "
             f"{100 * r['gaz_gf_plus_dynid_inertial']['rel_error']:.2f} %")
    L.append("")
    L.append(_row("joint", range(1, 8), "{:>8d}"))
    L.append(_row("held-out tau RMS [N m]", r["tau_rms_held"]))
    L.append(_row("dynid held-out RMS [N m]", r["held_out"]["rms"]))
    L.append(_row("dynid held-out MSE [N m^2]", r["held_out"]["mse"], "{:8.4f}"))
    L.append(_row("dynid MSE against raw tau, same instants", r["held_out_raw"]["mse"], "{:8.4f}"))
    L.append(_row("  raw tau minus its 4 Hz low-pass, MSE", r["raw_above_lowpass_mse"], "{:8.4f}"))
    L.append(_row("Gaz et al. published MSE (own trajectories)", r["published_mse"], "{:8.3f}"))
    L.append(_row("Gaz g + f MSE, same samples [N m^2]", r["gaz_gf"]["mse"], "{:8.3f}"))
    L.append(_row("Gaz g + f + dynid inertial MSE [N m^2]", r["gaz_gf_plus_dynid_inertial"]["mse"], "{:8.4f}"))
    L.append(_row("dynid inertial + Coriolis part RMS [N m]", r["inertial_rms_held"]))
    L.append(_row("gravity: dynid - Gaz, RMS [N m]", r["gravity_diff_rms"]))
    L.append("")
    L.append(f"  dead zone: {r['dead_zone']}")
    L.append("  (validate()'s moving-samples figure leaves those rows out; the ALL figures keep every sample)")
    L.append("")
    L.append("  rotor inertia and friction (link-side sensors: rotor and motor friction are not in tau):")
    L.append(f"    %sigma from the {r['uncertainty']} covariance (dynid identify's default)")
    L.append("    name        WLS value    WLS %sigma   essential value   %sigma")
    for a in r["actuator_parameters"]:
        ev = (f"{a['essential_value']:14.4g}  {a['essential_rel_std']:7.1f}" if a["essential"]
              else "       (dropped)")
        L.append(f"    {a['name']:<8}{a['wls']:12.4g}  {a['wls_rel_std']:11.1f}   {ev}")
    L.append("    Ia1, Ia2 are regrouped into ZZ1R, ZZ2R (not identifiable apart).")
    L.append("    Gaz et al.'s sigmoid friction tends to about +-A/2: "
             + " ".join(f"{v:.2f}" for v in r["gaz_coulomb_equivalent"]) + " N m")
    L.append("")
    L.append(f"  gravity parameters (dynid WLS vs implied by Gaz et al.'s g(q); that fit's "
             f"relative residual {r['gravity_fit_residual']:.1e}):")
    for g in r["gravity_parameters"]:
        L.append(f"    {g['name']:<6}{g['dynid']:10.4f} ({g['dynid_rel_std']:5.1f} %)   Gaz {g['gaz']:10.4f}")
    return "\n".join(L)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="the franka-panda-gaz folder (holding rbt_log/ and model/); "
                                   "default: shared/data/franka-panda-gaz in a parent directory")
    ap.add_argument("--out", default="out/franka_panda",
                    help="folder for panda.csv, experiment.toml and panda.json "
                         "(default ./out/franka_panda)")
    ap.add_argument("--json", help="also write the figures as JSON here "
                                   "(default OUT/panda.json)")
    args = ap.parse_args(argv)

    from convert import find_data, missing_data_message

    from dynid.errors import DynidError

    t0 = time.perf_counter()
    data = find_data(args.data)
    if data is None or not (data / "rbt_log").is_dir() or not (data / "model").is_dir():
        print(f"error: {missing_data_message(args.data)}", file=sys.stderr)
        return 2
    try:
        toml = prepare(data, args.out)
        r = analyse(toml, data)
    except DynidError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    r["seconds"] = time.perf_counter() - t0
    print(report(r))
    path = Path(args.json) if args.json else Path(args.out) / "panda.json"
    path.write_text(json.dumps(r, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"\n  data: {data}\n  wrote {Path(args.out) / 'panda.csv'}, "
          f"{Path(args.out) / 'experiment.toml'}, {path} in {r['seconds']:.1f} s")
    print(f"  same identification from the command line: {CLI}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
