"""Regressor rows zeroed in the velocity dead zone, and centred rows, in one compiled pass.

Before the parallel decimation (eq. (9)), the rows of a regressor chunk W (m, n, b) whose
joint is in the velocity dead zone are zeroed on both sides of `Y = W chi`; DIDIM's
centred torque (the mean of the commands held over the two periods around a sample) takes
the mean of two neighbouring rows first. With NumPy each is a pass over the chunk (the
mean a new array as well), together more than building the chunk's regressor. Here both
are one pass, in place, with the same operations in the same order: `0.5 * (W[k + 1] + W[k])`,
then times the row's keep (1.0 or 0.0), so the values are NumPy's to the last bit
(tests/analysis/processing/test_row_masks.py checks it).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from dynid.numba_cache import install as _cache_outside_the_package

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

__all__ = ["centred_rows", "zero_dead_rows"]


@njit(cache=True, nogil=True)
def _rows(W, keep, lead):
    m = W.shape[0] - lead
    n, b = W.shape[1], W.shape[2]
    for k in range(m):
        for j in range(n):
            f = keep[k, j]
            if lead:
                for c in range(b):
                    W[k, j, c] = (0.5 * (W[k + 1, j, c] + W[k, j, c])) * f
            else:
                for c in range(b):
                    W[k, j, c] = W[k, j, c] * f


def _checked(W, keep, lead):
    if not (isinstance(W, np.ndarray) and W.ndim == 3 and W.dtype == np.float64 and W.flags.c_contiguous
            and W.flags.writeable):
        raise ValueError("W must be a writeable C-contiguous float64 array (m, n, b)")
    m = W.shape[0] - lead
    if m < 0:
        raise ValueError(f"W has {W.shape[0]} rows; centred rows need at least one")
    if keep is None:
        return np.ones((m, W.shape[1]))
    keep = np.ascontiguousarray(keep, dtype=float)
    if keep.shape != (m, W.shape[1]):
        raise ValueError(f"keep has shape {keep.shape}, expected {(m, W.shape[1])}")
    return keep


def zero_dead_rows(W, keep):
    """`W *= keep[:, :, None]` in place: row (k, j) of the regressor chunk W (m, n, b) zeroed
    where `keep[k, j]` is False (the velocity dead zone). Returns W."""
    _rows(W, _checked(W, keep, 0), 0)
    return W


def centred_rows(W, keep=None):
    """Rows `0.5 * (W[k + 1] + W[k])` for k < m, times `keep[k, j]` when given, written over
    W[:m] of the regressor chunk W (m + 1, n, b). Returns the view W[:m].

    W is linear in chi, so the mean of the rows at t_k and t_k+1 models exactly a torque
    that is the mean of the commands held over the two periods around t_k.
    """
    _rows(W, _checked(W, keep, 1), 1)
    return W[:W.shape[0] - 1]
