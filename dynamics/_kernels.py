"""Compiled inner loops (numba) for the regressor.

The same Newton-Euler-in-the-parameters algorithm as the NumPy code in
`regressor.py`, written with scalars so nothing is allocated in the loop. It is
the default backend; `backend="numpy"` keeps the vectorised NumPy path (tests
check both against Pinocchio).

The kernel works on blocks of `LANES` samples held side by side, the sample index
last in every scratch array, so that each step is a short loop over the block's
samples that the compiler turns into SIMD instructions. Each lane carries out the
scalar operations of one sample, in the order of a per-sample loop, and without
`fastmath` the compiler neither reorders nor fuses them: the values are those of a
per-sample loop, bit for bit. Only the sign of a NaN result is not fixed: when both
operands of an addition are NaN, the x86 instruction returns the first, and which one
comes first is the compiler's choice, scalar or vector.
"""
from __future__ import annotations

import platform

import numpy as np

try:
    import numba
    from llvmlite import ir as _ir
    from numba.core import types as _types
    from numba.extending import intrinsic as _intrinsic

    _X86 = platform.machine().lower() in ("x86_64", "amd64", "i386", "i686", "x86")
    from dynid.numba_cache import install as _cache_outside_the_package
    _cache_outside_the_package()   # before the first njit(cache=True): dynid.numba_cache
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is a declared dependency
    HAVE_NUMBA = False


def _sign_py(d):
    """np.sign of one float: 0 at 0 (either sign), nan at nan."""
    return 1.0 if d > 0.0 else (-1.0 if d < 0.0 else (0.0 if d == 0.0 else d))


if HAVE_NUMBA:
    _sign = numba.njit(cache=True, nogil=True, inline="always")(_sign_py)
else:  # pragma: no cover
    _sign = _sign_py


def _joint_transforms_py(Rp, pp, sigma, q, R, P):
    """Frame j in frame j-1 for joint positions q (n,): `R[j] = Rp[j] Rot(z, q_j)` for a
    revolute joint, `P[j] = pp[j] + q_j Rp[j] z` for a prismatic one. Used by the dynamics
    of dynamic_model; `_regressor_rows` computes the same products, sample by sample in
    its SIMD lanes."""
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


#: Samples per block. The vectorised loops run over the block's samples, 4 doubles to a
#: register, so 8 gives each of them two full iterations; more samples made the block's
#: scratch (n x Ns x LANES doubles for its rows alone: 33 kB for a 6-joint arm) outgrow
#: the level-1 cache, and the kernel slower.
LANES = 8

#: Outputs from this size (bytes) on are written with non-temporal (streaming) stores.
#: A normal store first reads the cache line it writes from memory, which doubles the
#: memory traffic of writing W, and so large an array does not stay in the caches for
#: its reader anyway. Smaller outputs are written normally: they are still in the cache
#: when the caller reads them.
STREAM_BYTES = 4 << 20


def _vector_store(nontemporal):
    """An intrinsic `store(flat, index, v0, v1, v2, v3)` that writes v0..v3 to
    flat[index:index + 4] as one vector store, non-temporal or not; &flat[index] must be
    32-byte aligned."""
    @_intrinsic
    def store(typingctx, flat, index, v0, v1, v2, v3):
        def codegen(context, builder, signature, args):
            ary = context.make_array(signature.args[0])(context, builder, args[0])
            vty = _ir.VectorType(_ir.DoubleType(), 4)
            vec = _ir.Constant(vty, _ir.Undefined)
            for k, v in enumerate(args[2:]):
                vec = builder.insert_element(vec, v, _ir.Constant(_ir.IntType(32), k))
            ptr = builder.bitcast(builder.gep(ary.data, [args[1]]), vty.as_pointer())
            inst = builder.store(vec, ptr, align=32)
            if nontemporal:
                inst.set_metadata("nontemporal", builder.module.add_metadata(
                    [_ir.Constant(_ir.IntType(32), 1)]))
            return context.get_dummy_value()

        return _types.void(flat, index, v0, v1, v2, v3), codegen

    return store


def _row_entry_py(T1, b, p, rowlen, x):
    """The regressor entry at flat index x: of the block's sample b (whose n x Ns entries
    start at flat index p), or of sample b - 1 when x < p. Entry k of sample b is
    T1[k * LANES + b]."""
    return T1[(x - p + rowlen) * LANES + b - 1] if x < p else T1[(x - p) * LANES + b]


