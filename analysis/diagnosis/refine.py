"""Refinement of a selected candidate's nonlinear parameter (Stribeck's v_s, the delay d,
a ripple's order) by full-data least squares."""
from __future__ import annotations

import numpy as np
from scipy import optimize

from dynid.analysis.diagnosis.effects import RIPPLE_ORDERS
from dynid.analysis.diagnosis.scoring import weighted_sse

__all__ = ["refine_candidate", "refine_order", "candidate_sse", "ORDER_SCAN_PHASE"]

def refine_candidate(problem, scorer, cand, state, weights):
    """Refine a continuous nonlinear parameter (Stribeck's v_s, the delay d, a ripple's
    order) by full-data LS.

    v_s and d: a bounded 1-D search of the weighted residual sum of squares over
    log|value| within a factor 2 of the best grid value (sign kept). A ripple's
    order: `refine_order`.
    """
    if cand.name == "position_ripple":
        return refine_order(problem, scorer, cand)
    key = {"stribeck": "vs", "time_delay": "d"}.get(cand.name)
    if key is None:
        return cand
    v0 = float(cand.nonlinear[key])
    sgn = 1.0 if v0 > 0 else -1.0

    def sse(logv):
        v = sgn * float(np.exp(logv))
        if cand.name == "time_delay":
            X = problem.design(v, state["effects"], cache=False, cols=problem.all_cols)
            return weighted_sse(X, problem.Y, problem.mask, weights)[0]
        return candidate_sse(problem, scorer, cand.with_nonlinear(**{key: v}))

    a = np.log(abs(v0))
    r = optimize.minimize_scalar(sse, bounds=(a - np.log(2.0), a + np.log(2.0)), method="bounded",
                                 options={"xatol": 0.01})
    if r.success and r.fun < sse(a):
        return cand.with_nonlinear(**{key: sgn * float(np.exp(r.x))})
    return cand


def candidate_sse(problem, scorer, cand):
    """Full-data weighted residual sum of squares of the model plus one one-joint candidate."""
    D = problem.eobs.decimate(cand.columns(problem.signals), joint=cand.joint - 1)
    s = scorer.score([scorer.rows(D)])
    return float(np.sum(s["res"][:, 0] ** 2)) if s["active"][0] else np.inf


#: phase step of the ripple-order scan across the joint's range of motion, rad
ORDER_SCAN_PHASE = 0.2


def refine_order(problem, scorer, cand):
    """The ripple order the residual shows, between the grid's neighbours of the best one.

    The grid (`RIPPLE_ORDERS`) only brackets the order: a ripple of order 7 scored
    at 6 and 8 leaves most of itself in the residual, and the selection then adds 8, 6
    and 5 in turn (TX40 plant, joint 3), three families where there is one. The
    weighted residual sum of squares of the candidate is scanned over the orders
    between the grid's neighbours (or half and 1.5 times the order at the ends), in
    steps that move the ripple's phase by at most `ORDER_SCAN_PHASE` across the
    joint's range of motion (the SSE is multimodal in k on a coarser scan), and the best
    scan point is polished by a bounded 1-D search within one step.
    """
    k0 = float(cand.nonlinear["order"])
    j = cand.joint - 1
    grid = sorted(float(k) for k in RIPPLE_ORDERS)
    lower = [k for k in grid if k < k0 - 1e-9]
    upper = [k for k in grid if k > k0 + 1e-9]
    lo = lower[-1] if lower else 0.5 * k0
    hi = upper[0] if upper else 1.5 * k0
    q = np.asarray(problem.signals.q[:, j], dtype=float)
    span = float(q.max() - q.min())
    if not span > 0:
        return cand
    step = ORDER_SCAN_PHASE / span

    def sse(k):
        return candidate_sse(problem, scorer, cand.with_nonlinear(order=float(k)))

    ks = np.unique(np.concatenate([np.arange(lo, hi + 0.5 * step, step), [k0]]))
    vals = np.array([sse(k) for k in ks])
    ib = int(np.argmin(vals))
    kb = float(ks[ib])
    r = optimize.minimize_scalar(sse, bounds=(max(lo, kb - step), min(hi, kb + step)),
                                 method="bounded", options={"xatol": 1e-3 * max(kb, 1.0)})
    if r.success and r.fun < vals[ib]:
        kb = float(r.x)
    kb = float(f"{kb:.4g}")
    if not sse(kb) < sse(k0):
        return cand
    return cand.with_nonlinear(order=kb)


