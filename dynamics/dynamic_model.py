"""Per-sample rigid-body dynamics from a standard-parameter vector, compiled with numba.

The inverse dynamic model of eq. (1) of Gautier, Janot, Vandanjon 2010,
`tau = M(q) qdd + N(q, qd)`, and the direct dynamic model of eq. (17),
`qdd = M(q)^-1 (tau - N(q, qd))`, evaluated from the standard parameters
`chi_st` (`robot.standard_names`) rather than through the regressor, so the
closed-loop simulator (`dynid.dynamics.simulation`) can call them millions of
times without Python in the loop.

Algorithms
----------
* **RNEA** (recursive Newton-Euler, Khalil & Dombre 2002, §9.5): forward
  recursion of `w, dw, dv` in the link frames, link wrench about the link
  origin from the ten inertial parameters `XX XY XZ YY YZ ZZ MX MY MZ M`
  (`F = M dv + dw x MS + w x (w x MS)`, `N = I dw + w x (I w) + MS x dv`),
  backward recursion of the wrenches, projection on the joint axes.
* **Mass matrix**: `n` RNEA passes with `qd = 0`, `g = 0` and
  `qdd = e_k` (column `k`), sharing the link transforms computed once per
  configuration; the pass for column `k` starts its forward recursion at link
  `k` (the links before it are at rest). This is the "numerical" route of
  section 4 of the paper ("M and N are numerically calculated using the IDM for
  special values of q, qd, qdd"). Exactly symmetric (the upper triangle is
  mirrored). `simulate_closed_loop(crba=True)` (DIDIM's simulations) uses the composite rigid body algorithm instead
  (`_mass_crba`; CRBA, Featherstone 2008, §6.2, in Khalil's ten-parameter form:
  the composite inertia of links `j..n-1` about origin `j`, moved down the chain
  by `R J R^T` and the parallel-axis terms; the wrench a unit acceleration of
  joint `k` needs, `z x MS^c` and `J^c z` (prismatic `M^c z`, `MS^c x z`),
  carried to the base by the RNEA's backward recursion). Equal to rounding, at
  40 % of the cost (the direct dynamics of a 6-dof arm, the simulator's inner
  step: 1.7 against 1.1 us when measured); the default keeps the paper's route
  so that simulated data stay bit for bit those of earlier versions.
* **Actuator terms**: the armature matrix `A` (`diag(Ia)` plus the coupling
  off-diagonals `A[k, l] += c_k c_l / c_m^2 Ia_motor`, `k != l`, eq. (33)),
  viscous `Fv qd`, Coulomb `Fc s(qd)`, offset `Off`, and the coupling
  friction `tau_k += c_k (Fvm w + Fcm s(w))`, `w = sum_k c_k qd_k`.
* **Direct dynamics**: Cholesky factorisation of `M + A` (it must be positive
  definite; an error tells the caller when the parameters make it indefinite).

Coulomb friction and the smooth sign
------------------------------------
`s(x) = tanh(x / v_s)` when `v_s > 0`, the exact `sign(x)` (with
`sign(0) = 0`) when `v_s = 0`. The inverse-dynamics wrappers default to
`v_s = 0` (they then equal the regressor route `W(q, qd, qdd) chi_st`, kept as the
test oracle `dynid.dynamics.regressor._inverse_dynamics_via_regressor`); the
simulator defaults to `v_s = DEFAULT_V_S = 0.01` rad/s (m/s for a prismatic
joint), so an explicit integrator is not facing a discontinuous right-hand
side. Near `qd = 0` the smooth sign adds the viscous slope `Fc / v_s`;
see `dynid.dynamics.simulation` for what that means for the step size.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from dynid.errors import InputError
from dynid.numba_cache import install as _cache_outside_the_package

from ._kernels import joint_transforms as _transforms
from ._kernels import propagate_link
from .robot import PER_JOINT

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

N_PER_JOINT = len(PER_JOINT)          # 14
DEFAULT_V_S = 0.01                    # rad/s, smooth-sign width of the simulator

# status codes of the compiled kernels
OK = 0
NOT_POSITIVE_DEFINITE = 1
NOT_FINITE = 2


class ModelArrays(NamedTuple):
    """Everything the compiled kernels need, as contiguous float64/int64 arrays.

    Rp (n,3,3), pp (n,3): joint placements; sigma (n,): 0 revolute, 1 prismatic;
    gravity (3,); inertial (n,10): XX XY XZ YY YZ ZZ MX MY MZ M of each link
    (about its joint frame origin, in its frame); A (n,n): armature matrix
    (diag(Ia) + coupling off-diagonals); Ia, Fv, Fc, Off (n,); C (nc,n): the
    coupling coefficient rows (rotor velocity `w = C qd`); Fvm, Fcm (nc,):
    coupling friction (0 for a coupling declared without friction).
    """

    Rp: np.ndarray
    pp: np.ndarray
    sigma: np.ndarray
    gravity: np.ndarray
    inertial: np.ndarray
    A: np.ndarray
    Ia: np.ndarray
    Fv: np.ndarray
    Fc: np.ndarray
    Off: np.ndarray
    C: np.ndarray
    Fvm: np.ndarray
    Fcm: np.ndarray

    @property
    def n(self) -> int:
        return self.sigma.shape[0]

    def kernel_args(self):
        """The tuple the kernels unpack (Ia is folded into A)."""
        return (self.Rp, self.pp, self.sigma, self.gravity, self.inertial, self.A,
                self.Fv, self.Fc, self.Off, self.C, self.Fvm, self.Fcm)


def check_parameters(robot, chi_st) -> np.ndarray:
    """chi_st as a finite float vector of length `robot.n_standard`, else InputError."""
    try:
        chi = np.asarray(chi_st, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"chi_st must be a vector of {robot.n_standard} numbers "
                         f"(robot.standard_names of '{robot.name}')") from None
    if chi.ndim != 1 or chi.size != robot.n_standard:
        raise InputError(f"chi_st has shape {chi.shape}; robot '{robot.name}' has "
                         f"{robot.n_standard} standard parameters ({robot.standard_names[0]} … "
                         f"{robot.standard_names[-1]}), give a vector of that length")
    if not np.all(np.isfinite(chi)):
        bad = [robot.standard_names[k] for k in np.flatnonzero(~np.isfinite(chi))]
        raise InputError(f"chi_st holds non-finite value(s) for {', '.join(bad[:8])}")
    return chi


def model_arrays(robot, chi_st) -> ModelArrays:
    """Pack the robot's placements and the parameters `chi_st` for the kernels."""
    chi = check_parameters(robot, chi_st)
    n = robot.n_joints
    Rp = np.ascontiguousarray([j.R for j in robot.joints], dtype=float).reshape(n, 3, 3)
    pp = np.ascontiguousarray([j.p for j in robot.joints], dtype=float).reshape(n, 3)
    sigma = np.ascontiguousarray(robot.sigma, dtype=np.int64)
    gravity = np.ascontiguousarray(robot.gravity, dtype=float).reshape(3)
    blocks = chi[:N_PER_JOINT * n].reshape(n, N_PER_JOINT)
    inertial = np.ascontiguousarray(blocks[:, :10])
    Ia = blocks[:, 10].copy()
    Fv = blocks[:, 11].copy()
    Fc = blocks[:, 12].copy()
    Off = blocks[:, 13].copy()
    A = np.diag(Ia)
    nc = len(robot.couplings)
    C = np.zeros((nc, n))
    Fvm = np.zeros(nc)
    Fcm = np.zeros(nc)
    col = N_PER_JOINT * n
    for r, c in enumerate(robot.couplings):
        idx = [j - 1 for j in c.joints]
        coef = np.asarray(c.coefficients, dtype=float)
        cm = coef[list(c.joints).index(c.motor)] if c.motor in c.joints else 1.0
        ia_m = Ia[c.motor - 1]
        for a, ka in zip(idx, coef):
            for b, kb in zip(idx, coef):
                if a != b:
                    A[a, b] += ka * kb / cm ** 2 * ia_m
        C[r, idx] = coef
        if c.friction:
            Fvm[r] = chi[col]
            Fcm[r] = chi[col + 1]
            col += 2
    return ModelArrays(Rp, pp, sigma, gravity, inertial, np.ascontiguousarray(A), Ia, Fv, Fc,
                       Off, C, Fvm, Fcm)


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, nogil=True)
def _workspace(n):
    """Scratch arrays of one dynamics evaluation: R, P, W, DW, DV, F, NM, M, h, col."""
    return (np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, n)),
            np.empty(n), np.empty(n))


