"""PC-WLS of a model with effect columns: the rigid body constrained, the effects free.

The residual diagnosis names effects a rigid-body model lacks (springs, position
ripple, ...; `dynid.analysis.diagnosis.effects`). When the unconstrained fit is not
physical because the base parameters absorb such an effect, the physically consistent
fit must be made *with* the effect: the base parameters `beta` constrained as in
`dynid.analysis.estimators.physical`, the effect parameters `theta` free.

Why the base parameters' marginal covariance is the right target. The WLS of the stacked
design `[W, C]` (same per-joint weights, eq. (16)) gives `x_hat = (beta_hat, theta_hat)`
and `cov`; the weighted squared residual of any `(beta, theta)` is
`const + (x - x_hat)^T cov^-1 (x - x_hat)` (in units of sigma_rho^2). Minimising over
`theta` for a given `beta` leaves

    (beta - beta_hat)^T cov_bb^-1 (beta - beta_hat),                                  (1)
    theta(beta) = theta_hat + cov_tb cov_bb^-1 (beta - beta_hat)                        (2)

(Schur complement of the information matrix: its inverse's `bb` block is `cov_bb`). So
PC-WLS of `(beta_hat, cov_bb)` (`pc_wls`) followed
by (2) is the constrained minimum of the whole weighted residual, one SDP as without effects.

The effect parameters' uncertainty at the PC solution is eq. (3) of `profile_physical`:
the covariance of the base parameters' bootstrap refits carried through (2), plus the part of theta that
the base parameters do not explain. From the command line: `dynid identify EXP --robot R
--effects spring:all [--physical] [--validation V]` (JSON block `"effects"`).

Measured on the KUKA LWR4+ (`benchmarks/physical.py`, `examples/kuka_lwr4/README.md`):
a linear spring on every joint and the first position harmonic on joint 7 take the negative
ZZ1R, Ia3 and Ia7 the unconstrained fit wanted.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from dynid.analysis.diagnosis.effect_observation import observe_effects
from dynid.analysis.diagnosis.effects import make_candidate, signals_from_observation
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.physical import pc_wls
from dynid.analysis.results import HeldParameters, Result, percent
from dynid.analysis.statistics.validation import prediction_errors
from dynid.analysis.units import parameter_unit, prismatic_joints
from dynid.errors import IdentificationError, InputError
from dynid.provenance import json_safe

SPEC_EFFECTS = ("offset", "asymmetric_coulomb", "asymmetric_viscous", "spring", "position_ripple")


def _integer(text, what, item):
    try:
        return int(text)
    except ValueError:
        raise InputError(f"effect {item!r}: {what} must be a whole number, got {text!r}") from None


def effect_candidates(spec, n_joints):
    """Candidates from a short text: `"spring:all,position_ripple:7:1"`.

    Items `name:joint[:order]`, `joint` 1-based or `all`; `order` for
    `position_ripple` (harmonic k of cos k q_j, sin k q_j). Only the effects whose columns
    need nothing but the motion: offset, asymmetric_coulomb, asymmetric_viscous, spring,
    position_ripple. An effect named twice on one joint is refused (its columns would repeat).
    """
    out, seen = [], set()
    for item in [s.strip() for s in str(spec).split(",") if s.strip()]:
        parts = item.split(":")
        name = parts[0]
        if name not in SPEC_EFFECTS or len(parts) < 2 or len(parts) > 3:
            raise InputError(f"effect {item!r}: expected name:joint[:order] with name one of "
                             f"{', '.join(SPEC_EFFECTS)} and joint 1..{n_joints} or 'all', "
                             "e.g. spring:all,position_ripple:7:1")
        joints = range(1, n_joints + 1) if parts[1] == "all" else [_integer(parts[1], "the joint", item)]
        if name == "position_ripple":
            if len(parts) != 3:
                raise InputError(f"effect {item!r}: position_ripple needs an order, e.g. "
                                 "position_ripple:7:1")
            order = _integer(parts[2], "the order", item)
            if order < 1:
                raise InputError(f"effect {item!r}: the order must be 1 or more, got {order}")
        elif len(parts) == 3:
            raise InputError(f"effect {item!r}: only position_ripple takes an order (name:joint)")
        for j in joints:
            if not 1 <= j <= n_joints:
                raise InputError(f"effect {item!r}: joint {j} outside 1..{n_joints}")
            c = (make_candidate(name, j, n_joints, order=order) if name == "position_ripple"
                 else make_candidate(name, j, n_joints))
            key = (name, j, c.nonlinear.get("order"))
            if key in seen:
                raise InputError(f"effect {item!r}: {name} on joint {j} is given twice")
            seen.add(key)
            out.append(c)
    return out


def effect_design(experiment, robot, bp, settings, candidates):
    """Decimated `[W, C]` of one recording: (M, n, b + k), tau (M, n), row mask (M, n), names.

    `C` are the candidates' columns built at full rate from the same filtered motion as W
    and pushed through the same dead zone and parallel decimation
    (`decimate`).
    """
    # only the decimated system and the candidates' columns are used: the full-rate regressor
    # is not kept (on a 20 s, 5 kHz 6-joint log it would hold some 290 MB for nothing)
    eo = observe_effects(experiment, robot, bp, settings, cache_regressor=False)
    s = signals_from_observation(eo, robot=robot)
    blocks, names = [eo.obs.W], list(bp.names)
    for c in candidates:
        blocks.append(eo.decimate(c.full_columns(s)))
        names += list(c.active_params)
    mask = np.broadcast_to(np.asarray(eo.obs.row_mask, bool).reshape(eo.obs.tau.shape[0], -1),
                           eo.obs.tau.shape)
    return np.concatenate(blocks, axis=2), eo.obs.tau, mask, names


@dataclass(repr=False)
class EffectsFit(HeldParameters, Result):
    """The WLS of `[W, C]` and, when asked, its physically consistent counterpart.

    `to_csv()` writes the effect parameters (`effects()`), `to_json()` the JSON block;
    `params`, `bse`, `conf_int()` and `fit["Ks1"]` are the unconstrained WLS of every base and
    effect parameter, with the run's covariance.

    `cov_effects_pc`: sampling covariance of the PC effect parameters, eq. (3) (the reported
    sigma is floored at the unconstrained one, `effects`); `rel_error_*`:
    ||Y - W x|| / ||Y|| on the identification rows; `validation`: the held-out errors of
    `held_out_errors` when a validation recording was given (None otherwise).
    """

    names: list            # base parameters then effect parameters
    n_base: int
    wls: object            # IdentificationResult of the stacked design
    physical: object       # PhysicalResult of the base parameters, eq. (1); None: unconstrained only
    theta_pc: np.ndarray | None   # effect parameters given the PC base parameters, eq. (2)
    settings: dict
    candidates: list
    spec: str = ""
    cov_effects_pc: np.ndarray | None = None
    rel_error_wls: float = float("nan")
    rel_error_pc: float = float("nan")
    validation: dict | None = None
    prismatic: tuple = ()  # the robot's prismatic joints (1-based), for the units
    uncertainty: str = "classic"   # the covariance option of the sigma (least_squares.UNCERTAINTY)

    def _held(self):
        # params, bse, conf_int, fit["Ks1"]: the unconstrained WLS of the stacked design, every
        # base and effect parameter, with the run's covariance (the PC values: `effects()`)
        return self.wls

    @property
    def x_wls(self):
        return np.asarray(self.wls.chi, float)

    @property
    def x_pc(self):
        if self.physical is None:
            raise InputError("this fit has no physically consistent part (fitted without physical=True)")
        return np.concatenate([np.asarray(self.physical.chi, float), self.theta_pc])

    @property
    def sigma_label(self) -> str:
        """What the sigma are: the covariance option's name, as the summary and the report say it."""
        return ls.UNCERTAINTY_WORDS.get(self.uncertainty, self.uncertainty)

    @property
    def effect_names(self):
        return list(self.names[self.n_base:])

    def effects(self) -> list:
        """Per effect parameter: name, effect, joint, unconstrained value and sigma, PC value and sigma."""
        b = self.n_base
        sd = np.sqrt(np.maximum(np.diag(self.wls.cov)[b:], 0.0))
        # floored at the unconstrained sigma, as interval_covariance does for the base parameters:
        # the refits' spread is that of a truth on the constraint, too small for one inside it
        sd_pc = (np.maximum(np.sqrt(np.maximum(np.diag(self.cov_effects_pc), 0.0)), sd)
                 if self.cov_effects_pc is not None else [None] * len(sd))
        owner = [(c.name, c.joint) for c in self.candidates for _ in c.active_params]
        out = []
        for k, n in enumerate(self.effect_names):
            row = {"name": n, "effect": owner[k][0], "joint": owner[k][1],
                   "unit": parameter_unit(n, frozenset(self.prismatic)),
                   "wls": float(self.x_wls[b + k]), "wls_std": float(sd[k])}
            if self.physical is not None:
                row.update(pc=float(self.theta_pc[k]), pc_std=float(sd_pc[k]))
            out.append(row)
        return out

    def to_frame(self):
        """The effect parameters, one row each: effect, joint, unit, WLS value and sigma (PC too)."""
        return pd.DataFrame(self.effects()).set_index("name")

    def __repr__(self):
        return (f"<EffectsFit {self.spec}: {len(self.effect_names)} effect parameter(s), rel. error "
                f"{percent(self.rel_error_wls, 3)}>")

    def to_dict(self) -> dict:
        """The JSON block of the effects: `spec`, per-parameter values and sigma (unconstrained
        and, with the physical fit, PC), the errors on the identification data and held out."""
        return json_safe({
            "spec": self.spec, "candidates": [{"effect": c.name, "joint": c.joint, **c.nonlinear}
                                              for c in self.candidates],
            "parameters": self.effects(),
            "uncertainty": self.uncertainty,
            "sigma": (f"wls_std: the stacked WLS covariance ({self.sigma_label}); "
                      "pc_std: eq. (3) of dynid.analysis.diagnosis.physical_fit (the PC fit's refits, drawn "
                      "from that covariance, carried through the profile), floored at wls_std: a constraint "
                      "is not counted as information (the rule of the base parameters' sigma)"),
            "rel_error_wls": self.rel_error_wls, "rel_error_pc": self.rel_error_pc,
            "validation": self.validation,
        })

    def summary(self) -> str:
        pc = self.physical is not None
        lines = [f"Effects fitted with the rigid body ({self.spec}): "
                 + ("unconstrained WLS and PC-WLS of the same model" if pc else "unconstrained WLS")
                 + f"; sigma: {self.sigma_label}",
                 f"  relative error on the identification data: WLS {percent(self.rel_error_wls, 3)}"
                 + (f", PC {percent(self.rel_error_pc, 3)}" if pc else "")]
        if self.validation is not None:
            v = self.validation
            lines.append(f"  held-out relative error (all samples): WLS {percent(v['rel_error_wls'], 3)}"
                         + (f", PC {percent(v['rel_error_pc'], 3)} (PC - WLS {v['gap_points']:+.3f} points)"
                            if pc else ""))
        hdr = f"{'Parameter':<12}{'effect':>20}  {'unit':<12}{'WLS':>13}{'sigma':>11}"
        lines.append(hdr + (f"{'PC':>13}{'sigma':>11}" if pc else ""))
        for r in self.effects():
            line = (f"{r['name']:<12}{r['effect'] + ' j' + str(r['joint']):>20}  {r['unit']:<12}{r['wls']:>13.5g}"
                    f"{r['wls_std']:>11.3g}")
            if pc:
                line += f"{r['pc']:>13.5g}{r['pc_std']:>11.3g}"
            lines.append(line)
        return "\n".join(lines)


