"""The spike check's fast route against its definition, term for term (np.median of the 4
neighbours and the median absolute deviation of the column)."""
import numpy as np
import pytest

from dynid.analysis.data.plausibility import SPIKE_BLOCK, SPIKE_FACTOR, _isolated_spikes, _spikes_of_columns


def spikes_by_definition(x):
    """Samples more than SPIKE_FACTOR robust scales from the median of their 4 neighbours
    (edges repeated) and more than 4 neighbour spreads away; the scale 1.4826 MAD."""
    n = x.size
    if n < 9:
        return np.array([], dtype=int), 0.0
    scale = 1.4826 * float(np.median(np.abs(x - np.median(x))))
    if not scale > 0:
        return np.array([], dtype=int), 0.0
    p = np.pad(x, 2, mode="edge")
    nb = np.stack([p[0:n], p[1:n + 1], p[3:n + 3], p[4:n + 4]], axis=1)
    dev = np.abs(x - np.median(nb, axis=1))
    spread = nb.max(axis=1) - nb.min(axis=1)
    return np.flatnonzero((dev > SPIKE_FACTOR * scale) & (dev > 4.0 * spread)), scale


def columns(rng):
    for trial in range(240):
        n = int(rng.choice([8, 9, 10, 11, 64, 1001, SPIKE_BLOCK + 1, 2 * SPIKE_BLOCK + 2]))
        kind = trial % 6
        if kind == 0:
            x = rng.normal(size=n)
        elif kind == 1:      # smooth signal, tiny noise (a position)
            x = np.sin(np.arange(n) / 50) + rng.normal(0, 1e-4, n)
        elif kind == 2:      # quantised, with ties and signed zeros
            x = -np.round(rng.normal(size=n), 1) * 0.0 ** rng.integers(0, 2, n)
        elif kind == 3:      # mostly constant: zero scale
            x = np.zeros(n)
            x[rng.integers(0, n, 3)] = rng.normal(size=3) * 100
        elif kind == 4:      # a NaN
            x = rng.normal(size=n)
            x[rng.integers(0, n)] = np.nan
        else:                # infinities
            x = rng.normal(size=n)
            x[rng.integers(0, n, 2)] = [np.inf, -np.inf]
        if trial % 2:        # planted spikes
            k = rng.integers(0, n, rng.integers(1, 4))
            x[k] += rng.choice([-1, 1], k.size) * rng.uniform(5, 500, k.size)
        yield np.stack([x, -x], axis=1)[:, 0] if trial % 3 == 0 else x   # strided or not


def test_fast_spike_check_is_the_definition():
    rng = np.random.default_rng(7)
    found = 0
    for x in columns(rng):
        before = x.copy()
        with np.errstate(invalid="ignore"):
            want, want_scale = spikes_by_definition(x)
            got, scale = _isolated_spikes(x)
        np.testing.assert_array_equal(x, before)          # the caller's column is untouched
        np.testing.assert_array_equal(got, want)
        if want.size:
            found += 1
            assert scale == want_scale
    assert found > 40                                     # the spikes were there to find


@pytest.mark.parametrize("n", [9, 50_000])
def test_one_planted_spike_is_found_with_its_scale(n):
    rng = np.random.default_rng(1)
    x = np.sin(np.arange(n) / 500) + rng.normal(0, 1e-3, n)
    x[n // 2] += 50.0                                    # 20 x 1.4826 MAD is about 21
    got, scale = _isolated_spikes(x)
    want, want_scale = spikes_by_definition(x)
    assert list(got) == list(want) == [n // 2] and scale == want_scale


def test_columns_at_once_across_blocks_are_the_definition():
    """Every column of a 2-D signal, its spikes planted at and beside the block edges."""
    rng = np.random.default_rng(3)
    n = 2 * SPIKE_BLOCK + 3
    X = np.sin(np.arange(n)[:, None] / 300 + np.arange(4)) + rng.normal(0, 1e-3, (n, 4))
    at = [0, 1, SPIKE_BLOCK - 2, SPIKE_BLOCK - 1, SPIKE_BLOCK, SPIKE_BLOCK + 1, 2 * SPIKE_BLOCK, n - 2, n - 1]
    for j, k in enumerate(at):
        X[k, j % 4] += 40.0 * (-1) ** j
    X[:, 3] = np.round(X[:, 3], 2)                      # ties
    got = _spikes_of_columns(X)
    for j in range(4):
        want, want_scale = spikes_by_definition(X[:, j].copy())
        np.testing.assert_array_equal(got[j][0], want)
        assert want.size and got[j][1] == want_scale
