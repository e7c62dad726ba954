"""Payload identification: the ten inertial parameters of what the robot carries.

A payload rigidly fixed to link `k` (the last one by default) adds its ten
inertial parameters to that link's: with `pi_L` the payload's parameters in
a frame `L` fixed to the link (the flange, or the link frame moved by a
placement the user gives), the torque it costs is `W_k(q, qd, qdd) T pi_L`,
`W_k` the link's ten columns of the standard regressor of eq. (2) (XX XY XZ
YY YZ ZZ MX MY MZ M about the link frame, modified DH) and `T` the linear
map of a rigid change of frame (parallel axes, `transform_matrix`).
The names follow Gautier & Briot (2014): XXL XYL XZL YYL YZL ZZL MXL MYL MZL ML.

Two routes (the observation is IDIM's: zero-phase filter of q, central
differences, parallel decimation, eqs. (8)-(9) of Gautier, Janot &
Vandanjon 2010):

* robot fixed (`identify_payload(loaded, robot, model=...)`): the robot is
  an identified model (a dynid result or its JSON); the loaded recording's
  torque minus the model's prediction is regressed on the payload's ten
  columns, per-joint weighted (eq. (16)). The uncertainty of the robot's
  parameters is propagated (`cov += G cov_beta G^T`, `G` the payload
  estimate's sensitivity to the robot's parameters).
* global (`identify_payload(loaded, robot, unloaded=...)`): the unloaded
  and the loaded recordings are stacked, the robot's base parameters active
  on every row, the payload's ten columns on the loaded rows only; both are
  identified together.

Correlated residuals. After filtering and decimation the residual of a
recording is not white (the model's friction and the robot's parameter errors
follow the trajectory), so the covariance of eq. (14) is too small. The
covariance here is the sandwich `A S A` with `A = (W^T Om W)^-1` and
`S` the Newey-West (Bartlett) long-run covariance of the weighted scores
`sum_j W_tj e_tj / sigma_j^2` (statsmodels' `S_hac_simple`), its window
the residual's correlation length.

Torque timing (`zoh=True`). A controller's log holds the command `tau_k` applied over
`[t_k, t_k + T)`: half a sample after the position `q_k` it is paired with. The payload's
columns are small beside the robot's torque, and that half-sample lead of the whole torque
leaks into them (on the independent TX40 plant at 2 kHz, one development seed: the inertia
about the centre of mass off by 9.8 % of the largest principal moment, 4.5 % once centred;
benchmarks/payload_timing.py). `zoh=True` centres
the torque on the position samples, `(tau_k-1 + tau_k) / 2` (`centre_held_torque`, as
`dynid.analysis.decoupled.estimates` and dynid's simulator do). Every recording of one fit must
have the same timing: on the robot-fixed route the model must have been identified from centred
torques too (`dynid.identify(centre_held_torque(e), robot)`), else the robot's own torque, whose
delay the model absorbed, leaks into the payload instead.

Which parameters the data identify is decided by the wrist's motion: the
payload's ten columns must be independent on the recording. They are checked
(column-scaled singular values, `RANK_RTOL`); a direction the data do not
see is refused with the parameters it involves and the wrist's motion.

Physically consistent payload (`physical_payload`): the payload's
pseudo-inertia positive semidefinite (Wensing, Kim & Slotine 2017), mass >
0 and optionally the centre of mass in a box, one SDP solved by Clarabel as
the physical fits of `dynid.analysis.estimators.physical` (in payload_physical.py); it minimises
the distance to the free estimate in the metric of its covariance.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from dynid.analysis.data.experiment import Experiment, load_experiment
from dynid.analysis.data.record import recording_of
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.payload_physical import PAYLOAD_NAMES, PhysicalPayload, physical_payload
from dynid.analysis.processing.decimation import ParallelDecimator
from dynid.analysis.processing.observation import CHUNK, full_rate
from dynid.analysis.results import (
    IdentificationResult,
    ParameterResults,
    notices_block,
    p_phrase,
    parameter_table,
    percent,
)
from dynid.analysis.units import parameter_unit
from dynid.dynamics.base_parameters import base_parameters, random_samples
from dynid.dynamics.regressor import regressor
from dynid.dynamics.robot import Robot, model_signature
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.urdf import inertia_about_com
from dynid.dynamics.urdf_writer import inertial_slice, link_consistency
from dynid.errors import IdentificationError, InputError
from dynid.provenance import json_safe, versions
from dynid.ranges import check_range

__all__ = ["PAYLOAD_NAMES", "PayloadResult", "PhysicalPayload", "identify_payload", "physical_payload",
           "transform_matrix", "payload_frame", "payload_link_values", "centre_held_torque", "RANK_RTOL"]

UNITS = tuple(parameter_unit(n) for n in PAYLOAD_NAMES)   # kg m², kg m, kg: as every result's
#: a payload direction whose column-scaled singular value is below this fraction of the largest
#: is not identified: its sigma would be over 1e3 times that of the best-seen direction
RANK_RTOL = 1e-3
#: a parameter whose 95 % half-width exceeds this fraction of its scale (inertia entries: half the
#: trace of the inertia about the frame; first moments: |m c|, at least m x 1 cm; mass: m) is
#: not identified by the recording
MAX_REL_HALFWIDTH = 0.25
_Z95 = 1.959963984540054


# ------------------------------------------------------------------------------- frames
def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _to_link(values, R, p):
    """Ten parameters about frame F (axes R, origin p in the link frame) -> about the link frame."""
    XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, m = values
    I_f = np.array([[XX, XY, XZ], [XY, YY, YZ], [XZ, YZ, ZZ]])
    h = R @ np.array([MX, MY, MZ])
    P, H = _skew(p), _skew(h)
    # I_link = R I_F R^T - m [p]^2 - [p][h] - [h][p] (parallel axes with the first moments)
    I_l = R @ I_f @ R.T - m * P @ P - P @ H - H @ P
    h_l = m * np.asarray(p) + h
    return np.array([I_l[0, 0], I_l[0, 1], I_l[0, 2], I_l[1, 1], I_l[1, 2], I_l[2, 2], *h_l, m])


def transform_matrix(R=None, p=None) -> np.ndarray:
    """T (10, 10) with `pi_link = T pi_F`: a frame F with axes `R` and origin `p` (link frame).

    Parameters
    ----------
    R : (3, 3) array, optional
        Axes of F in the link frame (default identity).
    p : (3,) array, optional
        Origin of F in the link frame, m (default 0).

    Returns
    -------
    ndarray (10, 10)
        Linear in the parameters (order XX XY XZ YY YZ ZZ MX MY MZ M).
    """
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    p = np.zeros(3) if p is None else np.asarray(p, dtype=float)
    return np.column_stack([_to_link(e, R, p) for e in np.eye(10)])


def payload_frame(robot, frame="flange", offset=None):
    """`(link index, R, p)` of the payload frame: a link of `robot` and a placement in it.

    Parameters
    ----------
    robot : Robot
    frame : str or int
        `"flange"` (the last link's frame), a joint name of the robot (the link it
        moves) or a 1-based link number.
    offset : dict, optional
        `{"xyz": (3,), "rpy": (3,)}`: the payload frame in that link's frame (m, rad;
        URDF's roll-pitch-yaw).

    Raises
    ------
    InputError
        `frame` is not a link of the robot, or `offset` is malformed.
    """
    names = robot.joint_names
    if isinstance(frame, (int, np.integer)) and not isinstance(frame, bool):
        if not 1 <= int(frame) <= robot.n_joints:
            raise InputError(f"payload frame {frame} is not a link of robot '{robot.name}': links are "
                             f"1..{robot.n_joints} (or 'flange', or a joint name: {', '.join(names)})")
        j = int(frame) - 1
    elif frame in ("flange", None, "", "last"):
        j = robot.n_joints - 1
    elif isinstance(frame, str) and frame in names:
        j = names.index(frame)
    elif isinstance(frame, str) and frame.isdigit():
        return payload_frame(robot, int(frame), offset)
    else:
        raise InputError(f"payload frame {frame!r} is not a link of robot '{robot.name}': give "
                         f"'flange' (the last link), a joint name ({', '.join(names)}) or a link "
                         f"number 1..{robot.n_joints} (--frame)")
    R, p = np.eye(3), np.zeros(3)
    if offset:
        unknown = sorted(set(offset) - {"xyz", "rpy"}) if isinstance(offset, dict) else []
        if unknown:
            raise InputError(f"payload frame offset: unknown key(s) {', '.join(map(repr, unknown))}; give "
                             "{'xyz': [x, y, z], 'rpy': [roll, pitch, yaw]} (m, rad)")
        try:
            p = np.asarray(offset.get("xyz", (0, 0, 0)), dtype=float).reshape(3)
            r, pi, y = np.asarray(offset.get("rpy", (0, 0, 0)), dtype=float).reshape(3)
        except (AttributeError, TypeError, ValueError):
            raise InputError("payload frame offset must be {'xyz': [x, y, z], 'rpy': [roll, pitch, yaw]} "
                             f"(m, rad), got {offset!r}") from None
        cr, sr, cp_, sp, cy, sy = math.cos(r), math.sin(r), math.cos(pi), math.sin(pi), math.cos(y), math.sin(y)
        R = np.array([[cy * cp_, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                      [sy * cp_, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                      [-sp, cp_ * sr, cp_ * cr]])
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            raise InputError(f"payload frame offset holds non-finite values: {offset!r}")
    return j, R, p


def payload_link_values(result) -> np.ndarray:
    """The payload's ten parameters about its link's frame (for a robot file or an export)."""
    return result.T @ np.asarray(result.chi, dtype=float)


# ------------------------------------------------------------------------------- observation
@dataclass
class _Obs:
    """One recording's decimated system: robot base columns, payload columns, torques."""

    Wb: np.ndarray       # (M, n, b)
    Wp: np.ndarray       # (M, n, 10) payload columns in the payload frame
    tau: np.ndarray      # (M, n)
    q: np.ndarray        # (M, n)
    mask: np.ndarray     # (M, n)
    settings: dict
    notices: list


