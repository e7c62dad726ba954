"""Drive gains identified with the dynamic parameters, from a payload of known mass.

Many arms log motor currents (or control signals) `u`, not torques: `tau_j = g_j u_j`
with `g_j` the drive gain (torque constant times gear ratio), known only roughly. A
recording without a payload fixes the parameters only up to one scale per joint: `g_j`
times the parameters is all the data see. A payload of known mass fixes the scale
(Gautier & Briot, "Global identification of joint drive gains and dynamic parameters of
robots", 2014): stack the recordings without and with the payload and move the known
part of the payload's torque to the right-hand side,

    W_b beta + W_pu pi_u - diag(tau_log) k  =  - W_pk pi_k          (loaded rows)
    W_b beta             - diag(tau_log) k  =  0                    (unloaded rows)

`tau_log` the torque the recording holds (computed with the robot file's gains
`g_file`: `tau_log = g_file u`), `k_j = g_j / g_file_j` the correction of joint
`j`'s gain (a column `-tau_log_j` on that joint's rows), `pi_k` the payload's known
parameters (its mass; with `com` also its first moments `m c`) and `pi_u` the rest.
Solved as written, least squares would shrink `k`: the noisy logged torque sits in a
regressor column and the unloaded rows are homogeneous (errors in variables; Gautier & Briot
use total least squares for it). Here the same model is written with the logged torque as the
dependent variable, `tau_log_j = a_j (W_bj beta + W_puj pi_u + W_pkj pi_k)`, `a_j = 1 / k_j`
(1 on the joints whose gain is not identified), and solved by Gauss-Newton from the fit with the
file's gains, each step the per-joint weighted least squares of eq. (16) (Gautier, Janot &
Vandanjon 2010); the covariance is the HAC sandwich of `dynid.analysis.estimators.payload`
at the solution, `k` and its standard deviation by the delta method.

Low speeds. The scale of each gain rests on the known payload's torque, small beside the
robot's, so a torque the model lacks biases the gains in proportion to its size over that
torque, and more data do not shrink it. Such a torque sits at low speed: eq. (3)'s Coulomb
term `Fc sign(qd)` is a step, a real joint's friction a smooth (Stribeck, pre-sliding)
transition some hundredths of rad/s wide. IDIM's default dead zone (1 % of each joint's peak
speed) leaves part of it in the equations, and the noise moves it onto the gains through the
per-joint weights (comparable weights let the misfit of joints 2-3 bend the parameters the
joints share). Here the dead zone is `DEAD_ZONE_FRACTION` (5 %) of each joint's peak speed in
the first loaded recording unless the settings give `qd_threshold`. Measured on the
independent TX40 plant (friction `Fc tanh(qd / 0.01)`), seed 311, one motion and 12 draws of
the sensor noise: mean gain errors -0.88 / -1.01 / -1.03 / -0.87 % on joints 1, 4, 5, 6 with
IDIM's dead zone (stated sigma 0.5-0.8 %), -0.22 / -0.58 / -0.18 / -0.41 % with 5 %; 24 further
draws: -0.78 / -0.81 / -1.04 / -0.82 % and -0.04 / -0.12 / -0.12 / -0.10 %
(benchmarks/payload_gains_probe.py --draws, docs/payload.md).

What the known mass identifies: a mass at the wrist centre (where the last three axes
meet, as on the TX40) puts no torque on joints 4-6, and its gravity none on joint 1 (a
vertical axis). The wrist rows alone fix the wrist gains only up to one scale shared with the
payload's other parameters (`a_w / s`, `s pi_u` leave them unchanged); that scale comes from
the payload's inertia and first moments as the arm joints see them (their torque about the
wrist axes reaches joints 1-3 too), and joint 1's gain from the mass's inertial torque. So
the arm must accelerate in the loaded recordings, and the 95 % half-width of those gains
falls as one over the square root of their length (docs/payload.md, Drive gains: measured,
2 x 10 s with a slow arm 1.0-1.55 %, 3 x 30 s with the arm at 0.3 Hz 0.1-0.6 % for a 1.2 kg
payload 28 mm from the wrist centre). The known centre of mass (`com`) adds the wrist
joints' gravity torque of `m c`, small for such a payload (measured: the same half-widths
within 0.1 %). The rank check names the gains the data cannot fix.

The experiment description's `[currents]` section gives the gains the torque column is
computed with (`drive_gains`, the robot file's by default) and which of them are to be
identified (`identify_gains = true` or a list of joints; docs/formats.md): both are read
from the recordings' `meta`. The argument `joints` overrides the description; with neither,
every joint's gain is identified. Recordings computed with different gains are brought to
the first loaded recording's gains before the fit (one factor `k_j` per joint).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.payload import (
    PAYLOAD_NAMES,
    _as_robot,
    _hac_lags,
    _observe,
    _recordings,
    _sandwich,
    payload_frame,
    transform_matrix,
)
from dynid.analysis.processing.observation import full_rate
from dynid.analysis.processing.signals import dead_zone_thresholds
from dynid.analysis.results import ParameterResults, notices_block, parameter_table, percent
from dynid.dynamics.base_parameters import base_parameters
from dynid.errors import IdentificationError, InputError
from dynid.provenance import json_safe, versions
from dynid.ranges import check_joints

__all__ = ["DEAD_ZONE_FRACTION", "WEAK_GAIN_HALFWIDTH", "DriveGainResult", "identify_drive_gains"]

#: dead zone of the drive-gain fit: this fraction of each joint's peak speed (module doc, Low speeds)
DEAD_ZONE_FRACTION = 0.05
#: a gain whose 95 % half-width exceeds this fraction of it gets a notice (weakly fixed by the payload)
WEAK_GAIN_HALFWIDTH = 0.01


@dataclass(eq=False, repr=False)
class DriveGainResult(ParameterResults):
    """Identified drive gains `g1..gn` (N m per unit of the logged signal) and the rest.

    `chi`/`cov` are the gains of the joints in `joints` (1-based); `factor` the
    correction `k = g / g_file`; `g_file` the robot file's gains; `other` the names,
    values and standard deviations of the robot's base parameters and the payload's unknown
    parameters identified with them (scaled to the identified gains).
    """

    method = "drive-gains"
    names: list
    chi: np.ndarray
    cov: np.ndarray
    joints: list
    g_file: np.ndarray
    factor: np.ndarray
    factor_std: np.ndarray
    known: dict
    other: dict
    robot_name: str
    sources: list
    rel_error: float
    hac_lags: int
    notices: list = field(default_factory=list)

    @property
    def moved_percent(self):
        """How far each gain moved from the robot file's value, % (100 (k - 1))."""
        return 100.0 * (self.factor - 1.0)

    def verdict(self) -> str:
        worst = int(np.argmax(np.abs(self.moved_percent)))
        return (f"{len(self.joints)} drive gain(s) identified with a known payload "
                f"({', '.join(self.known)}); the largest change from the robot file is joint "
                f"{self.joints[worst]}: {self.moved_percent[worst]:+.2f} % "
                f"(+- {100 * self.factor_std[worst]:.2f} %)")

    def summary(self) -> str:
        lines = [f"Drive gains of robot '{self.robot_name}' (Gautier & Briot 2014, known payload)".center(78),
                 "=" * 78, f"recordings: {' + '.join(self.sources)}",
                 "known payload: " + ", ".join(f"{k} = {_fmt(v)}" for k, v in self.known.items()),
                 f"HAC window {self.hac_lags} decimated samples; rel. error {percent(self.rel_error)}", "-" * 78]
        ci = self.conf_int().to_numpy()
        lines += parameter_table(self.names, [
            ("file gain", self.g_file, lambda x: f"{x:.6g}"), ("identified", self.chi, lambda x: f"{x:.6g}"),
            ("sigma", self.bse.to_numpy(), lambda x: f"{x:.3g}"), ("moved %", self.moved_percent, lambda x: f"{x:.3f}"),
            ("95 % low", ci[:, 0], lambda x: f"{x:.5g}"), ("95 % high", ci[:, 1], lambda x: f"{x:.5g}")],
            prismatic=self._prismatic())
        lines += ["=" * 78, "Verdict: " + self.verdict()]
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        ci = self.conf_int().to_numpy()
        return json_safe({
            "method": self.method, "robot": self.robot_name, "sources": self.sources,
            "known_payload": self.known,
            # the interface's records (as every result's); `gains` below adds the file's values
            "parameters": self._records(),
            "gains": [{"joint": j, "name": nm, "file": gf, "value": v, "std": s, "factor": f,
                       "factor_std": fs, "moved_percent": mp, "lower_95": lo, "upper_95": hi}
                      for j, nm, gf, v, s, f, fs, mp, (lo, hi) in
                      zip(self.joints, self.names, self.g_file, self.chi, self.bse.to_numpy(), self.factor,
                          self.factor_std, self.moved_percent, ci)],
            "covariance": self.cov, "other_parameters": self.other, "rel_error": self.rel_error,
            "hac_lags": self.hac_lags, "verdict": self.verdict(), "notices": self.notices,
            "versions": versions()})


