"""Sufficient statistics of a linear model, per joint (see dynid.analysis.sampling.posterior).

With the rows of joint j kept by the row mask: G_j = W^jᵀW^j, and about a
reference χ_ref (the LS estimate) g_j = W^jᵀ(Y^j − W^jχ_ref),
s_j = ‖Y^j − W^jχ_ref‖² and the row count r_j, computed once after
decimation; S_j(χ) = s_j − 2 δᵀg_j + δᵀG_jδ with δ = χ − χ_ref is then exact
at a cost independent of the number of samples.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from dynid.errors import IdentificationError, InputError


@dataclass(eq=False)
class SufficientStats:
    """Per-joint sufficient statistics of a linear model (see the module docstring).

    Attributes: `names` (b,), `G` (n, b, b) = W^jᵀW^j, `g` (n, b) =
    W^jᵀ(Y^j − W^jχ_ref), `s` (n,) = ‖Y^j − W^jχ_ref‖², `rows` (n,) r_j,
    `ref` (b,) χ_ref, `WtY` (n, b) and `YtY` (n,) raw, `n_samples` N.
    """

    names: list
    G: np.ndarray
    g: np.ndarray
    s: np.ndarray
    rows: np.ndarray
    ref: np.ndarray
    WtY: np.ndarray
    YtY: np.ndarray
    n_samples: int
    data_hash: str | None = None

    @property
    def n_joints(self) -> int:
        return self.G.shape[0]

    @property
    def n_params(self) -> int:
        return self.G.shape[1]

    @property
    def active(self) -> np.ndarray:
        """Joints with at least one row."""
        return np.flatnonzero(self.rows > 0)

    def rss(self, X) -> np.ndarray:
        """S_j(χ) for every row χ of `X` (K, b): array (K, n)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        D = X - self.ref
        n, b = self.n_joints, self.n_params
        DG = (D @ self.G.transpose(1, 0, 2).reshape(b, n * b)).reshape(-1, n, b)
        DG -= 2.0 * self.g
        return np.einsum("kjb,kb->kj", DG, D) + self.s

    def ls(self, joint_sigma=None):
        """(χ̂, (Σ_j G_j/σ_j²)⁻¹) of the (weighted) LS problem these statistics define."""
        w = np.ones(self.n_joints) if joint_sigma is None else 1.0 / np.asarray(joint_sigma, float) ** 2
        w = np.where(self.rows > 0, w, 0.0)
        Lam = np.einsum("j,jbc->bc", w, self.G)
        rhs = np.einsum("j,jb->b", w, self.g)
        cf = cholesky(Lam, self.names, "WᵀW")
        cov = sla.cho_solve(cf, np.eye(self.n_params))
        return self.ref + sla.cho_solve(cf, rhs), cov


    def about(self, chi) -> SufficientStats:
        """The same statistics about another reference χ_ref = `chi` (exact: g_j − G_j δ, S_j(chi))."""
        chi = np.asarray(chi, dtype=float).reshape(self.n_params)
        d = chi - self.ref
        return SufficientStats(names=self.names, G=self.G, g=self.g - self.G @ d, s=self.rss(chi)[0],
                               rows=self.rows, ref=chi, WtY=self.WtY, YtY=self.YtY,
                               n_samples=self.n_samples, data_hash=self.data_hash)

    def joint_optimum(self, joint_sigma, max_iter: int = 200, rtol: float = 1e-10):
        """(χ*, σ*): the maximum of the Gaussian likelihood with one σ_j per joint (the
        posterior mode in log σ_j under the Jeffreys prior), by the fixed point σ_j² =
        S_j(χ)/r_j, χ = the WLS of those σ_j, from `joint_sigma` (eq. (16)'s, each joint fitted
        alone). Where the model misses torque the two differ (a joint's own fit absorbs more of
        it), and so do their optima."""
        act = self.active
        sigma = np.asarray(joint_sigma, dtype=float).reshape(self.n_joints).copy()
        sigma[self.rows == 0] = 1.0          # no rows: no weight, whatever it is (ls masks them)
        bad = act[~(np.isfinite(sigma[act]) & (sigma[act] > 0))]
        sigma[bad] = np.sqrt(np.maximum(self.s[bad], 1e-300) / self.rows[bad])
        chi = self.ls(sigma)[0]
        for _ in range(max_iter):
            new = sigma.copy()
            new[act] = np.sqrt(np.maximum(self.rss(chi)[0][act], 1e-300) / self.rows[act])
            done = np.max(np.abs(new[act] / sigma[act] - 1.0)) < rtol
            sigma, chi = new, self.ls(new)[0]
            if done:
                break
        return chi, sigma


