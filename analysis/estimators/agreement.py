"""Do several recordings (or time segments of one) find the same parameters within their intervals?

The covariance of one recording (classic eq. (14) of Gautier et al. 2010, or a
HAC / bootstrap one) describes the noise of that recording only. Model error
(torque the model does not describe: springs, tilt, friction shape, elasticity)
biases the estimate differently on different trajectories; the only way to see
it is to identify the same model on different data and compare.

* `pairwise_agreement`: for every pair of recordings and every parameter
  both call identified (%σ ≤ `rel_max`), z = (χa − χb)/√(σa² + σb²); the
  fraction with |z| ≤ 1.96 (95 % expected) and the median |z| (0.67 expected).
* `equality_test`: χ² test that all recordings share one parameter vector,
  overall (Cochran's Q summed over the parameters, referred to the χ² its
  correlations give) and per parameter (Cochran's Q).
* `random_effects`: the pooled estimate of each parameter whose standard
  error includes the between-recording variance τ² (DerSimonian & Laird 1986,
  statsmodels' combine_effects).
* `segments`: contiguous time segments of one recording (≥ 3, each
  identifying every parameter), for the same checks when there is one recording.
* `agreement`: all of these at once, as an `Agreement` result (the pooled
  estimate with `params`, `bse`, `conf_int()`, `summary()` and the JSON/CSV
  exports of every result).
* `agreement_verdict`: the verdict line.

Plain functions on numpy arrays, and the one result class.
"""
from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.linalg
from scipy import stats

from dynid.analysis.results import ParameterResults, p_phrase, parameter_table
from dynid.provenance import json_safe

__all__ = ["pairwise_agreement", "equality_test", "random_effects", "segments", "agreement_verdict",
           "agreement", "Agreement"]


def pairwise_agreement(chis, sigmas, *, rel_max: float = 10.0, names=None) -> dict:
    """Pairwise z-scores of K estimates of the same parameters.

    Parameters
    ----------
    chis, sigmas : sequences of K arrays (p,)
        Estimates and their standard deviations, one per recording (same parameter order).
    rel_max : float
        A parameter enters a pair only if its %σ (eq. (15)) is ≤ rel_max in both runs.
    names : list of p str, optional
        Parameter names, for the `z` records.

    Returns
    -------
    dict
        `pairs` (count), `within_95` (fraction with |z| ≤ 1.96, NaN without pairs),
        `median_abs_z`, `beyond_5` (fraction with |z| > 5), `z` (list of
        {a, b, name, z}).
    """
    chis = [np.asarray(c, dtype=float) for c in chis]
    sigmas = [np.asarray(s, dtype=float) for s in sigmas]
    names = names if names is not None else [str(k) for k in range(chis[0].size)]
    rec = []
    for a, b in itertools.combinations(range(len(chis)), 2):
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = (100 * sigmas[a] / np.abs(chis[a]) <= rel_max) & (100 * sigmas[b] / np.abs(chis[b]) <= rel_max)
            z = (chis[a] - chis[b]) / np.hypot(sigmas[a], sigmas[b])
        rec += [{"a": a, "b": b, "name": names[k], "z": float(z[k])} for k in np.flatnonzero(ok)]
    az = np.abs([r["z"] for r in rec])
    return {"pairs": len(rec),
            "within_95": float(np.mean(az <= 1.96)) if az.size else math.nan,
            "median_abs_z": float(np.median(az)) if az.size else math.nan,
            "beyond_5": float(np.mean(az > 5)) if az.size else math.nan,
            "rel_max": rel_max, "z": rec}


