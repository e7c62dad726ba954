"""Closed-loop simulation of a robot under its joint controller (DIDIM's simulated robot).

Figs. 3-4 and eqs. (25)-(30) of Gautier, Janot, Vandanjon 2010: each joint is
controlled as the normalised double integrator `1/s^2` with the gains
`kp = wn / (2 zeta)`, `kv = 2 zeta wn` (eq. (30)), the control signal being
scaled by the a-priori inertia over the a-priori drive gain.

Control law, per joint `j`, at the controller samples `t_k` (rate
`robot.controller.rate`, or `rate=`)::

    e      = qr_j(t_k) - q_j(t_k)
    u      = kv_j * (kp_j * e - qd_j [+ qdr_j(t_k)])        # [...] with feedforward=True
           [+ ki_j * I_j]                                    # PID only
    v_j    = (J_ap_j / g_ap_j) * kd_scale_j * u              # control signal (Fig. 3)
    tau_j  = clip(g_j * v_j, -tau_max_j, tau_max_j)          # g_j = robot.joints[j].drive_gain

* `kd_scale` multiplies the derivative gain `kv J_ap / g_ap` (the factor
  `J_hat_j^k / J_ap_j` of section 3.2 that keeps the simulated loop equal to the
  actual one when the simulated inertia is `J_hat`). `kp` sits inside it, so
  the proportional action scales too, exactly as in Fig. 4. For the PID the
  integral path is scaled by the same factor, so the normalised loop
  `s^3 + kv s^2 + kv kp s + ki` is kept (stable for `ki < kv^2 kp`).
* PID: `I_k = clip(I_{k-1} + T e_k, -I_max, I_max)` (rectangle rule, `T` the
  controller period, updated before `u` is formed). Anti-windup by clamping:
  `I_max = tau_max / |g ki J_ap kd_scale / g_ap|`, so the integral term alone
  never asks for more than `tau_max`. `ki` comes from `controller.ki`
  (normalised units, rad/s^3 per rad).
* The velocity fed back is the simulated joint velocity (the state).
* The torque is held constant between controller samples (zero-order hold).

Plant: `qdd = M(q)^-1 (tau - N(q, qd))` (eq. (17)) with the actuator terms,
from `dynid.dynamics.dynamic_model`; Coulomb friction with the smooth sign
`tanh(qd / v_s)`, `v_s = 0.01` rad/s by default. Integrated by the classical
fixed-step Runge-Kutta 4 with `substeps` steps per controller period
(`h = T / substeps`, default 1). The whole loop runs in one numba function.

Output at each controller sample `t_k`: the state `q_k, qd_k`, the torque
`tau_k` computed there and held over `[t_k, t_k+1)`, and `qdd_k` the
acceleration of the plant at `(q_k, qd_k, tau_k)` (the first RK4 stage).

Accuracy (measured by `tests/dynamics/test_simulation.py`, TX40 with Table-2-like
parameters tracking a 5-harmonic Fourier reference at 5 kHz, 5 s, v_s = 0.05):
the RK4 step of one controller period differs from a 4x finer step by
4e-9 rad in q (7e-6 rad/s in qd, 1e-5 N m in tau, mostly at velocity
reversals where the smoothed friction is steepest); a Pinocchio-based loop with
the same controller, hold and RK4 step agrees to ~1e-15 rad (same arithmetic).
With `v_s = 0.01` and `substeps = 3` the 4x-finer difference is ~6e-10 rad.

Stiffness. Near `qd = 0` the smooth sign acts as a viscous friction of slope
`Fc / v_s`; with a small inertia `J` the plant eigenvalue `-Fc / (v_s J)`
times the step `h` must stay below ~2.8 (RK4's real stability interval) and
below ~1 for accuracy. Example: the TX40 wrist with the Table 2 frictions
(`Fc6 + Fcm6 = 2.5` N m, `J6 ~ 0.012` kg m^2) at 5 kHz and `v_s = 0.01`
gives `h lambda ~ 4`: use `substeps >= 3` or `v_s >= 0.03`. The simulator
estimates `h lambda` at the start (`SimulationResult.stiffness`) and warns
when it exceeds 2.5, with the substeps and `v_s` that fix it.

Adaptive substeps (`adaptive=True`, opt-in; DIDIM uses it). The smooth sign's slope
is `(Fc / v_s) sech^2(qd / v_s)`: the friction is stiff only near a velocity
reversal. With `m = substeps`, one RK4 step over the whole period `T` at a speed
`|qd| >= c v_s`, `sech^2(c) = 1 / (4 m)`, i.e. `c = arccosh(2 sqrt(m))` (1.9 for
m = 3, 2.3 for 6, 2.6 for 11), sees the Coulomb slope times `T` no larger than a step
of the 4x-finer reference `T / (4 m)` sees at rest: the uniform mode's own error is
what that reference measures, so the long steps add less than it. (Stability alone,
`sech^2(c) = 1 / m`, is not enough for accuracy: on DIDIM's simulation of
benchmarks/didim_width.py, seed 5, it gave 4x the uniform error.) So a period is
integrated with all `m` substeps when, at its start, some joint (or coupled rotor,
`w = c_k qd`) has `|qd| < c v_s + 2 |qdd| T` (near zero, or may come near it within
the period: the state is seen only at the start, and the acceleration changes fastest
at a reversal, so the margin is twice the linear excursion), and with one RK4 step
otherwise. The viscous part `Fv` does not fade with speed: when it alone gives
`T lambda > 0.5` the mode falls back to uniform substeps (a note says so). The
stiffness warning is unchanged: its step `T / m` is still the one taken at rest.
Accuracy: against `scipy.integrate.solve_ivp` and against the 4x-finer uniform step
(tests/dynamics/test_simulation.py, TX40 closed loop, every joint reversing, v_s =
0.00625, m = 5) the adaptive error is 4.6e-10 rad beside the uniform mode's 4.7e-10;
on a DIDIM simulation (benchmarks/didim_width.py seed 5, v_s = 0.00625, m = 6) 1.2e-10
rad beside 1.1e-10 (tau 3.5e-6 N m beside 2.7e-6), with all substeps in 20 % of the
periods.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.linalg import eigh

from dynid.errors import DynidError, InputError
from dynid.numba_cache import install as _cache_outside_the_package

from .dynamic_model import (
    DEFAULT_V_S,
    NOT_FINITE,
    NOT_POSITIVE_DEFINITE,
    OK,
    _qdd,
    _workspace,
    check_parameters,
    mass_matrix,
    model_arrays,
)

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

RK4_STABILITY = 2.785        # RK4 is stable on the negative real axis for h*lambda < 2.785
STIFFNESS_WARNING = 2.5


class SimulationError(DynidError):
    """The simulation diverged (non-finite state)."""

    exit_code = 3


@dataclass(eq=False)
class SimulationResult:
    """Samples of a simulation at the controller (or input) times `t`.

    q, qd, qdd, tau: (N, n) state, acceleration at the sample and the torque held
    over `[t_k, t_k+1)`. qr, qdr: the reference on the same grid (None in open
    loop). `saturation`: fraction of samples where each joint's torque was
    clipped at tau_max. `stiffness`: the estimated `h lambda` of the
    friction (see the module doc). `notes`: what the simulator did on its own
    (resampling, derived qdr, ...). `adaptive`: the substeps were used only near
    velocity reversals (see the module doc); `refined`: the fraction of controller
    intervals integrated with all `substeps` (NaN when not adaptive).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    qr: np.ndarray | None = None
    qdr: np.ndarray | None = None
    robot: str = ""
    rate: float | None = None
    substeps: int = 1
    v_s: float = DEFAULT_V_S
    kd_scale: np.ndarray | None = None
    feedforward: bool = False
    kind: str = "open-loop"
    saturation: np.ndarray | None = None
    stiffness: float = float("nan")
    notes: list = field(default_factory=list)
    adaptive: bool = False
    refined: float = float("nan")

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def tracking_error(self):
        """qr - q, (N, n) (None in open loop)."""
        return None if self.qr is None else self.qr - self.q

    def to_frame(self):
        """pandas DataFrame with columns t, q1.., qr1.., qd1.., qdd1.., tau1.. (dynid's
        experiment column convention)."""
        import pandas as pd  # slow to import; the dynamics layer needs it only for this export

        cols = {"t": self.t}
        for name in ("q", "qr", "qd", "qdd", "tau"):
            a = getattr(self, name)
            if a is not None:
                for j in range(a.shape[1]):
                    cols[f"{name}{j + 1}"] = a[:, j]
        return pd.DataFrame(cols)