def _store4_py(flat, index, v0, v1, v2, v3, stream):
    """flat[index:index + 4] = v0..v3 in one vector store (&flat[index] 32-byte aligned),
    non-temporal with `stream`."""
    if stream:
        _store4_streaming(flat, index, v0, v1, v2, v3)
    else:
        _store4_cached(flat, index, v0, v1, v2, v3)


def _copy_out_py(T1, rowlen, flat, start, nb, stream):
    """Write a block's `nb` samples into `flat` (the regressor, flattened) from `start` on,
    each sample's `rowlen` = n x Ns entries (its n rows of IDM_st) in a row of `T1`: entry k
    of sample b is T1[k * LANES + b].

    The entries go out in 32-byte aligned groups of four, one vector store each
    (non-temporal with `stream`); a group that spans two samples takes the end of one and
    the start of the next, and the entries at either end of the block that are in no
    whole group are stored one by one. The indices of the main loop are unsigned: numba
    checks every signed index for a negative value, which cost more than the copy itself.
    """
    L = LANES
    if flat.ctypes.data % 8 != 0:        # a misaligned array: entry by entry
        for b in range(nb):
            for k in range(rowlen):
                flat[start + b * rowlen + k] = T1[k * L + b]
        return
    a = flat.ctypes.data // 8
    u1 = np.uint64(L)
    u2 = np.uint64(2 * L)
    u3 = np.uint64(3 * L)
    u4 = np.uint64(4 * L)
    four = np.uint64(4)
    for b in range(nb):
        p = start + b * rowlen
        k0 = (-(a + p)) % 4            # row b's first entry that starts a group
        if k0 and b == 0:
            for k in range(k0):
                flat[p + k] = T1[k * L + b]
        elif k0:                       # the group from the end of row b - 1
            g = p + k0 - 4
            _store4(flat, g, _row_entry(T1, b, p, rowlen, g), _row_entry(T1, b, p, rowlen, g + 1),
                    _row_entry(T1, b, p, rowlen, g + 2), _row_entry(T1, b, p, rowlen, g + 3), stream)
        groups = (rowlen - k0) // 4
        src = np.uint64(k0 * L + b)
        dst = np.uint64(p + k0)
        for _ in range(groups):
            _store4(flat, dst, T1[src], T1[src + u1], T1[src + u2], T1[src + u3], stream)
            src += u4
            dst += four
        if b == nb - 1:
            for k in range(k0 + 4 * groups, rowlen):
                flat[p + k] = T1[k * L + b]


if HAVE_NUMBA:
    _store4_streaming = _vector_store(True)
    _store4_cached = _vector_store(False)
    _store4 = numba.njit(cache=True, nogil=True, inline="always")(_store4_py)
    _row_entry = numba.njit(cache=True, nogil=True, inline="always")(_row_entry_py)
    _copy_out = numba.njit(cache=True, nogil=True)(_copy_out_py)

    @_intrinsic
    def _store_fence(typingctx):
        """Order the non-temporal stores before every later store (they are weakly ordered:
        another thread told the output is ready could otherwise read stale values). On x86
        the documented barrier is SFENCE; LLVM lowers its own `fence` there to a locked
        instruction, whose effect on non-temporal stores is not documented."""
        def codegen(context, builder, signature, args):
            if _X86:
                sfence = builder.module.declare_intrinsic("llvm.x86.sse.sfence", (),
                                                          _ir.FunctionType(_ir.VoidType(), ()))
                builder.call(sfence, ())
            else:
                builder.fence("seq_cst")
            return context.get_dummy_value()

        return _types.void(), codegen


def _copy_columns_py(T1, ns, cols, out, s0, nb):
    """Write the columns `cols` of a block's `nb` samples into out[s0:s0 + nb] (.., n,
    len(cols)): entry (i, c) of sample b is T1[(i * ns + c) * LANES + b]. Plain stores: the
    selected columns are not the contiguous runs the vector stores of `_copy_out` need."""
    L = LANES
    n = out.shape[1]
    for b in range(nb):
        for i in range(n):
            row = i * ns
            for k in range(cols.shape[0]):
                out[s0 + b, i, k] = T1[(row + cols[k]) * L + b]


if HAVE_NUMBA:
    _copy_columns = numba.njit(cache=True, nogil=True)(_copy_columns_py)


