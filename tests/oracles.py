"""Independent implementations dynid is checked against (test-time only).

Pinocchio models are built here from the robot's joint placements (DH rows or
URDF origins) without using dynid's kinematics or regressor code.
"""
import numpy as np

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
