"""Steps 8-10 of the orchestrator (dynid.analysis.run): the further analyses of a full report.

8. `didim_beside`: DIDIM (Gautier, Janot & Vandanjon 2010, section 3) beside IDIM.
9. `posterior_step`: the Bayesian posterior of the essential parameters (emcee).
10. `diagnosis_step`: the residual diagnosis (what the model lacks).

`further_analyses` runs them after the IDIM step of `dynid report` and `dynid demo`;
`diagnosis_run` is `dynid diagnose`. No step changes a result after it is returned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dynid.analysis.diagnosis.effect_observation import observe_effects
from dynid.analysis.diagnosis.effects import check_effect_names
from dynid.analysis.diagnosis.selection import diagnose
from dynid.analysis.run import (
    REPORT_PARTS,
    Settings,
    as_robot,
    check_identify,
    check_robot_options,
    holdout_hint,
    identify_step,
    load_data,
    messages,
    settings_from,
)
from dynid.analysis.sampling.posterior import sample_idim
from dynid.analysis.statistics.validation import validate
from dynid.analysis.statistics.verdict import verdict
from dynid.dynamics.base_parameters import base_parameters
from dynid.errors import InputError
from dynid.pages import small_pages

# ---------------------------------------------------------------- steps 8-10: a full report

def check_parts(skip) -> set:
    """The set of parts to skip, checked against REPORT_PARTS."""
    if isinstance(skip, str):
        skip = [skip]
    # each item may itself be comma-separated (--skip didim,sample or --skip didim --skip sample)
    skip = {x.strip() for item in (skip or ()) for x in str(item).split(",") if x.strip()}
    unknown = skip - set(REPORT_PARTS)
    if unknown:
        raise InputError(f"skip takes {', '.join(REPORT_PARTS)}; unknown: {', '.join(sorted(unknown))} "
                         "(--skip on the command line)")
    return skip


def check_diagnosis(settings: Settings) -> None:
    if not 0 < settings.alpha < 1:
        raise InputError(f"--alpha must be between 0 and 1, got {settings.alpha:g}")
    if settings.max_effects < 1:
        raise InputError(f"--max-effects must be at least 1, got {settings.max_effects}")


def diagnosis_step(experiment, robot, held_out, idim_result, settings: Settings, say=None,
                   candidates=None, observation=None):
    """Step 10: the residual diagnosis of an IDIM result (`no_offsets`: of the model without the
    torque offsets, identified here). `candidates`: the effects to consider (default all);
    `observation`: the EffectObservation `idim_result` was identified from, when built."""
    say = messages(say)
    with say.progress("diagnosis (selection steps)") as bar:
        kwargs = dict(validation=held_out, effects=candidates, max_effects=settings.max_effects,
                      alpha=settings.alpha, progress=bar.update)
        if settings.no_offsets:
            return diagnose(experiment, robot, settings=settings.processing(), exclude_parameters=("Off",),
                            max_error_growth=settings.max_error_growth, **kwargs)
        return diagnose(experiment, robot, idim_result=idim_result, observation=observation, **kwargs)


def didim_beside(experiments, robot, settings: Settings, say=None):
    """Step 8: DIDIM beside IDIM in a full report (None when it does not apply, with a message)."""
    say = messages(say)
    if robot.controller is None:
        say(f"DIDIM skipped: robot '{robot.name}' has no [controller] to simulate")
        return None
    if len(experiments) > 1:
        say("DIDIM skipped: it identifies one recording at a time")
        return None
    s = settings.replace(method="didim", gains="assumed", physical=False, prior=None, mass_tolerance=None)
    with say.progress("DIDIM iterations") as bar:
        return identify_step(experiments, robot, s, progress=bar.update)


def posterior_step(result, settings: Settings, say=None, robot=None):
    """Step 9: the posterior of the `which` (essential) parameters by emcee (`physical`: on the
    physically consistent support of the base parameters)."""
    if settings.physical and settings.which != "base":
        raise InputError("--physical samples the base parameters: add --which base")
    with messages(say).progress("sampling (steps / steps needed)") as bar:
        return sample_idim(result, which=settings.which, seed=settings.seed, max_seconds=settings.max_seconds,
                           noise=settings.noise,
                           progress=lambda n, need: bar.update(n / max(need, 1)),
                           **({"n_walkers": settings.walkers} if settings.walkers is not None else {}),
                           **({"max_steps": settings.max_steps} if settings.max_steps is not None else {}),
                           **({"physical": True, "robot": robot} if settings.physical else {}))


@dataclass(frozen=True, eq=False)
class Analyses:
    """Steps 8-10 of a full report: DIDIM, the posterior, the diagnosis, and what did not converge."""

    didim: object = None
    posterior: object = None
    diagnosis: object = None
    problems: tuple = ()


def further_analyses(experiments, robot, result, held_out, settings: Settings, say=None) -> Analyses:
    """Steps 8-10 after the IDIM `result`: a part that does not apply (no controller, several
    recordings) is skipped with a message; one that does not converge is listed in `problems`."""
    say = messages(say)
    skip = check_parts(settings.skip)
    didim = posterior = diagnosis = None
    problems = []
    if "didim" not in skip:
        didim = didim_beside(experiments, robot, settings, say)
        if didim is not None and not didim.converged:
            problems.append(f"DIDIM did not converge ({didim.stop_reason})")
    if "sample" not in skip:
        posterior = posterior_step(result, settings, say)
        if not posterior.converged:
            problems.append(f"the sampler did not converge ({posterior.reason})")
    if "diagnose" not in skip:
        if len(experiments) > 1:
            say("diagnosis skipped: it works on one recording at a time")
        else:
            say("diagnosis: scoring candidate effects")
            diagnosis = diagnosis_step(experiments[0], robot, held_out, result, settings, say,
                                       candidates=diagnosis_candidates(settings))
    return Analyses(didim=didim, posterior=posterior, diagnosis=diagnosis, problems=tuple(problems))


def diagnosis_candidates(settings: Settings):
    """The candidate effects of the diagnosis (`effects`: a list or comma-separated names), checked."""
    value = settings.effects
    if value is None:
        return None
    names = [x.strip() for x in value.split(",") if x.strip()] if isinstance(value, str) else list(value)
    if not names:       # an empty list read as "every effect"
        raise InputError("--effects (effects=) names no effect; give some (stribeck,offset,spring ...), "
                         "or leave it out to consider every effect")
    check_effect_names(names)
    return names


def report_verdict(result, validation, robot, diagnosis):
    """The verdict of a full report: with the diagnosis and its residuals when it ran."""
    residuals = None
    if diagnosis is not None:
        residuals = (getattr(diagnosis, "residuals", None) or {}).get("identification_before")
    return verdict(result, validation, robot=robot, diagnosis=diagnosis, residuals=residuals)


def check_report(settings: Settings) -> None:
    """The options of a full report, checked before any work."""
    check_parts(settings.skip)
    check_diagnosis(settings)
    diagnosis_candidates(settings)
    if settings.max_seconds is not None and not (
            isinstance(settings.max_seconds, (int, float)) and settings.max_seconds > 0
            and not math.isnan(settings.max_seconds)):
        raise InputError(f"max_seconds must be positive, got {settings.max_seconds!r} (--max-seconds)")


# ---------------------------------------------------------------- dynid diagnose

@dataclass(frozen=True, eq=False)
class DiagnosisRun:
    """What `dynid diagnose` gives: the diagnosis, the IDIM result it started from, its
    validation on the held-out data and its verdict. `to_dict()` is the command's JSON."""

    diagnosis: object
    result: object = None                # None with no_offsets when the diagnosis kept no IDIM
    robot: object = None
    experiment: object = None
    validation: object = None
    verdict: object = None

    def to_dict(self) -> dict:
        doc = self.diagnosis.to_dict()
        if self.verdict is not None:
            doc["verdict"] = self.verdict.to_dict()
        if self.validation is not None:
            doc["validation"] = self.validation.to_dict()
        return doc

    def summary(self) -> str:
        parts = [self.verdict.summary() if self.verdict is not None else "", self.diagnosis.summary()]
        return "\n\n".join(p for p in parts if p)

    def __str__(self) -> str:
        return self.summary()


