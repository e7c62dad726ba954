"""The reports layer of a run: the steps of dynid.analysis.run, then the exports.

`run` is `dynid identify` as a function (`dynid.run`): the orchestrator's steps 1-7
(dynid.analysis.run.run), the URDF/MJCF export, and the outputs (JSON, CSV, URDF,
MJCF, HTML) rendered in memory by `outputs` and written all or none.

`report` and `demo` are `dynid report` and `dynid demo`: IDIM (Gautier, Janot &
Vandanjon 2010, section 2) on the identification data, validation on held-out data,
then DIDIM (section 3), the Bayesian posterior of the essential parameters and the
residual diagnosis (the orchestrator's steps 8-10), rendered as one self-contained
HTML report with the matching JSON document.
"""
from __future__ import annotations

import dataclasses
import numbers
import warnings
from dataclasses import dataclass, field

from dynid.analysis import further
from dynid.analysis import run as steps
from dynid.analysis.data.synthetic import sample_count
from dynid.analysis.demo import run_demo
from dynid.analysis.estimators.didim import DEFAULT_MAX_ITER
from dynid.analysis.estimators.payload import identify_payload, unfelt_message, unfelt_parameters
from dynid.analysis.further import DiagnosisRun
from dynid.analysis.results import Result
from dynid.analysis.run import (  # noqa: F401 - REPORT_PARTS: public here since 0.1
    REPORT_GAIN_UPDATE,
    REPORT_PARTS,
    Identification,
    Settings,
    method_name,
)
from dynid.analysis.statistics.validation import validate
from dynid.dynamics.robot_file import load_robot
from dynid.errors import IdentificationError, InputError
from dynid.outputs import atomic_write_text, write_all
from dynid.provenance import dumps_json
from dynid.reports import render
from dynid.reports.input_files import check_python_outputs
from dynid.reports.payload_section import payload_refusal_section, payload_report_section
from dynid.reports.progress import Reporter
from dynid.reports.urdf_export import export_urdf, mjcf_of

check_parts = further.check_parts


# ---------------------------------------------------------------- dynid identify

def export_step(ident: Identification, say=None) -> Identification:
    """The URDF/MJCF export of a run (`urdf` or `mjcf` set): a new Identification that carries it."""
    s = ident.settings
    if not (s.urdf or s.mjcf):
        return ident
    say = say or Reporter()
    say("choosing a physically consistent standard parameter set for the URDF/MJCF")
    export = export_urdf(ident.result, ident.robot, physical=ident.physical, effects=ident.effects)
    say(f"URDF: {'consistent' if export.consistent else 'NOT consistent'}; "
        f"{'reproduces the identified values' if export.reproduces else 'does not reproduce the identified values (details in --report / --json)'}")
    # how the set was found, when not by the global SDP: the user must see it, not only the JSON
    for note in export.standard_set.search_caveats():
        say(f"URDF: {note}")
    if export.springs:
        say("MJCF: with the springs of --effects as joint stiffness: "
            + ", ".join(f"Ks{j} = {k:.4g}" for j, k in export.springs.items()))
    return dataclasses.replace(ident, export=export)


def run(data, robot, settings=None, *, say=None, write=True, **options) -> Identification:
    """`dynid identify` as a function: identify, validate, verdict, the optional parts, exports.

    Parameters
    ----------
    data : path, Experiment, or a list of them
        The identification recording(s).
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    settings : Settings or dict, optional
        A `dynid.Settings`, or a dict of processing overrides (`fc_position` ...).
        Default None: the defaults, from the data.
    say : Reporter or callable, optional
        A `dynid.reports.progress.Reporter`, or a function of a message (`print`: the
        messages, no progress bars). Default None: `Reporter()`, no messages, progress
        through `dynid.progress`.
    write : bool
        Write the outputs named by `json`, `report`, `csv`, `urdf`, `mjcf` (all or none).
    **options
        The options of `dynid identify`, by their names (`holdout=3`, `method="didim"`,
        `gravity_tilt=True`, `physical=True`, `effects="spring:all"`, `urdf="arm.urdf"` ...).

    Returns
    -------
    Identification
        `to_dict()` is the JSON that `dynid identify --json` writes; `verdict` its verdict.
    """
    say = say or Reporter()
    if write:
        # before any work, as the command line: an output that would destroy an input (the
        # recording itself, through any name) or cannot be written is refused now, not after minutes
        given = settings if isinstance(settings, Settings) else Settings()
        check_python_outputs([(f"{k}=", options.get(k, getattr(given, k, None)))
                              for k in ("json", "csv", "report", "urdf", "mjcf")],
                             data, robot, validation=options.get("validation", getattr(given, "validation", None)))
    ident = export_step(steps.run(data, robot, settings, say=say, **options), say)
    if write:
        write_all(outputs(ident), say)
    return ident