def cholesky(A, names, what):
    """Cholesky factor of A (scipy cho_factor), or an IdentificationError naming the parameters."""
    try:
        return sla.cho_factor(A, lower=True, check_finite=True)
    except (np.linalg.LinAlgError, ValueError):
        raise IdentificationError(
            f"{what} is not positive definite for the parameters {', '.join(map(str, names))}: "
            "the data do not identify them all. Use base or essential parameters, or a richer "
            "trajectory.") from None


def sufficient_statistics(W3, tau, names=None, *, row_mask=None, ref=None, chunk: int = 65536) -> SufficientStats:
    """Per-joint W^jᵀW^j, W^jᵀ(Y^j − W^jχ_ref), ‖Y^j − W^jχ_ref‖², r_j of the rows in `row_mask`.

    `W3` (N, n, b), `tau` (N, n), `row_mask` (N,) or (N, n) bool
    (True = use); `ref` (b,) defaults to 0 (then g = WᵀY and s = YᵀY).
    One pass over the data in chunks of `chunk` samples (BLAS products);
    masked rows may hold NaN.
    """
    W3 = np.asarray(W3, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if W3.ndim != 3 or tau.shape != W3.shape[:2]:
        raise InputError(f"W3 must be (N, n, b) and tau (N, n); got {W3.shape} and {tau.shape}")
    N, n, b = W3.shape
    names = [f"p{i + 1}" for i in range(b)] if names is None else [str(x) for x in names]
    if len(names) != b:
        raise InputError(f"{len(names)} names for {b} columns of W3")
    if row_mask is None:
        mask = np.ones((N, n), dtype=bool)
    else:
        m = np.asarray(row_mask)
        if m.dtype != bool:
            raise InputError(f"row_mask must be boolean, got dtype {m.dtype}")
        mask = np.broadcast_to(m[:, None] if m.shape == (N,) else m, (N, n))
        if mask.shape != (N, n):
            raise InputError(f"row_mask has shape {m.shape}; it must be ({N},) or ({N}, {n})")
    ref = np.zeros(b) if ref is None else np.asarray(ref, dtype=float).reshape(b)
    G = np.zeros((n, b, b))
    g = np.zeros((n, b))
    s = np.zeros(n)
    WtY = np.zeros((n, b))
    YtY = np.zeros(n)
    rows = mask.sum(axis=0).astype(int)
    for start in range(0, N, chunk):
        sl = slice(start, min(N, start + chunk))
        for j in range(n):
            mj = mask[sl, j]
            if not mj.any():
                continue
            Wc = W3[sl, j, :][mj]
            yc = tau[sl, j][mj]
            if not (np.all(np.isfinite(Wc)) and np.all(np.isfinite(yc))):
                raise InputError(f"non-finite W3 or tau in the rows used (joint {j + 1}, samples "
                                 f"{sl.start}..{sl.stop - 1}); exclude them with row_mask")
            e = yc - Wc @ ref
            G[j] += Wc.T @ Wc
            g[j] += Wc.T @ e
            s[j] += e @ e
            WtY[j] += Wc.T @ yc
            YtY[j] += yc @ yc
    return SufficientStats(names=names, G=G, g=g, s=s, rows=rows, ref=ref, WtY=WtY, YtY=YtY,
                           n_samples=N)


