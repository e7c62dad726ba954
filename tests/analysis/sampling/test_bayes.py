"""Tests of the Bayesian posterior (dynid.analysis.sampling.posterior; the gravity model: tests/support/gravity_posterior.py), its convergence rule (dynid.analysis.sampling.convergence)
and its report sections (dynid.reports.bayes_section).

Every statistical test compares emcee's draws with a closed form or with the truth of
simulated data, with tolerances set from the Monte-Carlo error (ESS from τ), so a wrong
likelihood, Jacobian, prior or sampler bookkeeping makes them fail. All runs are seeded.
"""
import json
import math

import numpy as np
import pytest
from scipy import stats

from dynid.analysis.estimators import least_squares as lsq
from dynid.analysis.sampling import posterior as bayes
from dynid.analysis.sampling.convergence import ConvergenceCriteria, diagnose, integrated_time, split_rhat
from dynid.provenance import dumps_json
from tests.support import gravity_posterior as gravity


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def tx40_essential():
    """W, tau, row_mask of the essential set of the simulated TX40 (demo_data(1, 20 s)) and its WLS."""
    from dynid.analysis.demo import demo_data
    from dynid.analysis.estimators.idim import identify_idim

    robot, bp, beta, ident, valid = demo_data(1, 20.0)
    res = identify_idim(ident, robot, bp=bp)
    ls = res.essential.result
    W = res.observation.W[:, :, res.columns(ls.names)]
    return W, res.observation.tau, res.observation.row_mask, ls


@pytest.fixture(scope="module")
def tx40_known_noise(tx40_essential):
    W, tau, mask, ls = tx40_essential
    res = bayes.sample_linear(W, tau, ls.names, row_mask=mask, ls=ls, sigma=ls.joint_sigma, seed=11,
                              noise="white")
    stats_ = bayes.sufficient_statistics(W, tau, ls.names, row_mask=mask, ref=ls.chi)
    mean, cov = bayes.known_noise_posterior(stats_, ls.joint_sigma)
    return res, mean, cov


def _one_joint(r, seed=5, chi=(0.8, 0.5), sigma=0.2):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, r)
    qd = np.sin(2 * np.pi * t) * 2 + 0.3
    W = np.stack([qd, np.sign(qd)], 1)[:, None, :]
    y = W[:, 0, :] @ np.asarray(chi) + sigma * rng.standard_normal(r)
    return W, y[:, None], ["Fv", "Fc"]


# ----------------------------------------------------------------------------- convergence
def test_integrated_time_equals_emcee():
    import emcee

    rng = np.random.default_rng(0)
    x = np.zeros((1500, 12, 3))
    for t in range(1, 1500):
        x[t] = 0.9 * x[t - 1] + rng.standard_normal((12, 3)) * [1, 2, 3]
    x[:, :, 2] += np.cumsum(rng.standard_normal((1500, 12)), 0) * 0.02
    for T in (1500, 333):
        ours = integrated_time(x[:T])
        ref = emcee.autocorr.integrated_time(x[:T], tol=0)
        np.testing.assert_allclose(ours, ref, rtol=1e-9)
    const = np.ones((50, 4, 1))
    assert np.isnan(integrated_time(const)[0])


def test_split_rhat_formula_and_behaviour():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((7, 3, 1))
    # hand computation of the documented formula: halves of n = 3 draws, middle draw dropped
    halves = [x[:3, w, 0] for w in range(3)] + [x[4:, w, 0] for w in range(3)]
    n, m = 3, 6
    means = np.array([h.mean() for h in halves])
    B = n / (m - 1) * ((means - means.mean()) ** 2).sum()
    Wv = np.mean([h.var(ddof=1) for h in halves])
    expected = math.sqrt(((n - 1) / n * Wv + B / n) / Wv)
    assert split_rhat(x)[0] == pytest.approx(expected, rel=1e-12)
    iid = rng.standard_normal((4000, 16, 2))
    assert np.all(split_rhat(iid) < 1.005)
    shifted = iid.copy()
    shifted[:, :8, 0] += 1.0                    # half the walkers elsewhere
    trend = iid.copy()
    trend[:, :, 1] += np.linspace(0, 2, 4000)[:, None]   # not stationary: halves differ
    r = split_rhat(np.concatenate([shifted[:, :, :1], trend[:, :, 1:]], axis=2))
    assert np.all(r > 1.1)


