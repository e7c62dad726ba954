"""The posterior's noise model (dynid.analysis.sampling.noise) on a problem with known truth.

A linear model with smooth regressors (as decimated robot data are) and AR(1) noise of
coefficient 0.8: the white likelihood counts every row as independent and its 95 % intervals
cover far less than 95 %; the likelihood tempered by the residual's effective sample size
covers. The coverage is that of the posterior's Gaussian closed form on the statistics the
sampler uses (the sampler's draws are checked against it below and, for the white model,
against the closed forms of test_bayes.py), so a wrong n_eff, a wrong tempering or a
tempering that is not applied makes these tests fail.
"""
import numpy as np
import pytest

from dynid.analysis.estimators import least_squares as lsq
from dynid.analysis.sampling import posterior as bayes
from dynid.analysis.sampling.noise import check_noise, noise_model, sandwich_model, temper
from dynid.errors import InputError

R, PHI, SIGMA = 400, 0.8, 0.3
CHI = np.array([1.5, -0.7, 0.4])
NAMES = ["Fv1", "Fc1", "Off1"]


def _regressor():
    t = np.linspace(0.0, 8.0, R)
    qd = np.sin(2 * np.pi * 0.4 * t) + 0.5 * np.sin(2 * np.pi * 0.15 * t + 1.0)
    return np.stack([qd, np.tanh(qd / 0.1), np.ones(R)], 1)[:, None, :]


def _ar1(rng):
    e = rng.standard_normal(R) * SIGMA * np.sqrt(1 - PHI**2)
    x = np.empty(R)
    x[0] = rng.standard_normal() * SIGMA
    for k in range(1, R):
        x[k] = PHI * x[k - 1] + e[k]
    return x


def _data(rng, W):
    return (W[:, 0, :] @ CHI + _ar1(rng))[:, None]


def _closed_form(W, y, kind):
    """(mean, std) of the posterior of χ with σ at the LS residual's, for noise model `kind`."""
    st = bayes.sufficient_statistics(W, y, NAMES)
    chi, _ = st.ls()
    st = bayes.sufficient_statistics(W, y, NAMES, ref=chi)
    sigma = np.sqrt(st.s / (st.rows - len(NAMES)))
    mean, cov = bayes.known_noise_posterior(temper(st, noise_model(kind, W, y, None, chi)), sigma)
    return mean, np.sqrt(np.diag(cov))


def test_tempered_likelihood_covers_ar1_noise_where_the_white_one_does_not():
    W = _regressor()
    rng = np.random.default_rng(26)
    hits = {"white": [], "neff": []}
    for _ in range(300):
        y = _data(rng, W)
        for kind in hits:
            mean, std = _closed_form(W, y, kind)
            hits[kind].append(np.abs(mean - CHI) <= 1.96 * std)
    white, neff = (float(np.mean(hits[k])) for k in ("white", "neff"))
    assert white < 0.7, white               # AR(1) 0.8: the true variance is ~ 9x the white one
    # n_eff's band truncation underestimates tau_int = 9 a little (~8): 0.91-0.94 over seeds
    assert 0.90 <= neff <= 0.985, neff


def test_white_residual_leaves_the_likelihood_untempered():
    W = _regressor()
    rng = np.random.default_rng(3)
    taus = []
    for _ in range(50):
        y = (W[:, 0, :] @ CHI + SIGMA * rng.standard_normal(R))[:, None]
        taus.append(noise_model("neff", W, y, None, CHI).tau_int[0])
    assert np.median(taus) == 1.0 and np.mean(np.asarray(taus) < 1.3) > 0.9


def test_sampler_draws_follow_the_tempered_posterior_and_say_so():
    W = _regressor()
    y = _data(np.random.default_rng(7), W)
    neff = bayes.sample_linear(W, y, NAMES, seed=2, n_walkers=16, criteria={"first_batch": 500}, noise="neff")
    white = bayes.sample_linear(W, y, NAMES, seed=2, n_walkers=16, criteria={"first_batch": 500},
                                noise="white")
    assert neff.converged and white.converged, (neff.reason, white.reason)
    _, std = _closed_form(W, y, "neff")
    # σ is sampled (Student-t tails with n_eff - b degrees of freedom): a little wider than the
    # closed form at fixed σ
    ratio = neff.std[:3] / std
    assert np.all((ratio > 0.9) & (ratio < 1.25)), ratio
    tau = neff.settings["noise_model"]["tau_int"][0]
    assert tau > 3
    assert np.all(neff.std[:3] / white.std[:3] > 0.8 * np.sqrt(tau))
    assert neff.noise_model == "neff" and white.noise_model == "white"
    assert neff.to_dict()["noise_model"] == "neff"
    assert "Noise model: neff" in neff.summary() and "Noise model: white" in white.summary()


