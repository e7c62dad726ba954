"""Decoupled per-joint robot model and its closed-loop simulation (Bona & Curatella 2005, sec. 3).

Each joint `i` is the 1-DOF model of eqs. (21)-(22)::

    M_i qdd_i = tau_i - g_i(q_i) - f_i(qd_i)

with the friction of eq. (2), asymmetric in the sign of the velocity::

    f_i(qd) = Fv+_i qd + Fc+_i    qd > 0
              0                   qd = 0
              Fv-_i qd - Fc-_i    qd < 0

All four coefficients are positive magnitudes. The paper prints `+ beta^{c-}`
in the third line; with the positive values of its Table 2 that would make
Coulomb friction push a joint moving backwards, so the physical sign (friction
opposes the motion) is used.

Gravity is a sinusoid of the joint's own position, eq. (23)::

    g_i(q) = k_i sin(q + q_off_i) = gs_i sin q + gc_i cos q,
    gs_i = k_i cos q_off_i,  gc_i = k_i sin q_off_i.

For a link with first moments `(MX_i, MY_i)` about a horizontal axis (x of
the previous frame horizontal) `g_i(q) = g0 (MX_i cos q - MY_i sin q)`, i.e.
`gs = -g0 MY`, `gc = g0 MX` (`JointModel.from_first_moments`).

Closed loop (`simulate_joints`): a sampled PID per joint at rate `1/T`
on the *measured* position (true position plus encoder noise), velocity by the
backward difference of the measured position, torque held over the period
(zero-order hold). Between samples the plant is integrated with `substeps`
steps of a trapezoidal rule whose velocity update is implicit in the friction::

    J v' + (h/2) Fv(v') v' + h Fc(v') = J v + h (u - g(q + h v / 2) - (h/2) Fv(v) v)

solved in closed form (try v' > 0, then v' < 0, else stick at 0), so the
Coulomb discontinuity needs no smoothing and no stiff step: sticking is exact
and the smooth part is second-order. `tests/analysis/decoupled/test_decoupled.py` checks it
against the exact zero-order-hold discretisation (matrix exponential) of the
linear case.

Everything is vectorised over repetitions and joints: states are (R, n).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynid.errors import InputError

G0 = 9.81

__all__ = ["JointModel", "JointPID", "JointSimulation", "simulate_joints", "G0"]


def _vec(x, n, name, *, positive=False, nonneg=False):
    try:
        a = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy()
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number or {n} numbers (one per joint), got {x!r}") from None
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be finite, got {a}")
    if positive and np.any(a <= 0):
        raise InputError(f"{name} must be > 0 for every joint, got {a}")
    if nonneg and np.any(a < 0):
        raise InputError(f"{name} must be >= 0 for every joint (magnitudes), got {a}")
    return a


@dataclass(eq=False)
class JointModel:
    """Per-joint parameters of eqs. (2), (21)-(23); every field is an (n,) array in SI units.

    `inertia` M_i [kg m^2]; `fv_pos`, `fv_neg` [N m s/rad]; `fc_pos`,
    `fc_neg` [N m] (positive magnitudes); `gs`, `gc` [N m]: gravity
    `gs sin q + gc cos q`.
    """

    inertia: np.ndarray
    fv_pos: np.ndarray
    fv_neg: np.ndarray
    fc_pos: np.ndarray
    fc_neg: np.ndarray
    gs: np.ndarray = None
    gc: np.ndarray = None
    name: str = "decoupled joints"

    def __post_init__(self):
        n = np.size(self.inertia)
        self.inertia = _vec(self.inertia, n, "inertia", positive=True)
        for f in ("fv_pos", "fv_neg", "fc_pos", "fc_neg"):
            setattr(self, f, _vec(getattr(self, f), n, f, nonneg=True))
        self.gs = _vec(0.0 if self.gs is None else self.gs, n, "gs")
        self.gc = _vec(0.0 if self.gc is None else self.gc, n, "gc")

    @property
    def n_joints(self) -> int:
        return self.inertia.size

    @staticmethod
    def gravity_from_sinusoid(k, q_off):
        """`(gs, gc)` of `k sin(q + q_off)`, eq. (23)."""
        k, q_off = np.asarray(k, dtype=float), np.asarray(q_off, dtype=float)
        return k * np.cos(q_off), k * np.sin(q_off)

    @staticmethod
    def gravity_from_first_moments(mx, my, g0=G0):
        """`(gs, gc)` of `g0 (MX cos q - MY sin q)` (horizontal joint axis)."""
        return -g0 * np.asarray(my, dtype=float), g0 * np.asarray(mx, dtype=float)

    def gravity(self, q):
        """g_i(q), eq. (23); q (..., n)."""
        return self.gs * np.sin(q) + self.gc * np.cos(q)

    def friction(self, qd):
        """f_i(qd), eq. (2) with the physical sign of the Coulomb term; qd (..., n)."""
        return np.where(qd > 0, self.fv_pos * qd + self.fc_pos,
                        np.where(qd < 0, self.fv_neg * qd - self.fc_neg, 0.0))

    def torque(self, q, qd, qdd):
        """Inverse dynamics of eq. (21): M qdd + g(q) + f(qd)."""
        return self.inertia * qdd + self.gravity(q) + self.friction(qd)


@dataclass(eq=False)
class JointPID:
    """Sampled PID per joint: `u = kp e + ki sum(e) T - kd v_meas` (derivative on the measurement,
    so a reference step does not kick the torque); gains (n,) in N m/rad, N m/(rad s), N m s/rad.

    `v_meas`: backward difference of the measured position, through a first-order low-pass
    at `velocity_filter_hz` when given (`v += a (dq/T - v)`, `a = 1 - exp(-2 pi f T)`)."""

    kp: np.ndarray
    kd: np.ndarray
    ki: np.ndarray
    velocity_filter_hz: float | None = None   # first-order low-pass of the differenced position

    @classmethod
    def triple_pole(cls, inertia, bandwidth_hz=3.0, velocity_filter_hz=None):
        """Gains placing the three poles of `J s^3 + kd s^2 + kp s + ki` at `-w`, `w = 2 pi
        bandwidth`: `kd = 3 J w`, `kp = 3 J w^2`, `ki = J w^3`."""
        J = np.asarray(inertia, dtype=float)
        w = 2 * np.pi * float(bandwidth_hz)
        return cls(kp=3 * J * w ** 2, kd=3 * J * w, ki=J * w ** 3, velocity_filter_hz=velocity_filter_hz)


@dataclass(eq=False)
class JointSimulation:
    """Samples at the controller times: `t` (N,), the rest (R, N, n).

    `q`, `qd`: true state; `tau`: torque applied over `[t_k, t_k+1)`;
    `q_meas`, `tau_meas`: with sensor noise (what a log holds); `qr`: the
    reference (N, n).
    """

    t: np.ndarray
    qr: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    q_meas: np.ndarray
    tau_meas: np.ndarray
    settings: dict = field(default_factory=dict)

    @property
    def n_repetitions(self) -> int:
        return self.q.shape[0]

    def describe(self) -> str:
        """`R repetitions x N samples (D s at F Hz) of n joints`: what the recording holds."""
        R, N, n = self.q.shape
        span = float(self.t[-1] - self.t[0]) if N > 1 else 0.0
        rate = f" at {(N - 1) / span:.0f} Hz" if span > 0 else ""
        return f"{R} repetition(s) x {N} samples ({span:.2f} s{rate}) of {n} joint(s)"

    def __repr__(self) -> str:
        return f"<JointSimulation {self.describe()}>"


def _step(model, q, v, u, h):
    """One trapezoidal step with implicit friction (see the module doc), in place of (q, v)."""
    J = model.inertia
    g = model.gravity(q + 0.5 * h * v)
    visc_now = np.where(v > 0, model.fv_pos, np.where(v < 0, model.fv_neg, 0.0)) * v
    rhs = J * v + h * (u - g - 0.5 * visc_now)
    v_pos = (rhs - h * model.fc_pos) / (J + 0.5 * h * model.fv_pos)
    v_neg = (rhs + h * model.fc_neg) / (J + 0.5 * h * model.fv_neg)
    # The friction graph is monotone, so at most one of the two branches is consistent.
    v_new = np.where(v_pos > 0, v_pos, np.where(v_neg < 0, v_neg, 0.0))
    q_new = q + 0.5 * h * (v + v_new)
    return q_new, v_new


def simulate_joints(model: JointModel, t, qr, controller: JointPID, *, repetitions=1, q0=None,
                    q_noise=0.0, tau_noise=0.0, substeps=2, tau_max=None, seed=None) -> JointSimulation:
    """Closed-loop simulation of the decoupled joints tracking `qr` (N, n) sampled at `t` (N,).

    `t` must be uniformly spaced (the controller period). `q0` (n,) initial
    position (default `qr[0]`), at rest. `q_noise`, `tau_noise`: standard
    deviations (scalar or (n,)) of the white Gaussian noise of the position
    sensor (fed back to the controller and logged) and of the torque log.
    `repetitions`: R independent noise realisations, simulated together.
    """
    t = np.asarray(t, dtype=float)
    qr = np.asarray(qr, dtype=float)
    n = model.n_joints
    if qr.ndim == 1:
        qr = qr[:, None]
    if t.ndim != 1 or t.size < 2 or qr.shape != (t.size, n):
        raise InputError(f"t must be (N,) and qr (N, {n}) for {n} joints; got t {t.shape}, qr {qr.shape}")
    dt = np.diff(t)
    T = float(dt.mean())
    if not np.all(np.isfinite(qr)) or T <= 0 or np.ptp(dt) > 1e-9 * max(T, 1.0):
        raise InputError("t must be uniformly spaced and increasing and qr finite "
                         "(the controller runs at a fixed rate)")
    R = int(repetitions)
    if R < 1:
        raise InputError(f"repetitions must be >= 1, got {repetitions!r}")
    substeps = int(substeps)
    if substeps < 1:
        raise InputError(f"substeps must be >= 1, got {substeps!r}")
    sq = _vec(q_noise, n, "q_noise", nonneg=True)
    st = _vec(tau_noise, n, "tau_noise", nonneg=True)
    tmax = np.full(n, np.inf) if tau_max is None else _vec(tau_max, n, "tau_max", positive=True)
    rng = np.random.default_rng(seed)
    N = t.size
    eq = rng.standard_normal((R, N, n)) * sq
    et = rng.standard_normal((R, N, n)) * st

    q = np.broadcast_to(qr[0] if q0 is None else _vec(q0, n, "q0"), (R, n)).copy()
    v = np.zeros((R, n))
    integ = np.zeros((R, n))
    q_prev_meas = q + eq[:, 0]
    Q = np.empty((R, N, n))
    V = np.empty((R, N, n))
    U = np.empty((R, N, n))
    h = T / substeps
    kp, kd, ki = controller.kp, controller.kd, controller.ki
    fv = controller.velocity_filter_hz
    # The differenced encoder noise, times kd, would be torque jitter of tens of N m on the
    # shoulder joints; drives filter it, at a lag negligible at the loop's bandwidth.
    alpha = 1.0 if fv is None else 1.0 - np.exp(-2 * np.pi * float(fv) * T)
    v_meas = np.zeros((R, n))
    for k in range(N):
        Q[:, k] = q
        V[:, k] = v
        qm = q + eq[:, k]
        e = qr[k] - qm
        integ += T * e
        v_meas = v_meas + alpha * ((qm - q_prev_meas) / T - v_meas)
        q_prev_meas = qm
        u = np.clip(kp * e + ki * integ - kd * v_meas, -tmax, tmax)
        U[:, k] = u
        for _ in range(substeps):
            q, v = _step(model, q, v, u, h)
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(U))):
        raise InputError("the simulation diverged: check the controller gains against the model")
    return JointSimulation(t=t, qr=qr, q=Q, qd=V, tau=U, q_meas=Q + eq, tau_meas=U + et,
                           settings={"rate": 1.0 / T, "substeps": substeps, "repetitions": R,
                                     "q_noise": sq.tolist(), "tau_noise": st.tolist(),
                                     "kp": kp.tolist(), "kd": kd.tolist(), "ki": ki.tolist(),
                                     "velocity_filter_hz": fv})