def _observe(experiment, robot, bp, link, T, settings=None):
    """IDIM's observation (filter, differentiate, dead zone, parallel decimation) with the payload's
    columns decimated beside the base regressor and the torque."""
    if experiment.q is None:
        raise InputError(f"{experiment.source}: payload identification needs measured joint positions "
                         f"(q1..q{robot.n_joints})")
    fr = full_rate(experiment, robot, experiment.q, settings)
    s = fr.settings
    nd = int(s["nd"])
    b = bp.n_base
    sl = inertial_slice(robot, link)
    cols = list(bp.independent) + list(range(sl.start, sl.stop))
    n_kept = fr.q.shape[0]
    dec = ParallelDecimator(nd, n_samples_total=n_kept, fs=fr.fs, cutoff=s["f_decimation_cutoff"]) \
        if nd > 1 else None
    parts = []
    for start in range(0, n_kept, CHUNK):
        c = slice(start, min(n_kept, start + CHUNK))
        W = regressor(robot, fr.q[c], fr.qd[c], fr.qdd[c], columns=cols)
        Wb, Wp = W[:, :, :b], W[:, :, b:] @ T
        tau = fr.tau[c]
        kept = np.ones(tau.shape)
        if fr.dead is not None:
            kept = (~fr.dead[c]).astype(float)
            Wb, Wp, tau = Wb * kept[:, :, None], Wp * kept[:, :, None], tau * kept
        parts.append((Wb, Wp, tau, fr.q[c], kept) if dec is None else dec.push(Wb, Wp, tau, fr.q[c], kept))
    if dec is not None:
        dec.finish()
    Wb, Wp, tau, q, kept = (np.concatenate([p[k] for p in parts], axis=0) for k in range(5))
    mask = kept >= 0.5 if dec is not None else kept > 0
    return _Obs(Wb, Wp, tau, q, mask, s, [fr.edge_notice])


