"""Bayesian posterior of the dynamic parameters by ensemble MCMC (emcee), with checks.

Two model families, both with the sampled system of Gautier, Janot &
Vandanjon (2010), section 2: Y = W χ + ρ (eq. (9)), the equations of each
joint grouped (eq. (10)), one error standard deviation σ_j per joint as in
the WLS of eq. (16).

1. Linear models (IDIM base or essential parameters, or any per-joint linear
   model given as W3 (N, n, b), tau (N, n)).

   Likelihood: ρ^j ~ N(0, σ_j² I_{r_j}) independently per joint.
   Priors: Jeffreys p(σ_j) ∝ 1/σ_j on each σ_j; flat on χ, or a Gaussian
   N(μ₀, P₀) on some or all of χ (`GaussianPrior`, e.g. from a-priori
   values or from a previous identification).

   χ and the σ_j are sampled JOINTLY (nothing is marginalised for the linear
   model). The σ_j are sampled as u_j = log σ_j; with the Jeffreys prior the
   Jacobian dσ_j/du_j = σ_j cancels it exactly, so the density in (χ, u) is::

       log p(χ, u | Y) = Σ_j [ −r_j u_j − S_j(χ) e^{−2 u_j} / 2 ] + log p(χ) + const
       S_j(χ) = ‖Y^j − W^j χ‖²  (rows of joint j kept by the row_mask)

   With known σ_j (`sigma=`) only χ is sampled: log p = −Σ_j S_j/(2σ_j²) + log p(χ).

   Cost: S_j is evaluated from sufficient statistics computed ONCE after
   decimation (`sufficient_statistics`): G_j = W^jᵀW^j, and, about a
   reference χ_ref (the LS estimate), g_j = W^jᵀ(Y^j − W^jχ_ref),
   s_j = ‖Y^j − W^jχ_ref‖² and the row count r_j (plus the raw W^jᵀY^j and
   Y^jᵀY^j for the record). With δ = χ − χ_ref,
   S_j(χ) = s_j − 2 δᵀg_j + δᵀG_jδ: exact, cost O(n b²) per evaluation
   whatever the number of samples, and free of the cancellation of
   YᵀY − 2χᵀWᵀY + χᵀWᵀWχ. The log-probability is vectorised over walkers
   (emcee `vectorize=True`): K positions cost one (K, b)·(b, n b) product.

   Analytic results for checking:

   (a) known σ_j, flat or Gaussian prior: χ | Y ~ N(m, Λ⁻¹) with
       Λ = Σ_j G_j/σ_j² + P₀⁻¹ and m = χ_ref + Λ⁻¹ (Σ_j g_j/σ_j² + P₀⁻¹(μ₀ − χ_ref))
       (`known_noise_posterior`).
   (b) a single joint, unknown σ, flat prior on χ, Jeffreys on σ:
       p(χ | Y) ∝ S(χ)^{−r/2}, a multivariate Student t. The marginal of χ_i is
       χ_i = χ̂_i + s √[(WᵀW)⁻¹]_ii · T_ν,  T_ν ~ Student t with ν = r − b,
       χ̂ = (WᵀW)⁻¹WᵀY (OLS), s² = ‖Y − Wχ̂‖² / (r − b) (eq. (13)); and
       σ² | Y ~ ‖Y − Wχ̂‖² / χ²_ν (scaled inverse χ²), i.e. the LS interval
       χ̂_i ± t_ν s √[(WᵀW)⁻¹]_ii is exactly the credible interval
       (`student_t_posterior`).

2. Nonlinear per-joint gravity model (Bona & Curatella 2005, eq. (23), with
   the friction of their eq. (22)):

       τ = k sin(q + q_off) + Fv q̇ + Fc sign(q̇) + τ_off + ρ,   ρ ~ N(0, σ²)

   (k, q_off) enter nonlinearly. Priors: flat on k > 0 and on
   q_off ∈ (q̂_off − π, q̂_off + π] (a fundamental domain of the periodic
   parameter, centred on the LS estimate; k > 0 removes the sign ambiguity
   (k, q_off) ≡ (−k, q_off + π)), flat on the friction terms β, Jeffreys on σ.
   Sufficient statistics: k sin(q + q_off) = a sin q + c cos q with
   a = k cos q_off, c = k sin q_off, so S(k, q_off, β) is a quadratic form in
   (a, c, β) of the Gram matrix of [sin q, cos q, q̇, sign q̇, 1, τ] —
   computed once, whatever the number of samples.

   `marginalize=True` (default, implemented): β and σ are integrated out
   analytically; emcee samples only (k, q_off) from
   p(k, q_off | Y) ∝ RSS_β(k, q_off)^{−(r − p)/2} (p = number of friction
   terms, RSS_β the residual minimised over β), and for each kept state β
   and σ are drawn exactly from their conditionals
   σ² | k, q_off, Y ~ RSS_β / χ²_{r−p},  β | σ, k, q_off, Y ~ N(β̂(k, q_off), σ² (ΦᵀΦ)⁻¹).
   `marginalize=False`: (k, q_off, β, log σ) are sampled jointly.
   The delta-method interval of a nonlinear LS fit
   (`fit_gravity_ls`, scipy.optimize.least_squares with the analytic
   Jacobian J, cov = s² (JᵀJ)⁻¹) is given for comparison.

Outputs: `PosteriorResult` (samples after burn-in and thinning,
summaries, intervals beside the LS values, convergence diagnostics from
`dynid.analysis.sampling.convergence`; `converged=False` with the reason whenever the
rule was not met). Runs are seeded: the same `seed` gives the same chain,
the same `PosteriorResult.to_dict` and the same CSV, byte for byte
(unless a `max_seconds` limit stopped the run).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.linalg as sla
from scipy import optimize, stats

from dynid.analysis.results import ParameterResults, _check_alpha
from dynid.analysis.sampling.convergence import ChainDiagnostics, ConvergenceCriteria, diagnose, run_until_converged
from dynid.errors import IdentificationError, InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import data_hash, json_safe, versions

__all__ = [
    "SufficientStats", "sufficient_statistics", "GaussianPrior", "LinearPosterior",
    "known_noise_posterior", "student_t_posterior", "StudentTPosterior",
    "sample_linear", "sample_idim",
    "GravityLSResult", "fit_gravity_ls", "GravityPosterior", "sample_gravity",
    "simulate_gravity_joint", "PosteriorResult", "MissingDependencyError",
]

_WIDTH = 100


class MissingDependencyError(ImportError):
    """An optional package (xarray, arviz) is needed for this export."""


# ============================================================ sufficient statistics
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
        cf = _cho(Lam, self.names, "WᵀW")
        cov = sla.cho_solve(cf, np.eye(self.n_params))
        return self.ref + sla.cho_solve(cf, rhs), cov


def _cho(A, names, what):
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


# ============================================================ priors
@dataclass(eq=False)
class GaussianPrior:
    """Gaussian prior N(mean, cov) on the parameters `names` (others stay flat)."""

    names: list
    mean: np.ndarray
    cov: np.ndarray

    def __post_init__(self):
        self.names = [str(x) for x in self.names]
        self.mean = np.asarray(self.mean, dtype=float).reshape(-1)
        self.cov = np.atleast_2d(np.asarray(self.cov, dtype=float))
        k = len(self.names)
        if self.mean.shape != (k,) or self.cov.shape != (k, k):
            raise InputError(f"GaussianPrior: {k} names, mean {self.mean.shape}, cov {self.cov.shape} disagree")
        if not np.allclose(self.cov, self.cov.T, rtol=1e-10, atol=0):
            raise InputError("GaussianPrior: cov must be symmetric")
        try:
            np.linalg.cholesky(self.cov)
        except np.linalg.LinAlgError:
            raise InputError("GaussianPrior: cov must be positive definite") from None

    @classmethod
    def from_values(cls, names, mean, std):
        """Independent priors N(mean_i, std_i²) (e.g. a-priori CAD values)."""
        std = np.asarray(std, dtype=float).reshape(-1)
        return cls(names, mean, np.diag(std ** 2))

    @classmethod
    def from_result(cls, result, names=None, inflate: float = 1.0):
        """From a previous identification (IdentificationResult): mean χ̂, cov × inflate²."""
        idx = list(range(len(result.names))) if names is None else [result.names.index(x) for x in names]
        return cls([result.names[i] for i in idx], result.chi[idx],
                   result.cov[np.ix_(idx, idx)] * float(inflate) ** 2)

    def bind(self, model_names):
        """(indices into model_names, mean, precision) of this prior."""
        try:
            idx = np.array([list(model_names).index(x) for x in self.names], dtype=int)
        except ValueError:
            missing = [x for x in self.names if x not in model_names]
            raise InputError(f"the prior names parameter(s) {', '.join(missing)} that the model does "
                             f"not have ({', '.join(model_names)})") from None
        prec = np.linalg.inv(self.cov)
        return idx, self.mean, 0.5 * (prec + prec.T)

    def to_dict(self):
        return json_safe({"names": self.names, "mean": self.mean, "cov": self.cov})


# ============================================================ linear model
class LinearPosterior:
    """The log-posterior of a linear model (see the module docstring), vectorised over walkers.

    Sampled coordinates: χ (b,), then u_j = log σ_j for each joint with rows
    (unless `sigma` is given). `names` are the reported names
    (σ_j as `sigma<j>`, 1-based); `coords` the sampled ones.
    """

    def __init__(self, stats: SufficientStats, sigma=None, prior: GaussianPrior | None = None):
        self.stats = stats
        self.active = stats.active
        if self.active.size == 0:
            raise InputError("no rows: every equation is excluded by the row mask")
        b = stats.n_params
        self.b = b
        if sigma is not None:
            sig = np.asarray(sigma, dtype=float).reshape(-1)
            if sig.size != stats.n_joints or not np.all(np.isfinite(sig[self.active]) & (sig[self.active] > 0)):
                raise InputError(f"sigma must give {stats.n_joints} positive standard deviations "
                                 f"(one per joint), got {sigma!r}")
            self.sigma = sig
        else:
            self.sigma = None
        self.prior = prior
        if prior is not None:
            self._pidx, self._pmean, self._pprec = prior.bind(stats.names)
        n_act = self.active.size
        self._G = stats.G[self.active]
        self._Gr = self._G.transpose(1, 0, 2).reshape(b, n_act * b)
        self._g = stats.g[self.active]
        self._s = stats.s[self.active]
        self._r = stats.rows[self.active].astype(float)
        sig_names = [f"sigma{j + 1}" for j in self.active]
        clash = set(sig_names) & set(stats.names)
        if clash and self.sigma is None:
            raise InputError(f"parameter names {sorted(clash)} clash with the noise parameters")
        self.names = list(stats.names) + ([] if self.sigma is not None else sig_names)
        self.coords = list(stats.names) + ([] if self.sigma is not None else
                                           [f"log_sigma{j + 1}" for j in self.active])
        self.ndim = len(self.coords)

    # ---------------------------------------------------------------- density
    def _S(self, D):
        DG = (D @ self._Gr).reshape(D.shape[0], -1, self.b)
        DG -= 2.0 * self._g
        return np.einsum("kjb,kb->kj", DG, D) + self._s

    def _log_prior(self, X):
        if self.prior is None:
            return 0.0
        E = X[:, self._pidx] - self._pmean
        return -0.5 * np.einsum("ki,ij,kj->k", E, self._pprec, E)

    def log_prob(self, X) -> np.ndarray:
        """log p (up to a constant) of each row of `X` (K, ndim); −inf outside the support."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        chi = X[:, : self.b]
        D = chi - self.stats.ref
        S = self._S(D)
        with np.errstate(over="ignore", invalid="ignore"):
            if self.sigma is not None:
                lp = -0.5 * (S / self.sigma[self.active] ** 2).sum(axis=1)
            else:
                u = X[:, self.b:]
                lp = -(u @ self._r) - 0.5 * (S * np.exp(-2.0 * u)).sum(axis=1)
            lp = lp + self._log_prior(chi)
        return np.where(np.isnan(lp), -np.inf, lp)

    __call__ = log_prob

    def to_output(self, X) -> np.ndarray:
        """Sampled coordinates → reported ones (log σ → σ), last axis."""
        X = np.array(X, dtype=float, copy=True)
        if self.sigma is None:
            X[..., self.b:] = np.exp(X[..., self.b:])
        return X

    # ---------------------------------------------------------------- analytic
    def analytic_known_noise(self):
        if self.sigma is None:
            raise InputError("the closed form needs known noise: construct with sigma=")
        return known_noise_posterior(self.stats, self.sigma, self.prior)


