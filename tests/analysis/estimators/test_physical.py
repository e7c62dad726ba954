"""PC-WLS (dynid.analysis.estimators.physical): closed forms, the real KUKA data, coverage."""
import sys

import bias_scenarios as bs
import numpy as np
import pytest
from scipy import stats

from dynid.analysis.estimators.physical import pc_wls, require_cvxpy
from dynid.analysis.estimators.standard_set import scales
from dynid.dynamics.urdf_writer import pseudo_inertia
from dynid.errors import InputError


@pytest.fixture(scope="module")
def pendulum():
    return bs.pendulum()


def _cov(beta):
    sig = np.abs(beta) * 0.01 + 1e-3
    return np.diag(sig ** 2), sig


def _pushed(pendulum, name, value):
    """The pendulum's base parameters with ``name`` set to ``value`` (off the physical set), the
    diagonal covariance of :func:`_cov`, and that parameter's index."""
    robot, bp, _, beta = pendulum
    cov, sig = _cov(beta)
    b = beta.copy()
    k = bp.names.index(name)
    b[k] = value
    return robot, bp, b, cov, sig, k


def test_a_physical_estimate_is_left_alone(pendulum):
    robot, bp, chi, beta = pendulum
    cov, sig = _cov(beta)
    r = pc_wls(robot, bp, beta, cov, n_boot=0)
    assert r.consistent
    assert np.all(np.abs(r.chi - beta) < 1e-3 * sig)
    assert r.chi2 < 1e-6 and r.p_value > 0.99
    assert "constraints cost nothing" in r.verdict_line()


def test_a_negative_inertia_costs_its_closed_form_chi2(pendulum):
    # ZZ1R = ZZ1 + Ia1 < 0 is no rigid body: with a diagonal covariance the nearest physical
    # point moves ZZ1R to (about) 0 and nothing else, at cost (ZZ1R / sigma)^2
    robot, bp, b, cov, sig, k = _pushed(pendulum, "ZZ1R", -0.05)
    r = pc_wls(robot, bp, b, cov, n_boot=0)
    assert r.consistent and r.wls_consistent is False
    assert 0 <= r.chi[k] < 0.01 * sig[k] * 10
    others = [i for i in range(bp.n_base) if i != k]
    assert np.all(np.abs(r.chi[others] - b[others]) < 0.01 * sig[others])
    assert r.chi2 == pytest.approx((0.05 / sig[k]) ** 2, rel=0.02)
    assert r.p_value < 1e-3 and any("link 1" in a for a in r.active)


def test_negative_friction_goes_to_its_bound(pendulum):
    robot, bp, b, cov, sig, k = _pushed(pendulum, "Fv1", -0.02)
    r = pc_wls(robot, bp, b, cov, n_boot=0)
    assert abs(r.chi[k]) < 1e-6 and "Fv1 = 0" in r.active
    assert r.chi2 == pytest.approx((0.02 / sig[k]) ** 2, rel=1e-3)


def test_mass_bounds_and_prior(pendulum):
    robot, bp, chi, beta = pendulum
    cov, _ = _cov(beta)
    r = pc_wls(robot, bp, beta, cov, n_boot=0, mass_tolerance=0.1)
    m = r.standard[r.standard_names.index("M1")]
    assert 1.8 - 1e-6 <= m <= 2.2 + 1e-6
    # the pull to the a-priori values trades fit for closeness to them, monotonically
    # (this a-priori set, a rod along z with XX = YY = 0, is itself not physical)
    s = scales(robot, chi)             # the metric the prior term uses
    fits = [pc_wls(robot, bp, beta, cov, n_boot=0, prior="apriori", prior_weight=w) for w in (1e-2, 1, 1e2)]
    assert [f.prior_weight for f in fits] == [1e-2, 1, 1e2]
    chi2 = [f.chi2 for f in fits]
    dist = [np.linalg.norm((f.standard - chi) / s) for f in fits]
    assert chi2[0] < chi2[1] < chi2[2] and dist[0] > dist[1] > dist[2]
    assert all(f.consistent for f in fits)
    with pytest.raises(InputError, match="prior must be one of"):
        pc_wls(robot, bp, beta, cov, prior="bogus")
    with pytest.raises(InputError, match="mass_tolerance"):
        pc_wls(robot, bp, beta, cov, mass_tolerance=-1)