def _fmt(v):
    return ", ".join(f"{x:.4g}" for x in np.atleast_1d(v))


def _gauss_newton(X, tau, known_tau, gcol, names, mask, max_iter=30, tol=1e-10):
    """Least squares of `tau_j = a_j (X_j theta + known_j)` (`a_j = 1 / k_j` on the joints
    `gcol`, 1 elsewhere), the noise on the logged torque (the dependent variable).

    The linear form of the module doc puts the noisy logged torque in a regressor column, and
    least squares then shrinks k (errors in variables: the unloaded rows are homogeneous); in
    this form the noise is where least squares expects it. Gauss-Newton from the fit with
    the file's gains (a = 1); per-joint weights from the residual, HAC covariance at the
    solution. Returns (theta and a, cov, the residual's relative error, HAC window).
    """
    M, n, p = X.shape
    g = len(gcol)
    gn = list(names) + [f"a{j + 1}" for j in gcol]
    a = np.ones(n)
    fit = ls.ols(X, tau - known_tau, names, row_mask=mask)
    theta = fit.chi

    def jac_res(theta, a):
        base = X @ theta + known_tau                        # (M, n)
        J = np.zeros((M, n, p + g))
        J[:, :, :p] = X * a[None, :, None]
        J[:, gcol, p + np.arange(g)] = base[:, gcol]
        return J, tau - a[None, :] * base

    for _ in range(max_iter):
        J, r = jac_res(theta, a)
        e = np.where(mask, r, 0.0)
        sig = np.sqrt((e ** 2).sum(axis=0) / np.maximum(mask.sum(axis=0) - 1, 1))
        step = ls.wls(J, r, gn, row_mask=mask, joint_sigma=sig)
        theta = theta + step.chi[:p]
        a[gcol] = a[gcol] + step.chi[p:]
        if np.max(np.abs(step.chi[p:])) < tol:
            break
    J, r = jac_res(theta, a)
    e = np.where(mask, r, 0.0)
    sig = np.sqrt((e ** 2).sum(axis=0) / np.maximum(mask.sum(axis=0) - 1, 1))
    lags = _hac_lags(r, mask)
    cov = _sandwich(J, r, mask, sig, lags)
    # ||residual|| / ||logged torque|| on the rows used, as every result's rel_error
    used_tau = np.where(mask, tau, 0.0)
    rel_error = float(np.sqrt((e ** 2).sum() / (used_tau ** 2).sum()))
    return np.concatenate([theta, a[gcol]]), 0.5 * (cov + cov.T), rel_error, lags