def test_sufficient_statistics_log_prob_equals_direct_sum():
    rng = np.random.default_rng(2)
    N, n, b = 300, 3, 4
    W3 = rng.standard_normal((N, n, b))
    tau = W3 @ rng.standard_normal(b) + 0.1 * rng.standard_normal((N, n))
    mask = rng.random((N, n)) > 0.2
    W3[~mask] = np.nan                          # excluded rows may hold anything
    tau[~mask] = np.nan
    names = ["a", "b", "c", "d"]
    ref = rng.standard_normal(b)
    st = bayes.sufficient_statistics(W3, tau, names, row_mask=mask, ref=ref, chunk=37)
    model = bayes.LinearPosterior(st)
    X = np.hstack([rng.standard_normal((5, b)), np.log(rng.uniform(0.05, 0.3, (5, n)))])
    direct = np.zeros(5)
    for k in range(5):
        for j in range(n):
            e = tau[mask[:, j], j] - W3[mask[:, j], j] @ X[k, :b]
            u = X[k, b + j]
            direct[k] += -mask[:, j].sum() * u - 0.5 * (e @ e) * math.exp(-2 * u)
    np.testing.assert_allclose(model.log_prob(X), direct, rtol=1e-10)
    assert model.names[-3:] == ["sigma1", "sigma2", "sigma3"]


# ----------------------------------------------------------------------------- known noise
def test_known_noise_tx40_matches_closed_form(tx40_known_noise):
    """Linear-Gaussian, known σ_j, flat prior, TX40 essential set (25 parameters).

    Mean: |mean_MC − m| < 4 MC standard errors, MC s.e. = sd / √ESS, ESS from τ.
    Covariance within 10 %: every variance within ±10 %, and every covariance
    element within 0.1 √(C_ii C_jj) (i.e. posterior correlations within ±0.1).
    """
    res, mean, cov = tx40_known_noise
    assert res.converged, res.reason
    assert len(res.names) == 25
    z = (res.mean - mean) / res.mc_stderr()
    assert np.all(np.abs(z) < 4), z
    sd = np.sqrt(np.diag(cov))
    C = np.cov(res.samples.T)
    assert np.all(np.abs(np.diag(C) / np.diag(cov) - 1) < 0.10)
    assert np.all(np.abs(C - cov) / np.outer(sd, sd) < 0.10)


def test_gaussian_prior_closed_form_and_emcee():
    W, y, names = _one_joint(12, seed=8)
    st = bayes.sufficient_statistics(W, y, names)
    prior = bayes.GaussianPrior(["Fc"], [0.4], [[0.05**2]])
    sigma = np.array([0.2])
    mean, cov = bayes.known_noise_posterior(st, sigma, prior)
    # the prior is one pseudo-observation: (Fc − 0.4)/0.05 ~ N(0, 1)
    A = np.vstack([W[:, 0, :] / 0.2, [0.0, 1 / 0.05]])
    c = np.concatenate([y[:, 0] / 0.2, [0.4 / 0.05]])
    np.testing.assert_allclose(mean, np.linalg.lstsq(A, c, rcond=None)[0], rtol=1e-10)
    np.testing.assert_allclose(cov, np.linalg.inv(A.T @ A), rtol=1e-10)
    res = bayes.sample_linear(W, y, names, sigma=sigma, prior=prior, seed=4, noise="white")
    assert res.converged, res.reason
    assert np.all(np.abs((res.mean - mean) / res.mc_stderr()) < 4)
    assert np.all(np.abs(res.std**2 / np.diag(cov) - 1) < 0.10)


