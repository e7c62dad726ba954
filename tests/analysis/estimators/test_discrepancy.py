"""The Gaussian-process discrepancy covariance against closed forms and known draws."""
import numpy as np
import pytest

from dynid.analysis.estimators import discrepancy as dc


def _system(seed=0, N=120, n=2, s=4):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 6.0, N)
    q = np.c_[np.sin(t), np.cos(1.3 * t)]
    qd = np.gradient(q, t, axis=0)
    qdd = np.gradient(qd, t, axis=0)
    W3 = rng.standard_normal((N, n, s))
    W3[:, 0, 2:] = 0.0             # joint 1 sees only the first two parameters
    mask = np.ones((N, n), dtype=bool)
    mask[::7, 1] = False
    w = np.array([1.0 / 0.3, 1.0 / 0.7])
    Wt = W3 * np.where(mask, w[None, :], 0.0)[:, :, None]
    B = Wt.reshape(-1, s)
    bread_inv = np.linalg.inv(B.T @ B)
    return rng, q, qd, qdd, W3, mask, w, bread_inv


def test_exact_covariance_is_the_closed_form_a_k_a():
    _, q, qd, qdd, W3, mask, w, bread_inv = _system()
    X = dc.normalized_state(q, qd, qdd, mask)
    s2, ell = np.array([0.4, 2.5]), np.array([0.8, 1.7])
    got = dc.discrepancy_covariance(W3, mask, w, bread_inv, X, s2, ell, method="exact")
    # b = (W~'W~)^-1 sum_j w_j^2 W_j' delta_j, written as one explicit matrix over all equations
    N, n, s = W3.shape
    want = np.zeros((s, s))
    for j in range(n):
        rows = np.flatnonzero(mask[:, j])
        A = bread_inv @ (W3[rows, j, :] * w[j] ** 2).T
        K = np.exp(-0.5 * ((X[rows, None, :] - X[None, rows, :]) ** 2).sum(-1) / ell[j] ** 2)
        want += s2[j] * A @ K @ A.T
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-14)


def test_random_features_converge_to_the_exact_kernel():
    _, q, qd, qdd, W3, mask, w, bread_inv = _system()
    X = dc.normalized_state(q, qd, qdd, mask)
    s2, ell = np.array([0.4, 2.5]), np.array([0.8, 1.7])
    exact = dc.discrepancy_covariance(W3, mask, w, bread_inv, X, s2, ell, method="exact")
    rff = dc.discrepancy_covariance(W3, mask, w, bread_inv, X, s2, ell, method="rff", n_features=4000)
    sd = np.sqrt(np.diag(exact))
    # correlation-scaled error: O(1/sqrt(D)) per entry of the kernel
    assert np.max(np.abs(rff - exact) / np.outer(sd, sd)) < 0.08
    phi = dc.random_fourier_features(X, 1.3, 4000, seed=3)
    assert np.max(np.abs(phi @ phi.T - dc.rbf_kernel(X, X, 1.3))) < 0.08


def test_monte_carlo_bias_of_wls_matches_the_covariance():
    """Draws of delta from the GP, the WLS error they cause: its covariance is A K A'."""
    rng, q, qd, qdd, W3, mask, w, bread_inv = _system(seed=4)
    X = dc.normalized_state(q, qd, qdd, mask)
    s2, ell = np.array([0.5, 1.0]), np.array([1.0, 1.0])
    cov = dc.discrepancy_covariance(W3, mask, w, bread_inv, X, s2, ell, method="exact")
    N, n, s = W3.shape
    L = np.linalg.cholesky(dc.rbf_kernel(X, X, 1.0) + 1e-9 * np.eye(N))
    Wt = (W3 * np.where(mask, w[None, :], 0.0)[:, :, None]).reshape(-1, s)
    draws = []
    for _ in range(2000):
        delta = (L @ rng.standard_normal((N, n))) * np.sqrt(s2)[None, :]
        y = (np.where(mask, delta, 0.0) * w[None, :]).reshape(-1)
        draws.append(np.linalg.lstsq(Wt, y, rcond=None)[0])
    mc = np.cov(np.asarray(draws), rowvar=False)
    np.testing.assert_allclose(np.sqrt(np.diag(mc)), np.sqrt(np.diag(cov)), rtol=0.08)