def equality_test(chis, covs) -> dict:
    """χ² test of H0: every recording has the same parameter vector.

    Overall: Q = Σ_k Σ_i (χ_ki − χ̄_i)² / v_ki, with v_ki the variance of parameter i in
    part k and χ̄_i the inverse-variance mean (Cochran's Q summed over the parameters).
    Under H0 the parts' errors e_k have covariances V_k and Q = eᵀ B e, a weighted sum of
    χ²₁ variables whose mean and variance are tr(BV) and 2 tr((BV)²); Q/g is referred to
    χ² with h degrees of freedom, g = tr((BV)²)/tr(BV), h = tr(BV)²/tr((BV)²)
    (Satterthwaite 1946; Box 1954). With diagonal V_k this is exact: g = 1, h = (K − 1) p.

    The full covariances enter through those two traces only, never inverted. The Wald form
    Σ_k (χ_k − χ̄)ᵀ V_k⁻¹ (χ_k − χ̄) inverts them, and a robust covariance (HAC, block
    bootstrap) of a short segment is estimated from fewer effective samples than it has
    parameters: its small eigenvalues are noise, and their inverses made the statistic 1.5
    (bootstrap) to 180 (HAC) times the classic one, whose σ are smaller (the three segments
    of LWR4+ recording 1, `dynid identify examples/kuka_lwr4/recording_1.toml --robot
    kuka_lwr4 --uncertainty U --json`: classic 1860, bootstrap 2719, HAC 342,106, on 138
    dof). On the independent plant it rejected a right model on most recordings with every
    covariance (benchmarks/agreement_size.py).
    Per parameter: Cochran's Q with the variances alone, K − 1 degrees of freedom.

    A parameter without a positive, finite variance in every part is left out of the
    overall test (its Q is NaN).

    Returns
    -------
    dict
        `chi2` (Q/g), `dof` (h, not necessarily whole), `p_value`, `scale` (g), and
        `per_parameter`: arrays `q` and `p_value` (p,).
    """
    chis = np.asarray(chis, dtype=float)
    covs = np.asarray(covs, dtype=float)
    K, p = chis.shape
    v = np.array([np.diag(C) for C in covs])
    usable = np.all(np.isfinite(v) & (v > 0), axis=0) & np.all(np.isfinite(chis), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):    # σ = 0: that parameter's Q is NaN
        w = np.where(v > 0, 1.0 / np.where(v > 0, v, 1.0), np.nan)
        mu = (w * chis).sum(axis=0) / w.sum(axis=0)
        q = (w * (chis - mu) ** 2).sum(axis=0)
    per_parameter = {"q": q, "p_value": stats.chi2.sf(q, K - 1)}
    m = int(usable.sum())
    if K < 2 or m == 0:
        return {"chi2": math.nan, "dof": math.nan, "p_value": math.nan, "scale": math.nan,
                "per_parameter": per_parameter}
    wu = w[:, usable]                                        # (K, m)
    Vu = covs[:, usable][:, :, usable]                       # (K, m, m)
    # d = L e with L = I − [S⁻¹W_1 ... S⁻¹W_K] stacked K times, S = Σ_k W_k (all diagonal)
    share = (wu / wu.sum(axis=0)).reshape(-1)               # (K m,): block j's diagonal of S⁻¹W_j
    L = np.eye(K * m) - np.tile(np.diag(share).reshape(K, m, K * m).sum(axis=0), (K, 1))
    B = L.T @ (wu.reshape(-1, 1) * L)
    BE = B @ scipy.linalg.block_diag(*(0.5 * (C + C.T) for C in Vu))
    t1, t2 = float(np.trace(BE)), float(np.einsum("ij,ji->", BE, BE))
    scale, dof = t2 / t1, t1 * t1 / t2
    stat = float(q[usable].sum()) / scale
    return {"chi2": stat, "dof": dof, "p_value": float(stats.chi2.sf(stat, dof)), "scale": scale,
            "per_parameter": per_parameter}


def random_effects(chis, sigmas) -> dict:
    """DerSimonian–Laird random-effects pooling of each parameter over K recordings.

    Returns
    -------
    dict of arrays (p,)
        `pooled` (random-effects mean), `std` (its standard error, with τ²),
        `tau` (between-recording standard deviation, √τ²), `fixed` and
        `fixed_std` (the inverse-variance pooling without τ²), `i2`.
    """
    from statsmodels.stats.meta_analysis import combine_effects
    chis = np.asarray(chis, dtype=float)
    var = np.asarray(sigmas, dtype=float) ** 2
    out = {k: np.full(chis.shape[1], np.nan) for k in ("pooled", "std", "tau", "fixed", "fixed_std", "i2")}
    for k in range(chis.shape[1]):
        if not np.all(var[:, k] > 0):
            continue
        with warnings.catch_warnings():   # its Knapp-Hartung extras (unused) warn for K = 2
            warnings.simplefilter("ignore", RuntimeWarning)
            r = combine_effects(chis[:, k], var[:, k], method_re="dl")
        out["fixed"][k], out["fixed_std"][k] = r.mean_effect_fe, r.sd_eff_w_fe
        if r.tau2 > 0:
            out["pooled"][k], out["std"][k] = r.mean_effect_re, r.sd_eff_w_re
        else:
            # DerSimonian-Laird truncates tau² at 0 (statsmodels keeps the negative moment estimate,
            # whose weights 1/(v + tau²) gave a pooled σ below the fixed-effect one, or NaN)
            out["pooled"][k], out["std"][k] = r.mean_effect_fe, r.sd_eff_w_fe
        out["tau"][k], out["i2"][k] = math.sqrt(max(r.tau2, 0.0)), max(float(r.i2), 0.0)
    return out


