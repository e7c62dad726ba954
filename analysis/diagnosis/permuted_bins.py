"""Binned sums of block-permuted residuals, for the permutation null of the spectral-line test.

The structure tests' spectral-line test (`dynid.analysis.diagnosis.structure`) compares the
residual's periodogram against position with its mean over block permutations of the
residual. Each permutation needs the permuted residual summed on the position grid:
`np.bincount(gi, weights=y[p])` with `p` the block order. Built with numpy, every
permutation gathered its own copy of the residual (blocks in the permuted order, the short
last block trimmed) and then binned it: two passes over memory per permutation, at the full
rate most of the structure tests' time.

`permuted_bins` does both in one compiled pass: it walks the permuted blocks and adds each
sample into its bin as it goes, in the same order `np.bincount` adds the gathered copy's
samples (sample by sample, each bin from 0.0), so the sums are the same to the last bit
(tests/analysis/diagnosis/test_permuted_bins.py checks it against the numpy definition).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from dynid.numba_cache import install as _cache_outside_the_package

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

__all__ = ["permuted_bins", "permuted_bins_numpy"]


@njit(cache=True, nogil=True)
def _kernel(Yb, perms, gi, L, short, out):
    nb = perms.shape[1]
    for i in range(perms.shape[0]):
        row = out[i]
        row[:] = 0.0
        s = 0
        for k in range(nb):
            b = perms[i, k]
            length = short if b == nb - 1 else L
            base = b * L
            for r in range(length):
                row[gi[s]] += Yb[base + r]
                s += 1


def permuted_bins(y, gi, perms, L, n_bins, out=None):
    """Sums on the grid `gi` of the residual `y` in each block order of `perms`.

    Parameters
    ----------
    y : array (n,)
        The residual, in time order.
    gi : int array (n,)
        Grid bin of each sample position, in [0, n_bins).
    perms : int array (B, nb)
        Block orders: row i lists the blocks of `L` samples of `y` (the last one holds the
        `n - (nb - 1) L` remaining samples and keeps its order wherever it lands) in the
        order they are laid end to end.
    L : int
        Block length in samples.
    n_bins : int
    out : array (B', n_bins), B' >= B, optional
        Where to write (its first B rows); default a new array.

    Returns
    -------
    array (B, n_bins)
        Row i: `np.bincount(gi, weights=y[p_i], minlength=n_bins)`, `p_i` the sample order of
        block order i (`permuted_bins_numpy`), bit for bit.

    Examples
    --------
    >>> y = np.arange(5.0)
    >>> permuted_bins(y, np.array([0, 0, 1, 1, 1]), np.array([[2, 0, 1]]), 2, 2)
    array([[4., 6.]])
    """
    y = np.ascontiguousarray(y, dtype=float)
    n = y.size
    nb = int(perms.shape[1])
    L = int(L)
    short = n - (nb - 1) * L
    if not 0 < short <= L:
        raise ValueError(f"{nb} blocks of {L} samples do not cover {n} samples")
    Yb = np.zeros(nb * L)
    Yb[:n] = y
    B = int(perms.shape[0])
    res = np.empty((B, int(n_bins))) if out is None else out[:B]
    _kernel(Yb, np.ascontiguousarray(perms, dtype=np.intp), np.ascontiguousarray(gi, dtype=np.intp),
            L, short, res)
    return res


def permuted_bins_numpy(y, gi, perms, L, n_bins):
    """The definition `permuted_bins` computes: each permuted copy of `y` gathered, then binned
    with `np.bincount` (numpy only; for tests and reference)."""
    y = np.asarray(y, dtype=float)
    n = y.size
    out = np.empty((perms.shape[0], int(n_bins)))
    for i, P in enumerate(perms):
        idx = (np.asarray(P)[:, None] * L + np.arange(L)[None, :]).ravel()
        idx = idx[idx < n]                 # the short last block keeps its order
        out[i] = np.bincount(gi, weights=y[idx], minlength=int(n_bins))
    return out
