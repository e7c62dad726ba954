"""Tests of the parallel decimation of eq. (9) (dynid.analysis.processing.decimation)."""

import zlib

import numpy as np
import pytest

from dynid.analysis.processing.decimation import DecimationFilter, ParallelDecimator, decimate
from dynid.errors import InputError

FS = 5000.0
ND = 100


def _sine(f, n=45000, fs=FS):
    t = np.arange(n) / fs
    return t, np.sin(2 * np.pi * f * t)


def test_passband_sine_keeps_amplitude_and_timing():
    # 8 Hz is well inside the pass band (cut-off 20 Hz).  A one-sample delay
    # would already cost 2*pi*8/5000 = 1e-2, so 3e-3 also checks zero phase.
    t, x = _sine(8.0)
    y, idx = decimate(x, ND, fs=FS)
    np.testing.assert_allclose(y, np.sin(2 * np.pi * 8.0 * t[idx]), atol=3e-3, rtol=0)
    assert np.all(idx % ND == 0)


def test_passband_amplitude_error_below_one_percent():
    for f in (1.0, 5.0, 12.0):
        t, x = _sine(f)
        y, idx = decimate(x, ND, fs=FS)
        # Least-squares amplitude of the decimated sine, phase free.
        basis = np.column_stack([np.sin(2 * np.pi * f * t[idx]), np.cos(2 * np.pi * f * t[idx])])
        coef = np.linalg.lstsq(basis, y, rcond=None)[0]
        assert abs(np.hypot(*coef) - 1.0) < 0.01, f
        assert abs(coef[1]) < 1e-3, f  # no phase shift


@pytest.mark.parametrize("f", [25.5, 27.0, 40.0, 123.0, 1000.0, 2499.0])
def test_stopband_sine_attenuated_40_db(f):
    # Above the decimated Nyquist fs/(2 nd) = 25 Hz, would alias.
    _, x = _sine(f)
    y, _ = decimate(x, ND, fs=FS)
    assert np.max(np.abs(y)) < 1e-2


@pytest.mark.parametrize("nd", [1, 2, 7, 10, 100])
def test_indices_and_dropped_counts(nd):
    n = 20000 + 37
    res = decimate(np.zeros(n), nd, fs=FS)
    y, idx = res
    assert np.array_equal(idx, res.indices) and y is res.samples
    assert np.all(np.diff(idx) == nd) and idx[0] % nd == 0
    flt = DecimationFilter(nd, FS)
    # Every kept window lies inside the record...
    assert idx[0] - flt.half_length >= 0 and idx[-1] + flt.half_length <= n - 1
    # ...and the grid samples not kept are exactly the ones counted as dropped.
    assert res.dropped_start + len(idx) + res.dropped_end == (n - 1) // nd + 1
    assert res.dropped_start == idx[0] // nd
    assert res.dropped_end >= 0 and res.n_taps == flt.n_taps


def test_window_beyond_end_is_dropped():
    # One sample fewer than the window of the last output needs drops it.
    flt = DecimationFilter(ND, FS)
    n = flt.min_samples + 3 * ND
    full = decimate(np.ones(n), ND, fs=FS)
    short = decimate(np.ones(n - 1), ND, fs=FS)
    assert len(short.indices) == len(full.indices) - 1
    assert short.dropped_end == full.dropped_end + 1 - (1 if (n - 1) % ND == 0 else 0)


def _random_chunks(rng, n):
    sizes = []
    while sum(sizes) < n:
        sizes.append(int(rng.choice([0, 1, 3, 17, 64, 150, 999, 2500, 7000])))
    sizes[-1] -= sum(sizes) - n
    return sizes


@pytest.mark.parametrize("shape", [(), (3,), (3, 4)])
@pytest.mark.parametrize("nd,factors", [(100, None), (100, (100,)), (100, (10, 10)), (7, None), (12, None)])
def test_streaming_equals_in_memory(shape, nd, factors):
    rng = np.random.default_rng(zlib.crc32(repr((shape, nd, factors)).encode()))
    n = 23457
    x = rng.standard_normal((n,) + shape) + 5.0
    ref = ParallelDecimator(nd, n_samples_total=n, fs=FS, factors=factors)
    expected = ref.push(x)
    ref.finish()
    if factors is None:
        np.testing.assert_array_equal(expected, decimate(x, nd, fs=FS).samples)

    dec = ParallelDecimator(nd, fs=FS, factors=factors)
    outs, pos = [], 0
    for size in _random_chunks(rng, n):
        outs.append(dec.push(x[pos : pos + size]))
        pos += size
        for stage in dec._stages:  # bounded memory: only a tail is kept
            assert stage.tails[0].shape[0] <= len(stage.poly.ravel()) + stage.down
    outs.append(dec.finish())
    got = np.concatenate(outs)
    assert got.shape == expected.shape == (len(ref.indices),) + shape
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_array_equal(dec.indices, ref.indices)
    assert (dec.dropped_start, dec.dropped_end) == (ref.dropped_start, ref.dropped_end)


