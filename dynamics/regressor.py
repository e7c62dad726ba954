"""The standard inverse-dynamics regressor IDM_st(q, qd, qdd) of eq. (2).

`tau = IDM_st(q, qd, qdd) chi_st` with chi_st the standard parameters of
eq. (3) (plus coupling parameters). The columns are built by the Newton-Euler
algorithm written linearly in the parameters (Khalil & Dombre 2002, §12.4),
for all samples at once: no Python loop runs over samples.

How: the forward recursion gives each link's `w, dw, dv` in its own frame;
the wrench of link `j` about its origin is linear in its ten inertial
parameters, `f = M dv + (dw x + w x w x) MS`,
`n = I dw + w x (I w) + MS x dv`. The torque that this wrench loads joint
`i <= j` with is `u_ij . n + v_ij . f`, where `u_ij` is joint `i`'s
axis and `v_ij = z_i x (O_j - O_i)`, both expressed in frame `j` (for a
prismatic joint `i` only `z_i . f` counts). That projection costs far less
than propagating full wrenches back link by link.
"""
from __future__ import annotations

import threading

import numpy as np

from dynid.errors import InputError

from . import _kernels

# the one implementation of each, importable from here too (e.g. benchmarks/idim.py)
from .dynamic_model import bias_torque, inverse_dynamics, mass_matrix  # noqa: F401
from .kinematics import _cross, forward_kinematics, newton_euler_forward
from .robot import PER_JOINT

N_PER_JOINT = len(PER_JOINT)
DEFAULT_CHUNK = 10_000

# symmetric basis matrices of the inertia tensor, order XX XY XZ YY YZ ZZ
_I_BASIS = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


def _as_samples(robot, q, qd, qdd):
    q = np.atleast_2d(np.asarray(q, dtype=float))
    qd = np.atleast_2d(np.asarray(qd, dtype=float))
    qdd = np.atleast_2d(np.asarray(qdd, dtype=float))
    n = robot.n_joints
    for name, a in (("q", q), ("qd", qd), ("qdd", qdd)):
        if a.ndim != 2 or a.shape[1] != n:
            raise ValueError(f"{name} must have shape (N, {n}) for robot '{robot.name}', got {a.shape}")
    if not (q.shape == qd.shape == qdd.shape):
        raise ValueError(f"q, qd, qdd shapes differ: {q.shape}, {qd.shape}, {qdd.shape}")
    return q, qd, qdd


def _link_wrench_columns(w, dw, dv):
    """Force and moment columns (N, 3, 10) of one link's wrench about its origin."""
    N = w.shape[0]
    f = np.zeros((N, 3, 10))
    m = np.zeros((N, 3, 10))
    # inertia tensor entries: n = D dw + w x (D w), D the symmetric basis matrix
    for k, (a, b) in enumerate(_I_BASIS):
        Ddw = np.zeros((N, 3))
        Dw = np.zeros((N, 3))
        Ddw[:, a] += dw[:, b]
        Dw[:, a] += w[:, b]
        if a != b:
            Ddw[:, b] += dw[:, a]
            Dw[:, b] += w[:, a]
        m[:, :, k] = Ddw + _cross(w, Dw)
    # first moments: f = dw x e + w x (w x e), n = e x dv
    eye = np.eye(3)
    for k in range(3):
        e = np.broadcast_to(eye[k], (N, 3))
        f[:, :, 6 + k] = _cross(dw, e) + _cross(w, _cross(w, e))
        m[:, :, 6 + k] = _cross(e, dv)
    # mass
    f[:, :, 9] = dv
    return f, m


#: `cols` of the compiled kernel that mean every column
_ALL = np.empty(0, dtype=np.int64)


def _robot_arrays(robot):
    """Placements as contiguous arrays for the compiled kernel."""
    Rp = np.ascontiguousarray([j.R for j in robot.joints], dtype=float)
    pp = np.ascontiguousarray([j.p for j in robot.joints], dtype=float)
    return Rp, pp, np.ascontiguousarray(robot.sigma, dtype=np.int64)


