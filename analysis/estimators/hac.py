"""Covariances of a (weighted) least-squares estimate that hold when the residual is correlated in time.

The classic covariance of eq. (14) of Gautier, Janot & Vandanjon (2010),
σ̂²(WᵀW)⁻¹, counts every decimated sample as an independent draw. The residual
of decimated closed-loop data is not (Ljung–Box p < 1e-10 on every real
recording dynid has), so that σ is too small. Two remedies, both on the
stacked, per-joint weighted system of eq. (16):

* a HAC sandwich (Newey & West 1987): cov = B⁻¹ S B⁻¹ with B = W̃ᵀW̃ and S the
  long-run covariance of the per-sample scores g_t = Σ_j W̃_tjᵀ ρ̃_tj. The
  scores sum the joints of one time instant, so the correlation across joints
  (at lag 0 and at every lag) is kept; the Bartlett bandwidth is chosen from
  the scores by Andrews' (1991) AR(1) plug-in rule; recordings are independent
  blocks (no lag crosses from one to the next);
* a circular block bootstrap (Politis & Romano 1992) of the decimated time
  samples that carry equations: every equation of a sample moves with it,
  blocks of consecutive samples keep the serial correlation; the block length
  is the automatic rule of Politis & White (2004) with the correction of
  Patton, Politis & White (2009) (flat-top lag window, no parametric model of
  the scores), the median over the score columns; a parameter whose own
  influence series (B⁻¹g_t) asks for a longer block by that rule (rounded to
  a power of two) gets its spread from replicates drawn with that block as
  well, and the larger of the two spreads; the standard deviation of
  each parameter is the half-width of its 2.5-97.5 % percentile interval over
  1.96, the correlations those of the replicates of the common block.

Why a block per parameter: the median over the columns fits most parameters,
but not a slow regressor, whose influence series carries the low-frequency
part of the residual (drift, an effect of the position the model lacks). On
the independent plant (coloured noise, a position ripple on joint 1) the offset
of joint 1 got blocks of 4 samples where its own series asks for 16-32, and its
intervals covered 79 % (held-out seeds 14000-14099); with its own block 94 %, and
the median σ over all parameters unchanged. Why never a shorter block than the common
one, and σ the larger of the two spreads: a short block biases the spread down (it cuts
the correlation beyond it); a long one is noisier, and biased down too when it is a
large part of the record (about b/T of the variance).

Why the percentile half-width and not the replicates' variance: with ~200
decimated samples and 60-70 parameters, a replicate that misses a short
informative stretch of the trajectory is nearly singular and lands far out;
a handful of those dominate a variance but not a 95 % interval, which is the
claim %σ makes (on the real recordings the two differ by a few per cent; on a
design excited in one short burst the variance is 15 % wider). Why only the
samples with equations: a time segment (a row mask) of a longer system leaves
the other samples without equations; drawing them too made the informative
share of each replicate random and inflated the spread (median σ 10 times the
classic one on the Panda's halves, 6.4 without those samples). Why not the
AR(1) plug-in for the block: the scores of a smooth, periodic trajectory are not
an AR(1); on the Panda (lag-1 correlation 0.97) it gave blocks of 66-79 of 473
samples, 6 or 7 blocks per half, and σ 6.4 times the classic one, against blocks
of 20-26 and 4.6 times with Politis & White's rule (benchmarks/uncertainty.py).

Plain functions on numpy arrays; the long-run covariance itself is
statsmodels' S_hac_simple with Bartlett weights.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dtrtrs as _trtrs
from statsmodels.stats.sandwich_covariance import S_hac_simple

try:    # numpy.linalg.cholesky's gufunc: one failing matrix gives NaN, not an error for all
    from numpy.linalg._umath_linalg import cholesky_lo as _cholesky_lo
except ImportError:     # pragma: no cover - numpy moved it; _cholesky_each loops instead
    _cholesky_lo = None

#: Largest memory (bytes) the bootstrap spends on the per-sample information matrices.
MAX_BOOT_BYTES = 256 * 2**20

__all__ = ["sample_scores", "andrews_bandwidth", "block_length", "politis_white_block", "parameter_blocks",
           "hac_covariance", "bootstrap_covariance", "score_ar1", "BOOT_SPREAD"]

#: How the bootstrap turns its replicates into standard deviations.
BOOT_SPREAD = ("percentile", "cov")


def sample_scores(W3, tau, mask, chi, weights) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample scores g_t = Σ_j w_j² W_tj ρ_tj and per-sample information A_t = Σ_j w_j² W_tjᵀW_tj.

    Parameters
    ----------
    W3 : array (N, n, s)
        Regressor of the parameters estimated (columns already selected).
    tau : array (N, n)
        Torques.
    mask : bool array (N, n)
        Equations used (the others contribute nothing).
    chi : array (s,)
        The estimate.
    weights : array (n,)
        Per-joint row weights (1 for OLS, 1/σ_j for WLS, eq. (16)).

    Returns
    -------
    g : array (N, s)
        Scores; Σ_t g_t = 0 at the LS solution.
    Wt : array (N, n, s)
        The weighted, masked regressor W̃ (rows of unused equations are 0).
    """
    w = np.where(mask, np.asarray(weights, dtype=float)[None, :], 0.0)
    Wt = W3 * w[:, :, None]
    with np.errstate(invalid="ignore", over="ignore"):
        rho = np.where(mask, tau - W3 @ chi, 0.0) * w
    g = np.einsum("tjs,tj->ts", Wt, rho)
    return g, Wt


