"""Period averaging and harmonic filtering of periodic experiments (Bona & Curatella 2005).

Section 2.3 of Bona & Curatella 2005: a periodic excitation (a finite Fourier
series of period `T = 1 / f0`) is repeated and the recorded periods are
averaged, which lowers the noise and, by the central limit theorem, makes it
Gaussian; the period-to-period spread measures the noise itself (section 3.4:
25 repetitions; the PDF of the noise of Fig. 5). Section 3.4 also keeps, of
the measured torque, only the FFT lines at the excitation's harmonics
`k f0, k <= N` (`harmonic_filter`).

`average_periods`
    * **Cutting.** The recording is cut, from its first sample, into `M`
      whole periods of `P = T fs` samples (`M = floor(n_samples / P)` unless
      `n_periods` is given; the samples after the last whole period are
      dropped and counted). When `T fs` is not an integer (within 1e-6), each
      signal is first resampled by linear interpolation onto `fs' = ceil(T fs) / T`
      so that a period is a whole number of samples; the result says so. Linear
      interpolation at fractional position `mu` scales the variance of white
      noise by `(1 - mu)^2 + mu^2`; the noise estimates are corrected by the
      mean of that factor over the new grid (exact in expectation for white
      noise), and the noise samples themselves are then slightly correlated.
    * **Alignment** (`align=True`). Each period of the signal `align_on`
      (default: the first key; choose the least noisy one, the measured
      positions) is compared with the first period by `estimate_period_shift`:
      the maximum of the circular cross-correlation (the signal is periodic),
      summed over joints weighted by `1 / sigma_j^2` and restricted to the DFT
      bins where the signal's power is 10x the noise's, refined to a fraction
      of a sample by Newton steps on the exact trigonometric correlation. That
      is the least-squares shift; its standard error `se` follows from the
      signal's derivative and the noise (`sigma_j`: the smaller of
      `std(diff(x)) / sqrt(2)` and the unaligned period-to-period spread). A
      lag is applied only when it exceeds both `align_tol` (default 0.05
      sample) and `4 se`: on synchronous periods the estimates are noise and
      nothing is shifted (a shift below a few standard errors changes the
      average by less than the noise anyway). A period is shifted back by its
      lag, the integer part by a circular roll, the fractional part by a
      linear phase in its DFT (band-limited and variance-preserving).
      `lag_estimates`, `lag_se` and the applied `shifts` are reported.
    * **Average and noise.** `mean = (1/M) sum_m x_m` per sample of the period.
      The noise samples are `e_m = (x_m - mean) sqrt(M / (M - 1))`: since
      `E sum_m (x_m - mean)^2 = (M - 1) sigma^2` for white noise of standard
      deviation `sigma`, the mean of `e^2` over all `M P` samples is an
      unbiased estimate of `sigma^2` (`sigma` below is its square root). The
      averaged signal's noise has standard deviation `sigma / sqrt(M)`
      (`sigma_mean`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["AveragedPeriods", "average_periods", "estimate_period_shift", "harmonic_filter",
           "whole_periods", "noise_level"]

_INTEGER_TOL = 1e-6
ALIGN_SIGNIFICANCE = 4.0   # a lag is applied when larger than 4 standard errors


def _as_2d(x, name):
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"signal {name!r} must be an array of numbers") from None
    if a.ndim == 1:
        return a[:, None], True
    if a.ndim != 2:
        raise InputError(f"signal {name!r} must have shape (N,) or (N, n), got {a.shape}")
    return a, False


def _sampling_rate(t, fs):
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InputError("t must be a 1-D array of at least 2 sample times (s)")
    if not np.all(np.isfinite(t)):
        raise InputError("t holds non-finite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise InputError("t must increase strictly")
    step = float(np.median(dt))
    if np.max(np.abs(dt - step)) > 1e-3 * step:
        raise InputError("t is not uniformly sampled (steps differ by more than 0.1 %); resample "
                         "the recording onto a uniform grid first")
    est = (t.size - 1) / (t[-1] - t[0])
    if fs is None:
        return est
    fs = float(fs)
    if not np.isfinite(fs) or fs <= 0 or abs(fs - est) > 1e-3 * est:
        raise InputError(f"fs = {fs!r} Hz does not match the sample times (1 / step = {est:.6g} Hz)")
    return fs


def noise_level(x):
    """Rough per-column noise std of a slowly varying signal: `std(diff(x)) / sqrt(2)`.

    Exact for white noise on a signal that changes little from one sample to
    the next (a band far below fs, as here); an overestimate otherwise.
    """
    x = np.asarray(x, dtype=float)
    x = x.reshape(-1, x.shape[-1])
    return np.std(np.diff(x, axis=0), axis=0) / math.sqrt(2.0)


SIGNAL_BIN_SNR = 10.0      # a DFT bin is "signal" when its power is 10x the noise's


def estimate_period_shift(reference, x, sigma=None, *, return_se=False):
    """Lag (samples, sub-sample) of one period `x` behind `reference`, both (P, n).

    Maximum of the weighted circular cross-correlation
    `c(tau) = sum_j sum_k Re(conj(R_jk) X_jk exp(i w_k tau)) / sigma_j^2` over the
    DFT bins `k` where the reference's power is at least `SIGNAL_BIN_SNR`
    times the noise's (`P sigma_j^2` per bin): the least-squares (Gaussian
    maximum-likelihood) shift, restricted to the band where the signal is.
    The integer peak of `c` is refined by Newton steps on the exact
    (trigonometric) `c(tau)`. `sigma` (n,) defaults to `noise_level`
    of both periods. Positive: `x` is `reference` delayed by that many
    samples. With `return_se` also the standard error
    `sqrt(2 / sum_j sum_t r_j'(t)^2 / sigma_j^2)` (both periods noisy).
    """
    r = np.asarray(reference, dtype=float)
    y = np.asarray(x, dtype=float)
    if r.ndim == 1:
        r, y = r[:, None], y[:, None]
    P = r.shape[0]
    if sigma is None:
        sigma = noise_level(np.concatenate([r, y]))
    sigma = np.asarray(sigma, dtype=float)
    scale = np.max(np.abs(r), axis=0)
    sigma = np.where(sigma > 1e-12 * np.maximum(scale, 1e-300), sigma, 1e-12 * np.maximum(scale, 1.0))
    R = np.fft.rfft(r - r.mean(0), axis=0)
    Y = np.fft.rfft(y - y.mean(0), axis=0)
    w = 2.0 * np.pi * np.arange(R.shape[0]) / P
    mask = np.abs(R) ** 2 >= SIGNAL_BIN_SNR * P * sigma ** 2
    mask[0] = False
    if P % 2 == 0:
        mask[-1] = False                       # the Nyquist bin carries no phase
    C = np.sum(np.where(mask, np.conj(R) * Y / sigma ** 2, 0.0), axis=1)     # (bins,)
    if not np.any(C):
        return (0.0, math.inf) if return_se else 0.0
    c = np.fft.irfft(C, n=P)                   # c(k) for integer k, up to a factor
    tau = float(np.argmax(c))
    if tau > P / 2:
        tau -= P
    for _ in range(8):
        e = C * np.exp(1j * w * tau)
        d1 = -np.sum(w * e.imag)
        d2 = -np.sum(w ** 2 * e.real)
        if d2 >= 0:
            break
        step = float(np.clip(-d1 / d2, -0.5, 0.5))
        tau += step
        if abs(step) < 1e-9:
            break
    if not return_se:
        return tau
    D = np.sum(np.where(mask, (2.0 / P) * w[:, None] ** 2 * np.abs(R) ** 2 / sigma ** 2, 0.0))
    return tau, (math.sqrt(2.0 / D) if D > 0 else math.inf)


def _shift(x, lag):
    """Advance the periodic block x (P, n) by `lag` samples (undo a delay of lag)."""
    P = x.shape[0]
    k = int(np.round(lag))
    frac = lag - k
    out = np.roll(x, -k, axis=0)
    if frac != 0.0:
        freqs = np.fft.rfftfreq(P)                     # cycles per sample
        X = np.fft.rfft(out, axis=0) * np.exp(2j * np.pi * freqs * frac)[:, None]
        out = np.fft.irfft(X, n=P, axis=0)
    return out


@dataclass
class AveragedPeriods:
    """Result of `average_periods` (see the module docstring)."""

    period: float
    fs: float
    samples_per_period: int
    n_periods: int
    t: np.ndarray                     # (P,) times of the averaged period, from 0
    mean: dict                        # name -> (P, n) averaged period
    noise: dict                       # name -> (M P, n) period-to-period noise samples
    sigma: dict                       # name -> (n,) single-measurement noise std
    sigma_mean: dict                  # name -> (n,) std of the averaged signal's noise
    shifts: np.ndarray                # (M,) lags (samples) applied to each period
    lag_estimates: np.ndarray = None  # (M,) estimated lags, applied or not
    lag_se: np.ndarray = None         # (M,) their standard errors
    resampled: bool = False
    noise_gain: float = 1.0           # variance factor of the resampling (1 without)
    dropped_samples: int = 0
    notices: list = field(default_factory=list)

    def periods(self, name):
        """The noise of `name` as (M, P, n): period m minus the mean, scaled by sqrt(M/(M-1))."""
        e = self.noise[name]
        return e.reshape(self.n_periods, self.samples_per_period, -1)

    def summary(self):
        lines = [f"Period averaging: {self.n_periods} periods of {self.period:g} s "
                 f"({self.samples_per_period} samples at {self.fs:g} Hz)"
                 + (" after resampling" if self.resampled else "")
                 + (f", {self.dropped_samples} trailing samples dropped" if self.dropped_samples else "")]
        if self.shifts.size and np.any(self.shifts != 0):
            lines.append(f"  alignment: lags {np.min(self.shifts):+.3f} .. {np.max(self.shifts):+.3f} samples")
        else:
            lines.append("  alignment: none applied")
        for name in self.mean:
            s = ", ".join(f"{v:.4g}" for v in self.sigma[name])
            sm = ", ".join(f"{v:.4g}" for v in self.sigma_mean[name])
            lines.append(f"  {name}: sigma [{s}]; averaged sigma / sqrt(M) [{sm}]")
        lines += [f"  note: {m}" for m in self.notices]
        return "\n".join(lines)

    def to_dict(self):

        return json_safe({
            "period": self.period, "fs": self.fs, "samples_per_period": self.samples_per_period,
            "n_periods": self.n_periods, "resampled": self.resampled, "noise_gain": self.noise_gain,
            "dropped_samples": self.dropped_samples, "shifts": self.shifts,
            "lag_estimates": self.lag_estimates, "lag_se": self.lag_se,
            "sigma": {k: v for k, v in self.sigma.items()},
            "sigma_mean": {k: v for k, v in self.sigma_mean.items()},
            "notices": self.notices,
        })


def average_periods(t, signals, period, n_periods=None, align=True, *, fs=None, align_on=None,
                    align_tol=0.05) -> AveragedPeriods:
    """Cut `signals` into whole periods, align and average them (module docstring).

    `signals`: `{name: (N, n) or (N,)}` sampled at the times `t` (uniform; a 1-D
    signal is one column, its mean is (P, 1));
    `period` in s; `n_periods`: how many periods to use (default all whole
    ones). Returns an `AveragedPeriods`.
    """
    if not isinstance(signals, dict) or not signals:
        raise InputError("signals must be a non-empty dict {name: array (N, n)}")
    t = np.asarray(t, dtype=float)
    fs = _sampling_rate(t, fs)
    try:
        period = float(period)
    except (TypeError, ValueError):
        raise InputError(f"period must be a positive number of seconds, got {period!r}") from None
    if not np.isfinite(period) or period <= 0:
        raise InputError(f"period must be a positive number of seconds, got {period!r}")
    data = {}
    for name, x in signals.items():
        a, _ = _as_2d(x, name)
        if a.shape[0] != t.size:
            raise InputError(f"signal {name!r} has {a.shape[0]} samples but t has {t.size}")
        data[name] = a
    notices = []
    P_exact = period * fs
    P = int(round(P_exact))
    resampled, gain = False, 1.0
    if abs(P_exact - P) > _INTEGER_TOL * P_exact or P < 2:
        P = int(math.ceil(P_exact))
        fs_new = P / period
        n_new = int(math.floor((t[-1] - t[0]) * fs_new + 1e-9)) + 1
        t_new = t[0] + np.arange(n_new) / fs_new
        pos = (t_new - t[0]) * fs                   # fractional sample positions
        mu = pos - np.floor(pos)
        gain = float(np.mean((1 - mu) ** 2 + mu ** 2))
        data = {k: np.stack([np.interp(t_new, t, a[:, j]) for j in range(a.shape[1])], axis=1)
                for k, a in data.items()}
        notices.append(f"a period is {P_exact:.6g} samples at {fs:g} Hz, not a whole number: "
                       f"resampled by linear interpolation to {fs_new:.6g} Hz ({P} samples per "
                       f"period); noise sigma corrected for the interpolation's variance factor "
                       f"{gain:.4f}")
        fs, t, resampled = fs_new, t_new, True
    n_total = t.size
    M_avail = n_total // P
    if n_periods is None:
        M = M_avail
    else:
        M = int(n_periods)
        if M != n_periods or M < 1:
            raise InputError(f"n_periods must be a positive integer, got {n_periods!r}")
        if M > M_avail:
            raise InputError(f"n_periods = {M} but the recording holds only {M_avail} whole "
                             f"periods of {period:g} s")
    if M < 2:
        raise InputError(f"the recording holds {M_avail} whole period(s) of {period:g} s; at least 2 "
                         "are needed to average and to estimate the noise")
    dropped = n_total - M * P
    blocks = {k: a[:M * P].reshape(M, P, a.shape[1]) for k, a in data.items()}
    shifts = np.zeros(M)
    lag_estimates = np.zeros(M)
    lag_se = np.zeros(M)
    if align:
        key = next(iter(blocks)) if align_on is None else align_on
        if key not in blocks:
            raise InputError(f"align_on = {align_on!r} is not one of the signals ({', '.join(blocks)})")
        b = blocks[key]
        spread = b.std(axis=0, ddof=1).mean(axis=0)         # inflated by misalignment
        sig = np.minimum(noise_level(b), spread) / math.sqrt(gain)
        ref = b[0]
        for m in range(1, M):
            lag, se = estimate_period_shift(ref, b[m], sig, return_se=True)
            lag_estimates[m], lag_se[m] = lag, se
            if abs(lag) >= max(align_tol, ALIGN_SIGNIFICANCE * se):
                shifts[m] = lag
        if np.any(shifts != 0):
            for k in blocks:
                blocks[k] = np.stack([_shift(blocks[k][m], shifts[m]) if shifts[m] else blocks[k][m]
                                      for m in range(M)])
            notices.append(f"{int(np.sum(shifts != 0))} of {M - 1} periods aligned on {key!r}: lags "
                           f"from {shifts.min():+.3f} to {shifts.max():+.3f} samples")
    mean, noise, sigma, sigma_mean = {}, {}, {}, {}
    for k, b in blocks.items():
        mu_ = b.mean(0)
        e = (b - mu_) * math.sqrt(M / (M - 1))
        s = np.sqrt(np.mean(e ** 2, axis=(0, 1)) / gain)
        mean[k] = mu_
        noise[k] = e.reshape(M * P, -1)
        sigma[k] = s
        sigma_mean[k] = s / math.sqrt(M)
    return AveragedPeriods(period=period, fs=fs, samples_per_period=P, n_periods=M,
                           t=np.arange(P) / fs, mean=mean, noise=noise, sigma=sigma,
                           sigma_mean=sigma_mean, shifts=shifts, lag_estimates=lag_estimates,
                           lag_se=lag_se, resampled=resampled,
                           noise_gain=gain, dropped_samples=int(dropped), notices=notices)


def whole_periods(n_samples, fs, f0):
    """`(L, M)`: the longest prefix of `n_samples` holding a whole number `M` of periods.

    `M` periods of `1 / f0` at `fs` must be a whole number of samples
    (within 1e-6); raises InputError when no `M >= 1` fits.
    """
    P = float(fs) / float(f0)
    for M in range(int(math.floor(n_samples / P + 1e-9)), 0, -1):
        L = M * P
        if abs(L - round(L)) <= _INTEGER_TOL * max(L, 1.0) and round(L) <= n_samples:
            return int(round(L)), M
    raise InputError(f"no whole number of periods of {1 / float(f0):g} s fits in {n_samples} samples "
                     f"at {float(fs):g} Hz as a whole number of samples; resample (see "
                     "average_periods) or give a longer recording")


def harmonic_filter(x, fs, f0, n_harmonics, *, keep_dc=True):
    """Keep only the FFT lines at `k f0` (`1 <= k <= n_harmonics`, plus DC) of `x`.

    Section 3.4 of Bona & Curatella 2005: the torque's components above the
    excitation's bandwidth (and between its lines) are noise and closed-loop
    effects. The FFT is taken over the longest whole number `M` of periods
    (`whole_periods`), where harmonic `k` falls exactly on bin `k M`;
    every other bin is zeroed. `x`: (N,) or (N, n); the result has the same
    shape: the filtered whole periods, continued periodically over any trailing
    samples.
    """
    a, vec = _as_2d(x, "x")
    try:
        N = int(n_harmonics)
    except (TypeError, ValueError):
        raise InputError(f"n_harmonics must be a positive integer, got {n_harmonics!r}") from None
    if N < 1 or N != n_harmonics:
        raise InputError(f"n_harmonics must be a positive integer, got {n_harmonics!r}")
    fs, f0 = float(fs), float(f0)
    if not (np.isfinite(fs) and fs > 0 and np.isfinite(f0) and f0 > 0):
        raise InputError(f"fs and f0 must be positive frequencies, got {fs!r}, {f0!r}")
    if N * f0 >= fs / 2:
        raise InputError(f"the highest harmonic {N * f0:g} Hz is not below the Nyquist frequency "
                         f"{fs / 2:g} Hz")
    L, M = whole_periods(a.shape[0], fs, f0)
    X = np.fft.rfft(a[:L], axis=0)
    keep = np.zeros(X.shape[0], bool)
    keep[M * np.arange(1, N + 1)] = True
    keep[0] = keep_dc
    X[~keep] = 0.0
    y = np.fft.irfft(X, n=L, axis=0)
    if L < a.shape[0]:
        reps = int(math.ceil(a.shape[0] / L))
        y = np.tile(y, (reps, 1))[:a.shape[0]]
    return y[:, 0] if vec else y