def _fill_chunk(robot, q, qd, qdd, out, gravity=None, backend="numba", cols=_ALL):
    """Write IDM_st for one chunk of samples into `out` (N, n, Ns), or its columns `cols`
    (N, n, len(cols); numba backend only, indices in 0 .. Ns - 1).

    The numba backend writes every column itself, so `out` may hold anything;
    the NumPy backend needs `out` zeroed.
    """
    if backend == "numba" and _kernels.HAVE_NUMBA:
        g = robot.gravity if gravity is None else np.asarray(gravity, dtype=float)
        Rp, pp, sigma = _robot_arrays(robot)
        ia_terms, ia_coef, fr_terms, fr_coef, fr_joints = _coupling_terms(robot)
        # the coupled velocities by the same matrix product as `_coupling_columns`: BLAS
        # rounds it its own way (fused multiply-adds), which the kernel cannot repeat
        wm = np.empty((len(fr_joints), q.shape[0]))
        for m, (idx, coef) in enumerate(fr_joints):
            wm[m] = qd[:, idx] @ coef
        _kernels.regressor_rows(Rp, pp, sigma, np.asarray(g, dtype=float),
                                np.ascontiguousarray(q), np.ascontiguousarray(qd),
                                np.ascontiguousarray(qdd), ia_terms, ia_coef, fr_terms, fr_coef,
                                wm, cols, out, out.nbytes >= _kernels.STREAM_BYTES)
    else:
        _inertial_columns_numpy(robot, q, qd, qdd, out, gravity)
        _actuator_columns(robot, qd, qdd, out)
    return out


def _coupling_terms(robot):
    """The coupling terms (section 4 of the DIDIM paper, eq. (33)) as tables, in the order
    both backends add them.

    Returns
    -------
    ia_terms : ndarray (K, 3) of int
        `(row, column, joint)`: `ia_coef[t] * qdd[:, joint]` is added to `out[:, row, column]`.
    ia_coef : ndarray (K,)
    fr_terms : ndarray (L, 3) of int
        `(row, column, m)`: `fr_coef[t]` times the coupled velocity `wm_m` is added to
        `out[:, row, column]`, and times `sign(wm_m)` to column + 1.
    fr_coef : ndarray (L,)
    fr_joints : list of (ndarray, ndarray)
        Per coupling with friction, its joints (0-based) and coefficients:
        `wm_m = qd[:, joints] @ coefficients`.
    """
    n = robot.n_joints
    col = N_PER_JOINT * n
    ia_terms, ia_coef, fr_terms, fr_coef, fr_joints = [], [], [], [], []
    for c in robot.couplings:
        # the kernel indexes with these unchecked: a robot built in Python is not validated
        # as a robot file is (robot_file._coupling)
        if not (1 <= c.motor <= n and all(1 <= j <= n for j in c.joints)
                and len(c.joints) == len(c.coefficients)):
            raise InputError(f"robot '{robot.name}': coupling of motor {c.motor} with joints {tuple(c.joints)} "
                             f"and {len(c.coefficients)} coefficient(s): the motor and every joint must be "
                             f"a joint number 1..{n}, with one coefficient per joint")
        idx = np.asarray(c.joints) - 1
        coef = np.asarray(c.coefficients, dtype=float)
        cm = coef[list(c.joints).index(c.motor)] if c.motor in c.joints else 1.0
        ia_col = N_PER_JOINT * (c.motor - 1) + 10
        for a, ka in zip(idx, coef):
            for b, kb in zip(idx, coef):
                if a != b:
                    ia_terms.append((a, ia_col, b))
                    ia_coef.append(ka * kb / cm ** 2)
        if c.friction:
            for a, ka in zip(idx, coef):
                fr_terms.append((a, col, len(fr_joints)))
                fr_coef.append(ka)
            fr_joints.append((idx, coef))
            col += 2
    return (np.array(ia_terms, dtype=np.int64).reshape(-1, 3), np.array(ia_coef, dtype=float),
            np.array(fr_terms, dtype=np.int64).reshape(-1, 3), np.array(fr_coef, dtype=float),
            fr_joints)


def _inertial_columns_numpy(robot, q, qd, qdd, out, gravity=None):
    """Vectorised NumPy version of the inertial columns (reference backend)."""
    N, n = q.shape
    links, Rs, Ps = newton_euler_forward(robot, q, qd, qdd, gravity)
    Rw, pw = forward_kinematics(robot, q, (Rs, Ps))
    Z = np.stack([R[:, :, 2] for R in Rw], axis=1)          # joint axes, base frame
    O = np.stack(pw, axis=1)                                 # joint origins, base frame
    prismatic = np.array([jt.sigma == 1 for jt in robot.joints])
    for j in range(n):
        w, dw, dv = links[j]
        f, m = _link_wrench_columns(w, dw, dv)
        MF = np.concatenate([m, f], axis=1)                  # (N, 6, 10)
        zi = Z[:, :j + 1]
        v = np.cross(zi, O[:, j:j + 1] - O[:, :j + 1])       # z_i x (O_j - O_i)
        # (R_j^T x)^T = x^T R_j: both projections expressed in frame j at once
        uv = np.concatenate([zi @ Rw[j], v @ Rw[j]], axis=2)  # (N, j+1, 6)
        if prismatic[:j + 1].any():
            pi = np.flatnonzero(prismatic[:j + 1])
            uv[:, pi, 3:] = uv[:, pi, :3]                    # force along z_i only
            uv[:, pi, :3] = 0.0
        c0 = N_PER_JOINT * j
        out[:, :j + 1, c0:c0 + 10] = uv @ MF