@njit(cache=True, nogil=True)
def _rnea_pass(R, P, sigma, inertial, gx, gy, gz, qd, qdd, unit, W, DW, DV, F, NM, tau):
    """Rigid-body RNEA torques into `tau` for the transforms R, P.

    `unit < 0`: velocities `qd`, accelerations `qdd`, gravity `g`.
    `unit = k >= 0`: `qd = 0`, `qdd = e_k` (`qd`, `qdd` are not read), and
    the caller passes `g = 0`; the forward recursion starts at link `k`.
    """
    n = R.shape[0]
    start = 0 if unit < 0 else unit
    # state of the parent of link `start`, in its frame
    wx = 0.0; wy = 0.0; wz = 0.0
    ax = 0.0; ay = 0.0; az = 0.0
    vx = -gx; vy = -gy; vz = -gz
    for j in range(start):
        F[j, 0] = 0.0; F[j, 1] = 0.0; F[j, 2] = 0.0
        NM[j, 0] = 0.0; NM[j, 1] = 0.0; NM[j, 2] = 0.0
    for j in range(start, n):
        if unit < 0:
            qdj = qd[j]
            qddj = qdd[j]
        else:
            qdj = 0.0
            qddj = 1.0 if j == unit else 0.0
        wx, wy, wz, ax, ay, az, vx, vy, vz = propagate_link(
            R, P, j, sigma[j], qdj, qddj, wx, wy, wz, ax, ay, az, vx, vy, vz)
        # link wrench about origin j, frame j
        XX = inertial[j, 0]; XY = inertial[j, 1]; XZ = inertial[j, 2]
        YY = inertial[j, 3]; YZ = inertial[j, 4]; ZZ = inertial[j, 5]
        mx = inertial[j, 6]; my = inertial[j, 7]; mz = inertial[j, 8]; m = inertial[j, 9]
        # w x MS
        sx = wy * mz - wz * my
        sy = wz * mx - wx * mz
        sz = wx * my - wy * mx
        F[j, 0] = m * vx + (ay * mz - az * my) + (wy * sz - wz * sy)
        F[j, 1] = m * vy + (az * mx - ax * mz) + (wz * sx - wx * sz)
        F[j, 2] = m * vz + (ax * my - ay * mx) + (wx * sy - wy * sx)
        Iwx = XX * wx + XY * wy + XZ * wz
        Iwy = XY * wx + YY * wy + YZ * wz
        Iwz = XZ * wx + YZ * wy + ZZ * wz
        NM[j, 0] = (XX * ax + XY * ay + XZ * az) + (wy * Iwz - wz * Iwy) + (my * vz - mz * vy)
        NM[j, 1] = (XY * ax + YY * ay + YZ * az) + (wz * Iwx - wx * Iwz) + (mz * vx - mx * vz)
        NM[j, 2] = (XZ * ax + YZ * ay + ZZ * az) + (wx * Iwy - wy * Iwx) + (mx * vy - my * vx)
    # backward recursion: f_j = F_j + R_{j+1} f_{j+1}, n_j = N_j + R_{j+1} n_{j+1} + P_{j+1} x (R_{j+1} f_{j+1})
    fx = 0.0; fy = 0.0; fz = 0.0
    mmx = 0.0; mmy = 0.0; mmz = 0.0
    for j in range(n - 1, -1, -1):
        if j < n - 1:
            k = j + 1
            rfx = R[k, 0, 0] * fx + R[k, 0, 1] * fy + R[k, 0, 2] * fz
            rfy = R[k, 1, 0] * fx + R[k, 1, 1] * fy + R[k, 1, 2] * fz
            rfz = R[k, 2, 0] * fx + R[k, 2, 1] * fy + R[k, 2, 2] * fz
            rnx = R[k, 0, 0] * mmx + R[k, 0, 1] * mmy + R[k, 0, 2] * mmz
            rny = R[k, 1, 0] * mmx + R[k, 1, 1] * mmy + R[k, 1, 2] * mmz
            rnz = R[k, 2, 0] * mmx + R[k, 2, 1] * mmy + R[k, 2, 2] * mmz
            px = P[k, 0]; py = P[k, 1]; pz = P[k, 2]
            fx = F[j, 0] + rfx
            fy = F[j, 1] + rfy
            fz = F[j, 2] + rfz
            mmx = NM[j, 0] + rnx + (py * rfz - pz * rfy)
            mmy = NM[j, 1] + rny + (pz * rfx - px * rfz)
            mmz = NM[j, 2] + rnz + (px * rfy - py * rfx)
        else:
            fx = F[j, 0]; fy = F[j, 1]; fz = F[j, 2]
            mmx = NM[j, 0]; mmy = NM[j, 1]; mmz = NM[j, 2]
        tau[j] = mmz if sigma[j] == 0 else fz


