"""dynid: identify the dynamic model of a robot arm from measured data, and say how far to trust it.

The public API (everything a user needs; the subpackages hold the rest)::

    import dynid
    robot = dynid.load_robot("tx40")                      # bundled name, .toml or .urdf
    exp = dynid.load_experiment("examples/staubli_tx40/experiment.toml", robot)
    train, held_out = dynid.holdout_split(exp, 3.0)       # the last 3 s held out
    r = dynid.identify(train, robot)                      # IDIM; or method="didim" | "projection" | "ml"
    print(r.summary()); r.params["ZZ1R"]; r.conf_int()
    v = dynid.validate(r, held_out)
    print(dynid.verdict(r, held_out))                     # how far to trust it (as the report)
    run = dynid.run(exp, robot, holdout=3.0, gravity_tilt=True)   # all of `dynid identify`
    dynid.report(exp, robot, "report.html", holdout=3.0)  # IDIM, DIDIM, posterior, diagnosis

Methods follow Gautier, Janot & Vandanjon (2010) and Bona & Curatella (2005).
"""
from __future__ import annotations

import os
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version
from typing import TYPE_CHECKING, Any

try:
    __version__ = _version("dynid")
except PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

from dynid.errors import (
    ConvergenceError,
    DataError,
    DynidError,
    IdentificationError,
    InputError,
    OutputError,
    RobotFileError,
)
from dynid.threads import with_single_blas_thread

# The public names, imported on first use (PEP 562): `import dynid` and the command line
# start in milliseconds, and a signal at start-up reaches the command's handler rather
# than an import of scipy half-way.
_LAZY = {
    "Experiment": "dynid.analysis.data.experiment", "load_experiment": "dynid.analysis.data.experiment",
    "holdout_split": "dynid.analysis.data.split", "simulate": "dynid.analysis.data.synthetic",
    "identify_campaign": "dynid.analysis.decoupled.campaign",
    "simulate_campaign": "dynid.analysis.decoupled.campaign",
    "identify": "dynid.analysis.identify", "ParameterResults": "dynid.analysis.results",
    "validate": "dynid.analysis.statistics.validation", "Robot": "dynid.dynamics.robot",
    "load_robot": "dynid.dynamics.robot_file", "FullReport": "dynid.reports.pipeline",
    "demo": "dynid.reports.pipeline", "report": "dynid.reports.pipeline", "run": "dynid.reports.pipeline",
    "Settings": "dynid.analysis.run", "Identification": "dynid.analysis.run",
    "identify_payload": "dynid.analysis.estimators.payload", "PayloadResult": "dynid.analysis.estimators.payload",
    "identify_drive_gains": "dynid.analysis.estimators.drive_gains",
    "DriveGainResult": "dynid.analysis.estimators.drive_gains",
}
# the public functions that compute: they run with one BLAS thread, as the command line does
# (dynid.threads: on dynid's tall, thin problems a second thread only spins; the user's own
# thread setting in the environment, or DYNID_BLAS_THREADS=0, is kept)
_ONE_BLAS_THREAD = {"simulate", "identify_campaign", "simulate_campaign", "identify", "validate",
                    "demo", "report", "run", "identify_payload", "identify_drive_gains"}
# subpackage-like modules loaded on first use: `dynid.fleet.run(...)` after a plain `import dynid`
_LAZY_MODULES = {"fleet": "dynid.fleet", "progress": "dynid.progress"}


def __getattr__(name: str) -> Any:
    if name in _LAZY_MODULES:
        import importlib
        return importlib.import_module(_LAZY_MODULES[name])
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'dynid' has no attribute {name!r}")
    import importlib
    value = getattr(importlib.import_module(module), name)
    if name in _ONE_BLAS_THREAD:
        value = with_single_blas_thread(value)
    globals()[name] = value
    return value


def __dir__() -> list:
    return sorted(set(globals()) | set(_LAZY) | set(_LAZY_MODULES))


if TYPE_CHECKING:   # static tools (type checkers, the API reference) see the real imports
    from dynid.analysis.data.experiment import Experiment, load_experiment
    from dynid.analysis.data.split import holdout_split
    from dynid.analysis.data.synthetic import simulate
    from dynid.analysis.decoupled.campaign import identify_campaign, simulate_campaign
    from dynid.analysis.diagnosis.selection import DiagnosisResult
    from dynid.analysis.estimators.idim import IDIMResult
    from dynid.analysis.identify import identify
    from dynid.analysis.results import ParameterResults
    from dynid.analysis.run import Identification, Settings
    from dynid.analysis.sampling.posterior import PosteriorResult
    from dynid.analysis.statistics.validation import validate
    from dynid.analysis.statistics.verdict import Verdict
    from dynid.dynamics.excitation import ExcitationResult
    from dynid.dynamics.robot import Robot
    from dynid.dynamics.robot_file import load_robot
    from dynid.reports.pipeline import FullReport, demo, report, run

