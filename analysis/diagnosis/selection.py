"""Residual diagnosis: which unmodelled effect explains what an identified model leaves.

Starting from an IDIM identification (the essential WLS model of section 2 of
Gautier, Janot & Vandanjon 2010), every effect of `dynid.analysis.diagnosis.effects` on
every joint and at every value of its nonlinear parameter is a *candidate*:
extra regressor columns built at full rate and decimated with W
(`dynid.analysis.diagnosis.effect_observation`), or, for `time_delay`, the model
re-fitted on the regressor of the motion shifted by d. Greedy forward
selection:

1. score every candidate against the current model (below);
2. rank them by the evidence: the chi2_k tail of the likelihood-ratio statistic
   with the effective sample size (most significant first; not the relative
   CV gain, which favours effects on quiet joints and candidates scored
   against another baseline, such as time_delay's full base model);
3. take the best-ranked candidate that passes the selection rule and, with
   `base_guard`, is also significant against the *full base model* (so a
   rigid-body parameter the essential reduction dropped never returns as a
   "missing effect"); add it (its nonlinear parameter refined by a 1-D search:
   Stribeck's v_s, the delay d), re-identify by WLS (the starting model +
   the effects selected so far); with validation data and
   `confirm_on_validation`, keep it only if the validation error falls,
   otherwise try the next candidate that passes (up to `max_tries`);
4. stop when none passes (or none is confirmed), or after `max_effects`.

After the selection, catalogue-free tests of the final residual
(`dynid.analysis.diagnosis.structure`) report the joints whose residual
still has structure no selected effect explains (`result.unexplained`).

Selection rule (why it does not fool itself)
--------------------------------------------
The residual rows are serially correlated: the decimation filter spreads
each sample over its neighbours and, above all, any model error is a smooth
function of the motion. An F-test counting the rows as independent is far
too optimistic, and with ~200 candidates the best of them always looks
"significant". Two checks, both required:

* **Blocked cross-validation** (the ranking statistic). The decimated
  samples are cut into `folds` (5) contiguous time blocks. For each block
  the model, and the model + candidate, are fitted on the other blocks minus
  a guard of `gap` samples on each side of the held-out block (the
  decimation filter's half length: rows closer than that share full-rate
  samples), and predict the held-out block. `cv_gain` is the fraction of
  the held-out (WLS-weighted) squared error the candidate removes; the
  candidate must lower the held-out error in at least `folds - 1` blocks
  (it is not carried by one segment).
* **Likelihood-ratio test with the effective sample size, Bonferroni over
  the candidates.** `LR = Σ_j n_eff,j (SSE0_j - SSE1_j) / SSE1_j`, with
  `n_eff,j = n_j / tau_int,j` the effective sample size of the candidate
  model's residual on joint j (`dynid.analysis.statistics.residuals.effective_sample_size`):
  the χ² statistic of adding k parameters, divided by the integrated
  autocorrelation time. Under "nothing is missing" LR is (conservatively)
  χ²_k; the p-value is multiplied by the number m of candidates scored at
  that step (Bonferroni, valid for correlated candidates) and must be below
  `alpha` (0.01 by default), so the chance of adding *anything* to a
  complete model is at most about alpha per step, whatever the number of
  candidates.

Measured false-alarm rate (simulated TX40 with nothing missing, 12 s + 5 s at
5 kHz, `benchmarks/diagnosis_campaign.py`). With alpha = 0.05: 2 of 50 runs
(seeds 1-50) and 1 of 100 (seeds 51-150) selected an effect, 2 % overall,
within the design level but one alarm from the benchmark's 5 % limit; the
step-1 winner's Bonferroni p was below 0.1 in 4 % of the runs (the test is
conservative, as Bonferroni over correlated candidates should be). The
default alpha = 0.01 was chosen after that measurement. With it: 1 of 50
(seeds 1-50) and 0 of 100 (seeds 51-150), 1 in 150 overall; every injected
effect of the campaign (2-10 % of its joint's torque RMS) is still found, its
smallest likelihood ratio (48, a 2-4 % spring) far above the threshold (~16).

Also reported: `ic_gain` = LR - k ln(n_eff) (BIC computed with the effective
sample size; positive favours the candidate).

Time delay. A delay is tested within the *full base model* (all base
parameters plus the effects so far, on W(t - d) against W(t); one degree of
freedom): the essential set was chosen by backward elimination on the
misaligned data and may lack parameters the aligned model needs (measured:
tested within the essential model, an 11.8 ms delay was estimated at 2.6 ms).
Once a delay is accepted the essential parameters are re-selected on the
re-aligned data, as IDIM would do on aligned data.

Candidates that explain the same thing are told apart by their shape: the
report ranks them by cv_gain and gives the gap between the winner and the
runner-up (the best candidate of another effect or joint) and the fraction
of held-out blocks in which the winner predicts better than the runner-up.
Candidates with the same columns on these data (`offset` and
`asymmetric_coulomb` of one joint: see `dynid.analysis.diagnosis.effects`) cannot be
told apart by any data of a moving joint; they are reported as aliases.
A candidate whose columns are already in the span of the model (e.g.
`offset` where the model has `Off_j`) is skipped. One that keeps less than
`SEPARABLE_MIN` (1 %) of its torque outside that span (`scoring.separability`)
passes the rule but is not added, naming the model parameter it nearly equals:
on the LWR4+ recording 1, where qd2 and qd5 correlate to 0.99999, a coupling on
joint 5 from qd2 (0.33 % outside) came with Cv5_2 = -110 and Fv5 = +107 N m s/rad,
absurd values that cancel. On the TX40 example and on 3 seeds of each effect of the
simulated campaign (benchmarks/diagnosis_campaign.py) the effects added keep 10-99 %
outside.

Code layout (one job per module): the candidate set (effects.py, effect_observation.py),
the data and model fits (problem.py), scoring (scoring.py), the selection rule (rule.py),
refinement of a nonlinear parameter (refine.py), notes on effects (notes.py), the structure
tests (structure.py), the hidden-effects route (hidden.py), the result objects (results.py,
summary_text.py). This module runs the stages in order.

Why one module above 800 lines: its docstring is the method's description (the selection rule
and why it does not fool itself, about 100 lines), and the greedy loop, the decision of one
step and the confirmation on validation data share one private selection state.
"""
from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.diagnosis.effect_observation import EffectObservation, observe_effects
from dynid.analysis.diagnosis.effects import (
    DELAY_GRID,
    STRIBECK_GRID,
    candidate_set,
    signals_from_observation,
)
from dynid.analysis.diagnosis.findings import TIME_VARYING, cut_effects, findings_not_added
from dynid.analysis.diagnosis.hidden import hidden_effects, physical_effects
from dynid.analysis.diagnosis.hypotheses import attach_findings, gear_ratios_of, name_flags
from dynid.analysis.diagnosis.notes import effect_title, onset_note, physics_note
from dynid.analysis.diagnosis.problem import (
    Problem,
    analyse_residual,
    delay_sigma,
    evaluate_effects,
    fit_effects,
    fit_wls,
    full_rate_residual,
    identify_from_observation,
    row_weights,
    start_model_fit,
    validation_problem,
    without_parameters,
)
from dynid.analysis.diagnosis.refine import refine_candidate
from dynid.analysis.diagnosis.rest import rest_phases
from dynid.analysis.diagnosis.results import (
    DiagnosisResult,
    DiagnosisStep,
    RankedEffect,
    SelectedEffect,
    errors_of,
    nonlinear_text,
)
from dynid.analysis.diagnosis.rule import (
    RULE,
    by_base_evidence,
    cand_needs_guard,
    group_key,
    passes_rule,
    rank_candidates,
    set_runner_up,
    spring_before_ripple,
)
from dynid.analysis.diagnosis.scoring import ALIAS_RTOL, Scorer, chi2_logsf, separability, shift_scores
from dynid.analysis.diagnosis.settings import DiagnosisSettings
from dynid.analysis.diagnosis.structure import position_noise_residual, residual_structure
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import EXACT_FIT, essential_parameters, with_selection_bias
from dynid.analysis.estimators.idim import identify_idim
from dynid.analysis.estimators.physical import require_cvxpy
from dynid.analysis.processing.decimation import DecimationFilter
from dynid.analysis.results import p_phrase
from dynid.dynamics.base_parameters import base_parameters
from dynid.errors import DataError, DynidError, IdentificationError, InputError
from dynid.ranges import check_joints
from dynid.threads import single_blas_thread

