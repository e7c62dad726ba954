"""One identification run, step by step: the orchestrator of dynid.

Every entry point runs the same steps in the same order with one settings
object, `Settings` (one field per command-line option, same name):
`dynid.identify` (step 3 alone), `dynid.run` and `dynid identify` (steps 1-7),
`dynid.report`, `dynid.demo`, `dynid report` and `dynid demo` (steps 1-4, 7, then 8-10).

1. `load_data`: the recordings, and the held-out data (a validation recording
   or the last `holdout` seconds of the one recording).
2. `tilt_step`: the direction of gravity (base tilt) on the identification data.
3. `identify_step`: IDIM (Gautier, Janot & Vandanjon 2010, eqs. (9)-(16)), DIDIM
   (eqs. (25)-(30)), the Projection Method or maximum likelihood (Bona &
   Curatella 2005, eqs. (10)-(16)).
4. `validate` on the held-out data.
5. `asymmetric_step`: friction with a different slope each way (Bona & Curatella eq. (2)).
6. `physical_step`: the physically consistent WLS, alone or with the effects of `effects`.
7. `verdict_of`: how far the result can be trusted.
8-10. DIDIM beside IDIM, the posterior, the diagnosis: the further analyses of a full report
   and the run of `dynid diagnose` (dynid.analysis.further).

The exports (URDF, MJCF, JSON, CSV, HTML) are rendered by the reports layer
(dynid.reports.pipeline) from what these steps return. No step changes a
result after it is returned: a step that adds to one builds a new one.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynid.analysis.data.experiment import DATA_EXTENSIONS, Experiment, load_experiment
from dynid.analysis.data.plausibility import GLITCH
from dynid.analysis.data.rates import check_rate_matches, check_same_rate
from dynid.analysis.data.record import SHARED_RUN, checked_experiment, recording_of, sample_keys, shared_run
from dynid.analysis.data.split import holdout_split
from dynid.analysis.diagnosis.asymmetric_friction import asymmetric_friction
from dynid.analysis.diagnosis.physical_fit import effect_candidates, identify_physical_effects
from dynid.analysis.estimators.controller_gains import identify_gains
from dynid.analysis.estimators.didim import DEFAULT_MAX_ITER, identify_didim
from dynid.analysis.estimators.drive_gains import DriveGainResult
from dynid.analysis.estimators.gravity_tilt import gravity_tilt
from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY, identify_idim
from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model
from dynid.analysis.estimators.payload import PayloadResult
from dynid.analysis.estimators.physical import identify_physical, require_cvxpy
from dynid.analysis.estimators.projection import identify_projection
from dynid.analysis.processing.observation import SETTINGS_HELP
from dynid.analysis.results import HeldParameters, Result, gathered_notices, notices_block, p_phrase
from dynid.analysis.sampling.noise import DEFAULT_NOISE
from dynid.analysis.statistics.validation import ValidationResult, validate
from dynid.analysis.statistics.verdict import verdict
from dynid.dynamics.robot import Robot, model_signature
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DataError, IdentificationError, InputError, did_you_mean
from dynid.ranges import check_range

METHODS = ("idim", "didim", "projection", "ml")
#: the JSON's spellings of the methods (`"method"`), taken as their names
METHOD_SPELLINGS = {"pm": "projection", "ml-eiv": "ml"}


def method_name(method):
    """`method` as one of METHODS when it is a spelling of one ("IDIM", "PM", "ML-EIV"); else as given."""
    if not isinstance(method, str):
        return method
    m = method.strip().lower()
    return METHOD_SPELLINGS.get(m, m)

#: --gain-update -> identify_didim's update_gains (eq. (27) at every step, the first simulation only, never)
GAIN_UPDATES = {"every": True, "initial": "initial", "none": False}

#: the analyses after IDIM that a full report runs (each can be skipped)
REPORT_PARTS = ("didim", "sample", "diagnose")

#: DIDIM's gain update by default (identify, report, demo): the paper's update at every step
#: oscillated on the demo data (25 steps, Ia6 +590 %) where updating only the first simulation
#: converged in 8 (all parameters within 1.5 %), and did not converge in 10 (nor 30) steps on
#: `dynid simulate --robot tx40` where "initial" converges in 6: the robot file's J_ap is not
#: max_q M_jj, so the update keeps the simulated loop's gains away from the recorded loop's.
#: `--gain-update every` is the paper's.
DEFAULT_GAIN_UPDATE = "initial"
#: the options of one method alone (Settings fields), refused with another
METHOD_OPTIONS = {"f0": ("ml",), "ml_harmonics": ("ml",), "max_iter": ("didim",), "gain_update": ("didim",),
                  "gains": ("didim",), "didim_start": ("didim",), "reference": ("didim",),
                  "torque_timing": ("didim",)}
#: the identification options a method does not read (given to it, they are refused, not ignored)
UNUSED_BY = {"ml": ("fc", "nd", "decimation_cutoff", "qd_threshold", "max_error_growth"),
             "projection": ("nd", "decimation_cutoff", "max_error_growth")}
UNUSED_WHY = {"ml": "maximum likelihood fits a Fourier series to the raw q, has its own velocity dead zone, "
                    "and reports every base parameter",
              "projection": "the Projection Method filters the recorded samples without decimation, and reports "
                            "every base parameter"}
#: the fewest bootstrap refits of the physical fit that have a spread (with fewer than 20 its σ
#: is the larger of the WLS σ and the refits' spread: PhysicalResult.bse)
MIN_BOOTSTRAP = 2
REPORT_GAIN_UPDATE = DEFAULT_GAIN_UPDATE

#: maximum likelihood keeps every sample: beyond this many values (samples x joints) it is refused
ML_MAX_VALUES = 200_000

#: smallest --fc as a fraction of the sampling rate: below it the zero-phase filter's
#: transient (about fs / fc samples at each end) is longer than any recording
MIN_FC_PER_FS = 1e-4

#: keyword names renamed to the command line's (old name -> new name); the old ones still work
RENAMED = {"update_gains": "gain_update", "n_boot": "bootstrap"}


@dataclass(frozen=True)
class Settings:
    """Every option of an identification run; the names are the command line's (`--gain-update`
    is `gain_update`).

    Data: `holdout` (seconds at the end held out) or `validation` (a recording);
    `resample` (irregular time steps put on a uniform grid). Processing (default: from the
    data): `fc` (Hz, filter of q), `nd` (decimation factor), `decimation_cutoff` (Hz),
    `qd_threshold` ('auto', a number or one per joint, rad/s), `max_error_growth` (the
    essential-parameter rule). Method: `method` ('idim', 'didim', 'projection', 'ml');
    ML: `f0` (Hz), `ml_harmonics`; DIDIM: `max_iter`, `gain_update` ('every', 'initial',
    'none'), `gains` ('assumed', 'identify'), `didim_start` ('idim', 'apriori'), `v_s` (rad/s or 'auto'), `reference` ('qr' or
    'q'). Model: `gravity_tilt`, `asymmetric_friction`, `physical`, `prior`, `prior_weight`,
    `mass_tolerance`, `physical_set`, `bootstrap`, `effects` (identify: the effects fitted
    beside the rigid body, 'spring:all'; diagnose: the candidate effects). Report and demo:
    `skip`, `seed`, `max_seconds`, `duration`. Diagnosis: `max_effects`, `alpha`, `no_offsets`.
    Posterior: `which`, `noise`, `walkers`, `max_steps`. Outputs (written by the reports layer):
    `report`, `json`, `csv`, `urdf`, `mjcf`.
    """

    method: str = "idim"
    holdout: float | None = None
    validation: object = None
    resample: bool = False
    fc: float | None = None
    nd: int | None = None
    decimation_cutoff: float | None = None
    qd_threshold: object = None
    max_error_growth: float = 0.02
    uncertainty: str = DEFAULT_UNCERTAINTY
    f0: float | None = None
    ml_harmonics: int | None = None
    max_iter: int | None = None
    gain_update: object = DEFAULT_GAIN_UPDATE
    gains: str = "assumed"
    didim_start: str = "idim"
    v_s: object = None
    torque_timing: str | None = None       # DIDIM: 'held' (its default) or 'centred'
    reference: str | None = None
    gravity_tilt: bool = False
    asymmetric_friction: bool = False
    physical: bool = False
    prior: str | None = None
    prior_weight: float = 1.0
    mass_tolerance: float | None = None
    physical_set: str = "base"
    bootstrap: int = 100
    effects: object = None
    skip: tuple = ()
    seed: int = 1
    max_seconds: float | None = None       # wall-clock limit of the sampler: off unless asked
    duration: float = 20.0
    max_effects: int = 3
    alpha: float = 0.01
    no_offsets: bool = False
    which: str = "essential"
    noise: str = DEFAULT_NOISE             # the posterior's noise model (dynid.analysis.sampling.noise)
    walkers: int | None = None
    max_steps: int | None = None
    report: object = None
    json: object = None
    csv: object = None
    urdf: object = None
    mjcf: object = None
    #: processing overrides by the observation's own names (fc_position ...), merged under the above
    processing_overrides: dict | None = None

    def __post_init__(self):
        object.__setattr__(self, "method", method_name(self.method))   # "IDIM", "PM": the JSON's spellings
        check_settings(self)

    def processing(self) -> dict | None:
        """The observation's settings (fc_position, nd, f_decimation_cutoff, qd_threshold, v_s).

        Returns
        -------
        dict or None
            The processing overrides by the observation's names; None when none is set.
        """
        s = dict(self.processing_overrides or {})
        for name, key in (("fc", "fc_position"), ("nd", "nd"), ("decimation_cutoff", "f_decimation_cutoff")):
            if getattr(self, name) is not None:
                s[key] = getattr(self, name)
        if self.qd_threshold is not None:
            s["qd_threshold"] = qd_threshold_value(self.qd_threshold)
        if self.v_s is not None and self.method == "didim":
            s["v_s"] = self.v_s
        if self.torque_timing is not None and self.method == "didim":
            s["torque_timing"] = self.torque_timing
        return s or (None if self.processing_overrides is None else s)

    @property
    def update_gains(self):
        """identify_didim's `update_gains` of `gain_update` (True, 'initial' or False)."""
        return GAIN_UPDATES.get(self.gain_update, self.gain_update) if isinstance(self.gain_update, str) \
            else self.gain_update

    def replace(self, **changes) -> Settings:
        return dataclasses.replace(self, **changes)


