"""`identify`: one entry point for every estimator of the two papers.

`identify(data, robot, method=...)` loads what it is given (a path, an
`Experiment` or a list of them, a robot
name, file or `Robot`) and runs

* `"idim"`: IDIM with OLS, per-joint WLS and essential parameters (Gautier,
  Janot & Vandanjon 2010, section 2, eqs. (9)-(16));
* `"didim"`: the closed-loop output error of section 3 (eqs. (25)-(30));
* `"projection"`: the Projection Method of Bona & Curatella (2005), eqs. (10)-(12);
* `"ml"`: errors-in-variables maximum likelihood, eqs. (13)-(16) (needs `f0`).

With `physical=True` (IDIM; DIDIM refits every Gauss-Newton step the same way) the WLS of all base parameters is refitted
under physical consistency (every link's pseudo-inertia positive
semidefinite, Ia, Fv, Fc >= 0; Wensing, Kim & Slotine 2017), an SDP:
`identify_physical`; the result is a
`PhysicalResult` whose `idim`
holds the unconstrained identification.

Every method returns a result with the interface of
`ParameterResults`.
"""
from __future__ import annotations

import inspect

from dynid.analysis.run import (  # noqa: F401 - as_robot, as_experiments, METHODS: public here since 0.1
    METHOD_OPTIONS,
    METHODS,
    ML_MAX_VALUES,
    Settings,
    as_experiments,
    as_robot,
    check_physical_options,
    identify_step,
    method_name,
    settings_from,
)
from dynid.errors import InputError, did_you_mean
from dynid.progress import task


