"""Independent implementations dynid is checked against (test-time only).

Pinocchio models are built here from the robot's joint placements (DH rows or
URDF origins) without using dynid's kinematics or regressor code.
"""
import numpy as np
from scipy.linalg.lapack import dgesv

pin = None
try:  # pragma: no cover - depends on the test environment
    import pinocchio as pin
except ImportError:
    pass


def pin_model_from_robot(robot, chi_st):
    """Pinocchio model of a dynid robot with inertias from the standard parameters.

    Uses only the joint placements (R, p) and sigma from the robot description,
    and Pinocchio's own dynamic-parameter convention
    [m, mc_x, mc_y, mc_z, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] (inertia about the joint
    frame origin), mapped from dynid's XX XY XZ YY YZ ZZ MX MY MZ M.
    """
    model = pin.Model()
    model.gravity.linear = np.asarray(robot.gravity, dtype=float)
    parent = 0
    for j, joint in enumerate(robot.joints):
        placement = pin.SE3(np.asarray(joint.R, dtype=float), np.asarray(joint.p, dtype=float))
        jm = pin.JointModelRZ() if joint.sigma == 0 else pin.JointModelPZ()
        parent = model.addJoint(parent, jm, placement, joint.name)
        XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, M = chi_st[14 * j:14 * j + 10]
        dyn = np.array([M, MX, MY, MZ, XX, XY, YY, XZ, YZ, ZZ])
        model.appendBodyToJoint(parent, pin.Inertia.FromDynamicParameters(dyn), pin.SE3.Identity())
    return model


def actuator_torques(robot, chi_st, q, qd, qdd):
    """Ia qdd + Fv qd + Fc sign(qd) + Off and the coupling terms, written out by hand."""
    n = robot.n_joints
    tau = np.zeros(n)
    for j in range(n):
        Ia, Fv, Fc, Off = chi_st[14 * j + 10:14 * j + 14]
        tau[j] += Ia * qdd[j] + Fv * qd[j] + Fc * np.sign(qd[j]) + Off
    k = 14 * n
    for c in robot.couplings:
        idx = [i - 1 for i in c.joints]
        coef = np.asarray(c.coefficients)
        cm = coef[list(c.joints).index(c.motor)]
        Ia_m = chi_st[14 * (c.motor - 1) + 10]
        for a, ka in zip(idx, coef):
            for b, kb in zip(idx, coef):
                if a != b:
                    tau[a] += ka * kb / cm ** 2 * Ia_m * qdd[b]
        if c.friction:
            w = float(coef @ qd[idx])
            for a, ka in zip(idx, coef):
                tau[a] += ka * (chi_st[k] * w + chi_st[k + 1] * np.sign(w))
            k += 2
    return tau


def armature_matrix(robot, chi_st):
    """The actuator-inertia part of M: diag(Ia) plus the coupling off-diagonals."""
    n = robot.n_joints
    A = np.diag([chi_st[14 * j + 10] for j in range(n)])
    for c in robot.couplings:
        idx = [i - 1 for i in c.joints]
        coef = np.asarray(c.coefficients)
        cm = coef[list(c.joints).index(c.motor)]
        Ia_m = chi_st[14 * (c.motor - 1) + 10]
        for a, ka in zip(idx, coef):
            for b, kb in zip(idx, coef):
                if a != b:
                    A[a, b] += ka * kb / cm ** 2 * Ia_m
    return A


def random_standard_parameters(robot, rng):
    """Random but physically plausible standard parameters (positive mass, PD inertia)."""
    chi = np.zeros(robot.n_standard)
    for j in range(robot.n_joints):
        m = rng.uniform(0.5, 5.0)
        c = rng.normal(0, 0.2, 3)
        A = rng.normal(0, 0.1, (3, 3))
        Ic = A @ A.T + 0.01 * np.eye(3)
        I = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
        chi[14 * j:14 * j + 14] = [I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2],
                                   *(m * c), m, rng.uniform(0.01, 1), rng.uniform(0, 5),
                                   rng.uniform(0, 5), rng.normal(0, 1)]
    chi[14 * robot.n_joints:] = rng.uniform(0.1, 2.0, robot.n_standard - 14 * robot.n_joints)
    return chi


