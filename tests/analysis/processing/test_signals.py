"""Tests of position filtering, differentiation and settings (dynid.analysis.processing.signals)."""

import numpy as np
import pytest

from dynid.analysis.processing.signals import (
    Derivatives,
    default_settings,
    derivatives,
    estimate_bandwidth,
    low_velocity_mask,
    lowpass_filtfilt,
    transient_samples,
    velocity_dead_zone,
    widen_in_time,
)
from dynid.errors import InputError

FS = 5000.0


def _time(seconds, fs=FS):
    return np.arange(int(round(seconds * fs))) / fs


def test_filtfilt_keeps_low_frequency_sine_without_phase_shift():
    fs, fc = 1000.0, 20.0
    t = _time(10.0, fs)
    x = np.column_stack([np.sin(2 * np.pi * 2.0 * t), np.cos(2 * np.pi * 0.7 * t)])
    y = lowpass_filtfilt(x, fs, fc)
    mid = slice(1000, -1000)
    # A one-sample delay at 2 Hz would give 2*pi*2/1000 = 1.3e-2.
    np.testing.assert_allclose(y[mid], x[mid], atol=1e-5)
    # Cross-correlation peaks at zero lag.
    lags = np.arange(-5, 6)
    corr = [np.dot(y[mid][:, 0], np.roll(x[:, 0], k)[mid]) for k in lags]
    assert lags[int(np.argmax(corr))] == 0


def test_filtfilt_removes_high_frequency():
    fs, fc = 1000.0, 20.0
    t = _time(5.0, fs)
    y = lowpass_filtfilt(np.sin(2 * np.pi * 200.0 * t), fs, fc)
    # 4th-order Butterworth applied twice: (20/200)^8 -> far below 1e-6.
    assert np.max(np.abs(y[500:-500])) < 1e-6


def test_filtfilt_shape_and_axis():
    x = np.random.default_rng(0).standard_normal((400, 2, 3))
    y = lowpass_filtfilt(x, 1000.0, 50.0)
    assert y.shape == x.shape
    np.testing.assert_allclose(y[:, 1, 2], lowpass_filtfilt(x[:, 1, 2], 1000.0, 50.0))


@pytest.mark.parametrize("fc", [2500.0, 3000.0, 0.0, -5.0])
def test_filtfilt_bad_cutoff(fc):
    with pytest.raises(InputError, match="fc") as err:
        lowpass_filtfilt(np.zeros(1000), FS, fc)
    assert f"{fc:g}" in str(err.value)


def test_filtfilt_bad_inputs():
    with pytest.raises(InputError, match="at least"):
        lowpass_filtfilt(np.zeros(10), FS, 50.0)
    with pytest.raises(InputError, match="NaN"):
        lowpass_filtfilt(np.r_[np.zeros(100), np.nan, np.zeros(100)], FS, 50.0)
    with pytest.raises(InputError, match="order"):
        lowpass_filtfilt(np.zeros(1000), FS, 50.0, order=0)


def test_derivatives_of_sum_of_sines():
    t = _time(6.0)
    freqs = np.array([0.4, 1.3, 2.9])
    amps = np.array([1.0, 0.3, 0.05])
    phases = np.array([0.2, 1.0, -0.5])
    arg = 2 * np.pi * freqs * t[:, None] + phases
    w = 2 * np.pi * freqs
    q = np.column_stack([(amps * np.sin(arg)).sum(1), (amps * np.cos(arg)).sum(1)])
    qd = np.column_stack([(amps * w * np.cos(arg)).sum(1), -(amps * w * np.sin(arg)).sum(1)])
    qdd = -np.column_stack([(amps * w**2 * np.sin(arg)).sum(1), (amps * w**2 * np.cos(arg)).sum(1)])

    result = derivatives(q, FS, fc=50.0)
    assert isinstance(result, Derivatives) and len(result) == 3
    q_f, qd_f, qdd_f = result
    assert q_f.shape == qd_f.shape == qdd_f.shape == q.shape
    edge = default_settings(FS, q, fc_position=50.0)["edge"]
    mid = slice(edge, -edge)
    np.testing.assert_allclose(q_f[mid], q[mid], atol=1e-6)
    np.testing.assert_allclose(qd_f[mid], qd[mid], atol=1e-4 * np.abs(qd).max())
    np.testing.assert_allclose(qdd_f[mid], qdd[mid], atol=1e-3 * np.abs(qdd).max())


