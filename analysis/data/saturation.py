"""Torque saturation: a joint whose |tau| sits at its maximum for a share of the record.

A notice is given for joint j when |tau_j| is within a relative `SATURATION_REL_TOL` of
its maximum over the record for at least `SATURATION_FRACTION` of the samples, counting
only runs of at least `SATURATION_MIN_RUN` consecutive samples (a drive at its current
limit clips the torque for a while; single samples at the top are ordinary peaks), and
when tau_j is constant throughout or barely varies beside another joint's torque
(`STUCK_SPAN`: the joint was not driven, or its torque not logged).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from dynid.analysis.data._format import _fmt
from dynid.numba_cache import install as _cache_outside_the_package

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

__all__ = ["SATURATION_FRACTION", "SATURATION_MIN_RUN", "SATURATION_REL_TOL", "STUCK_SPAN", "saturation_notices"]

#: Fraction of samples at max |tau| (in long enough runs) that triggers a saturation notice.
SATURATION_FRACTION = 0.005
#: Shortest run of consecutive samples at max |tau| that counts as saturation.
SATURATION_MIN_RUN = 3
#: Relative tolerance for "at its maximum".
SATURATION_REL_TOL = 1e-6
#: A joint torque whose peak-to-peak span is below this fraction of another joint's is named as
#: stuck or not logged: a driven joint's torque carries at least its own inertia and friction (on
#: the TX40, LWR4+ and Panda logs the smallest span is a few % of the largest).
STUCK_SPAN = 1e-3


#: Rows scanned at a time by `_extremes_and_tops`: a block of every column stays in cache while
#: each column of it is scanned.
BLOCK_ROWS = 2048


@njit(cache=True, nogil=True)
def _extremes_and_tops(X, rel_tol):  # pragma: no cover - compiled
    """Per column of X (n, k): (max, min, top = max(max, -min), samples with |x| >= top ×
    (1 - rel_tol), NaN present), in two passes over blocks of `BLOCK_ROWS` rows, each block
    column by column with the extremes in registers (a strided pass per column over the whole
    of a row-major X reads every cache line k times; benchmarks/io.py)."""
    n, k = X.shape
    hi = np.empty(k)
    lo = np.empty(k)
    top = np.empty(k)
    thr = np.empty(k)
    count = np.zeros(k, dtype=np.int64)
    nan = np.zeros(k, dtype=np.bool_)
    for j in range(k):
        hi[j] = X[0, j]
        lo[j] = X[0, j]
    for b in range(0, n, BLOCK_ROWS):
        e = min(n, b + BLOCK_ROWS)
        for j in range(k):
            h = hi[j]
            m = lo[j]
            bad = False
            for i in range(b, e):
                v = X[i, j]
                h = v if v > h else h
                m = v if v < m else m
                bad |= v != v
            hi[j] = h
            lo[j] = m
            nan[j] |= bad
    for j in range(k):
        top[j] = hi[j] if hi[j] > -lo[j] else -lo[j]
        thr[j] = top[j] * (1 - rel_tol)
    for b in range(0, n, BLOCK_ROWS):
        e = min(n, b + BLOCK_ROWS)
        for j in range(k):
            t = thr[j]
            c = 0
            for i in range(b, e):
                v = X[i, j]
                c += (v >= t) | (v <= -t)
            count[j] += c
    return hi, lo, top, count, nan


def saturation_notices(tau: np.ndarray, notices: list[str], what: str) -> None:
    """Append a notice for each joint of tau (n, k) that is constant, barely varies beside the
    other joints (`STUCK_SPAN`), or is saturated."""
    tau = np.ascontiguousarray(tau, dtype=float)
    n_samples = tau.shape[0]
    if n_samples == 0:
        return
    hi, lo, top, counts, nan = _extremes_and_tops(tau, SATURATION_REL_TOL)
    span = np.where(nan, 0.0, hi - lo)
    for j in range(tau.shape[1]):
        if nan[j]:      # as NumPy's max and min: NaN extremes, nothing at the top
            continue
        x = tau[:, j]
        if hi[j] == lo[j]:
            notices.append(
                f"joint {j + 1}: tau{j + 1} is constant ({_fmt(x[0])}) throughout {what}: "
                "check that the joint was driven and its torque logged"
            )
            continue
        others = span.copy()
        others[j] = -np.inf
        k = int(np.argmax(others))              # the widest other joint (k = j: there is none)
        if k != j and span[j] < STUCK_SPAN * span[k]:
            notices.append(
                f"joint {j + 1}: tau{j + 1} barely varies throughout {what} (its peak-to-peak span is "
                f"{100 * float(span[j] / span[k]):.2g} % of tau{k + 1}'s): a torque channel "
                "that is stuck or not logged (its noise alone); check that the joint was driven and its "
                "torque logged"
            )
            continue
        # runs of >= SATURATION_MIN_RUN samples at the top cannot reach the notice's share when
        # all the samples at the top do not: one count instead of the run lengths
        if counts[j] < SATURATION_FRACTION * n_samples:
            continue
        thr = float(top[j]) * (1 - SATURATION_REL_TOL)
        at = x >= thr
        at |= x <= -thr
        d = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        lens = ends - starts
        long = lens >= SATURATION_MIN_RUN
        count = int(lens[long].sum())
        if count and count >= SATURATION_FRACTION * n_samples:
            notices.append(
                f"joint {j + 1}: |tau{j + 1}| sits at its maximum {_fmt(float(top[j]))} for "
                f"{count} samples ({100 * count / n_samples:.2g} % of the record, "
                f"{int(long.sum())} run(s) of ≥ {SATURATION_MIN_RUN} samples): the drive "
                "was probably saturated (current limit). Clipped torques do not follow "
                "the model: exclude those samples or excite less."
            )
