"""Covariance of a per-joint WLS estimate from model error: a Gaussian-process discrepancy over the state.

Kennedy & O'Hagan (2001) write the measured torque as model plus discrepancy plus
noise: τ_tj = W_tj χ + δ_j(x_t) + ε_tj, with δ_j the torque the model lacks
(springs, tilt, friction shape, elasticity), a smooth function of the state
x = (q, q̇, q̈). The WLS estimate of eq. (16) of Gautier, Janot & Vandanjon
(2010), χ̂ = (W̃ᵀW̃)⁻¹ Σ_j w_j² W_jᵀ τ_j, then carries the error

    b = (W̃ᵀW̃)⁻¹ Σ_j w_j² W_jᵀ δ_j = Σ_j A_j δ_j.

With the prior δ_j ~ GP(0, s_j² k(x, x'; ℓ_j)), independent across joints and of
the noise, b has covariance Σ_j s_j² A_j K_j A_jᵀ, K_j the kernel over the
decimated samples of joint j. The kernel is over the state, not over time: a
recording that repeats one trajectory does not average b down, since every period
visits the same states and meets the same δ. The total covariance is the sampling
covariance (bootstrap, HAC) plus this term.

* `normalized_state`: the state of every decimated sample, each coordinate
  standardised over the samples with equations;
* `rbf_kernel`, `random_fourier_features`: k(x, x') = exp(−|x − x'|²/(2ℓ²)) and
  its random Fourier features (Rahimi & Recht 2007): K ≈ ΦΦᵀ with
  Φ = √(2/D) cos(XΩ/ℓ + β), Ω ~ N(0, I), β ~ U(0, 2π);
* `reml_hyperparameters`: s_j², the noise variance σ_n,j² and ℓ_j by restricted
  maximum likelihood of the residual of joint j on a subsample of its rows, the
  parameters of joint j's equations as fixed effects (the part of δ_j the
  parameters absorb does not reach the residual; REML accounts for it), white
  or AR(1)-in-time noise beside the GP (a residual correlated in time alone is
  not a discrepancy: only where the trajectory revisits a state can the two be
  told apart);
* `discrepancy_covariance`: Σ_j s_j² A_j K_j A_jᵀ, by random features or exactly;
* `noise_covariance`: Σ_j σ_n,j² A_j R_j A_jᵀ, the same model's noise part (R_j the
  AR(1) correlation in time), so that the model's own total is
  A(σ_n² R + s² K)Aᵀ.

The estimate itself never changes. Plain functions on numpy arrays.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["normalized_state", "rbf_kernel", "random_fourier_features", "reml_hyperparameters",
           "discrepancy_covariance", "noise_covariance", "discrepancy_from_fit"]

#: Lengthscales searched by `reml_hyperparameters`, in units of the median distance between samples.
LENGTHSCALE_GRID = tuple(np.geomspace(0.05, 2.0, 12))
#: Signal-to-noise ratios s²/σ_n² searched (then refined) by `reml_hyperparameters`.
RATIO_GRID = tuple(np.logspace(-4, 4, 33))
#: AR(1) coefficients (per sample) of the noise searched by `reml_hyperparameters` with noise="ar1".
PHI_GRID = (0.0, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.98)


def normalized_state(q, qd, qdd, mask) -> np.ndarray:
    """The state (q, q̇, q̈) of each sample, every coordinate standardised over the samples with equations.

    Parameters
    ----------
    q, qd, qdd : arrays (N, n)
        Positions, velocities and accelerations at the decimated samples.
    mask : bool array (N, n)
        Equations used; a sample with none does not enter the mean and scale.

    Returns
    -------
    array (N, 3n)
        Standardised state; a coordinate constant over the used samples is 0.
    """
    X = np.hstack([np.asarray(a, dtype=float) for a in (q, qd, qdd)])
    live = np.asarray(mask, dtype=bool).reshape(X.shape[0], -1).any(axis=1)
    mu = X[live].mean(axis=0)
    sd = X[live].std(axis=0)
    return np.where(sd > 0, (X - mu) / np.where(sd > 0, sd, 1.0), 0.0)


def rbf_kernel(X, Y, lengthscale: float) -> np.ndarray:
    """Squared-exponential kernel exp(−|x − y|²/(2ℓ²)) between the rows of X and Y."""
    X, Y = np.asarray(X, dtype=float), np.asarray(Y, dtype=float)
    d2 = np.maximum((X**2).sum(1)[:, None] + (Y**2).sum(1)[None, :] - 2 * X @ Y.T, 0.0)
    return np.exp(-0.5 * d2 / lengthscale**2)


def random_fourier_features(X, lengthscale: float, n_features: int = 500, seed: int = 0) -> np.ndarray:
    """Random Fourier features Φ (N, D) of the squared-exponential kernel: E[ΦΦᵀ] = `rbf_kernel`(X, X, ℓ).

    Φ = √(2/D) cos(XΩ/ℓ + β), Ω (d, D) standard normal, β uniform on [0, 2π)
    (Rahimi & Recht 2007); the error of each kernel entry is O(1/√D).
    """
    X = np.asarray(X, dtype=float)
    rng = np.random.default_rng(seed)
    omega = rng.standard_normal((X.shape[1], n_features))
    beta = rng.uniform(0.0, 2 * np.pi, n_features)
    return math.sqrt(2.0 / n_features) * np.cos(X @ omega / lengthscale + beta)


def _median_distance(X) -> float:
    d2 = np.maximum((X**2).sum(1)[:, None] + (X**2).sum(1)[None, :] - 2 * X @ X.T, 0.0)
    iu = np.triu_indices(X.shape[0], 1)
    med = float(np.sqrt(np.median(d2[iu]))) if iu[0].size else 1.0
    return med if med > 0 else 1.0


def reml_hyperparameters(residual, F, X, *, lengthscales=None, n_sub: int = 400, noise: str = "white",
                         index=None) -> dict:
    """s², σ_n² and ℓ of y = Fβ + δ + ε, δ ~ GP(0, s² k(·, ·; ℓ)), by restricted maximum likelihood.

    The restricted likelihood is that of z = Qᵀy, Q an orthonormal basis of the
    complement of the columns of F: z ~ N(0, σ_n²(QᵀRQ + λ QᵀKQ)), λ = s²/σ_n²
    (Patterson & Thompson 1971), R the correlation of the noise ε: the identity
    (white) or φ^|i − k| over the rows' time indices (AR(1), φ searched on a
    grid). With C the Cholesky factor of QᵀRQ, the eigenvalues of C⁻¹QᵀKQC⁻ᵀ give
    the likelihood for every λ at once; σ_n² is profiled out, λ is searched on
    `RATIO_GRID` and refined by a golden-section search on log λ, ℓ on
    `lengthscales`.

    Parameters
    ----------
    residual : array (T,)
        The residual (or the torque: z is the same) of one joint, in time order.
    F : array (T, p)
        The fixed effects (the regressor of that joint's equations).
    X : array (T, d)
        State of each row (`normalized_state`).
    lengthscales : sequence of float, optional
        ℓ searched; default `LENGTHSCALE_GRID` times the median distance between rows.
        One value fixes ℓ.
    n_sub : int
        At most this many rows, every k-th in time order (the likelihood costs T³).
    noise : {"white", "ar1"}
        The noise beside the GP.
    index : array (T,), optional
        Time index of each row (sample number), for the AR(1) noise; default 0, 1, ...

    Returns
    -------
    dict
        `s2`, `noise2` (marginal variance of ε), `lengthscale`, `phi` (AR(1) coefficient
        per time step, 0 for white noise), `loglik` (restricted, up to a constant),
        `rows` (used), `at_bound` (ℓ, λ or φ at the end of its grid), `median_distance`.

    Raises
    ------
    ValueError
        Fewer than 10 residual degrees of freedom, or an unknown `noise`.
    """
    if noise not in ("white", "ar1"):
        raise ValueError(f"noise must be 'white' or 'ar1', got {noise!r}")
    y = np.asarray(residual, dtype=float)
    F = np.asarray(F, dtype=float)
    X = np.asarray(X, dtype=float)
    idx = np.arange(y.size, dtype=float) if index is None else np.asarray(index, dtype=float)
    stride = max(1, math.ceil(y.size / n_sub))
    y, F, X, idx = y[::stride], F[::stride], X[::stride], idx[::stride]
    F = F[:, np.linalg.norm(F, axis=0) > 0]
    U, sv, _ = np.linalg.svd(F, full_matrices=True)
    p = int(np.sum(sv > sv.max() * 1e-10)) if sv.size else 0
    Q = U[:, p:]
    m = Q.shape[1]
    if m < 10:
        raise ValueError(f"only {m} residual degrees of freedom in {y.size} rows: too few for the discrepancy")
    z0 = Q.T @ y
    med = _median_distance(X)
    ells = [g * med for g in LENGTHSCALE_GRID] if lengthscales is None else [float(v) for v in np.atleast_1d(
        lengthscales)]
    phis = PHI_GRID if noise == "ar1" else (0.0,)
    log_ratios = np.log(np.asarray(RATIO_GRID))
    lag = np.abs(idx[:, None] - idx[None, :])

    def profile(lam, ev, z2, logdet_r):
        v = lam * ev + 1.0
        n2 = float(np.sum(z2 / v) / m)
        return -0.5 * (np.sum(np.log(v)) + logdet_r + m * math.log(max(n2, 1e-300)) + m), n2

    best = None
    for phi in phis:
        if phi > 0:
            C = np.linalg.cholesky(Q.T @ (phi**lag) @ Q)
            logdet_r = 2.0 * float(np.sum(np.log(np.diag(C))))
            Ci = np.linalg.solve(C, np.eye(m))
        else:
            Ci, logdet_r = None, 0.0
        zc = z0 if Ci is None else Ci @ z0
        for ell in ells:
            M = Q.T @ rbf_kernel(X, X, ell) @ Q
            ev, V = np.linalg.eigh(M if Ci is None else Ci @ M @ Ci.T)
            ev = np.maximum(ev, 0.0)
            z2 = (V.T @ zc) ** 2
            ll = [profile(math.exp(a), ev, z2, logdet_r)[0] for a in log_ratios]
            k = int(np.argmax(ll))
            lo, hi = log_ratios[max(k - 1, 0)], log_ratios[min(k + 1, log_ratios.size - 1)]
            for _ in range(40):   # golden section on log lambda between the grid neighbours
                a = hi - 0.618 * (hi - lo)
                b = lo + 0.618 * (hi - lo)
                if profile(math.exp(a), ev, z2, logdet_r)[0] >= profile(math.exp(b), ev, z2, logdet_r)[0]:
                    hi = b
                else:
                    lo = a
            lam = math.exp(0.5 * (lo + hi))
            val, n2 = profile(lam, ev, z2, logdet_r)
            if best is None or val > best["loglik"]:
                at_bound = (k in (0, log_ratios.size - 1) or (len(ells) > 1 and ell in (ells[0], ells[-1]))
                            or (len(phis) > 1 and phi == phis[-1]))
                best = {"s2": lam * n2, "noise2": n2, "lengthscale": ell, "phi": float(phi), "loglik": float(val),
                        "rows": int(y.size), "at_bound": bool(at_bound), "median_distance": med}
    return best


def discrepancy_covariance(W3, mask, weights, bread_inv, states, s2, lengthscales, *, method: str = "rff",
                           n_features: int = 500, seed: int = 0) -> np.ndarray:
    """Σ_j s_j² A_j K_j A_jᵀ, A_j = (W̃ᵀW̃)⁻¹ w_j² W_jᵀ: the covariance of the WLS error from the discrepancy.

    Parameters
    ----------
    W3 : array (N, n, s)
        Regressor of the parameters estimated.
    mask : bool array (N, n)
        Equations used.
    weights : array (n,)
        Per-joint weights w_j (1/σ_j of eq. (16); 1 for OLS).
    bread_inv : array (s, s)
        (W̃ᵀW̃)⁻¹ of the weighted system.
    states : array (N, d) or list of n arrays (N, d_j)
        State each joint's discrepancy depends on (one array: the same for all joints).
    s2, lengthscales : arrays (n,)
        GP variance (torque units squared) and lengthscale of each joint; s2 = 0 leaves a joint out.
    method : {"rff", "exact"}
        Random Fourier features (`n_features`, `seed`) or the exact kernel (memory N²).

    Returns
    -------
    array (s, s)
    """
    if method not in ("rff", "exact"):
        raise ValueError(f"method must be 'rff' or 'exact', got {method!r}")
    W3 = np.asarray(W3, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    n = W3.shape[1]
    S = np.zeros((W3.shape[2], W3.shape[2]))
    for j in range(n):
        rows = np.flatnonzero(mask[:, j])
        if rows.size == 0 or not s2[j] > 0:
            continue
        X = np.asarray(states[j] if isinstance(states, (list, tuple)) else states, dtype=float)[rows]
        Wj = W3[rows, j, :] * float(weights[j]) ** 2
        if method == "rff":
            G = Wj.T @ random_fourier_features(X, lengthscales[j], n_features, seed + j)
            S += s2[j] * (G @ G.T)
        else:
            S += s2[j] * (Wj.T @ rbf_kernel(X, X, lengthscales[j]) @ Wj)
    cov = bread_inv @ S @ bread_inv
    return 0.5 * (cov + cov.T)


def noise_covariance(W3, mask, weights, bread_inv, noise2, phi, *, chunk: int = 2048) -> np.ndarray:
    """Σ_j σ_n,j² A_j R_j A_jᵀ: the covariance of the WLS error from AR(1) noise, R_j[t, u] = φ_j^|t − u|.

    The sampling part of the same model as `discrepancy_covariance` (noise independent
    across joints, correlated in time with the coefficient `reml_hyperparameters` found);
    t and u are the sample numbers of joint j's equations.

    Parameters
    ----------
    W3, mask, weights, bread_inv
        As in `discrepancy_covariance`.
    noise2, phi : arrays (n,)
        Marginal noise variance (torque units squared) and AR(1) coefficient per sample of each joint.
    chunk : int
        Rows of R_j formed at a time (memory chunk · T_j).

    Returns
    -------
    array (s, s)
    """
    W3 = np.asarray(W3, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    S = np.zeros((W3.shape[2], W3.shape[2]))
    for j in range(W3.shape[1]):
        rows = np.flatnonzero(mask[:, j])
        if rows.size == 0 or not noise2[j] > 0:
            continue
        Wj = W3[rows, j, :] * float(weights[j]) ** 2
        t = rows.astype(float)
        for a in range(0, rows.size, chunk):
            R = float(phi[j]) ** np.abs(t[a:a + chunk, None] - t[None, :])
            S += noise2[j] * (Wj[a:a + chunk].T @ (R @ Wj))
    cov = bread_inv @ S @ bread_inv
    return 0.5 * (cov + cov.T)


def discrepancy_from_fit(W3, tau, mask, chi, weights, bread_inv, state, *, per_joint_state: bool = False,
                         lengthscale: str = "reml", noise: str = "white", n_sub: int = 400, method: str = "rff",
                         n_features: int = 500, seed: int = 0) -> tuple[np.ndarray, dict]:
    """The discrepancy covariance of a fitted per-joint WLS, its hyperparameters from the fit's own residual.

    Parameters
    ----------
    W3, tau, mask, chi, weights, bread_inv
        The weighted system and its solution (as in dynid.analysis.estimators.hac).
    state : tuple (q, qd, qdd) of arrays (N, n)
        The state of the decimated samples.
    per_joint_state : bool
        δ_j over joint j's own (q_j, q̇_j, q̈_j) instead of the whole state.
    lengthscale : {"reml", "median"}
        ℓ_j by restricted maximum likelihood with s_j² and σ_n,j², or fixed at the median
        distance between samples (s_j², σ_n,j² still by REML).
    noise : {"white", "ar1"}
        The noise beside the GP in the likelihood (`reml_hyperparameters`).
    n_sub, method, n_features, seed
        As in `reml_hyperparameters` and `discrepancy_covariance`.

    Returns
    -------
    cov : array (s, s)
    info : dict
        Per joint `s2`, `noise2`, `lengthscale` (in units of the state's median distance
        as `lengthscale_rel`), `phi`, `at_bound`.
    """
    if lengthscale not in ("reml", "median"):
        raise ValueError(f"lengthscale must be 'reml' or 'median', got {lengthscale!r}")
    W3 = np.asarray(W3, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    n = W3.shape[1]
    X = normalized_state(*state, mask)
    states = [X[:, [j, n + j, 2 * n + j]] for j in range(n)] if per_joint_state else [X] * n
    with np.errstate(invalid="ignore", over="ignore"):
        res = np.where(mask, tau - W3 @ chi, 0.0)
    info = {"s2": [], "noise2": [], "lengthscale": [], "lengthscale_rel": [], "phi": [], "at_bound": []}
    for j in range(n):
        rows = np.flatnonzero(mask[:, j])
        if rows.size < 20:
            hp = {"s2": 0.0, "noise2": float("nan"), "lengthscale": 1.0, "median_distance": 1.0, "at_bound": False,
                  "phi": 0.0}
        else:
            Xj = states[j][rows]
            ells = None
            if lengthscale == "median":
                stride = max(1, math.ceil(rows.size / n_sub))
                ells = [_median_distance(Xj[::stride])]
            hp = reml_hyperparameters(res[rows, j], W3[rows, j, :], Xj, lengthscales=ells, n_sub=n_sub,
                                      noise=noise, index=rows)
        info["s2"].append(float(hp["s2"]))
        info["noise2"].append(float(hp["noise2"]))
        info["lengthscale"].append(float(hp["lengthscale"]))
        info["lengthscale_rel"].append(float(hp["lengthscale"] / hp["median_distance"]))
        info["phi"].append(float(hp["phi"]))
        info["at_bound"].append(bool(hp["at_bound"]))
    cov = discrepancy_covariance(W3, mask, weights, bread_inv, states, np.array(info["s2"]),
                                 np.array(info["lengthscale"]), method=method, n_features=n_features, seed=seed)
    return cov, info