def _rot(axis, angle):
    """Rotation about a principal axis, via Pinocchio's AngleAxis (not dynid code)."""
    u = np.zeros(3)
    u["xyz".index(axis)] = 1.0
    return pin.AngleAxis(float(angle), u).matrix()


def mdh_se3(alpha, d, theta, r):
    """Rot(x, alpha) Trans(x, d) Rot(z, theta) Trans(z, r) as a product of Pinocchio SE3s."""
    ex, ez = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    return (pin.SE3(_rot("x", alpha), np.zeros(3)) * pin.SE3(np.eye(3), d * ex)
            * pin.SE3(_rot("z", theta), np.zeros(3)) * pin.SE3(np.eye(3), r * ez))


def pin_model_from_mdh(rows, gravity, chi_st):
    """Pinocchio model from modified-DH rows ``(sigma, alpha, d, theta, r)``.

    Independent of dynid's ``mdh_placement``: each placement is composed from
    elementary Pinocchio SE3 transforms, so a wrong DH convention in dynid shows.
    """
    model = pin.Model()
    model.gravity.linear = np.asarray(gravity, dtype=float)
    parent = 0
    for j, (sigma, alpha, d, theta, r) in enumerate(rows):
        jm = pin.JointModelRZ() if sigma == 0 else pin.JointModelPZ()
        parent = model.addJoint(parent, jm, mdh_se3(alpha, d, theta, r), f"j{j + 1}")
        XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, M = chi_st[14 * j:14 * j + 10]
        dyn = np.array([M, MX, MY, MZ, XX, XY, YY, XZ, YZ, ZZ])
        model.appendBodyToJoint(parent, pin.Inertia.FromDynamicParameters(dyn), pin.SE3.Identity())
    return model


def chi_from_values(robot, values):
    """Standard vector from a ``{name: value}`` mapping (missing names are 0)."""
    names = robot.standard_names
    chi = np.zeros(len(names))
    for k, v in values.items():
        chi[names.index(k)] = v
    return chi


def pin_torques(model, q, qd, qdd):
    """Pinocchio's rnea, one sample at a time (N, n)."""
    data = model.createData()
    return np.array([pin.rnea(model, data, q[i], qd[i], qdd[i]).copy() for i in range(len(q))])


def rel_err(a, b):
    """Largest error per column (joint) relative to that column's largest reference value.

    Columns that are (almost) zero throughout are measured against 1e-6 of the
    largest reference value of all columns instead.
    """
    a, b = np.asarray(a), np.asarray(b)
    big = np.abs(b).max()
    scale = np.maximum(np.abs(b).max(axis=0), max(1e-6 * big, 1e-300))
    return float((np.abs(a - b).max(axis=0) / scale).max())


# ----------------------------------------------------------------------------- simulation

def _ssign(x, v_s):
    """Smooth sign tanh(x / v_s), exact sign for v_s = 0 (written independently of dynid)."""
    return np.tanh(x / v_s) if v_s > 0 else np.sign(x)


def friction_torques(robot, chi_st, qd, v_s):
    """Fv qd + Fc s(qd) + Off + coupling friction c_k (Fvm w + Fcm s(w)), w = sum c_k qd_k.

    One call, written out per joint (benchmarks/didim.py's plain-Python baseline calls it at
    every step); `PinPlant` computes the same with the coefficients gathered once (`_Friction`).
    """
    n = robot.n_joints
    tau = np.zeros(n)
    for j in range(n):
        Ia, Fv, Fc, Off = chi_st[14 * j + 10:14 * j + 14]
        tau[j] = Fv * qd[j] + Fc * _ssign(qd[j], v_s) + Off
    k = 14 * n
    for c in robot.couplings:
        if not c.friction:
            continue
        idx = [i - 1 for i in c.joints]
        coef = np.asarray(c.coefficients, dtype=float)
        w = float(coef @ qd[idx])
        for a, ka in zip(idx, coef):
            tau[a] += ka * (chi_st[k] * w + chi_st[k + 1] * _ssign(w, v_s))
        k += 2
    return tau


