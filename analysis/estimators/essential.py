"""Essential parameters (Pham & Gautier, 1991) by backward elimination on %σ.

Starting from the base parameters, the parameter with the largest relative
standard deviation %σ (eq. (15)) is removed, the model is re-estimated with the
same estimator (OLS or WLS), and so on while the relative error norm
‖Y − Wχ̂‖/‖Y‖ stays close to that of the full base model. The essential
parameters are a subset of the base parameters that explains the data almost
as well and is better identified (smaller %σ, better conditioning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.results import IdentificationResult, ParameterResults, percent
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["essential_parameters", "EssentialResult", "with_base_covariance", "with_selection_bias", "has_selection_bias", "EXACT_FIT"]

#: a relative error norm below this (0.01 % of the torque) is an exact fit: a recording without
#: noise, whose residual is rounding and the simulation's integration error. Removing a
#: parameter that keeps the error below it removes nothing the data show, however much the
#: error grows in relative terms (+2.3 % from 3.2e-6 kept MY3R, truly 0, on a noise-free
#: simulated LWR4+); every recording with noise is far above it (0.3-10 %).
EXACT_FIT = 1e-4

_PATH_COLUMNS = ["step", "removed", "rel_std_removed", "max_rel_std_remaining", "rel_error", "n_remaining"]


@dataclass(eq=False, repr=False)
class EssentialResult(ParameterResults):
    """Outcome of `essential_parameters`.

    Attributes
    ----------
    result : IdentificationResult
        Estimate on the essential set.
    base : IdentificationResult
        Estimate on the full base-parameter set the search started from.
    essential : list[str]
        Essential parameter names (in the original column order).
    removed : list[str]
        Removed parameters, in removal order.
    path : pandas.DataFrame
        One row per removal: `step` (1, 2, ...), `removed`,
        `rel_std_removed` (its %σ just before removal, in percent), `max_rel_std_remaining`
        (max %σ of the re-estimated remaining set, in percent), `rel_error` (relative error
        norm after removal, a fraction), `n_remaining`. The %σ are the classic ones the
        search ranks by (eq. (15)), whatever covariance the result reports.
    stop_rule : str
        `"error_growth"`, `"target_rel_std"`, `"rel_std_ratio"` or `"last_parameter"`.
    stop_reason : str
        Human-readable explanation of why the search stopped.
    criteria : dict
        The thresholds used.
    """

    result: IdentificationResult
    base: IdentificationResult
    essential: list
    removed: list
    path: pd.DataFrame
    stop_rule: str
    stop_reason: str
    criteria: dict = field(default_factory=dict)

    @property
    def method(self):
        return f"essential {self.result.method}"

    @property
    def names(self):
        return self.result.names

    @property
    def cov(self):
        return self.result.cov

    def _estimate(self):
        return self.result.chi

    def summary(self) -> str:
        """Criteria, stop reason, removal path, then the essential-set summary."""
        rule = "=" * 78
        lines = [
            "Essential parameters (Pham & Gautier 1991)".center(78),
            rule,
            f"Base parameters: {len(self.essential) + len(self.removed)}    "
            f"essential: {len(self.essential)}    removed: {len(self.removed)}",
            "Criteria: " + ", ".join(f"{k}={v}" for k, v in self.criteria.items()),
            f"Base relative error norm: {percent(self.base.rel_error, 4)}",
            f"Stopped ({self.stop_rule}): {self.stop_reason}",
            "-" * 78,
        ]
        if len(self.path):
            # the path's %sigma columns are in percent already; its rel_error is a fraction (JSON)
            shown = self.path.assign(rel_error=100.0 * self.path["rel_error"]).rename(
                columns={"rel_error": "rel_error_%", "rel_std_removed": "rel_std_removed_%",
                         "max_rel_std_remaining": "max_rel_std_remaining_%"})
            lines.append(shown.to_string(index=False, float_format=lambda x: f"{x:.6g}"))
        else:
            lines.append("No parameter was removed.")
        lines.append(rule)
        lines.append(self.result.summary())
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def to_dict(self) -> dict:
        """JSON-safe dict (NaN and infinities become `None`)."""
        return json_safe(
            {
                "method": "essential",
                # the interface's records (as every result's), the essential model's
                "parameters": self.result._records(),
                "criteria": self.criteria,
                "stop_rule": self.stop_rule,
                "stop_reason": self.stop_reason,
                "essential": self.essential,
                "removed": self.removed,
                "base_rel_error": self.base.rel_error,
                "path": self.path.to_dict(orient="records"),
                "result": self.result.to_dict(),
            }
        )



def _check_criteria(max_error_growth, target_rel_std, rel_std_ratio) -> dict:
    def check(name, value, lower, strict=True):
        if value is None:
            return None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a number or None, got {value!r}.") from None
        if not math.isfinite(v) or (v <= lower if strict else v < lower):
            raise InputError(f"{name} must be a finite number {'>' if strict else '>='} {lower} (or None), got {value!r}.")
        return v

    crit = {
        "max_error_growth": check("max_error_growth", max_error_growth, 0.0, strict=False),
        "target_rel_std": check("target_rel_std", target_rel_std, 0.0),
        "rel_std_ratio": check("rel_std_ratio", rel_std_ratio, 1.0),
    }
    return crit


def _worst(rel_sigma: np.ndarray) -> int:
    # An undefined %σ (χ̂ = σ = 0) says nothing is known about the parameter's
    # significance, so it ranks with the infinite ones; ties go to the first.
    return int(np.argmax(np.where(np.isnan(rel_sigma), np.inf, rel_sigma)))


def _rel_sigma(chi, cov) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * np.sqrt(np.maximum(np.diag(cov), 0.0)) / np.abs(chi)


def essential_parameters(
    W3,
    tau,
    names,
    estimator=ls.ols,
    *,
    max_error_growth: float | None = 0.02,
    target_rel_std: float | None = None,
    rel_std_ratio: float | None = None,
    **estimator_kwargs,
) -> EssentialResult:
    """Essential parameters by iterative removal of the largest %σ (Pham & Gautier 1991).

    Parameters
    ----------
    W3, tau, names
        Base-parameter regressor (N, n, b), torques (N, n), names, as for
        `dynid.analysis.estimators.least_squares.ols`.
        Or `W3` a `Reduction`
        (a recording reduced chunk by chunk) with `tau` and `names` None:
        the same search on its triangles, the same result to rounding.
    estimator : callable
        `ols` or `wls`
        (or any function with the same signature returning an
        `IdentificationResult`).
    max_error_growth : float or None
        Largest accepted relative growth of the relative error norm over the
        full base model: a removal is refused if err_k > (1 + max_error_growth)·err_0.
        Default 0.02, i.e. 2 %. `None` disables this rule.
    target_rel_std : float or None
        Stop as soon as max %σ of the current set is ≤ this value (all the
        remaining parameters are then well identified).
    rel_std_ratio : float or None
        The "%σ ratio criterion": stop as soon as max %σ / min %σ of the current
        set is below this value.
    **estimator_kwargs
        Passed to `estimator` at every step (`row_mask`, `joints`,
        `rank_rtol`, `settings`, `joint_sigma`...).

    Stopping rule
    -------------
    At each step, before removing anything: stop if one parameter is left,
    if max %σ ≤ `target_rel_std`, or if max %σ / min %σ < `rel_std_ratio`.
    Otherwise the parameter with the largest %σ is removed and the model
    re-estimated; if that makes the relative error norm exceed
    (1 + `max_error_growth`)·err_0, the removal is undone and the search stops.

    Why 2 % of cumulative growth: removing a parameter whose true value is zero
    increases ‖ρ‖² by about σ_ρ² (one χ²₁ draw), i.e. ‖ρ‖ by a relative
    1/(2(r − b)) — negligible for the thousands of rows of a robot
    identification, so dozens of useless parameters can go within 2 %, while
    dropping a parameter that matters raises the error by its own contribution,
    usually far more than 2 %. Pham & Gautier accept such a small degradation of
    the error norm in exchange for a simpler, better identified model. The
    growth is measured against err_0 of the full model (not step to step) so
    that many small degradations cannot add up unnoticed.

    Re-estimation and weights
    -------------------------
    For `ols` and `wls` the re-estimates reuse the per-joint QR compression
    of `dynid.analysis.estimators.least_squares` (exact: same solution and residual norms
    as re-solving the full system), so each step costs a b x b solve. With
    `wls` the weights 1/σ_j are fixed to those of the full base model (from
    its OLS residual), so every step minimises the same weighted criterion and
    the error norms along the path are comparable. Any other estimator is
    simply called on the remaining columns at every step.
    """
    crit = _check_criteria(max_error_growth, target_rel_std, rel_std_ratio)
    # The search ranks parameters by the classic %σ of eq. (15) whatever covariance is
    # reported, so the essential set and its estimate do not depend on that choice.
    robust = {k: estimator_kwargs.pop(k) for k in ("uncertainty", "groups", "n_boot", "seed")
              if k in estimator_kwargs}
    if robust.get("uncertainty", "classic") != "classic":
        ls.check_uncertainty(robust["uncertainty"])
    if isinstance(W3, ls.Reduction):
        if robust.get("uncertainty", "classic") != "classic":
            raise InputError("essential_parameters of a Reduction reports the classic covariance only: "
                             "the robust ones need the samples.")
        return _essential_reduced(W3, estimator, crit, estimator_kwargs)
    out = _essential_samples(W3, tau, names, estimator, crit, estimator_kwargs)
    if robust.get("uncertainty", "classic") == "classic":
        return out
    kw = {**estimator_kwargs, **robust}
    if estimator is ls.wls and "joint_sigma" not in kw:
        kw["joint_sigma"] = out.base.joint_sigma
    cols = [out.base.names.index(n) for n in out.essential]
    out.base = estimator(W3, tau, out.base.names, **kw)
    kw["settings"] = out.result.settings
    kw["settings"] = {k: v for k, v in kw["settings"].items() if k != "least_squares"}
    out.result = with_selection_bias(estimator(np.asarray(W3)[:, :, cols], tau, out.essential, **kw),
                                      out.base, cols)
    return out


def with_selection_bias(res, base, cols):
    """The essential estimate's robust covariance: the full model's for the same parameters plus d dᵀ.

    For nested least squares with the same weights, χ̂_e = χ̂_base,e + d, with
    d = A χ̂_d (A = (W_eᵀW_e)⁻¹W_eᵀW_d) the shift caused by removing the parameters
    χ_d: so χ̂_e − χ_e = (χ̂_base,e − χ_e) + d. The first term is the full model's
    error, whose robust covariance (HAC or bootstrap of the full WLS) is the honest
    one; d, an estimate of the removal bias A χ_d, is added in quadrature. The
    essential model's own covariance cov_e = cov_base,e − A cov_d Aᵀ is smaller only
    because it treats the removed parameters as exactly zero, and cov_e + d dᵀ
    (the plug-in mean squared error) still under-covers: d² is a one-degree-of-freedom
    estimate of the squared bias, often far below it. On the independent TX40 plant
    with AR(1) noise and a ripple (benchmarks/coverage_independent.py, seeds
    1000-1099, the rule chosen on them): the bootstrap's essential intervals cover
    80.0 % with cov_e, 87.2 % with cov_e + d dᵀ, 95.5 % with this rule (96.6 % for
    the bound σ_base,e + |d|/1.96, which covers whenever the full model's interval
    does); median width 2.0 times the classic essential σ. Only for the robust
    options: "classic" stays eq. (14) of the essential model, as in the papers.
    """
    cols = np.asarray(cols, dtype=int)
    d = res.chi - base.chi[cols]
    unc = dict(res.settings.get("least_squares", {}).get("uncertainty", {}))
    unc["selection_bias"] = ("full model's covariance of these parameters + d d', d = essential estimate - "
                             "full-model estimate of the same parameters")
    settings = {**res.settings, "least_squares": {**res.settings.get("least_squares", {}), "uncertainty": unc}}
    own = res.bse.to_numpy()
    rms = float(np.sqrt(np.mean((d / np.where(own > 0, own, np.inf)) ** 2))) if d.size else 0.0
    note = (f"the essential sigma is the full model's {unc.get('uncertainty', 'robust')} sigma of the same "
            f"parameters with the bias of removing the others (the essential minus the full model's "
            f"estimate, rms {rms:.2g} of the essential model's own sigma) added in quadrature.")
    cov = base.cov[np.ix_(cols, cols)] + np.outer(d, d)
    return replace(res, cov=cov, settings=settings,
                               notices=list(res.notices) + [note])


def has_selection_bias(res) -> bool:
    """Whether `with_selection_bias` added the removal bias to the covariance of `res`."""
    return "selection_bias" in ((getattr(res, "settings", None) or {}).get("least_squares", {})
                                .get("uncertainty", {}))


def with_base_covariance(ess: EssentialResult, base: IdentificationResult) -> EssentialResult:
    """`ess` with the covariance of `base`, a fit of the same full base model on the same rows
    with another covariance (a robust one, or one with the controller gains' share).

    The essential set and estimate do not change: `ess.base` becomes `base`, and the
    essential estimate's covariance is `base`'s for the same parameters plus the bias of
    removing the others (`with_selection_bias`), the rule `essential_parameters` applies
    for the robust options. DIDIM uses it, whose full model's covariance comes from its
    last Gauss-Newton step.
    """
    cols = [list(base.names).index(n) for n in ess.essential]
    least_squares = {**ess.result.settings.get("least_squares", {}),
                     "uncertainty": dict(base.settings.get("least_squares", {}).get("uncertainty", {}))}
    own = replace(ess.result, settings={**ess.result.settings, "least_squares": least_squares},
                  notices=list(ess.result.notices) + [n for n in base.notices if n not in ess.result.notices])
    return replace(ess, base=base, result=with_selection_bias(own, base, cols))


def _essential_samples(W3, tau, names, estimator, crit, estimator_kwargs):
    base = estimator(W3, tau, names, **estimator_kwargs)
    names = list(base.names)
    fixed_kwargs = dict(estimator_kwargs)
    if estimator is ls.wls and "joint_sigma" not in fixed_kwargs:
        fixed_kwargs["joint_sigma"] = base.joint_sigma

    if estimator is ls.ols or estimator is ls.wls:
        system = ls._build_system(W3, tau, names, fixed_kwargs.get("row_mask"), fixed_kwargs.get("joints"))
        step_fit = _compressed_stepper(system, base, fixed_kwargs)
    else:
        def step_fit(cols):
            res = estimator(np.asarray(W3)[:, :, cols], tau, [names[c] for c in cols], **fixed_kwargs)
            return res.chi, res.rel_std.to_numpy(), res.rel_error, res

    def final(cols, essential, kw):
        return estimator(np.asarray(W3)[:, :, cols], tau, essential, **kw)

    return _search(base, names, step_fit, final, crit, fixed_kwargs, estimator_kwargs)


def _essential_reduced(reduction, estimator, crit, estimator_kwargs):
    """The search of `essential_parameters` on a `Reduction` (chunked recordings)."""
    reduced = {ls.ols: ls.ols_reduced, ls.wls: ls.wls_reduced}.get(estimator, estimator)
    if reduced not in (ls.ols_reduced, ls.wls_reduced):
        raise InputError("essential_parameters of a Reduction needs estimator=ls.ols or ls.wls "
                         "(or their _reduced forms): other estimators need the samples.")
    if {"row_mask", "joints"} & set(estimator_kwargs):
        raise InputError("row_mask and joints apply when a chunk is reduced (ls.reduce_system), "
                         "not to the Reduction.")
    base = reduced(reduction, **estimator_kwargs)
    names = list(base.names)
    fixed_kwargs = dict(estimator_kwargs)
    if reduced is ls.wls_reduced and "joint_sigma" not in fixed_kwargs:
        fixed_kwargs["joint_sigma"] = base.joint_sigma
    step_fit = _compressed_stepper(reduction.system(), base, fixed_kwargs)

    def final(cols, essential, kw):
        return reduced(reduction.columns(cols), **kw)

    return _search(base, names, step_fit, final, crit, fixed_kwargs, estimator_kwargs)


def _search(base, names, step_fit, final, crit, fixed_kwargs, estimator_kwargs):
    cols = np.arange(len(names))
    rel_sigma, err0 = base.rel_std.to_numpy(), base.rel_error
    current_result = base
    rows, removed = [], []
    stop_rule, stop_reason = "last_parameter", "one parameter left"
    while True:
        finite = rel_sigma[np.isfinite(rel_sigma)]
        max_rs = np.inf if finite.size < rel_sigma.size else float(rel_sigma.max())
        if cols.size <= 1:
            break
        if crit["target_rel_std"] is not None and max_rs <= crit["target_rel_std"]:
            stop_rule = "target_rel_std"
            stop_reason = f"max %sigma of the remaining parameters ({max_rs:.4g}) <= target_rel_std ({crit['target_rel_std']:g})"
            break
        if crit["rel_std_ratio"] is not None:
            ratio = max_rs / float(np.nanmin(rel_sigma)) if np.any(~np.isnan(rel_sigma)) else np.inf
            if ratio < crit["rel_std_ratio"]:
                stop_rule = "rel_std_ratio"
                stop_reason = f"max %sigma / min %sigma = {ratio:.4g} < rel_std_ratio ({crit['rel_std_ratio']:g})"
                break
        k = _worst(rel_sigma)
        trial = np.delete(cols, k)
        chi_t, rs_t, err_t, res_t = step_fit(trial)
        limit = (max((1.0 + crit["max_error_growth"]) * err0, EXACT_FIT)
                 if crit["max_error_growth"] is not None else np.inf)
        if not err_t <= limit:
            stop_rule = "error_growth"
            stop_reason = (
                f"removing {names[cols[k]]!r} (%sigma {rel_sigma[k]:.4g}, eq. (15)) would raise the relative "
                f"error norm from {percent(err0, 4)} to {percent(err_t, 4)} (+{100 * (err_t / err0 - 1):.3g} % > "
                f"{100 * crit['max_error_growth']:g} %)"
            )
            break
        removed.append(names[cols[k]])
        rows.append(
            {
                "step": len(removed),
                "removed": names[cols[k]],
                "rel_std_removed": float(rel_sigma[k]),
                "max_rel_std_remaining": float(np.max(np.where(np.isnan(rs_t), np.inf, rs_t))),
                "rel_error": float(err_t),
                "n_remaining": int(trial.size),
            }
        )
        cols, rel_sigma, current_result = trial, rs_t, res_t

    essential = [names[c] for c in cols]
    if current_result is None:
        # Compressed path: one full estimate on the essential set gives the
        # residual array, provenance and notices of a normal result.
        kw = dict(fixed_kwargs)
        kw["settings"] = {
            **(estimator_kwargs.get("settings") or {}),
            "essential_parameters": {**crit, "removed": removed, "stop_rule": stop_rule},
        }
        current_result = final(cols, essential, kw)
    path = pd.DataFrame(rows, columns=_PATH_COLUMNS)
    return EssentialResult(
        result=current_result,
        base=base,
        essential=essential,
        removed=removed,
        path=path,
        stop_rule=stop_rule,
        stop_reason=stop_reason,
        criteria=crit,
    )


def _compressed_stepper(system, base, kwargs):
    """Step function re-estimating a column subset on the compressed system.

    Returns (chi, rel_sigma, rel_error, None); `None` tells the caller that
    no full IdentificationResult was built for the step.
    """
    rtol = ls._check_rtol(kwargs.get("rank_rtol", ls.RANK_RTOL))
    if base.joint_sigma is None:
        weights = np.ones(system.n_joints)
    else:
        sig = np.asarray(kwargs.get("joint_sigma", base.joint_sigma), dtype=float)
        weights = np.where(system.rows > 0, 1.0 / np.where(np.isnan(sig), 1.0, sig), 0.0)
    r = int(system.rows.sum())
    y_norm = math.sqrt(float(system.y_ss.sum()))

    def step(cols):
        fit = ls._fit(system, cols, weights, rtol)
        s2 = fit.ss_weighted / (r - cols.size)  # eq. (13) for the reduced model
        rel_sigma = _rel_sigma(fit.chi, s2 * fit.cov_unscaled)
        with np.errstate(divide="ignore", invalid="ignore"):
            err = math.sqrt(float(fit.ss_joint.sum())) / y_norm
        return fit.chi, rel_sigma, err, None

    return step