def _render():
    """The HTML renderers (dynid.reports.render), imported when a report is rendered: they load
    matplotlib and every report section, seconds a run without --report does not need to spend
    (and an interrupted run then stops in the identification, not inside a plotting import)."""
    return render


def html(ident: Identification) -> str:
    """The HTML report of a run."""
    return _render().identification_html(ident)


def parameter_frame(ident: Identification):
    """The essential (IDIM, DIDIM) or estimated parameters as a table: what --csv writes."""
    return ident.result.model.to_frame() if ident.method in ("idim", "didim") else ident.result.to_frame()


def outputs(ident: Identification) -> list:
    """`(path, text)` of every output the settings name, rendered in memory (nothing written)."""
    s, out = ident.settings, []
    if s.json:
        out.append((s.json, dumps_json(ident.to_dict())))
    if ident.export is not None and s.urdf:
        out.append((s.urdf, ident.export.text))
    if ident.export is not None and s.mjcf:
        out.append((s.mjcf, mjcf_of(ident.export, ident.robot)))
    if s.csv:
        out.append((s.csv, parameter_frame(ident).to_csv()))
    if s.report:
        out.append((s.report, html(ident)))
    return out


# ---------------------------------------------------------------- sample, diagnose, excite

def sample_outputs(post, result, robot, experiment, verdict, settings: Settings) -> list:
    """`(path, text)` of the outputs of `dynid sample`: JSON (the posterior and the verdict of the
    identification it samples), the samples as CSV, the HTML report."""
    out = []
    if settings.json:
        doc = post.to_dict()
        doc["verdict"] = verdict.to_dict()
        out.append((settings.json, dumps_json(doc)))
    if settings.csv:
        out.append((settings.csv, post.samples_frame().to_csv(index=False, lineterminator="\n",
                                                               float_format="%.17g")))
    if settings.report:
        out.append((settings.report, _render().sample_html(post, result, robot, experiment, verdict)))
    return out


def diagnose_run(data, robot, settings=None, *, say=None, **options) -> DiagnosisRun:
    """`dynid diagnose` as a function (dynid.analysis.further.diagnosis_run), messages on `say`."""
    return further.diagnosis_run(data, robot, settings, say=say or Reporter(), **options)


def diagnosis_outputs(run: DiagnosisRun, settings: Settings | None = None) -> list:
    """`(path, text)` of the JSON and the HTML report of `dynid diagnose`."""
    s = settings or run_settings(run)
    out = []
    if s.json:
        out.append((s.json, dumps_json(run.to_dict())))
    if s.report:
        out.append((s.report, _render().diagnosis_html(run)))
    return out


def run_settings(run) -> Settings:
    return getattr(run, "settings", None) or Settings()


def excitation_rate(robot, f0, harmonics, fs=None, periods=1) -> float:
    """The sampling rate of an excitation's CSV (default: the controller's, else 1000 Hz), checked."""
    if periods < 1:
        raise InputError(f"--periods must be at least 1, got {periods}")
    fs = fs if fs is not None else (robot.controller.rate if robot.controller else 1000.0)
    if not fs > 0:
        raise InputError(f"--fs must be a positive sampling rate in Hz, got {fs:g}")
    if f0 > 0 and harmonics >= 1:
        top = f0 * harmonics
        if fs < 10 * top:
            raise InputError(f"--fs {fs:g} Hz is too low for the highest harmonic ({top:g} Hz): a "
                             f"controller reference needs at least 10 samples per period of it "
                             f"(--fs {10 * top:g} or more)")
        rows = fs * periods / f0
        if rows > 50_000_000:
            raise InputError(f"--fs {fs:g} Hz x --periods {periods} / --f0 {f0:g} Hz would write {rows:.3g} "
                             "rows (at most 50 million): raise --f0 (one period lasts 1/f0 s), or lower "
                             "--fs or --periods")
    return fs