def known_noise_posterior(stats: SufficientStats, sigma, prior: GaussianPrior | None = None):
    """(mean, cov) of the Gaussian posterior of χ with known σ_j (formula (a) of the module doc)."""
    sigma = np.asarray(sigma, dtype=float)
    act = stats.active
    w = np.zeros(stats.n_joints)
    w[act] = 1.0 / sigma[act] ** 2
    Lam = np.einsum("j,jbc->bc", w, stats.G)
    rhs = np.einsum("j,jb->b", w, stats.g)
    if prior is not None:
        idx, mu, P = prior.bind(stats.names)
        Lam[np.ix_(idx, idx)] += P
        rhs[idx] += P @ (mu - stats.ref[idx])
    cf = _cho(Lam, stats.names, "The posterior precision Σ G_j/σ_j²")
    cov = sla.cho_solve(cf, np.eye(stats.n_params))
    mean = stats.ref + sla.cho_solve(cf, rhs)
    return mean, 0.5 * (cov + cov.T)


@dataclass
class StudentTPosterior:
    """Closed-form posterior of a single-joint linear model, flat prior on χ, Jeffreys on σ.

    χ_i | Y = loc_i + scale_i · T_df (Student t, df = r − b), loc = χ̂_OLS,
    scale_i = s √[(WᵀW)⁻¹]_ii, s² = RSS / (r − b);  σ² | Y ~ RSS / χ²_df,
    i.e. inverse-gamma(shape df/2, scale RSS/2).
    """

    names: list
    loc: np.ndarray
    scale: np.ndarray
    df: int
    rss: float
    cov_unscaled: np.ndarray

    @property
    def s2(self) -> float:
        return self.rss / self.df

    def marginal(self, i):
        """scipy.stats frozen t distribution of parameter `i` (index or name)."""
        if isinstance(i, str):
            i = self.names.index(i)
        return stats.t(df=self.df, loc=self.loc[i], scale=self.scale[i])

    def sigma2(self):
        """Frozen distribution of σ² | Y."""
        return stats.invgamma(a=self.df / 2.0, scale=self.rss / 2.0)

    def sigma(self):
        """Frozen-like object with `cdf`/`ppf` of σ | Y."""
        d = self.sigma2()

        class _Sigma:
            def cdf(_, x):
                x = np.asarray(x, dtype=float)
                return d.cdf(np.where(x > 0, x, 0.0) ** 2)

            def ppf(_, p):
                return np.sqrt(d.ppf(p))
        return _Sigma()


