"""The posterior of a linear model Y = Wχ + ρ: priors, log-density and closed forms.

See dynid.analysis.sampling.posterior for the model (Gaussian likelihood per
joint, Jeffreys prior on σ_j, flat or Gaussian prior on χ) and for the two
closed forms that check the sampler (known σ: Gaussian; one joint with
unknown σ: Student t).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy import stats

from dynid.analysis.sampling.sufficient import SufficientStats, cholesky
from dynid.errors import IdentificationError, InputError
from dynid.provenance import json_safe


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
        self._g2 = 2.0 * self._g                    # exact: a power of two
        self._s = stats.s[self.active]
        self._r = stats.rows[self.active].astype(float)
        # S_j cannot fall by nine orders of magnitude below its value at the least-squares estimate
        # (noise keeps every fit's residual near it). Far out along a direction G hardly sees (an
        # ill-conditioned recording) the expanded form s - 2 d'g + d'G d cancels terms of 1e20 and
        # can come out at 1e-296, where the density is unbounded (sigma -> 0): outside the support.
        self._floor = 1e-9 * self._s
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
        DG -= self._g2
        S = np.einsum("kjb,kb->kj", DG, D)
        S += self._s
        return S

    def _log_prior(self, X):
        if self.prior is None:
            return 0.0
        E = X[:, self._pidx] - self._pmean
        return -0.5 * np.einsum("ki,ij,kj->k", E, self._pprec, E)

    def log_prob(self, X) -> np.ndarray:
        """log p (up to a constant) of each row of `X` (K, ndim); −inf outside the support."""
        if type(X) is not np.ndarray or X.ndim != 2 or X.dtype != np.float64:
            X = np.atleast_2d(np.asarray(X, dtype=float))
        chi = X[:, : self.b]
        D = chi - self.stats.ref
        S = self._S(D)
        # the sampler calls this twice a step: sums as np.add.reduce (what .sum calls), no
        # prior term when there is none (adding 0.0 changes no comparison), NaN -> -inf in place
        with np.errstate(over="ignore", invalid="ignore"):
            if self.sigma is not None:
                lp = -0.5 * np.add.reduce(S / self.sigma[self.active] ** 2, axis=1)
            else:
                u = X[:, self.b:]
                lp = -(u @ self._r) - 0.5 * np.add.reduce(S * np.exp(-2.0 * u), axis=1)
            if self.prior is not None:
                lp = lp + self._log_prior(chi)
        lp[np.isnan(lp)] = -np.inf
        lp[np.any(S < self._floor, axis=1)] = -np.inf
        return lp

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
    cf = cholesky(Lam, stats.names, "The posterior precision Σ G_j/σ_j²")
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
    cf = cholesky(G, stats.names, "WᵀW")
    Ginv = sla.cho_solve(cf, np.eye(b))
    delta = sla.cho_solve(cf, g)
    rss = float(s - g @ delta)
    df = r - b
    scale = np.sqrt(rss / df * np.diag(Ginv))
    return StudentTPosterior(names=list(stats.names), loc=stats.ref + delta, scale=scale, df=df,
                             rss=rss, cov_unscaled=Ginv)