# ----------------------------------------------------------------------------- Student t
def test_unknown_noise_single_joint_student_t_marginals():
    """One joint, b = 2, r = 10 (ν = 8), unknown σ, flat prior, Jeffreys on σ.

    emcee's marginals of Fv, Fc match t_ν(χ̂, s√[(WᵀW)⁻¹]_ii) and σ matches
    σ² ~ RSS/χ²_ν (KS p > 0.001, on draws ≥ 3 τ apart). Negative control: σ² is
    NOT distributed as RSS/χ²_{ν±1} (what a missing log-σ Jacobian would give).
    Three KS tests at 0.01 fail together about 3 % of the time under the null, so a
    new NumPy or emcee (another random stream for the same seed) could fail them
    (numpy 2.4 gave p = 0.006 for Fv); at 0.001 that is 0.3 %, and the negative
    control (p < 1e-3 for a one-degree-of-freedom error) shows the power kept.
    The run uses a stricter rule (≥ 200 τ instead of 50 τ): KS assumes independent
    draws, and at 50-100 τ the residual autocorrelation (τ itself is under-estimated
    on short chains) makes its p-values too small about 5 % of the time; at 200 τ
    they are uniform (checked over 30 seeds).
    """
    W, y, names = _one_joint(10)
    st = bayes.sufficient_statistics(W, y, names)
    an = bayes.student_t_posterior(st)
    assert an.df == 8
    ols = lsq.ols(W, y, names)
    np.testing.assert_allclose(an.loc, ols.chi, rtol=1e-10)
    np.testing.assert_allclose(an.scale, ols.bse.to_numpy(), rtol=1e-8)   # s √[(WᵀW)⁻¹]_ii = eq. (14)
    res = bayes.sample_linear(W, y, names, seed=0, criteria={"tau_multiple": 200}, noise="white")
    assert res.converged, res.reason
    k = int(np.ceil(3 * res.diagnostics.tau_max / res.diagnostics.thin))
    S = res.chain[:, ::k].reshape(-1, 3)
    assert S.shape[0] > 1500
    for i in range(2):
        assert stats.kstest(S[:, i], an.marginal(i).cdf).pvalue > 1e-3, names[i]
    assert stats.kstest(S[:, 2], an.sigma().cdf).pvalue > 1e-3
    for df in (an.df - 1, an.df + 1):
        wrong = stats.invgamma(a=df / 2, scale=an.rss / 2)
        assert stats.kstest(S[:, 2] ** 2, wrong.cdf).pvalue < 1e-3