@njit(cache=True, nogil=True)
def _ssign(x, v_s):
    """Smooth sign `tanh(x / v_s)`; the exact sign when `v_s <= 0`."""
    if v_s > 0.0:
        return np.tanh(x / v_s)
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, nogil=True)
def _mass(model, ws, q, with_transforms):
    """M(q) + A into ws[7] (transforms recomputed when `with_transforms`)."""
    Rp, pp, sigma, g, inertial, A, Fv, Fc, Off, C, Fvm, Fcm = model
    R, P, W, DW, DV, F, NM, M, h, col = ws
    n = q.shape[0]
    if with_transforms:
        _transforms(Rp, pp, sigma, q, R, P)
    for k in range(n):
        _rnea_pass(R, P, sigma, inertial, 0.0, 0.0, 0.0, q, q, k, W, DW, DV, F, NM, col)
        for i in range(k + 1):
            M[i, k] = col[i] + A[i, k]
            M[k, i] = M[i, k]


@njit(cache=True, nogil=True)
def _mass_crba(model, ws, q, with_transforms):
    """`_mass` by the CRBA (transforms recomputed when `with_transforms`).

    Overwrites the RNEA scratch W, DV, F, NM (the composite inertias), so `_qdd` calls
    it after `_bias`.
    """
    Rp, pp, sigma, g, inertial, A, Fv, Fc, Off, C, Fvm, Fcm = model
    R, P, W, DW, DV, F, NM, M, h, col = ws
    n = q.shape[0]
    if with_transforms:
        _transforms(Rp, pp, sigma, q, R, P)
    # composite inertia of links j..n-1 about origin j, in frame j, in the RNEA's scratch:
    # F[j] = (XX, XY, XZ), NM[j] = (YY, YZ, ZZ), DV[j] = MS, W[j, 0] = M
    for j in range(n - 1, -1, -1):
        XX = inertial[j, 0]; XY = inertial[j, 1]; XZ = inertial[j, 2]
        YY = inertial[j, 3]; YZ = inertial[j, 4]; ZZ = inertial[j, 5]
        sx = inertial[j, 6]; sy = inertial[j, 7]; sz = inertial[j, 8]; m = inertial[j, 9]
        if j < n - 1:
            k = j + 1
            a00 = F[k, 0]; a01 = F[k, 1]; a02 = F[k, 2]
            a11 = NM[k, 0]; a12 = NM[k, 1]; a22 = NM[k, 2]
            cs0 = DV[k, 0]; cs1 = DV[k, 1]; cs2 = DV[k, 2]
            mc = W[k, 0]
            r00 = R[k, 0, 0]; r01 = R[k, 0, 1]; r02 = R[k, 0, 2]
            r10 = R[k, 1, 0]; r11 = R[k, 1, 1]; r12 = R[k, 1, 2]
            r20 = R[k, 2, 0]; r21 = R[k, 2, 1]; r22 = R[k, 2, 2]
            # J' = R J^c_k R^T, the child's composite inertia in frame j (upper triangle)
            b00 = r00 * a00 + r01 * a01 + r02 * a02
            b01 = r00 * a01 + r01 * a11 + r02 * a12
            b02 = r00 * a02 + r01 * a12 + r02 * a22
            b10 = r10 * a00 + r11 * a01 + r12 * a02
            b11 = r10 * a01 + r11 * a11 + r12 * a12
            b12 = r10 * a02 + r11 * a12 + r12 * a22
            b20 = r20 * a00 + r21 * a01 + r22 * a02
            b21 = r20 * a01 + r21 * a11 + r22 * a12
            b22 = r20 * a02 + r21 * a12 + r22 * a22
            j00 = b00 * r00 + b01 * r01 + b02 * r02
            j01 = b00 * r10 + b01 * r11 + b02 * r12
            j02 = b00 * r20 + b01 * r21 + b02 * r22
            j11 = b10 * r10 + b11 * r11 + b12 * r12
            j12 = b10 * r20 + b11 * r21 + b12 * r22
            j22 = b20 * r20 + b21 * r21 + b22 * r22
            # its first moment about O_k, in frame j
            t0 = r00 * cs0 + r01 * cs1 + r02 * cs2
            t1 = r10 * cs0 + r11 * cs1 + r12 * cs2
            t2 = r20 * cs0 + r21 * cs1 + r22 * cs2
            px = P[k, 0]; py = P[k, 1]; pz = P[k, 2]
            # moved to O_j = O_k - p: + mc (|p|^2 I - p p^T) + 2 (p.t) I - p t^T - t p^T
            pp2 = px * px + py * py + pz * pz
            pt2 = 2.0 * (px * t0 + py * t1 + pz * t2)
            XX += j00 + mc * (pp2 - px * px) + pt2 - 2.0 * px * t0
            YY += j11 + mc * (pp2 - py * py) + pt2 - 2.0 * py * t1
            ZZ += j22 + mc * (pp2 - pz * pz) + pt2 - 2.0 * pz * t2
            XY += j01 - mc * px * py - px * t1 - t0 * py
            XZ += j02 - mc * px * pz - px * t2 - t0 * pz
            YZ += j12 - mc * py * pz - py * t2 - t1 * pz
            sx += t0 + mc * px
            sy += t1 + mc * py
            sz += t2 + mc * pz
            m += mc
        F[j, 0] = XX; F[j, 1] = XY; F[j, 2] = XZ
        NM[j, 0] = YY; NM[j, 1] = YZ; NM[j, 2] = ZZ
        DV[j, 0] = sx; DV[j, 1] = sy; DV[j, 2] = sz
        W[j, 0] = m
    # column k: the wrench on composite body k of a unit acceleration of joint k, carried down
    for k in range(n):
        if sigma[k] == 0:
            fx = -DV[k, 1]; fy = DV[k, 0]; fz = 0.0
            nx = F[k, 2]; ny = NM[k, 1]; nz = NM[k, 2]
            M[k, k] = nz + A[k, k]
        else:
            fx = 0.0; fy = 0.0; fz = W[k, 0]
            nx = DV[k, 1]; ny = -DV[k, 0]; nz = 0.0
            M[k, k] = fz + A[k, k]
        for j in range(k - 1, -1, -1):
            i = j + 1
            rfx = R[i, 0, 0] * fx + R[i, 0, 1] * fy + R[i, 0, 2] * fz
            rfy = R[i, 1, 0] * fx + R[i, 1, 1] * fy + R[i, 1, 2] * fz
            rfz = R[i, 2, 0] * fx + R[i, 2, 1] * fy + R[i, 2, 2] * fz
            rnx = R[i, 0, 0] * nx + R[i, 0, 1] * ny + R[i, 0, 2] * nz
            rny = R[i, 1, 0] * nx + R[i, 1, 1] * ny + R[i, 1, 2] * nz
            rnz = R[i, 2, 0] * nx + R[i, 2, 1] * ny + R[i, 2, 2] * nz
            px = P[i, 0]; py = P[i, 1]; pz = P[i, 2]
            fx = rfx; fy = rfy; fz = rfz
            nx = rnx + (py * rfz - pz * rfy)
            ny = rny + (pz * rfx - px * rfz)
            nz = rnz + (px * rfy - py * rfx)
            v = nz if sigma[j] == 0 else fz
            M[j, k] = v + A[j, k]
            M[k, j] = M[j, k]