def student_t_posterior(stats: SufficientStats, joint: int | None = None) -> StudentTPosterior:
    """Formula (b) of the module docstring, for the rows of one joint.

    `joint` (0-based) selects the joint; by default the statistics must
    have exactly one joint with rows.
    """
    act = stats.active
    if joint is None:
        if act.size != 1:
            raise InputError(f"the Student-t closed form is for one joint (one σ); these statistics "
                             f"have rows for joints {(act + 1).tolist()}: pass joint=")
        joint = int(act[0])
    G, g, s, r = stats.G[joint], stats.g[joint], stats.s[joint], int(stats.rows[joint])
    b = stats.n_params
    if r <= b:
        raise IdentificationError(f"{r} rows for {b} parameters: the Student-t posterior needs r > b")
    cf = _cho(G, stats.names, "WᵀW")
    Ginv = sla.cho_solve(cf, np.eye(b))
    delta = sla.cho_solve(cf, g)
    rss = float(s - g @ delta)
    df = r - b
    scale = np.sqrt(rss / df * np.diag(Ginv))
    return StudentTPosterior(names=list(stats.names), loc=stats.ref + delta, scale=scale, df=df,
                             rss=rss, cov_unscaled=Ginv)


# ============================================================ sampler plumbing
def _moves(moves):
    import emcee

    if moves is None or moves == "de":
        return emcee.moves.DEMove()
    if moves == "stretch":
        return emcee.moves.StretchMove()
    if moves == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    if isinstance(moves, str):
        raise InputError(f"moves must be 'de', 'de-snooker', 'stretch' or emcee move object(s), not {moves!r}")
    return moves


def _describe_moves(moves) -> str:
    return moves if isinstance(moves, str) else ("de" if moves is None else repr(moves))


def _n_walkers(n_walkers, d):
    if n_walkers is None:
        n_walkers = max(32, 2 * d + 2)
        n_walkers += n_walkers % 2
    n_walkers = int(n_walkers)
    if n_walkers < 2 * d:
        raise InputError(f"n_walkers = {n_walkers} is fewer than twice the {d} sampled dimensions; "
                         f"use at least {2 * d + 2}")
    return n_walkers


def _rng(seed):
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        raise InputError("seed must be an int (or a numpy Generator): runs are reproducible by design")
    return np.random.default_rng(seed)


def _initial_ball(log_prob, centre, cov, n_walkers, init_scale, rng):
    """Walkers centre + init_scale · N(0, cov), each with a finite log-probability."""
    d = centre.size
    cov = 0.5 * (cov + cov.T)
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, 1e-300)
    L = V * np.sqrt(w)
    p0 = centre + init_scale * rng.standard_normal((n_walkers, d)) @ L.T
    for _ in range(100):
        bad = ~np.isfinite(log_prob(p0))
        if not bad.any():
            return p0
        p0[bad] = centre + init_scale * rng.standard_normal((int(bad.sum()), d)) @ L.T
    raise IdentificationError("could not place the initial walkers where the posterior is positive; "
                              "check the LS starting point and the prior bounds")


def _sampler(log_prob, n_walkers, d, moves, rng):
    import emcee

    sampler = emcee.EnsembleSampler(n_walkers, d, log_prob, vectorize=True, moves=_moves(moves))
    # emcee 3.1 draws from a numpy RandomState; seed it from the run's Generator
    sampler.random_state = np.random.RandomState(int(rng.integers(0, 2**32 - 1))).get_state()
    return sampler


def _criteria(criteria, **overrides):
    if criteria is None:
        criteria = ConvergenceCriteria()
    elif isinstance(criteria, dict):
        criteria = ConvergenceCriteria(**criteria)
    elif isinstance(criteria, ConvergenceCriteria):
        criteria = dataclasses.replace(criteria)       # never modify the caller's object
    else:
        raise InputError(f"criteria must be a ConvergenceCriteria or a dict, not {type(criteria).__name__}")
    for k, v in overrides.items():
        if v is not None:
            setattr(criteria, k, v)
    criteria.__post_init__()
    return criteria