__all__ = [
    "__version__",
    "load_robot", "load_experiment", "holdout_split", "identify", "validate", "sample", "diagnose",
    "simulate", "excite", "report", "demo", "run", "verdict", "simulate_campaign", "identify_campaign",
    "identify_payload", "identify_drive_gains", "PayloadResult", "DriveGainResult",
    "Robot", "Experiment", "ParameterResults", "FullReport", "Settings", "Identification",
    "DynidError", "InputError", "DataError", "RobotFileError", "OutputError", "IdentificationError", "ConvergenceError",
]


@with_single_blas_thread
def sample(result: IDIMResult, *, which: str = "essential", seed: int = 1, **kwargs: Any) -> PosteriorResult:
    """Posterior of the essential (default) or base parameters of an IDIM result, by emcee.

    Parameters
    ----------
    result : IDIMResult
        What `dynid.identify(..., method="idim")` returned.
    which : str
        `"essential"` or `"base"` (all base parameters).
    seed : int
        The walkers' random seed: the same seed gives the same chains.
    **kwargs
        The options of `dynid.analysis.sampling.sample.sample_linear`, among them
        `n_walkers` (or `walkers`, the command line's name), `max_steps`, `max_seconds` (s),
        `noise` (the likelihood's noise model), `physical` (base parameters only: the
        physically consistent support) and `progress` (called with the fraction done, 0 to 1,
        as `identify`'s; without one the sampling reports through `dynid.progress`).

    Returns
    -------
    PosteriorResult
        Draws, posterior means, standard deviations and credible intervals of the
        parameters, with the chains' convergence diagnostics (ESS, R-hat). Chains that did
        not converge are returned too: `converged` is False and `reason` says why (the
        command line exits 3 then, unless `--allow-unconverged`).
    """
    import inspect

    from dynid.analysis.sampling.sample import sample_idim, sample_linear
    from dynid.errors import did_you_mean
    from dynid.progress import task
    known = {"walkers", "physical", "robot"} | {
        n for n in inspect.signature(sample_linear).parameters
        if not n.startswith("_") and n not in ("W3", "tau", "names", "row_mask", "ls", "truth", "suff_stats")}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"sample() got an unexpected keyword argument {unknown[0]!r}"
                        f"{did_you_mean(unknown[0], known)}; its options: {', '.join(sorted(known))}")
    user = kwargs.get("progress")
    if user is not None:
        if not callable(user):
            raise InputError(f"progress must be a function of the fraction done (0..1), or None; not "
                             f"{type(user).__name__}")
        # the sampler counts steps against the steps its convergence needs, which grow as it learns
        # the chains' integrated time: the fraction never goes back
        done = [0.0]

        def fraction(n, required):
            done[0] = max(done[0], min(1.0, n / required) if required else 0.0)
            user(done[0])

        out = sample_idim(result, which=which, seed=seed, **{**kwargs, "progress": fraction})
        user(1.0)
        return out
    with task("sampling the posterior") as progress:
        return sample_idim(result, which=which, seed=seed, **{**kwargs, "progress": progress})


@with_single_blas_thread
def diagnose(data: str | os.PathLike[str] | Experiment,
             robot: Robot | str | os.PathLike[str], *,
             validation: str | os.PathLike[str] | Experiment | None = None,
             idim_result: IDIMResult | None = None, **kwargs: Any) -> DiagnosisResult:
    """What does the identified model of `robot` lack in `data`? (residual diagnosis).

    `data` and `validation` may be paths or Experiments; the other options are
    those of `dynid.analysis.diagnosis.selection.diagnose`.

    Parameters
    ----------
    data : path or Experiment
        The recording to diagnose (one; a list of several is refused).
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    validation : path or Experiment, optional
        Data the model was not fitted to: the errors before and after the effects are
        reported on it too. Default None: none.
    idim_result : IDIMResult, optional
        The IDIM result of the same data (`dynid.identify(..., method="idim")`) to start
        from; the final model's σ take its covariance (`uncertainty`, bootstrap by
        default). Default None: identified here, with `uncertainty=` (default the run's,
        bootstrap, as `dynid.identify` and `dynid diagnose`).
    **kwargs
        The options of `dynid.analysis.diagnosis.selection.diagnose`, among them
        `settings` (processing overrides), `effects` (the candidate effects' names),
        `max_effects` (3), `alpha` (0.01, the level of the test at each step), `joints`
        (1-based) and `progress` (a callable; without one the diagnosis reports through
        `dynid.progress`).

    Returns
    -------
    DiagnosisResult
        The effects the model lacks, each with its estimated size and the evidence
        for it, and what of the residual is left unexplained.
    """
    from dynid.analysis.diagnosis.selection import diagnose as _diagnose
    from dynid.analysis.further import check_one_recording
    from dynid.analysis.identify import as_experiments, as_robot
    from dynid.analysis.run import check_validation_is_other_data
    robot = as_robot(robot)
    check_one_recording(data)
    experiments = as_experiments(data, robot)
    experiment = experiments[0]
    valid = as_experiments(validation, robot)[0] if validation is not None else None
    if valid is not None:
        check_validation_is_other_data(valid, [experiment])
    if idim_result is not None and getattr(idim_result, "observation", None) is None:
        raise InputError(f"diagnose: idim_result must be the IDIM result of the same data "
                         f"(dynid.identify(..., method='idim')), not {type(idim_result).__name__}")
    if idim_result is None and "uncertainty" not in kwargs:     # the σ dynid.identify reports
        from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY
        kwargs["uncertainty"] = DEFAULT_UNCERTAINTY
    if kwargs.get("progress") is not None:
        return _diagnose(experiment, robot, validation=valid, idim_result=idim_result, **kwargs)
    from dynid.progress import task
    with task("diagnosis") as progress:      # long work is not silent in Python either
        return _diagnose(experiment, robot, validation=valid, idim_result=idim_result,
                         **{**kwargs, "progress": progress})