# ----------------------------------------------------------------------------- kernels

#: most RK4 steps of one compiled call (a fraction of a second): between calls Python
#: handles a pending interruption, so a long simulation (a small v_s, many substeps) stops at once
RK4_STEPS_PER_CHUNK = 5_000


@njit(cache=True, nogil=True)
def _stages(n):
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n),
            np.empty(n), np.empty(n), np.empty(n))


@njit(cache=True, nogil=True)
def _rk4_step(model, ws, stg, q, qd, tau, a1, h, v_s, crba):
    """One classical RK4 step of (q, qd) in place, torque held; a1 = qdd(q, qd, tau)."""
    q2, v2, a2, q3, v3, a3, q4, v4, a4 = stg
    n = q.shape[0]
    hh = 0.5 * h
    for j in range(n):
        q2[j] = q[j] + hh * qd[j]
        v2[j] = qd[j] + hh * a1[j]
    st = _qdd(model, ws, q2, v2, tau, v_s, a2, crba)
    if st != OK:
        return st
    for j in range(n):
        q3[j] = q[j] + hh * v2[j]
        v3[j] = qd[j] + hh * a2[j]
    st = _qdd(model, ws, q3, v3, tau, v_s, a3, crba)
    if st != OK:
        return st
    for j in range(n):
        q4[j] = q[j] + h * v3[j]
        v4[j] = qd[j] + h * a3[j]
    st = _qdd(model, ws, q4, v4, tau, v_s, a4, crba)
    if st != OK:
        return st
    h6 = h / 6.0
    for j in range(n):
        q[j] += h6 * (qd[j] + 2.0 * v2[j] + 2.0 * v3[j] + v4[j])
        qd[j] += h6 * (a1[j] + 2.0 * a2[j] + 2.0 * a3[j] + a4[j])
    return OK


