"""PC-WLS of a model with effect columns: the rigid body constrained, the effects free.

The residual diagnosis names effects a rigid-body model lacks (springs, position
ripple, ...; :mod:`dynid.analysis.diagnosis.effects`). When the unconstrained fit is not
physical because the base parameters absorb such an effect, the physically consistent
fit must be made *with* the effect: the base parameters ``beta`` constrained as in
:mod:`dynid.analysis.estimators.physical`, the effect parameters ``theta`` free.

Why the base parameters' marginal covariance is the right target. The WLS of the stacked
design ``[W, C]`` (same per-joint weights, eq. (16)) gives ``x_hat = (beta_hat, theta_hat)``
and ``cov``; the weighted squared residual of any ``(beta, theta)`` is
``const + (x - x_hat)^T cov^-1 (x - x_hat)`` (in units of sigma_rho^2). Minimising over
``theta`` for a given ``beta`` leaves

    (beta - beta_hat)^T cov_bb^-1 (beta - beta_hat),                                  (1)
    theta(beta) = theta_hat + cov_tb cov_bb^-1 (beta - beta_hat)                        (2)

(Schur complement of the information matrix: its inverse's ``bb`` block is ``cov_bb``). So
PC-WLS of ``(beta_hat, cov_bb)`` (:func:`~dynid.analysis.estimators.physical.pc_wls`) followed
by (2) is the constrained minimum of the whole weighted residual, one SDP as without effects.

Measured on the KUKA LWR4+ (``benchmarks/physical.py``, ``examples/kuka_lwr4/README.md``):
a linear spring on every joint and the first position harmonic on joint 7 take the negative
ZZ1R, Ia3 and Ia7 the unconstrained fit wanted.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynid.analysis.diagnosis.effect_observation import observe_effects
from dynid.analysis.diagnosis.effects import make_candidate, signals_from_observation
from dynid.errors import InputError


def effect_candidates(spec, n_joints):
    """Candidates from a short text: ``"spring:all,position_ripple:7:1"``.

    Items ``name:joint[:order]``, ``joint`` 1-based or ``all``; ``order`` for
    ``position_ripple`` (harmonic k of cos k q_j, sin k q_j). Only the effects whose columns
    need nothing but the motion: offset, asymmetric_coulomb, asymmetric_viscous, spring,
    position_ripple.
    """
    allowed = ("offset", "asymmetric_coulomb", "asymmetric_viscous", "spring", "position_ripple")
    out = []
    for item in [s.strip() for s in str(spec).split(",") if s.strip()]:
        parts = item.split(":")
        name = parts[0]
        if name not in allowed or len(parts) < 2:
            raise InputError(f"effect {item!r}: expected name:joint[:order] with name one of "
                             f"{', '.join(allowed)} and joint 1..{n_joints} or 'all'")
        joints = range(1, n_joints + 1) if parts[1] == "all" else [int(parts[1])]
        for j in joints:
            if not 1 <= j <= n_joints:
                raise InputError(f"effect {item!r}: joint {j} outside 1..{n_joints}")
            if name == "position_ripple":
                if len(parts) != 3:
                    raise InputError(f"effect {item!r}: position_ripple needs an order, e.g. "
                                     "position_ripple:7:1")
                out.append(make_candidate(name, j, n_joints, order=int(parts[2])))
            else:
                out.append(make_candidate(name, j, n_joints))
    return out


def effect_design(experiment, robot, bp, settings, candidates):
    """Decimated ``[W, C]`` of one recording: (M, n, b + k), tau (M, n), row mask (M, n), names.

    ``C`` are the candidates' columns built at full rate from the same filtered motion as W
    and pushed through the same dead zone and parallel decimation
    (:meth:`~dynid.analysis.diagnosis.effect_observation.EffectObservation.decimate`).
    """
    eo = observe_effects(experiment, robot, bp, settings)
    s = signals_from_observation(eo, robot=robot)
    blocks, names = [eo.obs.W], list(bp.names)
    for c in candidates:
        blocks.append(eo.decimate(c.full_columns(s)))
        names += list(c.active_params)
    mask = np.broadcast_to(np.asarray(eo.obs.row_mask, bool).reshape(eo.obs.tau.shape[0], -1),
                           eo.obs.tau.shape)
    return np.concatenate(blocks, axis=2), eo.obs.tau, mask, names


@dataclass
class EffectsFit:
    """The WLS of ``[W, C]`` and its physically consistent counterpart."""

    names: list            # base parameters then effect parameters
    n_base: int
    wls: object            # IdentificationResult of the stacked design
    physical: object       # PhysicalResult of the base parameters, eq. (1)
    theta_pc: np.ndarray   # effect parameters given the PC base parameters, eq. (2)
    settings: dict
    candidates: list

    @property
    def x_wls(self):
        return np.asarray(self.wls.chi, float)

    @property
    def x_pc(self):
        return np.concatenate([np.asarray(self.physical.chi, float), self.theta_pc])


def profile_physical(robot, bp, x_hat, cov, n_base, **pc_options):
    """PC-WLS of the base parameters with the effect parameters profiled out: eqs. (1)-(2).

    ``x_hat`` (b + k,), ``cov`` (b + k, b + k): the WLS of the stacked design. Returns
    ``(PhysicalResult, theta_pc)``.
    """
    from dynid.analysis.estimators.physical import pc_wls
    b = int(n_base)
    x_hat, cov = np.asarray(x_hat, float), np.asarray(cov, float)
    cov_bb = 0.5 * (cov[:b, :b] + cov[:b, :b].T)
    pc = pc_wls(robot, bp, x_hat[:b], cov_bb, **pc_options)
    theta = x_hat[b:] + cov[b:, :b] @ np.linalg.solve(cov_bb, np.asarray(pc.chi, float) - x_hat[:b])
    return pc, theta


def identify_physical_effects(experiments, robot, result, candidates, **pc_options) -> EffectsFit:
    """WLS and PC-WLS of the base model of ``result`` (an IDIM result on ``experiments``) plus
    ``candidates``' columns, with ``result``'s processing settings; the per-joint sigma_j are
    re-estimated on the stacked design (eq. (16))."""
    from dynid.analysis.estimators import least_squares as ls
    if not isinstance(experiments, (list, tuple)):
        experiments = [experiments]
    bp, s = result.base, result.observation.settings
    parts = [effect_design(e, robot, bp, s, candidates) for e in experiments]
    W = np.concatenate([p[0] for p in parts])
    tau = np.concatenate([p[1] for p in parts])
    mask = np.concatenate([p[2] for p in parts])
    names = parts[0][3]
    wls = ls.wls(W, tau, names, row_mask=mask)
    pc, theta = profile_physical(robot, bp, wls.chi, wls.cov, bp.n_base, **pc_options)
    return EffectsFit(names=names, n_base=bp.n_base, wls=wls, physical=pc, theta_pc=theta,
                      settings=dict(s), candidates=list(candidates))


def held_out_errors(fit: EffectsFit, experiment, robot, bp):
    """Relative error ||tau - tau_hat|| / ||tau|| on all decimated samples of ``experiment`` (no
    dead zone, as :func:`dynid.analysis.statistics.validation.validate`): ``{"wls", "pc"}``."""
    from dynid.analysis.statistics.validation import prediction_errors
    W, tau, _, _ = effect_design(experiment, robot, bp, dict(fit.settings, qd_threshold=0.0), fit.candidates)
    return {"wls": prediction_errors(tau, W @ fit.x_wls)[0], "pc": prediction_errors(tau, W @ fit.x_pc)[0]}
