"""The full pipeline behind `dynid report` and `dynid demo`: everything in one report.

IDIM (Gautier, Janot & Vandanjon 2010, section 2) on the identification data,
validation on held-out data, then DIDIM (section 3), the Bayesian posterior of
the essential parameters and the residual diagnosis, rendered as one
self-contained HTML report with the matching JSON document.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from dynid.errors import InputError
from dynid.reports.progress import Reporter

#: the analyses after IDIM that a full report runs (each can be skipped)
REPORT_PARTS = ("didim", "sample", "diagnose")

#: DIDIM's gain update in reports: the paper's update at every step oscillated on
#: the demo data (25 steps, Ia6 +590 %) where updating only the first simulation
#: converged in 8 (all parameters within 1.5 %).
REPORT_GAIN_UPDATE = "initial"


@dataclass(eq=False)
class FullReport:
    """What `report` produced: the results, the HTML and the JSON document."""

    result: object                       # IDIMResult
    robot: object
    experiments: list
    validation: object = None            # ValidationResult or None
    didim: object = None
    posterior: object = None
    diagnosis: object = None
    sections: list = field(default_factory=list)
    problems: list = field(default_factory=list)

    _verdict: object = field(default=None, repr=False)

    @property
    def verdict(self):
        """The `dynid.analysis.statistics.verdict.Verdict` of this report (computed once)."""
        if self._verdict is None:
            from dynid.analysis.statistics.verdict import verdict
            residuals = None
            if self.diagnosis is not None:
                residuals = (getattr(self.diagnosis, "residuals", None) or {}).get("identification_before")
            self._verdict = verdict(self.result, self.validation, robot=self.robot,
                                    diagnosis=self.diagnosis, residuals=residuals)
        return self._verdict

    @property
    def html(self) -> str:
        from dynid.reports.html import render_idim_report
        return render_idim_report(self.result, self.robot, self.experiments[0], self.validation,
                                  extra_sections=self.sections, verdict=self.verdict)

    def to_dict(self) -> dict:
        doc = self.result.to_dict()
        doc["verdict"] = self.verdict.to_dict()
        doc["validation"] = self.validation.to_dict() if self.validation is not None else None
        for key, part in (("didim", self.didim), ("posterior", self.posterior), ("diagnosis", self.diagnosis)):
            if part is not None:
                doc[key] = part.to_dict()
        doc["problems"] = list(self.problems)
        return doc

    def summary(self) -> str:
        parts = [self.verdict.summary(), self.result.summary(),
                 self.validation.summary() if self.validation is not None else ""]
        parts += [p.summary() for p in (self.didim, self.posterior, self.diagnosis) if p is not None]
        return "\n\n".join(p for p in parts if p)

    def __str__(self) -> str:
        return self.summary()

    def write(self, path) -> None:
        """Write the HTML report to `path` atomically.

        Returns
        -------
        None
            The file is written whole or not at all.
        """
        from dynid.outputs import atomic_write_text
        atomic_write_text(path, self.html)


def check_parts(skip) -> set:
    """The set of parts to skip, checked against `REPORT_PARTS`."""
    skip = {x.strip() for x in (skip or ()) if x.strip()}
    unknown = skip - set(REPORT_PARTS)
    if unknown:
        raise InputError(f"skip takes {', '.join(REPORT_PARTS)}; unknown: {', '.join(sorted(unknown))} "
                         "(--skip on the command line)")
    return skip


def run_diagnosis(experiment, robot, validation, idim_result, *, settings=None, effects=None,
                  max_effects=3, alpha=0.01, no_offsets=False, max_error_growth=0.02, say=None):
    """The residual diagnosis of an IDIM result, with the command line's options."""
    from dynid.analysis.diagnosis.selection import diagnose
    say = say or Reporter()
    with say.progress("diagnosis (selection steps)") as bar:
        kwargs = dict(validation=validation, effects=effects, max_effects=max_effects, alpha=alpha,
                      progress=bar.update)
        if no_offsets:
            return diagnose(experiment, robot, settings=settings, exclude_parameters=("Off",),
                            max_error_growth=max_error_growth, **kwargs)
        return diagnose(experiment, robot, idim_result=idim_result, **kwargs)