def profile_physical(robot, bp, x_hat, cov, n_base, *, interval_cov=None, uncertainty="classic", **pc_options):
    """PC-WLS of the base parameters with the effect parameters profiled out: eqs. (1)-(3).

    `x_hat` (b + k,), `cov` (b + k, b + k): the WLS of the stacked design, eq. (14)'s covariance
    (the fit's metric: the estimate does not depend on the covariance option).
    `interval_cov` (b + k, b + k): the covariance of the option `uncertainty` (HAC or block
    bootstrap of the same fit, default `cov`), which the PC fit's refits draw from and which
    takes the place of `cov` in eq. (3). Returns
    `(PhysicalResult, theta_pc, cov_theta_pc)`. With `K = cov_tb cov_bb^-1`, eq. (2) reads
    `theta_pc = u + K beta_pc` where `u = theta_hat - K beta_hat` is uncorrelated with
    `beta_hat` (so independent, Gaussian errors) and `beta_pc` depends on `beta_hat`
    alone; hence

        cov(theta_pc) = (cov_tt - K cov_bt) + K cov(beta_pc) K^T,                         (3)

    with `cov(beta_pc)` the covariance of the PC fit's bootstrap refits (`boot_cov`: the
    sampling covariance if the truth sat on the active constraints; `cov_bb` itself when
    `n_boot = 0`, which gives back `cov_tt`). That independence holds for eq. (14)'s covariance;
    under a robust `interval_cov` S, u and `beta_hat` correlate (`S_bu = S_bt - S_bb K^T`), and
    the cross term `C + C^T`, `C = K cov(beta_pc) S_bb^-1 S_bu`, is added (beta_pc regressed on
    beta_hat: exact when no constraint is active, where the sum is S_tt). The sigma reported for
    theta (`EffectsFit.effects`) is never below the unconstrained one, the rule of the base
    parameters' (`interval_covariance`).
    """
    b = int(n_base)
    x_hat, cov = np.asarray(x_hat, float), np.asarray(cov, float)
    S = cov if interval_cov is None else np.asarray(interval_cov, float)
    cov_bb = 0.5 * (cov[:b, :b] + cov[:b, :b].T)
    S_bb = 0.5 * (S[:b, :b] + S[:b, :b].T)
    pc = pc_wls(robot, bp, x_hat[:b], cov_bb, interval_cov=S_bb, uncertainty=uncertainty, **pc_options)
    K = np.linalg.solve(cov_bb, cov[:b, b:]).T
    theta = x_hat[b:] + K @ (np.asarray(pc.chi, float) - x_hat[:b])
    cov_pc = S_bb if pc.boot_cov is None else np.asarray(pc.boot_cov, float)
    # u = theta_hat - K beta_hat under S. With S eq. (14)'s covariance, cov(beta_hat, u) = 0 and
    # cov_u = S_tt - K S_bt; under a robust S they correlate, and cov(beta_pc, u) is taken as
    # cov_pc S_bb^-1 cov(beta_hat, u) (beta_pc regressed on beta_hat), which gives S_tt back when
    # no constraint is active (beta_pc = beta_hat) and 0 for S = cov
    S_bu = S[:b, b:] - S_bb @ K.T
    cov_u = S[b:, b:] - K @ S[:b, b:] - S[b:, :b] @ K.T + K @ S_bb @ K.T
    C = K @ cov_pc @ np.linalg.solve(S_bb, S_bu)
    cov_t = cov_u + K @ cov_pc @ K.T + C + C.T
    return pc, theta, 0.5 * (cov_t + cov_t.T)


