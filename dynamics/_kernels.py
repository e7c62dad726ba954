"""Compiled inner loops (numba) for the regressor.

The same Newton-Euler-in-the-parameters algorithm as the NumPy code in
`regressor.py`, written per sample with scalars so nothing is allocated in
the loop. It is the default backend; `backend="numpy"` keeps the vectorised
NumPy path (tests check both against Pinocchio).
"""
from __future__ import annotations

import numpy as np

try:
    import numba

    from dynid.numba_cache import install as _cache_outside_the_package
    _cache_outside_the_package()   # before the first njit(cache=True): dynid.numba_cache
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is a declared dependency
    HAVE_NUMBA = False


def _whole_row_start_py(out, s, n, width, qd, qdd):
    """Sample `s`'s rows: zeros where the Newton-Euler loop writes nothing (links j < i do
    not load joint i, the other joints' actuator columns, the coupling columns), and Ia, Fv,
    Fc, Off on the diagonal as in `regressor._actuator_columns`."""
    for i in range(n):
        for j in range(n):
            c = 14 * j
            if j < i:
                for k in range(10):
                    out[s, i, c + k] = 0.0
            if j != i:
                for k in range(10, 14):
                    out[s, i, c + k] = 0.0
        for k in range(14 * n, width):
            out[s, i, k] = 0.0
        d = qd[s, i]
        c = 14 * i
        out[s, i, c + 10] = qdd[s, i]
        out[s, i, c + 11] = d
        # np.sign: 0 at 0, nan at nan
        out[s, i, c + 12] = 1.0 if d > 0.0 else (-1.0 if d < 0.0 else (0.0 if d == 0.0 else d))
        out[s, i, c + 13] = 1.0


if HAVE_NUMBA:
    _whole_row_start = numba.njit(cache=True, nogil=True, inline="always")(_whole_row_start_py)
else:  # pragma: no cover
    _whole_row_start = _whole_row_start_py


def _joint_transforms_py(Rp, pp, sigma, q, R, P):
    """Frame j in frame j-1 for joint positions q (n,): `R[j] = Rp[j] Rot(z, q_j)` for a
    revolute joint, `P[j] = pp[j] + q_j Rp[j] z` for a prismatic one. Shared by the regressor
    kernel here and the dynamics of dynamic_model."""
    n = q.shape[0]
    for j in range(n):
        if sigma[j] == 0:
            c = np.cos(q[j])
            s = np.sin(q[j])
            for a in range(3):
                R[j, a, 0] = Rp[j, a, 0] * c + Rp[j, a, 1] * s
                R[j, a, 1] = -Rp[j, a, 0] * s + Rp[j, a, 1] * c
                R[j, a, 2] = Rp[j, a, 2]
                P[j, a] = pp[j, a]
        else:
            for a in range(3):
                for b in range(3):
                    R[j, a, b] = Rp[j, a, b]
                P[j, a] = pp[j, a] + q[j] * Rp[j, a, 2]


if HAVE_NUMBA:
    joint_transforms = numba.njit(cache=True, nogil=True)(_joint_transforms_py)
else:  # pragma: no cover
    joint_transforms = _joint_transforms_py