@njit(cache=True, nogil=True)
def _add_friction(model, qd, v_s, out):
    """out += Fv qd + Fc s(qd) + Off + sum over couplings of c (Fvm w + Fcm s(w))."""
    Rp, pp, sigma, g, inertial, A, Fv, Fc, Off, C, Fvm, Fcm = model
    n = qd.shape[0]
    for j in range(n):
        out[j] += Fv[j] * qd[j] + Fc[j] * _ssign(qd[j], v_s) + Off[j]
    for r in range(C.shape[0]):
        w = 0.0
        for j in range(n):
            w += C[r, j] * qd[j]
        fr = Fvm[r] * w + Fcm[r] * _ssign(w, v_s)
        for j in range(n):
            out[j] += C[r, j] * fr


@njit(cache=True, nogil=True)
def _bias(model, ws, q, qd, v_s, with_transforms, out):
    """N(q, qd): Coriolis, centrifugal, gravity, friction (smooth sign) and offsets."""
    Rp, pp, sigma, g, inertial, A, Fv, Fc, Off, C, Fvm, Fcm = model
    R, P, W, DW, DV, F, NM, M, h, col = ws
    n = q.shape[0]
    if with_transforms:
        _transforms(Rp, pp, sigma, q, R, P)
    for j in range(n):
        col[j] = 0.0                                   # qdd = 0
    _rnea_pass(R, P, sigma, inertial, g[0], g[1], g[2], qd, col, -1, W, DW, DV, F, NM, out)
    _add_friction(model, qd, v_s, out)