def test_derivatives_are_central_differences_inside_and_flag_edges():
    q = np.random.default_rng(1).standard_normal(300).cumsum()
    fs = 100.0
    res = derivatives(q, fs, fc=10.0)
    assert res.edge == 2 and res.interior == slice(2, 298)
    k = np.arange(2, 298)
    dt = 1 / fs
    qd_c = (res.q[k + 1] - res.q[k - 1]) / (2 * dt)
    np.testing.assert_allclose(res.qd[k], qd_c, rtol=1e-12, atol=1e-9)
    qdd_c = (res.q[k + 2] - 2 * res.q[k] + res.q[k - 2]) / (4 * dt**2)
    np.testing.assert_allclose(res.qdd[k], qdd_c, rtol=1e-9, atol=1e-6)


def test_derivatives_default_cutoff_uses_default_settings():
    t = _time(10.0)
    q = np.sin(2 * np.pi * 1.0 * t) + 0.2 * np.sin(2 * np.pi * 3.0 * t)
    fc = default_settings(FS, q)["fc_position"]
    np.testing.assert_array_equal(derivatives(q, FS).q, lowpass_filtfilt(q, FS, fc))


def _robot_like_motion(seconds=20.0, top=3.0, n_joints=6, seed=0):
    """Joint positions with content up to ``top`` Hz (rad)."""
    rng = np.random.default_rng(seed)
    t = _time(seconds)
    freqs = np.linspace(0.2, top, 8)
    q = np.zeros((t.size, n_joints))
    for j in range(n_joints):
        amps = rng.uniform(0.05, 0.5, freqs.size) / (1 + freqs)
        q[:, j] = (amps * np.sin(2 * np.pi * freqs * t[:, None] + rng.uniform(0, 6, freqs.size))).sum(1)
    return q


def test_estimate_bandwidth_finds_top_frequency():
    q = _robot_like_motion(top=3.0)
    bw = estimate_bandwidth(q, FS)
    assert 3.0 <= bw <= 4.0
    assert 1.5 <= estimate_bandwidth(_robot_like_motion(top=1.5), FS) <= 2.5


def test_estimate_bandwidth_ignores_measurement_noise_and_still_joints():
    rng = np.random.default_rng(2)
    q = _robot_like_motion(top=3.0)
    q += 2e-5 * rng.standard_normal(q.shape)  # encoder-like noise
    q[:, 4] = 0.3 + 2e-5 * rng.standard_normal(q.shape[0])  # a joint that does not move
    assert 3.0 <= estimate_bandwidth(q, FS) <= 4.5


def test_estimate_bandwidth_bad_inputs():
    with pytest.raises(InputError, match="no joint moves"):
        estimate_bandwidth(np.ones((20000, 3)), FS)
    with pytest.raises(InputError, match="energy"):
        estimate_bandwidth(_robot_like_motion(seconds=2.0), FS, energy=1.5)


def test_default_settings_on_5khz_3hz_motion():
    q = _robot_like_motion(top=3.0)
    s = default_settings(FS, q)
    assert set(s) >= {"fc_position", "nd", "f_decimation_cutoff", "edge"}
    assert 50 <= s["nd"] <= 150
    # the position filter stays a decade above the decimated band (signals.py)
    assert s["fc_position"] == pytest.approx(10 * s["f_decimation_cutoff"])
    assert s["f_decimation_cutoff"] == pytest.approx(0.8 * FS / (2 * s["nd"]))
    assert 4 * s["bandwidth"] <= s["f_decimation_cutoff"] <= s["fc_position"]
    assert isinstance(s["edge"], int) and s["edge"] > transient_samples(FS, s["fc_position"])


def test_default_settings_reproduces_paper_decimation():
    s = default_settings(FS, None, bandwidth=5.0)
    assert (s["nd"], s["f_decimation_cutoff"]) == (100, 20.0)
    # the paper filters q at 50 Hz; dynid's default keeps a decade above the
    # 20 Hz band (FIGAROH uses 100 Hz on this robot), and the paper's value
    # stays one override away
    assert s["fc_position"] == 200.0
    s = default_settings(FS, None, bandwidth=5.0, fc_position=50.0)
    assert (s["fc_position"], s["nd"], s["f_decimation_cutoff"]) == (50.0, 100, 20.0)