#: the numeric fields of Settings, each checked against its finite range (dynid.ranges.RANGES)
#: when a Settings is made: the command line and Python refuse alike, before any work
RANGED_FIELDS = {"holdout": "holdout", "fc": "fc", "nd": "nd", "decimation_cutoff": "decimation_cutoff",
                 "max_error_growth": "max_error_growth", "f0": "f0", "ml_harmonics": "ml_harmonics",
                 "max_iter": "max_iter", "v_s": "v_s", "prior_weight": "prior_weight",
                 "mass_tolerance": "mass_tolerance", "bootstrap": "n_boot", "seed": "seed",
                 "max_seconds": "max_seconds", "duration": "duration", "max_effects": "max_effects",
                 "alpha": "alpha", "walkers": "walkers", "max_steps": "max_steps"}


def check_settings(settings: Settings) -> None:
    """Every numeric option of `settings` within its finite physical range (InputError naming
    the option both ways, `--bootstrap (bootstrap=)`, and the range): a decimation by 1e10, a
    bootstrap of 1e9 refits or a prior weighed 1e300 times the data is refused before any work."""
    for field, name in RANGED_FIELDS.items():
        value = getattr(settings, field)
        if value is None or (field == "v_s" and isinstance(value, str) and value.strip().lower() == "auto"):
            continue
        check_range(name, value, python=field)
    if settings.qd_threshold is not None:
        values = qd_threshold_value(settings.qd_threshold)
        if not (isinstance(values, str) and values == "auto"):
            try:
                numbers = [float(v) for v in (values if isinstance(values, (list, tuple)) else [values])]
            except (TypeError, ValueError):
                numbers = [math.nan]
            if not all(math.isfinite(v) and v >= 0 for v in numbers):
                raise InputError(f"--qd-threshold (qd_threshold=) {settings.qd_threshold!r}: the velocity dead "
                                 f"zone must be finite and non-negative rad/s (0 keeps every row), or 'auto'")
    g = settings.gain_update
    if not (isinstance(g, bool) or g in GAIN_UPDATES.values() or (isinstance(g, str) and g in GAIN_UPDATES)):
        raise InputError(f"--gain-update (gain_update=) {g!r}: DIDIM's controller-gain update is one of "
                         f"{', '.join(GAIN_UPDATES)}")