def test_missing_cvxpy_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "cvxpy", None)
    # the packages themselves, from the installed metadata: dynid is on no package index
    with pytest.raises(InputError, match=r'pip install "cvxpy>=[0-9.]+" "clarabel>=[0-9.]+"'):
        require_cvxpy()


def test_bootstrap_intervals_stay_physical_at_an_active_bound(pendulum):
    robot, bp, b, cov, sig, k = _pushed(pendulum, "Fv1", -0.01)
    r = pc_wls(robot, bp, b, cov, n_boot=60, seed=1)
    ci = r.conf_int()
    assert ci["lower"].iloc[k] >= -1e-9            # a normal interval would cross into Fv < 0
    assert 0 < r.boot_std[k] < sig[k]              # the constraint cuts the refits' spread ...
    assert r.bse.iloc[k] >= sig[k] - 1e-12         # ... but not the reported sigma (interval_covariance)
    assert r.to_dict()["physical"]["consistent"] is True


@pytest.mark.slow
def test_bootstrap_coverage_on_simulated_data(pendulum):
    """95 % intervals cover the truth at 95 +- 5 %, also for a true Fv1 = 0 on its bound.

    WLS estimates are drawn from their sampling distribution under Gaussian errors,
    N(beta_true, cov) with the covariance of a real identification of the pendulum (fixed
    design: the exact distribution), and each is fitted by PC-WLS with its bootstrap.
    """
    import dynid
    from dynid.analysis.data.synthetic import simulate_experiment
    robot, bp, chi, _ = pendulum
    chi = chi.copy()
    chi[robot.standard_names.index("Fv1")] = 0.0       # truth on a constraint
    beta = bp.from_standard(chi)
    exp = simulate_experiment(robot, chi, bs.excitation(), 4.0, rng=np.random.default_rng(0),
                              tau_noise=0.2, q_noise=1e-5)
    cov = dynid.identify(exp, robot).wls.cov
    rng = np.random.default_rng(7)
    L = np.linalg.cholesky(cov)
    hits = []
    for seed in range(50):
        b = beta + L @ rng.standard_normal(bp.n_base)
        r = pc_wls(robot, bp, b, cov, n_boot=100, seed=seed)
        ci = r.conf_int()
        hits.append((ci["lower"].to_numpy() <= beta + 1e-12) & (beta - 1e-12 <= ci["upper"].to_numpy()))
    hits = np.array(hits)
    k = bp.names.index("Fv1")
    print(f"coverage of the 95 % intervals: all {100 * hits.mean():.1f} %, per parameter "
          + ", ".join(f"{n} {100 * h:.0f} %" for n, h in zip(bp.names, hits.mean(axis=0))))
    assert 0.90 <= hits.mean() <= 1.0
    assert hits[:, k].mean() >= 0.90


def test_intervals_keep_the_wls_half_width_and_are_one_sided_at_a_bound(pendulum):
    """conf_int: hull of the percentiles and chi +- 1.96 sigma_wls, cut at Fv >= 0 (module doc)."""
    robot, bp, b, cov, sig, k = _pushed(pendulum, "Fv1", -0.01)
    r = pc_wls(robot, bp, b, cov, n_boot=30, seed=2)
    z = stats.norm.ppf(0.975)
    ci = r.conf_int()
    lo, hi = ci["lower"].to_numpy(), ci["upper"].to_numpy()
    assert lo[k] == 0.0 and r.chi[k] >= 0                   # one-sided: the bound cuts it
    assert hi[k] >= r.chi[k] + z * sig[k] - 1e-12        # the bootstrap's smaller spread is not used
    free = [i for i in range(bp.n_base) if i != k and not bp.names[i].startswith(("Fv", "Fc", "Ia"))]
    assert np.all(lo[free] <= r.chi[free] - z * sig[free] + 1e-12)
    assert np.all(hi[free] >= r.chi[free] + z * sig[free] - 1e-12)
    q_lo, q_hi = np.quantile(r.boot, [0.025, 0.975], axis=0)
    assert np.all(lo <= q_lo + 1e-12) and np.all(hi >= q_hi - 1e-12)
    r0 = pc_wls(robot, bp, b, cov, n_boot=0)
    ci0 = r0.conf_int()
    assert ci0["lower"].iloc[k] == 0.0
    assert np.allclose(ci0["upper"].to_numpy(), r0.chi + z * sig)


