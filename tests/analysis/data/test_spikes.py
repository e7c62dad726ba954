"""The spike check's compiled route against its definition, term for term (np.median of the 4
neighbours and the median absolute deviation of the column)."""
import numpy as np
import pytest

from dynid.analysis.data.spikes import (
    SPIKE_FACTOR,
    _candidates,
    _densest_window_bound,
    isolated_spikes,
    spikes_of_columns,
)


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
        n = int(rng.choice([8, 9, 10, 11, 64, 1001, 5000]))
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
            got, scale = isolated_spikes(x)
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
    got, scale = isolated_spikes(x)
    want, want_scale = spikes_by_definition(x)
    assert list(got) == list(want) == [n // 2] and scale == want_scale


def test_columns_at_once_are_the_definition():
    """Every column of a 2-D signal, its spikes planted at and beside the edges."""
    rng = np.random.default_rng(3)
    n = 9000
    X = np.sin(np.arange(n)[:, None] / 300 + np.arange(4)) + rng.normal(0, 1e-3, (n, 4))
    at = [0, 1, 2, 4095, 4096, 5000, n - 3, n - 2, n - 1]
    for j, k in enumerate(at):
        X[k, j % 4] += 40.0 * (-1) ** j
    X[:, 3] = np.round(X[:, 3], 2)                      # ties
    got = spikes_of_columns(X)
    for j in range(4):
        want, want_scale = spikes_by_definition(X[:, j].copy())
        np.testing.assert_array_equal(got[j][0], want)
        assert want.size and got[j][1] == want_scale


def test_candidates_are_the_neighbour_test_in_row_major_order():
    # a pulse every 5 samples is a candidate each time (its 4 neighbours agree): 20,000 of them,
    # beside a noisy column's scattered ones
    n = 100_000
    X = np.zeros((n, 2))
    X[2::5, 0] = 1.0
    X[:, 1] = np.random.default_rng(0).normal(size=n)
    rows, cols, devs = _candidates(X)
    p = np.pad(X, ((2, 2), (0, 0)), mode="edge")
    nb = np.stack([p[0:n], p[1:n + 1], p[3:n + 3], p[4:n + 4]], axis=2)
    dev = np.abs(X - np.median(nb, axis=2))
    want_r, want_c = np.nonzero(dev > 4.0 * (nb.max(axis=2) - nb.min(axis=2)))
    assert rows.size > 1 << 14
    np.testing.assert_array_equal(rows, want_r)
    np.testing.assert_array_equal(cols, want_c)
    np.testing.assert_array_equal(devs, dev[want_r, want_c])


def test_densest_window_bound_is_an_upper_bound():
    rng = np.random.default_rng(5)
    for _trial in range(60):
        n = int(rng.integers(2, 3000))
        x = np.round(rng.standard_t(2, n), int(rng.integers(0, 4)))
        v = float(rng.choice([1e-9, 1e-3, 0.05, 0.5, 5.0]))
        s = np.sort(x)
        # the most samples an open interval of width 2v holds: [c, c + 2v) from a sample c
        densest = max(np.searchsorted(s, c + 2 * v) - np.searchsorted(s, c) for c in s)
        assert densest <= _densest_window_bound(x, v) <= n
    # every sample within v of the middle of [c, c + 2v), wherever the bins' edges fall: the
    # bound must count them all
    for _trial in range(200):
        v = float(rng.choice([1e-6, 0.01, 3.0]))
        c = float(rng.uniform(-1e3, 1e3)) * v
        assert _densest_window_bound(c + rng.uniform(0, 2 * v, 500), v) == 500
    x = rng.normal(size=100)
    for bad in (np.nan, np.inf, 1e300):      # 1e300 / 0.1 is beyond the bins' integer range
        y = x.copy()
        y[7] = bad
        assert _densest_window_bound(y, 0.1) == 100
    # many more bins of width v than the ring holds: they share ring positions, and the count
    # stays an upper bound (and far below n, so it still rules candidates out)
    x = np.sin(np.arange(200_000) / 700.0)
    s = np.sort(x)
    densest = max(np.searchsorted(s, c + 2e-5) - np.searchsorted(s, c) for c in s[::97])
    assert densest <= _densest_window_bound(x, 1e-5) < 2000


def test_spike_notices_beside_are_cancelled_when_the_load_fails():
    """`plausibility.spike_notices` queues the last signal's check on the executor it is given;
    leaving its ``with`` block on an exception cancels that check while it waits (the load has
    failed: nobody will read its notices), and without one, `result()` has every notice."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from dynid.analysis.data import plausibility

    rng = np.random.default_rng(4)
    X = np.sin(np.arange(500)[:, None] / 40 + np.arange(2)) + rng.normal(0, 1e-3, (500, 2))
    X[100, 1] += 30.0
    signals = {"q": X.copy(), "tau": X.copy()}
    seen = []
    real = plausibility.spikes_of_columns

    def spy(x):
        seen.append(threading.current_thread().name)
        return real(x)

    plausibility.spikes_of_columns = spy
    try:
        with ThreadPoolExecutor(1, thread_name_prefix="side") as pool:
            gate = threading.Event()
            pool.submit(gate.wait)                       # the scan, still running
            with pytest.raises(ValueError), plausibility.spike_notices(signals, None, None, "f", pool):
                raise ValueError("a time check failed")
            gate.set()
        assert seen == [threading.current_thread().name]  # q here; tau's check never ran
        seen.clear()
        with ThreadPoolExecutor(1, thread_name_prefix="side") as pool:
            with plausibility.spike_notices(signals, None, None, "f", pool) as spikes:
                notices = spikes.result()
        assert len(notices) == 2 and all("sample 101" in n for n in notices)
        assert "isolated spike in q2" in notices[0] and "isolated spike in tau2" in notices[1]
        assert sorted(name.startswith("side") for name in seen) == [False, True]
    finally:
        plausibility.spikes_of_columns = real