def _propagate_link_py(R, P, j, sigma_j, qdj, qddj, wx, wy, wz, ax, ay, az, vx, vy, vz):
    """One step of the Newton-Euler forward recursion: link j's angular velocity, angular
    acceleration and origin acceleration (gravity included) in frame j, from its parent's in
    frame j-1 (R, P: joint j's rotation and origin in frame j-1; sigma_j 0 revolute, 1 prismatic).
    Shared by the regressor kernel here and the RNEA of dynamic_model, term for term."""
    px = P[j, 0]; py = P[j, 1]; pz = P[j, 2]
    # acceleration of origin j in frame j-1: dv + dw x P + w x (w x P)
    cx = wy * pz - wz * py
    cy = wz * px - wx * pz
    cz = wx * py - wy * px
    tx = vx + (ay * pz - az * py) + (wy * cz - wz * cy)
    ty = vy + (az * px - ax * pz) + (wz * cx - wx * cz)
    tz = vz + (ax * py - ay * px) + (wx * cy - wy * cx)
    # into frame j: R^T x
    nwx = R[j, 0, 0] * wx + R[j, 1, 0] * wy + R[j, 2, 0] * wz
    nwy = R[j, 0, 1] * wx + R[j, 1, 1] * wy + R[j, 2, 1] * wz
    nwz = R[j, 0, 2] * wx + R[j, 1, 2] * wy + R[j, 2, 2] * wz
    nax = R[j, 0, 0] * ax + R[j, 1, 0] * ay + R[j, 2, 0] * az
    nay = R[j, 0, 1] * ax + R[j, 1, 1] * ay + R[j, 2, 1] * az
    naz = R[j, 0, 2] * ax + R[j, 1, 2] * ay + R[j, 2, 2] * az
    nvx = R[j, 0, 0] * tx + R[j, 1, 0] * ty + R[j, 2, 0] * tz
    nvy = R[j, 0, 1] * tx + R[j, 1, 1] * ty + R[j, 2, 1] * tz
    nvz = R[j, 0, 2] * tx + R[j, 1, 2] * ty + R[j, 2, 2] * tz
    if sigma_j == 0:
        nax += nwy * qdj
        nay -= nwx * qdj
        naz += qddj
        nwz += qdj
    else:
        nvx += 2.0 * nwy * qdj
        nvy -= 2.0 * nwx * qdj
        nvz += qddj
    return nwx, nwy, nwz, nax, nay, naz, nvx, nvy, nvz


if HAVE_NUMBA:
    propagate_link = numba.njit(cache=True, nogil=True, inline="always")(_propagate_link_py)
else:  # pragma: no cover
    propagate_link = _propagate_link_py