__all__ = ["diagnose", "run_diagnosis", "DiagnosisSettings", "DiagnosisResult", "RankedEffect",
           "SelectedEffect", "DiagnosisStep", "without_parameters", "identify_from_observation",
           "evaluate_effects", "fit_effects", "RULE", "chi2_logsf", "nonlinear_text"]

#: A candidate keeps at least this fraction of its (weighted) torque outside what the model's
#: parameters give (`scoring.separability`), or it is not added: below it, its size and the
#: parameters it nearly equals are told apart by noise alone (their σ grow as 1 / fraction).
SEPARABLE_MIN = 0.01


# ======================================================================= API
def diagnose(experiment, robot, *, validation=None, idim_result=None, settings=None, effects=None,
             max_effects=3, rng=None, alpha=0.01, folds=5, gap="auto", exclude_parameters=None,
             joints=None, residual_analysis=True, confirm_on_validation=True, max_error_growth=0.02,
             progress=None, structure_tests=True, start_model="essential", base_guard=True,
             max_tries=5, hidden_tests=True, physical_tests=True, reselect_essential=True,
             gear_ratios=None, rest_phases=True, observation=None, uncertainty="classic"):
    """Find what the identified model of `robot` lacks in `experiment`.

    Parameters
    ----------
    experiment : Experiment, or the `EffectObservation` of one (to reuse its full-rate work)
    robot : Robot
    validation : Experiment or EffectObservation, optional
        Data the model was not fitted to: errors before/after are reported on it too.
    idim_result : IDIMResult, optional
        The identification to start from (default: `dynid.analysis.estimators.idim.identify_idim`
        of `experiment`, or of its observation).
    settings : processing overrides for that identification (as `identify_idim`).
    effects : names of the effects to consider (default all of `EFFECT_NAMES`).
    max_effects : most effects added (greedy forward selection).
    rng : accepted for API stability; the procedure is deterministic (contiguous folds).
    alpha : family-wise level of the LR test at each step (Bonferroni over the candidates);
        0.01 by default (see the module docstring for the measured false-alarm rate).
    folds, gap : blocked cross-validation: number of contiguous blocks, and
        guard in decimated samples dropped from training on each side of the
        held-out block ("auto": the decimation filter's half length).
    exclude_parameters : base parameters (names or prefixes, e.g. `("Off",)`) removed
        from the model before identifying (only when `idim_result` is None).
    joints : 1-based joints whose effects are considered (default all).
    residual_analysis : compute the residual analyses before/after (for reports).
    max_error_growth : essential-parameter criterion of that identification (when
        `idim_result` is None).
    progress : callable(fraction in [0, 1]) through the stages (`STAGES`): the data and
        candidates, each candidate tried at each selection step (at most `max_effects + 1`
        steps), the re-selection, the structure, hidden-effect and rest-phase tests; 1.0 at
        the end. The CLI and `dynid.report` pass a `dynid.progress.task` (a bar on a
        terminal, logging records elsewhere, silenced by `dynid.progress.silence()`).
    structure_tests : run the catalogue-free tests of the final residual
        (`dynid.analysis.diagnosis.structure`); joints with structure no selected
        effect explains are in `result.unexplained`.
    hidden_tests : when the identified parameters contradict `robot.apriori`, fit with the
        a-priori values as a prior and test gravity-shaped springs the base parameters
        absorbed (`dynid.analysis.diagnosis.hidden`); found ones are in `result.hidden`.
    reselect_essential : with `start_model="essential"` and effects selected, re-select the
        essential parameters on the torque less those effects (kept if the validation error
        does not grow); the reduction of the identification ran with their torque in the residual.
    physical_tests : when no a-priori test found one and PC-WLS (cvxpy) says the data want a model
        no rigid body has, test the same springs on the physically consistent fit
        (`dynid.analysis.diagnosis.hidden.physical_effects`); found ones are in
        `result.hidden` too (`route="physical"`).
    start_model : the model the selection starts from: `"essential"` (default: the
        essential WLS of the identification), `"base"` (all base parameters, WLS), or a
        list of base-parameter names (the set the user chose).
    base_guard : a candidate is added only if it is also significant (LR with n_eff,
        Bonferroni, alpha) against the *full base model* plus the effects so far, so that a
        rigid-body parameter the essential reduction dropped never comes back as a
        "missing effect" (e.g. a coupling from qdd restoring a dropped inertia term).
        Why not `start_model="base"` by default: measured on the independent plant (8 s,
        179 decimated samples, 60 base parameters) the blocked CV of the full base model is
        dominated by the held-out variance of its poorly excited parameters (an injected
        4 N m Stribeck friction: CV gain -1.4 %, LR 345), while the guard keeps the
        essential model's CV and still rejects what the dropped parameters explain.
    max_tries : at each step, how many candidates that pass the rule are tried, best
        ranked first, until one lowers the validation error (with `confirm_on_validation`).
    confirm_on_validation : with `validation`, keep an effect that passes the rule only if
        it also lowers the relative error norm on the validation data; otherwise the next
        candidate that passes the rule is tried (up to `max_tries`), and the selection
        stops when none does. Blocked cross-validation inside one recording cannot see a
        pattern that holds in that recording only (on the real TX40, a 4th effect passes
        the rule but raises the error on the held-out 3 s). The validation errors after
        are then no longer independent of the selection; `False` keeps them so.
    gear_ratios : gear ratios of the joints' motors: a flagged line at a harmonic of the motor
        turn is named as such (default: the data description's `[transmission]`).
    rest_phases : with validation data, choose the friction at rest per joint on the
        identification's rest rows and report the held-out error on all samples before/after
        and its rest-phase share (`dynid.analysis.diagnosis.rest`).
    observation : EffectObservation, optional
        `observe_effects` of `experiment` with `idim_result`'s base parameters and settings,
        already built (e.g. the one `idim_result` was identified from: `dynid diagnose`
        builds the full-rate regressor once); default: built here.
    uncertainty : {"classic", "hac", "bootstrap"}
        Covariance of the identification made here when `idim_result` is None (as
        `identify_idim`); the final model's σ take it. The decisions are taken on the
        classic one either way. `dynid.diagnose` gives the run's default (bootstrap).

    Returns
    -------
    DiagnosisResult
    """
    del rng  # deterministic procedure
    opts = DiagnosisSettings(
        effects=effects, max_effects=max_effects, alpha=alpha, folds=folds, gap=gap,
        exclude_parameters=exclude_parameters, joints=joints, residual_analysis=residual_analysis,
        confirm_on_validation=confirm_on_validation, max_error_growth=max_error_growth,
        structure_tests=structure_tests, start_model=start_model, base_guard=base_guard,
        max_tries=max_tries, hidden_tests=hidden_tests, physical_tests=physical_tests,
        reselect_essential=reselect_essential, processing=settings, gear_ratios=gear_ratios,
        rest_phases=rest_phases, uncertainty=uncertainty)
    return run_diagnosis(experiment, robot, opts, validation=validation, idim_result=idim_result,
                         progress=progress, observation=observation)