def _actuator_columns(robot, qd, qdd, out):
    """Ia, Fv, Fc, Off (diagonal) and coupling columns."""
    n = qd.shape[1]
    rows = np.arange(n)
    base = N_PER_JOINT * rows
    out[:, rows, base + 10] = qdd
    out[:, rows, base + 11] = qd
    out[:, rows, base + 12] = np.sign(qd)
    out[:, rows, base + 13] = 1.0
    _coupling_columns(robot, qd, qdd, out)


def _coupling_columns(robot, qd, qdd, out):
    """Coupling terms (section 4 of the DIDIM paper, eq. (33)), added to zeroed columns
    (the NumPy backend; the compiled kernel applies the same tables, `_coupling_terms`)."""
    ia_terms, ia_coef, fr_terms, fr_coef, fr_joints = _coupling_terms(robot)
    for (r, c, j), k in zip(ia_terms, ia_coef):
        out[:, r, c] += k * qdd[:, j]
    wm = [qd[:, idx] @ coef for idx, coef in fr_joints]
    for (r, c, m), k in zip(fr_terms, fr_coef):
        out[:, r, c] += k * wm[m]
        out[:, r, c + 1] += k * np.sign(wm[m])


def regressor(robot, q, qd, qdd, *, columns=None, chunk=DEFAULT_CHUNK, gravity=None,
              backend="numba", out=None):
    """IDM_st(q, qd, qdd) of eq. (2): array (N, n, Ns), or (N, n, len(columns)).

    Parameters
    ----------
    robot : Robot
    q, qd, qdd : array_like (N, n)
        Joint positions, velocities, accelerations.
    columns : sequence of int, optional
        Standard-parameter columns to keep (e.g. the independent ones of the base
        parameters), so only those are held in memory.
    chunk : int
        Samples processed at a time (bounds the temporary memory).
    gravity : array_like (3,), optional
        Instead of the robot's.
    backend : str
        `"numba"` (compiled, default) or `"numpy"` (vectorised reference implementation).
    out : ndarray (N, n, Ns or len(columns)), optional
        Float64, C-contiguous array to write into (every entry is written): a caller that
        builds the regressor of the same number of samples repeatedly reuses it instead of
        paying for fresh memory each time.

    Returns
    -------
    ndarray
        `out` when given, else a new array.
    """
    q, qd, qdd = _as_samples(robot, q, qd, qdd)
    N, n = q.shape
    ns = robot.n_standard
    width = ns if columns is None else len(columns)
    compiled = backend == "numba" and _kernels.HAVE_NUMBA
    if out is None:
        # the compiled kernel writes every column; the NumPy one adds into zeros
        W = np.empty((N, n, width)) if compiled or columns is not None else np.zeros((N, n, width))
    else:
        if (not isinstance(out, np.ndarray) or out.shape != (N, n, width) or out.dtype != np.float64
                or not out.flags.c_contiguous or not out.flags.writeable):
            raise ValueError(f"out must be a writeable C-contiguous float64 array of shape "
                             f"{(N, n, width)}, got {getattr(out, 'shape', type(out).__name__)}")
        W = out
        if not (compiled or columns is not None):
            W[...] = 0.0
    take = _take_mode(columns, ns)
    # the compiled kernel copies valid columns out itself; others go through np.take,
    # which raises for an index out of range as NumPy does
    direct = columns is None or (compiled and take[1] == "clip")
    cols = _ALL if columns is None or not direct else np.ascontiguousarray(take[0], dtype=np.int64)
    for start in range(0, N, chunk):
        sl = slice(start, min(N, start + chunk))
        if direct:
            _fill_chunk(robot, q[sl], qd[sl], qdd[sl], W[sl], gravity, backend, cols)
        else:
            block = _scratch_block((sl.stop - sl.start, n, ns))
            if not compiled:
                block[...] = 0.0
            _fill_chunk(robot, q[sl], qd[sl], qdd[sl], block, gravity, backend)
            np.take(block, take[0], axis=2, out=W[sl], mode=take[1])
    return W


