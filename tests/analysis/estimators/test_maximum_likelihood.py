"""Maximum likelihood with errors in variables (Bona & Curatella 2005, eqs. (13)-(16)).

Data: the closed-loop motion of a one-joint pendulum (dynid's simulator, PD +
feedforward, periodic steady state), simulated once; each seed adds white
Gaussian noise to the recorded positions and torques. OLS is IDIM's: q
filtered (zero-phase Butterworth) and differentiated, torques regressed on
the regressor of those noisy signals.
"""
from __future__ import annotations

import json
import math
import time

import bias_scenarios as bs
import numpy as np
import pytest

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.maximum_likelihood import (
    fourier_basis,
    joint_model,
    linear_model,
    maximum_likelihood,
    robot_model,
    select_harmonics,
)
from dynid.analysis.processing.signals import derivatives
from dynid.dynamics.base_parameters import base_regressor
from dynid.errors import InputError
from dynid.provenance import dumps_json

N_SEEDS = 50
FS = 200.0
SIGMA_Q = 5e-3          # rad
SIGMA_TAU = 0.5         # N m
K = 20                  # latent harmonics (see test_default_harmonics_are_chosen_by_bic)
FC = 20.0               # Hz, OLS position filter


def noisy(seed):
    t, q, tau = bs.periodic_motion(fs=FS)
    rng = np.random.default_rng(seed)
    return t, q + rng.normal(size=q.shape) * SIGMA_Q, tau + rng.normal(size=tau.shape) * SIGMA_TAU


def ols_estimate(q, tau):
    robot, bp, _, _ = bs.pendulum()
    d = derivatives(q, FS, FC)
    sl = slice(20, q.shape[0] - 20)
    W = base_regressor(robot, bp, d.q[sl], d.qd[sl], d.qdd[sl])
    keep = bs.dead_zone(d.qd[sl], threshold=0.1, guard=5)
    return ls.ols(W, tau[sl], bp.names, row_mask=keep).chi


@pytest.fixture(scope="module")
def campaign():
    robot, bp, _, beta = bs.pendulum()
    model = robot_model(robot, bp)
    t0 = time.perf_counter()
    e_ols, e_ml, s_ml, last = [], [], [], None
    for seed in range(N_SEEDS):
        t, q, tau = noisy(seed)
        e_ols.append(ols_estimate(q, tau) - beta)
        last = maximum_likelihood(t, q, tau, model, f0=bs.F0, n_harmonics=K)
        e_ml.append(last.chi - beta)
        s_ml.append(last.bse.to_numpy())
    return {"names": list(bp.names), "beta": beta, "ols": np.array(e_ols), "ml": np.array(e_ml),
            "ml_sigma": np.array(s_ml), "last": last, "elapsed": time.perf_counter() - t0}


def test_ml_is_less_biased_than_ols_with_noise_on_q_and_tau(campaign):
    names, beta = campaign["names"], campaign["beta"]
    n = campaign["ols"].shape[0]
    b_o, se_o = campaign["ols"].mean(0), campaign["ols"].std(0, ddof=1) / math.sqrt(n)
    b_m, se_m = campaign["ml"].mean(0), campaign["ml"].std(0, ddof=1) / math.sqrt(n)
    print(f"\nerrors in variables, {n} seeds ({campaign['elapsed']:.1f} s):")
    for k, nm in enumerate(names):
        print(f"  {nm:5s} true {beta[k]:7.4f}  OLS bias {b_o[k]:+.4f} ± {se_o[k]:.4f}   "
              f"ML bias {b_m[k]:+.4f} ± {se_m[k]:.4f}")
    # the bias that matters, over the parameters with a non-zero true value, relative to it
    nz = np.abs(beta) > 0
    rel_o = np.abs(b_o[nz] / beta[nz])
    rel_m = np.abs(b_m[nz] / beta[nz])
    print(f"  mean |relative bias|: OLS {rel_o.mean():.4f}, ML {rel_m.mean():.4f}")
    assert rel_m.mean() < 0.5 * rel_o.mean()
    # the inertia, which errors in the acceleration attenuate: OLS clearly biased, ML far less
    i = names.index("ZZ1R")
    assert abs(b_o[i]) > 10 * se_o[i]
    assert abs(b_m[i]) < 0.1 * abs(b_o[i])
    # every parameter: ML's |bias| no larger than OLS's (within the two standard errors)
    assert np.all(np.abs(b_m) <= np.abs(b_o) + 2 * np.hypot(se_o, se_m)), (b_m, b_o)