def settings_from(settings=None, **options) -> Settings:
    """A `Settings` from a `Settings`, a processing dict (fc_position ...) and keyword options.

    The renamed keywords `update_gains` and `n_boot` still work, with a DeprecationWarning.
    """
    for old, new in RENAMED.items():
        if old in options:
            warnings.warn(f"the keyword {old}= is now {new}= (as --{new.replace('_', '-')} on the command "
                          f"line); {old}= will be removed", DeprecationWarning, stacklevel=3)
            value = options.pop(old)
            if new == "gain_update":
                value = {v: k for k, v in GAIN_UPDATES.items()}.get(value, value) \
                    if isinstance(value, bool) or value == "initial" else value
            if new in options:
                raise InputError(f"give {new}= or the old {old}=, not both")
            options[new] = value
    unknown = sorted(set(options) - {f.name for f in dataclasses.fields(Settings)})
    if unknown:
        raise InputError(f"unknown option(s) {', '.join(unknown)}"
                         f"{did_you_mean(unknown[0], [f.name for f in dataclasses.fields(Settings)])}; the "
                         f"options are the fields of dynid.Settings (the command line's, with _ for -)")
    for f in dataclasses.fields(Settings):
        # a switch given as text ("yes", "false") would be taken for True
        if f.type in ("bool", bool) and f.name in options and type(options[f.name]).__name__ not in ("bool", "bool_"):
            raise InputError(f"{f.name}= is a switch: give True or False, not {options[f.name]!r}")
    if isinstance(settings, Settings):
        return settings.replace(**options)
    if settings is not None and not isinstance(settings, dict):
        raise InputError(f"settings must be a dict of processing options or a Settings, not "
                         f"{type(settings).__name__}")
    if settings is not None:
        from_run = sorted(set(settings) & {f.name for f in dataclasses.fields(Settings)}
                          - {"processing_overrides"} - set(SETTINGS_HELP))
        if from_run:
            # a dict holds the processing overrides (fc_position, nd, ...): a run option there was a DataError
            raise InputError(f"settings= as a dict holds processing overrides (fc_position, nd, ...); "
                             f"{', '.join(from_run)} {'is an option' if len(from_run) == 1 else 'are options'} "
                             f"of the run: pass {', '.join(f'{k}=' for k in from_run)} as a keyword, or "
                             f"settings=dynid.Settings({from_run[0]}=...)")
    return Settings(processing_overrides=dict(settings) if settings is not None else None, **options)


def qd_threshold_value(v):
    """--qd-threshold: 'auto', one number, or one number per joint (a list or comma-separated text)."""
    if not isinstance(v, str):
        return v
    v = v.strip()
    if v == "auto":
        return v
    try:
        vals = [float(x) for x in v.split(",")]
    except ValueError:
        raise InputError(f"qd_threshold (--qd-threshold) must be a number, per-joint numbers separated by "
                         f"commas, or 'auto'; got {v!r}") from None
    return vals[0] if len(vals) == 1 else vals


class _Silent:
    """The default reporter: no messages, no progress bars (the reports layer's Reporter prints)."""

    def __call__(self, msg):
        pass

    def progress(self, label):
        return contextlib.nullcontext(_NoBar())


class _Plain(_Silent):
    """A plain function of a message as a reporter: the messages, no progress bars."""

    def __init__(self, say):
        self._say = say

    def __call__(self, msg):
        self._say(msg)


class _NoBar:
    def update(self, fraction):
        pass


def messages(say):
    """`say` (a Reporter), a plain function of a message (`print`) with no progress bars, or a
    silent reporter when None."""
    if say is None:
        return _Silent()
    if not callable(say):
        raise InputError(f"say must be a function taking a message (print, or a dynid Reporter), or None "
                         f"for silence; not {type(say).__name__}")
    return say if callable(getattr(say, "progress", None)) else _Plain(say)


# ---------------------------------------------------------------- step 1: data

def as_robot(robot, *, base=None, tip=None):
    """A Robot from a Robot, a bundled name or a robot file path."""
    if isinstance(robot, Robot):
        return robot
    if not isinstance(robot, (str, os.PathLike)):
        # a recording or a result where the robot goes: the arguments' order, not a robot file
        raise InputError(f"robot must be a Robot, a bundled robot's name or a robot file's path, not "
                         f"{type(robot).__name__}; the recording comes first and the robot second "
                         "(dynid.diagnose(data, robot, validation=...))")
    if os.path.splitext(str(robot))[1].lower() in DATA_EXTENSIONS:
        raise InputError(f"robot {str(robot)!r} is a data file, not a robot file (.toml or .urdf) nor a bundled "
                         "robot's name; the recording comes first and the robot second (dynid.run(data, robot); "
                         "--robot on the command line)")
    return load_robot(robot, base=base, tip=tip)


def as_experiments(data, robot, *, resample=False) -> list:
    """A list of Experiments from one or several paths or Experiments: a path loaded, an Experiment
    in memory checked as the loader checks a file (`checked_experiment`). `resample`: irregular
    time steps of either put on a uniform grid at the median step."""
    items = list(data) if isinstance(data, (list, tuple)) else [data]
    if not items:
        raise InputError("no recording given: pass a data file or an Experiment")
    out = []
    for k, item in enumerate(items):
        item = recording_of(item)
        if isinstance(item, Experiment):
            out.append(checked_experiment(item, k, robot, resample=resample))
        elif isinstance(item, (str, os.PathLike)):
            out.append(_load_resampled(item, robot) if resample else _load(item, robot))
        else:
            raise InputError(f"a recording must be a data file path or an Experiment, not {type(item).__name__}")
    return out