@njit(cache=True, nogil=True)
def _reversal_ahead(model, qd, a1, dt, fast):
    """True when some joint's (or coupled rotor's) velocity is below `fast` + 2 |its
    acceleration| dt at the interval's start: near zero, or may come near it during the interval."""
    C = model[9]
    n = qd.shape[0]
    for j in range(n):
        if abs(qd[j]) < fast + 2.0 * abs(a1[j]) * dt:
            return True
    for r in range(C.shape[0]):
        w = 0.0
        wd = 0.0
        for j in range(n):
            w += C[r, j] * qd[j]
            wd += C[r, j] * a1[j]
        if abs(w) < fast + 2.0 * abs(wd) * dt:
            return True
    return False


@njit(cache=True, nogil=True)
def _integrate_interval(model, ws, stg, q, qd, tau, a1, dt, substeps, v_s, fast, REFINED, crba):
    """Advance (q, qd) over dt with `substeps` RK4 steps; a1 holds qdd at the start.

    `fast` >= 0 (adaptive mode): one RK4 step over dt unless a velocity reversal is near
    (`_reversal_ahead`); REFINED[0] counts the intervals integrated with `substeps`.
    """
    n = q.shape[0]
    if fast >= 0.0 and substeps > 1:
        if _reversal_ahead(model, qd, a1, dt, fast):
            REFINED[0] += 1
        else:
            substeps = 1
    h = dt / substeps
    for s in range(substeps):
        if s > 0:
            st = _qdd(model, ws, q, qd, tau, v_s, a1, crba)
            if st != OK:
                return st
        st = _rk4_step(model, ws, stg, q, qd, tau, a1, h, v_s, crba)
        if st != OK:
            return st
    for j in range(n):
        if not (np.isfinite(q[j]) and np.isfinite(qd[j])):
            return NOT_FINITE
    return OK