def test_ml_covariance_is_calibrated(campaign):
    # inverse Fisher information vs the spread of the estimates over the seeds
    emp = campaign["ml"].std(axis=0, ddof=1)
    rep = campaign["ml_sigma"].mean(axis=0)
    ratio = rep / emp
    print("\nML reported sigma / spread over seeds:", dict(zip(campaign["names"], ratio.round(2))))
    # 50 seeds: the sample std itself is uncertain by ~10 %
    assert np.all((ratio > 0.75) & (ratio < 1.35)), ratio


def test_result_object(campaign):
    res = campaign["last"]
    assert res.converged and res.n_harmonics == K
    # the noise levels are recovered from the data
    assert abs(res.sigma_q[0] / SIGMA_Q - 1) < 0.1 and abs(res.sigma_tau[0] / SIGMA_TAU - 1) < 0.15
    text = res.summary()
    assert "errors in variables" in text and "ZZ1R" in text
    d = json.loads(dumps_json(res.to_dict()))
    assert d["method"] == "ML-EIV" and len(d["parameters"]) == len(campaign["names"])
    q, qd, qdd = res.trajectory(np.linspace(0, 1, 5))
    assert q.shape == (5, 1)


def test_per_joint_model_nonlinear_in_its_parameters():
    # tau = J qdd + Fv qd + Fc sign(qd) + k sin(q + q_off) + Off is the pendulum's own
    # equation written differently (gravity along -y: g (MX1 cos q - MY1 sin q)), so on the
    # same data its ML estimate must map onto the rigid-body model's one
    robot, bp, _, beta = bs.pendulum()
    g = 9.81
    t, q, tau = noisy(100)
    a = maximum_likelihood(t, q, tau, joint_model(1), f0=bs.F0, n_harmonics=K)
    b = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0, n_harmonics=K)
    J, Fv, Fc, k, qoff, off = a.chi
    ZZ, MX, MY, Fv_b, Fc_b, Off_b = b.chi
    mapped = np.array([J, k * math.sin(qoff) / g, -k * math.cos(qoff) / g, Fv, Fc, off])
    assert np.allclose(mapped, b.chi, rtol=2e-3, atol=2e-3 * np.abs(b.chi).max()), (mapped, b.chi)
    # and against the truth, within 4 of its own standard deviations
    for name, true in (("J1", beta[0]), ("k1", g * beta[1]), ("qoff1", math.pi / 2)):
        value, std = a[name]
        assert abs(value - true) < 4 * std, (name, value, std, true)
    # the nonlinear parameter's sigma comes from the finite-difference Jacobian
    assert 0 < a["qoff1"][1] < 0.01


def test_linear_model_wrapper_matches_robot_model():
    robot, bp, _, _ = bs.pendulum()
    t, q, tau = noisy(7)
    m1 = robot_model(robot, bp)
    m2 = linear_model(lambda q, qd, qdd: base_regressor(robot, bp, q, qd, qdd), bp.names)
    a = maximum_likelihood(t, q, tau, m1, f0=bs.F0, n_harmonics=10)
    b = maximum_likelihood(t, q, tau, m2, f0=bs.F0, n_harmonics=10, sigma_q=a.sigma_q,
                           sigma_tau=a.sigma_tau, refine_sigma_tau=False)
    assert np.allclose(a.chi, b.chi, rtol=1e-3, atol=1e-4)


def test_fourier_basis_derivatives_and_bic():
    t = np.linspace(0, 2, 401)
    B, Bd, Bdd = fourier_basis(t, 0.5, 3)
    assert np.allclose(np.gradient(B, t, axis=0)[5:-5], Bd[5:-5], rtol=1e-3, atol=1e-3)
    assert np.allclose(np.gradient(Bd, t, axis=0)[5:-5], Bdd[5:-5], rtol=1e-3, atol=1e-2)
    rng = np.random.default_rng(0)
    q = (B @ np.array([0.1, 1, 0.5, 0.3, -0.2, 0.7, 0.4]))[:, None] + 1e-3 * rng.normal(size=(401, 1))
    K_sel, per, table = select_harmonics(t, q, 0.5)
    assert K_sel == 3 and per == [3]


