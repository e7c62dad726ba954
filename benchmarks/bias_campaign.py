"""Campaign: closed-loop bias of LS vs the Projection Method, and errors-in-variables bias
of OLS vs maximum likelihood (Bona & Curatella 2005, eqs. (10)-(16)).

    python benchmarks/bias_campaign.py                  # 100 seeds each
    python benchmarks/bias_campaign.py --seeds 50

Data (bias_scenarios): a one-joint pendulum simulated by dynid's
closed-loop simulator (PD + velocity feedforward).

* Closed loop: a coloured torque disturbance (6 N m RMS, low-passed at 15 Hz)
  and coloured position-sensor noise (1 mrad, 8 Hz) fed back through the
  controller; 8 s at 500 Hz per seed. LS = IDIM OLS on the measured
  positions; PM = dynid.analysis.estimators.projection.projection_method (FIR up to 25 lags,
  BIC).
* Errors in variables: one periodic steady-state motion, 4 s at 200 Hz;
  per seed white noise on q (5 mrad) and tau (0.5 N m). OLS = IDIM OLS on the
  Butterworth-filtered (20 Hz) noisy q; ML = dynid.analysis.estimators.maximum_likelihood with
  K = 20 latent harmonics.

Reference computation (same process): the 2SLS estimate written out with
numpy (chi = (W'PW)^-1 W'Pu, P from lstsq on the lag matrix) for the first
seeds, and the OLS-start of the ML; the ratios of timings and the largest
difference are printed. The last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # small BLAS calls: threads only cost

import argparse
import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))   # bias_scenarios: a test fixture

import bias_scenarios as bs  # noqa: E402
import numpy as np  # noqa: E402

from dynid.analysis.estimators import least_squares as ls  # noqa: E402
from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model  # noqa: E402
from dynid.analysis.estimators.projection import lag_matrix, projection_method  # noqa: E402
from dynid.analysis.processing.signals import derivatives  # noqa: E402
from dynid.dynamics.base_parameters import base_regressor  # noqa: E402


def _stats(e):
    return e.mean(axis=0), e.std(axis=0, ddof=1) / math.sqrt(e.shape[0])


def _reference_2sls(run, res):
    """2SLS with numpy, same rows and window, no dead zone handling beyond zeroing."""
    keep = run["keep"][:, 0]
    rows = res.rows
    m1, m2 = res.m1[0], res.m2[0]
    _, R = lag_matrix(run["r"][:, 0], m1, m2)
    R = R[rows - m2]
    W = run["W"][rows, 0, :] * keep[rows, None]
    u = run["u"][rows, 0] * keep[rows]
    PW = R @ np.linalg.lstsq(R, W, rcond=None)[0]
    return np.linalg.solve(PW.T @ W, PW.T @ u)


def closed_loop(seeds):
    e_ls, e_pm, t_pm, t_ref, d_ref = [], [], 0.0, 0.0, []
    t_sim = 0.0
    for seed in range(seeds):
        a = time.perf_counter()
        run = bs.closed_loop_run(seed)
        t_sim += time.perf_counter() - a
        a = time.perf_counter()
        res = projection_method(run["W"], run["u"], run["r"], run["names"], row_mask=run["keep"],
                                max_lag=25)
        t_pm += time.perf_counter() - a
        e_ls.append(res.ls.chi - run["beta"])
        e_pm.append(res.chi - run["beta"])
        if seed < 5:
            a = time.perf_counter()
            ref = _reference_2sls(run, res)
            t_ref += time.perf_counter() - a
            d_ref.append(np.max(np.abs(ref - res.chi) / np.maximum(np.abs(res.bse.to_numpy()), 1e-12)))
    names = run["names"]
    b_ls, se_ls = _stats(np.array(e_ls))
    b_pm, se_pm = _stats(np.array(e_pm))
    print(f"closed loop, {seeds} seeds: simulation {t_sim:.1f} s, PM {t_pm:.2f} s "
          f"({1000 * t_pm / seeds:.0f} ms per recording)")
    for k, n in enumerate(names):
        print(f"  {n:5s} LS bias {b_ls[k]:+.4f} ± {se_ls[k]:.4f}   PM bias {b_pm[k]:+.4f} ± {se_pm[k]:.4f}")
    print(f"  reference 2SLS (numpy lstsq projection) vs PM, first 5 seeds: largest difference "
          f"{max(d_ref):.2e} PM standard deviations (the two differ in how they truncate the "
          f"numerically dependent lag directions); time ratio PM / reference "
          f"{(t_pm / seeds) / (t_ref / min(seeds, 5)):.2f} (PM also chooses the order, runs LS and the HAC covariance)")
    i = names.index("ZZ1R")
    return {"parameter": "ZZ1R", "true": float(run["beta"][i]),
            "ls_bias": float(b_ls[i]), "ls_se": float(se_ls[i]),
            "pm_bias": float(b_pm[i]), "pm_se": float(se_pm[i]),
            "pm_max_abs_z": float(np.max(np.abs(b_pm / se_pm))),
            "ls_max_abs_z": float(np.max(np.abs(b_ls / se_ls))),
            "ref_max_diff_sigma": float(max(d_ref)), "pm_ms_per_run": 1000 * t_pm / seeds}


def eiv(seeds):
    robot, bp, _, beta = bs.pendulum()
    model = robot_model(robot, bp)
    t, q0, tau0 = bs.periodic_motion(fs=200.0)
    e_o, e_m, e_s, t_ml, t_ols = [], [], [], 0.0, 0.0
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        q = q0 + rng.normal(size=q0.shape) * 5e-3
        tau = tau0 + rng.normal(size=q0.shape) * 0.5
        a = time.perf_counter()
        d = derivatives(q, 200.0, 20.0)
        sl = slice(20, q.shape[0] - 20)
        W = base_regressor(robot, bp, d.q[sl], d.qd[sl], d.qdd[sl])
        e_o.append(ls.ols(W, tau[sl], bp.names, row_mask=bs.dead_zone(d.qd[sl], 0.1, 5)).chi - beta)
        t_ols += time.perf_counter() - a
        a = time.perf_counter()
        r = maximum_likelihood(t, q, tau, model, f0=bs.F0, n_harmonics=20)
        t_ml += time.perf_counter() - a
        e_m.append(r.chi - beta)
        e_s.append(r.theta_ls - beta)
    b_o, se_o = _stats(np.array(e_o))
    b_m, se_m = _stats(np.array(e_m))
    b_s, _ = _stats(np.array(e_s))
    nz = np.abs(beta) > 0
    print(f"errors in variables, {seeds} seeds: OLS {t_ols:.2f} s, ML {t_ml:.2f} s "
          f"(ratio ML / OLS {t_ml / t_ols:.1f})")
    for k, n in enumerate(bp.names):
        print(f"  {n:5s} OLS bias {b_o[k]:+.4f} ± {se_o[k]:.4f}   ML bias {b_m[k]:+.4f} ± {se_m[k]:.4f}"
              f"   (LS on the Fourier-fitted q, ML's start: {b_s[k]:+.4f})")
    rel_o = float(np.mean(np.abs(b_o[nz] / beta[nz])))
    rel_m = float(np.mean(np.abs(b_m[nz] / beta[nz])))
    rel_s = float(np.mean(np.abs(b_s[nz] / beta[nz])))
    print(f"  mean |relative bias| over the non-zero parameters: OLS {rel_o:.4f}, ML {rel_m:.4f} "
          f"(ratio {rel_m / rel_o:.3f}); ML's LS start {rel_s:.4f}")
    return {"ols_mean_rel_bias": rel_o, "ml_mean_rel_bias": rel_m, "ml_start_mean_rel_bias": rel_s,
            "ratio_ml_ols": rel_m / rel_o, "ml_ms_per_run": 1000 * t_ml / seeds,
            "ols_ms_per_run": 1000 * t_ols / seeds}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=100)
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    pm = closed_loop(a.seeds)
    ml = eiv(a.seeds)
    out = {"seeds": a.seeds, "closed_loop": pm, "errors_in_variables": ml,
           "elapsed_s": time.perf_counter() - t0}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