def further_analyses(out: FullReport, valid, *, skip=(), settings=None, seed=1, max_seconds=300.0,
                     gain_update=REPORT_GAIN_UPDATE, max_iter=15, max_error_growth=0.02,
                     diagnosis_options=None, say=None) -> FullReport:
    """DIDIM, posterior and diagnosis after the IDIM result of `out` (in place).

    A part that does not apply (no controller, several recordings) is skipped
    with a notice; one that does not converge is listed in `out.problems`.
    """
    from dynid.reports.bayes_section import bayes_sections
    from dynid.reports.diagnosis_section import diagnosis_sections
    from dynid.reports.didim_section import didim_sections
    say = say or Reporter()
    robot, experiments, result = out.robot, out.experiments, out.result
    if "didim" not in skip:
        if robot.controller is None:
            say(f"DIDIM skipped: robot '{robot.name}' has no [controller] to simulate")
        elif len(experiments) > 1:
            say("DIDIM skipped: it identifies one recording at a time")
        else:
            from dynid.analysis.estimators.didim import identify_didim
            exp = experiments[0]
            update = {"every": True, "initial": "initial", "none": False}.get(gain_update, gain_update)
            with say.progress("DIDIM iterations") as bar:
                out.didim = identify_didim(exp, robot, settings=settings,
                                           reference="qr" if exp.qr is not None else "q",
                                           max_iter=max_iter, update_gains=update,
                                           max_error_growth=max_error_growth, progress=bar.update)
            out.sections += didim_sections(out.didim)
            if not out.didim.converged:
                out.problems.append(f"DIDIM did not converge ({out.didim.stop_reason})")
    if "sample" not in skip:
        from dynid.analysis.sampling.posterior import sample_idim
        with say.progress("sampling (steps / steps needed)") as bar:
            out.posterior = sample_idim(result, which="essential", seed=seed, max_seconds=max_seconds,
                                        progress=lambda n, need: bar.update(n / max(need, 1)))
        out.sections += bayes_sections(out.posterior)
        if not out.posterior.converged:
            out.problems.append(f"the sampler did not converge ({out.posterior.reason})")
    if "diagnose" not in skip:
        if len(experiments) > 1:
            say("diagnosis skipped: it works on one recording at a time")
        else:
            say("diagnosis: scoring candidate effects")
            out.diagnosis = run_diagnosis(experiments[0], robot, valid, result, settings=settings,
                                          max_error_growth=max_error_growth, say=say,
                                          **(diagnosis_options or {}))
            out.sections += diagnosis_sections(out.diagnosis, robot)
    return out


def report(data, robot, path=None, *, holdout=None, validation=None, skip=(), settings=None, seed=1,
           max_seconds=300.0, max_error_growth=0.02, gain_update=REPORT_GAIN_UPDATE, max_iter=15,
           diagnosis_options=None, say=None) -> FullReport:
    """IDIM, validation, DIDIM, posterior and diagnosis of `data` in one report.

    Parameters
    ----------
    data : path, Experiment or a list of them (identification recordings)
    robot : Robot, bundled name or robot file
    path : where to write the HTML report (optional; `FullReport.html` has it)
    holdout : seconds at the end of a single recording held out for validation
    validation : a held-out recording (path or Experiment), instead of `holdout`
    skip : parts of `REPORT_PARTS` not to run

    Returns
    -------
    FullReport
        The results of every stage run, the verdict and the HTML (written to `path`
        when given).
    """
    from dynid.analysis.data.split import holdout_split
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.identify import as_experiments, as_robot
    from dynid.analysis.statistics.validation import validate
    say = say or Reporter()
    skip = check_parts(skip)
    if not max_seconds > 0:
        raise InputError(f"max_seconds must be positive, got {max_seconds:g} (--max-seconds)")
    robot = as_robot(robot)
    experiments = as_experiments(data, robot)
    valid = None
    if validation is not None and holdout is not None:
        raise InputError("give a validation recording or a holdout, not both (--validation, --holdout)")
    if validation is not None:
        valid = as_experiments(validation, robot)[0]
    elif holdout is not None:
        if len(experiments) > 1:
            raise InputError("holdout splits one recording; with several, give a validation recording "
                             "(--validation)")
        train, valid = holdout_split(experiments[0], holdout)
        experiments = [train]
    ident = experiments if len(experiments) > 1 else experiments[0]
    with say.progress("IDIM: regressor and decimation") as bar:
        result = identify_idim(ident, robot, settings=settings, max_error_growth=max_error_growth,
                               progress=bar.update)
    out = FullReport(result=result, robot=robot, experiments=experiments,
                     validation=validate(result, valid, robot) if valid is not None else None)
    further_analyses(out, valid, skip=skip, settings=settings, seed=seed, max_seconds=max_seconds,
                     gain_update=gain_update, max_iter=max_iter, max_error_growth=max_error_growth,
                     diagnosis_options=diagnosis_options, say=say)
    if path is not None:
        out.write(path)
    return out


def demo(*, seed=1, duration=20.0, skip=(), max_seconds=300.0, path=None, say=None) -> FullReport:
    """The demo: a simulated TX40 (Table 2 of the DIDIM paper) through the whole pipeline.

    Returns
    -------
    FullReport
        The results, the verdict and the HTML report of the simulated TX40 (written to
        `path` when given).
    """
    from dynid.analysis.demo import run_demo
    say = say or Reporter()
    skip = check_parts(skip)
    import math
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 2.0):
        raise InputError(f"duration must be a finite number of seconds, at least 2 s, got {duration!r} "
                         f"(--duration)")
    if not (isinstance(max_seconds, (int, float)) and max_seconds > 0 and not math.isnan(max_seconds)):
        raise InputError(f"max_seconds must be positive, got {max_seconds!r} (--max-seconds)")
    import numbers
    if isinstance(seed, numbers.Integral) and seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r} (--seed)")
    from dynid.analysis.data.synthetic import sample_count
    from dynid.dynamics.robot_file import load_robot
    sample_count(duration, float(load_robot("tx40").controller.rate),
                 what="the demo's controller rate (the TX40's)")
    result, robot, experiment, validation, valid = run_demo(seed=seed, duration=duration, say=say)
    out = FullReport(result=result, robot=robot, experiments=[experiment], validation=validation)
    further_analyses(out, valid, skip=skip, seed=seed, max_seconds=max_seconds, say=say)
    if path is not None:
        out.write(path)
    return out