def test_unknown_noise_model_is_one_clear_error():
    with pytest.raises(InputError, match="noise must be one of sandwich, neff, white"):
        check_noise("ar")
    W = _regressor()
    with pytest.raises(InputError, match="noise"):
        bayes.sample_linear(W, _data(np.random.default_rng(0), W), NAMES, noise="pink")


def _sandwich_closed_form(W, y, prior=None):
    """(mean, cov, Σ_R, χ̂, σ) of the sandwich posterior at σ_j = the WLS σ_j (flat or `prior`)."""
    fit = lsq.wls(W, y, NAMES, uncertainty="bootstrap", n_boot=200)
    st = bayes.sufficient_statistics(W, y, NAMES, ref=fit.chi)
    nm = sandwich_model(st, fit.cov, fit.joint_sigma)
    mean, cov = bayes.known_noise_posterior(temper(st, nm), fit.joint_sigma, prior)
    return mean, cov, fit.cov, fit.chi, fit.joint_sigma


def test_sandwich_posterior_is_the_robust_fit_and_takes_a_prior():
    W = _regressor()
    y = _data(np.random.default_rng(11), W)
    mean, cov, R, chi, _ = _sandwich_closed_form(W, y)
    # Cᵀ H C = Σ_R⁻¹: the posterior at the LS σ is N(χ̂, Σ_R) exactly
    np.testing.assert_allclose(mean, chi, rtol=0, atol=1e-9 * np.abs(chi).max())
    np.testing.assert_allclose(cov, R, rtol=1e-8, atol=1e-12 * np.abs(R).max())
    # a Gaussian prior combines with the robust likelihood: precisions add
    P = np.diag([0.05, 0.02, 0.01]) ** 2
    prior = bayes.GaussianPrior(NAMES, CHI + 0.01, P)
    mean_p, cov_p, *_ = _sandwich_closed_form(W, y, prior)
    Lam = np.linalg.inv(R) + np.linalg.inv(P)
    np.testing.assert_allclose(cov_p, np.linalg.inv(Lam), rtol=1e-8)
    np.testing.assert_allclose(mean_p, np.linalg.solve(Lam, np.linalg.solve(R, chi) + np.linalg.solve(P, CHI + 0.01)),
                               rtol=1e-8)


@pytest.mark.slow
def test_sandwich_covers_ar1_noise():
    W = _regressor()
    rng = np.random.default_rng(260)
    hits = []
    for _ in range(120):
        y = _data(rng, W)
        mean, cov, *_ = _sandwich_closed_form(W, y)
        hits.append(np.abs(mean - CHI) <= 1.96 * np.sqrt(np.diag(cov)))
    cover = float(np.mean(hits))
    # 0.886 here (white < 0.7): 400 rows of AR(1) 0.8 are ~45 effective rows, and a block
    # bootstrap of so few blocks under-estimates the variance a little (the IDIM campaigns,
    # 150-1000 rows per joint with far shorter correlation, cover 93-94 %)
    assert 0.85 <= cover <= 0.985, cover


def test_sampler_draws_follow_the_sandwich_posterior_and_say_so():
    W = _regressor()
    y = _data(np.random.default_rng(7), W)
    post = bayes.sample_linear(W, y, NAMES, seed=2, n_walkers=16, criteria={"first_batch": 500})
    assert post.converged, post.reason
    assert post.noise_model == "sandwich" and "Noise model: sandwich" in post.summary()
    _, cov, R, _, _ = _sandwich_closed_form(W, y)
    ratio = post.std[:3] / np.sqrt(np.diag(R))
    # σ_j sampled with a Jeffreys prior: a little wider than the closed form at the WLS σ_j
    assert np.all((ratio > 0.9) & (ratio < 1.25)), ratio
    nm = post.settings["noise_model"]
    assert nm["kind"] == "sandwich" and "bootstrap" in nm["source"] and len(nm["width_vs_white"]) == 3
    # the given robust covariance is the one used
    given = bayes.sample_linear(W, y, NAMES, seed=2, n_walkers=16, criteria={"first_batch": 500},
                                robust_cov=4 * R)
    assert np.all(given.std[:3] / post.std[:3] > 1.7), given.std[:3] / post.std[:3]
    assert given.settings["noise_model"]["source"] == "robust covariance given"