def test_default_settings_overrides():
    q = _robot_like_motion(seconds=10.0)
    s = default_settings(FS, q, nd=50)
    assert s["nd"] == 50 and s["f_decimation_cutoff"] == pytest.approx(40.0)
    s = default_settings(FS, q, fc_position=80.0, edge=7, f_decimation_cutoff=15.0)
    assert (s["fc_position"], s["edge"], s["f_decimation_cutoff"]) == (80.0, 7, 15.0)
    with pytest.raises(InputError, match="fc="):
        default_settings(FS, q, fc_position=2600.0)
    with pytest.raises(InputError, match="nd"):
        default_settings(FS, q, nd=0)
    with pytest.raises(InputError, match="cut-off"):
        default_settings(FS, q, nd=100, f_decimation_cutoff=30.0)


def test_default_settings_short_record_keeps_enough_samples():
    q = _robot_like_motion(seconds=1.5)
    s = default_settings(FS, q)
    from dynid.analysis.processing.decimation import DecimationFilter

    kept = DecimationFilter(s["nd"], FS).n_outputs(q.shape[0] - 2 * s["edge"])
    assert kept >= 100 and s["nd"] < 100


def test_low_velocity_mask():
    qd = np.array([[0.5, -0.2], [0.01, 1.0], [-0.3, -0.05], [0.2, 0.2]])
    np.testing.assert_array_equal(low_velocity_mask(qd, 0.1), [True, False, False, True])
    np.testing.assert_array_equal(low_velocity_mask(qd, [0.005, 0.25]), [False, True, False, False])
    np.testing.assert_array_equal(low_velocity_mask(qd[:, 0], 0.25), [True, False, True, False])
    with pytest.raises(InputError, match="one value per joint"):
        low_velocity_mask(qd, [0.1, 0.1, 0.1])
    with pytest.raises(InputError, match=">= 0"):
        low_velocity_mask(qd, -1.0)


def test_widen_in_time_is_scipys_binary_dilation():
    """The dead zone's widening is the binary dilation along time by a (2 guard + 1)-sample
    window (scipy.ndimage, the oracle), at the edges too and with guards beyond the record."""
    from scipy import ndimage

    rng = np.random.default_rng(7)
    for _ in range(400):
        N, n, guard = int(rng.integers(1, 300)), int(rng.integers(1, 5)), int(rng.integers(1, 120))
        mask = rng.random((N, n)) < rng.choice([0.002, 0.02, 0.2, 0.9])
        expected = ndimage.binary_dilation(mask, structure=np.ones((2 * guard + 1, 1), dtype=bool))
        np.testing.assert_array_equal(widen_in_time(mask, guard), expected)
        if N < 40:                      # guards beyond the record (clamped to it)
            np.testing.assert_array_equal(widen_in_time(mask, 3 * N + 5), ndimage.binary_dilation(
                mask, structure=np.ones((2 * (3 * N + 5) + 1, 1), dtype=bool)))
    one = np.zeros(9, dtype=bool)
    one[0] = True
    np.testing.assert_array_equal(widen_in_time(one, 2), [1, 1, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(widen_in_time(one, 0), one)
    with pytest.raises(ValueError, match=">= 0"):
        widen_in_time(one, -1)


def test_velocity_dead_zone_guard_widens_each_joint_alone():
    qd = np.ones((12, 2))
    qd[5, 0] = 0.0
    dead = velocity_dead_zone(qd, 0.1, guard=2)
    np.testing.assert_array_equal(np.flatnonzero(dead[:, 0]), [3, 4, 5, 6, 7])
    assert not dead[:, 1].any()


def test_a_recording_too_short_to_see_its_motion_is_called_short():
    """The first 200 samples (0.04 s) of a 5 kHz TX40 log, the robot moving but too slowly for a 0.04 s
    spectrum, were blamed on "no joint moves above the noise" and the advice to check the position
    columns. A robot standing still is still called still."""
    rng = np.random.default_rng(3)
    t = np.arange(200)[:, None] / 5000.0
    q = 0.3 + 0.1 * t + 2e-5 * rng.standard_normal((200, 6))
    with pytest.raises(InputError, match="no joint moves"):
        estimate_bandwidth(0.3 + 2e-5 * rng.standard_normal((200, 6)), 5000.0)
    with pytest.raises(InputError, match=r"lasts 0\.04 s \(200 samples at 5000 Hz\): too short"):
        estimate_bandwidth(q, 5000.0)