def run_diagnosis(experiment, robot, opts=None, *, validation=None, idim_result=None, progress=None,
                  observation=None):
    """`diagnose` with its settings in one `DiagnosisSettings` object.

    Parameters
    ----------
    experiment, robot, validation, idim_result, progress, observation : as `diagnose`.
    opts : DiagnosisSettings, optional (default: the defaults of `diagnose`).

    Returns
    -------
    DiagnosisResult
    """
    if isinstance(experiment, (list, tuple)) or isinstance(validation, (list, tuple)):
        raise InputError("diagnose takes one recording (and one validation recording): the "
                         "drift and time-delay effects are defined per recording")
    opts = (opts or DiagnosisSettings()).checked()
    if opts.joints is not None:
        opts = dataclasses.replace(opts, joints=tuple(check_joints(opts.joints, robot.n_joints, robot=robot.name)))
    # one BLAS thread for the whole diagnosis, not only its scoring: its dense problems are
    # tall and thin (hundreds of QRs and fits of a few thousand rows), where a second
    # OpenBLAS thread spins on a busy machine without speeding anything up (dynid.threads)
    with single_blas_thread():
        return _run(experiment, robot, opts, validation, idim_result, progress, observation)


def _run(experiment, robot, opts, validation, idim_result, progress, observation):
    """`run_diagnosis` with checked settings, inside one BLAS thread."""
    stage = _Progress(progress)
    setup = prepare(experiment, robot, opts, validation=validation, idim_result=idim_result,
                    observation=observation)
    stage("selection", 0.0)
    sel = select_effects(setup, opts, stage)
    stage("reselection", 0.0)
    if opts.start_model == "essential" and sel.state["effects"] and opts.reselect_essential:
        reselect_essential(setup, opts, sel)
    out = assemble(experiment, robot, setup, opts, sel, stage)
    stage("done", 0.0)
    return out


#: (stage, share of the work) in order: measured on the real TX40 (--holdout 3, 2 cores
#: shared), the scoring of the selection steps takes most of the time
STAGES = (("data", 0.15), ("selection", 0.6), ("reselection", 0.05), ("structure", 0.1),
          ("hidden", 0.05), ("rest", 0.05), ("done", 0.0))


class _Progress:
    """`stage(name, fraction of that stage)` -> `progress(overall fraction)`, never backwards."""

    def __init__(self, progress):
        self.progress = progress
        self.start, acc = {}, 0.0
        for name, share in STAGES:
            self.start[name] = (acc, share)
            acc += share
        self.last = 0.0

    def __call__(self, name, fraction):
        if self.progress is None:
            return
        a, share = self.start[name]
        f = 1.0 if name == "done" else min(max(a + share * min(max(fraction, 0.0), 1.0), self.last), 0.99)
        self.last = f
        self.progress(f)


# ======================================================================= stage 1: the data
@dataclass
class Setup:
    """Everything the selection works on: the identification, the starting model, the
    candidate set and the decimated data (identification and validation)."""

    eobs: EffectObservation
    idim_result: object
    model0: object               # IdentificationResult the selection starts from
    model_text: str
    cols0: np.ndarray
    names0: list
    cands: list                  # Candidate
    problem: Problem
    qd_peak: np.ndarray
    folds: int
    gap: int
    vprob: Problem | None
    notices: list = field(default_factory=list)
    validation: object = None    # the validation data as given