# ------------------------------------------------------------------------------- statistics
def _hac_lags(e, mask):
    """Newey-West window: the lag where the residual's mean autocorrelation (over joints) first
    falls below 0.05, at least Newey & West's rule 4 (M/100)^(2/9), at most M/4."""
    E = np.where(mask, e, 0.0)
    E = E - E.mean(axis=0)
    M = E.shape[0]
    n_fft = 1 << int(np.ceil(np.log2(2 * M)))
    F = np.fft.rfft(E, n_fft, axis=0)
    ac = np.fft.irfft(np.abs(F) ** 2, n_fft, axis=0)[:M]
    ac = ac / np.maximum(ac[0], 1e-300)
    rho = ac.mean(axis=1)
    below = np.flatnonzero(rho < 0.05)
    corr = int(below[0]) if below.size else M // 4
    rule = int(math.floor(4 * (M / 100.0) ** (2.0 / 9.0)))
    return int(min(max(2 * corr, rule), M // 4))


def _sandwich(W3, e, mask, sigma_j, lags):
    """A S A of the per-joint weighted LS (module doc): W3 (M, n, p), e (M, n) residuals."""
    from statsmodels.stats.sandwich_covariance import S_hac_simple
    w = np.where(mask, 1.0 / sigma_j[None, :] ** 2, 0.0)         # (M, n)
    A = np.linalg.pinv(np.einsum("tjp,tj,tjq->pq", W3, w, W3))
    psi = np.einsum("tjp,tj->tp", W3, w * e)
    S = S_hac_simple(psi, nlags=lags)          # a sum over samples, as A is
    return A @ S @ A


def _wls_hac(W3, tau, names, mask, joint_sigma=None):
    """Per-joint WLS (eq. (16)) and its HAC covariance: (estimate, cov, IdentificationResult, lags)."""
    fit = ls.wls(W3, tau, names, row_mask=mask, joint_sigma=joint_sigma)
    e = fit.residual
    sig = np.asarray(fit.joint_sigma, dtype=float)
    sig = np.where(np.isfinite(sig) & (sig > 0), sig, np.inf)
    lags = _hac_lags(e, mask)
    cov = _sandwich(W3, e, mask, sig, lags)
    return fit.chi, 0.5 * (cov + cov.T), fit, lags


def _identifiability(Wp, mask, names, rtol):
    """Directions of the payload's columns the data do not see: list of (ratio, {name: weight})."""
    X = np.where(mask[:, :, None], Wp, 0.0).reshape(-1, Wp.shape[2])
    norms = np.linalg.norm(X, axis=0)
    dead = norms <= 1e-12 * max(norms.max(), 1e-300)
    live = np.flatnonzero(~dead)
    # the columns the data never see are named once each, outside the SVD (whose null vectors
    # would name them again, mixed)
    _, s, Vt = np.linalg.svd(X[:, live] / norms[live], full_matrices=False)
    ratio = s / s[0] if s.size and s[0] > 0 else np.zeros_like(s)
    out = []
    for r, v in zip(ratio, Vt):
        if r < rtol:
            big = np.abs(v) >= 0.2 * np.abs(v).max()
            out.append((float(r), {names[live[k]]: float(v[k]) for k in np.flatnonzero(big)}))
    for k in np.flatnonzero(dead):
        out.append((0.0, {names[k]: 1.0}))
    return out, np.r_[ratio, np.zeros(int(dead.sum()))]


def unfelt_parameters(robot, frame="flange", offset=None) -> list:
    """The payload parameters no motion of `robot` can show (their regressor columns are zero at
    random configurations, velocities and accelerations): a planar arm never feels XXL, XYL ...
    Checked before any recording is read (`dynid report --payload` runs every method first)."""
    robot = _as_robot(robot)
    link, R, p = payload_frame(robot, frame, offset)
    sl = inertial_slice(robot, link)
    q, qd, qdd = random_samples(robot, 64, np.random.default_rng(0))
    Wp = regressor(robot, q, qd, qdd, columns=np.arange(sl.start, sl.stop)) @ transform_matrix(R, p)
    scale = np.abs(Wp).max()
    return [PAYLOAD_NAMES[k] for k in np.flatnonzero(np.abs(Wp).max(axis=(0, 1)) <= 1e-12 * max(scale, 1.0))]


def unfelt_message(robot, names) -> str:
    """Why a payload cannot be identified on a robot that never feels `names`."""
    return (f"the joints of robot '{robot.name}' never feel the payload parameters {', '.join(names)}: "
            f"their regressor columns are zero whatever the motion (the joints that carry the payload "
            f"turn it about fewer than three axes). dynid identifies the ten parameters of a payload "
            f"together, so not on this robot")


def _wrist_motion(robot, obs_list, link):
    """Range (deg) of each joint up to the payload's link, over the recordings, for messages."""
    q = np.concatenate([o.q for o in obs_list], axis=0)
    rng = np.degrees(q.max(axis=0) - q.min(axis=0))
    first = max(0, link - 2)
    return ", ".join(f"q{j + 1} {rng[j]:.3g} deg" for j in range(first, link + 1))


def _poorly_identified(chi, cov, limit):
    """Parameters whose 95 % half-width exceeds `limit` times their scale (MAX_REL_HALFWIDTH)."""
    m = max(abs(chi[9]), 1e-12)
    s_I = max(0.5 * (abs(chi[0]) + abs(chi[3]) + abs(chi[5])), 1e-12)
    s_h = max(float(np.linalg.norm(chi[6:9])), 0.01 * m)
    scale = np.r_[np.full(6, s_I), np.full(3, s_h), m]
    half = _Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0))
    return [(PAYLOAD_NAMES[k], half[k], half[k] / scale[k]) for k in np.flatnonzero(half > limit * scale)]


def _refuse_poor(poor, robot, obs_list, link, limit, chi=None, cov=None):
    names = ", ".join(f"{nm} (95 % half-width {h:.2g}, {100 * r:.0f} % of its scale)" for nm, h, r in poor)
    mass = ""
    if chi is not None and cov is not None:
        m, sm = float(chi[9]), float(np.sqrt(max(cov[9, 9], 0.0)))
        mass = f" (its estimated mass: {m:.3g} +- {sm:.2g} kg)"
        if abs(m) <= _Z95 * sm:
            # the scale the intervals are judged against is the payload's own size: none here
            raise IdentificationError(
                f"no payload found on link {link + 1}: its mass is {m:.3g} +- {sm:.2g} kg, zero within its 95 % "
                f"interval, so its centre of mass and inertia mean nothing. If the recording carried a "
                f"payload, it is lighter than the data can tell (the model's error on this recording is "
                f"of that size): a heavier payload, or a model identified on recordings of the same "
                f"motion, would show it.")
    raise IdentificationError(
        f"the recording does not identify the payload{mass}: parameters {names}: their 95 % intervals are wider "
        f"than {100 * limit:.0f} % of the payload's own size (inertia: half the trace of its inertia; first "
        f"moments: |m c|; mass: m). Why: the payload's inertia is seen only through the rotation of its "
        f"link; the joints that turn it moved over {_wrist_motion(robot, obs_list, link)}. Record with the "
        f"wrist rotating about three axes (wide, fast motion of the last three joints; docs/payload.md), "
        f"longer, or with a heavier excitation.")