def _load(path, robot):
    try:
        return load_experiment(path, robot)
    except DataError as exc:
        if "irregular time steps" in str(exc) and not str(path).lower().endswith(".toml"):
            raise DataError(f"{exc} On the command line: --resample.") from None
        raise


def _load_resampled(path, robot):
    """`--resample`: a recording in dynid's column format put on a uniform time grid, through the
    experiment description's `resample = true` (a one-line TOML beside nothing: a temporary one)."""
    if str(path).lower().endswith(".toml"):
        raise InputError(f"--resample: {path} is an experiment description; write resample = true in "
                         f"its [experiment] table instead")
    if not os.path.isfile(path):        # named here: the temporary description would be named otherwise
        raise DataError(f"{path}: file not found. Check the path.")
    with tempfile.TemporaryDirectory(prefix="dynid-resample-") as tmp:
        toml = os.path.join(tmp, "resample.toml")
        with open(toml, "w", encoding="utf-8") as fh:
            fh.write(f"[experiment]\nfile = {json.dumps(os.path.abspath(os.fspath(path)))}\n"
                     f"name = {json.dumps(Path(path).stem)}\nresample = true\n")
        exp = load_experiment(toml, robot)
    # the recording's own name, not the temporary description's
    return dataclasses.replace(exp, source=f"{os.fspath(path)} (resampled)")


def check_robot_options(settings: Settings, robot) -> None:
    """Options whose valid values depend on the robot, checked before any data is loaded."""
    v = settings.qd_threshold
    if isinstance(v, str) and v.strip() != "auto":
        k = len(v.split(","))
        if k not in (1, robot.n_joints):
            raise InputError(f"--qd-threshold {v}: {k} values for the {robot.n_joints} joints of robot "
                             f"'{robot.name}'; give one value for every joint or {robot.n_joints} "
                             f"comma-separated ones (one per joint)")


def check_cutoffs(settings: Settings, experiments) -> None:
    """--fc against the sampling rate of every recording (after loading)."""
    fc = settings.fc
    if fc is None:
        return
    for exp in experiments:
        fs = getattr(exp, "fs", None)
        if exp is None or not fs:
            continue
        name = getattr(exp, "name", None) or getattr(exp, "source", None) or "the recording"
        if fc >= fs / 2:
            raise InputError(f"--fc {fc:g} Hz is not below half the sampling rate ({fs:g} Hz) of {name}; "
                             f"give --fc below {fs / 2:g} Hz")
        if fc < MIN_FC_PER_FS * fs:
            raise InputError(f"--fc {fc:g} Hz is below {MIN_FC_PER_FS * fs:g} Hz ({MIN_FC_PER_FS:g} of the "
                             f"sampling rate {fs:g} Hz of {name}): the filter's transient would last about "
                             f"{fs / fc:.3g} samples at each end, longer than a recording; give --fc "
                             f"{MIN_FC_PER_FS * fs:g} or more (typically 10 to 100 Hz)")


def load_data(data, robot, settings: Settings, say=None):
    """Step 1: `(experiments, held_out)`: the identification recordings and the held-out
    Experiment (the `validation` recording, or the last `holdout` seconds; None without)."""
    say = messages(say)
    if settings.validation is not None and settings.holdout is not None:
        raise InputError("give a validation recording or a holdout, not both (--validation, --holdout)")
    if settings.holdout is not None and not settings.holdout > 0:
        raise InputError(f"--holdout must be a positive number of seconds, got {settings.holdout:g}")
    experiments = as_experiments(data, robot, resample=settings.resample)
    for item, exp in zip(data if isinstance(data, (list, tuple)) else [data], experiments):
        if isinstance(item, (str, os.PathLike)):
            say(f"loaded {item}: {exp.n_samples} samples at {exp.fs:g} Hz")
    check_same_rate(experiments, "a data file")
    check_cutoffs(settings, experiments)
    held_out = None
    if settings.validation is not None:
        held_out = as_experiments(settings.validation, robot, resample=settings.resample)[0]
        if isinstance(settings.validation, (str, os.PathLike)):
            say(f"validation {settings.validation}: {held_out.n_samples} samples")
        check_rate_matches(held_out, experiments[0].fs, "the --validation recording",
                           experiments[0].source or experiments[0].name)
        check_cutoffs(settings, [held_out])
        check_validation_is_other_data(held_out, experiments)
    elif settings.holdout is not None:
        if len(experiments) > 1:
            raise InputError("--holdout splits one recording; with several, use --validation")
        train, held_out = holdout_split(experiments[0], settings.holdout)
        experiments = [train]
    return experiments, held_out


def check_validation_is_other_data(held_out, experiments) -> None:
    """Refuse a validation recording that shares `SHARED_RUN` consecutive samples, bit for bit,
    with an identification recording (the same file, a copy, or a cut of it)."""
    keys = sample_keys(held_out)
    for exp in experiments:
        run = shared_run(keys, exp)
        if run >= SHARED_RUN:
            raise InputError(f"--validation (validation=) {held_out.source or held_out.name} shares {run} "
                             f"consecutive samples, bit for bit, with the identification recording "
                             f"{exp.source or exp.name}: validating on the identification data says nothing "
                             "about the model; give another recording, or hold out the end of this one "
                             "(--holdout SECONDS; dynid.holdout_split in Python)")


@contextlib.contextmanager
def holdout_hint(settings: Settings, experiments):
    """Within it, an identification that fails for want of data says what --holdout left of it
    (it advised a richer trajectory when the holdout had taken most of the recording), and
    which glitches the loader found in the data (a one-sample jump of a position zeroes a
    joint's rows through the velocity dead zone: the error alone would blame the trajectory)."""
    try:
        yield
    except IdentificationError as exc:
        glitches = [n for e in experiments for n in getattr(e, "notices", []) if GLITCH in n]
        tail = (" The data hold glitches, which can cause this: " + "; ".join(glitches)) if glitches else ""
        still = _still_joints(experiments)
        if still:
            text = "; ".join(still)
            tail += f" {text[0].upper()}{text[1:]}: a joint that does not move cannot identify its parameters; record it moving"
        if settings.holdout is None or not experiments:
            if not tail:
                raise
            raise IdentificationError(f"{exc}{tail}") from None
        t = experiments[0].t
        raise IdentificationError(f"--holdout {settings.holdout:g} s leaves the first {t[-1] - t[0]:.3g} s of the "
                                  f"recording to identify on, and they do not identify the model (hold out less): "
                                  f"{exc}{tail}") from None


