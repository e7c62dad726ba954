"""Is a robot file's joint controller stable on its robot, at its rate?

The simulated loop (`dynid.dynamics.simulation`, Figs. 3-4 and eq. (30) of Gautier,
Janot, Vandanjon 2010) is a decentralised PD (or PID) per joint, computed at the
controller samples and held over the period `T` (zero-order hold). Linearised about a
configuration `q` -- `M(q)` frozen, gravity, Coriolis and friction left out (they move
the equilibrium, not the stability of this loop at the rates robots run) -- the plant is
the coupled double integrator `M(q) qdd = tau`, whose exact ZOH discretisation is

    q+  = q + T qd + T^2/2 M^-1 tau
    qd+ = qd + T M^-1 tau

with `tau = -Kp q - Kv qd + Ki I`, `I` the integral of the error updated before the
torque is formed (`I_k = I_k-1 - T q_k`). The loop is stable at `q` when every
eigenvalue of the sampled closed loop lies inside the unit circle.

Why it matters: the gains scale each joint by its a-priori inertia `J_ap`, but what the
loop sees is `M(q)^-1`, whose diagonal grows wherever links move almost freely. The
KUKA LWR4+ a-priori model has no rotor inertia, so near its aligned wrist joints 5 and
7 nearly cancel, `(M^-1)_55` reaches 94 kg^-1 m^-2 against `1/J_ap5 = 10`, and its PD
at 200 Hz has a spectral radius of 4.5: the simulation limit-cycles near 100 Hz, and the
identification of that recording leaves 8 % of the torque that no rigid-body model
describes. At 1 kHz the same gains give 0.996.
"""
from __future__ import annotations

import numpy as np

from dynid.errors import InputError

from .dynamic_model import mass_matrix

__all__ = ["sampled_loop_radius", "radius_along", "CHECKS"]

#: configurations of a motion at which `radius_along` checks the loop
CHECKS = 200


def _gains(robot, c, kd_scale):
    """Per-joint Kp, Kv, Ki of the torque law (N m per rad, per rad/s, per rad s)."""
    n = robot.n_joints

    def vec(x, default):
        return np.broadcast_to(np.asarray(default if x is None else x, dtype=float), (n,))
    wn, zeta = vec(c.wn, 1.0), vec(c.zeta, 1.0)
    scale = robot.drive_gains * vec(c.J_ap, 1.0) / vec(getattr(c, "g_ap", None), 1.0) * vec(kd_scale, 1.0)
    kv = 2.0 * zeta * wn
    Kv = scale * kv
    Kp = Kv * wn / (2.0 * zeta)
    Ki = scale * vec(getattr(c, "ki", None), 0.0) if c.kind == "pid" else np.zeros(n)
    return Kp, Kv, Ki


def sampled_loop_radius(robot, chi_st, q, *, controller=None, rate=None, kd_scale=None):
    """Spectral radius of the robot's sampled joint-control loop, linearised at each `q`.

    Parameters
    ----------
    robot : Robot
        With a `[controller]` (or `controller=`).
    chi_st : (p,) standard parameters of the plant (with the actuator inertias).
    q : (n,) or (N, n) configurations, rad (m for a prismatic joint).
    controller : Controller, optional
        Replaces `robot.controller`.
    rate : float, optional
        Controller rate, Hz; default the controller's.
    kd_scale : float or (n,), optional
        DIDIM's factor on the gains (`dynid.dynamics.simulation.simulate_closed_loop`).

    Returns
    -------
    float or (N,) ndarray
        The largest eigenvalue modulus of the sampled closed loop (module docstring): below 1
        stable, above 1 the simulated motion oscillates at up to half the rate and grows until
        the torque limits or the friction bound it.
    """
    c = controller if controller is not None else robot.controller
    if c is None:
        raise InputError(f"robot '{robot.name}' has no [controller] to check")
    T = 1.0 / float(c.rate if rate is None else rate)
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    M = mass_matrix(robot, chi_st, q[None] if single else q)
    n = robot.n_joints
    Kp, Kv, Ki = _gains(robot, c, kd_scale)
    Mi = np.linalg.inv(M)
    eye = np.broadcast_to(np.eye(n), Mi.shape)
    # tau = -Kp q - Kv qd + Ki (I - T q): the integral updated before the torque
    Bp, Bv, Bi = Mi * (Kp + T * Ki), Mi * Kv, Mi * Ki        # M^-1 @ diag(K), column scaling
    rows = [[eye - T * T / 2 * Bp, T * eye - T * T / 2 * Bv],
            [-T * Bp, eye - T * Bv]]
    if np.any(Ki):
        rows[0].append(T * T / 2 * Bi)
        rows[1].append(T * Bi)
        rows.append([-T * eye, np.zeros_like(Mi), eye])
    A = np.concatenate([np.concatenate(r, axis=2) for r in rows], axis=1)
    radius = np.abs(np.linalg.eigvals(A)).max(axis=1)
    return float(radius[0]) if single else radius


def radius_along(robot, chi_st, q, *, checks=CHECKS, **kw):
    """(rows, radius): `sampled_loop_radius` at up to `checks` configurations of the motion `q`
    (N, n), evenly spaced, and their row numbers in `q`. `kw`: `controller`, `rate`, `kd_scale`."""
    q = np.asarray(q, dtype=float)
    rows = np.unique(np.linspace(0, len(q) - 1, min(checks, len(q))).astype(int))
    return rows, sampled_loop_radius(robot, chi_st, q[rows], **kw)