def test_streaming_several_arrays_share_indices():
    rng = np.random.default_rng(3)
    n, n_joints, n_params = 12000, 6, 5
    w = rng.standard_normal((n, n_joints, n_params))
    tau = rng.standard_normal((n, n_joints))
    dec = ParallelDecimator(ND, fs=FS)
    w_out, tau_out = [], []
    for start in range(0, n, 1234):
        wd, td = dec.push(w[start : start + 1234], tau[start : start + 1234])
        w_out.append(wd)
        tau_out.append(td)
    wd, td = dec.finish()
    assert wd.shape == (0, n_joints, n_params) and td.shape == (0, n_joints)
    w_ref, idx = decimate(w, ND, fs=FS)
    tau_ref, idx_tau = decimate(tau, ND, fs=FS)
    np.testing.assert_array_equal(idx, idx_tau)
    np.testing.assert_array_equal(dec.indices, idx)
    np.testing.assert_allclose(np.concatenate(w_out), w_ref, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(np.concatenate(tau_out), tau_ref, rtol=1e-12, atol=1e-13)


def test_parallel_property():
    # eq. (9): decimating W then multiplying by chi is decimating Y = W chi.
    rng = np.random.default_rng(4)
    w = rng.standard_normal((15000, 6, 8))
    chi = rng.standard_normal(8)
    lhs, idx1 = decimate(w @ chi, ND, fs=FS)
    rhs, idx2 = decimate(w, ND, fs=FS)
    np.testing.assert_array_equal(idx1, idx2)
    np.testing.assert_allclose(lhs, rhs @ chi, rtol=1e-10, atol=1e-12)


def test_normalised_frequency_default():
    x = np.random.default_rng(5).standard_normal(5000)
    a = decimate(x, 10)
    b = decimate(x, 10, fs=FS, cutoff=0.8 * FS / 20)
    np.testing.assert_allclose(a.samples, b.samples, rtol=1e-12, atol=1e-14)


def test_custom_cutoff():
    t, x = _sine(8.0)
    y, _ = decimate(x, ND, fs=FS, cutoff=5.0)  # 8 Hz is now in the stop band
    assert np.max(np.abs(y)) < 1e-2
    t, x = _sine(2.0)
    y, idx = decimate(x, ND, fs=FS, cutoff=5.0)
    np.testing.assert_allclose(y, np.sin(2 * np.pi * 2.0 * t[idx]), atol=3e-3)


def test_regressor_sized_array_is_decimated_column_by_column():
    # a regressor-sized block (samples x joints x parameters) in one call gives what each column
    # gives alone; its speed is measured by benchmarks/regressor.py, not by a timed test
    x = np.random.default_rng(6).standard_normal((45000, 6, 60))
    y, idx = decimate(x, ND, fs=FS)
    assert y.shape == (len(idx), 6, 60)
    for j, k in ((0, 0), (3, 17), (5, 59)):
        yj, idx_j = decimate(x[:, j, k], ND, fs=FS)
        np.testing.assert_array_equal(idx_j, idx)
        np.testing.assert_allclose(y[:, j, k], yj, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("nd", [0, -3, 2.5, "10", True])
def test_bad_nd(nd):
    with pytest.raises(InputError, match="nd"):
        decimate(np.zeros(10000), nd, fs=FS)


@pytest.mark.parametrize("cutoff", [25.0, 30.0, 0.0, -1.0])
def test_bad_cutoff(cutoff):
    with pytest.raises(InputError, match=r"fs/\(2 nd\)"):
        decimate(np.zeros(10000), ND, fs=FS, cutoff=cutoff)


def test_too_short_signal():
    flt = DecimationFilter(ND, FS)
    with pytest.raises(InputError, match=f"at least {flt.min_samples}"):
        decimate(np.zeros(flt.min_samples - 1), ND, fs=FS)
    assert len(decimate(np.zeros(flt.min_samples), ND, fs=FS).indices) == 1
    dec = ParallelDecimator(ND, fs=FS)
    dec.push(np.zeros((500, 2)))
    with pytest.raises(InputError, match="longer record"):
        dec.finish()
    with pytest.raises(InputError, match="at least"):
        ParallelDecimator(ND, n_samples_total=100, fs=FS)


def test_non_finite_input():
    x = np.zeros((20000, 2))
    x[7000, 1] = np.nan
    with pytest.raises(InputError, match="sample 7000 contains NaN"):
        decimate(x, ND, fs=FS)


def test_streaming_misuse():
    dec = ParallelDecimator(ND, n_samples_total=10000, fs=FS)
    dec.push(np.zeros((4000, 3)))
    with pytest.raises(InputError, match="shapes"):
        dec.push(np.zeros((100, 4)))
    with pytest.raises(InputError, match="n_samples_total"):
        dec.push(np.zeros((7000, 3)))
    with pytest.raises(InputError, match="n_samples_total"):
        dec.finish()
    with pytest.raises(InputError, match="same number of samples"):
        ParallelDecimator(ND, fs=FS).push(np.zeros(10), np.zeros(11))
