"""The data a diagnosis works on: the decimated observation of one recording, its
effect columns and the model's (shifted) base-regressor columns (`Problem`), the
starting model, WLS fits of a model plus effects, and the errors of such a model
on another recording (`evaluate_effects`, `fit_effects`).
"""
from __future__ import annotations

import math
import re

import numpy as np

from dynid.analysis.diagnosis.effect_observation import EffectObservation, observe_effects
from dynid.analysis.diagnosis.effects import signals_from_observation
from dynid.analysis.diagnosis.results import errors_of
from dynid.analysis.diagnosis.scoring import new_columns, weighted_sse
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters
from dynid.analysis.estimators.idim import IDIMResult
from dynid.analysis.statistics.residuals import analyze_residuals, effective_sample_size
from dynid.dynamics.base_parameters import BaseParameters
from dynid.errors import InputError

__all__ = ["without_parameters", "identify_from_observation", "Problem", "fit_wls", "row_weights",
           "full_rate_residual", "start_model_fit", "validation_problem", "delay_sigma",
           "analyse_residual", "evaluate_effects", "split_delay", "fit_effects"]

# ======================================================================= models
def without_parameters(bp: BaseParameters, drop) -> BaseParameters:
    """A base-parameter set without some parameters (e.g. `("Off",)`: a model without offsets).

    `drop` lists base-parameter names or prefixes followed by the joint
    number (`"Off"` drops Off1..Offn; `"Off3"` only Off3). The dropped
    parameters are taken as zero: their columns leave the regressor.
    """
    drop = [drop] if isinstance(drop, str) else list(drop)

    def dropped(name):
        for d in drop:
            if name == d or re.fullmatch(re.escape(d) + r"\d+", name):
                return True
        return False

    keep = np.array([not dropped(nm) for nm in bp.names], dtype=bool)
    if keep.all():
        return bp
    return BaseParameters(robot_name=bp.robot_name, standard_names=list(bp.standard_names),
                          independent=np.asarray(bp.independent)[keep], dependent=bp.dependent,
                          K=np.asarray(bp.K)[keep], names=[nm for nm, k in zip(bp.names, keep) if k])


def identify_from_observation(eobs: EffectObservation, robot, *, max_error_growth=0.02):
    """IDIM (OLS, WLS, essential WLS) from a prepared `EffectObservation`.

    The same estimators as `dynid.analysis.estimators.idim.identify_idim`, without
    building the observation system again (e.g. when only the torque changed:
    `EffectObservation.with_torque`).
    """
    obs = eobs.obs
    names = list(eobs.bp.names)
    info = dict(obs.settings)
    r_ols = ls.ols(obs.W, obs.tau, names, row_mask=obs.row_mask, settings=info)
    r_wls = ls.wls(obs.W, obs.tau, names, row_mask=obs.row_mask, settings=info)
    ess = essential_parameters(obs.W, obs.tau, names, ls.wls, max_error_growth=max_error_growth,
                               row_mask=obs.row_mask, settings=info)
    return IDIMResult(robot_name=robot.name, base=eobs.bp, ols=r_ols, wls=r_wls, essential=ess,
                      observation=obs, settings=obs.settings, notices=list(obs.notices),
                      source=eobs.source)