def segments(n_samples: int, mask, k: int = 3) -> list[np.ndarray]:
    """k contiguous, equal segments of the samples (boolean masks (N, n) of the rows to use)."""
    mask = np.asarray(mask, dtype=bool)
    out = []
    for idx in np.array_split(np.arange(n_samples), k):
        m = np.zeros_like(mask)
        m[idx] = mask[idx]
        out.append(m)
    return out


@dataclass(repr=False, eq=False)
class Agreement(ParameterResults):
    """K estimates of the same parameters (recordings, or segments of one) compared.

    The estimate (`params`, `bse`, `conf_int`) is the random-effects pooled value of each
    parameter, whose σ includes the between-recording spread τ (`between_std`): the figure
    to use when the recordings do not agree (`verdict`). Its covariance is diagonal (each
    parameter pooled alone). `to_dict()` is the `agreement` block of `dynid identify --json`.

    Attributes
    ----------
    kind : str
        "recordings" or "segments".
    k : int
        The number of parts compared.
    names : list of str
        The parameters every part identifies (`left_out`: the others).
    pairs, within_95, median_abs_z, beyond_5, z, rel_max
        `pairwise_agreement`.
    chi2, dof, p_value, chi2_scale, per_parameter_p_value
        `equality_test`: overall Q/g on h effective degrees of freedom (g = `chi2_scale`),
        and Cochran's Q per parameter.
    pooled, pooled_std, between_std : pandas.Series
        `random_effects` (DerSimonian-Laird), by parameter name (`per_parameter_p_value` too).
    uncertainty : str
        The covariance of each part (`classic`, `hac` or `bootstrap`).
    """

    kind: str
    k: int
    names: list
    pairs: int
    within_95: float
    median_abs_z: float
    beyond_5: float
    z: list
    rel_max: float
    chi2: float
    dof: float
    p_value: float
    per_parameter_p_value: np.ndarray
    pooled: np.ndarray
    pooled_std: np.ndarray
    between_std: np.ndarray
    uncertainty: str = "classic"
    chi2_scale: float = 1.0
    left_out: list = field(default_factory=list)
    prismatic: frozenset = frozenset()

    def __post_init__(self) -> None:
        self.names = list(self.names)
        # by parameter name, as `params` and `bse`
        for name in ("per_parameter_p_value", "pooled", "pooled_std", "between_std"):
            setattr(self, name, pd.Series(np.asarray(getattr(self, name), dtype=float), name=name,
                                          index=pd.Index(self.names, name="parameter")))

    @property
    def method(self) -> str:
        return f"pooled over {self.k} {self.kind} (random effects)"

    def _estimate(self) -> np.ndarray:
        return self.pooled.to_numpy()

    @property
    def cov(self) -> np.ndarray:
        """Diagonal: the pooled σ² of each parameter (pooled alone)."""
        return np.diag(self.pooled_std.to_numpy() ** 2)

    @property
    def agrees(self) -> bool:
        """Whether the parts agree on enough evidence: at least `MIN_PAIRS` pairwise differences,
        90 % of them within their 95 % intervals, and the chi2 test not rejecting at 1 % (a test
        that could not be computed rejects nothing)."""
        return bool(self.pairs >= MIN_PAIRS and self.within_95 >= 0.9 and not self.p_value < 0.01)

    @property
    def verdict(self) -> str:
        """The verdict's line (`agreement_verdict`)."""
        return agreement_verdict(self)

    def to_frame(self) -> pd.DataFrame:
        """One row per parameter: the pooled `value`, `std` (with τ), `rel_std_percent`,
        `between_std` (τ), `p_value` (Cochran's Q test of equal values), `unit`."""
        df = super().to_frame()
        df.insert(3, "between_std", self.between_std.to_numpy())
        df.insert(4, "p_value", self.per_parameter_p_value.to_numpy())
        return df

    def summary(self) -> str:
        table = parameter_table(self.names, [
            ("pooled", self.pooled.to_numpy(), "num"), ("std", self.pooled_std.to_numpy(), "num"),
            ("between std", self.between_std.to_numpy(), "num"),
            ("Q p-value", self.per_parameter_p_value.to_numpy(), "p")],
            prismatic=self._prismatic())
        lines = [f"Agreement of {self.k} {self.kind} ({self.uncertainty} covariance of each)",
                 self.verdict, ""] + table
        if self.left_out:
            lines += ["", f"Left out (not identified by every part): {', '.join(self.left_out)}"]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return json_safe({
            "kind": self.kind, "k": self.k, "names": self.names, "pairs": self.pairs,
            "within_95": self.within_95, "median_abs_z": self.median_abs_z, "beyond_5": self.beyond_5,
            "z": self.z, "rel_max": self.rel_max, "chi2": self.chi2, "dof": self.dof,
            "chi2_scale": self.chi2_scale, "p_value": self.p_value,
            "per_parameter_p_value": self.per_parameter_p_value.to_numpy(),
            "pooled": self.pooled.to_numpy(), "pooled_std": self.pooled_std.to_numpy(),
            "between_std": self.between_std.to_numpy(),
            "uncertainty": self.uncertainty, "left_out": self.left_out, "verdict": self.verdict})