@njit(cache=True, nogil=True)
def _qdd(model, ws, q, qd, tau, v_s, out, crba=False):
    """Direct dynamics, eq. (17): solve (M + A) qdd = tau - N by Cholesky. Returns a status.
    `crba`: M by `_mass_crba` instead of the RNEA columns (equal to rounding)."""
    R, P, W, DW, DV, F, NM, M, h, col = ws
    n = q.shape[0]
    _transforms(model[0], model[1], model[2], q, R, P)
    _bias(model, ws, q, qd, v_s, False, h)
    if crba:
        _mass_crba(model, ws, q, False)
    else:
        _mass(model, ws, q, False)
    # Cholesky M = L L^T in place (lower triangle)
    for j in range(n):
        d = M[j, j]
        for k in range(j):
            d -= M[j, k] * M[j, k]
        if not d > 0.0:
            return NOT_POSITIVE_DEFINITE
        d = np.sqrt(d)
        M[j, j] = d
        for i in range(j + 1, n):
            s = M[i, j]
            for k in range(j):
                s -= M[i, k] * M[j, k]
            M[i, j] = s / d
    for i in range(n):
        s = tau[i] - h[i]
        for k in range(i):
            s -= M[i, k] * out[k]
        out[i] = s / M[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= M[k, i] * out[k]
        out[i] = s / M[i, i]
    return OK


@njit(cache=True, nogil=True)
def _inverse_dynamics_batch(model, Q, QD, QDD, v_s, out):
    N, n = Q.shape
    R, P, W, DW, DV, F, NM, M, h, col = _workspace(n)
    Rp, pp, sigma, g, inertial, A, Fv, Fc, Off, C, Fvm, Fcm = model
    for s in range(N):
        _transforms(Rp, pp, sigma, Q[s], R, P)
        _rnea_pass(R, P, sigma, inertial, g[0], g[1], g[2], QD[s], QDD[s], -1,
                   W, DW, DV, F, NM, out[s])
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += A[j, k] * QDD[s, k]
            out[s, j] += acc
        _add_friction(model, QD[s], v_s, out[s])


@njit(cache=True, nogil=True)
def _mass_batch(model, Q, out):
    N, n = Q.shape
    ws = _workspace(n)
    M = ws[7]
    for s in range(N):
        _mass(model, ws, Q[s], True)
        for i in range(n):
            for k in range(n):
                out[s, i, k] = M[i, k]


@njit(cache=True, nogil=True)
def _bias_batch(model, Q, QD, v_s, out):
    N, n = Q.shape
    ws = _workspace(n)
    for s in range(N):
        _bias(model, ws, Q[s], QD[s], v_s, True, out[s])


@njit(cache=True, nogil=True)
def _forward_dynamics_batch(model, Q, QD, TAU, v_s, out):
    N, n = Q.shape
    ws = _workspace(n)
    for s in range(N):
        st = _qdd(model, ws, Q[s], QD[s], TAU[s], v_s, out[s])
        if st != OK:
            return st, s
    return OK, -1


# ----------------------------------------------------------------------------- wrappers

def _samples(robot, **arrays):
    """Validate (n,) or (N, n) arrays of equal shape; return 2-D copies and whether 1-D."""
    n = robot.n_joints
    out = []
    single = None
    shape = None
    for name, a in arrays.items():
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be an array of numbers with {n} columns "
                             f"(one per joint of '{robot.name}')") from None
        if a.ndim == 1:
            a = a[None, :]
            s1 = True
        elif a.ndim == 2:
            s1 = False
        else:
            raise InputError(f"{name} has shape {a.shape}; give (n,) for one sample or (N, n) "
                             f"with n = {n} joints of '{robot.name}'")
        if a.shape[1] != n:
            raise InputError(f"{name} has {a.shape[1]} columns but robot '{robot.name}' has "
                             f"{n} joints; give one column per joint")
        if shape is not None and a.shape != shape:
            raise InputError(f"{name} has shape {a.shape} but {list(arrays)[0]} has {shape}; "
                             "give the same number of samples for every signal")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name} holds non-finite values (NaN or inf)")
        shape = a.shape
        single = s1 if single is None else (single and s1)
        out.append(np.ascontiguousarray(a))
    return out, bool(single)