@njit(cache=True, nogil=True)
def _record_and_step(model, ws, stg, q, qd, tau, a1, QDD, t, k, substeps, v_s, fast, REFINED, crba):
    """The acceleration of sample k into QDD, then the state on to sample k + 1 (none after
    the last sample); returns (status, sample index of the failure or -1)."""
    N, n = QDD.shape
    st = _qdd(model, ws, q, qd, tau, v_s, a1, crba)
    if st != OK:
        return st, k
    for j in range(n):
        QDD[k, j] = a1[j]
    if k == N - 1:
        return OK, -1
    st = _integrate_interval(model, ws, stg, q, qd, tau, a1, t[k + 1] - t[k], substeps, v_s,
                             fast, REFINED, crba)
    if st != OK:
        return st, k + 1
    return OK, -1


@njit(cache=True, nogil=True)
def _closed_loop(model, v_s, t, substeps, qr, qdr, ff, pid, Kv, kp, Ki, gain, tau_max, I_max,
                 T, fast, crba, q, qd, integ, k0, k1, Q, QD, QDD, TAU, SAT, REFINED):
    """Closed-loop simulation of samples k0..k1-1; returns (status, sample index of the failure or -1).

    The state (q, qd, integral of the PID) is updated in place, so consecutive
    calls over adjacent ranges give exactly the result of one call.
    """
    N, n = Q.shape
    ws = _workspace(n)
    stg = _stages(n)
    tau = np.empty(n)
    a1 = np.empty(n)
    for k in range(k0, k1):
        for j in range(n):
            e = qr[k, j] - q[j]
            u = kp[j] * e - qd[j]
            if ff:
                u += qdr[k, j]
            v = Kv[j] * u
            if pid:
                x = integ[j] + T * e
                if x > I_max[j]:
                    x = I_max[j]
                elif x < -I_max[j]:
                    x = -I_max[j]
                integ[j] = x
                v += Ki[j] * x
            tj = gain[j] * v
            if tj > tau_max[j]:
                tj = tau_max[j]
                SAT[j] += 1
            elif tj < -tau_max[j]:
                tj = -tau_max[j]
                SAT[j] += 1
            tau[j] = tj
            Q[k, j] = q[j]
            QD[k, j] = qd[j]
            TAU[k, j] = tj
        st, at = _record_and_step(model, ws, stg, q, qd, tau, a1, QDD, t, k, substeps, v_s, fast,
                                  REFINED, crba)
        if st != OK:
            return st, at
    return OK, -1


@njit(cache=True, nogil=True)
def _open_loop(model, v_s, t, substeps, TAU, q0, qd0, Q, QD, QDD):
    N, n = Q.shape
    ws = _workspace(n)
    stg = _stages(n)
    q = q0.copy()
    qd = qd0.copy()
    tau = np.empty(n)
    a1 = np.empty(n)
    refined = np.zeros(1, dtype=np.int64)
    for k in range(N):
        for j in range(n):
            tau[j] = TAU[k, j]
            Q[k, j] = q[j]
            QD[k, j] = qd[j]
        st, at = _record_and_step(model, ws, stg, q, qd, tau, a1, QDD, t, k, substeps, v_s, -1.0,
                                  refined, False)
        if st != OK:
            return st, at
    return OK, -1


# ----------------------------------------------------------------------------- helpers

def _time(t, what="t"):
    try:
        t = np.asarray(t, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a 1-D array of times in s") from None
    if t.ndim != 1 or t.size < 2:
        raise InputError(f"{what} must be a 1-D array of at least 2 times in s, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{what} holds non-finite times")
    if not np.all(np.diff(t) > 0):
        raise InputError(f"{what} must be strictly increasing")
    return t


def _signal(a, N, n, name, robot_name):
    try:
        a = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an array of numbers of shape ({N}, {n})") from None
    if n == 1 and a.ndim == 1:
        a = a[:, None]
    if a.shape != (N, n):
        raise InputError(f"{name} has shape {a.shape}; expected ({N}, {n}): one row per time "
                         f"sample and one column per joint of '{robot_name}'")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} holds non-finite values (NaN or inf)")
    return np.ascontiguousarray(a)