# ----------------------------------------------------------------------------- calibration
@pytest.mark.slow
def test_calibration_of_credible_intervals():
    """120 simulated datasets of a small one-joint friction model (b = 2 plus σ).

    Model: τ = Fv q̇ + Fc sign(q̇) + ρ, ρ ~ N(0, σ²), r = 40 rows, σ unknown;
    truth drawn per dataset (Fv, Fc ±30 % around (0.8, 0.5), σ log-normal around 0.2).
    With a flat prior on χ and Jeffreys on σ the equal-tailed credible intervals are
    exact confidence intervals (t pivot for χ_i, χ²_ν pivot for σ), so emcee's 95 %
    intervals must contain the truth 95 % of the time. Pooled over the 3 parameters
    (360 intervals): 95 % ± 3 %; per parameter: ± 6 %; pooled 50 % intervals: 50 % ± 7 %.
    Every run must satisfy the convergence rule (≥ 50 τ, R̂ < 1.05).
    """
    r = 40
    t = np.linspace(0, 1, r, endpoint=False)
    qd = 2 * np.sin(2 * np.pi * t) + 0.4 * np.sin(6 * np.pi * t + 1)
    W = np.stack([qd, np.sign(qd)], 1)[:, None, :]
    names = ["Fv", "Fc"]
    rng = np.random.default_rng(2024)
    hits95, hits50 = [], []
    for _ in range(120):
        chi = np.array([0.8, 0.5]) * (1 + 0.3 * rng.standard_normal(2))
        sig = 0.2 * math.exp(0.5 * rng.standard_normal())
        y = W[:, 0, :] @ chi + sig * rng.standard_normal(r)
        res = bayes.sample_linear(W, y[:, None], names, seed=int(rng.integers(2**31)), n_walkers=16,
                                  criteria={"first_batch": 300})
        assert res.converged, res.reason
        truth = np.r_[chi, sig]
        hits95.append((res.ci95[:, 0] <= truth) & (truth <= res.ci95[:, 1]))
        i50 = res.conf_int(alpha=0.5).to_numpy()
        hits50.append((i50[:, 0] <= truth) & (truth <= i50[:, 1]))
    h95, h50 = np.array(hits95), np.array(hits50)
    assert abs(h95.mean() - 0.95) <= 0.03, h95.mean(0)
    assert np.all(np.abs(h95.mean(0) - 0.95) <= 0.06), h95.mean(0)
    assert abs(h50.mean() - 0.50) <= 0.07, h50.mean(0)


# ----------------------------------------------------------------------------- nonlinear gravity
@pytest.fixture(scope="module")
def gravity_runs():
    out = {}
    for label, amp in (("good", 1.5), ("poor", 0.15)):
        q, qd, tau, truth = gravity.simulate_gravity_joint(400, q_amplitude=amp, sigma=0.3, seed=3)
        ls = gravity.fit_gravity_ls(q, qd, tau)
        res = gravity.sample_gravity(q, qd, tau, ls=ls, seed=1, truth=truth)
        out[label] = (q, qd, tau, truth, ls, res)
    return out


def _width_ratio_and_asymmetry(ls, res):
    ci, dl = res.ci95[:2], ls.interval(0.95)[:2]
    ratio = (ci[:, 1] - ci[:, 0]) / (dl[:, 1] - dl[:, 0])
    asym = (ci[:, 1] - ls.value[:2]) / (ls.value[:2] - ci[:, 0])
    return ratio, asym, stats.skew(res.samples[:, :2])


def test_gravity_posterior_vs_delta_method(gravity_runs):
    """Good excitation (q over ±1.7 rad): posterior ≈ delta method (width ratio within
    ±10 %, symmetric, |skew| < 0.2). Poor excitation (q over ±0.17 rad): the posterior of
    k is visibly skewed (skew > 0.7) and its 95 % interval is asymmetric about the NLS
    value (upper/lower arm ratio > 2), which the symmetric delta interval cannot be.
    Both contain the truth of (k, q_off) at 95 %."""
    for label in ("good", "poor"):
        *_, truth, ls, res = gravity_runs[label]
        assert res.converged, res.reason
        for i, name in enumerate(("k", "q_off")):
            assert res.ci95[i, 0] <= truth[name] <= res.ci95[i, 1], (label, name)
    ratio, asym, skew = _width_ratio_and_asymmetry(*gravity_runs["good"][4:])
    assert np.all(np.abs(ratio - 1) < 0.10), ratio
    assert np.all(np.abs(asym - 1) < 0.25), asym
    assert np.all(np.abs(skew) < 0.2), skew
    ratio_p, asym_p, skew_p = _width_ratio_and_asymmetry(*gravity_runs["poor"][4:])
    assert skew_p[0] > 0.7, skew_p
    assert asym_p[0] > 2.0, asym_p