def test_coverage_with_few_refits_and_a_truth_on_its_bound(pendulum):
    """Coverage of the 95 % intervals with 20 refits: percentiles alone hold a new draw only
    (n + 1 - 2k) / (n + 1) ~ 86 % of the time at n = 20; the intervals of conf_int keep the WLS
    half-width, so they cover at least as often as WLS does (exact covariance here: 95 %)."""
    robot, bp, chi, _ = pendulum
    chi = chi.copy()
    chi[robot.standard_names.index("Fv1")] = 0.0       # truth on a constraint
    beta = bp.from_standard(chi)
    cov, _ = _cov(beta)
    k = bp.names.index("Fv1")
    cov[k, k] = 0.02 ** 2                              # the bound is well within the noise
    L = np.linalg.cholesky(cov)
    rng = np.random.default_rng(11)
    hits, pct, sym, spread = [], [], [], []
    z = stats.norm.ppf(0.975)
    for seed in range(60):
        b = beta + L @ rng.standard_normal(bp.n_base)
        r = pc_wls(robot, bp, b, cov, n_boot=20, seed=seed)
        ci = r.conf_int()
        hits.append((ci["lower"].to_numpy() <= beta + 1e-12) & (beta - 1e-12 <= ci["upper"].to_numpy()))
        q_lo, q_hi = np.quantile(r.boot, [0.025, 0.975], axis=0)
        pct.append((q_lo <= beta + 1e-12) & (beta - 1e-12 <= q_hi))
        # what a reader of %sigma does: the estimate +- 1.96 sigma
        sym.append(np.abs(r.chi - beta) <= z * r.bse.to_numpy() + 1e-12)
        spread.append(np.abs(r.chi - beta) <= z * r.boot_std + 1e-12)
        assert ci["lower"].iloc[k] >= 0.0
    hits, pct, sym, spread = map(np.array, (hits, pct, sym, spread))
    print(f"coverage: conf_int {100 * hits.mean():.1f} %, percentiles alone {100 * pct.mean():.1f} %, "
          f"+-1.96 sigma {100 * sym.mean():.1f} % (Fv1 {100 * sym[:, k].mean():.0f} %), +-1.96 refits' "
          f"spread {100 * spread.mean():.1f} % (Fv1 {100 * spread[:, k].mean():.0f} %)")
    assert hits.mean() >= 0.92
    assert hits[:, k].mean() >= 0.9
    assert pct.mean() < 0.92          # the scenario is one where percentiles alone fall short
    assert np.all(sym >= hits)        # +-1.96 sigma contains conf_int
    assert sym[:, k].mean() >= 0.9


def test_pseudo_inertia_of_the_solution_by_pinocchio(pendulum):
    """Pinocchio's own pseudo-inertia of each link of the PC set is positive semidefinite."""
    pin = pytest.importorskip("pinocchio")
    robot, bp, chi, beta = pendulum
    cov, _ = _cov(beta)
    b = beta.copy()
    b[bp.names.index("ZZ1R")] = -0.05
    r = pc_wls(robot, bp, b, cov, n_boot=0)
    v = r.standard[:10]
    m, h = v[9], v[6:9]
    c = h / m
    I_o = np.array([[v[0], v[1], v[2]], [v[1], v[3], v[4]], [v[2], v[4], v[5]]])
    I_c = I_o - m * (c @ c * np.eye(3) - np.outer(c, c))
    J = pin.PseudoInertia.FromInertia(pin.Inertia(m, c, I_c)).toMatrix()
    assert np.allclose(J, pseudo_inertia(v), atol=1e-9 * max(1.0, np.abs(J).max()))
    assert np.linalg.eigvalsh(J)[0] >= -1e-9


@pytest.fixture(scope="module")
def kuka_23():
    from conftest import ROOT

    import dynid
    robot = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    res = dynid.identify([dynid.load_experiment(here / f"recording_{i}.toml", robot) for i in (2, 3)], robot)
    return robot, res


