"""PC-WLS with effect columns (analysis/diagnosis/physical_fit.py) on the real KUKA LWR4+."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cvxpy")

import dynid
from dynid.analysis.diagnosis.physical_fit import (
    effect_candidates,
    effect_design,
    held_out_errors,
    identify_physical_effects,
)
from dynid.analysis.estimators import least_squares as ls
from dynid.errors import InputError

HERE = Path(__file__).resolve().parents[3] / "examples" / "kuka_lwr4"


@pytest.fixture(scope="module")
def lwr():
    robot = dynid.load_robot("kuka_lwr4")
    rec = {i: dynid.load_experiment(HERE / f"recording_{i}.toml", robot) for i in (1, 2)}
    res = dynid.identify(rec[1], robot)
    return robot, rec, res


def test_candidates_parse_and_refuse():
    c = effect_candidates("spring:all,position_ripple:7:1", 7)
    assert [x.name for x in c] == ["spring"] * 7 + ["position_ripple"]
    assert list(c[-1].active_params) == ["Rc7k1", "Rs7k1"]
    for bad in ("spring:9", "position_ripple:7", "time_delay:all", "spring"):
        with pytest.raises(InputError):
            effect_candidates(bad, 7)


def test_effect_parameters_are_the_least_squares_fit_given_the_physical_base(lwr):
    """Eq. (2): theta_pc minimises the weighted residual for the PC base parameters, i.e. the
    weighted normal equations in theta hold at (beta_pc, theta_pc)."""
    robot, rec, res = lwr
    fit = identify_physical_effects(rec[1], robot, res, effect_candidates("spring:all", 7), n_boot=0)
    W, tau, mask, names = effect_design(rec[1], robot, res.base, fit.settings, fit.candidates)
    assert names == fit.names and len(names) == res.base.n_base + 7
    w = np.where(mask, 1.0 / np.asarray(fit.wls.joint_sigma)[None, :], 0.0)
    r = (tau - W @ fit.x_pc) * w
    C = W[:, :, fit.n_base:] * w[:, :, None]
    grad = np.einsum("mjk,mj->k", C, r)
    scale = np.sqrt(np.einsum("mjk,mjk->k", C, C) * np.sum(r ** 2))
    assert np.all(np.abs(grad) <= 1e-6 * scale)
    # and the unconstrained fit is not moved by the profile: beta_pc differs, theta follows
    assert not np.allclose(fit.physical.chi, fit.x_wls[:fit.n_base])


def test_springs_close_the_lwr4_gap_on_flobaroids_split(lwr):
    """Identified on recording 1, validated on 2 (all samples): with a spring on every joint the
    PC fit is consistent and within 0.2 points of the unconstrained fit of the same model
    (measured +0.030; without the springs +0.358, benchmarks/physical.py --effects)."""
    robot, rec, res = lwr
    fit = identify_physical_effects(rec[1], robot, res, effect_candidates("spring:all", 7), n_boot=0)
    e = held_out_errors(fit, rec[2], robot, res.base)
    assert fit.physical.consistent
    assert e["pc"] - e["wls"] < 0.002
    none = identify_physical_effects(rec[1], robot, res, [], n_boot=0)
    e0 = held_out_errors(none, rec[2], robot, res.base)
    assert e0["pc"] - e0["wls"] > 0.003          # the gap the springs remove
    assert e["pc"] < e0["pc"]


def test_effects_sigma_follows_the_rigid_fits_covariance_option(lwr):
    """The effect parameters' sigma is that of the IDIM result's covariance option (the default
    block bootstrap, as the rigid body's), the estimate eq. (14)'s fit: a classic run's."""
    robot, rec, res = lwr
    assert res.uncertainty == "bootstrap"
    c = effect_candidates("spring:all", 7)
    fit = identify_physical_effects(rec[1], robot, res, c, n_boot=0)
    classic = identify_physical_effects(rec[1], robot, dataclasses.replace(res, uncertainty="classic"), c, n_boot=0)
    np.testing.assert_array_equal(fit.x_wls, classic.x_wls)
    np.testing.assert_array_equal(fit.x_pc, classic.x_pc)
    W, tau, mask, names = effect_design(rec[1], robot, res.base, fit.settings, fit.candidates)
    ref = ls.wls(W, tau, names, row_mask=mask, uncertainty="bootstrap", groups=np.zeros(tau.shape[0], int))
    sd = np.array([r["wls_std"] for r in fit.effects()])
    np.testing.assert_allclose(sd, ref.bse.to_numpy()[fit.n_base:], rtol=1e-12)
    sd_classic = np.array([r["wls_std"] for r in classic.effects()])
    assert np.all(sd != sd_classic)
    assert fit.to_dict()["uncertainty"] == "bootstrap" and "block bootstrap" in fit.summary().splitlines()[0]
    assert classic.to_dict()["uncertainty"] == "classic" and "eq. (14)" in classic.to_dict()["sigma"]


def _clamped_case():
    """planar2's a-priori base parameters with Fv1 = Fc2 = 0 (on their bound) and two effect
    parameters, each 0.95-correlated with one of them, sd 1; the base block of the covariance is
    diagonal."""
    from dynid.analysis.estimators.standard_set import apriori_standard
    from dynid.dynamics.base_parameters import base_parameters
    robot = dynid.load_robot("planar2")
    bp = base_parameters(robot)
    b = bp.n_base
    beta = bp.matrix @ apriori_standard(robot)
    idx = [bp.names.index("Fv1"), bp.names.index("Fc2")]
    beta[idx] = 0.0
    sd = np.r_[0.02 * np.abs(beta) + 0.01, 1.0, 1.0]
    corr = np.eye(b + 2)
    for t, i in zip((b, b + 1), idx):
        corr[t, i] = corr[i, t] = 0.95
    return robot, bp, np.r_[beta, 0.0, 0.0], corr * np.outer(sd, sd)


def test_pc_effect_covariance_at_a_lone_bound_is_the_clamped_normal_one():
    """Eq. (3) against a hand-derived value. Fv1 and Fc2 are lone base parameters with only their
    own bound >= 0 and a diagonal base covariance, so PC-WLS clamps them, beta_pc = max(0, beta_hat),
    variance (1/2 - 1/(2 pi)) sigma^2 at a true value 0; an effect parameter with correlation
    rho to one of them then has variance (1 - rho^2) + rho^2 (1/2 - 1/(2 pi)) = 0.405 (sd 1), where
    the unconstrained fit says 1."""
    from dynid.analysis.diagnosis.physical_fit import profile_physical
    robot, bp, x_true, cov = _clamped_case()
    _, _, cov3 = profile_physical(robot, bp, x_true, cov, bp.n_base, n_boot=800, seed=1)
    rho2 = 0.95 ** 2
    expected = (1 - rho2) + rho2 * (0.5 - 1 / (2 * np.pi))
    # 15 %: the bootstrap's own spread is ~4 % at 800 refits; leaving out the Schur term (0.31)
    # or the constraint (1.0) is outside it
    assert np.allclose(np.diag(cov3), expected, rtol=0.15), (np.diag(cov3), expected)


@pytest.mark.slow
def test_pc_effect_covariance_matches_a_monte_carlo_of_the_profiled_fit():
    """Eq. (3) against the estimator's own sampling distribution: x_hat ~ N(x_true, cov) drawn
    jointly (base and effect parameters), each draw's base part refitted under the constraints
    and theta from eq. (2) (~17 s: 800 SDP solves)."""
    from dynid.analysis.diagnosis.physical_fit import profile_physical
    from dynid.analysis.estimators.physical import TIE_BREAK
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, scales
    robot, bp, x_true, cov = _clamped_case()
    b = bp.n_base
    _, _, cov3 = profile_physical(robot, bp, x_true, cov, b, n_boot=2000, seed=1)
    chi_ap = apriori_standard(robot)
    cov_bb = cov[:b, :b]
    R = whitening(cov_bb)
    pb = build_sdp(robot, bp, R, chi_ap, scales(robot, chi_ap), TIE_BREAK, getattr(robot, "mass_tolerance", None))
    K = np.linalg.solve(cov_bb, cov[:b, b:]).T
    draws = np.random.default_rng(7).multivariate_normal(x_true, cov, size=800)
    theta = np.array([d[b:] + K @ (bp.matrix @ pb.solve(R @ d[:b]) - d[:b]) for d in draws])
    mc = np.cov(theta, rowvar=False)
    ratio = np.diag(cov3) / np.diag(mc)
    assert np.all(np.abs(ratio - 1) < 0.25), ratio            # sampling error ~ 7 % (800 draws, 2000 refits)
    assert np.all(np.diag(mc) < 0.75 * np.diag(cov[b:, b:]))  # the constraint does shrink theta


def test_effects_pc_covariance_under_a_robust_covariance_keeps_the_cross_term():
    """Eq. (3) under a robust covariance S (the bootstrap's): u = theta_hat - K beta_hat and
    beta_hat correlate; without the refits (n_boot = 0, cov(beta_pc) = S_bb) the effects'
    covariance must be S_tt itself, which the sum without the cross term is not."""
    from dynid.analysis.diagnosis.physical_fit import profile_physical
    from dynid.analysis.estimators.standard_set import apriori_standard
    from dynid.dynamics.base_parameters import base_parameters
    robot = dynid.load_robot("tx40")
    bp = base_parameters(robot)
    beta = bp.matrix @ apriori_standard(robot)
    b, rng = len(beta), np.random.default_rng(0)
    A, B = rng.normal(size=(2, b + 2, b + 2))
    cov, S = A @ A.T * 1e-6 + 1e-6 * np.eye(b + 2), B @ B.T * 2e-6 + 1e-6 * np.eye(b + 2)
    x = np.concatenate([beta, [0.1, -0.2]])
    _, _, cov_t = profile_physical(robot, bp, x, cov, b, interval_cov=S, uncertainty="bootstrap", n_boot=0)
    np.testing.assert_allclose(cov_t, S[b:, b:], rtol=1e-9, atol=1e-15)
    _, _, cov_c = profile_physical(robot, bp, x, cov, b, n_boot=0)
    np.testing.assert_allclose(cov_c, cov[b:, b:], rtol=1e-9, atol=1e-15)