def excitation_outputs(res, robot, fs, periods, *, out=None, json=None, report=None) -> list:
    """`(path, text)` of the trajectory CSV, the JSON and the HTML report of `dynid excite`."""
    outputs = []
    if out:
        outputs.append((out, res.to_csv(fs=fs, n_periods=periods)))
    if json:
        doc = res.to_dict()
        doc["csv"] = {"fs": fs, "periods": periods} if out else None
        outputs.append((json, dumps_json(doc)))
    if report:
        outputs.append((report, _render().excitation_html(res, robot)))
    return outputs


# ---------------------------------------------------------------- dynid report, dynid demo

@dataclass(eq=False, repr=False)
class FullReport(Result):
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
    payload: object = None               # PayloadResult, or the refusal's text (str), or None

    _verdict: object = field(default=None, repr=False)

    @property
    def verdict(self):
        """The Verdict of this report (dynid.analysis.statistics.verdict.Verdict)."""
        if self._verdict is None:        # a FullReport built by hand
            self._verdict = further.report_verdict(self.result, self.validation, self.robot, self.diagnosis)
        return self._verdict

    @property
    def html(self) -> str:
        return _render().render_idim_report(self.result, self.robot, self.experiments[0], self.validation,
                                            extra_sections=self.sections, verdict=self.verdict, kind="full")

    def to_dict(self) -> dict:
        """The full report's JSON (`dynid report --json`): the identification's, with the parts that ran.

        Returns
        -------
        dict
        """
        doc = self.result.to_dict()
        doc["verdict"] = self.verdict.to_dict()
        doc["validation"] = self.validation.to_dict() if self.validation is not None else None
        for key, part in (("didim", self.didim), ("posterior", self.posterior), ("diagnosis", self.diagnosis)):
            if part is not None:
                doc[key] = part.to_dict()
        if self.payload is not None:
            doc["payload"] = {"refused": self.payload} if isinstance(self.payload, str) else self.payload.to_dict()
        doc["problems"] = list(self.problems)
        return doc

    def summary(self) -> str:
        """The verdict, then each part's summary, as text.

        Returns
        -------
        str
        """
        parts = [self.verdict.summary(), self.result.summary(),
                 self.validation.summary() if self.validation is not None else ""]
        parts += [p.summary() for p in (self.didim, self.posterior, self.diagnosis) if p is not None]
        if self.payload is not None:
            parts.append(f"Payload not identified: {self.payload}" if isinstance(self.payload, str)
                         else self.payload.summary())
        return "\n\n".join(p for p in parts if p)

    @property
    def method(self) -> str:
        return "full report"

    def write(self, path) -> None:
        """Write the HTML report to `path` atomically."""
        atomic_write_text(path, self.html)


def _full_report(result, robot, experiments, validation, held_out, settings: Settings, say) -> FullReport:
    """Steps 8-10 after IDIM, the verdict, and the report's sections."""
    more = further.further_analyses(experiments, robot, result, held_out, settings, say)
    # the figures take seconds: say so, or a redirected log is silent meanwhile
    say("drawing the report's figures")
    sections = _render().full_report_sections(more, robot)
    return FullReport(result=result, robot=robot, experiments=experiments, validation=validation,
                      didim=more.didim, posterior=more.posterior, diagnosis=more.diagnosis, sections=sections,
                      problems=list(more.problems),
                      _verdict=further.report_verdict(result, validation, robot, more.diagnosis))


