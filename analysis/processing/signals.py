"""Filtering and differentiation of measured joint positions.

The IDIM regressor of eq. (8) is built from (q_hat, qd_hat, qdd_hat): the
joint positions low-pass filtered forward and backward (zero phase), and the
velocities and accelerations obtained from them by central differences
(Gautier, Janot & Vandanjon 2010, section 2 and section 5: 50 Hz Butterworth
at f_m = 5 kHz).  The functions below work on NumPy arrays with time on
axis 0 (`(N,)` or `(N, n_joints)`), in SI units and radians.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import signal

from dynid.analysis.processing.decimation import DecimationFilter
from dynid.errors import InputError
from dynid.ranges import check_range

#: Samples at each end whose derivatives come from one-sided formulas.
DIFFERENCE_EDGE = 2
#: Length of the Welch segments used by :func:`estimate_bandwidth`, in s.
WELCH_SEGMENT_SECONDS = 4.0
#: Rule constants of :func:`default_settings` (see its docstring).
FC_PER_BANDWIDTH = 10.0
FC_PER_DECIMATED_CUTOFF = 10.0
FC_MIN_HZ = 5.0
FC_MAX_PER_FS = 0.2
DECIMATED_CUTOFF_PER_BANDWIDTH = 4.0
MIN_DECIMATED_SAMPLES = 100
#: A filter transient is over once the impulse response stays below this
#: fraction of its peak.  Small because differentiating twice amplifies the
#: end transient by about (fc / bandwidth)^2 relative to the acceleration.
TRANSIENT_TOLERANCE = 1e-5


class Derivatives(NamedTuple):
    """Filtered position and its first two derivatives, time on axis 0.

    Unpacks as `q_f, qd, qdd`.  The first and last `edge` samples of
    `qd` and `qdd` come from one-sided differences; drop them (use
    `interior`) before building the regressor.
    """

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    edge = DIFFERENCE_EDGE

    @property
    def interior(self) -> slice:
        """Slice of the samples computed with central differences only."""
        return slice(DIFFERENCE_EDGE, len(self.q) - DIFFERENCE_EDGE)


def _positive(value, name: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}.") from None
    if not math.isfinite(value) or value <= 0.0:
        raise InputError(f"{name} must be a positive finite number, got {value!r}.")
    return value


def _order(order) -> int:
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise InputError(
            f"filter order must be a positive integer, got {order!r}; use e.g. order=4."
        )
    return int(order)


def _time_major(x, name: str, min_samples: int = 1) -> np.ndarray:
    """Return `x` as a finite float array with at least `min_samples` rows."""
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        raise InputError(f"{name} must be an array with time on axis 0, got a scalar.")
    if x.shape[0] < min_samples:
        raise InputError(
            f"{name} has {x.shape[0]} samples but at least {min_samples} are needed; "
            "use a longer recording."
        )
    bad = ~np.isfinite(x)
    if bad.any():
        where = np.argwhere(bad)[0]
        raise InputError(
            f"{name} contains NaN or inf at index {tuple(int(i) for i in where)}; "
            "remove or interpolate the missing samples first."
        )
    return x


def _butter_sos(fs: float, fc: float, order: int) -> np.ndarray:
    fs = _positive(fs, "sampling frequency fs")
    fc = _positive(fc, "cut-off frequency fc")
    if fc >= fs / 2:
        raise InputError(
            f"cut-off frequency fc={fc:g} Hz must be below the Nyquist frequency "
            f"fs/2={fs / 2:g} Hz (fs={fs:g} Hz); lower fc."
        )
    return signal.butter(_order(order), fc, btype="low", output="sos", fs=fs)


def lowpass_filtfilt(x, fs, fc, order=4) -> np.ndarray:
    """Zero-phase Butterworth low-pass of `x` along axis 0.

    Forward and reverse filtering (`scipy.signal.sosfiltfilt`) as used for
    q_hat in section 5 ("forward and reverse Butterworth filter"), so the
    filtered position has no delay with respect to the torque of eq. (8).
    The magnitude response is that of the Butterworth filter squared: the
    gain at `fc` is 0.5 (-6 dB).

    Parameters
    ----------
    x : array, shape (N, ...)
    fs : sampling frequency, Hz.
    fc : cut-off frequency, Hz, `0 < fc < fs/2`.
    order : order of the Butterworth prototype (applied twice).
    """
    sos = _butter_sos(fs, fc, order)
    # Pass padlen explicitly so the length check below matches what
    # sosfiltfilt needs (its own ValueError would not say what to do).
    padlen = 3 * (2 * sos.shape[0] + 1)
    x = _time_major(x, "signal", min_samples=padlen + 1)
    return signal.sosfiltfilt(sos, x, axis=0, padlen=padlen)


def derivatives(q, fs, fc=None, order=4) -> Derivatives:
    """Filtered position, velocity and acceleration of `q` (section 5).

    These are the (q_hat, qd_hat, qdd_hat) of eqs. (6) and (8).

    `q_f = lowpass_filtfilt(q, fs, fc, order)`; `qd` and `qdd` are
    central differences of `q_f` with `dt = 1/fs`:
    `qd[k] = (q_f[k+1] - q_f[k-1]) / (2 dt)` and `qdd` is the same
    central difference applied to `qd`.  The first and last
    `DIFFERENCE_EDGE = 2` samples use second-order one-sided formulas
    (`np.gradient(edge_order=2)`); they are flagged by `result.edge` /
    `result.interior` and should be dropped.  The filter transient at the
    ends is longer: see `default_settings(...)["edge"]`.

    `fc=None` uses the cut-off proposed by `default_settings`.

    Returns a `Derivatives` `(q_f, qd, qdd)`, each shaped like `q`.
    """
    fs = _positive(fs, "sampling frequency fs")
    if fc is None:
        fc = default_settings(fs, q, order=order)["fc_position"]
    q_f = lowpass_filtfilt(q, fs, fc, order)
    if q_f.shape[0] < 2 * DIFFERENCE_EDGE + 1:
        raise InputError(
            f"q has {q_f.shape[0]} samples; at least {2 * DIFFERENCE_EDGE + 1} are "
            "needed to differentiate it."
        )
    dt = 1.0 / fs
    qd = np.gradient(q_f, dt, axis=0, edge_order=2)
    qdd = np.gradient(qd, dt, axis=0, edge_order=2)
    return Derivatives(q_f, qd, qdd)


def default_position_cutoff(bandwidth, fs) -> float:
    """The position filter's default cut-off, Hz: 10 B rounded up to a multiple of 5 Hz, within
    [FC_MIN_HZ, FC_MAX_PER_FS fs] (`default_settings`' rule before any decimation raises it)."""
    fc = 5.0 * math.ceil(FC_PER_BANDWIDTH * bandwidth / 5.0)
    return float(min(max(fc, FC_MIN_HZ), FC_MAX_PER_FS * fs))


def estimate_bandwidth(q, fs, energy=0.99) -> float:
    """Frequency (Hz) below which `energy` of the motion's velocity power lies.

    For each joint: the velocity `diff(q) * fs` is analysed with
    `scipy.signal.welch` (Hann segments of `WELCH_SEGMENT_SECONDS` = 4 s,
    or the whole record if shorter, each segment mean-detrended); the
    returned frequency is the first Welch bin where the cumulative power
    reaches `energy` of the total.  The maximum over joints is returned.

    Measurement noise on q is taken as white; its velocity spectrum
    `s2 * 4 sin^2(pi f / fs)` rises with frequency and at kHz rates would
    otherwise own the top 1 %.  `s2` is the largest of its fits on the
    bands fs/16-fs/8, fs/8-fs/4 and fs/4-fs/2 (where robot motion has no
    power): on a log that was resampled or low-passed before it reached
    dynid (the Panda's, interpolated onto a uniform grid from 4-decimal
    positions) the top band is attenuated and a fit there alone would leave
    noise to be read as motion up to hundreds of Hz.
    Joints whose remaining power is not clearly above the uncertainty of
    that subtraction (10x) are considered still and ignored.

    The resolution is 1/4 Hz, so a pure tone at f0 reads as about f0 + 0.5 Hz
    (Hann main lobe): the estimate errs high, which is the safe side for
    choosing cut-offs.

    Raises InputError if no joint moves above the noise.
    """
    fs = _positive(fs, "sampling frequency fs")
    energy = float(energy)
    if not 0.0 < energy < 1.0:
        raise InputError(f"energy must be a fraction in (0, 1), got {energy!r}; e.g. 0.99.")
    q = _time_major(q, "q", min_samples=17)
    v = np.diff(q.reshape(q.shape[0], -1), axis=0) * fs
    nperseg = min(v.shape[0], max(16, int(round(WELCH_SEGMENT_SECONDS * fs))))
    f, power = signal.welch(v, fs=fs, nperseg=nperseg, detrend="constant", axis=0)

    shape = 4.0 * np.sin(np.pi * f / fs) ** 2
    # Mean, not median: the median of a chi-square PSD estimate is biased low
    # and the left-over noise would be read as motion at high frequency.
    fits = []
    for lo, hi in ((fs / 16, fs / 8), (fs / 8, fs / 4), (fs / 4, fs / 2 + 1.0)):
        band = (f >= lo) & (f < hi)
        if band.sum() >= 2:
            fits.append(np.mean(power[band] / shape[band, None], axis=0))
    s2 = np.max(fits, axis=0)
    noise = s2 * shape[:, None]
    motion = power - noise
    cumulative = np.cumsum(motion, axis=0)
    total = cumulative[-1]

    n_segments = 1 + (v.shape[0] - nperseg) // max(1, nperseg // 2)
    uncertainty = noise.sum(axis=0) / math.sqrt(len(f) * n_segments)
    moving = (total > 10.0 * uncertainty) & (total > 0.0)
    duration = q.shape[0] / fs
    if not moving.any() and duration < WELCH_SEGMENT_SECONDS and _drifts_beyond_noise(q):
        raise InputError(
            f"the recording lasts {duration:.3g} s ({q.shape[0]} samples at {fs:g} Hz): too short to tell its "
            f"motion from the measurement noise (the motion bandwidth is read from a spectrum of "
            f"{WELCH_SEGMENT_SECONDS:g} s segments). Give a recording of several periods of the excitation, "
            "at least a few seconds."
        )
    if not moving.any():
        raise InputError(
            "no joint moves clearly above the measurement noise, so the motion "
            "bandwidth cannot be estimated: check that the position columns hold the motion "
            "(the right columns, in rad) and that the recording covers it (several periods of "
            "the excitation). In Python the settings key 'bandwidth' (Hz) gives it; the command "
            "line has no option for it."
        )
    reached = cumulative[:, moving] >= energy * total[moving]
    return float(f[np.argmax(reached, axis=0)].max())


def _drifts_beyond_noise(q) -> bool:
    """Whether some joint's positions span more than 20 times their noise (the RMS of their second
    differences / sqrt(6), white noise's): a motion too slow for a short record's spectrum, not a
    robot standing still."""
    q = q.reshape(q.shape[0], -1)
    if q.shape[0] < 3:
        return False
    noise = np.std(np.diff(q, n=2, axis=0), axis=0) / math.sqrt(6.0)
    return bool(np.any(np.ptp(q, axis=0) > 20.0 * noise))


def _nice_floor(value: float) -> int:
    """Largest integer of the 1-2-5 series (1, 2, 5, 10, 20, ...) <= value."""
    if value < 1.0:
        return 1
    decade = 10 ** int(math.floor(math.log10(value)))
    for mantissa in (5, 2, 1):
        if mantissa * decade <= value:
            return mantissa * decade
    return decade  # pragma: no cover - unreachable


def _nice_below(nd: int) -> int:
    """Next 1-2-5 value strictly below `nd` (1 stays 1)."""
    return 1 if nd <= 1 else _nice_floor(nd - 1)


def transient_samples(fs, fc, order=4) -> int:
    """Samples until the Butterworth impulse response stays < 1e-5 of its peak."""
    sos = _butter_sos(fs, fc, order)
    n = int(math.ceil(40.0 * order * fs / fc)) + 16
    impulse = np.zeros(n)
    impulse[0] = 1.0
    h = np.abs(signal.sosfilt(sos, impulse))
    return int(np.nonzero(h >= TRANSIENT_TOLERANCE * h.max())[0][-1]) + 1


def default_settings(
    fs,
    q=None,
    *,
    bandwidth=None,
    fc_position=None,
    nd=None,
    f_decimation_cutoff=None,
    edge=None,
    order=4,
) -> dict:
    """Propose the filtering and decimation settings of eqs. (8)-(9).

    Rules (B = motion bandwidth, `estimate_bandwidth` of `q` unless
    `bandwidth` is given):

    * `fc_position` = 10 B rounded up to a multiple of 5 Hz and clipped to
      [5 Hz, 0.2 fs], and at least 10 x the decimation cut-off (rounded up
      to 5 Hz) so the position filter does not distort the decimated band: the position filter must pass the motion and its
      derivatives' harmonics, but cut the noise that differencing amplifies.
    * `nd` = the largest value of the 1-2-5 series (1, 2, 5, 10, 20, 50,
      100, ...) whose decimated cut-off 0.8 fs / (2 nd) is >= 4 B, raised if
      needed so the cut-off is <= `fc_position` (no point decimating above
      the position filter), then lowered until the decimated record (after
      `edge` and the decimation filter) keeps >= 100 samples.
    * `f_decimation_cutoff` = 0.8 fs / (2 nd), the paper's choice.
    * `edge` = `transient_samples` of the position filter (impulse
      response above 1e-5 of its peak) + 2 samples of one-sided
      differences: samples to drop at each end of q_f, qd, qdd and tau
      before decimating.  The decimation drops its own transient itself.

    At fs = 5 kHz and B = 3-5 Hz this gives nd = 100, a 20 Hz decimated
    cut-off and fc_position = 200 Hz (the paper uses 50 Hz, 100 and 20 Hz;
    FIGAROH 100 Hz on the same robot).

    Every keyword overrides the proposal; the others are then derived from
    it.  `q` may be None when `bandwidth` is given (no length check).

    Returns a dict with keys `fc_position`, `nd`, `f_decimation_cutoff`,
    `edge` and, for information, `bandwidth`.
    """
    fs = _positive(fs, "sampling frequency fs")
    n_samples = None
    if q is not None:
        n_samples = _time_major(q, "q").shape[0]
    if bandwidth is None:
        if q is None:
            raise InputError(
                "default_settings needs the positions q or an explicit bandwidth=... (Hz)."
            )
        bandwidth = estimate_bandwidth(q, fs)
    bandwidth = _positive(bandwidth, "bandwidth")

    fc_auto, edge_auto = fc_position is None, edge is None
    if fc_position is None:
        fc_position = default_position_cutoff(bandwidth, fs)
    fc_position = float(fc_position)
    _butter_sos(fs, fc_position, order)  # validates fc_position < fs/2

    if edge is None:
        edge = transient_samples(fs, fc_position, order) + DIFFERENCE_EDGE
    if isinstance(edge, bool) or not isinstance(edge, (int, np.integer)) or edge < 0:
        raise InputError(f"edge must be a non-negative integer, got {edge!r}.")
    edge = int(edge)

    if nd is None:
        nd = _nice_floor(0.8 * fs / (2.0 * DECIMATED_CUTOFF_PER_BANDWIDTH * bandwidth))
        nd = max(nd, int(math.ceil(0.8 * fs / (2.0 * fc_position))))
        if n_samples is not None:
            usable = n_samples - 2 * edge
            while nd > 1 and DecimationFilter(nd, fs).n_outputs(usable) < MIN_DECIMATED_SAMPLES:
                nd = _nice_below(nd)
    if isinstance(nd, bool) or not isinstance(nd, (int, np.integer)) or nd < 1:
        raise InputError(f"decimation factor nd must be an integer >= 1, got {nd!r}.")
    nd = check_range("nd", nd)      # before the decimation filter is built (its size grows with nd)

    if f_decimation_cutoff is None:
        f_decimation_cutoff = 0.8 * fs / (2.0 * nd)
    f_decimation_cutoff = float(f_decimation_cutoff)
    DecimationFilter(nd, fs, f_decimation_cutoff)  # validates the cut-off

    # The position filter must leave the decimated band untouched, or W (built
    # from filtered q) and Y (unfiltered tau) differ inside it and the inertias
    # are biased (measured: +0.5 % on ZZ1R of the simulated TX40 with a 15 Hz
    # filter under a 10 Hz decimation). The paper keeps 50 Hz over 20 Hz.
    if fc_auto and fc_position < FC_PER_DECIMATED_CUTOFF * f_decimation_cutoff:
        fc_position = 5.0 * math.ceil(FC_PER_DECIMATED_CUTOFF * f_decimation_cutoff / 5.0)
        fc_position = min(fc_position, FC_MAX_PER_FS * fs)
        if edge_auto:
            edge = transient_samples(fs, fc_position, order) + DIFFERENCE_EDGE

    return {
        "fc_position": fc_position,
        "nd": nd,
        "f_decimation_cutoff": f_decimation_cutoff,
        "edge": edge,
        "bandwidth": bandwidth,
    }


#: Default ('auto') velocity dead zone, as a fraction of each joint's peak
#: |qd_j|. The Coulomb model sign(qd) is wrong while a joint reverses
#: (stiction, Stribeck, filtered qd crossing zero late). On the real TX40 data
#: it is worth 7.4 % -> 5.0 % relative error; 1 % of the joint's peak speed
#: matches the thresholds FIGAROH uses there (0.05-0.12 rad/s).
AUTO_DEAD_ZONE = 0.01


def dead_zone_thresholds(qd, threshold="auto", *, fraction=AUTO_DEAD_ZONE) -> np.ndarray:
    """The per-joint thresholds (n,) of the velocity dead zone, in rad/s.

    `threshold` is a number, one value per joint, `None` or 0 (no dead
    zone), or `"auto"` = `fraction` x max_t |qd_j| (default
    `AUTO_DEAD_ZONE`, 1 %) over the samples `qd` (N, n) given.
    Raises InputError for anything else, or for thresholds < 0 or not finite.
    """
    qd = np.asarray(qd, dtype=float)
    qd2 = qd.reshape(qd.shape[0], -1)
    if threshold is None:
        threshold = 0.0
    if isinstance(threshold, str):
        if threshold != "auto":
            raise InputError(f"qd_threshold must be a number, one value per joint or 'auto', "
                             f"got {threshold!r}")
        threshold = fraction * np.abs(qd2).max(axis=0)
    try:
        thr = np.broadcast_to(np.asarray(threshold, dtype=float), (qd2.shape[1],)).copy()
    except (TypeError, ValueError):
        raise InputError(f"qd_threshold must be a number or one value per joint "
                         f"({qd2.shape[1]}), got {threshold!r}") from None
    if not np.all(np.isfinite(thr)) or np.any(thr < 0):
        raise InputError(f"qd_threshold must be finite and >= 0 rad/s, got {threshold!r}")
    return thr


def velocity_dead_zone(qd, threshold="auto", *, guard=0, couplings=(),
                       fraction=AUTO_DEAD_ZONE) -> np.ndarray:
    """Boolean (N, n), True where joint j is inside the velocity dead zone.

    The one implementation of dynid's velocity dead zone (IDIM's observation,
    the streaming observation, DIDIM, the residual diagnosis and maximum
    likelihood all call it). Sample t of joint j is in the zone when
    `|qd_tj| < threshold_j`: the sign of the Coulomb friction term
    `Fc_j sign(qd_j)` of eq. (3) is undetermined there (noise flips it,
    stiction is not modelled), so those torque equations are excluded.

    `threshold`: see `dead_zone_thresholds` (default `"auto"` =
    `fraction` = 1 % of each joint's peak |qd_j|). `couplings`: the
    robot's motor couplings (`robot.couplings`); a motor turning with
    several joints has its own Coulomb sign, sign(sum_k c_k qd_k), so all its
    joints are in the zone when `|sum_k c_k qd_k|` is below the motor's
    threshold. `guard`: the zone is widened by this many samples on each
    side (a joint that sticks and slips changes its acceleration abruptly and
    the position filter spreads that over about fs/fc samples of the
    estimated qdd while the torque stays sharp).
    """
    qd = np.asarray(qd, dtype=float)
    qd2 = qd.reshape(qd.shape[0], -1)
    thr = dead_zone_thresholds(qd2, threshold, fraction=fraction)
    dead = np.abs(qd2) < thr
    for c in couplings:
        idx = np.asarray(c.joints) - 1
        w = qd2[:, idx] @ np.asarray(c.coefficients, dtype=float)
        dead[:, idx] |= (np.abs(w) < thr[c.motor - 1])[:, None]
    guard = int(guard)
    if guard > 0 and dead.any():
        dead = widen_in_time(dead, guard)
    return dead


def widen_in_time(mask, guard: int) -> np.ndarray:
    """Boolean `mask` (N, ...) widened by `guard` >= 0 samples on each side along time: True at
    sample t where any of samples t - guard .. t + guard is True (outside the record: False).

    The binary dilation by a (2 guard + 1)-sample window, from running counts: its cost
    does not grow with the guard (scipy.ndimage's grows with the window).
    """
    mask = np.asarray(mask, dtype=bool)
    N = mask.shape[0]
    guard = int(guard)
    if guard < 0:
        raise ValueError(f"guard must be >= 0 samples, got {guard}")
    guard = min(guard, N)              # a wider window reaches no further than the record
    # counts[k] = True samples before padded row k; the record sits between guard False rows
    counts = np.zeros((N + 2 * guard + 1,) + mask.shape[1:], dtype=np.int32 if N < 2**31 else np.int64)
    body = counts[guard + 1: guard + 1 + N]
    body[...] = mask
    np.cumsum(body, axis=0, out=body)  # in place: no temporary of the counts' size
    counts[guard + 1 + N:] = counts[guard + N]
    return counts[2 * guard + 1:] > counts[:N]


def low_velocity_mask(qd, thresholds) -> np.ndarray:
    """Boolean (N,) mask, True where every joint has `|qd_j| >= threshold_j`.

    The row view of `velocity_dead_zone` (no couplings, no widening):
    True where no joint is in the dead zone. `thresholds` is a scalar or
    one value per joint, in rad/s (or `"auto"`).
    """
    qd = _time_major(qd, "qd")
    return ~velocity_dead_zone(qd, thresholds).any(axis=1)
