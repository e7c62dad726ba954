"""Motor-side ↔ joint-side conversion through a reduction (transmission) matrix.

Many drive logs record what the motors see: motor encoder angles and motor torques
(current × torque constant). The dynamic model works on the joint side. The two are
related by the reduction matrix `R` (n × n):

    q_motor   = R · q_joint          (positions, velocities, accelerations)
    tau_joint = Rᵀ · tau_motor       (torques; from equal power  tau_mᵀ·qd_m = tau_jᵀ·qd_j)

`R` is `diag(gear_ratios)` plus one off-diagonal term per mechanical coupling:
a coupling `(motor=m, joint=j, ratio=r)` (1-based) adds `r` to `R[m-1, j-1]`,
meaning that motor `m` also turns when joint `j` moves. Example, the Stäubli TX40
wrist, where motor 6 also drives through joint 5::

    R = reduction_matrix([32, 32, 45, -48, 45, 32], couplings=[(6, 5, 32)])
    q = joint_from_motor_positions(q_motor, R, offsets=[0, -pi/2, pi/2, 0, 0, 0])
    tau = joint_from_motor_torques(tau_motor, R)      # tau5 = 45·tm5 + 32·tm6

Position offsets (the joint angle at which the motor encoder reads zero) are added
*after* applying R⁻¹. They apply to positions only, not to velocities or accelerations.

Errors are raised as `dynid.errors.DataError` with a message that says which
entry is wrong; callers that know the file add it to the message.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from dynid.errors import DataError

__all__ = [
    "reduction_matrix",
    "joint_from_motor_positions",
    "joint_from_motor_velocities",
    "joint_from_motor_torques",
    "motor_from_joint_positions",
    "motor_from_joint_torques",
]


def _as_number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise DataError(f"{what} must be a number, got {value!r}.")
    x = float(value)
    if not np.isfinite(x):
        raise DataError(f"{what} must be a finite number, got {value!r}.")
    return x


def _as_index(value, n: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DataError(f"{what} must be a whole joint/motor number 1..{n}, got {value!r}.")
    k = int(value)
    if not 1 <= k <= n:
        raise DataError(f"{what} = {k} is out of range: joints and motors are numbered 1..{n}.")
    return k


def reduction_matrix(
    gear_ratios: Sequence[float],
    couplings: Iterable[Mapping | Sequence] = (),
) -> np.ndarray:
    """Build the reduction matrix `R` with `q_motor = R · q_joint`.

    Parameters
    ----------
    gear_ratios:
        n gear ratios, the diagonal of `R` (motor turns per joint turn, sign included).
        None of them may be zero.
    couplings:
        Off-diagonal terms, each either a mapping `{"motor": m, "joint": j, "ratio": r}`
        or a sequence `(m, j, r)`, with 1-based `m != j`. Each adds `r` to
        `R[m-1, j-1]`. A pair (m, j) may appear only once.

    Returns
    -------
    numpy.ndarray, shape (n, n), float64.

    Raises
    ------
    DataError
        Zero or non-numeric ratios, bad indices, duplicated couplings or a singular `R`.
    """
    if isinstance(gear_ratios, (str, bytes)) or not isinstance(gear_ratios, Iterable):
        raise DataError(f"gear_ratios must be a list of numbers, got {gear_ratios!r}.")
    ratios = [_as_number(g, f"gear_ratios[{k}] (joint {k + 1})") for k, g in enumerate(gear_ratios)]
    n = len(ratios)
    if n == 0:
        raise DataError("gear_ratios is empty: give one gear ratio per joint.")
    for k, g in enumerate(ratios):
        if g == 0.0:
            raise DataError(
                f"gear_ratios[{k}] = 0 (joint {k + 1}): a gear ratio cannot be zero "
                "(use 1 for a direct drive)."
            )
    R = np.diag(np.asarray(ratios, dtype=float))
    seen: set[tuple[int, int]] = set()
    if isinstance(couplings, Mapping):
        couplings = [couplings]
    for c_no, c in enumerate(couplings, start=1):
        what = f"couplings[{c_no}]"
        if isinstance(c, Mapping):
            unknown = set(c) - {"motor", "joint", "ratio"}
            missing = {"motor", "joint", "ratio"} - set(c)
            if unknown or missing:
                raise DataError(
                    f"{what} must have exactly the keys motor, joint and ratio"
                    + (f"; unknown: {', '.join(sorted(map(str, unknown)))}" if unknown else "")
                    + (f"; missing: {', '.join(sorted(missing))}" if missing else "")
                    + ". Example: {motor = 6, joint = 5, ratio = 32}."
                )
            m, j, r = c["motor"], c["joint"], c["ratio"]
        elif isinstance(c, Sequence) and not isinstance(c, (str, bytes)) and len(c) == 3:
            m, j, r = c
        else:
            raise DataError(
                f"{what} must be {{motor = m, joint = j, ratio = r}} or (m, j, r), got {c!r}."
            )
        m = _as_index(m, n, f"{what}.motor")
        j = _as_index(j, n, f"{what}.joint")
        r = _as_number(r, f"{what}.ratio")
        if m == j:
            raise DataError(
                f"{what} couples motor {m} with joint {j}: that is the diagonal; "
                "set it through gear_ratios instead."
            )
        if (m, j) in seen:
            raise DataError(f"{what}: motor {m} / joint {j} is given twice; keep one entry.")
        seen.add((m, j))
        R[m - 1, j - 1] += r
    if not np.isfinite(np.linalg.cond(R)) or np.linalg.cond(R) > 1e12:
        raise DataError(
            "The reduction matrix built from gear_ratios and couplings is singular; "
            "check the coupling ratios."
        )
    return R


def _check(values, R: np.ndarray, what: str) -> tuple[np.ndarray, bool]:
    R = np.asarray(R, dtype=float)
    if R.ndim != 2 or R.shape[0] != R.shape[1]:
        raise DataError(f"The reduction matrix must be square, got shape {R.shape}.")
    x = np.asarray(values, dtype=float)
    one = x.ndim == 1
    x2 = x[None, :] if one else x
    if x2.ndim != 2 or x2.shape[1] != R.shape[0]:
        raise DataError(
            f"{what} has shape {x.shape} but the reduction matrix is for "
            f"{R.shape[0]} joints: give an array (N, {R.shape[0]}) or ({R.shape[0]},)."
        )
    return x2, one


def joint_from_motor_positions(q_motor, R, offsets=None) -> np.ndarray:
    """Joint positions from motor positions: `q = R⁻¹ · q_motor + offsets`.

    `q_motor` has shape (N, n) (one row per sample) or (n,). `offsets` (n,) are added
    after the inverse reduction (default zeros). Pass `offsets=None` for velocities and
    accelerations (see `joint_from_motor_velocities`).
    """
    x, one = _check(q_motor, R, "q_motor")
    q = np.linalg.solve(np.asarray(R, dtype=float), x.T).T
    if offsets is not None:
        off = np.asarray(offsets, dtype=float).reshape(-1)
        if off.shape != (q.shape[1],):
            raise DataError(
                f"position_offsets has {off.size} entries but there are {q.shape[1]} joints."
            )
        q = q + off
    return q[0] if one else q


def joint_from_motor_velocities(qd_motor, R) -> np.ndarray:
    """Joint velocities (or accelerations) from motor ones: `qd = R⁻¹ · qd_motor`."""
    return joint_from_motor_positions(qd_motor, R, offsets=None)


def joint_from_motor_torques(tau_motor, R) -> np.ndarray:
    """Joint torques from motor torques: `tau = Rᵀ · tau_motor`.

    `tau_motor` has shape (N, n) or (n,), in motor-side torque units (drive gains,
    i.e. torque constants, already applied).
    """
    x, one = _check(tau_motor, R, "tau_motor")
    tau = x @ np.asarray(R, dtype=float)  # row-wise (Rᵀ·x_k)ᵀ = x_kᵀ·R
    return tau[0] if one else tau


def motor_from_joint_positions(q, R, offsets=None) -> np.ndarray:
    """Inverse of `joint_from_motor_positions`: `q_motor = R · (q − offsets)`."""
    x, one = _check(q, R, "q")
    if offsets is not None:
        x = x - np.asarray(offsets, dtype=float).reshape(1, -1)
    qm = x @ np.asarray(R, dtype=float).T
    return qm[0] if one else qm


def motor_from_joint_torques(tau, R) -> np.ndarray:
    """Inverse of `joint_from_motor_torques`: `tau_motor = R⁻ᵀ · tau`."""
    x, one = _check(tau, R, "tau")
    tm = np.linalg.solve(np.asarray(R, dtype=float).T, x.T).T
    return tm[0] if one else tm
