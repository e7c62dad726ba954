"""Exciting trajectories: finite Fourier series (Swevers et al. 1997; Bona & Curatella 2005).

Eqs. (17)-(19) of Bona & Curatella 2005, joint `i`, `w = 2 pi f0`::

    q_i(t)   = sum_k  a_ik / (w k) sin(w k t) - b_ik / (w k) cos(w k t)  + q_i0
    qd_i(t)  = sum_k  a_ik cos(w k t) + b_ik sin(w k t)
    qdd_i(t) = sum_k -a_ik w k sin(w k t) + b_ik w k cos(w k t)

The trajectory is periodic with period `1 / f0`; `q_i0` is the mean
position over a period. Velocity and acceleration are analytic: no numerical
differentiation of the reference is needed.
"""
from __future__ import annotations

import numpy as np

from dynid.errors import InputError

DEFAULT_SAMPLES_PER_HARMONIC = 200
MIN_CHECK_SAMPLES = 4000
#: the most harmonics of a Fourier trajectory dynid designs: the command line's `--harmonics` cap,
#: `dynid.reports.cli_options.MAX_HARMONICS` (not imported: the layers put dynamics below reports, and the
#: parser starts without the numerical modules; a test checks they agree). Beyond it the design's grids
#: (200 samples per harmonic) would take terabytes.
MAX_HARMONICS = 1000


def check_f0(f0) -> float:
    """The fundamental frequency as a float, or InputError if it is not a positive number of Hz."""
    try:
        f0 = float(f0)
    except (TypeError, ValueError):
        raise InputError(f"f0 must be a positive frequency in Hz, got {f0!r}") from None
    if not np.isfinite(f0) or f0 <= 0:
        raise InputError(f"f0 must be a positive frequency in Hz, got {f0!r}")
    return f0


def check_harmonics(n_harmonics) -> int:
    """The number of harmonics as an int, or InputError if it is not an integer from 1 to MAX_HARMONICS."""
    try:
        N = int(n_harmonics)
    except (TypeError, ValueError):
        raise InputError(f"n_harmonics must be a positive integer, got {n_harmonics!r}") from None
    if N < 1 or N != n_harmonics:
        raise InputError(f"n_harmonics must be a positive integer, got {n_harmonics!r}")
    if N > MAX_HARMONICS:
        raise InputError(f"n_harmonics (harmonics=, --harmonics) {N} is more than {MAX_HARMONICS}, the most "
                         f"dynid designs (a trajectory needs a few, typically 3 to 20)")
    return N


class FourierTrajectory:
    """Finite Fourier series of `n` joints and `N` harmonics of `f0` (Hz).

    a, b: (n, N) coefficients (velocity amplitudes, rad/s or m/s); q0: (n,) offsets.
    """

    def __init__(self, f0, a, b, q0):
        f0 = check_f0(f0)
        try:
            a = np.array(a, dtype=float, ndmin=2)
            b = np.array(b, dtype=float, ndmin=2)
            q0 = np.array(q0, dtype=float, ndmin=1)
        except (TypeError, ValueError):
            raise InputError("a, b and q0 must be arrays of numbers") from None
        if a.ndim != 2 or a.shape != b.shape or a.shape[1] < 1:
            raise InputError(f"a and b must both have shape (n joints, N harmonics), got "
                             f"{a.shape} and {b.shape}")
        if q0.ndim != 1 or q0.size != a.shape[0]:
            raise InputError(f"q0 must have one entry per joint ({a.shape[0]}), got shape {q0.shape}")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(q0))):
            raise InputError("a, b and q0 must be finite")
        self.f0 = f0
        self.a = a
        self.b = b
        self.q0 = q0

    @property
    def n_joints(self) -> int:
        return self.a.shape[0]

    @property
    def harmonics(self) -> int:
        """Number of harmonics N."""
        return self.a.shape[1]

    @property
    def period(self) -> float:
        """1 / f0, s."""
        return 1.0 / self.f0

    @property
    def bandwidth(self) -> float:
        """Highest frequency N f0 in Hz."""
        return self.harmonics * self.f0

    def evaluate(self, t):
        """(q, qd, qdd) at times `t`: each (len(t), n) for an array, (n,) for a scalar."""
        try:
            t_arr = np.asarray(t, dtype=float)
        except (TypeError, ValueError):
            raise InputError("t must be a number or a 1-D array of times in s") from None
        scalar = t_arr.ndim == 0
        t1 = np.atleast_1d(t_arr)
        if t1.ndim != 1:
            raise InputError(f"t must be a number or a 1-D array of times, got shape {t_arr.shape}")
        w = 2.0 * np.pi * self.f0
        wk = w * np.arange(1, self.harmonics + 1)          # (N,)
        phase = np.multiply.outer(t1, wk)                    # (T, N)
        s, c = np.sin(phase), np.cos(phase)
        q = s @ (self.a / wk).T - c @ (self.b / wk).T + self.q0
        qd = c @ self.a.T + s @ self.b.T
        qdd = -s @ (self.a * wk).T + c @ (self.b * wk).T
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    __call__ = evaluate

    def sample(self, fs, duration=None, t0=0.0):
        """Times `t0 + k / fs` over `duration` (default one period), and (q, qd, qdd)."""
        fs = float(fs)
        if not np.isfinite(fs) or fs <= 0:
            raise InputError(f"fs must be a positive sampling rate in Hz, got {fs!r}")
        duration = self.period if duration is None else float(duration)
        if not np.isfinite(duration) or duration <= 0:
            raise InputError(f"duration must be positive, got {duration!r}")
        t = t0 + np.arange(int(np.floor(duration * fs + 1e-9)) + 1) / fs
        return (t,) + self.evaluate(t)

    def _dense_grid(self, n_samples=None):
        m = n_samples or max(MIN_CHECK_SAMPLES, DEFAULT_SAMPLES_PER_HARMONIC * self.harmonics)
        return np.arange(m) * (self.period / m)

    def to_frame(self, t, derivatives=True):
        """pandas DataFrame with columns t, qr1..qrn and, with `derivatives`, qdr1..qdrn,
        qddr1..qddrn (the reference of an experiment)."""
        import pandas as pd  # slow to import; the dynamics layer needs it only for this export

        t = np.atleast_1d(np.asarray(t, dtype=float))
        q, qd, qdd = self.evaluate(t)
        cols = {"t": t}
        blocks = [("qr", q)] + ([("qdr", qd), ("qddr", qdd)] if derivatives else [])
        for name, a in blocks:
            for j in range(self.n_joints):
                cols[f"{name}{j + 1}"] = a[:, j]
        return pd.DataFrame(cols)

    def __repr__(self):
        return (f"FourierTrajectory(f0={self.f0:g} Hz, {self.n_joints} joints, "
                f"{self.harmonics} harmonics)")