class _Friction:
    """`friction_torques` with the coefficients gathered once, for a plant called at every
    RK4 stage: Fv, Fc, Off per joint as arrays and, per coupling with friction, its joint
    indices, coefficients c_k and (Fvm, Fcm), in the order of the couplings."""

    def __init__(self, robot, chi_st, v_s):
        chi = np.asarray(chi_st, dtype=float)
        n = robot.n_joints
        j14 = 14 * np.arange(n)
        self.Fv, self.Fc, self.Off = chi[j14 + 11], chi[j14 + 12], chi[j14 + 13]
        self.v_s = v_s
        self.couplings = []
        k = 14 * n
        for c in robot.couplings:
            if c.friction:
                idx = np.array([i - 1 for i in c.joints])
                self.couplings.append((idx, np.asarray(c.coefficients, dtype=float), float(chi[k]), float(chi[k + 1])))
                k += 2

    def __call__(self, qd):
        tau = self.Fv * qd + self.Fc * _ssign(qd, self.v_s) + self.Off
        for idx, coef, Fvm, Fcm in self.couplings:
            w = float(coef @ qd[idx])
            tau[idx] += coef * (Fvm * w + Fcm * _ssign(w, self.v_s))
        return tau


def _solve(M, b):
    """np.linalg.solve(M, b) for a symmetric M (passed transposed: Fortran order, no copy), by
    LAPACK's dgesv, the routine np.linalg.solve calls, without its per-call overhead.

    Overwrites M and b (the caller's temporaries) and returns b's storage as the solution.
    """
    _, _, x, info = dgesv(M.T, b, overwrite_a=1, overwrite_b=1)
    if info != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return x


class PinPlant:
    """qdd = f(q, qd, tau) from Pinocchio: aba with model.armature when the robot has
    no coupling, else solve(crba + armature_matrix, tau - nle - friction)."""

    def __init__(self, robot, chi_st, v_s):
        self.robot = robot
        self.chi = np.asarray(chi_st, dtype=float)
        self.v_s = v_s
        self.model = pin_model_from_robot(robot, self.chi)
        self.data = self.model.createData()
        self.A = armature_matrix(robot, self.chi)
        self.friction = _Friction(robot, self.chi, v_s)
        self.use_aba = not robot.couplings
        if self.use_aba:
            self.model.armature = np.diag(self.A).copy()
        # crba fills the upper triangle: M_sym = M.take(sym), sym[i, j] = flat index of M[min, max]
        i, j = np.indices(self.A.shape)
        n = self.A.shape[0]
        self.sym = np.minimum(i, j) * n + np.maximum(i, j)

    def __call__(self, q, qd, tau):
        f = self.friction(qd)
        if self.use_aba:
            return np.array(pin.aba(self.model, self.data, q, qd, tau - f))
        M = np.asarray(pin.crba(self.model, self.data, q)).take(self.sym)
        M += self.A
        h = pin.nonLinearEffects(self.model, self.data, q, qd)
        return _solve(M, tau - h - f)