def _repeating_path(N):
    """A state that repeats (period 2 pi over 12 s) and the fixed effects of a joint's regressor."""
    t = np.linspace(0.0, 12.0, N)
    X = np.c_[np.sin(t), np.cos(t), np.sin(2 * t)] / 0.7
    return X, np.c_[np.ones(N), X[:, 0]]


def test_reml_finds_no_discrepancy_in_white_noise_and_one_in_a_gp_draw():
    rng = np.random.default_rng(5)
    N = 200
    X, F = _repeating_path(N)
    white = dc.reml_hyperparameters(0.1 * rng.standard_normal(N), F, X, n_sub=N, lengthscales=[0.5, 1.0, 2.0])
    assert white["s2"] < 0.1 * white["noise2"]
    assert white["noise2"] == pytest.approx(0.01, rel=0.3)
    # the trajectory repeats (period 2 pi): a GP draw over the state repeats with it, the noise does not
    L = np.linalg.cholesky(dc.rbf_kernel(X, X, 1.0) + 1e-9 * np.eye(N))
    y = 1.0 * (L @ rng.standard_normal(N)) + 0.1 * rng.standard_normal(N)
    gp = dc.reml_hyperparameters(y, F, X, n_sub=N, noise="ar1", lengthscales=[1.0])
    assert gp["s2"] > 10 * gp["noise2"]
    assert gp["noise2"] == pytest.approx(0.01, rel=0.5)


def test_ar1_noise_is_not_taken_for_a_discrepancy():
    rng = np.random.default_rng(6)
    N = 160
    X, F = _repeating_path(N)
    u = rng.standard_normal(N)
    e = np.empty(N)
    e[0] = u[0] / np.sqrt(1 - 0.81)
    for k in range(1, N):   # AR(1), coefficient 0.9
        e[k] = 0.9 * e[k - 1] + u[k]
    e *= 0.1
    ells = [0.3, 1.0]
    ar = dc.reml_hyperparameters(e, F, X, n_sub=N, noise="ar1", lengthscales=ells)
    white = dc.reml_hyperparameters(e, F, X, n_sub=N, noise="white", lengthscales=ells)
    assert ar["phi"] >= 0.7
    assert ar["s2"] / ar["noise2"] < white["s2"] / white["noise2"]


def test_normalized_state_standardises_the_used_samples():
    _, q, qd, qdd, _, mask, _, _ = _system()
    mask = mask.copy()
    mask[:10] = False
    X = dc.normalized_state(q, qd, qdd, mask)
    live = mask.any(axis=1)
    np.testing.assert_allclose(X[live].mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(X[live].std(axis=0), 1.0, rtol=1e-12)


def test_bad_options_are_refused():
    _, q, qd, qdd, W3, mask, w, bread_inv = _system()
    with pytest.raises(ValueError, match="method"):
        dc.discrepancy_covariance(W3, mask, w, bread_inv, np.zeros((W3.shape[0], 1)), [1, 1], [1, 1],
                                  method="nystrom")
    with pytest.raises(ValueError, match="noise"):
        dc.reml_hyperparameters(np.zeros(50), np.ones((50, 1)), np.zeros((50, 2)), noise="pink")


def test_noise_covariance_is_the_closed_form_a_r_a():
    _, _, _, _, W3, mask, w, bread_inv = _system(seed=2)
    noise2, phi = np.array([0.2, 0.05]), np.array([0.9, 0.5])
    got = dc.noise_covariance(W3, mask, w, bread_inv, noise2, phi, chunk=17)   # chunks must not matter
    want = np.zeros_like(got)
    for j in range(W3.shape[1]):
        rows = np.flatnonzero(mask[:, j])
        A = bread_inv @ (W3[rows, j, :] * w[j] ** 2).T
        R = phi[j] ** np.abs(np.subtract.outer(rows, rows))
        want += noise2[j] * A @ R @ A.T
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-14)
    # white noise: the classic covariance of eq. (14) with sigma_j^2 = noise2_j (weights 1/sigma_j)
    w_white = 1.0 / np.sqrt(noise2)
    Wt = (W3 * np.where(mask, w_white[None, :], 0.0)[:, :, None]).reshape(-1, W3.shape[2])
    bread = np.linalg.inv(Wt.T @ Wt)
    np.testing.assert_allclose(dc.noise_covariance(W3, mask, w_white, bread, noise2, [0.0, 0.0]), bread,
                               rtol=1e-10)
