"""Reference trajectories of the per-joint experiments of Bona & Curatella 2005, section 3.

* `sweep_reference`: two constant-velocity slopes of opposite sign over a
  position range (section 3.2.1, gravity: Table 1, Fig. 2);
* `bang_bang_reference`: bang-bang acceleration, velocity triangles of both
  signs (section 3.2.2, friction: Table 2, Fig. 3);
* `excitation_reference`: finite Fourier series, eqs. (17)-(19), f0 = 0.1 Hz
  and 5 harmonics by default (section 3.3, inertia: Table 3), chosen per joint
  by a random search of eq. (20) on the decoupled regressor;
* `trapezoid_reference`: trapezoidal velocity moves (section 3.5, validation).

The first, second and fourth are piecewise-constant accelerations with the same
breakpoints for every joint (the amplitudes differ), integrated exactly by
`piecewise_acceleration`. Each returns `Reference` (t, q, qd, qdd).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dynid.errors import InputError

from .joint_model import G0
from .trajectories import FourierTrajectory

__all__ = ["Reference", "piecewise_acceleration", "sweep_reference", "bang_bang_reference",
           "trapezoid_reference", "excitation_reference"]


class Reference(NamedTuple):
    """Reference samples: `t` (N,), `q`, `qd`, `qdd` (N, n)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def _positive(x, name):
    try:
        x = float(x)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a positive number, got {x!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise InputError(f"{name} must be a positive number, got {x!r}")
    return x


def piecewise_acceleration(durations, accel, fs, q0) -> Reference:
    """Exact samples at `k / fs` of the motion with acceleration `accel[m]` (m, n) held over
    `durations[m]` (m,) seconds, starting at rest at `q0` (n,)."""
    durations = np.asarray(durations, dtype=float)
    accel = np.atleast_2d(np.asarray(accel, dtype=float))
    q0 = np.atleast_1d(np.asarray(q0, dtype=float))
    fs = _positive(fs, "fs")
    if durations.ndim != 1 or np.any(durations < 0) or accel.shape != (durations.size, q0.size):
        raise InputError(f"durations (m,) >= 0 and accel (m, n) with n = {q0.size}; got "
                         f"{durations.shape} and {accel.shape}")
    edges = np.concatenate([[0.0], np.cumsum(durations)])
    # velocity and position at each breakpoint, exactly
    v_b = np.vstack([np.zeros(q0.size), np.cumsum(accel * durations[:, None], axis=0)])
    dq = v_b[:-1] * durations[:, None] + 0.5 * accel * durations[:, None] ** 2
    q_b = q0 + np.vstack([np.zeros(q0.size), np.cumsum(dq, axis=0)])
    t = np.arange(int(np.floor(edges[-1] * fs + 1e-9)) + 1) / fs
    seg = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, durations.size - 1)
    s = (t - edges[seg])[:, None]
    a = accel[seg]
    qd = v_b[seg] + a * s
    q = q_b[seg] + v_b[seg] * s + 0.5 * a * s ** 2
    return Reference(t, q, qd, a.copy())


def sweep_reference(q_low, q_high, *, cruise_time=8.0, accel_time=0.5, pause=0.5, fs=1000.0):
    """From `q_low` up to `q_high` and back (n,), each at a constant velocity for `cruise_time`.

    Speed per joint `(q_high - q_low) / (cruise_time + accel_time)`, reached
    in `accel_time`; rests of `pause` at the start, between and at the end.
    """
    lo, hi = np.atleast_1d(np.asarray(q_low, float)), np.atleast_1d(np.asarray(q_high, float))
    if lo.shape != hi.shape or np.any(hi <= lo):
        raise InputError("q_high must be above q_low for every joint")
    tc, ta, tp = (_positive(cruise_time, "cruise_time"), _positive(accel_time, "accel_time"),
                  _positive(pause, "pause"))
    A = (hi - lo) / (tc + ta) / ta
    z = np.zeros_like(A)
    durations = [tp, ta, tc, ta, tp, ta, tc, ta, tp]
    accel = [z, A, z, -A, z, -A, z, A, z]
    return piecewise_acceleration(durations, accel, fs, lo)


