"""Results of an identification, modelled on statsmodels' results classes.

`Result` is the base of every result dynid returns (IDIM, DIDIM, the Projection
Method, maximum likelihood, the physically consistent fit, the posterior, the per-joint
models, validation, diagnosis, gravity tilt, asymmetric friction, payload, the full
report): `summary()` (and `str()`), `to_dict()`, `to_json()` and `to_csv()` through
one serializer (`serialize`), and a one-line `repr()` (method, robot, number of
parameters, error). Summaries print their parameters with the one table builder,
`parameter_table` (a Unit column, from `dynid.analysis.units`), their relative errors
as % (`percent`) and their remarks in one block (`notices_block`); JSON records of
parameters come from `parameter_records`.

`ParameterResults` adds the interface of a result with parameters: `method`,
`names`, `params` (a pandas Series), `bse`, `rel_std` (%σ, eq. (15)), `cov`,
`conf_int(alpha)`, `to_frame()` and `r[name]`, the record of one parameter
(`Parameter`: unpacks as `(value, std)`). Method-specific extras stay attributes of
each class. The raw accessors `sigma`, `rel_sigma` and `theta` and the posterior's
`interval(level)` are deprecated (`deprecated_alias`, a DeprecationWarning) for one
release: use `bse`, `rel_std`, `params` (or the array `chi`) and `conf_int(alpha)`.

`IdentificationResult` holds the estimate χ̂ (eq. (11)), its covariance
(eq. (14)), standard deviations and relative standard deviations (eq. (15)),
and the residual statistics, and knows how to print, tabulate and save itself.
Estimators in `dynid.analysis.estimators.least_squares` build it; users only read it.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import numbers
import os
import re
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.units import parameter_unit, prismatic_joints
from dynid.errors import InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import dumps_json, json_safe, versions

__all__ = ["Result", "Exportable", "ParameterResults", "ModelResults", "IdentificationResult", "Parameter",
           "parameter_records", "parameter_table", "notices_block", "gathered_notices", "percent", "serialize", "deprecated_alias"]

_WIDTH = 78


# ---------------------------------------------------------------- the shared pieces
def parameter_records(names, value, std, rel_std, prismatic=frozenset()) -> list:
    """The JSON record of each parameter: `{"name", "value", "std", "rel_std_percent", "unit"}`.

    Parameters
    ----------
    names : sequence of str
    value, std, rel_std : sequences of float
        Estimate, standard deviation and %σ (eq. (15)), in the order of `names`.
    prismatic : set of int
        The robot's prismatic joints (1-based), whose parameters carry N and m units.

    Returns
    -------
    list of dict
        One record per parameter (not yet JSON-safe: pass the document through `json_safe`);
        `unit` is "" where dynid has none for the name.
    """
    return [{"name": n, "value": v, "std": s, "rel_std_percent": r, "unit": parameter_unit(n, prismatic)}
            for n, v, s, r in zip(names, value, std, rel_std)]


def percent(fraction, digits: int = 2) -> str:
    """A relative error (a fraction) as a percentage: `0.0433888` -> `"4.34 %"`; beyond
    10^6 % in 3 significant digits (`"2.52e+31 %"`: a model off by that much is read by its order).

    Returns
    -------
    str
        `"nan"` for a missing value.
    """
    x = float(fraction)
    if not math.isfinite(x):
        return "nan" if math.isnan(x) else "inf"
    if abs(x) >= 1e4:
        return f"{100.0 * x:.3g} %"
    return f"{100.0 * x:.{digits}f} %"


def p_value_text(p, missing: str = "n/a") -> str:
    """A p-value as text: 3 significant digits, `1.2e-05` below 1e-4, `< 1e-300` where it
    underflows to 0 (not "0"); `missing` for NaN (a test that could not be computed)."""
    p = float(p)
    if not math.isfinite(p):
        return missing
    if p == 0.0:
        return "< 1e-300"
    return f"{p:.1e}" if p < 1e-4 else f"{p:.3g}"


def p_phrase(p, name: str = "p", missing: str = "n/a") -> str:
    """`p = 0.012`, or `p < 1e-300` where it underflows (`p_value_text`); `name` for another
    label ("Bonferroni p")."""
    text = p_value_text(p, missing)
    return f"{name} {text}" if text.startswith("<") else f"{name} = {text}"


def _cell(value, kind) -> str:
    if kind == "num":
        return _fmt(value)
    if kind == "pct":
        return _fmt_pct(value)
    if kind == "p":
        return p_value_text(value, "nan")
    if callable(kind):
        return kind(value)
    return str(value)


def parameter_table(names, columns, *, label: str = "Parameter", prismatic=frozenset()) -> list:
    """The one parameter table of every summary: name, unit, then `columns`.

    Parameters
    ----------
    names : sequence of str
        Parameter names; the unit comes from the name (`dynid.analysis.units.parameter_unit`).
    columns : sequence of (label, values, kind)
        `kind`: `"num"` (6 significant digits), `"pct"` (a %σ, two decimals), `"p"`
        (a p-value), `"text"`, or a function of the value giving its text.
    label : str
        Heading of the name column.
    prismatic : collection of int
        The 1-based numbers of the robot's prismatic joints (their per-joint units are N and m).

    Returns
    -------
    list of str
        The heading, a rule, one line per parameter.
    """
    names = [str(n) for n in names]
    units = [parameter_unit(n, prismatic) or "-" for n in names]
    cells = [[_cell(v, kind) for v in values] for _, values, kind in columns]
    nw = max([len(label)] + [len(n) for n in names]) + 2
    uw = max([4] + [len(u) for u in units]) + 2
    widths = [max([len(h)] + [len(c) for c in col]) + 2 for (h, _, _), col in zip(columns, cells)]
    widths = [max(w, 12) for w in widths]
    head = f"{label:<{nw}}{'unit':<{uw}}" + "".join(f"{h:>{w}}" for (h, _, _), w in zip(columns, widths))
    lines = [head, "-" * len(head)]
    for i, (n, u) in enumerate(zip(names, units)):
        lines.append(f"{n:<{nw}}{u:<{uw}}" + "".join(f"{col[i]:>{w}}" for col, w in zip(cells, widths)))
    return lines


_EXCLUDED_RE = re.compile(r"^(\d+) of (\d+) equations were excluded by row_mask/joints\.$")


def _plain(notice: str) -> str:
    m = _EXCLUDED_RE.match(notice)
    if m:
        k, r = int(m.group(1)), int(m.group(2))
        return (f"{k} of {r} equations ({100.0 * k / r:.1f} %) are left out of the fit (the velocity "
                f"dead zone, or joints not fitted)")
    return notice


def notices_block(*notice_lists) -> list:
    """The one block of remarks of a summary, in plain words, each remark once.

    Parameters
    ----------
    *notice_lists : lists of str
        The notices of a result and of the results it contains.

    Returns
    -------
    list of str
        `["Notices:", "  - ...", ...]`, or `[]` when there is nothing to say.
    """
    seen, out = set(), []
    for notices in notice_lists:
        for text in notices or ():
            text = _plain(str(text))
            if text not in seen:
                seen.add(text)
                out.append(text)
    gathered = _GATHERED.get()
    if gathered is not None:
        gathered.extend(out)
        return []
    return ["Notices:"] + [f"  - {text}" for text in out] if out else []


# the remarks of the summaries built inside `gathered_notices`, printed once by the caller
_GATHERED = contextvars.ContextVar("gathered_notices", default=None)


@contextlib.contextmanager
def gathered_notices():
    """Within this block, every `notices_block` hands its remarks to the yielded list and
    prints nothing, so that a summary made of several results has one Notices block.

    Yields
    ------
    list of str
        The remarks, in order; pass it to `notices_block` once the parts are built.
    """
    remarks = []
    token = _GATHERED.set(remarks)
    try:
        yield remarks
    finally:
        _GATHERED.reset(token)



def serialize(result, fmt: str, path: str | os.PathLike | None = None) -> str:
    """The one serializer of every result: its `to_dict()` as JSON, or its `to_frame()` as CSV.

    Parameters
    ----------
    result : Result
    fmt : {"json", "csv"}
    path : path, optional
        Written atomically (all or nothing) when given.

    Returns
    -------
    str
        The text (deterministic: equal results give byte-identical text).
    """
    # Serialise first: a failure here must not even create the temporary file.
    if fmt == "json":
        text = dumps_json(result.to_dict())
    elif fmt == "csv":
        text = result.to_frame().to_csv(lineterminator="\n")
    else:
        raise InputError(f"serialize: format must be 'json' or 'csv', got {fmt!r}")
    if path is not None:
        atomic_write_text(path, text)
    return text


class deprecated_alias:
    """A deprecated attribute: warns (DeprecationWarning) and returns `get(obj)`.

    Parameters
    ----------
    replacement : str
        What to use instead (shown in the warning).
    get : callable
        The value, from the object.
    """

    def __init__(self, replacement: str, get):
        self.replacement, self.get = replacement, get

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        warnings.warn(f"{type(obj).__name__}.{self.name} is deprecated and will be removed in the next "
                      f"release; use {self.replacement}", DeprecationWarning, stacklevel=2)
        return self.get(obj)

    def __set__(self, obj, value):
        raise AttributeError(f"{type(obj).__name__}.{self.name} is read-only (deprecated: use {self.replacement})")


def _describe(obj) -> str:
    """`method, robot 'x': n parameters, rel. error e %` of any result (the parts it has)."""
    parts = []
    method = getattr(obj, "method", None)
    if isinstance(method, str) and method:
        parts.append(method)
    robot = getattr(obj, "robot_name", None) or getattr(getattr(obj, "robot", None), "name", None)
    if isinstance(robot, str) and robot:
        parts.append(f"robot {robot!r}")
    head = ", ".join(parts)
    # a result holding another (a run, a full report) shows that one's parameters and error
    inner = getattr(obj, "result", None)
    tail = []
    for source in (obj, inner):
        try:
            tail.append(f"{len(source.names)} parameters")
            break
        except Exception:                  # noqa: BLE001 - a result without parameters
            continue
    err = None
    for source in (obj, getattr(obj, "model", None), inner, getattr(inner, "model", None)):
        err = getattr(source, "rel_error", None)
        if isinstance(err, (int, float, np.floating)):
            break
    if isinstance(err, (int, float, np.floating)):
        tail.append(f"rel. error {percent(err)}")
    return ": ".join(x for x in (head, ", ".join(tail)) if x)


class Result:
    """The base of every result: `str()` is `summary()`, `to_json()`/`to_csv()` come from the
    one serializer (`serialize`), `repr()` is one line. A class defines `summary()`,
    `to_dict()` and, for `to_csv`, `to_frame()`.

    `summary()` returns the printable report (str): parameters with their units, relative
    errors in %. `to_dict()` returns the result as a JSON-safe dict (NaN and infinities
    become None): what `to_json()` writes, and what a command's `--json` writes for the
    result it returns (`dynid identify --json`: the `to_dict()` of `dynid.run`'s result).
    """

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """`to_dict` as JSON, written atomically to `path` when given (all or nothing).

        Returns
        -------
        str
            The JSON text.
        """
        return serialize(self, "json", path)

    def to_csv(self, path: str | os.PathLike | None = None) -> str:
        """`to_frame` as CSV, written atomically to `path` when given (all or nothing).

        Returns
        -------
        str
            The CSV text.
        """
        return serialize(self, "csv", path)

    def to_frame(self) -> pd.DataFrame:
        """The result's table (what `to_csv` writes); a result holding another gives that one's.

        Returns
        -------
        pandas.DataFrame
        """
        inner = getattr(self, "result", None)
        if isinstance(inner, Result):
            return inner.to_frame()
        raise NotImplementedError(f"{type(self).__name__} has no table to write as CSV")

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {_describe(self)}>"


#: the old name of `Result`
Exportable = Result


class HeldParameters:
    """The parameter interface of a result that holds the parameters in another (`_held()`):
    `params`, `bse`, `rel_std`, `cov`, `conf_int()`, `cov_params()` and `r["name"]`, those of the
    held result, so that a run, a diagnosis or an effects fit answers as every result does."""

    def _held(self):
        raise NotImplementedError

    params = property(lambda self: self._held().params, doc="The estimates, by parameter name.")
    bse = property(lambda self: self._held().bse, doc="Their standard errors.")
    rel_std = property(lambda self: self._held().rel_std, doc="Their %σ (eq. (15)).")
    cov = property(lambda self: self._held().cov, doc="Their covariance.")

    def conf_int(self, alpha: float = 0.05):
        """The (1 - alpha) interval of each parameter.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `lower` and `upper`.
        """
        return self._held().conf_int(alpha)

    def cov_params(self):
        """The covariance as a table labelled by parameter name on both axes.

        Returns
        -------
        pandas.DataFrame
        """
        return self._held().cov_params()

    def __getitem__(self, name: str):
        """`r["ZZ1R"]`: the record of one parameter (unpacks as `(value, std)`)."""
        return self._held()[name]


class Parameter(tuple):
    """One parameter of a result, `r[name]`: unpacks as `(value, std)`.

    Attributes `name`, `value`, `std`, `rel_std_percent` (%σ, eq. (15)) and `unit`;
    `p["value"]` reads an attribute by name; `to_dict()` gives all five.
    """

    def __new__(cls, name, value, std, rel_std_percent=math.nan, unit=None):
        self = super().__new__(cls, (float(value), float(std)))
        self.name, self.rel_std_percent = str(name), float(rel_std_percent)
        self.unit = parameter_unit(self.name) if unit is None else str(unit)
        return self

    @property
    def value(self) -> float:
        return self[0]

    @property
    def std(self) -> float:
        return self[1]

    def __getitem__(self, key):
        if isinstance(key, str):
            if key not in ("name", "value", "std", "rel_std_percent", "unit"):
                raise KeyError(key)
            return getattr(self, key)
        return super().__getitem__(key)

    def to_dict(self) -> dict:
        """`{"name", "value", "std", "rel_std_percent", "unit"}`.

        Returns
        -------
        dict
            JSON-safe.
        """
        return json_safe({"name": self.name, "value": self.value, "std": self.std,
                          "rel_std_percent": self.rel_std_percent, "unit": self.unit})

    def __repr__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        return f"<Parameter {self.name} = {self.value:.6g} \u00b1 {self.std:.3g}{unit}>"

    def __getnewargs__(self):
        return self.name, self.value, self.std, self.rel_std_percent, self.unit


class ParameterResults(Result):
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

    def _records(self, prismatic=None) -> list:
        """`parameter_records` of this result's parameters (the JSON's `parameters`), with the units
        of its robot's prismatic joints unless `prismatic` is given."""
        return parameter_records(self.names, self._estimate(), self.bse.to_numpy(), self.rel_std.to_numpy(),
                                 self._prismatic() if prismatic is None else prismatic)

    def _units(self) -> list:
        """The SI unit of each parameter ("" where dynid has none for the name)."""
        prismatic = self._prismatic()
        return [parameter_unit(n, prismatic) for n in self._index()]

    def _prismatic(self) -> frozenset:
        """The 1-based numbers of the identified robot's prismatic joints (for the units)."""
        if getattr(self, "prismatic", None):
            return frozenset(self.prismatic)
        for owner in (self, getattr(self, "idim", None)):
            for model in (getattr(owner, "robot", None), getattr(owner, "base", None)):
                if model is not None:
                    return prismatic_joints(model)
        return frozenset()

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

    def __getitem__(self, name: str) -> Parameter:
        """The record of parameter `name` (`Parameter`: unpacks as `(value, std)`)."""
        names = list(self.names)
        try:
            i = names.index(name)
        except ValueError:
            raise KeyError(f"no parameter {name!r} in this result; its parameters are "
                           f"{', '.join(names)}") from None
        value, std = self._estimate()[i], self.bse.to_numpy()[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = 100.0 * std / abs(value)
        return Parameter(name, value, std, rel, parameter_unit(name, self._prismatic()))

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

        Parameters
        ----------
        alpha : float
            Level, between 0 and 1: 0.05 gives the 95 % interval (normal quantiles
            here; a class may use others, e.g. a posterior's sample quantiles).

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
        """Table of the parameters: index = names, columns value, std, rel_std_percent, unit.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `value`, `std`, `rel_std_percent` and `unit` (SI).
        """
        return pd.DataFrame({"value": self._estimate(), "std": self.bse.to_numpy(),
                             "rel_std_percent": self.rel_std.to_numpy(), "unit": self._units()},
                            index=self._index())



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

    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r.bse.to_numpy())
    rel_sigma = deprecated_alias("rel_std (a pandas Series; .to_numpy() for the array)",
                                 lambda r: r.rel_std.to_numpy())

    def _estimate(self):
        return self.model.chi

    def columns(self, names=None):
        """Indices of `names` (default: the model's) among the base parameters."""
        names = self.model.names if names is None else names
        index = {n: k for k, n in enumerate(self.base.names)}
        return [index[n] for n in names]

    def predict(self, W_base):
        """Torques (N, n) of `model` from a base regressor (N, n, b)."""
        W = np.asarray(W_base, dtype=float)
        b = len(self.base.names)
        if W.ndim != 3 or W.shape[2] != b:
            raise InputError(f"predict: the base regressor has shape {W.shape}, but this result expects "
                             f"(N, n, {b}): samples, joints and its {b} base parameters "
                             "(dynid.dynamics.regressor.base_regressor of the same robot)")
        return W[:, :, self.columns()] @ self.model.chi


def _check_alpha(alpha) -> None:
    # any real number (a numpy float32 too), not a bool
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real) or not 0 < alpha < 1:
        raise InputError(f"conf_int: alpha must be between 0 and 1 (0.05 for a 95 % interval), got {alpha!r}")


