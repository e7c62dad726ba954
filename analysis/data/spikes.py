"""Isolated spikes in a logged signal: one sample far from its neighbours, which agree.

A sample x_i of a column is a spike when it lies

* more than 4 times the spread (max - min) of its four neighbours x_{i-2}, x_{i-1},
  x_{i+1}, x_{i+2} (the first and last values repeated at the edges) from their median,
  and
* more than `SPIKE_FACTOR` times the column's robust scale, 1.4826 times its median
  absolute deviation (MAD), from that median.

The first test is local and cheap: one compiled pass over every column of a signal at
once (`_neighbour_candidates`). The column's medians are taken only for the columns with a
candidate, and the second median only when the first cannot rule every candidate out
(`_robust_spikes`). A NaN anywhere in a column means no spike in it (the loader refuses
NaN cells before this check; the rule is the one of ``np.median``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["SPIKE_FACTOR", "spikes_of_columns", "isolated_spikes"]

#: A sample farther than this × the column's robust scale (1.4826 × MAD) from the median
#: of its 4 neighbours, which agree among themselves, is an isolated spike.
SPIKE_FACTOR = 20.0

#: Bins of the histogram that bounds how many samples lie near the median (cache-sized).
HISTOGRAM_BINS = 2048

_NONE = (np.array([], dtype=np.intp), 0.0)


@njit(cache=True, nogil=True)
def _neighbour_candidates(X, rows, cols, devs):  # pragma: no cover - compiled
    """Write (row, column, |x - median of the 4 neighbours|) of every sample of X (n, k)
    farther than 4 neighbour spreads from that median, row by row, into the buffers while
    they last; return how many there are (more than the buffers' size: call again with
    larger ones).

    The median of 4 is (2nd + 3rd smallest) / 2, by the sorting network min/max of the
    pairs, in the order of operations that NumPy's ufuncs would use: the same bits."""
    n, k = X.shape
    cap = rows.size
    m = 0
    for i in range(n):
        ia = max(i - 2, 0)
        ib = max(i - 1, 0)
        ic = min(i + 1, n - 1)
        idd = min(i + 2, n - 1)
        for j in range(k):
            a = X[ia, j]
            b = X[ib, j]
            c = X[ic, j]
            d = X[idd, j]
            if a != a or b != b or c != c or d != d:   # a NaN neighbour: a NaN spread, no candidate
                continue
            lo1 = a if a < b else b
            hi1 = a if a > b else b
            lo2 = c if c < d else d
            hi2 = c if c > d else d
            spread = hi1 if hi1 > hi2 else hi2
            spread -= lo1 if lo1 < lo2 else lo2
            spread *= 4.0
            med = (lo1 if lo1 > lo2 else lo2) + (hi1 if hi1 < hi2 else hi2)
            med /= 2.0
            dev = abs(X[i, j] - med)
            if dev > spread:
                if m < cap:
                    rows[m] = i
                    cols[m] = j
                    devs[m] = dev
                m += 1
    return m


@njit(cache=True, nogil=True)
def _densest_window_bound(x, v):  # pragma: no cover - compiled
    """An upper bound on how many samples of x lie within v of any one value (x.size when a
    value is not finite).

    Bins of width w >= v (at most HISTOGRAM_BINS of them): an interval of width 2v meets at
    most 3, and rounding of a sample's bin index moves it by at most one bin, so 5
    neighbouring bins hold the interval's samples."""
    n = x.size
    lo = x[0]
    hi = x[0]
    nan = False
    for t in x:
        lo = min(lo, t)
        hi = max(hi, t)
        nan |= t != t
    w = max(v, (hi - lo) / HISTOGRAM_BINS)
    span = (hi - lo) / w
    if nan or not (w > 0.0) or not (span <= HISTOGRAM_BINS):   # NaN or inf
        return n
    m = int(span) + 1
    inv = 1.0 / w
    if not inv < np.inf:      # w subnormal: int() of an infinite index is undefined
        return n
    h = np.zeros(m + 4, dtype=np.int64)
    for t in x:
        i = int((t - lo) * inv)
        h[min(max(i, 0), m - 1) + 2] += 1
    s = h[0] + h[1] + h[2] + h[3] + h[4]
    best = s
    for i in range(5, m + 4):
        s += h[i] - h[i - 5]
        if s > best:
            best = s
    return best


def _candidates(X: np.ndarray):
    """(rows, columns, deviations) of the neighbour test's candidates of X (n, k), row-major."""
    n, k = X.shape
    cap = min(n * k, 1 << 14)
    while True:
        rows = np.empty(cap, dtype=np.intp)
        cols = np.empty(cap, dtype=np.intp)
        devs = np.empty(cap)
        m = _neighbour_candidates(X, rows, cols, devs)
        if m <= cap:
            return rows[:m], cols[:m], devs[:m]
        cap = m


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