def _rel_error(tau, W, x, mask):
    r = np.where(mask, tau - W @ x, 0.0)
    return float(np.linalg.norm(r) / np.linalg.norm(np.where(mask, tau, 0.0)))


def identify_physical_effects(experiments, robot, result, candidates, *, physical=True, validation=None,
                              spec="", **pc_options) -> EffectsFit:
    """WLS and (`physical=True`) PC-WLS of the base model of `result` (an IDIM result on
    `experiments`) plus `candidates`' columns, with `result`'s processing settings; the
    per-joint sigma_j are re-estimated on the stacked design (eq. (16)). `validation`: a
    held-out recording, whose errors (`held_out_errors`) go into the result."""
    if not isinstance(experiments, (list, tuple)):
        experiments = [experiments]
    bp, s = result.base, result.observation.settings
    parts = [effect_design(e, robot, bp, s, candidates) for e in experiments]
    W = np.concatenate([p[0] for p in parts])
    tau = np.concatenate([p[1] for p in parts])
    mask = np.concatenate([p[2] for p in parts])
    names = parts[0][3]
    clash = sorted(set(names[:bp.n_base]) & set(names[bp.n_base:]))
    if clash:
        raise InputError(f"effects {spec or ''}: {', '.join(clash)} already in the base model of "
                         f"'{robot.name}'; leave that effect out")
    uncertainty = getattr(result, "uncertainty", "classic")
    groups = np.repeat(np.arange(len(parts)), [p[1].shape[0] for p in parts])
    try:
        wls = ls.wls(W, tau, names, row_mask=mask)
        # the covariance option of `result` (its estimate is the same): the effects' sigma as the
        # rigid body's; eq. (14)'s stays the PC fit's metric
        robust = wls if uncertainty == "classic" else ls.wls(W, tau, names, row_mask=mask, uncertainty=uncertainty,
                                                              groups=groups)
    except IdentificationError as e:
        raise InputError(f"effects {spec or ''}: the model with these effects cannot be identified "
                         f"from these data ({str(e).splitlines()[0].rstrip('.')}; {_culprit(str(e))}); leave "
                         "out the effect named") from None
    pc = theta = cov_t = None
    if physical:
        pc, theta, cov_t = profile_physical(robot, bp, wls.chi, wls.cov, bp.n_base, interval_cov=robust.cov,
                                            uncertainty=uncertainty, **pc_options)
    fit = EffectsFit(names=names, n_base=bp.n_base, wls=robust, physical=pc, theta_pc=theta,
                     settings=dict(s), candidates=list(candidates), spec=str(spec), cov_effects_pc=cov_t,
                     rel_error_wls=_rel_error(tau, W, wls.chi, mask),
                     prismatic=tuple(sorted(prismatic_joints(robot))), uncertainty=uncertainty)
    if physical:
        fit.rel_error_pc = _rel_error(tau, W, fit.x_pc, mask)
    if validation is not None:
        fit.validation = held_out_errors(fit, validation, robot, bp, detail=True)
    return fit