#: Per thread, the last all-columns buffer of the `columns` route through np.take (the NumPy
#: backend, or columns the compiled kernel cannot copy out itself). A chunk of the TX40
#: (10,000 samples x 6 x 86) is 41 MB, above the size malloc hands back to the system at
#: once, so a fresh buffer per call paid its page faults again at every chunk.
_SCRATCH = threading.local()


def _scratch_block(shape):
    """A C-contiguous (m, n, Ns) buffer: the first m rows of this thread's kept one when it
    is large enough (a row slice of a C-contiguous array is one), else a new one, kept."""
    block = getattr(_SCRATCH, "block", None)
    if block is None or block.shape[1:] != shape[1:] or block.shape[0] < shape[0]:
        block = _SCRATCH.block = np.empty(shape)
    return block[:shape[0]]


def _take_mode(columns, ns):
    """(indices, mode) of the kept columns: non-negative in-range indices with mode "clip"
    when they all are (the compiled kernel copies them out itself; np.take with "clip" writes
    straight into `out`, where "raise" goes through a buffer, 3x slower); else the columns as
    given with "raise", and np.take raises for an index out of range as before."""
    if columns is None:
        return None
    cols = np.asarray(columns)
    if cols.dtype.kind not in "iu" or cols.ndim != 1 or not cols.size:
        return columns, "raise"
    if cols.min() < -ns or cols.max() >= ns:
        return columns, "raise"
    return np.where(cols < 0, cols + ns, cols).astype(np.intp), "clip"


def regressor_chunks(robot, q, qd, qdd, *, columns=None, chunk=DEFAULT_CHUNK):
    """Yield `(slice, W_chunk)` over the recording, for bounded memory."""
    q, qd, qdd = _as_samples(robot, q, qd, qdd)
    for start in range(0, q.shape[0], chunk):
        sl = slice(start, min(q.shape[0], start + chunk))
        yield sl, regressor(robot, q[sl], qd[sl], qdd[sl], columns=columns, chunk=chunk)


# ------------------------------------------------ the regressor route (test oracles)
# dynid's one public inverse_dynamics / mass_matrix / bias_torque are the
# per-sample RNEA of dynid.dynamics.dynamic_model (re-exported below). The three
# functions here compute the same quantities through the regressor, tau = W chi;
# they stay, private, only as an independent check: tests/dynamics/test_regressor.py
# compares them with Pinocchio (which checks the regressor's columns).

def _inverse_dynamics_via_regressor(robot, chi, q, qd, qdd, *, chunk=DEFAULT_CHUNK):
    """tau = IDM_st(q, qd, qdd) chi, shape (N, n), eq. (2) (test oracle)."""
    chi = np.asarray(chi, dtype=float)
    q, qd, qdd = _as_samples(robot, q, qd, qdd)
    tau = np.empty(q.shape)
    for sl, W in regressor_chunks(robot, q, qd, qdd, chunk=chunk):
        tau[sl] = W @ chi
    return tau


def _mass_matrix_via_regressor(robot, chi, q):
    """Inertia matrix M(q) of eq. (1), (N, n, n), from the standard parameters chi (test oracle).

    Column k is the inertial torque of a unit acceleration of joint k with the
    robot at rest and no gravity (the numerical route of section 4 of the paper).
    """
    chi = _inertia_only(robot, chi)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    N, n = q.shape
    zeros = np.zeros_like(q)
    M = np.empty((N, n, n))
    for k in range(n):
        qdd = np.zeros_like(q)
        qdd[:, k] = 1.0
        M[:, :, k] = regressor(robot, q, zeros, qdd, gravity=np.zeros(3)) @ chi
    return M


def _bias_torque_via_regressor(robot, chi, q, qd):
    """N(q, qd) of eq. (1): Coriolis, centrifugal, gravity, friction and offsets (test oracle)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return _inverse_dynamics_via_regressor(robot, chi, q, qd, np.zeros_like(q))


def gravity_torque(robot, chi, q):
    """Gravity torque G(q): the bias at rest without friction and offsets."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    z = np.zeros_like(q)
    return regressor(robot, q, z, z) @ _inertia_only(robot, chi)


def _inertia_only(robot, chi):
    """chi with friction and offset parameters zeroed (they are not inertia/gravity)."""
    chi = np.array(chi, dtype=float)
    for k, name in enumerate(robot.standard_names):
        if name.startswith(("Fv", "Fc", "Off")):
            chi[k] = 0.0
    return chi