def _vector(x, n, name, *, default=None, positive=False):
    if x is None:
        x = default
    try:
        v = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy()
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number or {n} numbers (one per joint), got {x!r}") from None
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} must be finite, got {x!r}")
    if positive and not np.all(v > 0):
        raise InputError(f"{name} must be positive, got {x!r}")
    return v


def _initial(x, default, n, name):
    if x is None:
        return np.ascontiguousarray(default, dtype=float).copy()
    return _vector(x, n, name)


def _substeps(substeps):
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise InputError(f"substeps must be a positive integer, got {substeps!r}")
    return int(substeps)


def _v_s(v_s):
    try:
        v = float(v_s)
    except (TypeError, ValueError):
        raise InputError(f"v_s must be a number >= 0 (rad/s), got {v_s!r}") from None
    if not np.isfinite(v) or v < 0:
        raise InputError(f"v_s (the smooth-sign velocity of Coulomb friction, rad/s) must be >= 0, "
                         f"got {v_s!r}")
    return v


def friction_stiffness(robot, chi_st, q0, h, v_s):
    """Estimated `h * lambda_max` of the friction near `qd = 0` at `q0`.

    `lambda` are the generalised eigenvalues of (D, M(q0)) with D the friction
    slope at rest: `diag(Fv + Fc / v_s) + sum_c c c^T (Fvm + Fcm / v_s)`. For
    `v_s = 0` only the viscous part counts (the sign has no slope).
    """
    ma = model_arrays(robot, chi_st)
    inv = 1.0 / v_s if v_s > 0 else 0.0
    D = np.diag(ma.Fv + ma.Fc * inv)
    for r in range(ma.C.shape[0]):
        D += np.outer(ma.C[r], ma.C[r]) * (ma.Fvm[r] + ma.Fcm[r] * inv)
    M = mass_matrix(robot, chi_st, q0)
    try:
        lam = eigh(D, M, eigvals_only=True)
    except np.linalg.LinAlgError:
        return float("nan")
    return float(h * np.max(np.abs(lam)))


