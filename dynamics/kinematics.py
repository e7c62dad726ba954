"""Forward kinematics and the Newton-Euler forward recursion, vectorised over samples.

All arrays carry the samples on axis 0. `q`, `qd`, `qdd` are `(N, n)`.
"""
from __future__ import annotations

import numpy as np


def _rot_z(q):
    """(N, 3, 3) rotations about z."""
    c, s = np.cos(q), np.sin(q)
    R = np.zeros(q.shape + (3, 3))
    R[:, 0, 0] = c
    R[:, 0, 1] = -s
    R[:, 1, 0] = s
    R[:, 1, 1] = c
    R[:, 2, 2] = 1.0
    return R


def _cross(a, b):
    """Row-wise cross product of (N, 3) arrays (faster than np.cross for small N x 3)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _mat_t_vec(R, v):
    """R^T v for (N,3,3) R and (N,3) v."""
    return np.einsum("nji,nj->ni", R, v)


def link_transforms(robot, q):
    """Orientation and origin of each joint frame relative to its predecessor.

    Returns lists `R[j]` (N, 3, 3) (frame j in frame j-1) and `P[j]` (N, 3)
    (origin of frame j in frame j-1).
    """
    N = q.shape[0]
    Rs, Ps = [], []
    for j, joint in enumerate(robot.joints):
        if joint.sigma == 0:
            R = joint.R @ _rot_z(q[:, j])          # (3,3) @ (N,3,3) broadcasts
            P = np.broadcast_to(joint.p, (N, 3))
        else:
            R = np.broadcast_to(joint.R, (N, 3, 3))
            P = joint.p + q[:, j, None] * joint.R[:, 2]
        Rs.append(R)
        Ps.append(P)
    return Rs, Ps


def forward_kinematics(robot, q, transforms=None):
    """Orientation (N,3,3) and origin (N,3) of every joint frame in the base frame.

    `transforms` reuses the output of `link_transforms`.
    """
    Rs, Ps = link_transforms(robot, q) if transforms is None else transforms
    R0 = np.broadcast_to(np.eye(3), (q.shape[0], 3, 3))
    p0 = np.zeros((q.shape[0], 3))
    Rw, pw = [], []
    for R, P in zip(Rs, Ps):
        p0 = p0 + np.einsum("nij,nj->ni", R0, P)
        R0 = R0 @ R
        Rw.append(R0)
        pw.append(p0)
    return Rw, pw


def newton_euler_forward(robot, q, qd, qdd, gravity=None):
    """Angular velocity, angular acceleration and origin acceleration of each link.

    The forward recursion of the Newton-Euler algorithm (Khalil & Dombre 2002,
    ch. 9), in each link's own frame. Gravity enters as an upward acceleration
    of the base, `v̇_0 = -g`, so the link forces include the weights.
    """
    N, n = q.shape
    g = robot.gravity if gravity is None else np.asarray(gravity, dtype=float)
    Rs, Ps = link_transforms(robot, q)
    w = np.zeros((N, 3))
    dw = np.zeros((N, 3))
    dv = np.broadcast_to(-g, (N, 3)).astype(float)
    out = []
    for j, joint in enumerate(robot.joints):
        R, P = Rs[j], Ps[j]
        # acceleration of the new origin, still in frame j-1
        a_prev = dv + _cross(dw, P) + _cross(w, _cross(w, P))
        w_in = _mat_t_vec(R, w)
        dw_in = _mat_t_vec(R, dw)
        dv_j = _mat_t_vec(R, a_prev)
        if joint.sigma == 0:
            w_j = w_in.copy()
            w_j[:, 2] += qd[:, j]
            dw_j = dw_in.copy()
            dw_j[:, 2] += qdd[:, j]
            # w_in x (qd z)
            dw_j[:, 0] += w_in[:, 1] * qd[:, j]
            dw_j[:, 1] -= w_in[:, 0] * qd[:, j]
        else:
            w_j = w_in
            dw_j = dw_in
            dv_j = dv_j.copy()
            dv_j[:, 2] += qdd[:, j]
            # Coriolis 2 w x (qd z)
            dv_j[:, 0] += 2.0 * w_j[:, 1] * qd[:, j]
            dv_j[:, 1] -= 2.0 * w_j[:, 0] * qd[:, j]
        out.append((w_j, dw_j, dv_j))
        w, dw, dv = w_j, dw_j, dv_j
    return out, Rs, Ps