def identify(data, robot, method: str | None = None, *, settings=None, max_error_growth: float = 0.02,
             f0: float | None = None, ml_harmonics: int | None = None, reference: str | None = None,
             max_iter: int | None = None, gain_update: str | None = None, gains: str = "assumed", progress=None,
             physical: bool = False, prior: str | None = None, prior_weight: float = 1.0,
             mass_tolerance: float | None = None, bootstrap: int | None = None, physical_set: str = "base",
             **options):
    """Identify the dynamic parameters of `robot` from `data` with `method`.

    Parameters
    ----------
    data : path, Experiment, or a list of them
        The identification recording(s). IDIM stacks several recordings; the
        other methods take one.
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    method : str
        `"idim"` (default: that of `settings`, else IDIM), `"didim"`, `"projection"` or `"ml"`: IDIM (Gautier et al.
        2010, eqs. (9)-(16)), DIDIM (eqs. (25)-(30)), the Projection Method or maximum
        likelihood (Bona & Curatella 2005).
    settings : dict or Settings, optional
        A dict of processing overrides (`fc_position` Hz, `nd`, `f_decimation_cutoff` Hz,
        `qd_threshold` rad/s ...: `dynid.analysis.processing.observation.SETTINGS_HELP`),
        or a `dynid.Settings`; the defaults come from the data.
    max_error_growth : float
        Essential-parameter rule (IDIM, DIDIM): stop removing parameters before the
        relative error grows by more than this fraction.
    f0 : float, optional
        ML only: fundamental frequency (Hz) of the periodic excitation. Required by ML.
    ml_harmonics : int, optional
        ML only: number of harmonics of the latent trajectory.
    reference : str, optional
        DIDIM only: the reference the simulated loop tracks; default `"qr"` (the
        logged reference) when logged, else `"q"`.
    max_iter : int, optional
        DIDIM only: maximum Gauss-Newton iterations.
    gain_update : str, optional
        DIDIM only: the gain update of eq. (27): the first simulation only (`"initial"`,
        the default), `"every"` step (the paper's) or `"none"` (the old keyword `update_gains` still works,
        with a DeprecationWarning).
    gains : str
        DIDIM only. `"assumed"`: the controller gains of the robot file, as the
        paper does. `"identify"`: the gains are first identified from the logged
        reference, position and torque, and DIDIM simulates with them (no gain
        update); the result's `gains` holds them with their %σ. Needs a logged
        reference.
    progress : callable, optional
        Called with the fraction done (0 to 1) during long steps; without one, long work
        reports through `dynid.progress` (a bar on a terminal, else a line on stderr every
        10 s; `dynid.progress.silence()` turns it off).
    physical : bool
        IDIM: return the physically consistent WLS (PC-WLS; every link's
        pseudo-inertia positive semidefinite, Ia, Fv, Fc >= 0; Wensing, Kim &
        Slotine 2017) instead. DIDIM: PC-DIDIM, each Gauss-Newton step's WLS refitted
        under physical consistency (`result.physical` is the last step's fit).
        Needs the `physical` extra (`pip install ".[physical]"` in the source folder).
    prior : str, optional
        Physical only: `"apriori"` adds `prior_weight` times the squared scaled
        distance to the robot file's a-priori values, `"geometric"` the entropic
        divergence of each link's pseudo-inertia from its a-priori one (Lee, Wensing
        & Park 2020). Default: none, the a-priori values only break ties.
    prior_weight : float
        Physical only: weight of `prior`.
    mass_tolerance : float, optional
        Physical only: keep each link mass within this fraction of its a-priori value.
    bootstrap : int, optional
        Physical only: parametric-bootstrap refits for the uncertainty (the old keyword
        `n_boot` still works, with a DeprecationWarning).
    physical_set : str
        IDIM physical only: constrain the WLS of all base parameters (default) or
        the essential WLS.
    **options
        The fields of `dynid.Settings` that identification reads, named as on the command
        line: `fc`, `nd`, `decimation_cutoff`, `qd_threshold`, `v_s`, `uncertainty`
        (`"classic"`, `"hac"` or `"bootstrap"`: the covariance of the estimates),
        `didim_start` (`"idim"` or `"apriori"`: DIDIM's starting estimate) and
        `torque_timing` (DIDIM: `"held"`, the default, when the logged torque is the
        command held over each period; `"centred"` when it is centred on the samples, as
        an integrating sensor and `dynid simulate` log it), and `resample` (True: irregular
        time steps are put on a uniform grid at the median step, as `--resample` does).

    Returns
    -------
    ParameterResults
        An `IDIMResult`, `DIDIMResult`, `ProjectionResult`, `MLResult` or, with
        `physical=True` and IDIM, a `PhysicalResult` (its `idim` holds the
        unconstrained identification). All have the interface of
        `ParameterResults`: `params`, `bse`, `rel_std`, `conf_int()`, `summary()`,
        `to_json()` ...

    Raises
    ------
    InputError
        An unknown method, several recordings for a method that takes one, an
        option the method does not have, DIDIM for a robot without a
        `[controller]`, ML without `f0` or with too many samples.
    DataError
        A recording dynid cannot use (the message names file, column and row).

    Examples
    --------
    >>> import dynid
    >>> r = dynid.identify("examples/staubli_tx40/experiment.toml", "tx40")  # doctest: +SKIP
    >>> r.params["ZZ1R"], r.rel_std["ZZ1R"]                                  # doctest: +SKIP
    """
    allowed = {"fc", "nd", "decimation_cutoff", "qd_threshold", "v_s", "uncertainty", "didim_start",
               "update_gains", "n_boot", "torque_timing", "resample"}
    unknown = sorted(set(options) - allowed)
    if unknown:
        keywords = set(inspect.signature(identify).parameters) - {"data", "robot", "options"}
        hint = did_you_mean(unknown[0], allowed | keywords | {"holdout"})
        if unknown[0] == "holdout" or "holdout" in hint:
            hint = (": identify fits all the data it is given; hold data out with dynid.holdout_split and "
                    "dynid.validate, or use dynid.run(..., holdout=...)")
        raise TypeError(f"identify() got an unexpected keyword argument {unknown[0]!r}{hint}")
    if method is None:          # not given: the Settings' method, else IDIM
        method = settings.method if isinstance(settings, Settings) else (
            settings.get("method", "idim") if isinstance(settings, dict) else "idim")
    given_method, method = method, method_name(method)     # "IDIM", "PM", "ML-EIV": the JSON's spellings
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {given_method!r}")
    chosen = {"f0": f0, "ml_harmonics": ml_harmonics, "max_iter": max_iter, "gain_update": gain_update,
              "reference": reference, "gains": None if gains == "assumed" else gains,
              "didim_start": options.get("didim_start"), "update_gains": options.get("update_gains"),
              "torque_timing": options.get("torque_timing")}
    for name, value in chosen.items():
        if value is not None and method not in _METHOD_OF[name]:
            raise InputError(f"{name}= is an option of {' and '.join(_METHOD_OF[name])}, not of method "
                             f"{method!r}: pass method={_METHOD_OF[name][0]!r}, or leave {name} out")
    given = dict(method=method, max_error_growth=max_error_growth, f0=f0, ml_harmonics=ml_harmonics,
                 reference=reference, max_iter=max_iter, gain_update=gain_update, gains=gains,
                 physical=physical, prior=prior, prior_weight=prior_weight, mass_tolerance=mass_tolerance,
                 bootstrap=bootstrap, physical_set=physical_set)
    # None: not given (the Settings default, or a deprecated keyword's value); with a Settings,
    # only the keywords that differ from identify's defaults change it
    given = {k: v for k, v in given.items() if v is not None and not (
        isinstance(settings, Settings) and v == _DEFAULTS.get(k))}
    s = settings_from(settings, **given, **options)
    check_physical_options(s)
    if progress is not None and not callable(progress):
        raise InputError(f"progress must be a function of the fraction done (0..1), or None; not "
                         f"{type(progress).__name__}")
    robot = as_robot(robot)
    experiments = as_experiments(data, robot, resample=s.resample)
    if progress is not None:
        return identify_step(experiments, robot, s, progress=progress)
    with task(f"identify ({s.method})") as bar:     # shows only for work longer than a few seconds
        return identify_step(experiments, robot, s, progress=bar)


#: the options only some methods read (an option given to another method is an error, not ignored)
_METHOD_OF = {**METHOD_OPTIONS, "update_gains": METHOD_OPTIONS["gain_update"]}

_DEFAULTS = {"max_error_growth": 0.02, "gains": "assumed", "physical": False,
             "prior_weight": 1.0, "physical_set": "base"}
