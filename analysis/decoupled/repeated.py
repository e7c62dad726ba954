"""Statistics of an estimate repeated over n experiments (Bona & Curatella 2005, Table 3).

The paper reports per parameter the mean θ̄ over the n repetitions, the
standard deviation σ, and the half amplitude of the 99.9 % confidence
interval "with t_γ found using the Student distribution with (n − 1) DoF",
printed as `t_γ σ / √(n − 1)`. dynid implements exactly that::

    θ̄ = (1/n) Σ θ_k
    σ  = sqrt((1/n) Σ (θ_k − θ̄)²)                  (1/n, the sample's own spread)
    half_width = t_γ σ / √(n − 1),  t_γ = t_{n−1}^{-1}((1 + γ) / 2)   (two-sided, γ = 0.999)

With σ computed with 1/n, `σ / √(n − 1)` equals `s / √n` with the unbiased
`s` (1/(n − 1)): the interval is the textbook Student interval of the mean,
`θ̄ ± t_γ s / √n`, which covers the true mean with probability γ. (With σ
computed with 1/(n − 1) the printed formula would be slightly too narrow.)

Check against the paper: in every row of its Table 3 half-width / σ = 0.6795,
which is t_{0.9995, 29} / √29 — the two-sided 99.9 % quantile for n = 30, not
for the n = 25 repetitions of section 3.4 (0.7645). dynid uses the n of the
data it is given.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from dynid.analysis.results import ParameterResults, parameter_table
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["RepeatedEstimate", "student_half_width", "MIN_REPETITIONS", "DEFAULT_CONFIDENCE"]

#: With n = 2 the 99.9 % Student quantile is 636.6: such an interval says nothing.
MIN_REPETITIONS = 3
DEFAULT_CONFIDENCE = 0.999


def student_half_width(std_1n, n, confidence=DEFAULT_CONFIDENCE):
    """`t_γ σ / √(n − 1)` with σ the 1/n standard deviation (module doc); returns (half, t_γ)."""
    t_g = float(stats.t.ppf(0.5 * (1.0 + confidence), n - 1))
    return t_g * np.asarray(std_1n, dtype=float) / math.sqrt(n - 1), t_g


@dataclass(eq=False, repr=False)
class RepeatedEstimate(ParameterResults):
    """Parameters estimated once per repetition, and their statistics (module doc).

    `estimates` (n, p): one row per repetition; `names` (p,) dynid names
    (`ZZ2`, `Fv+3`, `k2` ...); `symbols` the paper's symbols;
    `units` SI units; `joints` 1-based joint of each parameter; `truth`
    (p,) the true values when known (simulation), else None. Computed:
    `mean`, `std` (1/n), `half_width`, `t_gamma`, `inside`.
    """

    kind: str
    names: list
    estimates: np.ndarray
    joints: list
    symbols: list = None
    units: list = None
    confidence: float = DEFAULT_CONFIDENCE
    truth: np.ndarray | None = None
    table: str = ""
    settings: dict = field(default_factory=dict)
    notices: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.names = [str(x) for x in self.names]
        p = len(self.names)
        self.estimates = np.asarray(self.estimates, dtype=float).reshape(-1, p)
        n = self.estimates.shape[0]
        if n < MIN_REPETITIONS:
            raise InputError(f"{self.kind}: {n} repetition(s); a Student interval needs at least "
                             f"{MIN_REPETITIONS} repeated experiments (the paper uses 25)")
        if not 0 < self.confidence < 1:
            raise InputError(f"confidence must be in (0, 1), got {self.confidence!r}")
        self.joints = [int(j) for j in self.joints]
        self.symbols = list(self.symbols) if self.symbols is not None else list(self.names)
        self.units = list(self.units) if self.units is not None else [""] * p
        self.mean = self.estimates.mean(axis=0)
        self.std = self.estimates.std(axis=0, ddof=0)
        self.half_width, self.t_gamma = student_half_width(self.std, n, self.confidence)
        if self.truth is not None:
            self.truth = np.asarray(self.truth, dtype=float).reshape(p)

    # the shared interface: the mean over repetitions, its standard error std/sqrt(n-1),
    # and Student intervals with n-1 degrees of freedom (so conf_int(1 - confidence)
    # reproduces half_width)
    @property
    def method(self):
        return self.kind

    def _estimate(self):
        return self.mean

    @property
    def cov(self):
        return np.diag((self.std / math.sqrt(self.n_repetitions - 1)) ** 2)

    def _interval_quantile(self, alpha):
        return float(stats.t.ppf(1.0 - alpha / 2.0, self.n_repetitions - 1))

    @property
    def n_repetitions(self) -> int:
        return self.estimates.shape[0]

    @property
    def lower(self):
        return self.mean - self.half_width

    @property
    def upper(self):
        return self.mean + self.half_width

    @property
    def inside(self):
        """Per parameter: is the true value inside the interval? (None without truth.)"""
        if self.truth is None:
            return None
        return np.abs(self.truth - self.mean) <= self.half_width

    @property
    def all_inside(self):
        return None if self.truth is None else bool(np.all(self.inside))

    def value(self, name, default=0.0):
        return self[name][0] if name in self.names else default

    def to_frame(self) -> pd.DataFrame:
        """One row per parameter: `value` (the mean), `std` and `rel_std_percent` of that mean
        (the interface's, as for every result), `spread` (the paper's sigma of the repetitions,
        1/n) and the Student `half_width`."""
        se = self.bse.to_numpy()
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = 100.0 * se / np.abs(self.mean)
        df = pd.DataFrame({"joint": self.joints, "symbol": self.symbols, "unit": self.units,
                           "value": self.mean, "std": se, "rel_std_percent": rel, "spread": self.std,
                           "half_width": self.half_width},
                          index=pd.Index(self.names, name="parameter"))
        if self.truth is not None:
            df["true"] = self.truth
            df["inside"] = self.inside
        return df

    def summary(self) -> str:
        pct = f"{100 * self.confidence:g} %"
        lines = [f"{self.table or self.kind}: {self.n_repetitions} repetitions, {pct} Student "
                 f"interval, t_gamma = {self.t_gamma:.4f} ({self.n_repetitions - 1} dof)"]
        columns = [("mean", self.mean, lambda x: f"{x:.5g}"), ("bse", self.bse.to_numpy(), lambda x: f"{x:.4g}"),
                   ("sigma (1/n)", self.std, lambda x: f"{x:.4g}"),
                   ("t s/sqrt(n-1)", self.half_width, lambda x: f"{x:.4g}")]
        if self.truth is not None:
            columns += [("true", self.truth, lambda x: f"{x:.5g}"),
                        ("inside", ["yes" if x else "NO" for x in self.inside], "text")]
        lines += parameter_table(self.names, columns, label="param")
        if self.truth is not None:
            lines.append(f"true value inside: {int(self.inside.sum())} of {len(self.names)}")
        lines.append(f"bse: standard error of the mean (params, bse, conf_int(); conf_int() is 95 % unless "
                     f"alpha= is given); sigma (1/n): the spread of one repetition (the paper's); "
                     f"t s/sqrt(n-1): the half-width of the {pct} interval of the mean")
        lines += [f"note: {x}" for x in self.notices]
        return "\n".join(lines)

    def __str__(self):
        return self.summary()

    def to_dict(self) -> dict:

        params = []
        se = self.bse.to_numpy()
        for i, name in enumerate(self.names):
            d = {"name": name, "joint": self.joints[i], "symbol": self.symbols[i], "unit": self.units[i],
                 "value": self.mean[i], "std": se[i],
                 "rel_std_percent": 100 * se[i] / abs(self.mean[i]) if self.mean[i] else None,
                 "spread": self.std[i],
                 "half_width": self.half_width[i], "lower": self.lower[i], "upper": self.upper[i]}
            if self.truth is not None:
                d["true"] = self.truth[i]
                d["inside"] = bool(self.inside[i])
            params.append(d)
        return json_safe({"kind": self.kind, "table": self.table, "n_repetitions": self.n_repetitions,
                          "confidence": self.confidence, "t_gamma": self.t_gamma,
                          "std_definition": "standard error of the mean: spread / sqrt(n - 1)",
                          "spread_definition": "standard deviation of the repetitions (1/n), the paper's sigma",
                          "half_width_definition": "t_gamma * spread / sqrt(n - 1)",
                          "parameters": params, "estimates": self.estimates, "settings": self.settings,
                          "notices": self.notices})