def _report_settings(settings, options) -> Settings:
    """`dynid report`'s settings: its defaults (DIDIM gain update 'initial', 20 steps), the
    old keyword `diagnosis_options` (a dict of effects, max_effects, alpha, no_offsets) accepted."""
    for name in ("json", "csv", "urdf", "mjcf"):
        if options.get(name) is not None:
            raise InputError(f"report(): {name}= is an output of the command line; in Python, report() writes "
                             f"the HTML (path=) and returns a FullReport: write its JSON with "
                             f"FullReport.to_json(path), or use dynid.run(..., {name}=...) for the identification's")
    if method_name(options.get("method", "idim")) != "idim":
        raise InputError(f"report(): method={options['method']!r}: the full report is IDIM's, with DIDIM, the "
                         "posterior and the diagnosis beside it (skip= leaves parts out); for another method "
                         "alone use dynid.identify(..., method=...)")
    old = options.pop("diagnosis_options", None)
    if old:
        warnings.warn("report(diagnosis_options={...}) is now report(effects=..., max_effects=..., alpha=..., "
                      "no_offsets=...); diagnosis_options= will be removed", DeprecationWarning, stacklevel=3)
        options.update({k: v for k, v in old.items() if v is not None})
    if not isinstance(settings, Settings):       # a Settings (the command line's) carries its own
        options.setdefault("gain_update", REPORT_GAIN_UPDATE)
        options.setdefault("max_iter", DEFAULT_MAX_ITER)
    s = steps.settings_from(settings, **options)
    further.check_report(s)
    return s


def _payload_options(options):
    """`report`'s payload_options, checked before any work: the robot-fixed route's options."""
    options = dict(options or {})
    if options.get("zoh"):
        # the robot is fixed to this report's IDIM model, identified from the torque as logged: centring
        # only the loaded recording would put the robot's own half-sample delay into the payload
        raise InputError("payload_options zoh=True: the report's model was identified from the torque as "
                         "logged, and the payload must see the same timing. Leave zoh off here, or use "
                         "dynid payload --unloaded ... --zoh (the global route) (docs/payload.md)")
    options.pop("zoh", None)
    unknown = sorted(set(options) - {"frame", "offset", "physical", "com_box"})
    if unknown:
        raise InputError(f"payload_options: unknown option(s) {', '.join(unknown)}; known: frame, offset, "
                         "physical, com_box")
    return options


def _payload_part(out, payload, robot, options, say):
    """The payload of `report(..., payload=...)`: the robot-fixed route on the report's IDIM
    result, its section appended; a recording that does not identify it becomes a section
    saying what is not identifiable and why (bad input still fails the report)."""
    options = _payload_options(options)
    loaded = payload if isinstance(payload, (list, tuple)) else [payload]
    with say.progress("payload (robot fixed)"):
        try:
            res = identify_payload(list(loaded), robot, model=out.result, **options)
        except IdentificationError as e:
            out.payload = str(e)
            out.problems.append(f"payload not identified: {e}")
            out.sections.append(payload_refusal_section(str(e), [getattr(x, "source", x) for x in loaded]))
            return out
    out.payload = res
    if res.model_misfit:
        out.problems.append("payload not identified: the report's model does not describe the loaded recording")
    out.sections.append(payload_report_section(res))
    return out