def _check_stiffness(robot, chi, q0, h, v_s, substeps, notes):
    x = friction_stiffness(robot, chi, q0, h, v_s)
    if np.isfinite(x) and x > STIFFNESS_WARNING:
        need = int(math.ceil(substeps * x / 1.5))
        msg = (f"Coulomb friction smoothed over v_s = {v_s:g} makes the plant stiff for the "
               f"RK4 step h = {h:.3g} s: h*lambda ~ {x:.2g} > {STIFFNESS_WARNING} (RK4 is stable "
               f"below {RK4_STABILITY}); the simulation may chatter near velocity reversals. "
               f"Use substeps >= {need} or v_s >= {v_s * x / 1.5:.2g}.")
        notes.append(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
    return x


#: the viscous friction alone must keep one RK4 step per controller period this accurate
#: (h * lambda) for the adaptive mode to take such steps at all
ADAPTIVE_VISCOUS_LIMIT = 0.5


def _adaptive_threshold(robot, chi, q0, T, v_s, substeps, notes):
    """`c v_s`, the speed above which one RK4 step per period is no stiffer than a step of the
    4x-finer reference at rest (module doc, "Adaptive substeps"); -1 (uniform substeps) when
    the viscous friction alone
    makes a whole period's step stiff."""
    if substeps == 1:
        return -1.0
    x_viscous = friction_stiffness(robot, chi, q0, T, 0.0)
    if not (np.isfinite(x_viscous) and x_viscous <= ADAPTIVE_VISCOUS_LIMIT):
        notes.append(f"adaptive substeps off: the viscous friction alone gives h*lambda ~ {x_viscous:.2g} "
                     f"> {ADAPTIVE_VISCOUS_LIMIT} for one step per controller period; all {substeps} "
                     "substeps used in every period")
        return -1.0
    return math.acosh(2.0 * math.sqrt(substeps)) * v_s


def _status(status, index, t, robot, where):
    if status == OK:
        return
    k = min(max(index, 0), t.size - 1)
    # from the first sample: a logger's clock (seconds since 1970) says nothing to the reader
    at = f"{t[k] - t[0]:.6g} s after the first sample (sample {k + 1})"
    if status == NOT_POSITIVE_DEFINITE:
        raise InputError(f"{where}: the mass matrix M(q) of these parameters is not positive "
                         f"definite {at}; chi_st is not physically consistent for "
                         f"'{robot.name}' (check masses, inertias and Ia)")
    raise SimulationError(f"{where}: the simulation of '{robot.name}' diverged (non-finite state) "
                          f"{at}; check the parameters, the controller gains, "
                          "or reduce the step (substeps) ")


def _controller_of(robot, controller):
    c = controller if controller is not None else robot.controller
    if c is None:
        raise InputError(f"robot '{robot.name}' has no controller: add a [controller] table "
                         "(kind, rate, wn, zeta, J_ap, g_ap) to its description or pass "
                         "controller=Controller(...)")
    if c.kind not in ("pd", "pid"):
        raise InputError(f"controller.kind must be 'pd' or 'pid', got {c.kind!r}")
    return c


def _reference_on_grid(robot, t, qr, qdr, T, rate, feedforward, notes):
    """The controller's time grid (t itself when it steps by the period T, else t[0] + k T) and
    the reference qr, qdr on it: a trajectory object evaluated there, sampled arrays linearly
    interpolated when the grids differ, qdr by finite differences of qr when not given. What
    was done goes to `notes`."""
    n = robot.n_joints
    span = t[-1] - t[0]
    steps = np.diff(t)
    uniform = np.all(np.abs(steps - T) <= 1e-6 * T)
    if uniform:
        grid = t
    else:
        K = int(math.floor(span / T * (1 + 1e-12) + 1e-9)) + 1
        if K < 2:
            raise InputError(f"t spans {span:.3g} s, less than one controller period 1/{rate:g} s")
        grid = t[0] + T * np.arange(K)
    N = grid.size

    if hasattr(qr, "evaluate"):
        qr_g, qdr_g, _ = qr.evaluate(grid)
        qr_g = _signal(qr_g, N, n, "qr", robot.name)
        qdr_g = _signal(qdr_g, N, n, "qdr", robot.name)
        if qdr is not None:
            raise InputError("give qdr only with a sampled qr, not with a trajectory object")
    else:
        qr_a = _signal(qr, t.size, n, "qr", robot.name)
        qdr_a = None if qdr is None else _signal(qdr, t.size, n, "qdr", robot.name)
        if uniform:
            qr_g, qdr_g = qr_a, qdr_a
        else:
            notes.append(f"reference sampled at {1 / np.median(steps):.6g} Hz, controller at "
                         f"{rate:.6g} Hz: qr{'/qdr' if qdr_a is not None else ''} linearly "
                         "interpolated onto the controller grid")
            qr_g = np.column_stack([np.interp(grid, t, qr_a[:, j]) for j in range(n)])
            qdr_g = (None if qdr_a is None else
                     np.column_stack([np.interp(grid, t, qdr_a[:, j]) for j in range(n)]))
        if qdr_g is None:
            edge = 2 if N >= 3 else 1
            qdr_g = np.gradient(qr_g, grid, axis=0, edge_order=edge)
            notes.append("qdr not given: finite difference of qr used for the initial velocity"
                         + (" and the feedforward" if feedforward else ""))
    return grid, qr_g, qdr_g


# ----------------------------------------------------------------------------- API

def simulate_closed_loop(robot, chi_st, t, qr, qdr=None, *, q0=None, qd0=None, controller=None,
                         kd_scale=None, substeps=1, v_s=DEFAULT_V_S, feedforward=False,
                         rate=None, saturate=True, progress=None, adaptive=False, crba=False) -> SimulationResult:
    """Simulate the robot with parameters `chi_st` tracking `qr` under its controller.

    Parameters
    ----------
    t : (N,) increasing times of the reference samples (s). When `t` is uniform with
        the controller period `1/rate` it is used as the controller grid as is;
        otherwise the controller runs on `t[0] + k/rate` up to `t[-1]` and the
        reference is linearly interpolated onto it (a note says so).
    qr : (N, n) reference positions, or a trajectory object with
        `evaluate(t) -> (q, qd, qdd)` (e.g. `dynid.dynamics.trajectories.FourierTrajectory`),
        evaluated on the controller grid (its velocity becomes `qdr`).
    qdr : (N, n) reference velocities (feedforward, initial velocity). When
        missing it is the second-order finite difference of `qr` (a note says so).
    q0, qd0 : initial state; default `qr(t0)`, `qdr(t0)` (section 3.2).
    controller : a `dynid.dynamics.robot.Controller` replacing `robot.controller`.
    kd_scale : per-joint factor on the derivative gain (DIDIM's `J_hat^k / J_ap`);
        scalar or (n,), positive; default 1.
    substeps : RK4 steps per controller period (>= 1).
    v_s : smooth-sign velocity of Coulomb friction (rad/s); 0 = exact sign.
    feedforward : add the reference velocity `kv qdr` to the PD.
    rate : controller rate in Hz, overriding `controller.rate`.
    saturate : clip the torque at the joints' `tau_max` (default True).
    progress : callable(fraction in [0, 1]) called as the simulation advances.
    adaptive : integrate a controller period with all `substeps` only when a velocity
        reversal is near (some joint or coupled rotor with `|qd| < c v_s + 2 |qdd| T` at the
        period's start, `c = arccosh(2 sqrt(substeps))`), else with one RK4 step (see the
        module doc, "Adaptive substeps"). Default False: every period gets `substeps`.
    crba : M(q) by the composite rigid body algorithm rather than the RNEA columns
        (`dynid.dynamics.dynamic_model`): equal to rounding, about a third cheaper per step.
        Default False: the simulation is bit for bit that of earlier versions.

    Returns
    -------
    SimulationResult
    """
    c = _controller_of(robot, controller)
    n = robot.n_joints
    chi = check_parameters(robot, chi_st)
    ma = model_arrays(robot, chi)
    substeps = _substeps(substeps)
    v_s = _v_s(v_s)
    rate = float(c.rate if rate is None else rate)
    if not np.isfinite(rate) or rate <= 0:
        raise InputError(f"the controller rate must be a positive number of Hz, got {rate!r}")
    T = 1.0 / rate
    t = _time(t)
    notes = []

    grid, qr_g, qdr_g = _reference_on_grid(robot, t, qr, qdr, T, rate, feedforward, notes)
    N = grid.size
    qr_g = np.ascontiguousarray(qr_g, dtype=float)
    qdr_g = np.ascontiguousarray(qdr_g, dtype=float)

    q0 = _initial(q0, qr_g[0], n, "q0")
    qd0 = _initial(qd0, qdr_g[0], n, "qd0")

    wn = _vector(c.wn, n, "controller.wn", positive=True)
    zeta = _vector(c.zeta, n, "controller.zeta", positive=True)
    J_ap = _vector(c.J_ap, n, "controller.J_ap", positive=True)
    g_ap = _vector(c.g_ap, n, "controller.g_ap", default=1.0, positive=True)
    kds = _vector(kd_scale, n, "kd_scale", default=1.0, positive=True)
    kp = wn / (2.0 * zeta)
    kv = 2.0 * zeta * wn
    Kv = J_ap / g_ap * kv * kds
    pid = c.kind == "pid"
    ki = _vector(c.ki, n, "controller.ki", default=0.0) if pid else np.zeros(n)
    Ki = J_ap / g_ap * kds * ki
    gain = robot.drive_gains
    tau_max = robot.limits()[4] if saturate else np.full(n, np.inf)
    tau_max = np.where(np.isfinite(tau_max), tau_max, np.inf)
    with np.errstate(divide="ignore"):
        I_max = np.where(np.abs(gain * Ki) > 0, tau_max / np.abs(gain * Ki), np.inf)

    stiffness = _check_stiffness(robot, chi, q0, T / substeps, v_s, substeps, notes)
    fast = _adaptive_threshold(robot, chi, q0, T, v_s, substeps, notes) if adaptive else -1.0

    Q = np.empty((N, n))
    QD = np.empty((N, n))
    QDD = np.empty((N, n))
    TAU = np.empty((N, n))
    SAT = np.zeros(n, dtype=np.int64)
    REFINED = np.zeros(1, dtype=np.int64)
    q_state, qd_state, integ = q0.copy(), qd0.copy(), np.zeros(n)
    args = (ma.kernel_args(), v_s, np.ascontiguousarray(grid), substeps, qr_g, qdr_g, bool(feedforward),
            pid, Kv, kp, Ki, gain, tau_max, I_max, T, fast, bool(crba), q_state, qd_state, integ)
    # chunks to report progress and, bounded in RK4 steps, to let Ctrl-C / SIGTERM through
    # between them (the compiled loop runs no Python signal handler); the state carries over exactly
    n_chunks = max(1 if progress is None else min(50, N // 2000), -(-N * substeps // RK4_STEPS_PER_CHUNK))
    bounds = np.linspace(0, N, min(N, max(1, n_chunks)) + 1).astype(int)
    for k0, k1 in zip(bounds[:-1], bounds[1:]):
        status, idx = _closed_loop(*args, int(k0), int(k1), Q, QD, QDD, TAU, SAT, REFINED)
        if status != OK:
            break
        if progress is not None:
            progress(k1 / N)
    _status(status, idx, grid, robot, "simulate_closed_loop")
    return SimulationResult(t=np.array(grid), q=Q, qd=QD, qdd=QDD, tau=TAU, qr=qr_g, qdr=qdr_g,
                            robot=robot.name, rate=rate, substeps=substeps, v_s=v_s,
                            kd_scale=kds, feedforward=bool(feedforward), kind=c.kind,
                            saturation=SAT / N, stiffness=stiffness, notes=notes,
                            adaptive=fast >= 0,
                            refined=float(REFINED[0]) / max(N - 1, 1) if fast >= 0 else float("nan"))


def simulate_torque(robot, chi_st, t, tau, q0, qd0, *, substeps=1, v_s=DEFAULT_V_S) -> SimulationResult:
    """Open-loop simulation: `tau` (N, n) held over `[t_k, t_k+1)` (zero-order hold),
    RK4 with `substeps` steps per interval (`t` may be non-uniform)."""
    n = robot.n_joints
    chi = check_parameters(robot, chi_st)
    ma = model_arrays(robot, chi)
    substeps = _substeps(substeps)
    v_s = _v_s(v_s)
    t = _time(t)
    N = t.size
    TAU = _signal(tau, N, n, "tau", robot.name)
    q0 = _vector(q0, n, "q0")
    qd0 = _vector(qd0, n, "qd0")
    notes = []
    stiffness = _check_stiffness(robot, chi, q0, float(np.max(np.diff(t))) / substeps, v_s,
                                 substeps, notes)
    Q = np.empty((N, n))
    QD = np.empty((N, n))
    QDD = np.empty((N, n))
    status, idx = _open_loop(ma.kernel_args(), v_s, np.ascontiguousarray(t), substeps, TAU,
                             q0, qd0, Q, QD, QDD)
    _status(status, idx, t, robot, "simulate_torque")
    steps = np.diff(t)
    rate = 1.0 / float(np.median(steps))
    return SimulationResult(t=t.copy(), q=Q, qd=QD, qdd=QDD, tau=TAU.copy(), robot=robot.name,
                            rate=rate, substeps=substeps, v_s=v_s, kind="open-loop",
                            stiffness=stiffness, notes=notes)