def _checked_mass(mass):
    """The payload's mass as a float, > 0 kg."""
    try:
        mass = float(mass)
    except (TypeError, ValueError):
        raise InputError(f"payload mass must be a number in kg, got {mass!r} (--mass)") from None
    if not (math.isfinite(mass) and mass > 0):
        raise InputError(f"payload mass must be > 0 kg, got {mass!r} (--mass): the known mass is what "
                         "fixes the scale of the drive gains")
    return mass


def _checked_joints(joints, n):
    """The 1-based joints whose gain is identified (default all `n`): distinct, in 1..n."""
    return check_joints(joints, n, option="joints (whose drive gain is identified)")


def _known_payload(mass, com):
    """The payload's known parameters `{name: value}`: its mass, with `com` its first moments too."""
    known = {"ML": mass}
    if com is not None:
        c = np.asarray(com, dtype=float).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InputError(f"com must be the payload's centre of mass [x, y, z] in m, got {com!r}")
        known.update({"MXL": mass * c[0], "MYL": mass * c[1], "MZL": mass * c[2]})
    return known


def _described_joints(exps):
    """The 1-based joints the descriptions mark `identify_gains` (one list shared by all), or None."""
    marked = {tuple(e.meta["identify_gains"]) for e in exps
              if isinstance(getattr(e, "meta", None), dict) and e.meta.get("identify_gains")}
    if len(marked) > 1:
        raise InputError("the recordings' descriptions mark different joints with identify_gains ("
                         + "; ".join(str(list(m)) for m in sorted(marked)) + "): mark the same joints in "
                         "every [currents] section, or give the joints explicitly (joints=, --gains 1,2,3)")
    return list(marked.pop()) if marked else None


def _logged_gains(e):
    """The gains the recording's torque column was computed with (description's), or None."""
    g = e.meta.get("drive_gains") if isinstance(getattr(e, "meta", None), dict) else None
    return None if g is None else np.asarray(g, dtype=float)