def test_real_kuka_the_data_want_a_non_physical_model(kuka_23):
    """Recordings 2 + 3 of the real LWR4+: WLS is no rigid body; PC-WLS is, at a clear cost."""
    from dynid.analysis.estimators.physical import identify_physical
    robot, res = kuka_23
    pc = identify_physical(res, robot, n_boot=0)
    assert pc.wls_consistent is False and pc.consistent
    assert all(lk["consistent"] for lk in pc.links) and len(pc.links) == 7
    assert pc.chi2 > 100 and pc.p_value < 1e-6 and pc.active
    assert "non-physical" in pc.verdict_line()
    # the PC model fits its identification data worse than WLS, but not by much
    assert pc.wls_rel_error < pc.rel_error < pc.wls_rel_error + 0.01
    block = pc.physical_block()
    assert block["consistent"] is True and block["chi2"] == pc.chi2 and block["active"] == pc.active


def test_real_kuka_sdp_is_below_the_log_cholesky_search(kuka_23):
    """The SDP is a global optimum: with the same constraints (J_l >= 0, Ia >= 0) its chi2 is at
    most that of the log-Cholesky local search (which stopped at 1431-1440 in 2000 evaluations)."""
    from dynid.analysis.estimators.sdp import build_sdp, whitening
    from dynid.analysis.estimators.standard_set import apriori_standard, choose_standard_set
    robot, res = kuka_23
    b, cov = res.wls.chi, res.wls.cov
    local = choose_standard_set(robot, res.base, b, cov, solver="log-cholesky", max_nfev=300)
    ap = apriori_standard(robot)
    R = whitening(cov)
    pb = build_sdp(robot, res.base, R, ap, scales(robot, ap), 1e-8, None, nonneg_kinds=("Ia",))
    chi = pb.solve(R @ b)
    chi2 = float(np.sum((R @ (res.base.matrix @ chi - b)) ** 2))
    assert chi2 < local.chi2
    assert all(lk["pseudo_inertia_min_eig"] > 0 for lk in local.links)


def test_pc_is_never_farther_from_a_physical_truth_in_the_wls_metric(pendulum):
    """Projection on a convex set holding the truth is non-expansive: ||R (beta_pc - beta)|| <=
    ||R (beta_wls - beta)|| for every draw of the WLS estimate (here the truth has Fv1 = 0, on
    a constraint, and a 30 % noise level so that WLS is often non-physical)."""
    from dynid.analysis.estimators.sdp import whitening
    robot, bp, chi, _ = pendulum
    chi = chi.copy()
    chi[robot.standard_names.index("Fv1")] = 0.0
    beta = bp.from_standard(chi)
    cov, _ = _cov(beta)
    cov = cov * 30 ** 2
    R = whitening(cov)
    L = np.linalg.cholesky(cov)
    rng = np.random.default_rng(3)
    non_physical = 0
    for _ in range(12):
        b = beta + L @ rng.standard_normal(bp.n_base)
        # weight 0: the pure projection (no tie-break pull toward the a-priori values)
        r = pc_wls(robot, bp, b, cov, n_boot=0, prior="apriori", prior_weight=0.0)
        non_physical += r.chi2 > 1e-6
        assert np.linalg.norm(R @ (r.chi - beta)) <= np.linalg.norm(R @ (b - beta)) * (1 + 1e-6)
    assert non_physical >= 3


def test_mass_tolerance_from_the_robot_file(tmp_path):
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    from dynid.errors import RobotFileError
    text = bs.PENDULUM_TOML.replace('[apriori]\n', '[apriori]\nmass_tolerance = 0.05\n')
    path = tmp_path / "p.toml"
    path.write_text(text)
    robot = load_robot(path)
    assert robot.mass_tolerance == 0.05
    bp = base_parameters(robot)
    beta = bp.from_standard(robot.standard_vector({k: v for k, v in robot.apriori.items()}))
    cov, _ = _cov(beta)
    # MX1 = 1 needs ZZ1 >= MX1^2 / M1: a small ZZ1R forces a large mass, which the bound refuses
    b = beta.copy()
    b[bp.names.index("ZZ1R")] = 0.3
    free = pc_wls(robot, bp, b, cov, n_boot=0, mass_tolerance=9.0)
    bound = pc_wls(robot, bp, b, cov, n_boot=0)
    m = bound.standard[bound.standard_names.index("M1")]
    assert 1.9 - 1e-6 <= m <= 2.1 + 1e-6 and bound.mass_tolerance == 0.05
    assert any("M1 at its bound" in a for a in bound.active)
    assert bound.chi2 > free.chi2
    path.write_text(bs.PENDULUM_TOML.replace('[apriori]\n', '[apriori]\nmass_tolerance = -1\n'))
    with pytest.raises(RobotFileError, match="mass_tolerance"):
        load_robot(path)