# ============================================================ linear sampling
def sample_linear(W3, tau, names, *, row_mask=None, ls=None, sigma=None, prior=None, seed=0,
                  n_walkers=None, criteria=None, max_steps=None, max_seconds=None, moves="de",
                  init_scale: float = 0.1, method_label: str = "linear model", truth=None,
                  suff_stats: SufficientStats | None = None, progress=None, support=None,
                  start=None) -> PosteriorResult:
    """Posterior of χ (and σ_j) of Y = Wχ + ρ by emcee; see the module docstring.

    Parameters
    ----------
    W3, tau, names, row_mask
        As `dynid.analysis.estimators.least_squares.wls` (decimated system, eq. (9)).
    ls : IdentificationResult, optional
        LS estimate to start from and to report beside the posterior (its
        χ̂, σ and %σ; its `joint_sigma` for the σ_j). Default: WLS of these
        data (with `sigma` as fixed weights when given).
    sigma : (n,) array, optional
        Known noise standard deviations: then only χ is sampled.
    prior : GaussianPrior, optional
        Gaussian prior on (some of) χ; default flat.
    seed : int or numpy.random.Generator
        Seeds the initial ball and emcee's RandomState.
    n_walkers : int, optional
        Default max(32, 2·ndim + 2), even.
    criteria : ConvergenceCriteria or dict, optional
        The convergence rule (≥ 50 τ etc.); `max_steps` and `max_seconds`
        override its limits.
    moves : "de" (default, emcee DEMove), "de-snooker", "stretch" or emcee moves.
    init_scale : float
        Walkers start at the LS estimate + init_scale · N(0, cov_LS) (for
        log σ_j the variance is 1/(2 r_j)).
    suff_stats : SufficientStats, optional
        Precomputed statistics (then W3/tau are only used for `ls` if needed).
    progress : callable, optional
        `progress(n_steps, required_steps)` after each batch of the sampler.
    support : callable, optional
        `support(chi)` (K, b) -> bool (K,): the prior is restricted to where it is true
        (log p = −inf elsewhere), e.g. the physically consistent set
        (`dynid.analysis.estimators.physical.PhysicalSupport`).
    start : (b,) array, optional
        Centre of the initial ball instead of the LS estimate (it must be in `support`).
    """
    from dynid.analysis.estimators import least_squares as lsq

    rng = _rng(seed)
    if ls is None:
        ls = lsq.wls(W3, tau, names, row_mask=row_mask, joint_sigma=sigma)
    if list(ls.names) != [str(x) for x in names]:
        raise InputError("ls must be a result on the same parameters, in the same order, as names")
    st = suff_stats
    if st is None:
        st = sufficient_statistics(W3, tau, names, row_mask=row_mask, ref=ls.chi)
        st.data_hash = data_hash(np.asarray(W3), np.asarray(tau),
                                    None if row_mask is None else np.asarray(row_mask))
    model = LinearPosterior(st, sigma=sigma, prior=prior)
    d = model.ndim
    b = st.n_params
    nw = _n_walkers(n_walkers, d)
    centre = np.empty(d)
    centre[:b] = ls.chi if start is None else np.asarray(start, dtype=float)
    log_prob = model.log_prob
    if support is not None:
        def log_prob(X, _lp=model.log_prob):
            lp = _lp(X)
            X = np.atleast_2d(X)
            fin = np.isfinite(lp)
            inside = np.zeros(lp.shape, dtype=bool)
            inside[fin] = support(X[fin, :b])
            return np.where(inside, lp, -np.inf)
    cov = np.zeros((d, d))
    cov[:b, :b] = ls.cov
    if sigma is None:
        act = model.active
        js = getattr(ls, "joint_sigma", None)
        if js is None or not np.all(np.isfinite(np.asarray(js)[act])):
            js = np.sqrt(st.s / np.maximum(st.rows - b, 1))
        centre[b:] = np.log(np.asarray(js, dtype=float)[act])
        cov[b:, b:] = np.diag(1.0 / (2.0 * st.rows[act]))
    crit = _criteria(criteria, max_steps=max_steps, max_seconds=max_seconds)
    p0 = _initial_ball(log_prob, centre, cov, nw, init_scale, rng)
    sampler = _sampler(log_prob, nw, d, moves, rng)
    run = run_until_converged(sampler, p0, crit, progress=progress)
    chain = model.to_output(run.kept())
    ls_value = np.full(d, np.nan)
    ls_std = np.full(d, np.nan)
    ls_value[:b] = ls.chi
    ls_std[:b] = ls.sigma
    if sigma is None and getattr(ls, "joint_sigma", None) is not None:
        ls_value[b:] = np.asarray(ls.joint_sigma)[model.active]
    ls_cov = np.full((d, d), np.nan)
    ls_cov[:b, :b] = ls.cov
    noise = ("known σ_j = " + ", ".join(f"{v:.4g}" for v in model.sigma[model.active])) if sigma is not None \
        else "one σ_j per joint, Jeffreys prior p(σ_j) ∝ 1/σ_j, sampled as log σ_j"
    settings = {
        "model": method_label,
        "likelihood": "Gaussian, independent rows, per-joint σ_j (eqs. (9), (10), (16))",
        "noise": noise,
        "prior_chi": "flat" if prior is None else {"gaussian": prior.to_dict()},
        "linear_parameters": "sampled jointly with the noise parameters (not marginalised)",
        "sampler": "emcee.EnsembleSampler(vectorize=True)",
        "moves": _describe_moves(moves),
        "n_walkers": nw,
        "init": f"LS estimate + {init_scale:g} x N(0, cov_LS); log sigma_j variance 1/(2 r_j)",
        "seed": seed if isinstance(seed, (int, np.integer)) else "numpy Generator",
        "rows_per_joint": st.rows,
        "n_samples": st.n_samples,
        "sufficient_statistics": "per joint W'W, W'(Y - W chi_ref), |Y - W chi_ref|^2, r_j; chi_ref = LS",
        "support": "all of R^b" if support is None else getattr(support, "description", "restricted"),
    }
    return PosteriorResult(
        method="emcee", model=method_label, names=model.names, chain=chain,
        diagnostics=run.diagnostics, ls_value=ls_value, ls_std=ls_std, ls_cov=ls_cov,
        ls_label=getattr(ls, "method", "LS"), settings=settings, truth=truth,
        data_hash=st.data_hash or getattr(ls, "data_hash", None),
        coords=model.coords)


def sample_idim(idim_result, *, which: str = "essential", physical: bool = False, robot=None,
                **kwargs) -> PosteriorResult:
    """Posterior of the essential (default) or base parameters of an `IDIMResult`.

    Uses its decimated observation (W, tau, row_mask) and its WLS estimate
    as the starting point and LS reference. Other arguments: `sample_linear`.

    `physical=True` (base parameters only): the posterior's support is the physically
    consistent set (`PhysicalSupport`: some
    standard set with PSD pseudo-inertias and Ia, Fv, Fc >= 0 gives these base parameters),
    i.e. the flat prior restricted to it; the walkers start around the PC-WLS estimate.
    `robot` defaults to the result's.
    """
    obs = idim_result.observation
    if which == "essential":
        ls = idim_result.essential.result
    elif which == "base":
        ls = idim_result.wls
    else:
        raise InputError(f"which must be 'essential' or 'base', not {which!r}")
    cols = idim_result.columns(ls.names)
    W = obs.W[:, :, cols]
    truth = None
    if idim_result.truth:
        truth = {k: v for k, v in idim_result.truth.items() if k in ls.names}
    kwargs.setdefault("method_label", f"IDIM {which} parameters of {idim_result.robot_name}"
                      + (", physically consistent support" if physical else ""))
    if physical:
        if which != "base":
            raise InputError("the physically consistent posterior is over the base parameters: "
                             "use which='base' (--which base)")
        from dynid.analysis.estimators.physical import PhysicalSupport, pc_wls
        robot = robot if robot is not None else getattr(idim_result, "robot", None)
        if robot is None:
            raise InputError("physical=True needs the robot of the identification")
        pc = pc_wls(robot, idim_result.base, ls.chi, ls.cov, n_boot=0)
        support = PhysicalSupport(robot, idim_result.base, ls.names, reference=pc.standard)
        support.description = ("physically consistent set: some standard set with every link's "
                               "pseudo-inertia PSD and Ia, Fv, Fc >= 0 gives these base parameters "
                               "(feasibility SDP per point, cvxpy + Clarabel)")
        kwargs["support"] = support
        kwargs["start"] = pc.chi
    res = sample_linear(W, obs.tau, ls.names, row_mask=obs.row_mask, ls=ls, truth=truth, **kwargs)
    res.data_hash = idim_result.data_hash or res.data_hash
    return res


# ============================================================ gravity model
_FRICTION = {"Fv": "viscous friction Fv·q̇", "Fc": "Coulomb friction Fc·sign(q̇)", "offset": "torque offset"}


def _gravity_regressor(q, qd, friction):
    cols = [np.sin(q), np.cos(q)]
    for f in friction:
        cols.append(qd if f == "Fv" else np.sign(qd) if f == "Fc" else np.ones_like(q))
    return np.stack(cols, axis=-1)