def check_one_recording(data) -> None:
    """Refuse several recordings given to a diagnosis, before they are loaded (the rest would be
    dropped without a word)."""
    if isinstance(data, (list, tuple)) and len(data) > 1:
        raise InputError(f"diagnose: one recording at a time, {len(data)} were given (its drift and time-delay "
                         "effects are defined per recording); diagnose each, or pass the second as the "
                         "validation recording (--validation, validation=)")


def diagnosis_run(data, robot, settings=None, *, say=None, **options) -> DiagnosisRun:
    """`dynid diagnose`: identify (IDIM; not with `no_offsets`), look for the effects the model
    lacks (step 10), validate on the held-out data and give the verdict with the diagnosis."""
    with small_pages():
        return _diagnosis_run(data, robot, settings, say=say, **options)


def _diagnosis_run(data, robot, settings=None, *, say=None, **options) -> DiagnosisRun:
    s = settings_from(settings, **options)
    say = messages(say)
    check_diagnosis(s)
    candidates = diagnosis_candidates(s)          # bad names fail before the long work
    robot = as_robot(robot)
    check_robot_options(s, robot)
    check_one_recording(data)
    experiments, held_out = load_data(data, robot, s, say)
    experiment = experiments[0]
    result = eobs = None
    if not s.no_offsets:
        ident = s.replace(method="idim", physical=False)
        check_identify(ident)
        with holdout_hint(s, experiments), say.progress("regressor and decimation") as bar:
            # the diagnosis' observation first: its decimated system is observe's, so IDIM
            # identifies from it and the full-rate regressor is built once, not twice
            eobs = observe_effects(experiment, robot, base_parameters(robot), ident.processing(),
                                   progress=bar.update)
            result = identify_step([experiment], robot, ident, observation=eobs.obs, bp=eobs.bp)
    say("scoring candidate effects")
    diag = diagnosis_step(experiment, robot, held_out, result, s, say, candidates=candidates,
                          observation=eobs)
    result = diag.idim if diag.idim is not None else result
    validation = validate(result, held_out, robot) if held_out is not None and result is not None else None
    the_verdict = verdict(result, validation, robot=robot, diagnosis=diag) if result is not None else None
    return DiagnosisRun(diagnosis=diag, result=result, robot=robot, experiment=experiment,
                        validation=validation, verdict=the_verdict)