@pytest.mark.slow
def test_pc_didim_simulates_physical_estimates():
    """PC-DIDIM (each Gauss-Newton step a PC-WLS) on a simulated planar arm whose truth is
    physical: the last step's estimate is physical and, where DIDIM's own estimate is
    compatible with a physical model (small chi2), both agree within a standard deviation."""
    import dynid
    from dynid.analysis.estimators.didim import identify_didim
    robot = dynid.load_robot("planar2")
    rec = dynid.simulate(robot, 8.0, seed=3)
    plain = identify_didim(rec.experiment, robot, max_iter=4, essential=False)
    res = identify_didim(rec.experiment, robot, max_iter=4, physical=True, essential=False)
    pc = res.physical
    assert plain.physical is None and pc is not None and pc.consistent
    assert pc.chi2 < 10
    sig = plain.result.bse.to_numpy()
    assert np.all(np.abs(pc.chi - plain.result.chi) <= sig + 1e-9)


def test_a_failed_bootstrap_refit_is_left_out_and_reported(pendulum, monkeypatch):
    """One refit failing in the solver (it happened once in 2,500 PC-DIDIM refits) leaves the
    fit and the other refits standing, and says how many were left out."""
    from dynid.analysis.estimators.sdp import SDPProblem
    robot, bp, chi, beta = pendulum
    cov, _ = _cov(beta)
    solve, calls = SDPProblem.solve, []

    def flaky(self, t):
        calls.append(1)
        if len(calls) == 3:
            raise InputError("the physically consistent fit failed in the SDP solver: test")
        return solve(self, t)
    monkeypatch.setattr(SDPProblem, "solve", flaky)
    r = pc_wls(robot, bp, beta, cov, n_boot=25, seed=0)
    assert len(r.boot) == 24 and r.n_boot == 25
    assert any("1 of 25 bootstrap refits failed" in n for n in r.notices)


def test_pc_didim_options_reach_the_last_step():
    """identify_didim(physical=True, prior=..., prior_weight=..., n_boot=...): the last step's PC
    fit is pc_wls of that step's WLS with those options (recomputed here), its sigma holds the
    intervals, and the prior changes the standard set (so it was applied, not ignored)."""
    import dynid
    from dynid.analysis.estimators.didim import identify_didim
    robot = dynid.load_robot("planar2")
    rec = dynid.simulate(robot, 4.0, seed=5)
    res = identify_didim(rec.experiment, robot, max_iter=2, physical=True, essential=False,
                         settings={"v_s": 0.01}, prior="apriori", prior_weight=10.0, n_boot=30)
    pc = res.physical
    assert pc.prior == "apriori" and pc.prior_weight == 10.0 and pc.n_boot == 30 and len(pc.boot) == 30
    again = pc_wls(robot, res.base, res.result.chi, res.result.cov, prior="apriori", prior_weight=10.0,
                   n_boot=30)
    assert np.allclose(again.standard, pc.standard, rtol=1e-6, atol=1e-9)
    tie = pc_wls(robot, res.base, res.result.chi, res.result.cov, n_boot=0)
    assert np.max(np.abs(tie.standard - pc.standard)) > 1e-4
    ci = pc.conf_int()
    z = stats.norm.ppf(0.975)
    assert np.all(pc.chi - z * pc.bse.to_numpy() <= ci["lower"].to_numpy() + 1e-12)
    assert np.all(ci["upper"].to_numpy() <= pc.chi + z * pc.bse.to_numpy() + 1e-12)