def _gravity_inputs(q, qd, tau, row_mask, friction):
    q = np.asarray(q, dtype=float).reshape(-1)
    qd = np.asarray(qd, dtype=float).reshape(-1)
    tau = np.asarray(tau, dtype=float).reshape(-1)
    if not (q.shape == qd.shape == tau.shape):
        raise InputError(f"q, qd and tau must have the same length; got {q.size}, {qd.size}, {tau.size}")
    friction = tuple(friction)
    bad = [f for f in friction if f not in _FRICTION]
    if bad or len(set(friction)) != len(friction):
        raise InputError(f"friction terms must be distinct, among {list(_FRICTION)}; got {list(friction)}")
    mask = np.ones(q.size, dtype=bool) if row_mask is None else np.asarray(row_mask, dtype=bool).reshape(-1)
    if mask.shape != q.shape:
        raise InputError(f"row_mask must have {q.size} entries")
    return q[mask], qd[mask], tau[mask], friction


@dataclass(eq=False)
class GravityLSResult:
    """Nonlinear LS fit of τ = k sin(q + q_off) + friction, and its delta-method statistics.

    `cov = s² (JᵀJ)⁻¹` with J the Jacobian of the residual at the solution
    (scipy.optimize.least_squares), s² = RSS / (r − p_total). Intervals are
    value ± t_{dof, 1−α/2} · std (Student t with dof = r − p_total, which is
    the normal interval for large r).
    """

    names: list
    value: np.ndarray
    cov: np.ndarray
    s: float
    rss: float
    n_rows: int
    jtj: np.ndarray
    nfev: int
    method: str = "NLS (delta method)"

    @property
    def dof(self) -> int:
        return self.n_rows - len(self.names)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    @property
    def rel_sigma(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.sigma / np.abs(self.value)

    def interval(self, level: float = 0.95) -> np.ndarray:
        """(p, 2) delta-method intervals."""
        t = stats.t.ppf(0.5 + level / 2.0, self.dof)
        return np.stack([self.value - t * self.sigma, self.value + t * self.sigma], axis=1)

    def ellipse(self, i: int = 0, j: int = 1, level: float = 0.95, n: int = 181) -> np.ndarray:
        """(n, 2) boundary of the delta-method region of (θ_i, θ_j): Δᵀ C⁻¹ Δ = χ²₂(level)."""
        C = self.cov[np.ix_([i, j], [i, j])]
        r2 = stats.chi2.ppf(level, 2)
        w, V = np.linalg.eigh(C)
        t = np.linspace(0.0, 2.0 * np.pi, n)
        circle = np.stack([np.cos(t), np.sin(t)], axis=1) * np.sqrt(r2 * np.maximum(w, 0.0))
        return self.value[[i, j]] + circle @ V.T

    def to_dict(self):
        return json_safe({"method": self.method, "names": self.names, "value": self.value,
                          "std": self.sigma, "cov": self.cov, "s": self.s, "rss": self.rss,
                          "n_rows": self.n_rows, "dof": self.dof})


def _gravity_stats(q, qd, tau, friction, ref=None):
    Phi = _gravity_regressor(q, qd, friction)
    names = ["a_sin", "a_cos"] + list(friction)
    return sufficient_statistics(Phi[:, None, :], tau[:, None], names, ref=ref)


def fit_gravity_ls(q, qd, tau, *, row_mask=None, friction=("Fv", "Fc", "offset")) -> GravityLSResult:
    """Nonlinear LS of (k, q_off, friction) with scipy.optimize.least_squares (method 'lm').

    Started from the exact linear LS in (a, c) = (k cos q_off, k sin q_off)
    (so it cannot fall in a local minimum); k > 0 and q_off ∈ (−π, π] at the
    solution. The delta-method covariance uses the returned Jacobian.
    """
    q, qd, tau, friction = _gravity_inputs(q, qd, tau, row_mask, friction)
    p = 2 + len(friction)
    if q.size <= p:
        raise IdentificationError(f"{q.size} rows for {p} parameters")
    st = _gravity_stats(q, qd, tau, friction)
    lin, _ = st.ls()
    a, c = lin[:2]
    x0 = np.concatenate([[math.hypot(a, c), math.atan2(c, a)], lin[2:]])
    Phi = _gravity_regressor(q, qd, friction)[:, 2:]

    def resid(x):
        return tau - x[0] * np.sin(q + x[1]) - Phi @ x[2:]

    def jac(x):
        J = np.empty((q.size, p))
        J[:, 0] = -np.sin(q + x[1])
        J[:, 1] = -x[0] * np.cos(q + x[1])
        J[:, 2:] = -Phi
        return J

    sol = optimize.least_squares(resid, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x = sol.x.copy()
    if x[0] < 0:
        x[0], x[1] = -x[0], x[1] + np.pi
    x[1] = math.remainder(x[1], 2 * math.pi)
    J = jac(x)
    rss = float(resid(x) @ resid(x))
    dof = q.size - p
    # (JᵀJ)⁻¹ through the SVD of J (never forms JᵀJ for the inverse)
    _, sv, Vt = np.linalg.svd(J, full_matrices=False)
    if sv[-1] <= 1e-12 * sv[0]:
        raise IdentificationError("the Jacobian of the gravity model is rank-deficient at the LS "
                                  "solution: k, q_off and the friction terms are not identifiable "
                                  "from these data (excite the joint over a wider range)")
    cov_u = (Vt.T / sv**2) @ Vt
    s2 = rss / dof
    return GravityLSResult(names=["k", "q_off", *friction], value=x, cov=s2 * cov_u, s=math.sqrt(s2),
                           rss=rss, n_rows=int(q.size), jtj=J.T @ J, nfev=int(sol.nfev))


class GravityPosterior:
    """Log-posterior of the gravity model (see the module docstring), vectorised over walkers."""

    def __init__(self, stats: SufficientStats, friction, q_off_centre: float,
                 marginalize: bool = True, k_max: float = np.inf):
        self.stats = stats
        self.friction = list(friction)
        self.marginalize = bool(marginalize)
        self.lo = q_off_centre - np.pi
        self.hi = q_off_centre + np.pi
        self.k_max = float(k_max)
        G, g, s = stats.G[0], stats.g[0], float(stats.s[0])
        self.r = int(stats.rows[0])
        self.p = len(self.friction)
        a, bb = slice(0, 2), slice(2, 2 + self.p)
        self._G, self._g, self._s = G, g, s
        if self.p:
            cf = _cho(G[bb, bb], self.friction, "ΦᵀΦ of the friction terms")
            self._Gbb_cf = cf
            self._H = sla.cho_solve(cf, G[bb, a])                # G_bb⁻¹ G_ba  (p, 2)
            self._hb = sla.cho_solve(cf, g[bb])                   # G_bb⁻¹ g_b
            self._schur = G[a, a] - G[a, bb] @ self._H
            self._ga = g[a] - G[a, bb] @ self._hb
            self._s0 = s - g[bb] @ self._hb
            self._Lbb = np.linalg.cholesky(sla.cho_solve(cf, np.eye(self.p)))
        else:
            self._schur, self._ga, self._s0 = G[a, a], g[a], s
        self.names = ["k", "q_off", *self.friction, "sigma"]
        self.coords = ["k", "q_off"] + ([] if self.marginalize else [*self.friction, "log_sigma"])
        self.ndim = len(self.coords)

    def _ac_delta(self, X):
        k, qo = X[:, 0], X[:, 1]
        return np.stack([k * np.cos(qo), k * np.sin(qo)], axis=1) - self.stats.ref[:2]

    def rss_beta(self, X) -> np.ndarray:
        """RSS minimised over the friction terms, at (k, q_off) = X[:, :2]."""
        D = self._ac_delta(np.atleast_2d(X))
        return self._s0 - 2.0 * D @ self._ga + np.einsum("ki,ij,kj->k", D, self._schur, D)

    def in_support(self, X):
        return (X[:, 0] > 0) & (X[:, 0] < self.k_max) & (X[:, 1] > self.lo) & (X[:, 1] <= self.hi)

    def log_prob(self, X) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        ok = self.in_support(X)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.marginalize:
                R = np.maximum(self.rss_beta(X), 1e-300)
                lp = -0.5 * (self.r - self.p) * np.log(R)
            else:
                D = np.concatenate([self._ac_delta(X), X[:, 2:2 + self.p] - self.stats.ref[2:]], axis=1)
                S = self._s - 2.0 * D @ self._g + np.einsum("ki,ij,kj->k", D, self._G, D)
                u = X[:, -1]
                lp = -self.r * u - 0.5 * S * np.exp(-2.0 * u)
        lp = np.where(ok & np.isfinite(lp), lp, -np.inf)
        return lp

    __call__ = log_prob

    def complete(self, X, rng) -> np.ndarray:
        """Reported parameters (k, q_off, friction, σ) for sampled states `X` (..., ndim).

        Marginalised model: σ and β drawn exactly from their conditionals.
        """
        X = np.asarray(X, dtype=float)
        shape = X.shape[:-1]
        Xf = X.reshape(-1, X.shape[-1])
        out = np.empty((Xf.shape[0], len(self.names)))
        out[:, :2] = Xf[:, :2]
        if not self.marginalize:
            out[:, 2:2 + self.p] = Xf[:, 2:2 + self.p]
            out[:, -1] = np.exp(Xf[:, -1])
            return out.reshape(*shape, -1)
        R = np.maximum(self.rss_beta(Xf), 1e-300)
        nu = self.r - self.p
        sig2 = R / rng.chisquare(nu, size=R.size)
        out[:, -1] = np.sqrt(sig2)
        if self.p:
            D = self._ac_delta(Xf)
            beta_hat = self.stats.ref[2:] + self._hb - D @ self._H.T
            z = rng.standard_normal((Xf.shape[0], self.p))
            out[:, 2:2 + self.p] = beta_hat + np.sqrt(sig2)[:, None] * (z @ self._Lbb.T)
        return out.reshape(*shape, -1)


def sample_gravity(q, qd, tau, *, row_mask=None, friction=("Fv", "Fc", "offset"), marginalize=True,
                   ls: GravityLSResult | None = None, seed=0, n_walkers=None, criteria=None,
                   max_steps=None, max_seconds=None, moves="de", init_scale: float = 0.1,
                   truth=None, joint_label: str = "joint") -> PosteriorResult:
    """Posterior of (k, q_off, friction, σ) of the per-joint gravity model (module docstring).

    `marginalize=True` samples (k, q_off) only and draws the friction terms
    and σ exactly from their conditionals at every stored state (so they also
    get τ and R̂; the convergence rule is applied to the sampled (k, q_off)).
    Returns a `PosteriorResult` whose LS columns are the delta-method
    values of `fit_gravity_ls` (`ls_cov` holds its covariance).
    """
    rng = _rng(seed)
    qm, qdm, taum, friction = _gravity_inputs(q, qd, tau, row_mask, friction)
    if ls is None:
        ls = fit_gravity_ls(qm, qdm, taum, friction=friction)
    elif list(ls.names) != ["k", "q_off", *friction]:
        raise InputError(f"ls is a fit of {ls.names}, but the model has k, q_off and {list(friction)}")
    a_ref = ls.value[0] * np.array([np.cos(ls.value[1]), np.sin(ls.value[1])])
    ref = np.concatenate([a_ref, ls.value[2:]])
    st = _gravity_stats(qm, qdm, taum, friction, ref=ref)
    st.data_hash = data_hash(qm, qdm, taum)
    model = GravityPosterior(st, friction, q_off_centre=float(ls.value[1]), marginalize=marginalize)
    d = model.ndim
    nw = _n_walkers(n_walkers, d)
    p_all = 2 + len(friction)
    if marginalize:
        centre, cov = ls.value[:2].copy(), ls.cov[:2, :2]
    else:
        centre = np.concatenate([ls.value, [math.log(ls.s)]])
        cov = np.zeros((d, d))
        cov[:p_all, :p_all] = ls.cov
        cov[-1, -1] = 1.0 / (2.0 * st.rows[0])
    crit = _criteria(criteria, max_steps=max_steps, max_seconds=max_seconds)
    p0 = _initial_ball(model.log_prob, centre, cov, nw, init_scale, rng)
    sampler = _sampler(model.log_prob, nw, d, moves, rng)
    sampled = np.zeros(len(model.names), dtype=bool)
    sampled[:2] = True
    if not marginalize:
        sampled[:] = True
    run = run_until_converged(sampler, p0, crit)
    # reported coordinates at every stored state; diagnostics for all of them
    full = model.complete(run.stored, rng)
    dg0 = run.diagnostics
    dg = diagnose(full, run.interval, dg0.n_steps, dg0.acceptance * dg0.n_steps, crit, sampled=sampled,
                  limit=dg0.limit, history=dg0.history, elapsed=dg0.elapsed)
    if dg.converged != dg0.converged:  # cannot happen: same sampled coordinates, same rule
        raise AssertionError("convergence verdict changed when adding derived parameters")
    run.stored, run.diagnostics = full, dg
    chain = run.kept()
    ls_value = np.concatenate([ls.value, [ls.s]])
    ls_std = np.concatenate([ls.sigma, [np.nan]])
    ls_cov = np.full((len(model.names),) * 2, np.nan)
    ls_cov[:p_all, :p_all] = ls.cov
    settings = {
        "model": f"gravity + friction of {joint_label}: tau = k sin(q + q_off) + "
                 + " + ".join({"Fv": "Fv qd", "Fc": "Fc sign(qd)", "offset": "offset"}[f] for f in friction),
        "reference": "Bona & Curatella (2005) eq. (23); friction as their eq. (22)",
        "priors": "flat on k > 0 and q_off in (q_off_LS - pi, q_off_LS + pi]; flat on friction; "
                  "Jeffreys on sigma",
        "linear_parameters": ("marginalised analytically (friction and sigma drawn from their exact "
                              "conditionals)" if marginalize else "sampled jointly with (k, q_off, log sigma)"),
        "sampler": "emcee.EnsembleSampler(vectorize=True)",
        "moves": _describe_moves(moves),
        "n_walkers": nw,
        "init": f"NLS estimate + {init_scale:g} x N(0, cov_delta)",
        "seed": seed if isinstance(seed, (int, np.integer)) else "numpy Generator",
        "n_rows": int(st.rows[0]),
        "sufficient_statistics": "Gram of [sin q, cos q, friction regressors, tau] about the NLS solution",
    }
    return PosteriorResult(
        method="emcee", model=settings["model"], names=model.names, chain=chain, diagnostics=dg,
        ls_value=ls_value, ls_std=ls_std, ls_cov=ls_cov, ls_label=ls.method, settings=settings,
        truth=truth, data_hash=st.data_hash, coords=model.coords, reference=ls)


def simulate_gravity_joint(n: int = 400, *, q_centre: float = 0.0, q_amplitude: float = 1.5,
                           k: float = 12.0, q_off: float = 0.4, Fv: float = 0.8, Fc: float = 0.6,
                           offset: float = 0.2, sigma: float = 0.3, cycles: float = 2.0, seed=0):
    """A simulated per-joint gravity experiment: (q, qd, tau, truth dict).

    q(t) = q_centre + q_amplitude · sin(2π cycles t / T) (+ a small second
    harmonic), qd its derivative, tau = k sin(q + q_off) + Fv qd + Fc sign(qd)
    + offset + N(0, σ²). A small `q_amplitude` gives the poorly excited case.
    """
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n, endpoint=False) + 0.5 / n
    w = 2 * np.pi * cycles
    q = q_centre + q_amplitude * (np.sin(w * t) + 0.15 * np.sin(2 * w * t + 0.7))
    qd = q_amplitude * w * (np.cos(w * t) + 0.3 * np.cos(2 * w * t + 0.7))
    tau = k * np.sin(q + q_off) + Fv * qd + Fc * np.sign(qd) + offset + sigma * rng.standard_normal(n)
    truth = {"k": k, "q_off": q_off, "Fv": Fv, "Fc": Fc, "offset": offset, "sigma": sigma}
    return q, qd, tau, truth


# ============================================================ results
@dataclass(eq=False)
class PosteriorResult(ParameterResults):
    """Posterior samples and summaries, beside the LS estimate, with convergence diagnostics.

    Attributes
    ----------
    names : list[str]
        Reported parameters (σ_j as `sigma<j>`).
    chain : ndarray (n_walkers, n_draws, d)
        Draws after burn-in, thinned by ≈ τ/2 (diagnostics.burn_in, .thin).
    samples : ndarray (n_walkers · n_draws, d)
        `chain` flattened (walker-major).
    mean, median, std : (d,)
    ci95, ci999 : (d, 2)
        Equal-tailed 95 % and 99.9 % credible intervals (sample quantiles).
    corr : (d, d)
        Posterior correlation matrix.
    ls_value, ls_std, ls_rel_std : (d,)
        LS estimate (NaN where it has none), its σ and %σ (eq. (15)).
    diagnostics : ChainDiagnostics
        τ, R̂, acceptance, n_steps, converged and the reason.
    """

    method: str
    model: str
    names: list
    chain: np.ndarray
    diagnostics: ChainDiagnostics
    ls_value: np.ndarray
    ls_std: np.ndarray
    ls_cov: np.ndarray | None = None
    ls_label: str = "LS"
    settings: dict = field(default_factory=dict)
    truth: dict | None = None
    data_hash: str | None = None
    coords: list | None = None
    reference: object = None
    notices: list = field(default_factory=list)

    def __post_init__(self):
        self.names = [str(x) for x in self.names]
        self.chain = np.asarray(self.chain, dtype=float)
        d = len(self.names)
        if self.chain.ndim != 3 or self.chain.shape[2] != d:
            raise ValueError(f"chain must be (n_walkers, n_draws, {d}), got {self.chain.shape}")
        self.samples = self.chain.reshape(-1, d)
        S = self.samples
        self.mean = S.mean(axis=0)
        self.median = np.median(S, axis=0)
        self.std = S.std(axis=0, ddof=1) if S.shape[0] > 1 else np.full(d, np.nan)
        self.ci95 = np.quantile(S, [0.025, 0.975], axis=0).T
        self.ci999 = np.quantile(S, [0.0005, 0.9995], axis=0).T
        with np.errstate(divide="ignore", invalid="ignore"):
            self.corr = np.corrcoef(S.T) if S.shape[0] > 1 else np.full((d, d), np.nan)
            self.ls_value = np.asarray(self.ls_value, dtype=float)
            self.ls_std = np.asarray(self.ls_std, dtype=float)
            self.ls_rel_std = 100.0 * self.ls_std / np.abs(self.ls_value)
        self.corr = np.atleast_2d(self.corr)
        if not self.converged and not any("NOT CONVERGED" in n for n in self.notices):
            self.notices.insert(0, self.diagnostics.reason)

    # ------------------------------------------------------------ access
    @property
    def converged(self) -> bool:
        return bool(self.diagnostics.converged)

    @property
    def reason(self) -> str:
        return self.diagnostics.reason

    @property
    def tau(self) -> np.ndarray:
        return self.diagnostics.tau

    @property
    def rhat(self) -> np.ndarray:
        return self.diagnostics.rhat

    @property
    def acceptance(self) -> float:
        return self.diagnostics.acceptance_mean

    @property
    def n_steps(self) -> int:
        return self.diagnostics.n_steps

    @property
    def ess(self) -> np.ndarray:
        return self.diagnostics.ess()

    @property
    def n_samples(self) -> int:
        return self.samples.shape[0]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no parameter {name!r}; parameters: {', '.join(self.names)}") from None

    def __getitem__(self, name: str) -> np.ndarray:
        """Samples of parameter `name`."""
        return self.samples[:, self.index(name)]

    def interval(self, level: float) -> np.ndarray:
        """(d, 2) equal-tailed credible intervals at `level`.

        Returns
        -------
        numpy.ndarray
            (d, 2): lower and upper bound per parameter.
        """
        a = (1.0 - level) / 2.0
        return np.quantile(self.samples, [a, 1.0 - a], axis=0).T

    def mc_stderr(self) -> np.ndarray:
        """Monte-Carlo standard error of the posterior mean: std / √ESS.

        Returns
        -------
        numpy.ndarray
            (d,) in the parameters' units.
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.std / np.sqrt(self.ess)

    # the shared interface: posterior mean, sample covariance, equal-tailed credible intervals
    def _estimate(self):
        return self.mean

    @property
    def cov(self):
        if self.samples.shape[0] < 2:
            return np.full((len(self.names),) * 2, np.nan)
        return np.atleast_2d(np.cov(self.samples, rowvar=False, ddof=1))

    def conf_int(self, alpha: float = 0.05) -> pd.DataFrame:
        """Equal-tailed (1 − alpha) credible interval from the draws: columns `lower`, `upper`.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `lower` and `upper`.
        """
        _check_alpha(alpha)
        lo, hi = np.quantile(self.samples, [alpha / 2.0, 1.0 - alpha / 2.0], axis=0)
        return pd.DataFrame({"lower": lo, "upper": hi}, index=self._index())

    def __repr__(self):
        flag = "converged" if self.converged else "NOT CONVERGED"
        return (f"<PosteriorResult {self.model}: {len(self.names)} parameters, {self.n_samples} draws, "
                f"{self.n_steps} steps, {flag}>")

    # ------------------------------------------------------------ presentation
    def to_frame(self) -> pd.DataFrame:
        """One row per parameter: posterior summaries, LS value/σ/%σ, τ, ESS, R̂.

        Returns
        -------
        pandas.DataFrame
            One row per parameter.
        """
        dg = self.diagnostics
        sampled = dg.sampled if dg.sampled.size == len(self.names) else np.ones(len(self.names), bool)
        df = pd.DataFrame({
            "mean": self.mean, "median": self.median, "std": self.std,
            "rel_std_percent": self.rel_std.to_numpy(),
            "ci95_low": self.ci95[:, 0], "ci95_high": self.ci95[:, 1],
            "ci999_low": self.ci999[:, 0], "ci999_high": self.ci999[:, 1],
            "ls_value": self.ls_value, "ls_std": self.ls_std, "ls_rel_std_percent": self.ls_rel_std,
            "tau": dg.tau, "ess": self.ess, "rhat": dg.rhat, "sampled": sampled,
        }, index=pd.Index(self.names, name="parameter"))
        if self.truth:
            df["truth"] = [self.truth.get(n, np.nan) for n in self.names]
        return df

    def summary(self) -> str:
        dg = self.diagnostics
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        flag = "CONVERGED" if self.converged else "NOT CONVERGED - do not use these intervals"
        lines = [f"Posterior ({self.method}): {self.model}".center(_WIDTH), rule,
                 f"Status: {flag}", f"  {dg.reason}",
                 f"Walkers {dg.n_walkers}   steps {dg.n_steps}   burn-in {dg.burn_in}   thin {dg.thin}   "
                 f"draws {self.n_samples}",
                 f"max tau {dg.tau_max:.4g} steps   chain/tau {dg.chain_over_tau:.1f} "
                 f"(rule >= {dg.criteria.tau_multiple:g})   max split R-hat {dg.rhat_max:.4f} "
                 f"(< {dg.criteria.rhat_max:g})   acceptance {dg.acceptance_mean:.3f}",
                 thin,
                 f"{'Parameter':<12}{'mean':>12}{'std':>11}{'95% low':>12}{'95% high':>12}"
                 f"{self.ls_label[:11]:>12}{'LS %sig':>9}{'tau':>8}{'R-hat':>8}", thin]
        for i, n in enumerate(self.names):
            lines.append(f"{n[:12]:<12}{_g(self.mean[i]):>12}{_g(self.std[i]):>11}{_g(self.ci95[i, 0]):>12}"
                         f"{_g(self.ci95[i, 1]):>12}{_g(self.ls_value[i]):>12}{_pct(self.ls_rel_std[i]):>9}"
                         f"{_g(dg.tau[i], 3):>8}{dg.rhat[i]:>8.4f}")
        lines.append(rule)
        if self.notices:
            lines.append("Notices:")
            lines += [f"[{i}] {t}" for i, t in enumerate(self.notices, 1)]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-safe and deterministic for a given seed (no timings).

        Returns
        -------
        dict
            JSON-safe.
        """
        params = []
        for i, n in enumerate(self.names):
            params.append({
                "name": n, "mean": self.mean[i], "median": self.median[i], "std": self.std[i],
                "ci95": self.ci95[i], "ci999": self.ci999[i],
                "ls_value": self.ls_value[i], "ls_std": self.ls_std[i],
                "ls_rel_std_percent": self.ls_rel_std[i],
                "tau": self.diagnostics.tau[i], "ess": self.ess[i], "rhat": self.diagnostics.rhat[i],
                "truth": None if not self.truth else self.truth.get(n),
            })
        return json_safe({
            "method": self.method,
            "model": self.model,
            "converged": self.converged,
            "reason": self.reason,
            "settings": self.settings,
            "ls_method": self.ls_label,
            "parameters": params,
            "correlation": self.corr,
            "n_draws": self.n_samples,
            "sampled_coordinates": self.coords,
            "diagnostics": self.diagnostics.to_dict(),
            "notices": self.notices,
            "data_hash": self.data_hash,
            "versions": versions(),
        })


    def samples_frame(self) -> pd.DataFrame:
        nw, nd, _ = self.chain.shape
        df = pd.DataFrame(self.samples, columns=self.names)
        df.insert(0, "draw", np.tile(np.arange(nd), nw))
        df.insert(0, "walker", np.repeat(np.arange(nw), nd))
        return df

    def draws_to_csv(self, path) -> None:
        """The kept draws, one row each: walker, draw, then the parameters (full precision).

        Returns
        -------
        None
            The file is written whole or not at all.
        """
        atomic_write_text(path, self.samples_frame().to_csv(index=False, lineterminator="\n",
                                                            float_format="%.17g"))

    def _dataset(self):
        try:
            import xarray as xr
        except ImportError:
            raise MissingDependencyError(
                "to_netcdf needs the optional package xarray (pip install xarray); "
                "draws_to_csv() and to_json() work without it") from None
        nw, nd, _ = self.chain.shape
        data = {n: (("chain", "draw"), self.chain[:, :, i]) for i, n in enumerate(self.names)}
        ds = xr.Dataset(data, coords={"chain": np.arange(nw), "draw": np.arange(nd)})
        # netCDF attributes: no booleans, and plain ASCII for the classic (scipy) format
        ds.attrs.update({"model": _ascii(self.model), "converged": int(self.converged),
                         "reason": _ascii(self.reason), "n_steps": self.n_steps,
                         "burn_in": self.diagnostics.burn_in, "thin": self.diagnostics.thin,
                         "inference_library": "emcee"})
        return ds

    def to_netcdf(self, path) -> None:
        """Write the draws (chain = walker, draw) as netCDF via xarray (optional dependency).

        Returns
        -------
        None
            The file is written whole or not at all.
        """
        from dynid.outputs import staged_path
        ds = self._dataset()
        with staged_path(path) as tmp:
            ds.to_netcdf(tmp)

    def to_inference_data(self):
        """An arviz.InferenceData (optional dependency arviz); chains are the walkers.

        Returns
        -------
        arviz.InferenceData
            The posterior group, one chain per walker.
        """
        try:
            import arviz as az
        except ImportError:
            raise MissingDependencyError(
                "to_inference_data needs the optional package arviz (pip install arviz); "
                "the draws are in .chain (n_walkers, n_draws, d) and draws_to_csv() writes them") from None
        posterior = {n: self.chain[:, :, i] for i, n in enumerate(self.names)}
        attrs = {"model": self.model, "converged": int(self.converged), "reason": self.reason,
                 "inference_library": "emcee"}
        try:
            return az.from_dict(posterior=posterior, attrs=attrs)
        except TypeError:                      # arviz >= 1.0: from_dict({group: {var: array}})
            return az.from_dict({"posterior": posterior}, attrs=attrs)


_ASCII = {"τ": "tau", "≥": ">=", "≤": "<=", "R̂": "R-hat", "σ": "sigma", "χ": "chi", "π": "pi",
          "—": "-", "–": "-", "·": "*", "±": "+/-", "²": "^2", "ᵀ": "'", "⁻¹": "^-1"}


def _ascii(text: str) -> str:
    for k, v in _ASCII.items():
        text = text.replace(k, v)
    return text.encode("ascii", "replace").decode("ascii")


def _g(x, digits=5) -> str:
    x = float(x)
    if not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return f"{x:.{digits}g}"


def _pct(x) -> str:
    x = float(x)
    return f"{x:.2f}" if math.isfinite(x) else "-"