def score_ar1(g: np.ndarray) -> np.ndarray:
    """Lag-1 autocorrelation of each column of g (columns of zeros give 0)."""
    x = g - g.mean(axis=0)
    den = np.einsum("ts,ts->s", x, x)
    num = np.einsum("ts,ts->s", x[1:], x[:-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(den > 0, num / den, 0.0)
    return np.clip(rho, -0.97, 0.97)


def andrews_bandwidth(g: np.ndarray) -> float:
    """Bartlett bandwidth of Andrews (1991), eq. (6.4) with AR(1) plug-ins on each score column.

    α(1) = Σ_a 4ρ_a²σ_a⁴/((1−ρ_a)⁶(1+ρ_a)²) / Σ_a σ_a⁴/(1−ρ_a)⁴ with the
    columns standardised first (so that a parameter in small units does not
    drop out), and S_T = 1.1447 (α(1) T)^(1/3). Returns the lag truncation
    (a real number ≥ 0: lags with |l| < S_T get weight 1 − |l|/S_T).
    """
    T = g.shape[0]
    sd = g.std(axis=0)
    keep = sd > 0
    if not keep.any() or T < 3:
        return 0.0
    rho = score_ar1(g[:, keep] / sd[keep])
    s2 = 1.0 - rho**2  # innovation variance of a unit-variance AR(1)
    num = np.sum(4 * rho**2 * s2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2))
    den = np.sum(s2**2 / (1 - rho) ** 4)
    alpha = num / den
    return float(min(1.1447 * (alpha * T) ** (1.0 / 3.0), T - 1))


def block_length(g: np.ndarray) -> int:
    """Circular-block bootstrap block length from an AR(1) plug-in (Politis & White 2004).

    For an AR(1) of coefficient ρ, b = (6ρ²/(1−ρ²)²)^(1/3) T^(1/3); the
    columns' ρ are combined as in `andrews_bandwidth` (median of |ρ|). The
    population value of `politis_white_block` for an AR(1); kept for comparison
    (benchmarks/uncertainty.py), the bootstrap uses `politis_white_block`.
    """
    T = g.shape[0]
    sd = g.std(axis=0)
    keep = sd > 0
    if not keep.any():
        return 1
    rho = float(np.median(np.abs(score_ar1(g[:, keep] / sd[keep]))))
    b = (6 * rho**2 / (1 - rho**2) ** 2) ** (1.0 / 3.0) * T ** (1.0 / 3.0)
    return int(min(max(1, math.ceil(b)), max(1, T // 3)))


def _pw_one(x: np.ndarray) -> float:
    """Politis & White (2004) / Patton et al. (2009) circular-block length of one series."""
    T = x.size
    e = x - x.mean()
    kn = max(5, int(math.sqrt(math.log10(T))))
    m_max = min(int(math.ceil(math.sqrt(T))) + kn, T - 1)
    acv = np.array([e[k:] @ e[:T - k] / T for k in range(m_max + 1)])
    if acv[0] <= 0:
        return 1.0
    rho = np.abs(acv / acv[0])
    band = 2.0 * math.sqrt(math.log10(T) / T)
    # m-hat: the first lag after which kn consecutive autocorrelations are insignificant
    m_hat = next((m for m in range(1, m_max - kn + 1) if np.all(rho[m + 1:m + kn + 1] < band)), None)
    M = m_max if m_hat is None else min(2 * m_hat, m_max)
    k = np.arange(1, M + 1)
    lam = np.where(k / M <= 0.5, 1.0, 2.0 * (1.0 - k / M))   # flat-top lag window
    G = 2.0 * np.sum(lam * k * acv[1:M + 1])
    g0 = acv[0] + 2.0 * np.sum(lam * acv[1:M + 1])
    if g0 <= 0:
        return 1.0
    b = (2.0 * G**2 / (4.0 / 3.0 * g0**2)) ** (1.0 / 3.0) * T ** (1.0 / 3.0)
    return float(min(b, math.ceil(min(3 * math.sqrt(T), T / 3))))


def politis_white_block(g: np.ndarray, groups=None) -> int:
    """Circular-block length of the score series g (T, s): the automatic rule of Politis & White (2004).

    Each non-constant column gets b = (2Ĝ²/D̂_CB)^(1/3) T^(1/3) with
    Ĝ = Σ λ(k/M)|k|R̂(k), D̂_CB = (4/3)ĝ(0)², ĝ(0) = Σ λ(k/M)R̂(k), λ the
    flat-top window and M = 2m̂ from the first run of insignificant
    autocorrelations (with the correction of Patton, Politis & White 2009;
    the rule of arch.bootstrap.optimal_block_length). The block is the median
    over the columns (and the `groups`, each a series of its own), at least 1
    and at most a third of the shortest group.

    Parameters
    ----------
    g : array (T, s)
        Scores, in time order.
    groups : array (T,), optional
        Independent series (recordings).

    Returns
    -------
    int
        The block length in samples.
    """
    g = np.asarray(g, dtype=float)
    parts = _groups(g.shape[0], groups)
    bs = [_pw_one(g[idx, c]) for idx in parts if idx.size >= 8
          for c in range(g.shape[1]) if np.ptp(g[idx, c]) > 0]
    if not bs:
        return 1
    shortest = min(idx.size for idx in parts)
    return int(min(max(1, math.ceil(np.median(bs))), max(1, shortest // 3)))


def _groups(N: int, groups) -> list[np.ndarray]:
    if groups is None:
        return [np.arange(N)]
    groups = np.asarray(groups)
    return [np.flatnonzero(groups == k) for k in np.unique(groups)]


def hac_covariance(W3, tau, mask, chi, weights, bread_inv, *, groups=None, bandwidth=None,
                   dof: int | None = None) -> tuple[np.ndarray, dict]:
    """Newey–West sandwich B⁻¹ S B⁻¹ of a per-joint weighted LS estimate.

    Parameters
    ----------
    W3, tau, mask, chi, weights
        As in `sample_scores`.
    bread_inv : array (s, s)
        (W̃ᵀW̃)⁻¹ of the weighted system (the unscaled covariance of eq. (14)).
    groups : array (N,), optional
        Recording of each sample: lags never cross from one recording to the next.
    bandwidth : float, optional
        Bartlett lag truncation; default: `andrews_bandwidth` of the scores.
    dof : int, optional
        Number of parameters for the small-sample factor r/(r − s) (default s).

    Returns
    -------
    cov : array (s, s)
    info : dict
        `bandwidth`, `nlags` (largest lag with a non-zero weight),
        `score_ar1` (median lag-1 autocorrelation of the scores).
    """
    g, _ = sample_scores(W3, tau, mask, chi, weights)
    if bandwidth is None:
        bandwidth = andrews_bandwidth(g)
    nlags = max(0, math.ceil(bandwidth) - 1) if bandwidth > 0 else 0
    S = np.zeros((g.shape[1], g.shape[1]))
    for idx in _groups(g.shape[0], groups):
        S += S_hac_simple(g[idx], nlags=min(nlags, idx.size - 1))  # a sum over t, not a mean
    r = int(np.count_nonzero(mask))
    s = g.shape[1] if dof is None else int(dof)
    cov = bread_inv @ S @ bread_inv * (r / max(r - s, 1))
    return 0.5 * (cov + cov.T), {"bandwidth": float(bandwidth), "nlags": int(nlags),
                                 "score_ar1": float(np.median(score_ar1(g))) if g.size else 0.0}


def _on_grid(b: float) -> int:
    """b rounded, in log scale, to a power of two.

    The bootstrap variance changes slowly with the block near the optimum, so
    blocks within a factor √2 share one set of replicates.
    """
    return int(2 ** round(math.log2(max(b, 1.0))))


def parameter_blocks(g: np.ndarray, B: np.ndarray, groups=None) -> np.ndarray:
    """Politis & White block of each parameter, from its own influence series.

    The estimate's error is, to first order, Σ_t u_t with u_t = B⁻¹ g_t (B the
    information W̃ᵀW̃, g_t the scores), so parameter i is the sum of the series
    u_·i and Politis & White's rule, derived for the mean of one series, applies
    to it as it stands. The median over the score columns (`politis_white_block`)
    fits most parameters of a trajectory, but not those whose regressor is slow:
    a joint offset (a constant column) or a Coulomb term whose sign changes a few
    times; their influence series carry the low-frequency part of the residual
    (drift, a position ripple the model lacks) that short blocks cut.

    Parameters
    ----------
    g : array (T, s)
        Scores, in time order.
    B : array (s, s)
        Information of the fit (positive definite).
    groups : array (T,), optional
        Independent series (recordings).

    Returns
    -------
    array (s,) of int
        Each parameter's block: the median of its groups' rule, at least 1 and
        at most a third of the shortest group.
    """
    d = np.sqrt(np.diag(B))
    L = np.linalg.cholesky(B / np.outer(d, d))
    u = np.linalg.solve(L.T, np.linalg.solve(L, (g / d).T)).T / d
    parts = [idx for idx in _groups(g.shape[0], groups) if idx.size >= 8]
    cap = max(1, min((idx.size for idx in _groups(g.shape[0], groups)), default=1) // 3)
    out = np.ones(g.shape[1], dtype=int)
    for i in range(g.shape[1]):
        bs = [_pw_one(u[idx, i]) for idx in parts if np.ptp(u[idx, i]) > 0]
        if bs:
            out[i] = min(max(1, math.ceil(np.median(bs))), cap)
    return out


def bootstrap_covariance(W3, tau, mask, chi, weights, *, groups=None, n_boot: int = 300,
                         block: int | str | None = None, spread: str = "percentile",
                         seed: int = 0) -> tuple[np.ndarray, dict]:
    """Covariance of the estimate over a circular block bootstrap of the decimated samples.

    Each replicate draws, within each recording, ⌈T/b⌉ blocks of b consecutive
    samples (wrapping around) among the T samples that carry at least one
    equation, and refits the weighted LS with the same weights; the per-sample
    information A_t = Σ_j W̃_tjᵀW̃_tj and c_t = Σ_j W̃_tjᵀỸ_tj are summed with
    the multiplicities of the draw, so a replicate costs one s x s solve.
    Replicates whose information is singular are skipped (counted in
    `info["failed"]`).

    With the default rule the common block is that of the scores
    (`politis_white_block`), and a parameter whose own block (`parameter_blocks`,
    rounded to a power of two and at most a third of the shortest recording) is
    longer gets its spread from replicates drawn with that block too: its σ is
    the larger of the two spreads. The correlations are those of the common
    block's replicates. When a longer block's replicates cannot be refitted
    (too few, singular), its parameters take the longest shorter block that
    could, and `info["longer_blocks_failed"]` names it.

    Parameters
    ----------
    W3, tau, mask, chi, weights
        As in `sample_scores`.
    groups : array (N,), optional
        Recording of each sample: no block crosses from one recording to the next.
    n_boot : int
        Replicates (per block).
    block : int or {"politis-white", "politis-white-scores", "ar1"}, optional
        Block length in samples, or the rule that chooses it: "politis-white"
        (default) per parameter as above; "politis-white-scores" one block for
        all, `politis_white_block` of the scores; "ar1" the AR(1) plug-in
        `block_length`.
    spread : {"percentile", "cov"}
        "percentile": σ_i = (q97.5 − q2.5)/(2 · 1.96) of the replicates, with
        their correlations (module doc); "cov": the replicates' covariance.
    seed : int
        Seed of the draws.

    Returns
    -------
    cov : array (s, s)
    info : dict
        `block` (the common block, behind the correlations), `block_rule`,
        `parameter_blocks` (each parameter's block), `spread`, `n_boot` (per
        block), `failed` (of the common block's replicates), `failed_longer`
        (of the longer blocks' replicates), `longer_blocks_failed` (the longer
        blocks given up), `seed`, `samples` (the samples with equations).

    Raises
    ------
    ValueError
        Fewer than max(20, n_boot/2) replicates of the common block could be
        refitted.
    """
    if spread not in BOOT_SPREAD:
        raise ValueError(f"spread must be one of {BOOT_SPREAD}, got {spread!r}")
    g, Wt = sample_scores(W3, tau, mask, chi, weights)
    live = np.asarray(mask, dtype=bool).any(axis=1)
    grp = np.zeros(g.shape[0], dtype=int) if groups is None else np.asarray(groups).reshape(-1)
    parts = [idx for idx in (np.flatnonzero(live & (grp == k)) for k in np.unique(grp)) if idx.size]
    used = np.concatenate(parts)
    rule = block if isinstance(block, str) or block is None else "given"
    if rule in (None, "politis-white", "politis-white-scores"):
        block = politis_white_block(g[used], grp[used])
        rule = "politis-white" if rule is None else rule
    elif rule == "ar1":
        block = block_length(g[used])
    elif rule != "given":
        raise ValueError(f"block must be a number of samples, 'politis-white', 'politis-white-scores' or "
                         f"'ar1', got {block!r}")
    block = int(block)
    w = np.where(mask, np.asarray(weights, dtype=float)[None, :], 0.0)
    yt = np.where(mask, tau, 0.0) * w
    # upper triangles of the per-sample information A_t, held when they fit in MAX_BOOT_BYTES
    # (else each replicate's is summed from Wt)
    N, s = g.shape
    A = _packed_information(Wt) if N * (s * (s + 1) // 2) * 8 <= MAX_BOOT_BYTES else None
    c = np.einsum("tjs,tj->ts", Wt, yt)
    D, failed = _replicates(Wt, A, c, parts, block, n_boot, np.random.default_rng(seed))
    if len(D) < max(20, n_boot // 2):
        raise ValueError(f"only {len(D)} of {n_boot} bootstrap replicates could be refitted")
    cov = np.cov(D, rowvar=False).reshape(s, s)
    spread_of = {block: _spread(D, cov, spread)}
    blocks, failed_longer, given_up = np.full(s, block), 0, []
    if rule == "politis-white":
        cap = max(1, min(idx.size for idx in parts) // 3)
        try:
            own = parameter_blocks(g[used], np.einsum("tjs,tjk->sk", Wt, Wt), grp[used])
        except np.linalg.LinAlgError:   # information not positive definite to rounding: one block for all
            own = np.full(s, block)
        # never shorter than the common block: a short block biases the spread down (it cuts the
        # correlation beyond it); a longer one is noisier, and biased down too when it is a large
        # part of the record (about b/T of the variance), which the larger of the two spreads offsets
        blocks = np.array([min(_on_grid(b), cap) if _on_grid(b) > _on_grid(block) else block for b in own])
        done = block
        for b in np.unique(blocks[blocks != block]):   # shortest first
            Db, fb = _replicates(Wt, A, c, parts, int(b), n_boot, np.random.default_rng([seed, int(b)]))
            failed_longer += fb
            if len(Db) < max(20, n_boot // 2):   # too few samples for blocks that long
                blocks[blocks == b] = done
                given_up.append(int(b))
                continue
            spread_of[int(b)], done = _spread(Db, np.cov(Db, rowvar=False).reshape(s, s), spread), int(b)
    # a longer block's spread below the common block's is the replicates' noise, not information
    sd = np.maximum([spread_of[int(b)][i] for i, b in enumerate(blocks)], spread_of[block])
    sd0 = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        C = np.where(np.outer(sd0, sd0) > 0, cov / np.outer(sd0, sd0), 0.0)
    np.fill_diagonal(C, 1.0)
    cov = C * np.outer(sd, sd)
    return cov, {"block": block, "block_rule": rule, "parameter_blocks": [int(b) for b in blocks],
                 "spread": spread, "n_boot": int(n_boot), "failed": int(failed),
                 "failed_longer": int(failed_longer), "longer_blocks_failed": given_up, "seed": int(seed),
                 "samples": int(sum(p.size for p in parts))}


def _spread(D: np.ndarray, cov: np.ndarray, spread: str) -> np.ndarray:
    """Each parameter's σ from its replicates D: 95 % percentile half-width / 1.96, or their std."""
    if spread == "percentile":
        lo, hi = np.percentile(D, [2.5, 97.5], axis=0)
        return (hi - lo) / (2 * 1.959963984540054)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _replicates(Wt, A, c, parts, block, n_boot, rng) -> tuple[np.ndarray, int]:
    """The refitted estimates of `n_boot` circular-block draws of length `block` (the singular ones
    left out), and how many were left out.

    `A` holds the upper triangles of the per-sample information matrices (N, s(s+1)/2), or is
    None (then each replicate's information is summed from `Wt`).
    """
    N, s = c.shape
    counts_all = np.zeros((n_boot, N))
    for r in range(n_boot):
        counts = counts_all[r]
        for idx in parts:
            T = idx.size
            b = min(block, T)
            starts = rng.integers(0, T, size=math.ceil(T / b))
            pos = (starts[:, None] + np.arange(b)[None, :]).reshape(-1)[:T] % T
            np.add.at(counts, idx[pos], 1.0)
    c_all = counts_all @ c
    if A is not None:
        # every replicate's information in one matrix product over the upper triangles: A is read
        # once, not once per replicate, and half of it
        iu = np.triu_indices(s)
        A_all = np.empty((n_boot, s, s))
        A_all[:, iu[0], iu[1]] = counts_all @ A
        A_all[:, iu[1], iu[0]] = A_all[:, iu[0], iu[1]]
        return _solve_all(A_all, c_all)
    draws, failed = [], 0
    for r in range(n_boot):   # one at a time: the memory path
        As = np.einsum("tjs,t,tjk->sk", Wt, counts_all[r], Wt)
        x, bad = _solve_all(As[None], c_all[r][None])
        failed += bad
        draws.extend(x)
    return np.asarray(draws).reshape(-1, s), failed


def _packed_information(Wt, chunk: int = 1024) -> np.ndarray:
    """Upper triangles (N, s(s+1)/2) of the per-sample information W̃_tᵀW̃_t, built in chunks of
    samples so that the full (N, s, s) array never exists."""
    N, _, s = Wt.shape
    iu = np.triu_indices(s)
    out = np.empty((N, iu[0].size))
    for t0 in range(0, N, chunk):
        full = np.einsum("tjs,tjk->tsk", Wt[t0:t0 + chunk], Wt[t0:t0 + chunk])
        out[t0:t0 + chunk] = full[:, iu[0], iu[1]]
    return out


def _cholesky_each(A: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack of matrices, NaN where one is not positive definite.

    numpy.linalg.cholesky raises for the whole stack when one matrix fails; its gufunc (what
    it calls) marks that matrix with NaN instead, with the same factors for the others."""
    if _cholesky_lo is not None:
        try:
            with np.errstate(invalid="ignore"):
                return _cholesky_lo(A, signature="d->d")
        except TypeError:       # pragma: no cover - numpy changed its call; the loop below
            pass
    L = np.full_like(A, np.nan)
    for r in range(len(A)):
        try:
            L[r] = np.linalg.cholesky(A[r])
        except np.linalg.LinAlgError:
            pass
    return L


def _solve_all(A_all, c_all):
    """Every replicate's refit by Cholesky factors (one batched call) and triangular solves,
    with the replicates whose information is not positive definite (a zero diagonal included)
    left out: the refits of the others, and how many were left out."""
    with np.errstate(invalid="ignore"):
        d = np.sqrt(np.einsum("rii->ri", A_all))
    good = np.all(d > 0, axis=1)
    d = d[good]
    # unit-diagonal scaling: parameters' units differ by orders of magnitude
    L = _cholesky_each(A_all[good] / (d[:, :, None] * d[:, None, :]))
    factored = ~np.isnan(L).any(axis=(1, 2))
    L, d, c = L[factored], d[factored], c_all[good][factored]
    if not len(L):
        return np.empty((0, c_all.shape[1])), len(A_all)
    # LAPACK's triangular solve on each factor as scipy.linalg.solve_triangular calls it (the
    # same numbers), without its per-matrix checks, which cost more than the solves here
    x = np.empty_like(c)
    for r, (Lr, cr) in enumerate(zip(L, c / d)):
        y, _ = _trtrs(Lr.T, cr, lower=0, trans=1)
        x[r], _ = _trtrs(Lr.T, y, lower=0, trans=0)
    return x / d, len(A_all) - len(x)
