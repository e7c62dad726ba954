"""Isolated spikes in a logged signal: one sample far from its neighbours, which agree.

A sample x_i of a column is a spike when it lies

* more than 4 times the spread (max - min) of its four neighbours x_{i-2}, x_{i-1},
  x_{i+1}, x_{i+2} (the first and last values repeated at the edges) from their median,
  and
* more than `SPIKE_FACTOR` times the column's robust scale, 1.4826 times its median
  absolute deviation (MAD), from that median.

The first test is local and cheap: one compiled, vectorised pass over every column of a
signal at once (`_interior_flags`). The column's medians are taken only for the columns with a
candidate, and the second median only when the first cannot rule every candidate out
(`_robust_spikes`). A NaN anywhere in a column means no spike in it (the loader refuses
NaN cells before this check; the rule is the one of ``np.median``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from dynid.numba_cache import install as _cache_outside_the_package

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

__all__ = ["SPIKE_FACTOR", "spikes_of_columns", "isolated_spikes", "jumps_of_columns"]

#: A sample farther than this × the column's robust scale (1.4826 × MAD) from the median
#: of its 4 neighbours, which agree among themselves, is an isolated spike.
SPIKE_FACTOR = 20.0

#: Bins of the ring histogram that bounds how many samples lie near the median (cache-sized,
#: a power of 2).
HISTOGRAM_BINS = 4096

_NONE = (np.array([], dtype=np.intp), 0.0)


@njit(cache=True, nogil=True)
def _neighbour_test(a, b, c, d, x):  # pragma: no cover - compiled
    """(|x - median of a, b, c, d|, True when that is more than 4 times their spread and
    none of them is NaN).

    The median of 4 is (2nd + 3rd smallest) / 2, by the sorting network min/max of the
    pairs, in the order of operations that NumPy's ufuncs would use: the same bits. A NaN
    neighbour gives no candidate; a NaN x neither (its deviation is NaN)."""
    lo1 = a if a < b else b
    hi1 = a if a > b else b
    lo2 = c if c < d else d
    hi2 = c if c > d else d
    spread = hi1 if hi1 > hi2 else hi2
    spread -= lo1 if lo1 < lo2 else lo2
    spread *= 4.0
    med = (lo1 if lo1 > lo2 else lo2) + (hi1 if hi1 < hi2 else hi2)
    med /= 2.0
    dev = abs(x - med)
    return dev, (dev > spread) & (a == a) & (b == b) & (c == c) & (d == d)


@njit(cache=True, nogil=True)
def _interior_flags(xa, xb, x, xc, xd, flags):  # pragma: no cover - compiled
    """flags[i] = the neighbour test of x[i] against xa[i], xb[i], xc[i], xd[i].

    The five are views of one row-major (n, k) signal, flattened, shifted by -2k, -k, 0, k and
    2k: one branch-free loop over contiguous memory, which LLVM vectorises (about 4x the
    row-by-row loop with the neighbours' indices clamped)."""
    for i in range(flags.size):
        flags[i] = _neighbour_test(xa[i], xb[i], xc[i], xd[i], x[i])[1]


@njit(cache=True, nogil=True)
def _clamped_test(x, i, j, k, n):  # pragma: no cover - compiled
    """`_neighbour_test` of sample (i, j) of the flattened row-major (n, k) signal x, its
    neighbours' rows clamped to the first and the last."""
    a = x[max(i - 2, 0) * k + j]
    b = x[max(i - 1, 0) * k + j]
    c = x[min(i + 1, n - 1) * k + j]
    d = x[min(i + 2, n - 1) * k + j]
    return _neighbour_test(a, b, c, d, x[i * k + j])


@njit(cache=True, nogil=True)
def _deviations(x, p, k, n):  # pragma: no cover - compiled
    """|x - median of its 4 neighbours| at the flat indices p of x (row-major, (n, k))."""
    out = np.empty(p.size)
    for m in range(p.size):
        i = p[m] // k
        out[m] = _clamped_test(x, i, p[m] - i * k, k, n)[0]
    return out


@njit(cache=True, nogil=True)
def _edge_candidates(x, k, n):  # pragma: no cover - compiled
    """Flat indices of the candidates in the first two and the last two rows of x (row-major,
    (n, k), n >= 4)."""
    out = np.empty(4 * k, dtype=np.intp)
    m = 0
    for i in (0, 1, n - 2, n - 1):
        for j in range(k):
            if _clamped_test(x, i, j, k, n)[1]:
                out[m] = i * k + j
                m += 1
    return out[:m]


#: a value of |t / v| beyond which its bin is not an int64 (NaN and inf fail the test too)
_SAFE_BIN = 4.611686018427388e18


@njit(cache=True, nogil=True)
def _densest_window_bound(x, v):  # pragma: no cover - compiled
    """An upper bound on how many samples of x lie within v of any one value (x.size when a
    value is not finite or |x| / v is beyond 2**62).

    One pass, without the column's extremes: sample t goes to bin floor(t / v) modulo
    HISTOGRAM_BINS (a ring). An interval of width 2v meets at most 3 consecutive bins, and
    rounding of t / v moves a sample by at most one bin, so 5 consecutive bins of the ring
    hold the interval's samples; the bins that share a ring position only add to the count.
    Sample k is counted in the (k mod 4)-th of four histograms, summed at the end: a smooth
    signal puts consecutive samples in one bin, and a single histogram chained every
    increment on the one before (twice the time)."""
    n = x.size
    if not v > 0.0:
        return n
    inv = 1.0 / v
    if not inv < np.inf:      # v subnormal
        return n
    h = np.zeros((4, HISTOGRAM_BINS), dtype=np.int64)
    mask = HISTOGRAM_BINS - 1
    m = n - n % 4
    for k in range(0, m, 4):
        f0 = np.floor(x[k] * inv)
        f1 = np.floor(x[k + 1] * inv)
        f2 = np.floor(x[k + 2] * inv)
        f3 = np.floor(x[k + 3] * inv)
        if not (abs(f0) < _SAFE_BIN and abs(f1) < _SAFE_BIN and abs(f2) < _SAFE_BIN and abs(f3) < _SAFE_BIN):
            return n
        h[0, np.int64(f0) & mask] += 1
        h[1, np.int64(f1) & mask] += 1
        h[2, np.int64(f2) & mask] += 1
        h[3, np.int64(f3) & mask] += 1
    for k in range(m, n):
        f = np.floor(x[k] * inv)
        if not abs(f) < _SAFE_BIN:
            return n
        h[0, np.int64(f) & mask] += 1
    g = h[0] + h[1] + h[2] + h[3]
    s = g[HISTOGRAM_BINS - 4] + g[HISTOGRAM_BINS - 3] + g[HISTOGRAM_BINS - 2] + g[HISTOGRAM_BINS - 1] + g[0]
    best = s
    for i in range(1, HISTOGRAM_BINS):
        s += g[i] - g[i - 5 + HISTOGRAM_BINS if i < 5 else i - 5]
        if s > best:
            best = s
    return min(best, n)


def _candidates(X: np.ndarray):
    """(rows, columns, deviations) of the neighbour test's candidates of X (n, k), n >= 4,
    row-major."""
    n, k = X.shape
    x = np.ascontiguousarray(X).reshape(-1)
    m = (n - 4) * k
    flags = np.empty(m, dtype=np.bool_)
    _interior_flags(x[:m], x[k:k + m], x[2 * k:2 * k + m], x[3 * k:3 * k + m], x[4 * k:4 * k + m], flags)
    edges = _edge_candidates(x, k, n)
    head = edges[edges < 2 * k]
    p = np.concatenate([head, np.flatnonzero(flags) + 2 * k, edges[head.size:]])
    rows = p // k
    return rows, p - rows * k, _deviations(x, p, k, n)


def _cannot_be_spikes(dev, within, n) -> bool:
    """True when no candidate (deviations `dev`) can be a spike because the MAD is too large.

    If at most (n - 1) // 2 samples lie within V of the median (``within(V)`` counts them, or
    bounds the count from above), the MAD is at least V; with V the largest deviation /
    (SPIKE_FACTOR * 1.4826), no candidate is then a spike. A count is one pass; the medians a
    copy and a partition each. (A NaN makes the median NaN, hence no spike.)"""
    top = float(dev.max())
    v = top / (SPIKE_FACTOR * 1.4826) * (1.0 + 1e-12)
    return SPIKE_FACTOR * (1.4826 * v) >= top and within(v) <= (n - 1) // 2


def _robust_spikes(y: np.ndarray, cand: np.ndarray, dev: np.ndarray):
    """The candidates `cand` (deviations `dev`) of the column copy `y` (reordered here) that
    are spikes, and the column's robust scale 1.4826 MAD (0.0 when there is no spike)."""
    n = y.size
    med = np.median(y, overwrite_input=True)
    if _cannot_be_spikes(dev, lambda v: int(np.count_nonzero(np.abs(y - med) < v)), n):
        return _NONE
    absdev = np.abs(np.subtract(y, med, out=y), out=y)
    scale = 1.4826 * float(np.median(absdev, overwrite_input=True))
    if not scale > 0:
        return _NONE
    return cand[dev > SPIKE_FACTOR * scale], scale


def spikes_of_columns(X: np.ndarray) -> list:
    """[(row indices of the isolated spikes, robust scale)] for each column of X (n, k);
    (no rows, 0.0) for a column without a spike."""
    X = np.asarray(X, dtype=float)
    n, k = X.shape
    if n < 9:
        return [_NONE] * k
    rows, cols, devs = _candidates(X)
    out = []
    y = np.empty(n)
    for j in range(k):
        sel = cols == j
        if not sel.any():
            out.append(_NONE)
            continue
        x = X[:, j]
        # most columns: their samples are too spread out for the MAD to be small, which a
        # histogram shows without a median
        if _cannot_be_spikes(devs[sel], lambda v, x=x: _densest_window_bound(x, v), n):
            out.append(_NONE)
            continue
        np.copyto(y, x)
        out.append(_robust_spikes(y, rows[sel], devs[sel]))
    return out


def isolated_spikes(x: np.ndarray):
    """(row indices of the isolated spikes, robust scale) of one column `x`."""
    return spikes_of_columns(np.asarray(x, dtype=float).reshape(-1, 1))[0]


@njit(cache=True, nogil=True)
def _jumps(x, factor, floor, first, count, mean, step):  # pragma: no cover - compiled
    """Per column of the row-major (n, k) `x`: the mean |step| and the samples that step away
    and back by more than max(factor * mean, floor) (first row, count, its step). Two passes
    over contiguous rows, no temporaries."""
    n, k = x.shape
    for j in range(k):
        mean[j] = 0.0
        first[j] = -1
        count[j] = 0
    for i in range(1, n):
        for j in range(k):
            mean[j] += abs(x[i, j] - x[i - 1, j])
    for j in range(k):
        mean[j] /= n - 1
    for i in range(1, n - 1):
        for j in range(k):
            lim = max(factor * mean[j], floor)
            d0 = x[i, j] - x[i - 1, j]
            d1 = x[i + 1, j] - x[i, j]
            if abs(d0) > lim and abs(d1) > lim and d0 * d1 < 0.0:
                if count[j] == 0:
                    first[j] = i
                    step[j] = d0
                count[j] += 1


def jumps_of_columns(X: np.ndarray, factor: float, floor: float):
    """(first row or -1, count, mean |step|, the first jump's step) per column of X (n, k), n >= 3:
    the samples that step away from both neighbours, out and back, by more than
    max(factor x the column's mean |step|, floor)."""
    X = np.ascontiguousarray(X, dtype=float)
    k = X.shape[1]
    first, count = np.empty(k, dtype=np.int64), np.empty(k, dtype=np.int64)
    mean, step = np.empty(k), np.zeros(k)
    _jumps(X, float(factor), float(floor), first, count, mean, step)
    return first, count, mean, step