def _v_s(v_s):
    v = float(v_s)
    if not np.isfinite(v) or v < 0:
        raise InputError(f"v_s (the smooth-sign velocity of Coulomb friction) must be >= 0, got {v_s!r}")
    return v


def inverse_dynamics(robot, chi_st, q, qd, qdd, *, v_s=0.0):
    """tau = (M(q) + A) qdd + N(q, qd) of eq. (1), from chi_st; (n,) or (N, n).

    With `v_s = 0` (default) Coulomb friction uses the exact sign and the result
    equals the regressor route `regressor(robot, q, qd, qdd) @ chi_st` (the test oracle
    `dynid.dynamics.regressor._inverse_dynamics_via_regressor`). dynid's one
    implementation of the inverse dynamics, also importable from
    `dynid.dynamics.regressor`.
    """
    ma = model_arrays(robot, chi_st)
    (q, qd, qdd), single = _samples(robot, q=q, qd=qd, qdd=qdd)
    out = np.empty_like(q)
    _inverse_dynamics_batch(ma.kernel_args(), q, qd, qdd, _v_s(v_s), out)
    return out[0] if single else out


def mass_matrix(robot, chi_st, q):
    """M(q) including the actuator inertias (diag Ia and coupling terms); (n,n) or (N,n,n)."""
    ma = model_arrays(robot, chi_st)
    (q,), single = _samples(robot, q=q)
    out = np.empty((q.shape[0], ma.n, ma.n))
    _mass_batch(ma.kernel_args(), q, out)
    return out[0] if single else out