def test_pc_fit_of_the_essential_set(kuka_23):
    """which="essential": the essential WLS constrained; its parameters are the essential ones,
    equal to P_e chi of a standard set whose pseudo-inertias are PSD (eigenvalues computed
    here from the 4x4 matrices), and the held-out prediction uses the essential columns."""
    from conftest import ROOT

    import dynid
    from dynid.analysis.estimators.physical import identify_physical
    robot, res = kuka_23
    pe = identify_physical(res, robot, n_boot=0, which="essential")
    ess = res.essential.result
    assert pe.names == list(ess.names) and pe.model == "essential" and len(pe.names) < res.base.n_base
    rows = [res.base.names.index(n) for n in pe.names]
    np.testing.assert_allclose(pe.chi, res.base.matrix[rows] @ pe.standard, atol=1e-12)
    names = robot.standard_names
    for j in range(1, robot.n_joints + 1):
        g = {k: pe.standard[names.index(f"{k}{j}")] for k in ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")}
        inertia = np.array([[g["XX"], g["XY"], g["XZ"]], [g["XY"], g["YY"], g["YZ"]], [g["XZ"], g["YZ"], g["ZZ"]]])
        J = np.block([[0.5 * np.trace(inertia) * np.eye(3) - inertia, np.array([[g["MX"], g["MY"], g["MZ"]]]).T],
                      [np.array([[g["MX"], g["MY"], g["MZ"]]]), np.array([[g["M"]]])]])
        assert np.linalg.eigvalsh(J)[0] >= -1e-9
        # the robot file's +-50 % mass bounds
        ap = robot.apriori[f"M{j}"]
        assert 0.5 * ap - 1e-9 <= g["M"] <= 1.5 * ap + 1e-9
    assert pe.consistent and pe.chi2 > 100 and pe.physical_block()["model"] == "essential"
    # same data, same constraints: the essential PC fit is no better on its own data than WLS
    assert ess.rel_error < pe.rel_error < ess.rel_error + 0.01
    held = dynid.load_experiment(ROOT / "examples" / "kuka_lwr4" / "recording_1.toml", robot)
    v = dynid.validate(pe, held, robot)
    assert np.isfinite(v.rel_error) and v.rel_error < 0.03


@pytest.mark.slow
def test_pc_didim_steps_lower_the_output_error():
    """Panda seed 16 of benchmarks/physical_seeds.py: without a descent test PC-DIDIM's
    projected steps drove the output error from 13.9 to 431 N m (distance to the truth 779 in
    the WLS metric). With it every accepted full or halved step lowers the output error, and
    PC-DIDIM stays within a few times the distance of its start (WLS, 10.6): 55-60.

    Not compared with plain DIDIM: without a descent test its output error grows here (10.8 to
    21-83 N m) and where it stops is chaotic: 48.8 or 184 for a 0.1 % change of sigma_1."""
    from physical_truth import truth

    import dynid
    from dynid.analysis.data.synthetic import simulate_experiment
    from dynid.analysis.estimators.didim import identify_didim
    from dynid.analysis.estimators.sdp import whitening
    from dynid.dynamics.trajectories import random_fourier_trajectory
    robot = dynid.load_robot("panda")
    chi = truth(robot, np.random.default_rng(15))
    r = np.random.default_rng(1016)
    exp = simulate_experiment(robot, chi, random_fourier_trajectory(robot, 0.1, 6, r), 6.0, rng=r,
                              tau_noise=0.5, q_noise=1e-5)
    res = dynid.identify(exp, robot)
    start = dict(zip(res.base.names, res.wls.chi))
    kw = dict(chi0=start, max_iter=4, essential=False, update_gains=False)
    pc = identify_didim(exp, robot, physical=True, **kw)
    h = pc.history
    oe = h["output_error"].to_numpy()
    full_or_tested = h["step_length"].to_numpy()[1:] > 0.5 ** 6          # DEFAULT_HALVINGS
    assert np.all(oe[1:][full_or_tested] <= oe[:-1][full_or_tested] + 1e-9)
    beta = res.base.from_standard(chi)
    R = whitening(res.wls.cov)
    assert np.linalg.norm(R @ (pc.physical.chi - beta)) <= 10 * np.linalg.norm(R @ (res.wls.chi - beta))
    assert pc.physical.consistent


def test_pc_didim_with_the_automatic_v_s_continues_from_physical_estimates(monkeypatch):
    """PC-DIDIM with v_s = "auto": every warm start of the v_s search and of its final run is the
    physical estimate of a previous run (its unconstrained WLS may have M(q) indefinite: on
    simulated Panda seeds 15 and 123 the final run could not simulate it)."""
    import dynid
    from dynid.analysis.estimators import didim
    robot = dynid.load_robot("planar2")
    rec = dynid.simulate(robot, 4.0, seed=5)
    # the search's iterations (first run, one step per candidate width, the final run continuing
    # a candidate's step) are calls of didim._gauss_newton: their starts and last estimates
    real, starts, lasts = didim._gauss_newton, [], []

    def spy(L, beta0, *args, **kw):
        starts.append(beta0 if kw.get("resume") is None else kw["resume"]["beta_ls"])
        out = real(L, beta0, *args, **kw)
        lasts.append(out[2])
        return out
    monkeypatch.setattr(didim, "_gauss_newton", spy)
    out = didim.identify_didim(rec.experiment, robot, max_iter=10, physical=True, essential=False, n_boot=0)
    assert "v_s_scan" in out.settings             # the search ran (the first run converged)
    assert len(starts) >= 3                        # the first run, candidates, the final run
    physical = [np.asarray(last["physical"].chi) for last in lasts]
    for chi0 in starts[1:]:
        assert any(np.array_equal(np.asarray(chi0), p) for p in physical)


def test_interval_covariance_moves_sigma_and_intervals_not_the_estimate(pendulum):
    # the metric stays cov_wls; the bootstrap draws from (and the intervals keep the half-width
    # of) interval_cov: four times the variance, twice the half-width, the same PC estimate
    robot, bp, b, cov, sig, k = _pushed(pendulum, "Fv1", -0.01)
    ref = pc_wls(robot, bp, b, cov, n_boot=24, seed=2)
    wide = pc_wls(robot, bp, b, cov, n_boot=24, seed=2, interval_cov=4 * cov, uncertainty="hac")
    np.testing.assert_array_equal(wide.chi, ref.chi)
    assert wide.chi2 == ref.chi2
    assert np.all(wide.bse.to_numpy() >= 2 * sig - 1e-12)
    ci = wide.conf_int().to_numpy()
    s = wide.bse.to_numpy()
    assert np.all(ci[:, 0] >= wide.chi - 1.96 * s - 1e-12) and np.all(ci[:, 1] <= wide.chi + 1.96 * s + 1e-12)
    others = [i for i in range(bp.n_base) if i != k]
    # never narrower than twice the classic WLS interval where no bound cuts it (percentiles may widen it)
    assert np.all((ci[others, 1] - ci[others, 0]) / (2 * 1.96 * sig[others]) >= 1.9999)
    assert np.all((ref.conf_int().to_numpy()[others, 1] - ref.conf_int().to_numpy()[others, 0])
                  / (2 * 1.96 * sig[others]) < 2.0)
    assert wide.physical_block()["uncertainty"] == "hac" and any("hac covariance" in n for n in wide.notices)
    with pytest.raises(InputError, match="covariances of shape"):
        pc_wls(robot, bp, b, cov, n_boot=0, interval_cov=cov[:2, :2])


def test_identify_physical_draws_from_the_robust_covariance(kuka_23):
    # same IDIM result, same PC estimate; the hac option's interval covariance is the WLS sandwich's
    # (with the recordings as groups)
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.physical import identify_physical
    robot, res = kuka_23
    classic = identify_physical(res, robot, n_boot=0, uncertainty="classic")
    boot = identify_physical(res, robot, n_boot=0, uncertainty="hac")
    np.testing.assert_array_equal(boot.chi, classic.chi)
    obs = res.observation
    direct = ls.wls(obs.W, obs.tau, list(res.base.names), row_mask=obs.row_mask, uncertainty="hac",
                    groups=res.groups)
    np.testing.assert_allclose(boot.wls_cov, direct.cov, rtol=1e-10)
    assert boot.uncertainty == "hac" and classic.uncertainty == "classic"
    with pytest.raises(InputError, match="uncertainty must be one of"):
        identify_physical(res, robot, n_boot=0, uncertainty="robust")


def test_few_refits_conf_int_and_bse_agree_at_every_level():
    """With 2-19 refits `bse` is the larger of the WLS σ and the refits' spread; conf_int uses the
    same σ, at every alpha (it used the WLS σ alone)."""
    pytest.importorskip("cvxpy")
    import dynid
    robot = dynid.load_robot("planar2")
    r = dynid.identify(dynid.simulate(robot, 6.0, seed=1).experiment, robot, physical=True, bootstrap=5)
    assert r.boot is not None and len(r.boot) == 5
    from scipy.stats import norm
    for alpha in (0.05, 0.32):
        ci = r.conf_int(alpha)
        upper = (ci["upper"] - r.chi) / r.bse
        assert np.allclose(upper, norm.ppf(1 - alpha / 2), rtol=1e-9)