def _refuse(directions, robot, obs_list, link, rtol):
    bad = []
    for r, comb in directions:
        terms = " + ".join(f"{v:+.2f} {k}" for k, v in comb.items())
        bad.append(f"{terms} (relative singular value {r:.1e})")
    names = sorted({k for _, comb in directions for k in comb}, key=PAYLOAD_NAMES.index)
    if all(r == 0.0 and len(comb) == 1 for r, comb in directions):
        # zero columns: no motion of this robot can show them
        raise IdentificationError(unfelt_message(robot, names) + ".")
    raise IdentificationError(
        f"the recording does not identify the payload parameters {', '.join(names)}: their columns "
        f"are (nearly) dependent on it, along {'; '.join(bad)} (threshold {rtol:g}). Why: the "
        f"payload's inertia is seen only through the rotation of its link; the joints that turn it "
        f"moved over {_wrist_motion(robot, obs_list, link)}. Record with the wrist rotating about "
        f"three axes (wide, fast motion of the last three joints; docs/payload.md).")


# ------------------------------------------------------------------------------- robot model
def _as_robot(robot):
    """A Robot from a Robot, a bundled name or a robot file (as dynid.identify takes it)."""
    return robot if isinstance(robot, Robot) else load_robot(robot)


def centre_held_torque(experiment):
    """The recording with its torque centred on the position samples (module doc, `zoh`).

    Parameters
    ----------
    experiment : Experiment
        A recording whose torque `tau_k` is a command held over `[t_k, t_k + T)`.

    Returns
    -------
    Experiment
        A copy with `tau_k` replaced by `(tau_k-1 + tau_k) / 2` (the first sample kept; the
        position filter's edge drops it), and a notice saying so.
    """
    import dataclasses
    tau = np.asarray(experiment.tau, dtype=float)
    out = tau.copy()
    out[1:] = 0.5 * (tau[1:] + tau[:-1])
    notices = list(getattr(experiment, "notices", [])) + [
        "torque centred on the position samples, (tau_k-1 + tau_k) / 2: the log holds each command over "
        "the next sample period (zoh)"]
    return dataclasses.replace(experiment, tau=out, notices=notices)


def _recordings(x, robot, zoh):
    """One recording or a list of them, as Experiments (torques centred with `zoh`)."""
    exps = [_as_experiment(e, robot) for e in (x if isinstance(x, (list, tuple)) else [x])]
    return [centre_held_torque(e) for e in exps] if zoh else exps


def _as_experiment(x, robot):
    x = recording_of(x)
    if isinstance(x, Experiment):
        return x
    if isinstance(x, (str, os.PathLike)):
        return load_experiment(x, robot)
    raise InputError(f"a recording must be a data file path or an Experiment, not {type(x).__name__}")


def _base_fit(model):
    """The WLS of every base parameter of an identification result, when it keeps one: the essential
    model sets the parameters it dropped to 0, and the payload would take up what they carry."""
    model = getattr(model, "result", model) if hasattr(model, "experiments") else model   # a run()
    if getattr(model, "wls", None) is not None:                      # IDIM
        return model.wls
    if getattr(model, "tau_est_dec", None) is not None:              # DIDIM: its last step's WLS
        return model.result
    return model


def _json_covariance(matrix, n):
    """The (n, n) covariance of a result JSON's WLS parameters, or None when absent or malformed."""
    if matrix is None:
        return None
    try:
        cov = np.asarray(matrix, dtype=float)
    except (TypeError, ValueError):
        return None
    if cov.shape != (n, n) or not np.all(np.isfinite(cov)):
        return None
    return 0.5 * (cov + cov.T)


def _json_rows(rows, src, key):
    """(names, values, std) of a result JSON's parameter records, each checked: a name that is
    not text, a repeated name or a value that is not a number is refused, naming the record."""
    names, values, std, seen = [], [], [], set()
    for k, r in enumerate(rows):
        name = r.get("name")
        if not isinstance(name, str) or not name:
            raise InputError(f"{src}: {key}[{k}].name is {name!r}, not a parameter name; pass the JSON written "
                             "by dynid identify --json, unedited")
        if name in seen:
            raise InputError(f"{src}: {key} lists {name} twice; pass the JSON written by dynid identify "
                             "--json, unedited")
        seen.add(name)
        row = []
        for field_, absent in (("value", np.nan), ("std", 0.0)):
            v = r.get(field_)
            if v is None:
                row.append(absent)
            elif isinstance(v, bool) or not isinstance(v, (int, float)):
                raise InputError(f"{src}: {key}[{k}] ({name}): {field_} is {v!r}, not a number; pass the JSON "
                                 "written by dynid identify --json, unedited")
            else:
                row.append(float(v))
        names.append(name)
        values.append(row[0])
        std.append(row[1])
    return names, np.array(values, dtype=float), np.array(std, dtype=float)