def _culprit(message):
    lines = [ln.strip(" -") for ln in message.splitlines()[1:] if "column is" in ln]
    return lines[0].split(", so")[0] if lines else "see the message above"


def held_out_errors(fit: EffectsFit, experiment, robot, bp, *, detail=False):
    """Relative error ||tau - tau_hat|| / ||tau|| on all decimated samples of `experiment` (no
    dead zone, as `dynid.analysis.statistics.validation.validate`): `{"wls", "pc"}`
    ("pc" only with the physical fit). `detail=True`: the block of the JSON instead, with the
    per-joint RMS [N m] and the gap PC - WLS in points."""
    W, tau, _, _ = effect_design(experiment, robot, bp, dict(fit.settings, qd_threshold=0.0), fit.candidates)
    e_wls, rms_wls, _ = prediction_errors(tau, W @ fit.x_wls)
    out = {"wls": e_wls}
    if fit.physical is not None:
        e_pc, rms_pc, _ = prediction_errors(tau, W @ fit.x_pc)
        out["pc"] = e_pc
    if not detail:
        return out
    block = {"samples": "all", "n_samples": int(tau.shape[0]), "rel_error_wls": e_wls,
             "rms_wls": [float(x) for x in rms_wls]}
    if fit.physical is not None:
        block.update(rel_error_pc=e_pc, rms_pc=[float(x) for x in rms_pc],
                     gap_points=100.0 * (e_pc - e_wls))
    return block
