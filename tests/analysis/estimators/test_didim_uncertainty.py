"""DIDIM's sigma: the robust covariance of the last Gauss-Newton step and the identified gains' share.

Data from dynid's own closed-loop simulator (it tests the estimator here, not itself): the TX40
with the Table 2 values under the robot file's PD (at 1 kHz), 3 s, torque noise coloured (AR(1),
coefficient 0.99 at 1 kHz: correlated over ~0.1 s, longer than the decimation step) as on real closed-loop data. The coverage of the intervals is
measured on the independent Pinocchio plant by benchmarks/coverage_didim.py, not here.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.signal import lfilter

from dynid.analysis.data.synthetic import simulate_experiment, tx40_true_parameters
from dynid.analysis.estimators.controller_gains import GainsResult
from dynid.analysis.estimators.didim import didim_covariance, identify_didim
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import random_fourier_trajectory
from dynid.errors import InputError


@pytest.fixture(scope="module")
def run():
    robot = load_robot("tx40")
    # a 1 kHz controller: the data are recorded at its rate (a cheap run)
    robot = dataclasses.replace(robot, controller=dataclasses.replace(robot.controller, rate=1000.0))
    bp = base_parameters(robot)
    beta, chi = tx40_true_parameters(robot, bp)
    rng = np.random.default_rng(3)
    traj = random_fourier_trajectory(robot, 1 / 3.0, 10, rng)
    exp = simulate_experiment(robot, chi, traj, 3.0, rng=rng, q_noise=0.0, tau_noise=0.0, v_s=0.05,
                              name="simulated TX40")
    scale = np.array([2.0, 2.0, 0.7, 0.25, 0.4, 0.25])
    e = rng.standard_normal(exp.tau.shape) * scale * np.sqrt(1 - 0.99 ** 2)
    exp = dataclasses.replace(exp, tau=exp.tau + lfilter([1.0], [1.0, -0.99], e, axis=0))
    res = identify_didim(exp, robot, bp=bp, settings={"v_s": 0.05}, max_iter=4, essential=False)
    return robot, bp, exp, res


def test_robust_sigma_of_the_last_step(run):
    robot, bp, exp, res = run
    classic = res.result.bse.to_numpy()
    for opt in ("hac", "bootstrap"):
        r = didim_covariance(res, opt)
        np.testing.assert_allclose(r.chi, res.chi, rtol=1e-10, atol=1e-14)
        assert r.settings["least_squares"]["uncertainty"]["uncertainty"] == opt
        # AR(1) noise correlated beyond the decimation step: the samples are not independent, eq. (14) is optimistic
        ratio = np.median(r.bse.to_numpy() / classic)
        print(opt, "median sigma / classic", round(float(ratio), 3))
        assert ratio > 1.05, (opt, ratio)
    np.testing.assert_allclose(didim_covariance(res, "classic").cov, res.result.cov)
    with pytest.raises(InputError, match="uncertainty"):
        didim_covariance(res, "sandwich")
    with pytest.raises(InputError, match="uncertainty"):
        identify_didim(exp, robot, bp=bp, uncertainty="white")


def _robot_file_gains(robot, n_rows, rel_sd):
    """The robot file's PD gains as identified gains with relative standard deviations `rel_sd` (12,)."""
    c = robot.controller
    g = np.array([jt.drive_gain for jt in robot.joints])
    kv = 2 * np.asarray(c.zeta) * np.asarray(c.wn)
    Kd = kv * g * np.asarray(c.J_ap) / np.asarray(c.g_ap)
    Kp = Kd * np.asarray(c.wn) / (2 * np.asarray(c.zeta))
    names = [f"{k}{j + 1}" for j in range(6) for k in ("Kp", "Kd")]
    chi = np.ravel(np.column_stack([Kp, Kd]))
    return GainsResult(names=names, chi=chi, cov=np.diag((np.asarray(rel_sd) * chi) ** 2), n_joints=6,
                       feedforward=True, integral=False, rel_error=np.zeros(6), n_rows=n_rows, source="test")


@pytest.mark.slow
def test_gains_covariance_is_propagated(run):
    """The gains' covariance enters through the loop: nothing without it, more with more of it."""
    robot, bp, exp, res = run
    c = robot.controller
    gains = _robot_file_gains(robot, exp.t.size, [0.02] * 12)
    assert np.allclose(gains.controller(robot).wn, c.wn) and np.allclose(gains.controller(robot).zeta, c.zeta)
    none = didim_covariance(res, "classic", gains=dataclasses.replace(gains, cov=0 * gains.cov))
    np.testing.assert_array_equal(none.cov, res.result.cov)
    one = didim_covariance(res, "classic", gains=gains)
    four = didim_covariance(res, "classic", gains=dataclasses.replace(gains, cov=16 * gains.cov))
    np.testing.assert_allclose(one.chi, res.chi)
    add1, add4 = np.diag(one.cov - res.result.cov), np.diag(four.cov - res.result.cov)
    assert np.all(add1 >= 0) and add1.max() > 0
    # 4x the gains' sigma: more (not 16x: the one-sided differences of the loop are not linear
    # over 2-8 % of a gain; the estimate's response to the gains is of the size of its noise)
    assert add4.sum() > 2 * add1.sum(), (add4.sum(), add1.sum())
    assert any("controller gains" in n for n in one.notices)