# ======================================================================= problem
class Problem:
    """The decimated data of one recording, its effect columns and (shifted) model columns.

    The model's design for a state (delay d, effects) is the decimated base
    regressor of the model's columns, of the motion shifted by d (W(t - d),
    `EffectObservation.shifted_regressor`), followed by the effects'
    decimated columns.
    """

    def __init__(self, eobs, signals, cols, names):
        self.eobs = eobs
        self.signals = signals
        self.cols = np.asarray(cols, dtype=int)
        self.names = list(names)
        self.all_cols = np.arange(len(eobs.bp.names))
        self.all_names = list(eobs.bp.names)
        self.X = eobs.obs.W[:, :, self.cols]
        self.Y = eobs.obs.tau
        self.mask = eobs.obs.row_mask
        self._cache = {}
        self._shifted = {}

    def decimated(self, cands):
        """Decimated columns (M, n, k) of column candidates (cached by key and active set)."""
        todo = [c for c in cands if self._key(c) not in self._cache]
        joint_blocks, joint_c, glob = [], [], []
        for c in todo:
            if c.joint is None:
                glob.append(c)
            else:
                # built when its joint is decimated: one joint's columns in memory at a time
                joint_blocks.append((lambda c=c: c.columns(self.signals), c.joint - 1))
                joint_c.append(c)
        if joint_blocks:
            for c, D in zip(joint_c, self.eobs.decimate_joint_blocks(joint_blocks)):
                self._cache[self._key(c)] = D
        for c in glob:
            self._cache[self._key(c)] = self.eobs.decimate(c.columns(self.signals))
        return [self._cache[self._key(c)] for c in cands]

    def base(self, delay=0.0, cache=True, cols=None):
        """Decimated base-regressor columns `cols` (default the model's), motion shifted by `delay` s."""
        cols = self.cols if cols is None else np.asarray(cols, dtype=int)
        if not delay:
            return self.eobs.obs.W[:, :, cols]
        key = float(delay)
        if key not in self._shifted:
            B = self.eobs.shifted_regressor(self.all_cols, key)
            if not cache:
                return B[:, :, cols]
            self._shifted[key] = B
        return self._shifted[key][:, :, cols]

    def design(self, delay, effects, cache=True, cols=None):
        parts = [self.base(delay, cache, cols)] + self.decimated(list(effects))
        return np.concatenate(parts, axis=2) if len(parts) > 1 else parts[0]

    def names_for(self, effects, names=None):
        names = self.names if names is None else names
        return list(names) + [p for c in effects for p in c.active_params]

    def essential(self, delay, max_error_growth=0.02):
        """Essential parameters (names, base columns) re-selected on the motion shifted by `delay`."""
        X = self.base(delay, cols=self.all_cols)
        ess = essential_parameters(X, self.Y, self.all_names, ls.wls,
                                   max_error_growth=max_error_growth, row_mask=self.mask)
        names = list(ess.result.names)
        index = {n: k for k, n in enumerate(self.all_names)}
        return names, np.array([index[n] for n in names], dtype=int)

    @staticmethod
    def _key(c):
        return (c.key, None if c.active is None else tuple(c.active))


def fit_wls(X, Y, mask, names, uncertainty="classic"):
    return ls.wls(X, Y, names, row_mask=mask, uncertainty=uncertainty)



def row_weights(fit):
    w = 1.0 / np.asarray(fit.joint_sigma, dtype=float)
    return np.where(np.isfinite(w), w, 0.0)



def full_rate_residual(problem, state, fit):
    """(residual (N, n), used rows (N, n)) of the final model at the full rate, or (None, None)
    with a time delay (no full-rate shifted regressor)."""
    if state["delay"]:
        return None, None
    eobs = problem.eobs
    names = list(fit.names)
    nb = len(state["names"])
    model = eobs.model_torque(np.asarray(state["cols"], dtype=int), np.asarray(fit.chi[:nb]))
    k = nb
    for c in state["effects"]:
        m = len(c.active_params)
        model = model + c.full_columns(problem.signals) @ np.asarray(fit.chi[k:k + m])
        k += m
    del names
    used = np.ones(model.shape, dtype=bool) if eobs.dead is None else ~np.asarray(eobs.dead)
    return np.asarray(eobs.tau, dtype=float) - model, used


def start_model_fit(idim_result, obs, start_model):
    """(IdentificationResult, description) of the model the selection starts from."""
    if isinstance(start_model, str):
        if start_model == "base":
            return idim_result.wls, "full base-parameter WLS of the IDIM identification"
        if start_model == "essential":
            return idim_result.model, "essential WLS of the IDIM identification"
        raise InputError(f"start_model must be 'base', 'essential' or a list of base-parameter "
                         f"names, got {start_model!r}")
    names = [str(n) for n in start_model]
    bad = [n for n in names if n not in idim_result.base.names]
    if bad:
        raise InputError(f"start_model: unknown base parameter(s) {', '.join(bad)}")
    cols = idim_result.columns(names)
    fit = fit_wls(obs.W[:, :, cols], obs.tau, obs.row_mask, names)
    return fit, f"WLS of the {len(names)} base parameters chosen by the user"


def validation_problem(data, robot, idim_result, t0, T, model=None):
    eobs = data if isinstance(data, EffectObservation) else observe_effects(
        data, robot, idim_result.base, idim_result.settings)
    model0 = idim_result.model if model is None else model
    cols0 = idim_result.columns(model0.names)
    sig = signals_from_observation(eobs, cols0, model0.chi, model0.names, t0=t0, T=T, robot=robot)
    return Problem(eobs, sig, cols0, model0.names)