def bang_bang_reference(q0, peak_velocity, *, accel_time=1.0, cycles=2, pause=0.5, fs=1000.0):
    """Bang-bang acceleration about `q0` (n,): per cycle +A for `accel_time`, -A for twice
    that, +A again, so the velocity runs 0 -> +peak -> -peak -> 0 and the position returns.

    `A = peak_velocity / accel_time`; the excursion is `A accel_time^2` each way.
    """
    q0 = np.atleast_1d(np.asarray(q0, float))
    vp = np.broadcast_to(np.asarray(peak_velocity, float), q0.shape)
    if np.any(vp <= 0):
        raise InputError("peak_velocity must be positive")
    ta, tp = _positive(accel_time, "accel_time"), _positive(pause, "pause")
    cycles = int(cycles)
    if cycles < 1:
        raise InputError("cycles must be >= 1")
    A = vp / ta
    z = np.zeros_like(A)
    durations, accel = [tp], [z]
    for _ in range(cycles):
        durations += [ta, 2 * ta, ta]
        accel += [A, -A, A]
    durations.append(tp)
    accel.append(z)
    return piecewise_acceleration(durations, accel, fs, q0)


def trapezoid_reference(q_start, q_end, *, move_time=4.0, accel_time=1.0, pause=1.0, fs=1000.0):
    """Trapezoidal-velocity move `q_start -> q_end` (n,) in `move_time` and back (section 3.5)."""
    qs, qe = np.atleast_1d(np.asarray(q_start, float)), np.atleast_1d(np.asarray(q_end, float))
    T, ta, tp = (_positive(move_time, "move_time"), _positive(accel_time, "accel_time"),
                 _positive(pause, "pause"))
    if 2 * ta >= T:
        raise InputError("accel_time must be less than half of move_time")
    A = (qe - qs) / (ta * (T - ta))
    z = np.zeros_like(A)
    durations = [tp, ta, T - 2 * ta, ta, tp, ta, T - 2 * ta, ta, tp]
    accel = [z, A, z, -A, z, -A, z, A, z]
    return piecewise_acceleration(durations, accel, fs, qs)


def _scale_to_limits(traj, q_half, qd_max, qdd_max):
    t = np.arange(4000) * (traj.period / 4000)
    q, qd, qdd = traj.evaluate(t)
    ratio = np.minimum.reduce([q_half / np.abs(q - traj.q0).max(0), qd_max / np.abs(qd).max(0),
                               qdd_max / np.abs(qdd).max(0)])
    traj.a = traj.a * ratio[:, None]
    traj.b = traj.b * ratio[:, None]
    return traj


def excitation_reference(q_mid, q_half, qd_max, qdd_max, *, first_moments=None, f0=0.1,
                         harmonics=5, candidates=200, seed=0, g0=G0):
    """A per-joint Fourier excitation (eqs. (17)-(19)) scaled to the limits, eq. (20) by random search.

    For each joint, `candidates` random coefficient sets are scaled to
    `|q - q_mid| <= q_half`, `|qd| <= qd_max`, `|qdd| <= qdd_max` (n,),
    and the one with the lowest condition number of the unit-column regressor
    `[qdd, g0 cos q, -g0 sin q]` (just `[qdd]` where `first_moments` is
    False) over one period is kept. Returns the `FourierTrajectory`.
    """
    q_mid = np.atleast_1d(np.asarray(q_mid, float))
    n = q_mid.size
    q_half, qd_max, qdd_max = (np.broadcast_to(np.asarray(x, float), (n,)) for x in (q_half, qd_max, qdd_max))
    fm = np.ones(n, bool) if first_moments is None else np.asarray(first_moments, bool)
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((candidates, n, harmonics))
    b = rng.standard_normal((candidates, n, harmonics))
    t = np.arange(1000) * (1.0 / f0 / 1000)
    best_a, best_b = np.zeros((n, harmonics)), np.zeros((n, harmonics))
    best = np.full(n, np.inf)
    for c in range(candidates):
        tr = _scale_to_limits(FourierTrajectory(f0, a[c], b[c], q_mid), q_half, qd_max, qdd_max)
        q, _, qdd = tr.evaluate(t)
        for j in range(n):
            cols = [qdd[:, j]] + ([g0 * np.cos(q[:, j]), -g0 * np.sin(q[:, j])] if fm[j] else [])
            W = np.column_stack(cols)
            W = W / np.linalg.norm(W, axis=0)
            k = np.linalg.cond(W)
            if k < best[j]:
                best[j], best_a[j], best_b[j] = k, tr.a[j], tr.b[j]
    return FourierTrajectory(f0, best_a, best_b, q_mid)