def pin_closed_loop(robot, chi_st, t, qr, qdr, q0, qd0, *, kd_scale=None, substeps=1,
                    v_s=0.01, feedforward=False, saturate=True):
    """Closed-loop simulation written in plain Python on a Pinocchio plant.

    Same controller (PD of the normalised double integrator scaled by J_ap / g_ap,
    derivative gain times kd_scale, optional velocity feedforward, PID with the
    integral clamped so its torque stays within tau_max), same zero-order hold on
    the grid t, same classical RK4 with `substeps` steps per interval.
    Returns (q, qd, qdd, tau) at the samples.
    """
    ctrl = robot.controller
    n = robot.n_joints
    plant = PinPlant(robot, chi_st, v_s)
    wn = np.asarray(ctrl.wn, float)
    zeta = np.asarray(ctrl.zeta, float)
    kp = wn / (2 * zeta)
    kv = 2 * zeta * wn
    scale = np.asarray(ctrl.J_ap, float) / np.asarray(ctrl.g_ap if ctrl.g_ap is not None else 1.0)
    scale = scale * (np.ones(n) if kd_scale is None else np.asarray(kd_scale, float))
    ki = np.asarray(ctrl.ki, float) if ctrl.kind == "pid" and ctrl.ki is not None else np.zeros(n)
    g = np.array([jt.drive_gain for jt in robot.joints], float)
    tmax = np.array([jt.tau_max for jt in robot.joints], float) if saturate else np.full(n, np.inf)
    with np.errstate(divide="ignore"):
        imax = np.where(np.abs(g * scale * ki) > 0, tmax / np.abs(g * scale * ki), np.inf)
    skv, ski = scale * kv, scale * ki             # (scale kv) u, (scale ki) integral, as written below
    pid = ctrl.kind == "pid"
    clip_tau = bool(np.isfinite(tmax).any())      # clip to +-inf is the identity
    T = t[1] - t[0]
    N = len(t)
    Q, QD, QDD, TAU = (np.zeros((N, n)) for _ in range(4))
    q, qd, integ = np.array(q0, float), np.array(qd0, float), np.zeros(n)
    for k in range(N):
        # tau = clip(g (scale kv (kp e - qd + qdr_ff) + scale ki integ), -tmax, tmax)
        e = qr[k] - q
        u = kp * e - qd
        u += qdr[k] if feedforward else 0.0     # + 0.0 as before: a -0.0 becomes +0.0
        v = skv * u
        if pid:
            integ = np.minimum(np.maximum(integ + T * e, -imax), imax)
            v += ski * integ
        tau = g * v
        if clip_tau:
            tau = np.minimum(np.maximum(tau, -tmax), tmax)
        a1 = plant(q, qd, tau)
        Q[k], QD[k], QDD[k], TAU[k] = q, qd, a1, tau
        if k == N - 1:
            break
        h = (t[k + 1] - t[k]) / substeps
        for s in range(substeps):
            if s > 0:
                a1 = plant(q, qd, tau)
            q, qd = rk4_step(plant, q, qd, tau, h, a1)
    return Q, QD, QDD, TAU


def rk4_step(plant, q, qd, tau, h, a1):
    """One classical RK4 step of qdd = plant(q, qd, tau) with tau held; a1 = plant(q, qd, tau)."""
    h2 = h / 2
    q2, v2 = q + h2 * qd, qd + h2 * a1
    a2 = plant(q2, v2, tau)
    q3, v3 = q + h2 * v2, qd + h2 * a2
    a3 = plant(q3, v3, tau)
    q4, v4 = q + h * v3, qd + h * a3
    a4 = plant(q4, v4, tau)
    h6 = h / 6
    return q + h6 * (qd + 2.0 * v2 + 2.0 * v3 + v4), qd + h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)


# ----------------------------------------------------------------------------- base-parameter data

def pin_compatible_parameters(robot, bp, beta, mass=1.0):
    """A standard-parameter vector with base parameters ``beta`` that Pinocchio can hold.

    Base-parameter values written as standard parameters with the regrouped ones at
    zero (``bp.to_standard(beta, 'zero')``) have zero link masses but non-zero first
    moments (MX2R of the TX40), which Pinocchio's Inertia (mass, centre of mass)
    cannot represent. This moves along the null space of the regrouping: the
    smallest change of that vector that sets every link mass to ``mass`` while
    keeping ``P chi = beta`` exactly, so the dynamics are unchanged.
    """
    P = bp.matrix
    chi0 = bp.to_standard(beta, "zero")
    rows = [14 * j + 9 for j in range(robot.n_joints)]        # M_j
    E = np.zeros((len(rows), P.shape[1]))
    E[np.arange(len(rows)), rows] = 1.0
    A = np.vstack([P, E])
    b = np.concatenate([np.asarray(beta, dtype=float), np.full(len(rows), float(mass))])
    delta = np.linalg.lstsq(A, b - A @ chi0, rcond=None)[0]
    chi = chi0 + delta
    if not np.allclose(P @ chi, beta, rtol=0, atol=1e-9 * max(1.0, np.abs(beta).max())):
        raise RuntimeError("pin_compatible_parameters: link masses are not free for this robot")
    return chi


def regressor_inverse_dynamics(robot, chi_st, q, qd, qdd):
    """tau = IDM_st(q, qd, qdd) chi_st of eq. (2), through dynid's public regressor.

    Not independent of dynid: a second route (the linear-in-parameters regressor) against
    which the compiled per-sample RNEA of dynid.dynamics.dynamic_model is compared.
    """
    from dynid.dynamics.regressor import regressor
    return regressor(robot, q, qd, qdd) @ np.asarray(chi_st, dtype=float)