def test_a_gain_whose_moved_loop_cannot_be_simulated_is_moved_the_other_way_or_said(run, monkeypatch):
    """A converged estimate need not be a rigid body off its own simulated motion: a loop moved by a
    gain's sigma can reach a pose where M(q) is not positive definite. The covariance step then moves
    that gain the other way, and when neither way simulates, leaves its share out and says so (it
    raised, after a converged run, on held-out plant seed 14384)."""
    from dynid.analysis.estimators import didim as didim_module
    robot, bp, exp, res = run
    gains = _robot_file_gains(robot, exp.t.size, [0.02, 0.02] + [0.0] * 10)   # Kp1 and Kd1 only
    real, calls = didim_module._simulate, []

    def refuse(*args, **kwargs):
        calls.append(len(calls))
        if len(calls) in (1, 3, 4):   # Kp1 +sigma; Kd1 +sigma and -sigma
            raise InputError("simulate_closed_loop: the mass matrix M(q) of these parameters is not positive "
                             "definite")
        return real(*args, **kwargs)

    monkeypatch.setattr(didim_module, "_simulate", refuse)
    r = didim_covariance(res, "classic", gains=gains)
    assert len(calls) == 4
    unc = r.settings["least_squares"]["uncertainty"]
    assert unc["controller_gains_missing"] == ["Kd1"]
    assert "covariance of the 1 identified gains" in unc["controller_gains"]
    assert any("Kd1" in n and "optimistic" in n for n in r.notices)
    add = np.diag(r.cov - res.result.cov)
    assert np.all(add >= -1e-12 * np.abs(np.diag(res.result.cov))) and add.max() > 0   # Kp1's share is in
    np.testing.assert_allclose(r.chi, res.chi)


def test_reported_essential_parameters_carry_the_chosen_covariance(run):
    """The essential set DIDIM reports (`params`, `bse`) gets the option's covariance, by the rule of
    IDIM's essential set: the full model's robust sigma of the same parameters with the removal bias
    added; a classic covariance asked for afterwards is still eq. (14)."""
    robot, bp, exp, classic_run = run
    res = identify_didim(exp, robot, bp=bp, settings={"v_s": 0.05}, max_iter=4, essential=True,
                         uncertainty="hac")
    np.testing.assert_allclose(res.result.chi, classic_run.result.chi, rtol=1e-10, atol=1e-14)
    ess = res.essential.result
    cols = [list(res.result.names).index(n) for n in ess.names]
    d = ess.chi - res.result.chi[cols]
    expected = res.result.cov[np.ix_(cols, cols)] + np.outer(d, d)
    np.testing.assert_allclose(res.cov.to_numpy() if hasattr(res.cov, "to_numpy") else res.cov, expected)
    np.testing.assert_allclose(res.bse.to_numpy(), np.sqrt(np.diag(expected)))
    assert ess.settings["least_squares"]["uncertainty"]["uncertainty"] == "hac"
    assert "selection_bias" in ess.settings["least_squares"]["uncertainty"]
    assert res.essential.base is res.result
    half = (res.conf_int().iloc[:, 1] - res.conf_int().iloc[:, 0]).to_numpy() / 2
    np.testing.assert_allclose(half, 1.959963984540054 * res.bse.to_numpy(), rtol=1e-9)
    # eq. (14) of the last step, not the hac covariance the run reported
    np.testing.assert_allclose(didim_covariance(res, "classic").cov, classic_run.result.cov, rtol=1e-10)
    hac_sigma = res.result.bse.to_numpy()
    assert np.median(hac_sigma / classic_run.result.bse.to_numpy()) > 1.05


def test_the_physical_fit_does_not_depend_on_the_covariance_option():
    """PC-DIDIM, as IDIM's PC-WLS: the metric is eq. (14)'s, so the estimate is the same for every
    `uncertainty`; only its σ follows the option, and the result names it (it used the robust
    covariance as the metric, moved ZZ2R by 0.7σ and said "classic")."""
    import dynid
    robot = dynid.load_robot("planar2")
    exp = dynid.simulate(robot, 6.0, seed=1).experiment
    a = dynid.identify(exp, robot, method="didim", physical=True, uncertainty="classic", bootstrap=20)
    b = dynid.identify(exp, robot, method="didim", physical=True, uncertainty="bootstrap", bootstrap=20)
    assert np.array_equal(a.physical.chi, b.physical.chi) and a.physical.chi2 == b.physical.chi2
    assert (a.physical.uncertainty, b.physical.uncertainty) == ("classic", "bootstrap")
    assert not np.allclose(a.physical.bse.to_numpy(), b.physical.bse.to_numpy())