@dataclass(eq=False, repr=False)
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
    bse : pandas.Series (b,)
        Standard deviations σ_χ̂i = sqrt(cov[i, i]) (computed, not passed; `sigma`,
        the array, is deprecated).
    rel_std : pandas.Series (b,)
        Relative standard deviations %σ = 100 σ / |χ̂|, eq. (15) (computed):
        `inf` when χ̂_i = 0 < σ_i, `nan` when both are 0 (`rel_sigma` is deprecated).
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
    # the 1-based numbers of the robot's prismatic joints: their per-joint units (N, m)
    prismatic: tuple = ()

    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r._sigma)
    rel_sigma = deprecated_alias("rel_std (a pandas Series; .to_numpy() for the array)", lambda r: r._rel_sigma)

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
        self._sigma = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            # eq. (15); |χ̂| = 0 gives inf (or nan when σ is 0 too), never an error.
            self._rel_sigma = 100.0 * self._sigma / np.abs(self.chi)

    @property
    def bse(self) -> pd.Series:
        """Standard errors sqrt(diag(cov)) (rounding below 0 is clipped)."""
        return pd.Series(self._sigma, index=self._index(), name="std")

    @property
    def rel_std(self) -> pd.Series:
        """Relative standard deviations %σ = 100 σ / |χ̂| (eq. (15)); inf where χ̂ = 0 < σ."""
        return pd.Series(self._rel_sigma, index=self._index(), name="rel_std_percent")

    # ------------------------------------------------------------------ access

    @property
    def dof(self) -> int:
        """Residual degrees of freedom r − b of eq. (13)."""
        return self.n_rows - self.n_params

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
    def summary(self, notices: bool = True, prismatic=None, title: str | None = None) -> str:
        """Printable report: header block, per-joint residuals, parameter table, notices.

        Parameters
        ----------
        notices : bool
            False leaves the notices to the caller (a result that holds this one prints
            one block of notices for both).
        prismatic : collection of int, optional
            The robot's prismatic joints, for the units (default: `prismatic`); a result
            that holds this one and knows the robot passes them.
        title : str, optional
            The heading (default: "Dynamic identification results (method)"); a result that
            holds this fit says what it is (DIDIM's last step).

        Returns
        -------
        str
            Relative errors in %, every parameter with its unit.
        """
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        title = title or f"Dynamic identification results ({self.method})"
        prismatic = self._prismatic() if prismatic is None else frozenset(prismatic)
        left = [
            ("Method:", self.method),
            ("Samples N:", str(self.n_samples)),
            ("Joints n:", str(self.n_joints)),
            ("Rows r:", str(self.n_rows)),
            ("Parameters b:", str(self.n_params)),
        ]
        sigma_label = "sigma_rho (eq. 13, weighted):" if self.joint_sigma is not None else "sigma_rho (eq. 13):"
        right = [
            ("Rel. error |Y-Wx|/|Y|:", percent(self.rel_error)),
            (sigma_label, _fmt(self.sigma_rho)),
            ("cond(W):", _fmt(self.cond)),
            ("cond(W, unit columns):", _fmt(self.cond_scaled)),
            ("Residual dof r-b:", str(self.dof)),
        ]
        lines = [title.center(_WIDTH), rule]
        for (lk, lv), (rk, rv) in zip(left, right):
            lines.append(f"{lk:<16}{lv:>14}     {rk:<30}{rv:>13}")
        lines.append(thin)
        head = f"{'Joint':<8}{'RMS residual':>18}{'Rel. error':>14}"
        if self.joint_sigma is not None:
            head += f"{'sigma_j (WLS)':>18}"
        lines.append(head)
        for j in range(self.n_joints):
            unit = "N" if j + 1 in prismatic else "N m"
            row = f"{j + 1:<8}{_fmt(self.rms[j]) + ' ' + unit:>18}{percent(self.joint_rel_error[j]):>14}"
            if self.joint_sigma is not None:
                row += f"{_fmt(self.joint_sigma[j]) + ' ' + unit:>18}"
            lines.append(row)
        lines.append(thin)
        lines += parameter_table(self.names, [("value", self.chi, "num"), ("sigma", self._sigma, "num"),
                                              ("%sigma", self._rel_sigma, "pct")], prismatic=prismatic)
        lines.append(rule)
        if notices:
            lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-safe dict (NaN and infinities become `None`), deterministic.

        Returns
        -------
        dict
            Method, settings, parameter records, residual statistics, versions and data hash:
            what `to_json()` writes.
        """
        out = {
            "method": self.method,
            "settings": self.settings,
            "parameters": parameter_records(self.names, self.chi, self._sigma, self._rel_sigma, self._prismatic()),
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


def identified_line(method, robot_name, source):
    """IDIM's first summary line, `<method> identification of robot 'x' from <source>`, when the
    result knows its robot or recording (none for a result built from arrays)."""
    if not robot_name and not source:
        return []
    robot = f" of robot '{robot_name}'" if robot_name else ""
    return [f"{method} identification{robot}" + (f" from {source}" if source else "")]
