"""The robot at rest: what the friction does when a joint is still (issue 27 item 4).

dynid's friction is `Fc sign(qd)`. At rest `qd` is velocity noise, so the model's
friction takes a random sign there; the velocity dead zone keeps those rows out of
the fit, but the held-out error on all samples (the headline figure) scores them, and
on the real TX40 they dominate it (15.6 % on all held-out samples against 6.6 % on the
moving ones, 56.6 % of the held-out equations at rest).

Candidates for the friction at rest of joint j, in the full-rate signal the Coulomb
column is built from (then decimated exactly as the regressor):

* `sign(qd)`: the model as identified;
* `zero`: no Coulomb friction while the joint is in the dead zone;
* `last motion`: sticking (hysteresis): at rest the friction keeps the sign of the last
  motion, at the identified Coulomb level (the static friction that holds the joint
  against the torque it last moved with).

The choice is made per joint on the *identification* recording's rest rows, which the
fit never used (the dead zone drops them), by the blocked CV rule of the other
candidates (rule.py): the rest rows are cut into `folds` contiguous time blocks, and a
rest model other than `sign(qd)` wins when it lowers the squared error on the rest rows
in total (CV gain > 0) and in all but one of the blocks that hold rest rows (at least 3
such blocks); among winners the largest gain. A rest model that wins is part of the diagnosed model: its prediction of the
held-out recording (`after`) uses it on the rest rows. No parameter is refitted, no sample
is left out: the held-out error is scored on all samples before and after, and its
rest-phase share reported per joint, with the RMS error on the held-out rest rows.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dynid.errors import DynidError

__all__ = ["RestPhases", "rest_phases", "REST_MODELS", "coulomb_signal"]

REST_MODELS = ("sign(qd)", "zero", "last motion")


@dataclass
class RestPhases:
    """Held-out error on all samples with the friction at rest as identified and as chosen."""

    model: list                   # chosen rest model per joint
    rest_fraction: np.ndarray     # held-out decimated rows at rest per joint
    rel_error_before: float       # all held-out samples, all joints
    rel_error_after: float
    joint_rel_error_before: np.ndarray
    joint_rel_error_after: np.ndarray
    rest_share_before: np.ndarray  # share of the joint's held-out squared error on rest rows
    rest_share_after: np.ndarray
    id_rest_sse: dict             # {model: (n,) identification rest-row SSE}
    rest_rms_before: np.ndarray = None   # (n,) RMS error on the held-out rest rows, N m
    rest_rms_after: np.ndarray = None
    cv_gain: dict = None          # {model: (n,) CV gain on the identification rest rows}
    blocks_better: dict = None    # {model: (n,) blocks of `folds` where it beats sign(qd)}
    folds: int = 5

    def coulomb_signal(self, joint, qd, dead):
        """The full-rate signal that multiplies Fc of `joint` (1-based) in the diagnosed model:
        `coulomb_signal` with the rest model chosen for that joint.

        Parameters
        ----------
        joint : int, 1-based.
        qd : (N,) velocity of the joint, rad/s.
        dead : (N,) bool, the rows of the velocity dead zone (the joint at rest).

        Returns
        -------
        np.ndarray (N,)
        """
        return coulomb_signal(qd, dead, self.model[joint - 1])

    def lines(self):
        js = range(len(self.model))
        return [f"held-out error on all samples, the identified model without the added effects: "
                f"{100 * self.rel_error_before:.2f} % -> {100 * self.rel_error_after:.2f} % with the friction "
                f"at rest chosen per joint ({', '.join(f'j{j + 1} {self.model[j]}' for j in js)}); the "
                f"effects are scored on the moving samples, above",
                "  per joint, all samples before -> after (share of the squared error from rest "
                "phases; fraction of rows at rest): "
                + "; ".join(f"j{j + 1} {100 * self.joint_rel_error_before[j]:.1f} -> "
                            f"{100 * self.joint_rel_error_after[j]:.1f} % "
                            f"({100 * self.rest_share_before[j]:.0f} -> {100 * self.rest_share_after[j]:.0f} %; "
                            f"{100 * self.rest_fraction[j]:.0f} %)" for j in js),
                "  held-out rest rows, RMS error before -> after [N m]: "
                # a joint that never stops in the held-out data has no rest-row error (not 0)
                + "; ".join(f"j{j + 1} {self.rest_rms_before[j]:.3g} -> {self.rest_rms_after[j]:.3g}"
                            if self.rest_fraction[j] > 0 else f"j{j + 1} no rest row" for j in js)]

    def to_dict(self):
        return {"rest_models": list(REST_MODELS), "chosen": list(self.model),
                "chosen_on": (f"identification rows at rest (not fitted): blocked CV in {self.folds} "
                              f"contiguous blocks, CV gain > 0 and lower error than sign(qd) in all but one "
                              f"of the blocks holding rest rows (at least 3)"),
                "cv_gain": {k: list(map(float, v)) for k, v in (self.cv_gain or {}).items()},
                "blocks_better": {k: list(map(int, v)) for k, v in (self.blocks_better or {}).items()},
                "rest_rms_nm": {"before": list(map(float, self.rest_rms_before)),
                                "after": list(map(float, self.rest_rms_after))},
                "rest_fraction": list(map(float, self.rest_fraction)),
                "all_samples_rel_error": {"before": self.rel_error_before, "after": self.rel_error_after},
                "joint_rel_error": {"before": list(map(float, self.joint_rel_error_before)),
                                    "after": list(map(float, self.joint_rel_error_after))},
                "rest_share_of_squared_error": {"before": list(map(float, self.rest_share_before)),
                                                "after": list(map(float, self.rest_share_after))},
                "identification_rest_sse": {k: list(map(float, v)) for k, v in self.id_rest_sse.items()}}


def rest_phases(robot, cols, chi, names, id_eobs, val_eobs, folds=5):
    """`RestPhases` of the model (`cols`, `chi`, `names`) or None (no Coulomb term, no data).

    Parameters
    ----------
    robot : the robot identified.
    cols, chi, names : the model's base-regressor columns, values and names.
    id_eobs, val_eobs : EffectObservation (dead zone on) of the identification and the held-out
        recordings, as `observe_effects` builds them (with their robot and base parameters).
    folds : contiguous blocks of the CV choice (the diagnosis' blocked CV).

    Returns
    -------
    RestPhases or None
    """
    fc = {j: names.index(f"Fc{j + 1}") for j in range(robot.n_joints) if f"Fc{j + 1}" in names}
    if not fc or id_eobs.dead is None or val_eobs.dead is None:
        return None
    try:
        ident = _all_samples(cols, chi, id_eobs, fc)
        held = _all_samples(cols, chi, val_eobs, fc)
    except DynidError:
        return None
    n = robot.n_joints
    sse = {m: np.array([np.sum(np.where(ident["rest"][:, j], ident["res"][m][:, j], 0.0) ** 2)
                        for j in range(n)]) for m in REST_MODELS}
    gain, better = _blocked_cv(ident["res"], ident["rest"], folds)
    # blocks without rest rows of the joint cannot be better: the rule counts the others
    # (KUKA LWR4+, 2-3 % of the rows at rest: some blocks hold none)
    occupied = _occupied(ident["rest"], folds)
    chosen = []
    for j in range(n):
        wins = [m for m in REST_MODELS[1:] if gain[m][j] > 0 and occupied[j] >= 3
                and better[m][j] >= occupied[j] - 1]
        chosen.append(max(wins, key=lambda m: gain[m][j]) if wins else REST_MODELS[0])
    before = held["res"]["sign(qd)"]
    after = np.column_stack([held["res"][chosen[j]][:, j] for j in range(n)])
    tau, rest = held["tau"], held["rest"]
    return RestPhases(model=chosen, rest_fraction=rest.mean(axis=0),
                      rel_error_before=float(np.linalg.norm(before) / np.linalg.norm(tau)),
                      rel_error_after=float(np.linalg.norm(after) / np.linalg.norm(tau)),
                      joint_rel_error_before=np.linalg.norm(before, axis=0) / np.linalg.norm(tau, axis=0),
                      joint_rel_error_after=np.linalg.norm(after, axis=0) / np.linalg.norm(tau, axis=0),
                      rest_share_before=_share(before, rest), rest_share_after=_share(after, rest),
                      id_rest_sse=sse, rest_rms_before=_rms(before, rest), rest_rms_after=_rms(after, rest),
                      cv_gain=gain, blocks_better=better, folds=folds)


def _blocked_cv(res, rest, folds):
    """({model: (n,) CV gain}, {model: (n,) blocks better}) of each rest model against sign(qd) on
    the rest rows, cut into `folds` contiguous time blocks (no parameter is fitted: each block's
    error is already out of sample)."""
    M, n = rest.shape
    block = np.minimum((np.arange(M) * folds) // max(M, 1), folds - 1)
    ref = res[REST_MODELS[0]]
    e0 = np.array([[np.sum(np.where(rest[:, j] & (block == b), ref[:, j], 0.0) ** 2)
                    for j in range(n)] for b in range(folds)])
    gain, better = {}, {}
    for m in REST_MODELS[1:]:
        e = np.array([[np.sum(np.where(rest[:, j] & (block == b), res[m][:, j], 0.0) ** 2)
                       for j in range(n)] for b in range(folds)])
        tot0 = e0.sum(axis=0)
        gain[m] = np.where(tot0 > 0, (tot0 - e.sum(axis=0)) / np.where(tot0 > 0, tot0, 1.0), 0.0)
        better[m] = (e < e0).sum(axis=0)
    return gain, better


def _occupied(rest, folds):
    """(n,) number of the `folds` contiguous blocks holding at least one rest row of each joint."""
    M = rest.shape[0]
    block = np.minimum((np.arange(M) * folds) // max(M, 1), folds - 1)
    return np.array([len(set(block[rest[:, j]])) for j in range(rest.shape[1])])


def _rms(res, rest):
    k = rest.sum(axis=0)
    return np.sqrt(np.sum(np.where(rest, res, 0.0) ** 2, axis=0) / np.maximum(k, 1))


def coulomb_signal(qd, dead, model):
    """The full-rate signal multiplying Fc of one joint under a rest model of `REST_MODELS`.

    Parameters
    ----------
    qd : (N,) velocity, rad/s.
    dead : (N,) bool, the velocity dead zone (the joint at rest).
    model : "sign(qd)" (as identified), "zero" (no Coulomb friction at rest) or "last motion"
        (sticking: at rest the sign of the last motion).

    Returns
    -------
    np.ndarray (N,)
    """
    s = np.sign(np.asarray(qd, dtype=float))
    dead = np.asarray(dead, dtype=bool)
    if model == "zero":
        return np.where(dead, 0.0, s)
    if model == "last motion":
        return _last_motion(s, dead)
    if model == "sign(qd)":
        return s
    raise ValueError(f"rest model must be one of {', '.join(REST_MODELS)}, got {model!r}")


def _share(res, rest):
    tot = np.sum(res ** 2, axis=0)
    return np.sum(np.where(rest, res, 0.0) ** 2, axis=0) / np.where(tot > 0, tot, 1.0)


def _all_samples(cols, chi, eobs_dz, fc):
    """Residuals (M, n) on all samples for each rest model, the torque and the rest rows.

    The system without the dead zone is `eobs_dz`'s full-rate data decimated without the
    zeroing (the dead zone changes nothing before it: same filtered motion, same regressor,
    same decimator); the model's prediction is the decimated full-rate model torque (the
    filter is linear), so the regressor is not rebuilt (it was, by a second
    `observe_effects`: about 1.5 s per 20 s at 5 kHz; equal to 1e-13 relative).
    """
    e0 = replace(eobs_dz, dead=None)
    cols = np.asarray(cols, dtype=int)
    tau = e0.decimate(eobs_dz.tau)[:, :, 0]
    if tau.shape != eobs_dz.obs.tau.shape:
        raise DynidError("the all-samples and dead-zone systems have different rows")
    pred = e0.decimate(eobs_dz.model_torque(cols, np.asarray(chi, dtype=float)[:len(cols)]))[:, :, 0]
    rest = ~np.asarray(eobs_dz.obs.row_mask, dtype=bool)
    res = {m: tau - pred for m in REST_MODELS}
    qd = np.asarray(eobs_dz.qd, dtype=float)
    for j, k in fc.items():
        dead = np.asarray(eobs_dz.dead[:, j], dtype=bool)
        cur = e0.decimate(coulomb_signal(qd[:, j], dead, "sign(qd)"), joint=j)[:, j, 0]
        for m in REST_MODELS[1:]:
            d = e0.decimate(coulomb_signal(qd[:, j], dead, m), joint=j)[:, j, 0] - cur
            res[m][:, j] = res[m][:, j] - chi[k] * d
    return {"res": res, "tau": tau, "rest": rest}


def _last_motion(s, dead):
    """sign(qd) while moving; at rest the sign of the last motion (0 before the first)."""
    idx = np.where(~dead, np.arange(s.size), -1)
    idx = np.maximum.accumulate(idx)
    out = np.where(idx >= 0, s[np.maximum(idx, 0)], 0.0)
    return np.where(dead, out, s)