def prepare(experiment, robot, opts, *, validation=None, idim_result=None, observation=None):
    """Identify (unless given), build the candidate set and the decimated data: `Setup`.
    `observation`: the identification data's `EffectObservation`, when already built."""
    notices = []
    eobs, idim_result = _identification(experiment, robot, opts, idim_result, notices, observation)
    obs = eobs.obs
    ref = idim_result.observation
    if ref.tau.shape != obs.tau.shape or not np.allclose(ref.tau, obs.tau, rtol=1e-9, atol=1e-12):
        raise DataError("idim_result was not identified from this experiment (its observation system "
                        "differs); pass the matching idim_result or none")
    model0, model_text = start_model_fit(idim_result, obs, opts.start_model)
    names0 = list(model0.names)
    cols0 = idim_result.columns(names0)
    sig = signals_from_observation(eobs, cols0, model0.chi, names0, t0=eobs.t_start, T=eobs.duration,
                                   robot=robot)
    peak = np.abs(eobs.qd).max(axis=0)
    cands = candidate_set(sig, opts.effects, joints=opts.joints, qd_peak=peak)
    problem = Problem(eobs, sig, cols0, names0)
    problem.decimated([c for c in cands if c.name != "time_delay"])
    folds, gap = _folds_and_gap(eobs, opts, notices)
    vprob = None
    if validation is not None:
        vprob = validation_problem(validation, robot, idim_result, eobs.t_start, eobs.duration,
                                   model=model0)
    return Setup(eobs=eobs, idim_result=idim_result, model0=model0, model_text=model_text,
                 cols0=np.asarray(cols0), names0=names0, cands=cands, problem=problem, qd_peak=peak,
                 folds=folds, gap=gap, vprob=vprob, notices=notices, validation=validation)


def _identification(experiment, robot, opts, idim_result, notices, observation=None):
    """(EffectObservation, IDIMResult) of the identification data (`observation`: its
    EffectObservation when the caller built it, with `idim_result`)."""
    if isinstance(experiment, EffectObservation):
        if idim_result is None:
            idim_result = identify_from_observation(experiment, robot,
                                                    max_error_growth=opts.max_error_growth)
        return experiment, idim_result
    if idim_result is None:
        bp = base_parameters(robot)
        if opts.exclude_parameters:
            bp = without_parameters(bp, opts.exclude_parameters)
            notices.append("model identified without the base parameters "
                           + ", ".join(opts.exclude_parameters))
        idim_result = identify_idim(experiment, robot, settings=opts.processing, bp=bp,
                                    max_error_growth=opts.max_error_growth, uncertainty=opts.uncertainty)
    if observation is not None:
        if observation.bp is None or list(observation.bp.names) != list(idim_result.base.names):
            raise DataError("observation has other base parameters than idim_result; pass the "
                            "matching observation or none")
        return observation, idim_result
    return observe_effects(experiment, robot, idim_result.base, idim_result.settings), idim_result