def _inertial_columns(Rp, pp, sigma, gravity, q, qd, qdd, out, whole_rows):
    """Fill the 10 inertial columns of every link, for every sample, into `out`.

    out: (N, n, Ns) with link j's columns at 14*j ... 14*j+9. With `whole_rows`
    False the other columns are untouched; with True every column of a sample is
    written here (zeros, and Ia, Fv, Fc, Off on the diagonal as in
    `regressor._actuator_columns`), while that sample's rows are still in cache:
    a separate zeroing pass and a separate actuator pass over W cost two more
    trips through memory than the kernel itself.
    """
    N, n = q.shape
    width = out.shape[2]
    R = np.empty((n, 3, 3))       # frame j in frame j-1
    P = np.empty((n, 3))          # origin j in frame j-1
    Rw = np.empty((n, 3, 3))      # frame j in base
    Ow = np.empty((n, 3))         # origin j in base
    # the entries of a link's wrench columns that are always zero (f of the inertia-tensor
    # columns, m[0, 6], m[1, 7], m[2, 8], m of the mass column) are zeroed once, here, not
    # per link and sample; the loop overwrites every other entry
    f = np.zeros((3, 10))
    m = np.zeros((3, 10))
    for s in range(N):
        if whole_rows:
            _whole_row_start(out, s, n, width, qd, qdd)
        # --- kinematics
        joint_transforms(Rp, pp, sigma, q[s], R, P)
        for j in range(n):
            if j == 0:
                for a in range(3):
                    Ow[0, a] = P[0, a]
                    for b in range(3):
                        Rw[0, a, b] = R[0, a, b]
            else:
                for a in range(3):
                    acc = Ow[j - 1, a]
                    for b in range(3):
                        acc += Rw[j - 1, a, b] * P[j, b]
                    Ow[j, a] = acc
                    for b in range(3):
                        acc2 = 0.0
                        for k in range(3):
                            acc2 += Rw[j - 1, a, k] * R[j, k, b]
                        Rw[j, a, b] = acc2
        # --- Newton-Euler forward recursion, in link frames
        wx = 0.0; wy = 0.0; wz = 0.0
        ax = 0.0; ay = 0.0; az = 0.0           # angular acceleration
        vx = -gravity[0]; vy = -gravity[1]; vz = -gravity[2]
        for j in range(n):
            wx, wy, wz, ax, ay, az, vx, vy, vz = propagate_link(
                R, P, j, sigma[j], qd[s, j], qdd[s, j], wx, wy, wz, ax, ay, az, vx, vy, vz)
            # --- wrench columns of link j (about its origin, frame j)
            # XX: D w = (wx,0,0)
            m[0, 0] = ax;  m[1, 0] = wz * wx;  m[2, 0] = -wy * wx
            # XY: D w = (wy, wx, 0)
            m[0, 1] = ay - wz * wx
            m[1, 1] = ax + wz * wy
            m[2, 1] = wx * wx - wy * wy
            # XZ: D w = (wz, 0, wx)
            m[0, 2] = az + wy * wx
            m[1, 2] = wz * wz - wx * wx
            m[2, 2] = ax - wy * wz
            # YY: D w = (0, wy, 0)
            m[0, 3] = -wz * wy;  m[1, 3] = ay;  m[2, 3] = wx * wy
            # YZ: D w = (0, wz, wy)
            m[0, 4] = wy * wy - wz * wz
            m[1, 4] = az - wx * wy
            m[2, 4] = ay + wx * wz
            # ZZ: D w = (0, 0, wz)
            m[0, 5] = wy * wz;  m[1, 5] = -wx * wz;  m[2, 5] = az
            # MX, MY, MZ: f = dw x e + w x (w x e), n = e x dv
            f[0, 6] = -(wy * wy + wz * wz); f[1, 6] = az + wx * wy;  f[2, 6] = -ay + wx * wz
            f[0, 7] = -az + wx * wy;  f[1, 7] = -(wx * wx + wz * wz); f[2, 7] = ax + wy * wz
            f[0, 8] = ay + wx * wz;  f[1, 8] = -ax + wy * wz;  f[2, 8] = -(wx * wx + wy * wy)
            m[1, 6] = -vz; m[2, 6] = vy
            m[0, 7] = vz;  m[2, 7] = -vx
            m[0, 8] = -vy; m[1, 8] = vx
            f[0, 9] = vx; f[1, 9] = vy; f[2, 9] = vz
            # --- project on the axes of joints i <= j
            c0 = 14 * j
            for i in range(j + 1):
                zx = Rw[i, 0, 2]; zy = Rw[i, 1, 2]; zz = Rw[i, 2, 2]
                ux = Rw[j, 0, 0] * zx + Rw[j, 1, 0] * zy + Rw[j, 2, 0] * zz
                uy = Rw[j, 0, 1] * zx + Rw[j, 1, 1] * zy + Rw[j, 2, 1] * zz
                uz = Rw[j, 0, 2] * zx + Rw[j, 1, 2] * zy + Rw[j, 2, 2] * zz
                if sigma[i] == 0:
                    rx = Ow[j, 0] - Ow[i, 0]
                    ry = Ow[j, 1] - Ow[i, 1]
                    rz = Ow[j, 2] - Ow[i, 2]
                    bx = zy * rz - zz * ry
                    by = zz * rx - zx * rz
                    bz = zx * ry - zy * rx
                    gx = Rw[j, 0, 0] * bx + Rw[j, 1, 0] * by + Rw[j, 2, 0] * bz
                    gy = Rw[j, 0, 1] * bx + Rw[j, 1, 1] * by + Rw[j, 2, 1] * bz
                    gz = Rw[j, 0, 2] * bx + Rw[j, 1, 2] * by + Rw[j, 2, 2] * bz
                    for k in range(6):
                        out[s, i, c0 + k] = ux * m[0, k] + uy * m[1, k] + uz * m[2, k]
                    for k in range(6, 9):
                        out[s, i, c0 + k] = (ux * m[0, k] + uy * m[1, k] + uz * m[2, k]
                                             + gx * f[0, k] + gy * f[1, k] + gz * f[2, k])
                    out[s, i, c0 + 9] = gx * f[0, 9] + gy * f[1, 9] + gz * f[2, 9]
                else:
                    for k in range(6):
                        out[s, i, c0 + k] = 0.0
                    for k in range(6, 10):
                        out[s, i, c0 + k] = ux * f[0, k] + uy * f[1, k] + uz * f[2, k]


if HAVE_NUMBA:
    inertial_columns = numba.njit(cache=True, nogil=True)(_inertial_columns)
else:  # pragma: no cover
    inertial_columns = None