def _model_vector(model, robot, bp, notices):
    """(beta (b,), cov (b, b), source, the model's relative error on its own data or NaN) of an
    identified robot: a dynid result, its dict or JSON file. The covariance is the one the result
    reports (its `uncertainty` option), by either route."""
    if isinstance(model, (str, os.PathLike)):
        try:
            with open(model, encoding="utf-8") as fh:
                data = json.load(fh)
        except OSError as e:
            raise InputError(f"cannot read the identified model {model}: {e.strerror or e}") from None
        except json.JSONDecodeError as e:
            raise InputError(f"{model} is not a dynid result JSON (line {e.lineno}: {e.msg})") from None
        src = str(model)
        model = data
    else:
        # what the reader knows the model by: its method (a class name means nothing to them)
        src = f"the {getattr(model, 'method', None) or type(model).__name__} identification given as model"
    own_error = _own_error(model if isinstance(model, dict) else _base_fit(model))
    if isinstance(model, dict):
        # the WLS of every base parameter when the JSON has it (dynid identify --json), as above
        wls = model.get("wls") or {}
        rows = wls.get("parameters") or model.get("parameters")
        if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) and "name" in r for r in rows):
            raise InputError(f"{src}: no 'parameters' list of {{name, value, std}}: pass the JSON "
                             "written by dynid identify --json")
        if model.get("robot") not in (None, robot.name):
            raise InputError(f"{src} identifies robot '{model.get('robot')}', not '{robot.name}'")
        _check_signature(model.get("robot_signature"), robot, src,
                         (model.get("gravity_tilt") or {}).get("gravity"))
        names, values, std = _json_rows(rows, src, "wls.parameters" if rows is wls.get("parameters") else "parameters")
        if rows is wls.get("parameters"):
            # the WLS lists every base parameter: one missing is an edited or foreign file, not a 0
            listed = set(names)
            missing = [nm for nm in bp.names if nm not in listed]
            if missing:
                raise InputError(f"{src}: wls.parameters lacks the base parameter(s) {', '.join(missing[:5])}"
                                 f"{' ...' if len(missing) > 5 else ''} of robot '{robot.name}' (an edited file, or "
                                 "one of another robot); pass the JSON written by dynid identify --json, unedited")
        if model.get("robot_signature") is None:
            notices.append(f"{src} has no robot_signature (written by an earlier dynid, or edited): whether it "
                           f"identified this robot file's kinematics and gravity is not checked")
        given = wls.get("covariance") if rows is wls.get("parameters") else None
        cov = _json_covariance(given, len(names))
        if cov is not None:
            ev = np.linalg.eigvalsh(cov)
            if np.any(np.diag(cov) < 0) or ev[0] < -1e-9 * max(abs(ev[-1]), 1e-300):
                # a negative variance would give the payload sigma 0 and intervals of zero width
                raise InputError(f"{src}: wls.covariance is not a covariance (smallest eigenvalue "
                                 f"{ev[0]:.3g}: not positive semi-definite); pass the JSON written by "
                                 "dynid identify --json, unedited")
        if cov is None:
            # σ alone: the correlations of the base parameters are lost, and with them the cancellation
            # of their errors in the payload's columns (its σ is then far too wide)
            cov = np.diag(std ** 2)
            why = ("has no WLS block (a result of method " + str(model.get("method", "?")) + ")"
                   if not wls.get("parameters") else
                   "has no covariance of its WLS parameters (written by an earlier dynid)" if given is None else
                   f"has a wls.covariance that is not a finite {len(names)} x {len(names)} matrix")
            # without the correlations the payload's σ is usually too wide; with the model's parameters
            # alone (an essential set) the base parameters it left out count as exactly 0, which can
            # make it too narrow instead: either way it is not the payload's σ
            notices.append(f"{src} {why}: the robot's σ were propagated without their correlations"
                           + ("" if rows is wls.get("parameters") or len(names) >= bp.n_base else
                              f", and the base parameters it does not list ({bp.n_base - len(names)}) as exactly 0")
                           + ", so the payload's σ may be too wide or too narrow; identify the robot with "
                           "IDIM or DIDIM (dynid identify --json) and pass that JSON")
    else:
        inner = getattr(model, "result", model) if hasattr(model, "experiments") else model   # a run()
        _check_signature(getattr(inner, "robot_signature", None), robot, src,
                         getattr(getattr(inner, "robot", None), "gravity", None))
        model = _base_fit(model)
        try:
            names = list(model.names)
            values = np.asarray(model.params, dtype=float)
            cov = np.asarray(model.cov, dtype=float)
        except AttributeError:
            raise InputError("model must be a dynid identification result (e.g. from dynid.identify), "
                             f"its to_dict() or the path of its JSON, not {type(model).__name__}") from None
    index = {nm: k for k, nm in enumerate(bp.names)}
    unknown = [nm for nm in names if nm not in index]
    if unknown:
        raise InputError(f"{src}: parameter(s) {', '.join(unknown[:5])} are not base parameters of robot "
                         f"'{robot.name}': identify the robot with dynid identify (IDIM or DIDIM) and "
                         "pass that result")
    if not np.all(np.isfinite(values)):
        raise InputError(f"{src}: the identified parameters hold NaN or infinite values")
    P = np.zeros((bp.n_base, len(names)))
    P[[index[nm] for nm in names], np.arange(len(names))] = 1.0
    return P @ values, P @ cov @ P.T, src, own_error


def _check_signature(signature, robot, src, gravity=None):
    """Refuse a model identified on a robot file of other kinematics, gravity, couplings or
    drive gains than `robot`'s (the same name does not make the same robot); a model written
    without a signature (an earlier dynid) is taken as it is. `gravity`: the model's own (an
    estimated base tilt), to say so when it is the only difference."""
    if not isinstance(signature, str) or not signature or signature == model_signature(robot):
        return
    where = f" ({robot.source})" if robot.source else ""
    try:
        g = np.asarray(gravity, dtype=float).reshape(3)
    except (TypeError, ValueError):
        g = None
    if g is not None and np.all(np.isfinite(g)) and signature == model_signature(dataclasses.replace(robot, gravity=g)):
        raise InputError(f"{src} was identified with an estimated base tilt (--gravity-tilt: gravity "
                         f"[{', '.join(f'{v:.6g}' for v in g)}] m/s^2), not the gravity of the robot given{where}: "
                         "put that vector in the robot file's gravity and give that file")
    raise InputError(f"{src} was identified on a robot '{robot.name}' whose kinematics, gravity, couplings or "
                     f"drive gains differ from those of the robot given{where}: its parameters do not apply "
                     "to this recording. Give the robot file the model was identified with, or identify the "
                     "robot again with this one (dynid identify --json)")


def _own_error(model) -> float:
    """The identified model's relative error ||Y - W chi|| / ||Y|| on its own data (its WLS, whose
    parameters the payload takes, where the result has one), NaN if unknown."""
    if isinstance(model, dict):
        value = (model.get("wls") or {}).get("rel_error", model.get("rel_error"))
    else:
        value = getattr(model, "rel_error", None)
    try:
        value = float(value)
    except (TypeError, ValueError):
        return math.nan
    return value if math.isfinite(value) and value >= 0 else math.nan