def report(data, robot, path=None, *, settings=None, say=None, payload=None, payload_options=None,
           **options) -> FullReport:
    """IDIM, validation, DIDIM, posterior and diagnosis of `data` in one report.

    Parameters
    ----------
    data : path, Experiment or a list of them
        The identification recording(s).
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    path : str or path, optional
        Where to write the HTML report. Default None: not written (`FullReport.html`
        has it).
    settings : Settings or dict, optional
        A `dynid.Settings`, or a dict of processing overrides (`fc_position` ...).
        Default None: the report's defaults, from the data.
    say : Reporter, optional
        A `dynid.reports.progress.Reporter`. Default None: `Reporter()`, no messages,
        progress through `dynid.progress`.
    payload : path, Experiment or a list of them, optional
        Recording(s) with a payload on the robot: the payload is identified with the
        robot fixed to this report's IDIM result (dynid.identify_payload) and gets its
        section; a recording that does not identify it gets a section saying why.
    payload_options : dict, optional
        identify_payload's frame, offset, physical, com_box (not zoh: the report's model is
        identified from the torque as logged).
    **options
        The options of `dynid report` by name: holdout (seconds at the end of a single
        recording held out), validation (a held-out recording, path or Experiment),
        skip (parts of REPORT_PARTS not to run), seed, max_seconds (default None: no wall-clock
        limit, the sampler stops on its step budget),
        max_error_growth, gain_update (default 'initial'), max_iter (default 20, DIDIM's), fc, nd ...

    Returns
    -------
    FullReport
        The results, the verdict and the HTML report (written to `path` when given).
    """
    say = say or Reporter()
    s = _report_settings(settings, options)
    check_python_outputs([("report (path=)", path)], data, robot, validation=getattr(s, "validation", None),
                         payload=payload)
    robot = steps.as_robot(robot)
    if payload_options and payload is None:
        raise InputError("payload_options given without payload=: give the loaded recording(s) as "
                         "payload=, or leave payload_options out")
    if payload is not None:
        _payload_options(payload_options)
        # before every method runs: a robot that cannot feel a payload is bad input, not a late failure
        frame = (payload_options or {}).get("frame", "flange")
        unfelt = unfelt_parameters(robot, frame, (payload_options or {}).get("offset"))
        if unfelt:
            raise InputError(f"--payload: {unfelt_message(robot, unfelt)}; leave --payload out")
        # read (and checked) now: a bad payload file is refused before minutes of other work
        payload = steps.as_experiments(payload, robot)      # as identify_payload reads it: --resample is the data's
    experiments, held_out = steps.load_data(data, robot, s, say)
    with steps.holdout_hint(s, experiments), say.progress("IDIM: regressor and decimation") as bar:
        result = steps.identify_step(experiments, robot, s.replace(method="idim"), progress=bar.update)
    validation = validate(result, held_out, robot) if held_out is not None else None
    out = _full_report(result, robot, experiments, validation, held_out, s, say)
    if payload is not None:
        out = _payload_part(out, payload, robot, payload_options, say)
    if path is not None:
        out.write(path)
    return out


def demo(*, seed=1, duration=20.0, skip=(), max_seconds=None, max_iter=None, gain_update=None, path=None,
         say=None) -> FullReport:
    """The demo: a simulated TX40 (Table 2 of the DIDIM paper) through the whole pipeline.

    Parameters
    ----------
    seed : int
        Seed of the simulated references and noise, and of the posterior's sampler.
    duration : float
        Length of the simulated identification recording, s (2 s or more); the
        validation recording is another 10 s.
    skip : sequence of str
        Parts of `REPORT_PARTS` (`"didim"`, `"sample"`, `"diagnose"`) not to run.
    max_seconds : float, optional
        Wall-clock limit of the posterior's sampler, s. Default None: no limit, the
        sampler stops on its step budget.
    max_iter : int, optional
        DIDIM's largest number of Gauss-Newton steps (default 20, DIDIM's, as `report`).
    gain_update : str, optional
        DIDIM's derivative-gain update (default `"initial"`, as `report`; `identify`'s
        `gain_update`).
    path : str or path, optional
        Where to write the HTML report. Default None: not written.
    say : Reporter or callable, optional
        A `dynid.reports.progress.Reporter`, or a function of a message (`print`).
        Default None: `Reporter()`, no messages, progress through `dynid.progress`.

    Returns
    -------
    FullReport
        The results, the verdict and the HTML report of the simulated TX40 (written to
        `path` when given).
    """
    say = say or Reporter()
    didim = {k: v for k, v in (("max_iter", max_iter), ("gain_update", gain_update)) if v is not None}
    s = _report_settings(None, dict(seed=seed, skip=skip, max_seconds=max_seconds, duration=duration, **didim))
    if not (isinstance(duration, (int, float)) and duration == duration and abs(duration) != float("inf")
            and duration >= 2.0):
        raise InputError(f"duration must be a finite number of seconds, at least 2 s, got {duration!r} "
                         f"(--duration)")
    if isinstance(seed, numbers.Integral) and seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r} (--seed)")
    sample_count(duration, float(load_robot("tx40").controller.rate),
                 what="the demo's controller rate (the TX40's)")
    check_python_outputs([("report (path=)", path)], robot="tx40")
    result, robot, experiment, validation, held_out = run_demo(seed=seed, duration=duration, say=say, uncertainty=s.uncertainty)
    out = _full_report(result, robot, [experiment], validation, held_out, s, say)
    if path is not None:
        out.write(path)
    return out