#: a joint whose position spans less than this (rad, or m) in a recording is still
STILL_SPAN = 1e-3


def _still_joints(experiments) -> list:
    """'joint j does not move in <recording> (qj spans x rad)' for each still joint of a recording
    in which another joint moves (a wholly still recording is refused before, with its own message)."""
    out = []
    for e in experiments:
        q = getattr(e, "q", None)
        if q is None or q.shape[0] < 2:
            continue
        span = np.ptp(q, axis=0)
        if np.all(span < STILL_SPAN):
            continue
        out += [f"joint {j + 1} does not move in {e.source or e.name} (q{j + 1} spans {span[j]:.3g} rad)"
                for j in np.flatnonzero(span < STILL_SPAN)]
    return out


# ---------------------------------------------------------------- step 2: gravity tilt
#: the likelihood-ratio level below which the data tell a tilt from a level base (as the tilt's summary)
TILT_LEVEL = 0.01


def tilt_step(experiments, robot, settings: Settings, say=None):
    """Step 2: `(tilt, robot)`: the base tilt and the robot with the tilted gravity (None, robot
    without `gravity_tilt`)."""
    if not settings.gravity_tilt:
        return None, robot
    messages(say)("estimating the direction of gravity (base tilt) on the identification data")
    tilt = gravity_tilt(experiments, robot, settings=settings.processing())
    if not tilt.p_value < TILT_LEVEL:
        # asked for, so applied; but the data do not tell it from a level base
        tilt.notices.append(f"the tilt is not significant ({p_phrase(tilt.p_value)}, level {TILT_LEVEL:g}): the "
                            "identification uses the tilted gravity as --gravity-tilt asks"
                            + (f", with {len(tilt.added_parameters)} more base parameters "
                               f"({', '.join(tilt.added_parameters)})" if tilt.added_parameters else "")
                            + "; without the option the level gravity would serve as well")
    return tilt, tilt.robot


# ---------------------------------------------------------------- step 3: identify

def check_identify(settings: Settings) -> None:
    """The method's options, checked before any work."""
    method = settings.method
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if settings.physical and method not in ("idim", "didim"):
        raise InputError(f"physical=True works with methods idim and didim only, not {method!r}")
    if method in ("projection", "ml") and settings.uncertainty != DEFAULT_UNCERTAINTY:
        # it was ignored: the Projection Method and ML have a covariance of their own
        raise InputError(f"uncertainty={settings.uncertainty!r} (--uncertainty) chooses the covariance of IDIM "
                         f"and DIDIM; method {method!r} reports its own (its summary names it): leave it out")
    unused = UNUSED_BY.get(method, ())
    given = [f"--{name.replace('_', '-')} ({name}=)" for name in unused
             if getattr(settings, name) != getattr(Settings, name)]
    if settings.processing_overrides and method == "ml":
        given.append(f"settings {sorted(settings.processing_overrides)}")
    elif settings.processing_overrides and method == "projection":      # its own names for nd, decimation
        given += [f"settings {k!r}" for k in ("nd", "f_decimation_cutoff")
                  if settings.processing_overrides.get(k) is not None]
    if given:       # they were ignored without a word
        raise InputError(f"{', '.join(given)}: method {method!r} does not use "
                         f"{'it' if len(given) == 1 else 'them'} ({UNUSED_WHY[method]}); leave "
                         f"{'it' if len(given) == 1 else 'them'} out")
    if not settings.physical and (settings.prior is not None or settings.mass_tolerance is not None):
        raise InputError("prior and mass_tolerance are options of the physically consistent fit: "
                         "pass physical=True (--physical)")
    if method == "didim" and settings.gains not in ("assumed", "identify"):
        raise InputError(f"gains must be 'assumed' or 'identify', got {settings.gains!r} (--gains)")
    if method == "didim" and settings.didim_start not in ("idim", "apriori"):
        raise InputError(f"didim_start must be 'idim' or 'apriori', got {settings.didim_start!r} (--didim-start)")
    if settings.physical:
        require_cvxpy()          # before the identification, not after it


def _carrying(result, robot, experiment=None):
    """`result` with its robot (DIDIM, PM and ML results are built without one): dynid.verdict and
    dynid.validate of the result then judge it as the command line does (joint names, a-priori values).
    A result with `robot_name`, `robot_signature` and `source` fields left empty (ML, built from
    arrays; the Projection Method's `identify_projection` fills its own) gets the robot's name and
    signature and the `experiment`'s source, as IDIM's has."""
    if getattr(result, "robot", None) is None:
        try:
            result.robot = robot
        except AttributeError:           # a read-only property: the result knows its robot otherwise
            pass
    if getattr(result, "robot_name", None) == "":
        result.robot_name = robot.name
    if getattr(result, "robot_signature", None) == "":
        result.robot_signature = model_signature(robot)
    if experiment is not None and getattr(result, "source", None) == "":
        result.source = str(experiment.source)
    return result