# ------------------------------------------------------------------------------- results
def _com(chi, cov):
    """Centre of mass c = h / m and its covariance (delta method)."""
    m, h = chi[9], chi[6:9]
    c = h / m
    J = np.zeros((3, 10))
    J[:, 6:9] = np.eye(3) / m
    J[:, 9] = -h / m ** 2
    return c, J @ cov @ J.T


def _inertia_at_com(chi):
    m, h = chi[9], chi[6:9]
    I_o = np.array([[chi[0], chi[1], chi[2]], [chi[1], chi[3], chi[4]], [chi[2], chi[4], chi[5]]])
    c = h / m
    return inertia_about_com(m, c, I_o)


#: robot fixed: the loaded recording's relative error with the payload above MISFIT_RATIO times
#: the model's own, and above MISFIT_FLOOR, says the model does not describe the recording
#: (the simulated TX40 with a 2 kg payload: 0.19 % against the model's own 0.20 %; with a robot
#: file whose joint 3 is 0.1 m off, 7.5 %; with joint 6's torque lost, 17 %)
MISFIT_RATIO, MISFIT_FLOOR = 3.0, 0.05


@dataclass(eq=False, repr=False)
class PayloadResult(ParameterResults):
    """The identified payload: ten parameters about the payload frame, with their uncertainty.

    Attributes
    ----------
    method : str
        `"payload-robot-fixed"` (robot fixed) or `"payload-global"`.
    names : list[str]
        XXL XYL XZL YYL YZL ZZL (kg m^2, about the payload frame's origin), MXL MYL MZL
        (kg m), ML (kg).
    chi, cov : ndarray
        Estimate and its HAC covariance (module doc).
    link : int
        0-based link carrying the payload; `R`, `p` the payload frame in it, `T` the
        map to the link frame (`transform_matrix`).
    physical : PhysicalPayload or None
        The physically consistent estimate (`physical=True`).
    robot_params : IdentificationResult or None
        The robot's base parameters of the global route.
    """

    method: str
    names: list
    chi: np.ndarray
    cov: np.ndarray
    robot_name: str
    link: int
    frame: str
    R: np.ndarray
    p: np.ndarray
    T: np.ndarray
    joint_sigma: np.ndarray
    rel_error: float
    n_rows: int
    hac_lags: int
    singular_ratio: np.ndarray
    sources: list
    settings: dict = field(default_factory=dict)
    physical: PhysicalPayload | None = None
    robot_params: object = None
    model_source: str = ""
    notices: list = field(default_factory=list)
    loaded_error: float = math.nan
    model_error: float = math.nan

    # ---------------------------------------------------------------- derived
    @property
    def mass(self):
        """(value, std) of the mass, kg."""
        return float(self.chi[9]), float(math.sqrt(max(self.cov[9, 9], 0.0)))

    @property
    def com(self):
        """Centre of mass in the payload frame (m), (3,)."""
        return _com(self.chi, self.cov)[0]

    @property
    def com_std(self):
        """Standard deviations of the centre of mass (m), delta method."""
        return np.sqrt(np.maximum(np.diag(_com(self.chi, self.cov)[1]), 0.0))

    @property
    def inertia_com(self):
        """Inertia tensor about the centre of mass, payload-frame axes (kg m^2), (3, 3)."""
        return _inertia_at_com(self.chi)

    def as_link(self, name="payload", constrained=True) -> dict:
        """The `payload=` argument of urdf_text / mjcf_text: the (constrained, if fitted) payload
        about its link's frame, `{"link": 1-based, "values": (10,), "name": name}`."""
        chi = self.physical.chi if (constrained and self.physical is not None) else self.chi
        return {"link": self.link + 1, "values": self.T @ chi, "name": name}

    @property
    def model_misfit(self) -> bool:
        """Robot fixed: the model leaves far more of the loaded recording's torque unexplained,
        with the payload, than of its own data (`MISFIT_RATIO`, `MISFIT_FLOOR`)."""
        return (math.isfinite(self.loaded_error) and math.isfinite(self.model_error)
                and self.loaded_error > max(MISFIT_RATIO * self.model_error, MISFIT_FLOOR))

    def verdict(self) -> str:
        m, sm = self.mass
        c, sc = self.com, self.com_std
        cons = link_consistency(self.chi)
        if self.model_misfit:
            return (f"NOT identified: the robot model does not describe the loaded recording: with the "
                    f"payload it leaves {percent(self.loaded_error)} of the torque unexplained against "
                    f"{percent(self.model_error)} on its own data, so the payload (mass {m:.4g} kg) takes "
                    f"up the model's error; check that --model was identified on this robot, with this "
                    f"robot file and the same processing, and that it predicts recordings it was not "
                    f"fitted to (its held-out error); or use --unloaded recordings of the same motion")
        text = (f"payload on link {self.link + 1} ({self.frame}): mass {m:.4g} +- {sm:.2g} kg, centre of "
                f"mass ({', '.join(f'{1e3 * x:.1f}' for x in c)}) +- ({', '.join(f'{1e3 * x:.1f}' for x in sc)}) mm; "
                f"all ten parameters identified: each 95 % half-width within "
                f"{100 * self.settings.get('max_rel_halfwidth', MAX_REL_HALFWIDTH):.0f} % of "
                f"its scale (the inertia's half trace, |m c|, m: a %\u03c3 of a near-zero entry is large), smallest "
                f"relative singular value {self.singular_ratio.min():.2g}; ")
        text += ("physically consistent as identified" if cons["consistent"] else
                 "NOT physically consistent as identified (see the constrained fit)")
        if self.physical is not None:
            text += f"; constrained fit chi^2 distance {self.physical.delta:.3g}"
            p_box = float(stats.chi2.sf(self.physical.delta, len(self.names)))
            if cons["consistent"] and self.physical.com_box is not None and p_box < 0.01:
                # the free estimate is a body: only the box can have moved the constrained one
                text += (f" ({p_phrase(p_box)}): the data do NOT fit the --com-box: their centre of mass is "
                         f"outside it, and the box pulls the constrained payload (mass {self.physical.chi[9]:.4g} "
                         f"kg) away from it; check the box's frame and units (m)")
        return text

    def summary(self) -> str:
        rule = "=" * 78
        lines = [f"Payload identification ({self.method}) of robot '{self.robot_name}'".center(78), rule,
                 f"recordings: {' + '.join(self.sources)}",
                 f"frame: {self.frame} (link {self.link + 1}; origin {_vec3(self.p)} m in the link frame)",
                 f"rows: {self.n_rows}, rel. error of the fit {percent(self.rel_error)}, "
                 f"HAC window {self.hac_lags} decimated samples", "-" * 78]
        ci = self.conf_int().to_numpy()
        lines += parameter_table(self.names, [
            ("value", self.chi, lambda x: f"{x:.6g}"), ("sigma", self.bse.to_numpy(), lambda x: f"{x:.3g}"),
            ("95 % low", ci[:, 0], lambda x: f"{x:.5g}"), ("95 % high", ci[:, 1], lambda x: f"{x:.5g}")])
        lines.append("-" * 78)
        c, sc = self.com, self.com_std
        lines.append("centre of mass (m): " + ", ".join(f"{x:.5g} +- {s:.2g}" for x, s in zip(c, sc)))
        Ic = self.inertia_com
        lines.append("inertia about the centre of mass (kg m²): principal moments "
                     + ", ".join(f"{x:.4g}" for x in np.linalg.eigvalsh(0.5 * (Ic + Ic.T))))
        if self.physical is not None:
            lines += ["-" * 78, f"{'constrained vs free':<20}{'constrained':>16}{'free':>16}"]
            for nm, a, b in zip(self.names, self.physical.chi, self.chi):
                lines.append(f"{nm:<20}{a:>16.6g}{b:>16.6g}")
            lines.append(f"chi^2 distance {self.physical.delta:.3g}; active constraints: "
                         f"{', '.join(self.physical.active) or 'none'}")
        lines += [rule, "Verdict: " + self.verdict()]
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        ci = self.conf_int().to_numpy()
        c, sc = self.com, self.com_std
        return json_safe({
            "method": self.method, "robot": self.robot_name, "sources": self.sources,
            "model": self.model_source, "link": self.link + 1, "frame": self.frame,
            "frame_origin_m": self.p, "frame_axes": self.R,
            "parameters": [{"name": nm, "value": v, "std": s, "rel_std_percent": r, "lower_95": lo, "upper_95": hi,
                            "unit": u}
                           for nm, v, s, r, (lo, hi), u in zip(self.names, self.chi, self.bse.to_numpy(),
                                                               self.rel_std.to_numpy(), ci, UNITS)],
            "covariance": self.cov,
            "mass_kg": self.mass[0], "com_m": c, "com_std_m": sc,
            "inertia_com_kgm2": self.inertia_com,
            "link_frame_values": payload_link_values(self),
            "consistency": link_consistency(self.chi),
            "physical": None if self.physical is None else self.physical.to_dict(),
            "robot_parameters": None if self.robot_params is None else [
                {"name": n, "value": v, "std": s} for n, v, s in
                zip(self.robot_params.names, self.robot_params.chi, self.robot_params.bse.to_numpy())],
            "joint_sigma": self.joint_sigma, "rel_error": self.rel_error, "n_rows": self.n_rows,
            "loaded_error": self.loaded_error, "model_error": self.model_error,
            "hac_lags": self.hac_lags, "singular_ratio": self.singular_ratio,
            "settings": self.settings, "verdict": self.verdict(), "notices": self.notices,
            "versions": versions(),
        })