def test_gravity_marginalised_equals_joint_sampling(gravity_runs):
    """Analytic marginalisation of friction and σ gives the same posterior as sampling them."""
    q, qd, tau, truth, ls, marg = gravity_runs["good"]
    joint = gravity.sample_gravity(q, qd, tau, ls=ls, seed=2, marginalize=False)
    assert joint.converged, joint.reason
    assert joint.names == marg.names
    se = np.sqrt(marg.mc_stderr() ** 2 + joint.mc_stderr() ** 2)
    assert np.all(np.abs(marg.mean - joint.mean) / se < 4.5)
    assert np.all(np.abs(marg.std / joint.std - 1) < 0.12)
    assert not marg.diagnostics.sampled[2:].any() and marg.diagnostics.sampled[:2].all()
    assert np.all(np.isfinite(marg.tau))                 # derived parameters get τ too


def test_fit_gravity_ls_normalises_sign_and_matches_linear_fit():
    q, qd, tau, truth = gravity.simulate_gravity_joint(300, k=-5.0, q_off=0.3, seed=4)
    ls = gravity.fit_gravity_ls(q, qd, tau)
    assert ls.value[0] > 0 and -math.pi < ls.value[1] <= math.pi
    assert ls.value[0] == pytest.approx(5.0, rel=0.05)
    assert math.remainder(ls.value[1] - (0.3 + math.pi), 2 * math.pi) == pytest.approx(0, abs=0.05)
    # the NLS optimum is the polar form of the linear LS in (a, c) = (k cos q_off, k sin q_off)
    Phi = np.stack([np.sin(q), np.cos(q), qd, np.sign(qd), np.ones_like(q)], 1)
    lin = np.linalg.lstsq(Phi, tau, rcond=None)[0]
    assert ls.value[0] == pytest.approx(math.hypot(lin[0], lin[1]), rel=1e-9)
    np.testing.assert_allclose(ls.value[2:], lin[2:], rtol=1e-8, atol=1e-12)
    e = ls.ellipse(level=0.95)
    d = e - ls.value[:2]
    m = np.einsum("ki,ij,kj->k", d, np.linalg.inv(ls.cov[:2, :2]), d)
    np.testing.assert_allclose(m, stats.chi2.ppf(0.95, 2), rtol=1e-8)


# ----------------------------------------------------------------------------- the flag
def test_tiny_step_limit_is_reported_not_converged():
    W, y, names = _one_joint(30)
    res = bayes.sample_linear(W, y, names, seed=0, max_steps=60)
    assert not res.converged
    assert res.n_steps == 60
    assert "step limit" in res.reason and "NOT CONVERGED" in res.reason
    d = res.to_dict()
    assert d["converged"] is False and d["diagnostics"]["converged"] is False
    assert "step limit" in d["reason"]
    assert "NOT CONVERGED" in res.summary()
    assert res.notices and "NOT CONVERGED" in res.notices[0]

    from dynid.reports.bayes_section import bayes_sections
    from dynid.reports.html import render_sections

    secs = bayes_sections(res, prefix="post")
    assert all("NOT CONVERGED" in s.title for s in secs)
    html = render_sections(secs, title="posterior")
    assert "NOT CONVERGED" in html and "step limit" in html
    import html as html_module
    assert res._optimum_lines()
    for line in res._optimum_lines():     # where the sampled sigma_j settle, beside eq. (16)'s LS value
        assert line.strip().split(":")[0] in html_module.unescape(html) and "The LS value of" in html


def test_diagnose_rejects_short_and_accepts_long_iid_chain():
    rng = np.random.default_rng(3)
    crit = ConvergenceCriteria()
    x = rng.standard_normal((4000, 16, 2))
    ok = diagnose(x, 1, 4000, np.full(16, 4000 * 0.3), crit)
    assert ok.converged, ok.reason
    short = diagnose(x[:40], 1, 40, np.full(16, 12.0), crit)
    assert not short.converged
    stuck = diagnose(x, 1, 4000, np.r_[np.zeros(1), np.full(15, 1200.0)], crit)
    assert not stuck.converged and "stuck" in stuck.reason