def _rng(rng):
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer)):
        return np.random.default_rng(rng)
    raise InputError(f"rng must be a numpy Generator, an integer seed or None, got {rng!r}")


def random_fourier_trajectory(robot, f0, n_harmonics, rng=None, margin=0.9, *, n_check=None):
    """A random Fourier trajectory inside the robot's limits.

    Coefficients `a, b` are drawn standard normal, then each joint's series is
    scaled by the largest factor that keeps, on a dense grid of one period
    (`n_check` points, default `max(4000, 200 N)`):

    * `q` inside `q_mid +- margin * (q_max - q_min) / 2` with `q0 = q_mid`
      the centre of the joint range (`q0 = 0` and no position bound when a limit
      is infinite),
    * `|qd| <= margin * qd_max` and `|qdd| <= margin * qdd_max`.

    Scaling the coefficients scales `q - q0`, `qd` and `qdd` alike, so one
    factor per joint meets all three limits. Between grid points a trigonometric
    polynomial of degree N can exceed its grid maximum, by at most a relative
    `(pi N / n_check)^2 / 2` (Bernstein's inequality); the factor is reduced by
    that much, so the limits hold at every time, and the binding one is reached
    to within that relative amount (~1e-5). A joint with no finite limit at all
    is an error.
    """
    n = robot.n_joints
    N = check_harmonics(n_harmonics)
    margin = float(margin)
    if not 0 < margin <= 1:
        raise InputError(f"margin must be in (0, 1], got {margin!r}")
    rng = _rng(rng)
    q_min, q_max, qd_max, qdd_max, _ = robot.limits()
    finite_q = np.isfinite(q_min) & np.isfinite(q_max)
    with np.errstate(invalid="ignore"):
        q0 = np.where(finite_q, 0.5 * (q_min + q_max), 0.0)
        half = np.where(finite_q, 0.5 * (q_max - q_min), np.inf)
    if np.any(~finite_q & ~np.isfinite(qd_max) & ~np.isfinite(qdd_max)):
        bad = [robot.joints[j].name for j in range(n)
               if not finite_q[j] and not np.isfinite(qd_max[j]) and not np.isfinite(qdd_max[j])]
        raise InputError(f"joint(s) {', '.join(bad)} of '{robot.name}' have no finite position, "
                         "velocity or acceleration limit: the trajectory amplitude is unbounded; "
                         "give q_limits, qd_max or qdd_max")
    a = rng.standard_normal((n, N))
    b = rng.standard_normal((n, N))
    traj = FourierTrajectory(f0, a, b, q0)
    t = traj._dense_grid(n_check)
    q, qd, qdd = traj.evaluate(t)
    dq = np.abs(q - q0).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.stack([margin * half / dq,
                           margin * qd_max / np.abs(qd).max(axis=0),
                           margin * qdd_max / np.abs(qdd).max(axis=0)])
    # grid maximum -> true maximum: for a trigonometric polynomial p of degree N,
    # Bernstein's |p''| <= (2 pi N / T)^2 max|p| and p' = 0 at the maximum give
    # max|p| <= max_grid|p| / (1 - (pi N / m)^2 / 2) on an m-point grid of one period.
    guard = 1.0 - 0.5 * (np.pi * N / t.size) ** 2
    scale = guard * np.nanmin(np.where(np.isfinite(ratios), ratios, np.inf), axis=0)
    traj.a = a * scale[:, None]
    traj.b = b * scale[:, None]
    return traj