def identify_step(experiments, robot, settings: Settings, progress=None, *, observation=None, bp=None):
    """Step 3: identify with `settings.method`; IDIM stacks several recordings, the others take one.

    IDIM with `physical`: the PC-WLS (a PhysicalResult whose `idim` is the unconstrained fit).
    DIDIM: its notices say which controller gains it simulated with. `observation` and `bp`:
    IDIM's decimated system of the one recording and its base parameters, when the caller
    has built them already (the diagnosis).
    """
    check_identify(settings)
    method = settings.method
    if method != "idim" and len(experiments) > 1:
        raise InputError(f"method {method} identifies one recording at a time; "
                         f"{len(experiments)} were given")
    if method == "idim":
        # PC-WLS takes the WLS covariance as its metric and has its own bootstrap sigma:
        # its estimate must not depend on the IDIM interval option
        res = identify_idim(experiments if len(experiments) > 1 else experiments[0], robot,
                            settings=settings.processing(), max_error_growth=settings.max_error_growth,
                            progress=progress, observation=observation, bp=bp,
                            uncertainty="classic" if settings.physical else settings.uncertainty)
        if not settings.physical:
            return res
        return identify_physical(res, robot, prior=settings.prior, prior_weight=settings.prior_weight,
                                 mass_tolerance=settings.mass_tolerance, n_boot=settings.bootstrap,
                                 which=settings.physical_set, uncertainty=settings.uncertainty)
    exp = experiments[0]
    if method == "didim":
        return _carrying(_didim(exp, robot, settings, progress), robot)
    if method == "projection":
        return _carrying(identify_projection(exp, robot, settings=settings.processing()), robot)
    if settings.f0 is None:
        raise InputError("method ml needs f0, the fundamental frequency (Hz) of the periodic excitation "
                         "(--f0 on the command line)")
    if exp.n_samples * robot.n_joints > ML_MAX_VALUES:
        raise InputError(f"{exp.source}: {exp.n_samples} samples x {robot.n_joints} joints; maximum "
                         f"likelihood keeps every sample and is limited to {ML_MAX_VALUES:,} values: "
                         "resample or cut the recording (a TOML experiment file), or use IDIM")
    return _carrying(maximum_likelihood(exp.t, exp.q, exp.tau, robot_model(robot), f0=settings.f0,
                                        n_harmonics=settings.ml_harmonics, progress=progress), robot, exp)


def _didim(exp, robot, settings: Settings, progress):
    """DIDIM (section 3), with the gains of the robot file or identified from the logged loop."""
    if robot.controller is None:
        raise InputError(f"DIDIM simulates the robot under its controller, but '{robot.name}' "
                         f"({robot.source}) has no [controller] table: add one to the robot file")
    ref = settings.reference or ("qr" if exp.qr is not None else "q")
    processing = settings.processing()
    identified, controller, chi0, update_gains = None, None, None, settings.update_gains
    if settings.gains == "identify":
        if exp.qr is None:
            raise InputError(f"{exp.source}: --gains identify needs the reference the controller tracked: "
                             "the recording has no qr columns. Log the controller's reference "
                             "(columns qr1..qrn); use the gains of the robot file "
                             "(--gains assumed) and read the DIDIM result as depending on them")
        identified = identify_gains(exp, robot)
        controller = identified.controller(robot)
        update_gains = False
        # With the real loop's gains, the paper's rough start (Ia = 1 ...) drives the simulated
        # robot into saturation on the first step; IDIM's estimate is a start in the right basin.
        # The start gets the settings IDIM shares with DIDIM (not v_s, substeps, transient ...).
        if settings.didim_start == "idim":
            shared = None if processing is None else {k: v for k, v in processing.items() if k in SETTINGS_HELP}
            start = identify_idim(exp, robot, settings=shared, max_error_growth=settings.max_error_growth)
            chi0 = dict(zip(start.base.names, start.wls.chi))
    if settings.didim_start == "apriori":
        # the robot file's a-priori values (base names as given, the rest zero); a start whose
        # M(q) is not positive definite is projected onto the physically consistent set by DIDIM
        if not getattr(robot, "apriori", None):
            raise InputError(f"--didim-start apriori: '{robot.name}' ({robot.source}) has no [apriori] "
                             "values; add them to the robot file or start from IDIM (--didim-start idim)")
        chi0 = dict(robot.apriori)

    res = identify_didim(exp, robot, settings=processing, reference=ref, controller=controller, chi0=chi0,
                         max_iter=DEFAULT_MAX_ITER if settings.max_iter is None else settings.max_iter,
                         max_error_growth=settings.max_error_growth, update_gains=update_gains,
                         progress=progress, physical=settings.physical, prior=settings.prior,
                         prior_weight=settings.prior_weight, mass_tolerance=settings.mass_tolerance,
                         n_boot=settings.bootstrap, uncertainty=settings.uncertainty)
    # the new result's own fields, set before it leaves this step
    res.gains = identified
    res.notices.append(didim_gains_notice(exp, robot, identified))
    return res


def didim_gains_notice(exp, robot, identified) -> str:
    """What DIDIM's parameters depend on: the gains it simulated the loop with."""
    if identified is not None:
        return ("controller gains identified from the logged reference, position and torque ("
                + ", ".join(f"{n} {v:.4g}" for n, v in zip(identified.names, identified.chi)) + ")")
    what = ("the logged reference" if exp.qr is not None else
            "the measured position used as the reference (no reference logged)")
    return (f"DIDIM simulated the loop with the controller gains assumed in the robot "
            f"file ({robot.source}) tracking {what}: its parameters depend on those gains"
            + ("" if exp.qr is None else "; dynid identify --method didim --gains identify estimates them from the data"))


# ---------------------------------------------------------------- steps 5-6: friction, physical

def check_physical_options(settings: Settings) -> None:
    """The physical fit's options without it would be ignored; one refit has no spread. Names as on the command line (`--bootstrap`, bootstrap= in Python)."""
    if not settings.physical:
        given = [f"--{o}" for o, set_ in (("bootstrap", settings.bootstrap != Settings.bootstrap),
                                          ("prior-weight", settings.prior_weight != Settings.prior_weight))
                 if set_]
        if given:
            raise InputError(f"{', '.join(given)} {'is an option' if len(given) == 1 else 'are options'} of the "
                             f"physically consistent fit: add --physical (physical=True), or leave "
                             f"{'it' if len(given) == 1 else 'them'} out")
    if settings.physical_set not in ("base", "essential"):
        raise InputError(f"--physical-set (physical_set=) must be 'base' or 'essential', got "
                         f"{settings.physical_set!r}")
    if settings.bootstrap < 0 or 0 < settings.bootstrap < MIN_BOOTSTRAP:
        raise InputError(f"--bootstrap {settings.bootstrap}: give 0 (no bootstrap σ) or at least {MIN_BOOTSTRAP} "
                         f"refits (one has no spread)")