# ----------------------------------------------------------------------------- outputs
def test_same_seed_same_bytes(tmp_path):
    W, y, names = _one_joint(30)
    a = bayes.sample_linear(W, y, names, seed=7)
    b = bayes.sample_linear(W, y, names, seed=7)
    c = bayes.sample_linear(W, y, names, seed=8)
    assert dumps_json(a.to_dict()) == dumps_json(b.to_dict())
    assert dumps_json(a.to_dict()) != dumps_json(c.to_dict())
    a.to_csv(tmp_path / "a.csv")
    b.to_csv(tmp_path / "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    json.loads(dumps_json(a.to_dict()))
    df = a.to_frame()
    assert list(df.index) == ["Fv", "Fc", "sigma1"]
    for col in ("mean", "median", "std", "ci95_low", "ci999_high", "ls_value", "ls_rel_std_percent",
                "tau", "rhat", "ess"):
        assert col in df.columns
    assert a.corr.shape == (3, 3) and np.allclose(np.diag(a.corr), 1)
    assert np.all(a.ci999[:, 0] < a.ci95[:, 0]) and np.all(a.ci95[:, 1] < a.ci999[:, 1])


def test_optional_exports_are_clear_about_missing_packages(tmp_path):
    W, y, names = _one_joint(30)
    res = bayes.sample_linear(W, y, names, seed=1)
    try:
        import xarray  # noqa: F401
    except ImportError:
        with pytest.raises(bayes.MissingDependencyError, match="xarray"):
            res.to_netcdf(tmp_path / "p.nc")
    else:
        res.to_netcdf(tmp_path / "p.nc")
        assert (tmp_path / "p.nc").stat().st_size > 0
    try:
        import arviz  # noqa: F401
    except ImportError:
        with pytest.raises(bayes.MissingDependencyError, match="arviz"):
            res.to_inference_data()
    else:
        idata = res.to_inference_data()
        assert idata.posterior["Fv"].shape == res.chain.shape[:2]


def test_report_sections_for_linear_and_gravity(tx40_known_noise, gravity_runs):
    from dynid.reports.bayes_section import corner_selection
    from dynid.reports.html import render_sections
    from tests.support.gravity_posterior import bayes_sections  # the library's sections + the gravity one

    res = tx40_known_noise[0]
    idx, note = corner_selection(res)
    assert len(idx) == 8 and "8 of 25" in note
    g = gravity_runs["poor"][-1]
    secs = bayes_sections(res, prefix="posterior") + bayes_sections(g, prefix="gravity")
    ids = [s.id for s in secs]
    assert ids == ["posterior", "posterior-convergence", "gravity", "gravity-convergence", "gravity-gravity"]
    html = render_sections(secs, title="posterior")
    assert "8 of 25 parameters shown" in html
    assert "delta method" in html and "CONVERGED" in html


def test_rank_normalized_rhat_sees_chains_that_differ_in_scale_only():
    # Vehtari et al. (2021): chains with one mean but different scales fool the classic
    # split R-hat (close to 1) and not the rank-normalised, folded one
    from dynid.analysis.sampling.convergence import rank_normalized_rhat, split_rhat
    rng = np.random.default_rng(3)
    same = rng.normal(size=(2000, 8, 1))
    scaled = same * np.array([1, 1, 1, 1, 3, 3, 3, 3])[None, :, None]
    assert split_rhat(same)[0] < 1.01 and rank_normalized_rhat(same)[0] < 1.01
    assert split_rhat(scaled)[0] < 1.02
    assert rank_normalized_rhat(scaled)[0] > 1.1
    # for well-mixed Gaussian chains the two agree
    assert abs(rank_normalized_rhat(same)[0] - split_rhat(same)[0]) < 0.01
    # heavy tails (Cauchy) leave the rank version finite and near 1
    cauchy = rng.standard_cauchy(size=(2000, 8, 1))
    assert rank_normalized_rhat(cauchy)[0] < 1.02