def _common_gains(exps, robot):
    """(reference gains, experiments with their torques brought to those gains).

    The reference is the first loaded recording's description's gains (the robot file's when
    it has none): a recording computed with other gains is rescaled by g_ref / g_rec, so one
    factor k_j per joint holds for all."""
    import dataclasses
    ref = next((g for g in map(_logged_gains, exps) if g is not None), None)
    ref = np.asarray(robot.drive_gains, dtype=float) if ref is None else ref
    out = []
    for e in exps:
        g = _logged_gains(e)
        if g is not None and g.shape == ref.shape and not np.allclose(g, ref, rtol=1e-12, atol=0):
            e = dataclasses.replace(e, tau=np.asarray(e.tau, dtype=float) * (ref / g))
        out.append(e)
    return ref, out


def _gain_settings(experiment, robot, settings):
    """IDIM's settings with the drive gains' dead zone (module doc, Low speeds): `DEAD_ZONE_FRACTION`
    of each joint's peak filtered speed in `experiment`, unless `settings` give `qd_threshold`.
    Returns (settings, notice or None)."""
    if settings and settings.get("qd_threshold") is not None:
        return settings, None
    settings = dict(settings or {})
    qd = full_rate(experiment, robot, experiment.q, dict(settings, qd_threshold=0.0)).qd
    thr = dead_zone_thresholds(qd, "auto", fraction=DEAD_ZONE_FRACTION)
    settings["qd_threshold"] = [float(v) for v in thr]
    return settings, (f"drive gains: equations below {100 * DEAD_ZONE_FRACTION:g} % of each joint's peak speed "
                      f"dropped (" + ", ".join(f"{v:.3g}" for v in thr) + " rad/s; IDIM's default 1 %): an "
                      "unmodelled smooth Coulomb transition there biases the gains (settings qd_threshold "
                      "overrides)")


def _stacked_model(obs_u, obs_l, known, bp):
    """The unloaded then loaded rows stacked: regressor `X` (base and unknown payload columns,
    the latter zero on unloaded rows), logged torque, known payload torque, row mask, names."""
    kidx = [PAYLOAD_NAMES.index(k) for k in known]
    uidx = [k for k in range(10) if k not in kidx]
    pi_k = np.array([known[PAYLOAD_NAMES[k]] for k in kidx])
    obs = obs_u + obs_l
    Wb = np.concatenate([o.Wb for o in obs])
    Wp = np.concatenate([o.Wp for o in obs])
    tau = np.concatenate([o.tau for o in obs])
    mask = np.concatenate([o.mask for o in obs])
    on = np.zeros(tau.shape[0], dtype=bool)
    on[sum(o.tau.shape[0] for o in obs_u):] = True          # loaded rows
    Wpu = Wp[:, :, uidx] * on[:, None, None]
    known_tau = (Wp[:, :, kidx] @ pi_k) * on[:, None]
    X = np.concatenate([Wb, Wpu], axis=2)
    names = list(bp.names) + [PAYLOAD_NAMES[k] for k in uidx]
    return X, tau, known_tau, mask, names


def _solve(X, tau, known_tau, gcol, names, mask, com):
    """`_gauss_newton`, its failure restated for the drive gains (with a hint when `com` is missing)."""
    try:
        return _gauss_newton(X, tau, known_tau, gcol, names, mask)
    except IdentificationError as e:
        hint = "" if com is not None else (" With the mass alone a payload at the wrist centre gives the wrist "
                                           "joints no known torque: give its centre of mass too (com=, --com).")
        raise IdentificationError(f"the recordings with and without the payload do not identify the drive "
                                  f"gains with the dynamic parameters: {e}{hint}") from None


def _gain_factors(est, cov, g):
    """`k = 1 / a` of the last `g` estimates and its covariance by the delta method."""
    a = est[-g:]
    k = 1.0 / a
    Jk = np.diag(-1.0 / a ** 2)
    return k, Jk @ cov[-g:, -g:] @ Jk.T


def _weak_gain_notice(joints, k, k_std):
    """A notice naming the gains whose 95 % half-width exceeds `WEAK_GAIN_HALFWIDTH`, or None."""
    half = 1.959963984540054 * np.asarray(k_std) / np.abs(k)
    weak = [f"joint {j} +- {100 * h:.2g} %" for j, h in zip(joints, half) if h > WEAK_GAIN_HALFWIDTH]
    if not weak:
        return None
    return ("gain(s) weakly fixed by the payload (95 % half-width above "
            f"{100 * WEAK_GAIN_HALFWIDTH:g} %): {', '.join(weak)}. The payload's torque on those joints "
            "is small beside the noise, or the arm joints did not see it (a light payload near the wrist "
            "centre; an arm moving slowly: the scale of a gain the mass's gravity does not load, a vertical "
            "first axis or the wrist, comes from the payload's torque as the arm joints see it); the error "
            "is noise the interval covers. Record "
            "the loaded recordings with the arm accelerating too and longer (docs/payload.md, Drive gains: "
            "3 x 30 s), or use a heavier payload or one farther from the wrist centre; its centre of mass "
            "(com=, --com) adds the wrist joints' gravity torque, little for a payload near the wrist centre")


