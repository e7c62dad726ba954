"""permuted_bins against its definition: np.bincount of the block-permuted residual."""
import numpy as np
import pytest

from dynid.analysis.diagnosis.permuted_bins import permuted_bins, permuted_bins_numpy
from dynid.analysis.diagnosis.structure import _block_perms


@pytest.mark.parametrize("n, L", [(1000, 37), (999, 37), (960, 40), (5, 5), (7, 1)])
def test_bit_for_bit_as_bincount_of_the_block_permutation(n, L):
    rng = np.random.default_rng(n + L)
    y = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)   # sums that round
    gi = rng.integers(0, 50, n)
    nb = -(-n // L)
    # the sample orders of structure._block_perms, from the same draws as the block orders
    orders = _block_perms(n, L, 6, np.random.default_rng(7))
    r = np.random.default_rng(7)
    perms = np.array([r.permutation(nb) for _ in range(6)])
    want = np.array([np.bincount(gi, weights=y[p], minlength=50) for p in orders])
    got = permuted_bins(y, gi, perms, L, 50)
    assert np.array_equal(got, want)
    assert np.array_equal(permuted_bins_numpy(y, gi, perms, L, 50), want)
    out = np.full((8, 50), np.nan)
    assert np.array_equal(permuted_bins(y, gi, perms, L, 50, out=out), want)
    assert np.array_equal(out[:6], want) and np.isnan(out[6:]).all()


def test_blocks_that_do_not_cover_the_samples_are_refused():
    with pytest.raises(ValueError, match="do not cover"):
        permuted_bins(np.ones(10), np.zeros(10, int), np.array([[0, 1]]), 4, 3)