def delay_sigma(problem, state, d, weights):
    """(d, sigma_d): sigma from the curvature of the weighted SSE in d (white-noise formula)."""
    h = max(0.02 * abs(d), 0.5 / problem.eobs.fs)
    S = []
    for x in (d - h, d, d + h):
        S.append(weighted_sse(problem.design(x, state["effects"], cache=False, cols=state["cols"]),
                               problem.Y, problem.mask, weights))
    (sm, _), (s0, dof), (sp, _) = S
    curv = (sp - 2 * s0 + sm) / h ** 2
    if not curv > 0 or dof <= 0:
        return float(d), float("nan")
    # white-noise formula, inflated by the residual's integrated autocorrelation time
    X = problem.design(d, state["effects"], cache=False, cols=state["cols"])
    ri, rj = np.nonzero(problem.mask)
    A = X[ri, rj, :] * weights[rj][:, None]
    y = problem.Y[ri, rj] * weights[rj]
    r = np.zeros(problem.mask.shape)
    r[ri, rj] = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    n_eff, _, _, n_used = effective_sample_size(r, problem.mask)
    inflate = float(np.sum(n_used) / max(np.sum(n_eff), 1.0))
    return float(d), float(math.sqrt(2.0 * (s0 / dof) / curv * inflate))



def analyse_residual(obs, residual, eobs):
    fs = eobs.fs / max(1, int(obs.settings["nd"]))
    return analyze_residuals(residual, t=obs.t, q=obs.q, qd=obs.qd, mask=obs.row_mask, fs=fs)



def evaluate_effects(data, robot, idim_result, candidates, fit=None, *, signals_t0=None,
                     signals_T=None):
    """Errors of the model before/after effects on a recording (validation), or a fit on it.

    `data`: Experiment or EffectObservation of the recording (processed with
    `idim_result.settings`); `candidates`: the effects (columns built on
    this recording with the identification's model torque and time scale; a
    `time_delay` shifts the model's regressor); `fit`: the
    IdentificationResult of the essential model + effects (columns in that
    order). `signals_t0`/`signals_T`: the drift time scale (default this
    recording's; pass the identification's for validation data). Returns a
    dict with `before`/`after` `Errors`, the predictions, the
    design X and the EffectObservation.
    """
    prob = validation_problem(data, robot, idim_result, signals_t0, signals_T)
    delay, effects = split_delay(candidates)
    cols = None
    if fit is not None:
        # the fit's names: the model's base parameters, then the effects' (which may
        # reuse a base name, e.g. the offset effect's Off3 where the model has none)
        n_eff = sum(len(c.active_params) for c in effects)
        index = {n: k for k, n in enumerate(prob.all_names)}
        cols = [index[n] for n in fit.names[:len(fit.names) - n_eff]]
    X = prob.design(delay, effects, cache=False, cols=cols)
    model0 = idim_result.model
    pred_before = prob.X @ model0.chi
    pred_after = pred_before if fit is None else X @ fit.chi
    return {"before": errors_of(prob.Y, pred_before, prob.mask),
            "after": errors_of(prob.Y, pred_after, prob.mask),
            "pred_before": pred_before, "pred_after": pred_after, "eobs": prob.eobs,
            "source": prob.eobs.source, "X": X}


def split_delay(candidates):
    delay, effects = 0.0, []
    for c in candidates:
        if c.name == "time_delay":
            delay = float(c.nonlinear["d"])
        else:
            effects.append(c)
    return delay, effects


def fit_effects(data, robot, idim_result, candidates, uncertainty="classic"):
    """WLS of the essential model + the given effects on a recording: (IdentificationResult, ev),
    its covariance the option `uncertainty` (the estimate does not depend on it).

    For comparisons, e.g. the "true model" of a simulation (the injected
    effect with its true nonlinear parameter, linear parameters fitted).
    Effect columns already in the span of the model (and of the effects
    before them) are dropped, as in the diagnosis; the candidates passed are
    updated in place (`active`).
    """
    prob = validation_problem(data, robot, idim_result, None, None)
    delay, effects = split_delay(candidates)
    names, cols = (prob.names, prob.cols) if not delay else prob.essential(delay)
    X = prob.base(delay, cache=False, cols=cols)
    w = row_weights(idim_result.model)
    for c in effects:
        c.active = None
        D = prob.decimated([c])[0]
        keep = new_columns(X, D, prob.mask, w)
        if not keep:
            raise InputError(f"{c.label}: its columns are in the span of the model already")
        if len(keep) < D.shape[2]:
            c.active = keep
            D = D[:, :, keep]
        X = np.concatenate([X, D], axis=2)
    fit = fit_wls(X, prob.Y, prob.mask, prob.names_for(effects, names), uncertainty)
    ev = evaluate_effects(prob.eobs, robot, idim_result, candidates)
    return fit, ev