def identify_drive_gains(unloaded, loaded, robot, *, mass, com=None, joints=None, frame="flange",
                         offset=None, settings=None, zoh=False):
    """Identify the drive gains with the dynamic parameters from a payload of known mass (module doc).

    Parameters
    ----------
    unloaded, loaded : path, Experiment, or a list of them
        Recordings without and with the payload; their torques computed with the robot
        file's gains (a `[currents]` description) or logged as the signal itself (gain 1).
    robot : Robot, bundled name or robot file
    mass : float
        The payload's mass, kg (> 0).
    com : (3,) array, optional
        Its centre of mass in the payload frame, m: fixes the wrist gains too.
    joints : list of int, optional
        1-based joints whose gain is identified (default: the joints the recordings'
        descriptions mark with `identify_gains`, else all).
    frame, offset : as in identify_payload (the link carrying the payload and its frame).
    settings : dict, optional
        IDIM's processing overrides.
    zoh : bool
        The logged signals are commands held over the next sample period: centre them on
        the position samples (as identify_payload's `zoh`).

    Returns
    -------
    DriveGainResult

    Raises
    ------
    InputError
        mass <= 0, a malformed com or joint list, a frame that is not a link.
    IdentificationError
        The data cannot fix some gains or parameters (named).
    """
    robot = _as_robot(robot)
    mass = _checked_mass(mass)
    known = _known_payload(mass, com)
    link, R, p = payload_frame(robot, frame, offset)
    T = transform_matrix(R, p)
    bp = base_parameters(robot)
    exps_u = _recordings(unloaded, robot, zoh)
    exps_l = _recordings(loaded, robot, zoh)
    from_description = joints is None and _described_joints(exps_l + exps_u) is not None
    joints = _checked_joints(_described_joints(exps_l + exps_u) if joints is None else joints, robot.n_joints)
    g_ref, exps = _common_gains(exps_l + exps_u, robot)
    exps_l, exps_u = exps[:len(exps_l)], exps[len(exps_l):]
    settings, dz_notice = _gain_settings(exps_l[0], robot, settings)
    first = _observe(exps_l[0], robot, bp, link, T, settings)
    obs_l = [first] + [_observe(e, robot, bp, link, T, first.settings) for e in exps_l[1:]]
    obs_u = [_observe(e, robot, bp, link, T, first.settings) for e in exps_u]
    gcol = np.array(joints) - 1

    X, tau, known_tau, mask, names = _stacked_model(obs_u, obs_l, known, bp)
    est, cov, rel_error, lags = _solve(X, tau, known_tau, gcol, names, mask, com)
    gnames = [f"g{j}" for j in joints]
    names = names + [f"a{j}" for j in joints]
    g = len(joints)
    k, cov_k = _gain_factors(est, cov, g)
    g_file = g_ref[gcol]
    D = np.diag(g_file)
    other = {"names": names[:-g], "values": est[:-g], "std": np.sqrt(np.maximum(np.diag(cov)[:-g], 0.0)),
             "note": "the robot's base parameters and the payload's unknown ones in the units of the "
                     "logged torque times a (tau_j = a_j (W_j theta + known_j))"}
    notices = [n for e in exps_u + exps_l for n in getattr(e, "notices", [])]
    if dz_notice:
        notices.append(dz_notice)
    weak = _weak_gain_notice(joints, k, np.sqrt(np.maximum(np.diag(cov_k), 0.0)))
    if weak:
        notices.append(weak)
    notices.append("gains identified for joints " + ", ".join(map(str, joints)) + (
        " (marked identify_gains in the experiment description)" if from_description else
        " (joints= / --gains)" if len(joints) < robot.n_joints else " (all joints: the default)"))
    return DriveGainResult(names=gnames, chi=g_file * k, cov=D @ cov_k @ D, joints=joints, g_file=g_file,
                           factor=k, factor_std=np.sqrt(np.maximum(np.diag(cov_k), 0.0)), known=known,
                           other=other, robot_name=robot.name,
                           sources=[f"{e.source} (unloaded)" for e in exps_u] + [str(e.source) for e in exps_l],
                           rel_error=rel_error, hac_lags=lags, notices=notices)