def _vec3(v):
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


# ------------------------------------------------------------------------------- entry point
def identify_payload(loaded, robot, *, model=None, unloaded=None, frame="flange", offset=None,
                     settings=None, physical=False, com_box=None, zoh=False, rank_rtol=RANK_RTOL,
                     max_rel_halfwidth=MAX_REL_HALFWIDTH):
    """Identify the payload's ten inertial parameters (module doc), robot fixed or global.

    Parameters
    ----------
    loaded : path, Experiment, or a list of them
        Recording(s) with the payload.
    robot : Robot, bundled name or robot file
    model : identification result, its dict, or the path of its JSON, optional
        The identified robot (its base parameters): the robot-fixed route.
    unloaded : path, Experiment, or a list of them, optional
        Recording(s) without the payload: the global route. Exactly one of `model`
        and `unloaded`.
    frame : str or int
        The link carrying the payload: `"flange"` (last link, default), a joint name
        or a 1-based link number.
    offset : dict, optional
        `{"xyz": ..., "rpy": ...}` of the payload frame in that link's frame.
    settings : dict, optional
        IDIM's processing overrides (fc_position, nd, ...), taken for every recording.
    physical : bool
        Also the physically consistent payload (`physical_payload`).
    com_box : ((3,), (3,)), optional
        With `physical`: a box holding the centre of mass (payload frame, m).
    zoh : bool
        The torques are commands held over the next sample period (a controller's log):
        centre them on the position samples (`centre_held_torque`; module doc). On the
        robot-fixed route the model must come from centred torques too.
    rank_rtol : float
        Identifiability threshold of the columns (RANK_RTOL).
    max_rel_halfwidth : float
        A parameter whose 95 % half-width exceeds this fraction of its scale is refused
        (MAX_REL_HALFWIDTH; `inf` turns the check off).

    Returns
    -------
    PayloadResult

    Raises
    ------
    InputError
        Not exactly one of `model` / `unloaded`; a frame that is not a link.
    IdentificationError
        The recordings do not identify every payload parameter (names them and says why).

    Examples
    --------
    >>> r = identify_payload("loaded.toml", "tx40", model="identified.json")  # doctest: +SKIP
    >>> r.mass, r.com, r.conf_int()                                           # doctest: +SKIP
    """
    robot = _as_robot(robot)
    rank_rtol = check_range("rank_rtol", rank_rtol)
    if not (isinstance(max_rel_halfwidth, float) and max_rel_halfwidth == math.inf):
        max_rel_halfwidth = check_range("max_rel_halfwidth", max_rel_halfwidth)
    if (model is None) == (unloaded is None):
        raise InputError("give either model= (an identified robot: the robot-fixed route, --model) or "
                         "unloaded= (recordings without the payload: the global route, --unloaded), "
                         "exactly one")
    link, R, p = payload_frame(robot, frame, offset)
    T = transform_matrix(R, p)
    bp = base_parameters(robot)
    names = list(PAYLOAD_NAMES)
    load_list = _recordings(loaded, robot, zoh)
    if not load_list:
        raise InputError("no loaded recording given")
    first = _observe(load_list[0], robot, bp, link, T, settings)
    obs_l = [first] + [_observe(e, robot, bp, link, T, first.settings) for e in load_list[1:]]
    sources = [str(e.source) for e in load_list]
    notices = [n for e in load_list for n in getattr(e, "notices", [])]
    Wp = np.concatenate([o.Wp for o in obs_l])
    mask_l = np.concatenate([o.mask for o in obs_l])
    directions, ratio = _identifiability(Wp, mask_l, names, rank_rtol)
    if directions:
        _refuse(directions, robot, obs_l, link, rank_rtol)
    Wb = np.concatenate([o.Wb for o in obs_l])
    tau = np.concatenate([o.tau for o in obs_l])
    if model is not None:
        chi, cov, fit, lags, model_source, model_fit = _fit_with_robot_fixed(model, robot, bp, Wp, Wb, tau,
                                                                              mask_l, names, notices)
        if not math.isfinite(model_fit[1]):
            notices.append(f"{model_source} does not give its relative error on its own data: whether it "
                           "describes the loaded recording was not checked (pass dynid identify's result or JSON)")
        robot_params, method = None, "payload-robot-fixed"
        notices.append(f"robot fixed: {model_source}; its parameters' uncertainty is propagated")
    else:
        un_list = _recordings(unloaded, robot, zoh)
        obs_u = [_observe(e, robot, bp, link, T, first.settings) for e in un_list]
        sources += [f"{e.source} (unloaded)" for e in un_list]
        chi, cov, fit, lags, robot_params = _fit_with_unloaded(obs_u, bp, Wp, Wb, tau, mask_l, names)
        model_source, method, model_fit = "", "payload-global", (math.nan, math.nan)
    cov = 0.5 * (cov + cov.T)
    poor = _poorly_identified(chi, cov, max_rel_halfwidth)
    if poor:
        _refuse_poor(poor, robot, obs_l, link, max_rel_halfwidth, chi, cov)
    res = PayloadResult(method=method, names=names, chi=chi, cov=cov, robot_name=robot.name, link=link,
                        frame=str(frame if frame is not None else "flange"), R=R, p=p, T=T,
                        joint_sigma=fit.joint_sigma, rel_error=fit.rel_error, n_rows=fit.n_rows,
                        hac_lags=lags, singular_ratio=ratio, sources=sources,
                        settings=dict(first.settings, zoh=bool(zoh), max_rel_halfwidth=max_rel_halfwidth),
                        robot_params=robot_params,
                        model_source=model_source, notices=notices + first.notices,
                        loaded_error=model_fit[0], model_error=model_fit[1])
    if not chi[9] > 0:
        raise IdentificationError(f"the identified payload mass is {chi[9]:.3g} kg (<= 0): the loaded "
                                  "recording does not show a payload, or the robot model does not fit it")
    if physical:
        res.physical = physical_payload(chi, cov, com_box=com_box)
    elif com_box is not None:
        raise InputError("com_box is an option of the physically consistent payload: pass physical=True "
                         "(on the command line: --com-box needs --physical)")
    return res