@with_single_blas_thread
def excite(robot: Robot | str | os.PathLike[str], f0: float, harmonics: int, **kwargs: Any) -> ExcitationResult:
    """Optimal Fourier excitation of `robot` (Bona & Curatella 2005, eq. (20)).

    See `dynid.dynamics.excitation.design_excitation` for the options.

    Parameters
    ----------
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    f0 : float
        Fundamental frequency of the Fourier series, Hz (the period is `1 / f0`).
    harmonics : int
        Number of harmonics N (the bandwidth is `N f0`).
    **kwargs
        The options of `dynid.dynamics.excitation.design_excitation`, among them
        `n_starts` (4 random starts), `criterion` (`"cond"` or `"logdet"`), `margin`
        (0.95: the fraction of every limit used), `rng` (Generator or seed of the starts),
        `max_iter` (150 SLSQP iterations per start), `chi` (standard parameters for the
        torque limits; default the robot's a-priori values, False ignores those limits)
        and `progress` (a callable of the fraction done; without one the design reports
        through `dynid.progress`). The command line's `starts` and `seed` are accepted
        for `n_starts` and `rng`.

    Returns
    -------
    ExcitationResult
        The optimised Fourier trajectory, its condition number and limit margins.
    """
    import inspect

    from dynid.analysis.identify import as_robot
    from dynid.dynamics.excitation import design_excitation
    for cli, name in (("starts", "n_starts"), ("seed", "rng")):     # the command line's names
        if cli in kwargs:
            if name in kwargs:
                raise InputError(f"excite: give {name}= or {cli}=, not both")
            kwargs[name] = kwargs.pop(cli)
    known = set(inspect.signature(design_excitation).parameters) - {"robot", "f0", "n_harmonics"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise InputError(f"excite: unknown option(s) {', '.join(unknown)}; the options are "
                         f"{', '.join(sorted(known | {'starts', 'seed'}))}")
    robot = as_robot(robot)
    if kwargs.get("progress") is not None:
        return design_excitation(robot, f0, harmonics, **kwargs)
    from dynid.progress import task
    with task("excitation design") as progress:      # long work is not silent in Python either
        return design_excitation(robot, f0, harmonics, **{**kwargs, "progress": progress})


@with_single_blas_thread
def verdict(result: Any, held_out: str | os.PathLike[str] | Experiment | None = None, *,
            robot: Robot | None = None) -> Verdict:
    """How far to trust `result`: the verdict the report and the command line show.

    Parameters
    ----------
    result : ParameterResults, Identification or FullReport
        Any identification result (IDIM, DIDIM, Projection Method, ML, PC-WLS), or what
        `dynid.run` or `dynid.report` returned (without `held_out`, their own verdict is
        returned as is).
    held_out : Experiment, path or ValidationResult, optional
        Held-out data: the result is validated on it (`dynid.validate`) and the verdict
        judges the held-out errors too. A ValidationResult is used as it is. IDIM results
        and their PC-WLS fit only: the held-out system is built with IDIM's processing
        (for DIDIM, validate the IDIM result of the same data). Default None: no
        held-out check.
    robot : Robot, optional
        Default None: the result's robot.

    Returns
    -------
    Verdict
        `print()` shows it; `to_dict()` is the "verdict" block of the command's JSON.

    Examples
    --------
    >>> train, held_out = dynid.holdout_split(exp, 3.0)        # doctest: +SKIP
    >>> print(dynid.verdict(dynid.identify(train, robot), held_out))   # doctest: +SKIP
    """
    from dynid.analysis.run import verdict_of
    return verdict_of(result, held_out, robot=robot)
