"""Noise PDF checks: is the measurement noise Gaussian, and which noise dominates?

Section 3.4 and Fig. 5 of Bona & Curatella 2005: from the period-averaged data
(`dynid.analysis.processing.averaging`) the PDF of the measurement noise is computed and
compared with a Gaussian one; the torque noise turns out larger than the
position noise, so the position noise is neglected. Section 3.5 does the same
with the validation error. This module gives the numbers behind such a
figure.

`noise_pdf_tests`
    Per joint (column): mean, standard deviation, skewness, `excess_kurtosis`
    (0 for a Gaussian) and four normality tests (the first two, and the
    moments, from `normality_row`, the one normality computation that
    validation and the residual analysis use too),

    * Jarque-Bera (`statsmodels.stats.stattools.jarque_bera`; asymptotic
      chi-square p-value),
    * Shapiro-Wilk (`scipy.stats.shapiro`). Its p-value is only accurate up
      to 5000 samples: a longer series is tested on an evenly spaced subsample
      of at most `max_shapiro` (default 5000) samples, every `ceil(N/5000)`-th
      one (deterministic; for period-averaging noise it spreads over all
      periods),
    * Anderson-Darling (`scipy.stats.anderson`, p-value interpolated in the
      tables of scipy, so clipped to [0.01, 0.15]),
    * Lilliefors (`statsmodels.stats.diagnostic.lilliefors`, table p-value).

    **Verdict.** `gaussian` is True when the *primary* test does not reject
    normality at `alpha` (default: Shapiro-Wilk). One test at level `alpha`
    falsely rejects Gaussian noise with probability `alpha`; the rule "all
    four tests accept" would reject it up to ~4 alpha (the tests are
    correlated, about 2-3 alpha in practice), which is why it is not the
    default. `rule="bonferroni"` (any test rejects at `alpha / 4`, size at
    most alpha, somewhat below it) and `rule="all"` are available. The other
    tests are reported with their own `reject` flags for the reader. The
    tests of the package's suite check the default rule: on 200 seeds of
    Gaussian noise of 2000 samples (one averaged period of the paper: 10 s at
    200 Hz) it rejects 5 % +- 3 %, and on Laplace noise of the same sigma it
    rejects in at least 90 % of the seeds.

`noise_pdf`
    Histogram (density), fitted normal density and Gaussian KDE
    (`scipy.stats.gaussian_kde`, Scott's bandwidth) on a common grid, per
    joint, for plotting.

`compare_noise`
    Torque noise against position noise (Fig. 5). The two are in different
    units; they are compared either

    * in torque units, when a `sensitivity` `s_j` (N m per rad, e.g. the
      stiffness of the position loop, or `|d tau / d q|` of the model) is
      given: `sigma_q_equiv = s_j sigma_q`, and the larger of `sigma_tau` and
      `sigma_q_equiv` dominates; or
    * as signal-to-noise ratios, when the noise-free (e.g. averaged) signals
      are given: `SNR = RMS(signal - mean) / sigma` per joint, in dB
      `20 log10`; the noise with the *lower* SNR dominates (it corrupts its
      signal relatively more).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats
from statsmodels.stats.diagnostic import lilliefors
from statsmodels.stats.stattools import jarque_bera

from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["NoiseTests", "noise_pdf_tests", "noise_pdf", "compare_noise", "NoiseComparison",
           "TESTS", "RULES", "normality", "normality_row", "shapiro_subsample"]

TESTS = ("jarque_bera", "shapiro", "anderson", "lilliefors")
RULES = ("primary", "bonferroni", "all")
MAX_SHAPIRO = 5000


def _columns(noise, names=None):
    try:
        a = np.asarray(noise, dtype=float)
    except (TypeError, ValueError):
        raise InputError("noise must be an array of numbers, (N,) or (N, n)") from None
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise InputError(f"noise must have shape (N,) or (N, n), got {a.shape}")
    if names is None:
        names = [f"j{k + 1}" for k in range(a.shape[1])]
    names = list(names)
    if len(names) != a.shape[1]:
        raise InputError(f"{len(names)} names for {a.shape[1]} columns of noise")
    return a, names


def _anderson(e):
    try:
        r = stats.anderson(e, dist="norm", method="interpolate")
        return float(r.statistic), float(r.pvalue)
    except TypeError:              # scipy < 1.17: critical values only
        r = stats.anderson(e, dist="norm")
        levels = np.asarray(r.significance_level) / 100.0          # 0.15 ... 0.01
        crit = np.asarray(r.critical_values)
        if r.statistic < crit[0]:
            return float(r.statistic), float(levels[0])
        if r.statistic > crit[-1]:
            return float(r.statistic), float(levels[-1])
        return float(r.statistic), float(np.interp(r.statistic, crit, levels))


def shapiro_subsample(e, max_shapiro=MAX_SHAPIRO):
    """The evenly spaced subsample Shapiro-Wilk is run on: every `ceil(N / max_shapiro)`-th sample."""
    step = int(math.ceil(e.size / max_shapiro)) if e.size else 1
    return e[::max(1, step)]


def normality_row(e, max_shapiro=MAX_SHAPIRO):
    """THE normality computation of dynid, for one residual or noise column.

    Non-finite samples (NaN marks a sample that was not fitted or predicted,
    e.g. a row in the velocity dead zone) are dropped first. Returns `n`,
    `mean`, `std`, `skew`, `excess_kurtosis` (0 for a Gaussian),
    Jarque-Bera (statistic and asymptotic p, statsmodels) and Shapiro-Wilk
    (scipy; on the evenly spaced subsample of `shapiro_subsample`, at
    most `max_shapiro` = 5000 samples, `shapiro_n` of them). Validation
    (`dynid.analysis.statistics.validation.normality`), the residual
    analysis and the noise sections all call it, so one residual always gets
    one set of numbers.
    """
    e = np.asarray(e, dtype=float)
    e = e[np.isfinite(e)]
    n = int(e.size)
    row = {"n": n, "mean": np.nan, "std": np.nan, "skew": np.nan, "excess_kurtosis": np.nan,
           "jarque_bera": np.nan, "jarque_bera_p": np.nan, "shapiro": np.nan, "shapiro_p": np.nan,
           "shapiro_n": 0}
    if n < 3:
        return row
    row["mean"] = float(e.mean())
    row["std"] = float(e.std(ddof=1))
    if np.ptp(e) == 0:
        return row
    jb, jb_p, skew, kurt = jarque_bera(e)
    row.update(skew=float(skew), excess_kurtosis=float(kurt) - 3.0, jarque_bera=float(jb),
               jarque_bera_p=float(jb_p))
    sub = shapiro_subsample(e, max_shapiro)
    sw = stats.shapiro(sub)
    row.update(shapiro=float(sw.statistic), shapiro_p=float(sw.pvalue), shapiro_n=int(sub.size))
    return row


def normality(residual, names=None, max_shapiro=MAX_SHAPIRO):
    """Per-joint `normality_row` of `residual` (N,) or (N, n); DataFrame indexed by joint.

    The index is `joint` = 1..n unless `names` are given. NaN samples are
    left out (pass the residual with the rows that were not fitted set to NaN).
    """
    a = np.asarray(residual, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    rows = [normality_row(a[:, j], max_shapiro) for j in range(a.shape[1])]
    index = (pd.Index(list(names), name="joint") if names is not None
             else pd.Index(np.arange(1, a.shape[1] + 1), name="joint"))
    return pd.DataFrame(rows, index=index)


def _one(e, max_shapiro):
    row = normality_row(e, max_shapiro)
    for name in ("anderson", "lilliefors"):
        row[name] = np.nan
        row[f"{name}_p"] = np.nan
    e = np.asarray(e, dtype=float)
    e = e[np.isfinite(e)]
    if e.size < 8 or np.ptp(e) == 0:
        for name in ("jarque_bera", "shapiro"):
            row[name] = row[f"{name}_p"] = np.nan
        return row
    row["anderson"], row["anderson_p"] = _anderson(e)
    lf, lf_p = lilliefors(e, dist="norm", pvalmethod="table")
    row["lilliefors"], row["lilliefors_p"] = float(lf), float(lf_p)
    return row


def _verdict(row, alpha, rule, primary):
    ps = np.array([row[f"{t}_p"] for t in TESTS], dtype=float)
    if not np.all(np.isfinite(ps)):
        return None
    if rule == "primary":
        return bool(row[f"{primary}_p"] >= alpha)
    if rule == "bonferroni":
        return bool(np.all(ps >= alpha / len(TESTS)))
    return bool(np.all(ps >= alpha))


@dataclass
class NoiseTests:
    """Per-joint normality tests of a noise record (see the module docstring)."""

    table: pd.DataFrame           # one row per joint
    alpha: float
    rule: str
    primary: str
    noise: np.ndarray = field(repr=False)
    names: list = field(default_factory=list)
    label: str = "noise"
    unit: str = ""

    @property
    def gaussian(self) -> np.ndarray:
        return self.table["gaussian"].to_numpy()

    def pdf(self, **kwargs):
        """`noise_pdf` of the tested noise."""
        return noise_pdf(self.noise, names=self.names, **kwargs)

    def rule_text(self) -> str:
        if self.rule == "primary":
            return (f"Gaussian when {self.primary.replace('_', '-')} does not reject normality at "
                    f"alpha = {self.alpha:g}")
        if self.rule == "bonferroni":
            return (f"Gaussian when no test rejects at alpha / {len(TESTS)} = "
                    f"{self.alpha / len(TESTS):g} (Bonferroni)")
        return f"Gaussian when no test rejects at alpha = {self.alpha:g}"

    def summary(self):
        lines = [f"Noise PDF tests of {self.label} ({self.rule_text()}):",
                 "  joint        n        std     skew  ex.kurt    JB p    SW p    AD p    LF p  gaussian"]
        for name, r in self.table.iterrows():
            lines.append(f"  {name:>5} {int(r['n']):8d} {r['std']:10.4g} {r['skew']:8.3f} {r['excess_kurtosis']:8.3f} "
                         f"{r['jarque_bera_p']:7.3g} {r['shapiro_p']:7.3g} {r['anderson_p']:7.3g} "
                         f"{r['lilliefors_p']:7.3g}  {'yes' if r['gaussian'] else 'no'}")
        return "\n".join(lines)

    def to_dict(self):

        return json_safe({"label": self.label, "unit": self.unit, "alpha": self.alpha,
                          "rule": self.rule, "primary": self.primary, "rule_text": self.rule_text(),
                          "joints": self.table.reset_index().to_dict(orient="records")})


def noise_pdf_tests(noise, alpha=0.05, *, rule="primary", primary="shapiro", names=None,
                    max_shapiro=MAX_SHAPIRO, label="noise", unit="") -> NoiseTests:
    """Normality tests of `noise` (N,) or (N, n), per column; see the module docstring."""
    alpha = float(alpha)
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha!r}")
    if rule not in RULES:
        raise InputError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
    if primary not in TESTS:
        raise InputError(f"primary must be one of {', '.join(TESTS)}, got {primary!r}")
    max_shapiro = int(max_shapiro)
    if not 3 <= max_shapiro <= MAX_SHAPIRO:
        raise InputError(f"max_shapiro must be in [3, {MAX_SHAPIRO}], got {max_shapiro!r}")
    a, names = _columns(noise, names)
    rows = []
    for j in range(a.shape[1]):
        row = _one(a[:, j], max_shapiro)
        for t in TESTS:
            p = row[f"{t}_p"]
            row[f"{t}_reject"] = bool(p < alpha) if np.isfinite(p) else None
        row["gaussian"] = _verdict(row, alpha, rule, primary)
        rows.append(row)
    table = pd.DataFrame(rows, index=pd.Index(names, name="joint"))
    order = ["n", "mean", "std", "skew", "excess_kurtosis"]
    for t in TESTS:
        order += [t, f"{t}_p", f"{t}_reject"]
    order += [c for c in table.columns if c not in order and c != "gaussian"] + ["gaussian"]
    return NoiseTests(table=table[order], alpha=alpha, rule=rule, primary=primary, noise=a,
                      names=names, label=label, unit=unit)


def noise_pdf(noise, *, names=None, bins=None, n_grid=200):
    """Per column: histogram density, fitted normal and KDE on a common grid.

    Returns a list of dicts `{name, edges, density, x, normal, kde, mean, std}`;
    `bins` default `clip(sqrt(N), 8, 60)`. `kde` is None when the KDE
    cannot be computed (constant data).
    """
    a, names = _columns(noise, names)
    out = []
    for j, name in enumerate(names):
        e = a[:, j]
        e = e[np.isfinite(e)]
        mu = float(e.mean()) if e.size else np.nan
        sd = float(e.std(ddof=1)) if e.size > 1 else np.nan
        nb = bins or int(np.clip(np.ceil(np.sqrt(max(e.size, 1))), 8, 60))
        if e.size and np.ptp(e) > 0:
            density, edges = np.histogram(e, bins=nb, density=True)
            lo, hi = float(e.min()), float(e.max())
            pad = 0.1 * (hi - lo)
            x = np.linspace(lo - pad, hi + pad, n_grid)
            normal = stats.norm.pdf(x, mu, sd)
            try:
                kde = stats.gaussian_kde(e)(x)
            except (np.linalg.LinAlgError, ValueError):
                kde = None
        else:
            density, edges, x, normal, kde = np.array([]), np.array([]), np.array([]), np.array([]), None
        out.append({"name": name, "edges": edges, "density": density, "x": x, "normal": normal,
                    "kde": kde, "mean": mu, "std": sd})
    return out


@dataclass
class NoiseComparison:
    """Torque noise vs position noise per joint (Fig. 5); see `compare_noise`."""

    table: pd.DataFrame
    mode: str                      # "sensitivity" or "snr"

    @property
    def dominant(self):
        return list(self.table["dominant"])

    def summary(self):
        if self.mode == "sensitivity":
            head = "  joint  sigma_tau [N m]  sigma_q [rad]  sigma_q*s [N m]  ratio  dominant"
            rows = [f"  {n:>5} {r.sigma_tau:16.4g} {r.sigma_q:14.4g} {r.sigma_q_equiv:16.4g} "
                    f"{r.ratio:6.3g}  {r.dominant}" for n, r in self.table.iterrows()]
            title = "Torque vs position noise, in torque units (sigma_q times the sensitivity):"
        else:
            head = "  joint  sigma_tau [N m]  sigma_q [rad]  SNR tau [dB]  SNR q [dB]  dominant"
            rows = [f"  {n:>5} {r.sigma_tau:16.4g} {r.sigma_q:14.4g} {r.snr_tau_db:13.1f} "
                    f"{r.snr_q_db:11.1f}  {r.dominant}" for n, r in self.table.iterrows()]
            title = "Torque vs position noise, as signal-to-noise ratios (lower SNR dominates):"
        return "\n".join([title, head] + rows)

    def to_dict(self):

        return json_safe({"mode": self.mode,
                          "joints": self.table.reset_index().to_dict(orient="records")})


def _sigma(noise, as_sigma, what):
    a = np.asarray(noise, dtype=float)
    if as_sigma:
        if a.ndim > 1:
            raise InputError(f"{what}: with as_sigma=True give one standard deviation per joint (n,)")
        return np.atleast_1d(a)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise InputError(f"{what} must be noise samples (N,) or (N, n)")
    return np.sqrt(np.nanmean(a ** 2, axis=0))


def compare_noise(tau_noise, q_noise, *, sensitivity=None, tau_signal=None, q_signal=None,
                  names=None, as_sigma=False) -> NoiseComparison:
    """Which noise dominates, torque or position (Fig. 5)? See the module docstring.

    `tau_noise`, `q_noise`: zero-mean noise samples (N,) or (N, n) (e.g.
    `AveragedPeriods.noise`; their RMS is the sigma), or, with
    `as_sigma=True`, their standard deviations (n,). `sensitivity`: (n,) or a
    scalar, N m per rad: compares in torque units; otherwise `tau_signal` and
    `q_signal` ((N, n), e.g. the averaged period) give SNRs.
    """
    st = _sigma(tau_noise, as_sigma, "tau_noise")
    sq = _sigma(q_noise, as_sigma, "q_noise")
    if st.shape != sq.shape:
        raise InputError(f"tau_noise has {st.size} joints but q_noise has {sq.size}")
    n = st.size
    names = list(names) if names is not None else [f"j{k + 1}" for k in range(n)]
    df = pd.DataFrame({"sigma_tau": st, "sigma_q": sq}, index=pd.Index(names, name="joint"))
    if sensitivity is not None:
        s = np.broadcast_to(np.abs(np.asarray(sensitivity, dtype=float)), (n,)).astype(float)
        df["sensitivity"] = s
        df["sigma_q_equiv"] = sq * s
        with np.errstate(divide="ignore", invalid="ignore"):
            df["ratio"] = st / (sq * s)
        df["dominant"] = np.where(df["ratio"] >= 1.0, "torque", "position")
        return NoiseComparison(df, "sensitivity")
    if tau_signal is None or q_signal is None:
        raise InputError("compare_noise needs either a sensitivity (N m per rad) or the signals "
                         "tau_signal and q_signal to compare the noises as SNRs")

    def rms(x):
        x = np.asarray(x, dtype=float)
        x = x[:, None] if x.ndim == 1 else x
        return np.sqrt(np.mean((x - x.mean(0)) ** 2, axis=0))

    with np.errstate(divide="ignore", invalid="ignore"):
        snr_t = rms(tau_signal) / st
        snr_q = rms(q_signal) / sq
    df["snr_tau"] = snr_t
    df["snr_q"] = snr_q
    df["snr_tau_db"] = 20 * np.log10(snr_t)
    df["snr_q_db"] = 20 * np.log10(snr_q)
    df["dominant"] = np.where(snr_t <= snr_q, "torque", "position")
    return NoiseComparison(df, "snr")