def test_default_harmonics_are_chosen_by_bic():
    robot, bp, _, _ = bs.pendulum()
    t, q, tau = noisy(3)
    res = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0)
    assert 5 <= res.n_harmonics <= 40 and any("BIC" in n for n in res.notices)


def test_bad_input():
    robot, bp, _, _ = bs.pendulum()
    model = robot_model(robot, bp)
    t, q, tau = noisy(1)
    with pytest.raises(InputError, match="same number"):
        maximum_likelihood(t, q[:-1], tau, model, f0=bs.F0)
    bad = q.copy()
    bad[3, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        maximum_likelihood(t, bad, tau, model, f0=bs.F0)
    with pytest.raises(InputError, match="f0"):
        maximum_likelihood(t, q, tau, model, f0=-1)
    with pytest.raises(InputError, match="too few"):
        maximum_likelihood(t[:30], q[:30], tau[:30], model, f0=bs.F0, n_harmonics=20)
    with pytest.raises(InputError, match="sigma_q"):
        maximum_likelihood(t, q, tau, model, f0=bs.F0, sigma_q=-1.0)
    with pytest.raises(InputError, match="theta0"):
        maximum_likelihood(t, q, tau, model, f0=bs.F0, theta0=[1.0, 2.0])
    with pytest.raises(InputError, match="qd_threshold"):
        maximum_likelihood(t, q, tau, model, f0=bs.F0, qd_threshold="never")


def test_a_joint_that_never_moves_is_refused_as_by_idim():
    """ML on a recording whose joint 2 stands still returned Ia2 = -3e13 with sigma 1e-32 and an [ok]
    %sigma line (found by a bad-input hunt); IDIM refuses the same data, and so does ML now."""
    import dataclasses

    import dynid
    from dynid.errors import IdentificationError
    exp = dynid.simulate("planar2", duration=4.0, seed=1, f0=0.5, harmonics=3).experiment
    q = exp.q.copy()
    q[:, 1] = 0.2
    still = dataclasses.replace(exp, q=q, qr=None if exp.qr is None else q.copy())
    with pytest.raises(IdentificationError, match="rank-deficient"):
        dynid.identify(still, "planar2", method="ml", f0=0.5)
    assert np.isfinite(dynid.identify(exp, "planar2", method="ml", f0=0.5).params).all()


def test_a_motion_that_is_not_periodic_at_the_noise_level_is_said():
    """Two periods with the closed loop's start-up transient: the latent trajectory left 100 times q's
    noise, ML read it as position noise, and Fv1 came out 7 sigma off without a word (bad-input hunt)."""
    import dynid
    exp = dynid.simulate("planar2", duration=4.0, seed=1, f0=0.5, harmonics=3).experiment
    r = dynid.identify(exp, "planar2", method="ml", f0=0.5)
    assert any("times the noise of joint" in n for n in r.notices), r.notices
    steady = exp.segment(2.0, exp.t[-1] + 1.0)          # the second period alone
    r2 = dynid.identify(steady, "planar2", method="ml", f0=0.5)
    assert not any("times the noise" in n for n in r2.notices), r2.notices


def test_progress_follows_the_optimiser_and_leaves_the_estimate_alone():
    """ML ran for a minute without a progress line: it now reports the share of its evaluation
    budget spent (rising, ending at 1), and the estimate is the one without progress."""
    robot, bp, _, _ = bs.pendulum()
    t, q, tau = noisy(101)
    seen = []
    a = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0, n_harmonics=K, progress=seen.append)
    b = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0, n_harmonics=K)
    assert len(seen) >= a.n_evaluations and seen[-1] == 1.0
    assert all(0 < f <= 1 for f in seen) and seen == sorted(seen)
    assert np.array_equal(a.chi, b.chi) and np.array_equal(a.cov, b.cov)
