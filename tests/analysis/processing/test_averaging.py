"""Period averaging and harmonic filtering (Bona & Curatella 2005, sections 2.3 and 3.4).

Simulated data, no robot: a periodic multi-sine "torque" with the paper's
settings (f0 = 0.1 Hz, 5 harmonics, 25 periods at 200 Hz) plus white
Gaussian noise of known standard deviation.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dynid.analysis.processing.averaging import average_periods, estimate_period_shift, harmonic_filter, whole_periods
from dynid.errors import InputError
from dynid.provenance import dumps_json

F0, N_HARM, FS, M = 0.1, 5, 200.0, 25
SIGMA = np.array([0.05, 0.2, 1.0])            # N m, per joint


def periodic_signal(t, n=3, seed=7):
    """A multi-sine at k f0, k = 1..5, plus an offset, per joint."""
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.5, 3.0, (n, N_HARM))
    ph = rng.uniform(0, 2 * np.pi, (n, N_HARM))
    k = np.arange(1, N_HARM + 1)
    x = np.einsum("jk,tjk->tj", amp, np.sin(2 * np.pi * F0 * k * t[:, None, None] + ph))
    return x + np.arange(1, n + 1)


def recording(seed=0, m=M, fs=FS, extra=0):
    t = np.arange(int(round(m * fs / F0)) + extra) / fs
    clean = periodic_signal(t)
    noise = np.random.default_rng(seed).normal(size=clean.shape) * SIGMA
    return t, clean, clean + noise


def test_averaging_25_periods_divides_the_noise_by_5():
    t, clean, tau = recording()
    res = average_periods(t, {"tau": tau}, 1 / F0)
    assert res.n_periods == M and res.samples_per_period == 2000 and not res.resampled
    assert np.all(res.shifts == 0)                 # synchronous periods are left untouched
    # the averaged period's actual error against the noise-free signal
    err_mean = res.mean["tau"] - clean[:2000]
    reduction = SIGMA / err_mean.std(axis=0)
    assert np.all(np.abs(reduction / math.sqrt(M) - 1) < 0.15), reduction
    # the period-to-period estimate of the single-measurement noise
    assert np.all(np.abs(res.sigma["tau"] / SIGMA - 1) < 0.10), res.sigma["tau"]
    assert np.allclose(res.sigma_mean["tau"], res.sigma["tau"] / 5)
    # and sigma_mean predicts the averaged signal's error
    assert np.all(np.abs(err_mean.std(axis=0) / res.sigma_mean["tau"] - 1) < 0.15)
    # noise samples: M P of them per joint, zero mean per sample of the period
    e = res.periods("tau")
    assert e.shape == (M, 2000, 3)
    assert np.allclose(e.sum(axis=0), 0, atol=1e-9)


def test_sigma_estimate_is_unbiased_over_seeds():
    # few periods make the sqrt(M / (M - 1)) factor matter: without it sigma is 13 % low at M = 4
    ratios = []
    for seed in range(20):
        t, _, tau = recording(seed, m=4)
        ratios.append(average_periods(t, {"tau": tau}, 1 / F0, align=False).sigma["tau"] / SIGMA)
    assert np.abs(np.mean(ratios) - 1) < 0.01
    assert np.abs(np.mean(ratios) * math.sqrt(3 / 4) - 1) > 0.1


def test_several_signals_partial_periods_and_n_periods():
    t, clean, tau = recording(extra=137)
    q = 0.01 * clean + np.random.default_rng(3).normal(size=clean.shape) * 1e-4
    res = average_periods(t, {"tau": tau, "q": q}, 1 / F0, n_periods=20)
    assert res.n_periods == 20 and res.dropped_samples == 5 * 2000 + 137
    assert set(res.mean) == {"tau", "q"} and res.mean["q"].shape == (2000, 3)
    assert np.all(np.abs(res.sigma["q"] / 1e-4 - 1) < 0.1)
    d = json.loads(dumps_json(res.to_dict()))
    assert d["n_periods"] == 20 and len(d["sigma"]["q"]) == 3
    assert "20 periods" in res.summary()
    with pytest.raises(InputError):
        average_periods(t, {"tau": tau}, 1 / F0, n_periods=40)
    with pytest.raises(InputError):
        average_periods(t[:3000], {"tau": tau[:3000]}, 1 / F0)     # less than 2 periods
    with pytest.raises(InputError):
        average_periods(t, {"tau": tau[:-1]}, 1 / F0)


def test_alignment_undoes_period_delays():
    t, clean, _ = recording(m=10)
    P = 2000
    delays = np.array([0, 30.0, -24.4, 0.4, 73.3, 0, -50, 16.6, 0.25, -7.7])
    blocks = []
    rng = np.random.default_rng(1)
    tp = np.arange(P) / FS
    for d in delays:
        # the same period delayed by d samples (exactly, the signal is analytic)
        blocks.append(periodic_signal(tp - d / FS) + rng.normal(size=(P, 3)) * SIGMA)
    x = np.concatenate(blocks)
    res = average_periods(t, {"tau": x}, 1 / F0, align=True)
    se = res.lag_se[1:]
    assert np.all(se < 0.1)                    # joint 1 (sigma 0.05 N m) pins the lag down
    err_lag = np.abs(res.lag_estimates - delays)[1:]
    assert np.all(err_lag < 4 * se), err_lag / se
    big = np.abs(delays) > 8 * res.lag_se.max()
    assert np.all(res.shifts[big] == res.lag_estimates[big])          # applied
    assert np.all(res.shifts[np.abs(res.lag_estimates) < 4 * res.lag_se] == 0)  # insignificant: not
    err = res.mean["tau"] - periodic_signal(tp)
    assert np.all(err.std(axis=0) < 1.3 * SIGMA / math.sqrt(10))
    # without alignment the delays smear the average of the least noisy joint
    bad = average_periods(t, {"tau": x}, 1 / F0, align=False)
    assert (bad.mean["tau"] - periodic_signal(tp)).std(axis=0)[0] > 2 * err.std(axis=0)[0]
    assert bad.sigma["tau"][0] > 1.5 * SIGMA[0]
    assert abs(res.sigma["tau"][0] / SIGMA[0] - 1) < 0.1
    # a single estimate
    assert estimate_period_shift(blocks[0], blocks[4]) == pytest.approx(73.3, abs=0.3)


def test_non_integer_samples_per_period_are_resampled():
    fs = 201.37                               # 2013.7 samples per period
    t = np.arange(int(M * fs / F0)) / fs
    clean = periodic_signal(t)
    tau = clean + np.random.default_rng(2).normal(size=clean.shape) * SIGMA
    res = average_periods(t, {"tau": tau}, 1 / F0)
    assert res.resampled and res.samples_per_period == 2014
    assert res.fs == pytest.approx(201.4)
    assert res.notices and "resampled" in res.notices[0]
    assert 0.5 < res.noise_gain < 0.75
    assert np.all(np.abs(res.sigma["tau"] / SIGMA - 1) < 0.10), res.sigma["tau"]
    assert np.all(np.abs((res.mean["tau"] - periodic_signal(res.t)).std(axis=0)[1:]
                         / (SIGMA[1:] / 5) - 1) < 0.25)


def test_harmonic_filter_keeps_the_lines_and_removes_the_rest():
    t, clean, _ = recording(m=12, extra=333)
    rng = np.random.default_rng(4)
    # exactly on the grid: kept to rounding
    assert np.max(np.abs(harmonic_filter(clean, FS, F0, N_HARM) - clean)) < 1e-10
    # off-grid tone on an FFT bin (2.5 f0), above the bandwidth (7 f0 and 13.3 Hz): removed
    tone = (0.7 * np.sin(2 * np.pi * 2.5 * F0 * t) + 0.4 * np.cos(2 * np.pi * 7 * F0 * t)
            + 0.3 * np.sin(2 * np.pi * 13.3 * t))
    y = harmonic_filter(clean + tone[:, None], FS, F0, N_HARM)
    assert np.max(np.abs(y - clean)) < 1e-9
    # a tone between FFT bins leaks only a little into the kept lines
    off = np.sin(2 * np.pi * 0.2537 * t)
    assert np.std(harmonic_filter(off, FS, F0, N_HARM)) < 0.1 * np.std(off)
    # white noise: only 11 of 12000 bins are kept
    noise = rng.normal(size=clean.shape) * SIGMA
    y = harmonic_filter(clean + noise, FS, F0, N_HARM)
    assert np.all((y - clean).std(axis=0) < 0.05 * SIGMA)
    # DC dropped on request; shape kept for 1-D input
    y1 = harmonic_filter(clean[:, 0], FS, F0, N_HARM, keep_dc=False)
    assert y1.shape == (t.size,) and abs(y1[:24000].mean()) < 1e-9
    # the trailing 333 samples are the periodic continuation
    assert np.allclose(y1[-333:], y1[-333 - 2000:-2000])
    assert whole_periods(t.size, FS, F0) == (24000, 12)
    with pytest.raises(InputError):
        harmonic_filter(clean, FS, F0, 1000)       # above Nyquist
    with pytest.raises(InputError):
        harmonic_filter(clean[:1000], FS, F0, N_HARM)   # less than one period
