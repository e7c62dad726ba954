"""The posterior's result: draws, summaries beside the LS estimate, diagnostics and exports."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.results import ParameterResults, _check_alpha, notices_block, parameter_table
from dynid.analysis.sampling.convergence import ChainDiagnostics
from dynid.outputs import atomic_write_text, staged_path
from dynid.provenance import json_safe, versions


class MissingDependencyError(ImportError):
    """An optional package (xarray, arviz) is needed for this export."""



_WIDTH = 100


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
    def noise_model(self) -> str:
        """The likelihood's noise model ("sandwich", "neff", "white"; see dynid.analysis.sampling.noise)."""
        return str((self.settings.get("noise_model") or {}).get("kind", "white"))

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

    def draws(self, name: str) -> np.ndarray:
        """The draws of parameter `name` (`r[name]` is its record, as for every result).

        Returns
        -------
        numpy.ndarray
            (n_samples,) in the parameter's unit.
        """
        return self.samples[:, self.index(name)]

    def interval(self, level: float) -> np.ndarray:
        """Deprecated: `conf_int(alpha=1 - level)` (the same equal-tailed quantiles).

        Returns
        -------
        numpy.ndarray
            (d, 2): lower and upper bound per parameter.
        """
        warnings.warn("PosteriorResult.interval(level) is deprecated and will be removed in the next release; "
                      "use conf_int(alpha=1 - level) (a DataFrame; .to_numpy() for the (d, 2) array)",
                      DeprecationWarning, stacklevel=2)
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
    def bse(self) -> pd.Series:
        """The posterior standard deviation of each parameter (`std`, the draws' own: the JSON's and
        the table's to the last digit; the diagonal of `cov` computes it in another order)."""
        return pd.Series(np.asarray(self.std, dtype=float), index=self._index(), name="std")

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
            "value": self.mean,          # the interface's estimate (the posterior mean)
            "mean": self.mean, "median": self.median, "std": self.std,
            "rel_std_percent": self.rel_std.to_numpy(), "unit": self._units(),
            "ci95_low": self.ci95[:, 0], "ci95_high": self.ci95[:, 1],
            "ci999_low": self.ci999[:, 0], "ci999_high": self.ci999[:, 1],
            "ls_value": self.ls_value, "ls_std": self.ls_std, "ls_rel_std_percent": self.ls_rel_std,
            "tau": dg.tau, "ess": self.ess, "rhat": dg.rhat, "sampled": sampled,
        }, index=pd.Index(self.names, name="parameter"))
        if self.truth:
            df["truth"] = [self.truth.get(n, np.nan) for n in self.names]
        return df

    def _optimum_lines(self) -> list:
        """Where the sandwich was matched, when not at the LS estimate (noise_model.joint_optimum)."""
        opt = (self.settings.get("noise_model") or {}).get("joint_optimum")
        if not opt:
            return []
        fmt = ", ".join
        return [f"  matched at the likelihood's joint optimum, where the sampled sigma_j settle: sigma* "
                f"{fmt(f'{v:.4g}' for v in opt['sigma'])} (eq. (16): {fmt(f'{v:.4g}' for v in opt['sigma_eq16'])})"]

    def summary(self) -> str:
        dg = self.diagnostics
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        flag = "CONVERGED" if self.converged else "NOT CONVERGED - do not use these intervals"
        lines = [f"Posterior ({self.method}): {self.model}".center(_WIDTH), rule,
                 f"Status: {flag}", f"  {dg.reason}",
                 f"Noise model: {(self.settings.get('noise_model') or {}).get('description', 'white')}",
                 *self._optimum_lines(),
                 f"Walkers {dg.n_walkers}   steps {dg.n_steps}   burn-in {dg.burn_in}   thin {dg.thin}   "
                 f"draws {self.n_samples}",
                 f"max tau {dg.tau_max:.4g} steps   chain/tau {dg.chain_over_tau:.1f} "
                 f"(rule >= {dg.criteria.tau_multiple:g})   max split R-hat {dg.rhat_max:.4f} "
                 f"(< {dg.criteria.rhat_max:g})   acceptance {dg.acceptance_mean:.3f}",
                 thin]
        lines += parameter_table(self.names, [
            ("mean", self.mean, _g), ("std", self.std, _g), ("95% low", self.ci95[:, 0], _g),
            ("95% high", self.ci95[:, 1], _g), (self.ls_label[:11], self.ls_value, _g),
            ("LS %sig", self.ls_rel_std, _pct), ("tau", dg.tau, lambda x: _g(x, 3)),
            ("R-hat", dg.rhat, lambda x: f"{x:.4f}")], prismatic=self._prismatic())
        lines.append(rule)
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-safe and deterministic for a given seed (no timings).

        Returns
        -------
        dict
            JSON-safe.
        """
        params, units = [], self._units()
        for i, n in enumerate(self.names):
            params.append({
                "name": n, "value": self.mean[i], "mean": self.mean[i], "median": self.median[i],
                "std": self.std[i], "rel_std_percent": float(self.rel_std.to_numpy()[i]), "unit": units[i],
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
            "noise_model": self.noise_model,
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
        """The kept draws, one row each: walker, draw, then the parameters (full precision)."""
        atomic_write_text(path, self.samples_frame().to_csv(index=False, lineterminator="\n",
                                                            float_format="%.17g"))

    def _dataset(self):
        try:
            import xarray as xr  # optional extra "arviz"
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
        """Write the draws (chain = walker, draw) as netCDF via xarray (optional dependency)."""
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
            import arviz as az  # optional extra "arviz"
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