def agreement(chis, sigmas, covs, names, *, kind: str = "recordings", rel_max: float = 10.0,
              uncertainty: str = "classic", left_out=(), prismatic=frozenset()) -> Agreement:
    """Pairwise figures, χ² tests and random-effects pooling of K estimates.

    Parameters
    ----------
    chis, sigmas : sequences of K arrays (p,)
        The estimates and their σ, one per part, in the order of `names`.
    covs : sequence of K arrays (p, p)
        Their covariances (the χ² test).
    names : list of p str
    kind : str
        "recordings" or "segments" (the texts).
    rel_max : float
        %σ at or below which a parameter enters a pair (`pairwise_agreement`).
    uncertainty, left_out, prismatic
        Carried by the result: the parts' covariance, the parameters not compared, the
        robot's prismatic joints (units).

    Returns
    -------
    Agreement
    """
    pw = pairwise_agreement(chis, sigmas, rel_max=rel_max, names=names)
    eq = equality_test(chis, covs)
    re = random_effects(chis, sigmas)
    return Agreement(kind=kind, k=len(chis), names=list(names), pairs=pw["pairs"],
                     within_95=pw["within_95"], median_abs_z=pw["median_abs_z"], beyond_5=pw["beyond_5"],
                     z=pw["z"], rel_max=rel_max, chi2=eq["chi2"], dof=eq["dof"], p_value=eq["p_value"],
                     chi2_scale=eq["scale"], per_parameter_p_value=eq["per_parameter"]["p_value"], pooled=re["pooled"],
                     pooled_std=re["std"], between_std=re["tau"], uncertainty=uncertainty,
                     left_out=list(left_out), prismatic=frozenset(prismatic))


#: fewer pairwise differences than this say little whichever way they fall
MIN_PAIRS = 10


def agreement_verdict(a: Agreement) -> str:
    """One verdict line: do the recordings (segments) agree within their intervals?

    `a` is an `Agreement`.
    """
    what = a.kind
    if not a.pairs:
        return (f"Agreement across {a.k} {what}: no parameter has %sigma <= {a.rel_max:g} % in two "
                f"{what}; nothing to compare.")
    # a chi2 test that could not be computed (NaN) rejects nothing
    pairs_ok, joint_ok = a.within_95 >= 0.9, not a.p_value < 0.01
    ok = pairs_ok and joint_ok
    # say which test decided: the pairs one at a time, or all the parameters together (the chi2
    # test sees small shifts the pairwise intervals hold one by one)
    few = a.pairs < MIN_PAIRS and joint_ok and not pairs_ok
    if few:
        # one difference outside its 95 % interval among a few pairs is what chance gives
        # (6 pairs: 26 % of the time), and the chi2 test of all the parameters does not reject
        outside = int(round(a.pairs * (1.0 - a.within_95)))
        chance = 1.0 - 0.95 ** a.pairs
        head = (f"cannot be told apart from agreeing: {outside} of only {a.pairs} pairwise differences outside "
                f"its 95 % interval (at least one outside by chance {100 * chance:.0f} % of the time), and the "
                f"chi2 test does not reject equal parameters")
    head = (head if few else
            "agree within their intervals" + (f", on weak evidence (only {a.pairs} pairwise differences)"
                                              if a.pairs < MIN_PAIRS else "") if ok else
            "agree pair by pair but NOT all together (the chi2 test rejects equal parameters)" if pairs_ok else
            "do NOT agree within their intervals (too few pairwise differences inside them)" if joint_ok else
            "do NOT agree within their intervals (too few pairwise differences inside them, and the chi2 "
            "test rejects equal parameters)")
    tail = ("" if ok or few else "; the intervals of one recording are optimistic: model error differs between "
            f"{what} (use the pooled estimate and its between-{what[:-1]} spread)")
    return (f"The {a.k} {what} {head}: {100 * a.within_95:.0f} % of {a.pairs} pairwise differences "
            f"within their 95 % interval (95 % expected), median |z| {a.median_abs_z:.2f} (0.67 expected); "
            f"chi2 test of equal parameters {a.chi2:.4g} on {a.dof:.1f} dof, {p_phrase(a.p_value)}{tail}.")



