"""What the selection found but did not add to the model (issue 27 items 2 and 3).

* **Findings** (named, not added): time-varying effects (drift, warm-up) that pass the
  selection rule on the identification data. A change during one recording cannot
  predict another one (a drift identified today does not hold tomorrow), so the
  selection never adds them, not even when the validation recording confirms them: a
  plant that warms up from its own start in every run drifts the same way in the
  validation recording, which then rewards the identification's drift by coincidence
  (independent plant, friction warm-up on joints 1 and 2: both drifts were added).
  They are reported by name with their size (the change over the recording, fitted
  with the final model) and evidence (CV gain, LR).
* **Cut effects**: candidates that pass the rule at the last step but were not tried
  because `max_effects` effects were added already; listed with their gain and how to
  include them (`--max-effects`, `diagnose(max_effects=...)`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynid.analysis.diagnosis.problem import fit_wls
from dynid.analysis.results import p_phrase

__all__ = ["Finding", "findings_not_added", "cut_effects", "TIME_VARYING"]

#: effects that describe a change during one recording: they cannot predict another one
TIME_VARYING = ("drift",)


@dataclass
class Finding:
    """An effect significant on the identification data, named but not added to the model."""

    name: str
    joint: int | None
    label: str
    size: str                    # e.g. "friction level changes by 0.21 N m (6 % of Fc5)"
    change: float                # N m over the recording
    rel_change: float | None     # fraction of the joint's Coulomb level (friction drift)
    cv_gain: float
    statistic: float
    p_value: float
    why: str                     # why it was not added

    def sentence(self):
        return (f"{self.label}: {self.size}; CV gain {100 * self.cv_gain:.1f} %, LR {self.statistic:.0f}, "
                f"p_adj {self.p_value:.2g}; not added: {self.why}")

    def to_dict(self):
        return {"name": self.name, "joint": self.joint, "label": self.label, "size": self.size,
                "change_nm": self.change, "relative_change": self.rel_change, "cv_gain": self.cv_gain,
                "statistic": self.statistic, "p_value": self.p_value, "not_added_because": self.why,
                "sentence": self.sentence()}


def cut_effects(steps, max_effects):
    """RankedEffect that pass the rule at the step where `max_effects` stopped the selection."""
    if not steps or not steps[-1].reason.startswith("passes the rule, but max_effects"):
        return []
    # time-varying effects are never added (findings): raising max_effects would not add them
    return [r for r in steps[-1].ranking if r.passes and not r.selected and r.name not in TIME_VARYING]


def findings_not_added(problem, state, ranking, cut, structure=None, alpha=None, exact=False):
    """`Finding` per time-varying effect that passes the rule, or that the structure tests
    found on a joint, and is not in the model.

    A drift whose shape is not the candidate's (an exponential warm-up against the linear
    drift columns) can fail the blocked CV's block count, which extrapolates it in time
    across contiguous blocks (independent plant, warm-up on joints 1 and 2: joint 1's drift
    had LR 339 and a CV gain of 20 %, but better in 3 of 5 blocks), while the
    catalogue-free structure tests find the friction level changing with time on that joint.
    Such a joint is named as a drift too, with the candidate's size and evidence, and the
    structure test that found it.

    Parameters
    ----------
    problem : Problem of the identification data.
    state : the final model's state (delay, effects, cols, names, fit).
    ranking : the final ranking (RankedEffect).
    cut : the effects cut by max_effects (time-varying effects are never among them).
    structure : StructureResult of the final residual with hypotheses (hypotheses.py), or None.
    alpha : the selection's level: an effect that passes the rule in a reduced (essential) model
        but whose Bonferroni p against the full base model (`base_p`, set by the selection) is
        not below it is no finding, as it would not be added. None: not checked.
    exact : the model fits to rounding (`EXACT_FIT`): what passes the rule is rounding-sized,
        and only the structure tests' drifts (not run then) could be named.

    Returns
    -------
    list of Finding
    """
    del cut   # time-varying effects are never cut: they are never added (selection.py)
    drift_flags = {u.joint: u for u in (structure.unexplained if structure is not None else [])
                   if getattr(u, "mechanism", "") in ("drift", "time")}
    out = []
    for r in ranking:
        if r.name not in TIME_VARYING or r.selected:
            continue
        why = "a change during this recording cannot predict another recording"
        u = drift_flags.get(r.joint)
        if r.passes and u is None and (exact or (alpha is not None and np.isfinite(r.base_p)
                                                 and not r.base_p < alpha)):
            continue
        if not r.passes:
            if u is None:
                continue
            why += (f"; found by the structure tests (residual against {u.variable}, {p_phrase(u.p_value)}), the drift "
                    f"candidate being better in {r.folds_better} of {r.n_folds} contiguous blocks only "
                    f"(its shape is not linear in time)")
        change, rel, size = _drift_size(problem, state, r.candidate)
        out.append(Finding(name=r.name, joint=r.joint, label=r.label, size=size, change=change,
                           rel_change=rel, cv_gain=r.cv_gain, statistic=r.statistic,
                           p_value=r.p_value, why=why))
    return out


def _drift_size(problem, state, cand):
    """(change over the recording in N m, relative to Fc_j or None, text) of a drift fitted
    beside the final model."""
    effects = list(state["effects"]) + [cand]
    X = problem.design(state["delay"], effects, cols=state["cols"])
    fit = fit_wls(X, problem.Y, problem.mask, problem.names_for(effects, state["names"]))
    params = list(cand.active_params)
    vals = {p: float(fit.chi[len(fit.names) - len(params) + k]) for k, p in enumerate(params)}
    j = cand.joint
    # the drift's torque on the identification rows: its size against the joint's torque
    tq = problem.decimated([cand])[0] @ np.array([vals[p] for p in params])
    m = problem.mask[:, j - 1]
    rms = float(np.sqrt(np.mean(tq[m, j - 1] ** 2))) if m.any() else float("nan")
    if cand.nonlinear.get("shape") == "friction":
        # columns s qd_j, s sign(qd_j) with s = (t - t0) / T from 0 to 1: the Coulomb level and
        # the viscous coefficient change by the two coefficients over the recording
        named = dict(zip(fit.names, fit.chi))
        change = vals.get(f"Dc{j}", 0.0)
        dv = vals.get(f"Dv{j}", 0.0)
        fc, fv = named.get(f"Fc{j}"), named.get(f"Fv{j}")
        rel = abs(change / fc) if fc else None
        parts = [f"Coulomb level {change:+.3g} N m" + (f" ({100 * rel:.0f} % of Fc{j})" if rel is not None else ""),
                 f"viscous coefficient {dv:+.3g} N m s/rad" + (f" ({100 * abs(dv / fv):.0f} % of Fv{j})" if fv else "")]
        size = (f"friction changes over the recording: {', '.join(parts)}; the drift's torque "
                f"{rms:.3g} N m RMS on joint {j}")
        return change, rel, size
    change = float(np.sum(list(vals.values())))
    return change, None, (f"torque level changes by {change:+.3g} N m over the recording ({rms:.3g} N m "
                          f"RMS on joint {j})")