def bias_torque(robot, chi_st, q, qd, *, v_s=0.0):
    """N(q, qd) of eq. (1): Coriolis, centrifugal, gravity, friction, offsets."""
    ma = model_arrays(robot, chi_st)
    (q, qd), single = _samples(robot, q=q, qd=qd)
    out = np.empty_like(q)
    _bias_batch(ma.kernel_args(), q, qd, _v_s(v_s), out)
    return out[0] if single else out


def forward_dynamics(robot, chi_st, q, qd, tau, *, v_s=0.0):
    """qdd = M(q)^-1 (tau - N(q, qd)), eq. (17); (n,) or (N, n).

    Raises InputError when M(q) (with the actuator inertias) is not positive
    definite at a sample: the parameters are not physically consistent there.
    """
    ma = model_arrays(robot, chi_st)
    (q, qd, tau), single = _samples(robot, q=q, qd=qd, tau=tau)
    out = np.empty_like(q)
    status, s = _forward_dynamics_batch(ma.kernel_args(), q, qd, tau, _v_s(v_s), out)
    if status != OK:
        raise InputError(f"the mass matrix M(q) of these parameters is not positive definite at "
                         f"sample {s} (q = {np.array2string(q[s], precision=4)}); chi_st is not "
                         "physically consistent (check masses, inertias and Ia)")
    return out[0] if single else out