def check_run(settings: Settings, robot=None):
    """The options of a whole run (`dynid identify`), refused before any data is loaded;
    returns the effect candidates of `effects` (None without)."""
    if settings.method != "idim":
        given = [f"--{o}" for o, v in (("validation", settings.validation), ("holdout", settings.holdout),
                                       ("urdf", settings.urdf),
                                       ("asymmetric-friction", settings.asymmetric_friction),
                                       ("mjcf", settings.mjcf), ("effects", settings.effects),
                                       ("physical", settings.physical and settings.method != "didim"),
                                       ("gravity-tilt", settings.gravity_tilt))
                 if v is not None and v is not False]
        if given:
            raise InputError(f"{', '.join(given)} work{'s' if len(given) == 1 else ''} with --method idim only, "
                             f"not with --method "
                             f"{settings.method}; run the IDIM identification for "
                             f"{'it' if len(given) == 1 else 'them'}")
    check_identify(settings)
    if settings.v_s is not None and settings.method != "didim":
        raise InputError(f"--v-s is the simulated Coulomb friction's sign width of DIDIM; it does not "
                         f"apply to --method {settings.method}")
    # an option of another method would be ignored without a word (given: not the Settings default)
    for method in ("didim", "ml"):
        given = [f"--{name.replace('_', '-')}" for name, methods in METHOD_OPTIONS.items()
                 if methods == (method,) and getattr(settings, name) != getattr(Settings, name)]
        if given and settings.method != method:
            raise InputError(f"{', '.join(given)} {'is an option' if len(given) == 1 else 'are options'} of "
                             f"--method {method}, not of --method {settings.method}: leave "
                             f"{'it' if len(given) == 1 else 'them'} out or add --method {method}")
    check_physical_options(settings)
    if robot is not None:
        check_robot_options(settings, robot)
        return _effect_candidates(settings, robot)
    return None


def _effect_candidates(settings: Settings, robot):
    """The candidates of `effects` (None without it), refused early with the options they
    do not combine with."""
    if settings.effects is None:
        return None
    if isinstance(settings.effects, str) and not settings.effects.strip():
        raise InputError("--effects (effects=) names no effect; give some (name:joint[:order], e.g. "
                         "spring:all), or leave it out")
    spec = settings.effects
    if settings.physical_set != "base":
        raise InputError("--effects fits the effects beside all base parameters: drop --physical-set "
                         f"{settings.physical_set}")
    if settings.urdf:
        raise InputError("--urdf writes a rigid body, and URDF has no field for the effects of --effects: "
                         "--mjcf PATH writes the rigid body with its springs (MuJoCo joint stiffness), "
                         "or export the URDF from a run without --effects")
    out = effect_candidates(spec, robot.n_joints)
    if not out:
        raise InputError(f"--effects {spec!r} names no effect; e.g. --effects spring:all")
    if settings.mjcf:
        if not settings.physical:
            raise InputError("--mjcf with --effects writes the physically consistent rigid body fitted "
                             "with the springs (an unconstrained fit may not be a body MuJoCo accepts, "
                             "and another consistent set does not go with these springs): add --physical")
        other = [f"{c.name} on joint {c.joint}" for c in out if c.name != "spring"]
        if other:
            raise InputError("--mjcf with --effects: MJCF has no field for " + ", ".join(other) +
                             "; only spring (joint stiffness) can be written: drop the others from "
                             "--effects, or drop --mjcf")
    return out


def asymmetric_step(experiments, robot, result, settings: Settings):
    """Step 5: each joint's friction with different slopes for q' > 0 and q' < 0 (None without)."""
    if not settings.asymmetric_friction:
        return None
    if len(experiments) > 1:
        raise InputError("--asymmetric-friction works on one recording at a time")
    return asymmetric_friction(experiments[0], robot, result)


def physical_step(experiments, robot, result, held_out, settings: Settings, candidates=None, say=None):
    """Step 6: `(physical, effects)`: the PC-WLS of the IDIM `result` (with `physical`) and the
    fit with the effects of `effects` beside the rigid body (with `candidates`)."""
    say = messages(say)
    if candidates is not None:
        say(f"effects beside the rigid body: {settings.effects}"
            + ("; physically consistent WLS (SDP)" if settings.physical else ""))
        effects = identify_physical_effects(experiments, robot, result, candidates, physical=settings.physical,
                                            validation=held_out, spec=settings.effects, prior=settings.prior,
                                            prior_weight=settings.prior_weight,
                                            mass_tolerance=settings.mass_tolerance, n_boot=settings.bootstrap)
        if effects.physical is None:
            return None, effects
        physical = dataclasses.replace(effects.physical, idim=result,
                                       data_hash=getattr(result, "data_hash", "") or "",
                                       rel_error=effects.rel_error_pc, wls_rel_error=effects.rel_error_wls,
                                       validation=effects.validation)
        return physical, dataclasses.replace(effects, physical=physical)
    if not settings.physical:
        return None, None
    say("physically consistent WLS (SDP)")
    physical = identify_physical(result, robot, prior=settings.prior, prior_weight=settings.prior_weight,
                                 mass_tolerance=settings.mass_tolerance, n_boot=settings.bootstrap,
                                 which=settings.physical_set, uncertainty=settings.uncertainty)
    if held_out is not None:
        physical = dataclasses.replace(physical, validation=physical.held_out_block(held_out, robot))
    return physical, None


# ---------------------------------------------------------------- step 7: verdict