def _fit_with_robot_fixed(model, robot, bp, Wp, Wb, tau, mask, names, notices):
    """The payload's WLS on the loaded recordings' torque minus the robot's known model
    `model` (its base parameters beta): (chi, cov, fit, HAC lags, the model's source). The
    robot's own covariance is propagated: the estimate moves by G d(beta)."""
    beta, cov_beta, model_source, own_error = _model_vector(model, robot, bp, notices)
    y = tau - Wb @ beta
    chi, cov, fit, lags = _wls_hac(Wp, y, names, mask)
    w = np.where(mask, 1.0 / fit.joint_sigma[None, :] ** 2, 0.0)
    A = np.linalg.pinv(np.einsum("tjp,tj,tjq->pq", Wp, w, Wp))
    G = -A @ np.einsum("tjp,tj,tjq->pq", Wp, w, Wb)
    m = np.broadcast_to(mask, tau.shape)
    loaded_error = float(np.linalg.norm((y - Wp @ chi)[m]) / max(np.linalg.norm(tau[m]), 1e-300))
    return chi, cov + G @ cov_beta @ G.T, fit, lags, model_source, (loaded_error, own_error)


def _fit_with_unloaded(obs_u, bp, Wp, Wb, tau, mask, names):
    """The global route: the robot's base parameters and the payload's in one WLS of the
    unloaded recordings (`obs_u`, payload columns zero) stacked on the loaded ones:
    (chi, cov of the payload, fit, HAC lags, the robot's IdentificationResult)."""
    Wu = np.concatenate([o.Wb for o in obs_u])
    W3 = np.concatenate([np.concatenate([Wu, np.zeros(Wu.shape[:2] + (10,))], axis=2),
                         np.concatenate([Wb, Wp], axis=2)])
    tau_all = np.concatenate([np.concatenate([o.tau for o in obs_u]), tau])
    mask_all = np.concatenate([np.concatenate([o.mask for o in obs_u]), mask])
    all_names = list(bp.names) + names
    try:
        est, cov_all, fit, lags = _wls_hac(W3, tau_all, all_names, mask_all)
    except IdentificationError as e:
        raise IdentificationError(f"the stacked unloaded and loaded recordings do not identify the "
                                  f"robot's base parameters with the payload's: {e}") from None
    b = bp.n_base
    robot_params = IdentificationResult(
        method="WLS (global, with payload)", names=list(bp.names), chi=est[:b], cov=cov_all[:b, :b],
        sigma_rho=fit.sigma_rho, residual=fit.residual, rel_error=fit.rel_error, rms=fit.rms,
        joint_rel_error=fit.joint_rel_error, cond=fit.cond, n_samples=fit.n_samples,
        n_joints=fit.n_joints, n_rows=fit.n_rows, joint_sigma=fit.joint_sigma)
    return est[b:], cov_all[b:, b:], fit, lags, robot_params


def parameter_frame(result) -> pd.DataFrame:
    """Table (value, std, unit) of a payload result."""
    return pd.DataFrame({"value": result.chi, "std": result.bse.to_numpy(), "unit": UNITS},
                        index=pd.Index(result.names, name="parameter"))