def _folds_and_gap(eobs, opts, notices):
    """(folds, gap) of the blocked CV: gap "auto" is the decimation filter's half length."""
    obs = eobs.obs
    nd = int(obs.settings["nd"])
    gap = opts.gap
    if gap == "auto":
        gap = 2
        if nd > 1:
            filt = DecimationFilter(nd, eobs.fs, obs.settings["f_decimation_cutoff"])
            gap = max(2, int(math.ceil(filt.half_length / nd)))
    gap = int(gap)
    folds = opts.folds
    M = obs.W.shape[0]
    if M < folds * (2 * gap + 10):
        old = folds
        folds = max(3, M // (2 * gap + 10))
        notices.append(f"only {M} decimated samples: {folds} CV blocks instead of {old}")
    return folds, gap


# ======================================================================= stage 2: selection
@dataclass
class Selection:
    """The state of the greedy forward selection (the model after the last accepted step)."""

    state: dict                  # delay, effects, fit, cols, names
    history: list                # the state after each step
    selected: list = field(default_factory=list)   # (Candidate, step, RankedEffect)
    steps: list = field(default_factory=list)      # DiagnosisStep
    last_scored: dict = field(default_factory=dict)
    val_prev: float = float("nan")                 # validation error of the current model


def select_effects(setup, opts, progress=None):
    """The greedy forward selection (module docstring): `Selection`. `progress`: callable(stage,
    fraction) (`_Progress`), or None."""
    model0 = setup.model0
    state = {"delay": 0.0, "effects": [], "fit": model0, "cols": np.asarray(setup.cols0),
             "names": list(setup.names0)}
    sel = Selection(state=state, history=[dict(state)])
    vprob = setup.vprob
    if vprob is not None:
        sel.val_prev = errors_of(vprob.Y, vprob.X @ model0.chi, vprob.mask).rel_error
    chosen_families = set()
    step = 0
    while True:
        step += 1
        pool = [c for c in setup.cands if c.family not in chosen_families]
        if not pool:
            break
        weights = row_weights(sel.state["fit"])
        n_steps = opts.max_effects + 1
        scorer, ranking, skipped, m = _score_pool(setup, sel.state, pool, weights, step, opts.alpha)
        if progress is not None:
            progress("selection", (step - 0.5) / n_steps)
        for r in ranking:
            sel.last_scored[group_key(r.candidate)] = r
        st = DiagnosisStep(step=step, ranking=ranking, n_candidates=m, skipped=skipped,
                           accepted=False, reason="")
        sel.steps.append(st)
        accepted = _decide_step(setup, opts, sel, st, scorer, weights, m)
        if progress is not None:
            progress("selection", step / n_steps)
        if accepted is None:
            break
        w, cand, new_state, note = accepted
        if note:
            setup.notices.append(note)
        w.selected = True
        chosen_families.add(cand.family)
        sel.state = new_state
        sel.history.append(new_state)
        sel.selected.append((cand, step, w))
    return sel


def _score_pool(setup, state, pool, weights, step, alpha):
    """Score every candidate of `pool` against the model `state`: (scorer, ranking, skipped, m)."""
    problem, folds, gap = setup.problem, setup.folds, setup.gap
    col_pool = [c for c in pool if c.name != "time_delay"]
    shift_pool = [c for c in pool if c.name == "time_delay"]
    X = problem.design(state["delay"], state["effects"], cols=state["cols"])
    scorer = Scorer(X, problem.Y, problem.mask, weights, folds, gap)
    scores = scorer.score([scorer.rows(D) for D in problem.decimated(col_pool)])
    mc = len(col_pool)
    scores["err0"] = np.repeat(scores["err0"][:, None], mc, axis=1)
    scores["res0"] = np.repeat(scores["res0"][:, None], mc, axis=1)
    if shift_pool:
        err_s, res_s, e0, r0 = shift_scores(problem, state, [c.nonlinear["d"] for c in shift_pool],
                                            weights, folds, gap)
        ms = len(shift_pool)
        scores["err"] = np.concatenate([scores["err"], err_s], axis=1)
        scores["res"] = np.concatenate([scores["res"], res_s], axis=1)
        scores["err0"] = np.concatenate([scores["err0"], np.repeat(e0[:, None], ms, 1)], axis=1)
        scores["res0"] = np.concatenate([scores["res0"], np.repeat(r0[:, None], ms, 1)], axis=1)
        scores["active"] = scores["active"] + [[0]] * ms   # one degree of freedom
    ranking, skipped, m = rank_candidates(col_pool + shift_pool, scores, scorer, step, alpha, folds)
    return scorer, ranking, skipped, m


def _decide_step(setup, opts, sel, st, scorer, weights, m):
    """Apply the selection rule to a scored step: (winner, candidate, new state, note) or None
    (the selection stops; `st.reason` says why)."""
    ranking, alpha, folds = st.ranking, opts.alpha, setup.folds
    if not ranking:
        st.reason = "no candidate outside the model's span"
        return None
    passing = [r for r in ranking if passes_rule(r, alpha, folds)[0]]
    if not passing:
        st.accepted, st.reason = passes_rule(ranking[0], alpha, folds)
        return None
    fit_error = float(getattr(sel.state["fit"], "rel_error", np.nan))
    if fit_error < EXACT_FIT:
        # the tests compare the candidates with the residual's own spread: without noise, that
        # is rounding and integration error, and rounding-sized structure passes them all
        st.reason = (f"the model fits the recording to {100 * fit_error:.2g} % of the torque (an exact fit, "
                     f"below {100 * EXACT_FIT:g} %: little or no noise); what passes the rule is the size "
                     f"of rounding, and nothing is added")
        return None
    # a change during this recording (drift, warm-up) is a finding, never part of a model
    # that predicts another recording: a validation recording that happens to drift the
    # same way from its own start (a plant warming up in every run) would otherwise
    # confirm it (issue 27 item 2; findings.py)
    changing = [r for r in passing if r.name in TIME_VARYING]
    passing = [r for r in passing if r.name not in TIME_VARYING]
    problem, state = setup.problem, sel.state
    reduced = opts.base_guard and len(state["cols"]) < len(problem.all_cols)
    guard = (Scorer(problem.design(state["delay"], state["effects"], cols=problem.all_cols),
                    problem.Y, problem.mask, weights, folds, setup.gap)
             if reduced and (passing or changing) else None)
    if guard is not None and changing:
        # a finding is named only if the full base model confirms it too, as an added effect
        # must be (`base_p`, read by findings_not_added): a friction drift that only restores
        # what the essential reduction dropped is no finding (simulated LWR4+, seed 4, joint 7)
        by_base_evidence(problem, guard, changing, m)
    if not passing:
        named = [r for r in changing if not (np.isfinite(r.base_p) and not r.base_p < alpha)]
        st.reason = (f"only time-varying effects pass the rule ({', '.join(r.label for r in changing[:3])}): "
                     + ("named as findings, not added" if named else
                        "none is significant against the full base model, so none is named"))
        return None
    spans = np.ptp(np.asarray(problem.signals.q, float), axis=0)
    if st.step > opts.max_effects:
        st.chosen = spring_before_ripple(passing, spans)[0][0]
        set_runner_up(st, ranking)
        st.reason = f"passes the rule, but max_effects = {opts.max_effects} effects were added already"
        return None
    if reduced:
        passing = by_base_evidence(problem, guard, passing, m)
    passing, moved = spring_before_ripple(passing, spans)
    before = {id(spring): (label, why) for spring, label, why in moved}
    for w in passing[:opts.max_tries]:
        st.chosen = w
        set_runner_up(st, ranking)
        if id(w) in before:
            st.reordered.append(before[id(w)])
        if reduced and cand_needs_guard(w) and not w.base_p < alpha:
            st.tried.append((w.candidate.label,
                             f"not significant against the full base model ({p_phrase(w.base_p, 'Bonferroni p')}): "
                             f"it restores base parameters the essential "
                             f"reduction dropped"))
            continue
        trial = _trial(setup, opts, sel, scorer, weights, w)
        if trial is None:
            continue
        st.accepted = True
        st.reason = "passes: CV gain > 0 in enough blocks and Bonferroni p < alpha" + (
            "" if len(st.tried) == 1 else
            f" (after {len(st.tried) - 1} better-ranked candidate(s) were rejected: "
            + "; ".join(f"{a}: {b}" for a, b in st.tried[:-1]) + ")") + (
            f"; tried before {before[id(w)][0]}: {before[id(w)][1]}" if id(w) in before else "")
        return trial
    st.accepted = False
    st.reason = ("passes the rule, but the validation error does not fall: not kept"
                 if len(st.tried) == 1 and "validation" in st.tried[0][1] else
                 f"{len(st.tried)} candidate(s) pass the rule, but none is kept: "
                 f"{'; '.join(f'{a}: {b}' for a, b in st.tried)}")
    return None


def _trial(setup, opts, sel, scorer, weights, w):
    """Add the passing candidate `w` (nonlinear parameter refined) and refit; with validation
    data keep it only if the validation error falls: (w, candidate, state, note) or None."""
    problem, state, vprob = setup.problem, sel.state, setup.vprob
    st = sel.steps[-1]
    cand = refine_candidate(problem, scorer, w.candidate, state, weights)
    w.candidate = cand
    w.nonlinear = dict(cand.nonlinear)
    trial = dict(state)
    note = None
    if cand.name == "time_delay":
        # re-align, then re-select the essential parameters as IDIM would on aligned data
        trial["delay"] = float(cand.nonlinear["d"])
        essential = opts.start_model == "essential"
        if essential:
            trial["names"], trial["cols"] = problem.essential(trial["delay"])
        note = (f"time delay {1e3 * trial['delay']:.3g} ms: "
                + (f"essential parameters re-selected on the re-aligned data "
                   f"({len(trial['names'])} parameters)" if essential
                   else "model re-fitted on the re-aligned data"))
    else:
        why = _not_separable(problem, state, cand, weights)
        if why:
            st.tried.append((cand.label, why))
            return None
        trial["effects"] = trial["effects"] + [cand]
    Xn = problem.design(trial["delay"], trial["effects"], cols=trial["cols"])
    trial["fit"] = fit_wls(Xn, problem.Y, problem.mask, problem.names_for(trial["effects"], trial["names"]))
    if vprob is not None and opts.confirm_on_validation:
        Xv = vprob.design(trial["delay"], trial["effects"], cols=trial["cols"])
        val_new = errors_of(vprob.Y, Xv @ trial["fit"].chi, vprob.mask).rel_error
        if not val_new < sel.val_prev:
            st.tried.append((cand.label, f"validation error does not fall "
                                         f"({100 * sel.val_prev:.3f} % -> {100 * val_new:.3f} %)"))
            return None
        sel.val_prev = val_new
    st.tried.append((cand.label, "added"))
    return w, cand, trial, note


def _not_separable(problem, state, cand, weights):
    """Why candidate `cand` cannot be told apart from the model's parameters in this data
    (`scoring.separability` below `SEPARABLE_MIN`), or "" when it can."""
    X = problem.design(state["delay"], state["effects"], cols=state["cols"])
    frac, terms = separability(X, problem.decimated([cand])[0], problem.mask, weights)
    if frac >= SEPARABLE_MIN:
        return ""
    names = problem.names_for(state["effects"], state["names"])
    what = (names[terms[0][0]] if len(terms) == 1 else
            "a mix of " + ", ".join(f"{names[i]} ({100 * sh:.0f} %)" for i, sh in terms)) if terms else "the model"
    return (f"nearly the same signal as {what} in this recording ({100 * frac:.2g} % of its torque lies "
            f"outside what the model already gives): their sizes cannot be told apart, and both would "
            f"take values that cancel; not added. Record motion that separates them")


# ======================================================================= stage 3: essential set
def reselect_essential(setup, opts, sel):
    """Re-select the essential parameters on the torque less the selected effects (in place).

    The essential reduction of the identification ran with the effects' torque still in the
    residual, where it dominates the error criterion: parameters whose torque is small
    against it were dropped although the data determine them (independent plant, KUKA
    LWR4+ with a 3 N m Stribeck friction on joint 2: found exactly, Fs 3.02, v_s 0.202,
    but the held-out RMS of joints 3, 4 stayed 0.044, 0.038 N m against 0.015, 0.017 for
    the true model). Re-selected as IDIM would on the torque less the selected effects,
    then refitted with them; kept if the validation error does not grow. The effects'
    torque is taken from a fit with the full base model: fitted beside an essential set
    that lacks a term the effect needs (a spring's rest position needs Off_j), the
    effect's own parameters take part of that term, the torque less the effects keeps
    too little of it, and the re-selection leaves it out again (TX40 plant, spring on
    joint 4, seed 8: Off4 stayed out, held-out RMS of joint 4 0.31 N m against 0.012).
    """
    problem, state, vprob = setup.problem, sel.state, setup.vprob
    nb = len(problem.all_cols)
    X_e = problem.design(state["delay"], state["effects"], cols=problem.all_cols)
    fit_full = fit_wls(X_e, problem.Y, problem.mask, problem.names_for(state["effects"], problem.all_names))
    tau_e = X_e[:, :, nb:] @ np.asarray(fit_full.chi[nb:])
    ess = essential_parameters(problem.base(state["delay"], cols=problem.all_cols),
                               problem.Y - tau_e, problem.all_names, ls.wls,
                               max_error_growth=opts.max_error_growth, row_mask=problem.mask)
    index = {nm: k for k, nm in enumerate(problem.all_names)}
    names_e = list(ess.result.names)
    if set(names_e) == set(state["names"]):
        return
    trial = dict(state, names=names_e, cols=np.array([index[nm] for nm in names_e], dtype=int))
    trial["fit"] = fit_wls(problem.design(trial["delay"], trial["effects"], cols=trial["cols"]),
                           problem.Y, problem.mask, problem.names_for(trial["effects"], trial["names"]))
    if vprob is not None:
        Xv = vprob.design(trial["delay"], trial["effects"], cols=trial["cols"])
        if not errors_of(vprob.Y, Xv @ trial["fit"].chi, vprob.mask).rel_error <= sel.val_prev:
            return
    setup.notices.append(f"essential parameters re-selected on the torque less the selected "
                         f"effects: {len(state['names'])} -> {len(names_e)} parameters")
    sel.state = trial
    sel.history[-1] = trial


# ======================================================================= stage 4: report assembly
def assemble(experiment, robot, setup, opts, sel, stage=None):
    """The `DiagnosisResult`: effects added, errors, ranking, structure and hidden-effect tests.
    `stage`: callable(stage, fraction) reporting progress (`_Progress`), or None."""
    stage = stage or (lambda name, fraction: None)
    state = sel.state
    model_after = _reported_fit(setup, state)
    errors, residuals, path, vsource = _errors_and_path(setup, opts, sel)
    cfg = _settings_record(setup, opts)
    cfg["parameters_uncertainty"] = (model_after.settings.get("least_squares", {}).get("uncertainty", {})
                                     .get("uncertainty", "classic"))
    test_state, test_fit = _test_model(setup.problem, state)
    structure = None
    stage("structure", 0.0)
    fit_error = float(getattr(state["fit"], "rel_error", np.nan))
    exact = fit_error < EXACT_FIT
    if opts.structure_tests and exact:
        setup.notices.append(f"structure tests of the final residual not run: the model fits the recording to "
                             f"{100 * fit_error:.2g} % of the torque (an exact fit, below {100 * EXACT_FIT:g} %: "
                             "little or no noise), and the residual's structure is that of rounding")
    if opts.structure_tests and not exact:
        structure = _structure(experiment, robot, setup, opts, sel, test_state, test_fit)
        cfg["structure_rule"] = structure.rule
        cfg["structure_model"] = ("full base model" if test_state is not state else "final model") + (
            " plus the selected effects" if state["effects"] else "")
        gear = opts.gear_ratios
        if gear is None and not isinstance(experiment, EffectObservation):
            gear = gear_ratios_of(experiment)
        structure.hypotheses = name_flags(structure, setup.eobs, gear_ratios=gear,
                                          model_names=list(test_fit.names), model_values=test_fit.chi)
    stage("hidden", 0.0)
    hidden = _hidden(robot, setup, opts, state, test_state, test_fit)
    ranking = _final_ranking(sel)
    cut = cut_effects(sel.steps, opts.max_effects)
    findings = findings_not_added(setup.problem, state, ranking, cut, structure, alpha=opts.alpha, exact=exact)
    attach_findings(structure, findings)
    stage("rest", 0.0)
    rest = _rest(experiment, robot, setup, opts)
    stage("rest", 1.0)
    return DiagnosisResult(hidden_tests=hidden, robot_name=robot.name, source=setup.eobs.source,
                           ranking=ranking, steps=sel.steps, structure=structure,
                           findings=findings, cut=cut,
                           rest=rest,
                           selected=_selected_effects(setup, state, sel.selected, model_after),
                           model_before=setup.model0, model_after=model_after,
                           errors=errors, settings=cfg, idim=setup.idim_result, residuals=residuals,
                           validation_source=vsource, notices=setup.notices, path=path,
                           data_hash=getattr(setup.idim_result, "data_hash", "") or "")


def _reported_fit(setup, state):
    """The final model's fit as reported: the selection's own WLS, with the covariance of the
    identification it started from (`uncertainty`: the same estimate, the decisions taken on
    the classic one are unchanged). For a robust option, by the rule of the identification's
    essential parameters (`essential.with_selection_bias`): the covariance of the same
    parameters in the full base model with the same effects, plus the bias of the base
    parameters left out; without it, the essential model's own sigma would read as better
    identified after the diagnosis than before for that reason alone."""
    fit = state["fit"]
    uncertainty = getattr(setup.idim_result, "uncertainty", "classic")
    if uncertainty == "classic":
        return fit
    problem = setup.problem
    X = problem.design(state["delay"], state["effects"], cols=state["cols"])
    robust = ls.wls(X, problem.Y, list(fit.names), row_mask=problem.mask, joint_sigma=fit.joint_sigma,
                    uncertainty=uncertainty)
    if not np.allclose(robust.chi, fit.chi, rtol=1e-8, atol=1e-12 * max(1.0, float(np.abs(fit.chi).max()))):
        return fit      # not the same weighted problem: keep the fit the decisions were taken on
    names_full = problem.names_for(state["effects"], problem.all_names)
    if list(fit.names) != names_full:
        try:
            full = ls.wls(problem.design(state["delay"], state["effects"], cols=problem.all_cols), problem.Y,
                          names_full, row_mask=problem.mask, joint_sigma=fit.joint_sigma, uncertainty=uncertainty)
        except IdentificationError:
            setup.notices.append("the final model's sigma is its own robust one: the full base model with the "
                                 "selected effects cannot be identified, so the bias of the parameters left out "
                                 "is not added")
        else:
            robust = with_selection_bias(robust, full, [names_full.index(n) for n in fit.names])
    robust.data_hash = getattr(fit, "data_hash", "")
    return robust


def _selected_effects(setup, state, selected, model_after):
    """`SelectedEffect` per added effect, with its parameters in the final model (`model_after`)."""
    problem = setup.problem
    X_after = problem.design(state["delay"], state["effects"], cols=state["cols"])
    out = []
    for cand, step, _ in selected:
        if cand.name == "time_delay":
            d, sd_d = delay_sigma(problem, state, cand.nonlinear["d"], row_weights(model_after))
            tq = (X_after - problem.design(0.0, state["effects"], cols=state["cols"])) @ model_after.chi
            values, sigmas, params = np.array([d]), np.array([sd_d]), ["d"]
        else:
            idx = [model_after.names.index(p) for p in cand.active_params]
            tq = problem.decimated([cand])[0] @ model_after.chi[idx]
            values, sigmas, params = model_after.chi[idx], model_after.bse.to_numpy()[idx], cand.active_params
        rms = np.sqrt(np.sum(np.where(problem.mask, tq, 0.0) ** 2, axis=0)
                      / np.maximum(problem.mask.sum(axis=0), 1))
        onset = onset_note(cand, values, setup.eobs.obs.settings, setup.qd_peak)
        out.append(SelectedEffect(name=cand.name, joint=cand.joint, nonlinear=dict(cand.nonlinear),
                                  params=list(params), values=np.asarray(values),
                                  sigma=np.asarray(sigmas), step=step, candidate=cand, torque_rms=rms,
                                  note=onset or physics_note(cand, values),
                                  kind="coulomb_onset" if onset else "effect",
                                  title=effect_title(cand.name, values)))
    return out


def _errors_and_path(setup, opts, sel):
    """(errors before/after, residual analyses, errors after each step, validation source)."""
    problem, vprob, state, model0 = setup.problem, setup.vprob, sel.state, setup.model0
    obs = setup.eobs.obs
    pred_before = problem.X @ model0.chi
    pred_after = problem.design(state["delay"], state["effects"], cols=state["cols"]) @ state["fit"].chi
    errors = {"identification": {"before": errors_of(problem.Y, pred_before, problem.mask),
                                 "after": errors_of(problem.Y, pred_after, problem.mask)},
              "validation": None}
    residuals = {}
    if opts.residual_analysis:
        residuals["identification_before"] = analyse_residual(obs, problem.Y - pred_before, setup.eobs)
        residuals["identification_after"] = _same_or_analyse(
            residuals["identification_before"], pred_before, pred_after,
            lambda: analyse_residual(obs, problem.Y - pred_after, setup.eobs))
    vsource, val_path = "", None
    if vprob is not None:
        val_path = [errors_of(vprob.Y, vprob.design(h["delay"], h["effects"], cache=True, cols=h["cols"])
                              @ h["fit"].chi, vprob.mask) for h in sel.history]
        errors["validation"] = {"before": val_path[0], "after": val_path[-1]}
        vsource = vprob.eobs.source
        if opts.residual_analysis:
            v_before = vprob.X @ model0.chi
            v_after = vprob.design(state["delay"], state["effects"], cols=state["cols"]) @ state["fit"].chi
            vobs = vprob.eobs.obs
            residuals["validation_before"] = analyse_residual(vobs, vobs.tau - v_before, vprob.eobs)
            residuals["validation_after"] = _same_or_analyse(
                residuals["validation_before"], v_before, v_after,
                lambda: analyse_residual(vobs, vobs.tau - v_after, vprob.eobs))
    path = []
    for k, h in enumerate(sel.history):
        Xh = problem.design(h["delay"], h["effects"], cols=h["cols"])
        path.append({"step": k, "added": None if k == 0 else sel.selected[k - 1][0].label,
                     "identification": errors_of(problem.Y, Xh @ h["fit"].chi, problem.mask),
                     "validation": None if val_path is None else val_path[k]})
    return errors, residuals, path, vsource


def _same_or_analyse(before, pred_before, pred_after, analyse):
    """The residual analysis after: a copy of the one before when the prediction is the same
    (nothing was added: about 0.1 s per analysis saved), else `analyse()`."""
    if np.array_equal(pred_before, pred_after):
        return copy.deepcopy(before)
    return analyse()


def _final_ranking(sel):
    """Selected effects in order, then the last step's ranking, then the rest last scored."""
    final = [w for _, _, w in sel.selected]
    seen = {group_key(w.candidate) for w in final}
    last_step = sel.steps[-1].ranking if sel.steps else []
    for r in last_step:
        if group_key(r.candidate) not in seen:
            final.append(r)
            seen.add(group_key(r.candidate))
    for key, r in sel.last_scored.items():
        if key not in seen:
            final.append(r)
            seen.add(key)
    return final


def _settings_record(setup, opts):
    """The settings as reported (`result.settings`)."""
    return {"alpha": opts.alpha, "folds": setup.folds, "gap": setup.gap, "max_effects": opts.max_effects,
            "effects": list(opts.effects), "n_candidates": len(setup.cands), "rule": RULE,
            "alias_rtol": ALIAS_RTOL, "joints": opts.joints,
            "stribeck_grid_fraction_of_peak_qd": [float(v) for v in STRIBECK_GRID],
            "delay_grid_s": [float(v) for v in DELAY_GRID],
            "processing": dict(setup.eobs.obs.settings),
            "confirm_on_validation": bool(opts.confirm_on_validation and setup.vprob is not None),
            "model": setup.model_text + (
                f" without {', '.join(opts.exclude_parameters)}" if opts.exclude_parameters else ""),
            "start_model": opts.start_model if isinstance(opts.start_model, str) else list(opts.start_model),
            "ranking": "chi2_k tail of the LR statistic with n_eff (most significant first)",
            "max_tries": opts.max_tries,
            "drift_time_origin_s": setup.eobs.t_start, "drift_time_scale_s": setup.eobs.duration}


def _rest(experiment, robot, setup, opts):
    """The friction at rest (rest.py): with validation recordings given as data, else None."""
    if not opts.rest_phases or setup.vprob is None or isinstance(experiment, EffectObservation) \
            or isinstance(setup.validation, EffectObservation):
        return None
    return rest_phases(robot, setup.cols0, setup.model0.chi, list(setup.names0), setup.eobs,
                       setup.vprob.eobs, folds=setup.folds)


# ======================================================================= stage 5: tests of the final model
def _test_model(problem, state):
    """(state, fit) of the model the structure and physical tests examine.

    The full base model plus the selected effects: a rigid-body term the essential
    reduction dropped is explained by the base parameters, not by a missing effect
    (measured on the independent plant, TX40 with a 1 N m speed-dependent ripple on
    joint 1: the essential model of 24 parameters left 0.064 and 0.074 N m on the
    wrist joints 5, 6, 5.6 x their noise floor; the full base model leaves them at the floor).
    """
    if len(state["cols"]) >= len(problem.all_cols):
        return state, state["fit"]
    s_test = dict(state, cols=problem.all_cols, names=list(problem.all_names))
    fit_test = fit_wls(problem.design(s_test["delay"], s_test["effects"], cols=s_test["cols"]),
                       problem.Y, problem.mask, problem.names_for(s_test["effects"], s_test["names"]))
    return s_test, fit_test


def _structure(experiment, robot, setup, opts, sel, s_test, fit_test):
    """Catalogue-free structure tests of the final residual (structure.py)."""
    problem, eobs = setup.problem, setup.eobs
    X_test = problem.design(s_test["delay"], s_test["effects"], cols=s_test["cols"])
    pred_test = X_test @ fit_test.chi
    full_res, full_mask = full_rate_residual(problem, s_test, fit_test)
    delta = None
    if not isinstance(experiment, EffectObservation) and not s_test["delay"]:
        try:
            delta, _ = position_noise_residual(experiment, robot, eobs, s_test["cols"],
                                               fit_test.chi[:len(s_test["cols"])])
        except DynidError as exc:     # the floor is then the torque noise's alone
            setup.notices.append(f"position-noise floor not estimated: {exc}")
    return residual_structure(eobs, problem.Y - pred_test, problem.mask, alpha=opts.alpha,
                              gap=setup.gap, explained=[c.label for c, _, _ in sel.selected],
                              full_residual=full_res, full_mask=full_mask, position_delta=delta)


def _hidden(robot, setup, opts, state, s_test, fit_test):
    """The hidden-effects route: a-priori prior tests, then the physically consistent test."""
    problem, vprob, eobs = setup.problem, setup.vprob, setup.eobs
    model_after = state["fit"]
    hidden = []
    if opts.hidden_tests:
        vdata = None
        if vprob is not None:
            vdata = (vprob.design(state["delay"], state["effects"], cols=state["cols"]), vprob.Y,
                     vprob.mask, vprob.eobs)
        X_after = problem.design(state["delay"], state["effects"], cols=state["cols"])
        hidden = hidden_effects(eobs, X_after, problem.Y, problem.mask, list(model_after.names),
                                model_after.chi, model_after.bse.to_numpy(), robot,
                                weights=row_weights(model_after), alpha=opts.alpha, validation=vdata)
    if not opts.physical_tests or any(h.reported for h in hidden):
        return hidden
    if len(s_test["cols"]) != len(problem.all_cols) or list(s_test["names"]) != list(eobs.bp.names):
        return hidden
    # the parameters may contradict physics rather than the a-priori values (or the robot
    # file has none): the residual of the physically consistent fit (issue 15 item 3)
    try:
        require_cvxpy()
        vfull = None
        if vprob is not None:
            vfull = (vprob.design(s_test["delay"], s_test["effects"], cols=s_test["cols"]),
                     vprob.Y, vprob.mask, vprob.eobs)
        X_test = problem.design(s_test["delay"], s_test["effects"], cols=s_test["cols"])
        hidden = hidden + physical_effects(eobs, X_test, problem.Y, problem.mask,
                                           len(s_test["cols"]), fit_test.chi, robot,
                                           weights=row_weights(fit_test), alpha=opts.alpha,
                                           validation=vfull)
    except DynidError as exc:      # no cvxpy, or a robot PC-WLS cannot handle
        setup.notices.append(f"physically consistent test not run: {exc}")
    return hidden