def verdict_of(result, held_out=None, *, robot=None, diagnosis=None, residuals=None):
    """Step 7: the verdict of `result` (statistics.verdict.verdict), on the `held_out` data when
    given: an Experiment or a path (validated here) or a ValidationResult.

    A run (`Identification`) or a full report carries its verdict: it is returned as is.
    """
    if result is None or not any(hasattr(result, a) for a in ("names", "result", "verdict")):
        raise InputError(f"verdict: give an identification result (dynid.identify, dynid.run), not "
                         f"{type(result).__name__}")
    if isinstance(result, (PayloadResult, DriveGainResult)):
        # the robot model's rules (rotor inertias, friction, %sigma of base parameters) say
        # nothing of a payload's ten parameters or of drive gains: those have their own rule
        what = "drive-gain" if isinstance(result, DriveGainResult) else "payload"
        raise InputError(f"verdict: a {what} result has its own verdict, result.verdict() (the rule of its "
                         f"report section: identified, with reservations or not identified); dynid.verdict "
                         f"judges an identified robot model")
    if held_out is not None and not isinstance(held_out, (Experiment, ValidationResult, str, os.PathLike)):
        raise InputError(f"verdict: the held-out data must be an Experiment, a file path or a ValidationResult, "
                         f"not {type(held_out).__name__}")
    if robot is not None:
        robot = as_robot(robot)
    own = getattr(result, "verdict", None)
    if own is not None and not callable(own) and held_out is None:
        return own
    validation = held_out
    if held_out is not None and not isinstance(held_out, ValidationResult):
        # a run: its identification result (an estimator's own result keeps itself)
        target = result if getattr(result, "base", None) is not None else getattr(result, "result", result)
        validation = validate(target, held_out, robot)
        result = target
    return verdict(result, validation, robot=robot, diagnosis=diagnosis, residuals=residuals)


# ---------------------------------------------------------------- the run

@dataclass(frozen=True, eq=False, repr=False)
class Identification(HeldParameters, Result):
    """What one run of `dynid identify` gives: the identification, its validation and
    verdict, and the optional parts (tilt, asymmetric friction, PC fit, effects, export).

    `to_dict()` is the JSON `dynid identify --json` writes; `summary()` what it prints.
    """

    settings: Settings
    robot: object                        # with the tilted gravity under gravity_tilt
    experiments: list
    result: object                       # IDIMResult, DIDIMResult, ProjectionResult, ML, PhysicalResult
    verdict: object
    held_out: object = None              # the held-out Experiment
    validation: object = None            # ValidationResult
    tilt: object = None
    asymmetric_friction: object = None
    physical: object = None
    effects: object = None
    export: object = None                # the URDF/MJCF export (reports layer), when asked

    @property
    def method(self) -> str:
        return self.settings.method

    def to_dict(self) -> dict:
        doc = self.result.to_dict()
        doc["verdict"] = self.verdict.to_dict()
        if self.method != "idim":
            return doc
        if self.validation is not None:
            doc["validation"] = self.validation.to_dict()
        for key, part in (("gravity_tilt", self.tilt), ("asymmetric_friction", self.asymmetric_friction),
                          ("urdf_export", self.export)):
            if part is not None:
                doc[key] = part.to_dict()
        if self.physical is not None:
            doc["physical"] = self.physical.physical_block()
        if self.effects is not None:
            doc["effects"] = self.effects.to_dict()
            if self.physical is not None:
                doc["physical"]["effects"] = doc["effects"]
        return doc

    def summaries(self) -> list:
        """The printed parts, the verdict first, then one Notices block for all of them.

        Returns
        -------
        list of str
            The summaries in print order.
        """
        gains = getattr(self.result, "gains", None)
        with gathered_notices() as remarks:
            validation = self.validation.summary() if self.validation is not None else None
            if validation is not None and self.settings.holdout is not None:
                validation = f"held out: the last {self.settings.holdout:g} s\n{validation}"
            parts = [self.verdict.summary()]
            parts += [p if isinstance(p, str) else p.summary()
                      for p in (self.tilt, self.result, validation, self.asymmetric_friction, self.effects,
                                self.physical if self.method == "idim" else None, gains) if p is not None]
        block = notices_block(remarks)
        return [p for p in parts if p] + (["\n".join(block)] if block else [])

    def summary(self) -> str:
        return "\n\n".join(self.summaries())

    def _held(self):
        # the parameter interface (params, bse, conf_int, run["ZZ1R"]) is the identification's,
        # as --csv writes it; the physically consistent fit is `physical`, with the same interface
        return self.result

    def __repr__(self) -> str:
        return f"{super().__repr__()[:-1]}; verdict {getattr(self.verdict, 'status', '?')}>"


def run(data, robot, settings=None, *, say=None, **options) -> Identification:
    """Steps 1-7 of `dynid identify`: load, split, tilt, identify, validate, asymmetric
    friction, physically consistent fit and effects, verdict.

    Parameters
    ----------
    data : path, Experiment, or a list of them
        The identification recording(s).
    robot : Robot, bundled name or robot file
    settings : Settings or dict, optional
        A `Settings`, or processing overrides by the observation's names (fc_position ...).
    say : callable with a progress(label) method, optional
        Messages and progress bars (dynid.reports.progress.Reporter); silent by default.
    **options
        Any field of `Settings` (the command line's options: holdout=3, gravity_tilt=True ...).

    Returns
    -------
    Identification
        Its `to_dict()` is the JSON of `dynid identify --json`.
    """
    settings = settings_from(settings, **options)
    say = messages(say)
    robot = as_robot(robot)
    candidates = check_run(settings, robot)
    experiments, held_out = load_data(data, robot, settings, say)
    tilt, robot = tilt_step(experiments, robot, settings, say)
    label = {"didim": "DIDIM iterations", "ml": "maximum likelihood",
             "projection": "Projection Method"}.get(settings.method, "regressor and decimation")
    with holdout_hint(settings, experiments), say.progress(label) as bar:
        # IDIM: the unconstrained fit; its PC-WLS (physical) is step 6, beside it
        result = identify_step(experiments, robot, settings.replace(physical=False, prior=None, mass_tolerance=None)
                               if settings.method == "idim" else settings, progress=bar.update)
    if settings.method != "idim":
        # PC-DIDIM's fit is the result's own (`result.physical`); `physical` names it, as for IDIM
        return Identification(settings=settings, robot=robot, experiments=experiments, result=result,
                              verdict=verdict(result, robot=robot), physical=getattr(result, "physical", None))
    validation = validate(result, held_out, robot) if held_out is not None else None
    asym = asymmetric_step(experiments, robot, result, settings)
    physical, effects = physical_step(experiments, robot, result, held_out, settings, candidates, say)
    return Identification(settings=settings, robot=robot, experiments=experiments, result=result,
                          verdict=verdict(result, validation, robot=robot, physical=physical, effects=effects),
                          held_out=held_out,
                          validation=validation, tilt=tilt, asymmetric_friction=asym, physical=physical,
                          effects=effects)