def _regressor_rows(Rp, pp, sigma, gravity, q, qd, qdd, ia_terms, ia_coef, fr_terms, fr_coef,
                    wm, cols, out, stream):
    """Write every column of IDM_st, or the columns `cols`, for every sample, into `out`.

    Parameters
    ----------
    Rp, pp, sigma : ndarray
        Joint placements (n, 3, 3), (n, 3) and types (n,), as `regressor._robot_arrays`.
    gravity : ndarray (3,)
    q, qd, qdd : ndarray (N, n)
    ia_terms, ia_coef, fr_terms, fr_coef, wm : ndarray
        The coupling terms of `regressor._coupling_columns`, as tables
        (`regressor._coupling_terms`): `ia_terms[t] = (row, column, joint)` adds
        `ia_coef[t] * qdd[:, joint]`; `fr_terms[t] = (row, column, m)` adds `fr_coef[t]`
        times the coupled velocity `wm[m]` (wm: (couplings with friction, N)) to
        `column` and times its sign to `column + 1`. In table order, onto zeros or the
        diagonal Ia entry, as the NumPy code adds them.
    cols : ndarray of int
        The standard-parameter columns to write (each in 0 .. Ns - 1, unchecked), in this
        order; empty for all of them.
    out : ndarray (N, n, Ns), or (N, n, len(cols))
        Every entry is written. Link j's inertial columns are 14*j ... 14*j+9, its Ia,
        Fv, Fc, Off the next four (on row j only, as in `regressor._actuator_columns`),
        the coupling columns last.
    stream : bool
        Write `out` with non-temporal stores (see `STREAM_BYTES`); all columns only (the
        columns `cols` are copied out with plain stores).

    Notes
    -----
    A block's samples are built in the scratch `T` and copied out whole (`_copy_out`), or
    their columns `cols` (`_copy_columns`), so each entry of `out` is written once, in
    memory order. The entries that are the
    same for every sample (zero for links j < i, for a prismatic joint's inertia-tensor
    columns and for the other joints' actuator columns; one for Off) are set in `T`
    once, not per sample.
    """
    N, n = q.shape
    # every column is built whatever `cols`: the columns of one link come from its shared
    # recursion, so selecting only saves the copy of the others
    width = 14 * n + 2 * wm.shape[0] if cols.shape[0] else out.shape[2]      # Ns
    L = LANES
    cq = np.empty((n, L))
    sq = np.empty((n, L))
    qb = np.empty((n, L))
    R = np.empty((n, 3, 3, L))    # frame j in frame j-1, per lane
    P = np.empty((n, 3, L))       # origin j in frame j-1
    # the entries that do not depend on q: a revolute joint's z column and origin, a
    # prismatic joint's rotation
    for j in range(n):
        for a in range(3):
            for b in range(L):
                if sigma[j] == 0:
                    R[j, a, 2, b] = Rp[j, a, 2]
                    P[j, a, b] = pp[j, a]
                else:
                    for c in range(3):
                        R[j, a, c, b] = Rp[j, a, c]
    Rw = np.empty((n, 3, 3, L))   # frame j in base
    Ow = np.empty((n, 3, L))      # origin j in base
    qdb = np.empty((n, L))
    qddb = np.empty((n, L))
    K = np.empty((9, L))          # w, dw, dv of the current link
    # a link's wrench columns; the entries that are always zero (f of the inertia-tensor
    # columns, m[0, 6], m[1, 7], m[2, 8], m of the mass column) are never written
    M = np.zeros((3, 10, L))
    F = np.zeros((3, 10, L))
    T = np.zeros((n, width, L))
    for i in range(n):
        for b in range(L):
            T[i, 14 * i + 13, b] = 1.0
    T1 = T.reshape(-1)
    flat = out.reshape(-1)
    for s0 in range(0, N, L):
        nb = min(L, N - s0)
        # --- the block's inputs, sample index last, and its joint transforms as
        # `joint_transforms` computes them (sin and cos are library calls, one sample at a
        # time; the compiler makes one sincos call of each pair)
        for b in range(nb):
            for j in range(n):
                x = q[s0 + b, j]
                qb[j, b] = x
                if sigma[j] == 0:
                    cq[j, b] = np.cos(x)
                    sq[j, b] = np.sin(x)
                qdb[j, b] = qd[s0 + b, j]
                qddb[j, b] = qdd[s0 + b, j]
        for j in range(n):
            if sigma[j] == 0:
                for a in range(3):
                    r0 = Rp[j, a, 0]; r1 = Rp[j, a, 1]
                    for b in range(nb):
                        R[j, a, 0, b] = r0 * cq[j, b] + r1 * sq[j, b]
                        R[j, a, 1, b] = -r0 * sq[j, b] + r1 * cq[j, b]
            else:
                for a in range(3):
                    p0 = pp[j, a]; r2 = Rp[j, a, 2]
                    for b in range(nb):
                        P[j, a, b] = p0 + qb[j, b] * r2
        # --- actuator and coupling columns; the coupling terms add onto zeros, or onto
        # the diagonal Ia entries set in between
        for t in range(ia_terms.shape[0]):
            r = ia_terms[t, 0]; c = ia_terms[t, 1]
            for b in range(nb):
                T[r, c, b] = 0.0
        for t in range(fr_terms.shape[0]):
            r = fr_terms[t, 0]; c = fr_terms[t, 1]
            for b in range(nb):
                T[r, c, b] = 0.0
                T[r, c + 1, b] = 0.0
        for i in range(n):
            c = 14 * i
            for b in range(nb):
                T[i, c + 10, b] = qddb[i, b]
                T[i, c + 11, b] = qdb[i, b]
                T[i, c + 12, b] = _sign(qdb[i, b])
        for t in range(ia_terms.shape[0]):
            r = ia_terms[t, 0]; c = ia_terms[t, 1]; jt = ia_terms[t, 2]; k = ia_coef[t]
            for b in range(nb):
                T[r, c, b] += k * qddb[jt, b]
        for t in range(fr_terms.shape[0]):
            r = fr_terms[t, 0]; c = fr_terms[t, 1]; m = fr_terms[t, 2]; k = fr_coef[t]
            for b in range(nb):
                x = wm[m, s0 + b]
                T[r, c, b] += k * x
                T[r, c + 1, b] += k * _sign(x)
        # --- frames in the base
        for b in range(nb):
            for a in range(3):
                Ow[0, a, b] = P[0, a, b]
                for c in range(3):
                    Rw[0, a, c, b] = R[0, a, c, b]
        for j in range(1, n):
            for b in range(nb):
                for a in range(3):
                    acc = Ow[j - 1, a, b]
                    acc += Rw[j - 1, a, 0, b] * P[j, 0, b]
                    acc += Rw[j - 1, a, 1, b] * P[j, 1, b]
                    acc += Rw[j - 1, a, 2, b] * P[j, 2, b]
                    Ow[j, a, b] = acc
                    for c in range(3):
                        acc = 0.0
                        acc += Rw[j - 1, a, 0, b] * R[j, 0, c, b]
                        acc += Rw[j - 1, a, 1, b] * R[j, 1, c, b]
                        acc += Rw[j - 1, a, 2, b] * R[j, 2, c, b]
                        Rw[j, a, c, b] = acc
        # --- Newton-Euler forward recursion, in link frames
        for b in range(nb):
            K[0, b] = 0.0; K[1, b] = 0.0; K[2, b] = 0.0          # angular velocity
            K[3, b] = 0.0; K[4, b] = 0.0; K[5, b] = 0.0          # angular acceleration
            K[6, b] = -gravity[0]; K[7, b] = -gravity[1]; K[8, b] = -gravity[2]
        for j in range(n):
            sj = sigma[j]
            for b in range(nb):
                wx, wy, wz, ax, ay, az, vx, vy, vz = propagate_link(
                    R[:, :, :, b], P[:, :, b], j, sj, qdb[j, b], qddb[j, b],
                    K[0, b], K[1, b], K[2, b], K[3, b], K[4, b], K[5, b], K[6, b], K[7, b], K[8, b])
                K[0, b] = wx; K[1, b] = wy; K[2, b] = wz
                K[3, b] = ax; K[4, b] = ay; K[5, b] = az
                K[6, b] = vx; K[7, b] = vy; K[8, b] = vz
                # --- wrench columns of link j (about its origin, frame j)
                # XX: D w = (wx,0,0)
                M[0, 0, b] = ax;  M[1, 0, b] = wz * wx;  M[2, 0, b] = -wy * wx
                # XY: D w = (wy, wx, 0)
                M[0, 1, b] = ay - wz * wx
                M[1, 1, b] = ax + wz * wy
                M[2, 1, b] = wx * wx - wy * wy
                # XZ: D w = (wz, 0, wx)
                M[0, 2, b] = az + wy * wx
                M[1, 2, b] = wz * wz - wx * wx
                M[2, 2, b] = ax - wy * wz
                # YY: D w = (0, wy, 0)
                M[0, 3, b] = -wz * wy;  M[1, 3, b] = ay;  M[2, 3, b] = wx * wy
                # YZ: D w = (0, wz, wy)
                M[0, 4, b] = wy * wy - wz * wz
                M[1, 4, b] = az - wx * wy
                M[2, 4, b] = ay + wx * wz
                # ZZ: D w = (0, 0, wz)
                M[0, 5, b] = wy * wz;  M[1, 5, b] = -wx * wz;  M[2, 5, b] = az
                # MX, MY, MZ: f = dw x e + w x (w x e), n = e x dv
                F[0, 6, b] = -(wy * wy + wz * wz); F[1, 6, b] = az + wx * wy
                F[2, 6, b] = -ay + wx * wz
                F[0, 7, b] = -az + wx * wy; F[1, 7, b] = -(wx * wx + wz * wz)
                F[2, 7, b] = ax + wy * wz
                F[0, 8, b] = ay + wx * wz; F[1, 8, b] = -ax + wy * wz
                F[2, 8, b] = -(wx * wx + wy * wy)
                M[1, 6, b] = -vz; M[2, 6, b] = vy
                M[0, 7, b] = vz;  M[2, 7, b] = -vx
                M[0, 8, b] = -vy; M[1, 8, b] = vx
                F[0, 9, b] = vx; F[1, 9, b] = vy; F[2, 9, b] = vz
            # --- project on the axes of joints i <= j
            c0 = 14 * j
            for i in range(j + 1):
                if sigma[i] == 0:
                    for b in range(nb):
                        zx = Rw[i, 0, 2, b]; zy = Rw[i, 1, 2, b]; zz = Rw[i, 2, 2, b]
                        ux = Rw[j, 0, 0, b] * zx + Rw[j, 1, 0, b] * zy + Rw[j, 2, 0, b] * zz
                        uy = Rw[j, 0, 1, b] * zx + Rw[j, 1, 1, b] * zy + Rw[j, 2, 1, b] * zz
                        uz = Rw[j, 0, 2, b] * zx + Rw[j, 1, 2, b] * zy + Rw[j, 2, 2, b] * zz
                        rx = Ow[j, 0, b] - Ow[i, 0, b]
                        ry = Ow[j, 1, b] - Ow[i, 1, b]
                        rz = Ow[j, 2, b] - Ow[i, 2, b]
                        bx = zy * rz - zz * ry
                        by = zz * rx - zx * rz
                        bz = zx * ry - zy * rx
                        gx = Rw[j, 0, 0, b] * bx + Rw[j, 1, 0, b] * by + Rw[j, 2, 0, b] * bz
                        gy = Rw[j, 0, 1, b] * bx + Rw[j, 1, 1, b] * by + Rw[j, 2, 1, b] * bz
                        gz = Rw[j, 0, 2, b] * bx + Rw[j, 1, 2, b] * by + Rw[j, 2, 2, b] * bz
                        for k in range(6):
                            T[i, c0 + k, b] = ux * M[0, k, b] + uy * M[1, k, b] + uz * M[2, k, b]
                        for k in range(6, 9):
                            T[i, c0 + k, b] = (ux * M[0, k, b] + uy * M[1, k, b] + uz * M[2, k, b]
                                               + gx * F[0, k, b] + gy * F[1, k, b] + gz * F[2, k, b])
                        T[i, c0 + 9, b] = gx * F[0, 9, b] + gy * F[1, 9, b] + gz * F[2, 9, b]
                else:   # a prismatic joint takes the force along its axis only
                    for b in range(nb):
                        zx = Rw[i, 0, 2, b]; zy = Rw[i, 1, 2, b]; zz = Rw[i, 2, 2, b]
                        ux = Rw[j, 0, 0, b] * zx + Rw[j, 1, 0, b] * zy + Rw[j, 2, 0, b] * zz
                        uy = Rw[j, 0, 1, b] * zx + Rw[j, 1, 1, b] * zy + Rw[j, 2, 1, b] * zz
                        uz = Rw[j, 0, 2, b] * zx + Rw[j, 1, 2, b] * zy + Rw[j, 2, 2, b] * zz
                        for k in range(6, 10):
                            T[i, c0 + k, b] = ux * F[0, k, b] + uy * F[1, k, b] + uz * F[2, k, b]
        # `stream` passed as a constant: the copy is compiled once per value, and only
        # there does every store keep its non-temporal mark (with a run-time flag LLVM
        # merges the two stores of the group spanning two samples and drops it); the copy
        # stays a function of its own, since inlined here it made the whole kernel slower
        if cols.shape[0]:
            _copy_columns(T1, width, cols, out, s0, nb)
        elif stream:
            _copy_out(T1, n * width, flat, s0 * n * width, nb, True)
        else:
            _copy_out(T1, n * width, flat, s0 * n * width, nb, False)
    if stream and not cols.shape[0]:
        _store_fence()


if HAVE_NUMBA:
    regressor_rows = numba.njit(cache=True, nogil=True)(_regressor_rows)
else:  # pragma: no cover
    regressor_rows = None
