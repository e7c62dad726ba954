"""Results of an identification, modelled on statsmodels' results classes.

`ParameterResults` is the one interface every estimator's result has
(IDIM, DIDIM, the Projection Method, maximum likelihood, the posterior, the
per-joint models): `method`, `names`, `params` (a pandas Series),
`bse`, `rel_std` (%σ, eq. (15)), `cov`, `conf_int(alpha)`,
`summary()`, `to_frame()`, `to_dict()`, `to_json(path)` and
`to_csv(path)`. Method-specific extras stay attributes of each class.

`IdentificationResult` holds the estimate χ̂ (eq. (11)), its covariance
(eq. (14)), standard deviations and relative standard deviations (eq. (15)),
and the residual statistics, and knows how to print, tabulate and save itself.
Estimators in `dynid.analysis.estimators.least_squares` build it; users only read it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.errors import InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import dumps_json, json_safe, versions

__all__ = ["Exportable", "ParameterResults", "ModelResults", "IdentificationResult"]

_WIDTH = 78


class Exportable:
    """`to_json(path)` and `str()` of any result with `to_dict()` and `summary()`."""

    def to_json(self, path: str | os.PathLike) -> None:
        """Write `to_dict` as JSON to `path` atomically (all or nothing)."""
        # Serialise first: a failure here must not even create the temporary file.
        text = dumps_json(self.to_dict())
        atomic_write_text(path, text)

    def __str__(self) -> str:
        return self.summary()


class ParameterResults(Exportable):
    """The interface shared by every result (a mixin; it holds no data of its own).

    A class using it has `method` (str), `names` (list of parameter names),
    `cov` (ndarray (p, p), the covariance of the estimate), `summary()` and
    `to_dict()`, and says what its estimate is by `_estimate`
    (default: the attribute `chi`). Intervals are normal by default;
    `_interval_quantile` and `conf_int` are overridden where the
    estimate's distribution is another (Student for repeated experiments,
    sample quantiles for a posterior).
    """

    def _estimate(self) -> np.ndarray:
        return np.asarray(self.chi, dtype=float)

    def _index(self) -> pd.Index:
        return pd.Index(list(self.names), name="parameter")

    @property
    def n_params(self) -> int:
        """The number of estimated parameters."""
        return len(self.names)

    @property
    def params(self) -> pd.Series:
        """The estimate, by parameter name (SI units of each parameter)."""
        return pd.Series(self._estimate(), index=self._index(), name=self.method)

    @property
    def bse(self) -> pd.Series:
        """Standard errors sqrt(diag(cov)) (rounding below 0 is clipped)."""
        var = np.maximum(np.diag(np.asarray(self.cov, dtype=float)), 0.0)
        return pd.Series(np.sqrt(var), index=self._index(), name="std")

    @property
    def rel_std(self) -> pd.Series:
        """Relative standard deviations %σ = 100 σ / |χ̂| (eq. (15)); inf where χ̂ = 0 < σ."""
        with np.errstate(divide="ignore", invalid="ignore"):
            values = 100.0 * self.bse.to_numpy() / np.abs(self._estimate())
        return pd.Series(values, index=self._index(), name="rel_std_percent")

    def cov_params(self) -> pd.DataFrame:
        """The covariance as a labelled table (statsmodels' name).

        Returns
        -------
        pandas.DataFrame
            (p, p) covariance, rows and columns labelled by parameter name.
        """
        index = self._index()
        return pd.DataFrame(np.asarray(self.cov, dtype=float), index=index, columns=list(index))

    def _interval_quantile(self, alpha: float) -> float:
        from scipy import stats
        return float(stats.norm.ppf(1.0 - alpha / 2.0))

    def conf_int(self, alpha: float = 0.05) -> pd.DataFrame:
        """Two-sided (1 − alpha) interval per parameter: columns `lower` and `upper`.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `lower` and `upper` (the parameter's unit).
        """
        _check_alpha(alpha)
        half = self._interval_quantile(alpha) * self.bse.to_numpy()
        value = self._estimate()
        return pd.DataFrame({"lower": value - half, "upper": value + half}, index=self._index())

    def to_frame(self) -> pd.DataFrame:
        """Table of the parameters: index = names, columns value, std, rel_std_percent.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `value`, `std` and `rel_std_percent`.
        """
        return pd.DataFrame({"value": self._estimate(), "std": self.bse.to_numpy(),
                             "rel_std_percent": self.rel_std.to_numpy()}, index=self._index())

    def to_csv(self, path: str | os.PathLike) -> None:
        """Write `to_frame` as CSV to `path` atomically (all or nothing).

        Returns
        -------
        None
            The file is written whole or not at all.
        """
        text = self.to_frame().to_csv(lineterminator="\n")
        atomic_write_text(path, text)


class ModelResults(ParameterResults):
    """A result whose parameters are those of its `model` (an IdentificationResult).

    IDIM and DIDIM identify every base parameter (`base`) and then keep a model (the
    essential parameters): `params`, `bse`, `conf_int()` and `predict` are the
    model's. The class using it defines `model` and `base`.
    """

    @property
    def names(self):
        return self.model.names

    @property
    def cov(self):
        return self.model.cov

    def _estimate(self):
        return self.model.chi

    def columns(self, names=None):
        """Indices of `names` (default: the model's) among the base parameters."""
        names = self.model.names if names is None else names
        index = {n: k for k, n in enumerate(self.base.names)}
        return [index[n] for n in names]

    def predict(self, W_base):
        """Torques (N, n) of `model` from a base regressor (N, n, b)."""
        return np.asarray(W_base)[:, :, self.columns()] @ self.model.chi


def _check_alpha(alpha) -> None:
    if not (isinstance(alpha, (int, float)) and 0 < alpha < 1):
        raise InputError(f"conf_int: alpha must be between 0 and 1 (0.05 for a 95 % interval), got {alpha!r}")


@dataclass(eq=False)
class IdentificationResult(ParameterResults):
    """Estimated base parameters and their statistics.

    Attributes
    ----------
    method : str
        Estimator, e.g. `"OLS"` or `"WLS"`.
    names : list[str]
        Parameter names, in the order of the columns of W.
    chi : ndarray (b,)
        Estimate χ̂, eq. (11).
    cov : ndarray (b, b)
        Covariance of χ̂, eq. (14) (for WLS: of the weighted system).
    sigma : ndarray (b,)
        Standard deviations σ_χ̂i = sqrt(cov[i, i]) (computed, not passed).
    rel_sigma : ndarray (b,)
        Relative standard deviations %σ = 100 σ / |χ̂|, eq. (15) (computed):
        `inf` when χ̂_i = 0 < σ_i, `nan` when both are 0.
    sigma_rho : float
        σ̂_ρ of eq. (13). For WLS it is that of the weighted system
        (dimensionless, close to 1 when the joint weights are consistent).
    joint_sigma : ndarray (n,) or None
        Per-joint error standard deviations σ_j used as WLS weights 1/σ_j
        (original units); `None` for OLS; `nan` for a joint without rows.
    residual : ndarray (N, n)
        τ − W3 χ̂ in original units, for every sample (also excluded ones).
    rel_error : float
        ‖Y − Wχ̂‖ / ‖Y‖ over the included rows, original units.
    rms : ndarray (n,)
        RMS of the residual of each joint over its included rows.
    joint_rel_error : ndarray (n,)
        ‖ρ^j‖ / ‖Y^j‖ per joint.
    cond : float
        2-norm condition number of the matrix actually solved (W, or the
        weighted W for WLS), in the parameters' own units.
    cond_scaled : float
        Condition number of the same matrix with unit-norm columns; it does
        not depend on the units of the parameters.
    n_samples, n_joints : int
        N and n of the input W3 (N, n, b).
    n_rows : int
        r, number of stacked equations used (eq. (9)).
    settings : dict
        Settings that produced the result (JSON-safe).
    notices : list[str]
        Remarks the estimator wants the user to read.
    data_hash : str or None
        SHA-256 of the input data (see `dynid.provenance.data_hash`).
    """

    method: str
    names: list
    chi: np.ndarray
    cov: np.ndarray
    sigma_rho: float
    residual: np.ndarray
    rel_error: float
    rms: np.ndarray
    joint_rel_error: np.ndarray
    cond: float
    n_samples: int
    n_joints: int
    n_rows: int
    joint_sigma: np.ndarray | None = None
    cond_scaled: float = math.nan
    settings: dict = field(default_factory=dict)
    notices: list = field(default_factory=list)
    data_hash: str | None = None
    sigma: np.ndarray = field(init=False, repr=False)
    rel_sigma: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.names = [str(n) for n in self.names]
        self.chi = np.asarray(self.chi, dtype=float).reshape(-1)
        b = self.chi.size
        self.cov = np.asarray(self.cov, dtype=float)
        if len(self.names) != b or self.cov.shape != (b, b):
            raise ValueError(
                f"IdentificationResult: {len(self.names)} names, chi of size {b} and cov of "
                f"shape {self.cov.shape} do not agree"
            )
        self.residual = np.asarray(self.residual, dtype=float)
        self.rms = np.asarray(self.rms, dtype=float)
        self.joint_rel_error = np.asarray(self.joint_rel_error, dtype=float)
        if self.joint_sigma is not None:
            self.joint_sigma = np.asarray(self.joint_sigma, dtype=float)
        self.notices = list(self.notices)
        self.settings = dict(self.settings)
        # Rounding can make a diagonal entry of a PSD matrix a hair negative.
        self.sigma = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            # eq. (15); |χ̂| = 0 gives inf (or nan when σ is 0 too), never an error.
            self.rel_sigma = 100.0 * self.sigma / np.abs(self.chi)

    # ------------------------------------------------------------------ access

    @property
    def dof(self) -> int:
        """Residual degrees of freedom r − b of eq. (13)."""
        return self.n_rows - self.n_params

    def __getitem__(self, name: str) -> tuple[float, float]:
        """`(value, std)` of parameter `name`."""
        try:
            i = self.names.index(name)
        except ValueError:
            raise KeyError(
                f"no parameter {name!r} in this result; its parameters are {', '.join(self.names)}"
            ) from None
        return float(self.chi[i]), float(self.sigma[i])

    def __repr__(self) -> str:
        return (
            f"<IdentificationResult {self.method}: {self.n_params} parameters, "
            f"{self.n_rows} rows, rel_error={self.rel_error:.4g}>"
        )

    def predict(self, W3) -> np.ndarray:
        """Torques W3 χ̂, shape (N, n), for a regressor `W3` of shape (N, n, b)."""
        W3 = np.asarray(W3, dtype=float)
        if W3.ndim != 3 or W3.shape[2] != self.n_params or W3.shape[1] != self.n_joints:
            raise InputError(
                f"predict: W3 has shape {W3.shape} but this result expects (N, {self.n_joints}, "
                f"{self.n_params}) (samples, joints, parameters {', '.join(self.names[:3])}...); "
                "build the regressor for the same model and parameter list."
            )
        return W3 @ self.chi

    # ------------------------------------------------------------ presentation
    def summary(self) -> str:
        """Printable report: header block, per-joint residuals, parameter table."""
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        title = f"Dynamic identification results ({self.method})"
        left = [
            ("Method:", self.method),
            ("Samples N:", str(self.n_samples)),
            ("Joints n:", str(self.n_joints)),
            ("Rows r:", str(self.n_rows)),
            ("Parameters b:", str(self.n_params)),
        ]
        sigma_label = "sigma_rho (eq. 13, weighted):" if self.joint_sigma is not None else "sigma_rho (eq. 13):"
        right = [
            ("Rel. error |Y-Wx|/|Y|:", _fmt(self.rel_error)),
            (sigma_label, _fmt(self.sigma_rho)),
            ("cond(W):", _fmt(self.cond)),
            ("cond(W, unit columns):", _fmt(self.cond_scaled)),
            ("Residual dof r-b:", str(self.dof)),
        ]
        lines = [title.center(_WIDTH), rule]
        for (lk, lv), (rk, rv) in zip(left, right):
            lines.append(f"{lk:<16}{lv:>14}     {rk:<30}{rv:>13}")
        lines.append(thin)
        head = f"{'Joint':<8}{'RMS residual':>16}{'Rel. error':>14}"
        if self.joint_sigma is not None:
            head += f"{'sigma_j (WLS)':>16}"
        lines.append(head)
        for j in range(self.n_joints):
            row = f"{j + 1:<8}{_fmt(self.rms[j]):>16}{_fmt(self.joint_rel_error[j]):>14}"
            if self.joint_sigma is not None:
                row += f"{_fmt(self.joint_sigma[j]):>16}"
            lines.append(row)
        lines.append(thin)
        lines.append(f"{'Parameter':<20}{'value':>18}{'sigma':>18}{'%sigma':>14}")
        lines.append(thin)
        for name, v, s, rs in zip(self.names, self.chi, self.sigma, self.rel_sigma):
            lines.append(f"{name:<20}{_fmt(v):>18}{_fmt(s):>18}{_fmt_pct(rs):>14}")
        lines.append(rule)
        if self.notices:
            lines.append("Notices:")
            lines.extend(f"[{i}] {text}" for i, text in enumerate(self.notices, 1))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-safe dict (NaN and infinities become `None`), deterministic."""
        out = {
            "method": self.method,
            "settings": self.settings,
            "parameters": [
                {"name": n, "value": v, "std": s, "rel_std_percent": rs}
                for n, v, s, rs in zip(self.names, self.chi, self.sigma, self.rel_sigma)
            ],
            "rel_error": self.rel_error,
            "rms_per_joint": self.rms,
            "joint_rel_error": self.joint_rel_error,
            "joint_sigma": self.joint_sigma,
            "cond": self.cond,
            "cond_scaled": self.cond_scaled,
            "sigma_rho": self.sigma_rho,
            "n_samples": self.n_samples,
            "n_joints": self.n_joints,
            "n_rows": self.n_rows,
            "dof": self.dof,
            "versions": versions(),
            "data_hash": self.data_hash,
            "notices": self.notices,
        }
        return json_safe(out)

def _fmt(x: float) -> str:
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == int(x) and abs(x) < 1e6:
        return f"{x:.1f}" if x != 0 else "0"
    return f"{x:.6g}" if 1e-3 <= abs(x) < 1e6 else f"{x:.4e}"


def _fmt_pct(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        return "inf" if x == math.inf else "nan"
    return f"{x:.2f}" if x < 1e4 else f"{x:.3g}"
