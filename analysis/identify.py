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

import os

from dynid.errors import InputError

METHODS = ("idim", "didim", "projection", "ml")

#: maximum likelihood keeps every sample: beyond this many values (samples x joints) it is refused
ML_MAX_VALUES = 200_000


def as_robot(robot):
    """A `Robot` from a Robot, a bundled name or a robot file path."""
    from dynid.dynamics.robot import Robot
    from dynid.dynamics.robot_file import load_robot
    return robot if isinstance(robot, Robot) else load_robot(robot)


def as_experiments(data, robot) -> list:
    """A list of Experiments from one or several paths or Experiments."""
    from dynid.analysis.data.experiment import Experiment, load_experiment
    items = list(data) if isinstance(data, (list, tuple)) else [data]
    if not items:
        raise InputError("no recording given: pass a data file or an Experiment")
    out = []
    for item in items:
        if isinstance(item, Experiment):
            out.append(item)
        elif isinstance(item, (str, os.PathLike)):
            out.append(load_experiment(item, robot))
        else:
            raise InputError(f"a recording must be a data file path or an Experiment, not {type(item).__name__}")
    return out


def identify(data, robot, method: str = "idim", *, settings=None, max_error_growth: float = 0.02,
             f0: float | None = None, ml_harmonics: int | None = None, reference: str | None = None,
             max_iter: int | None = None, update_gains=True, gains: str = "assumed", progress=None,
             physical: bool = False, prior: str | None = None, prior_weight: float = 1.0,
             mass_tolerance: float | None = None, n_boot: int = 100, physical_set: str = "base"):
    """Identify the dynamic parameters of `robot` from `data` with `method`.

    Parameters
    ----------
    data : path, Experiment, or a list of them
        The identification recording(s). IDIM stacks several recordings; the
        other methods take one.
    robot : Robot, str or path
        A Robot, a bundled name (`"tx40"`) or the path of a `.toml` / `.urdf` file.
    method : str
        `"idim"` (default), `"didim"`, `"projection"` or `"ml"`: IDIM (Gautier et al.
        2010, eqs. (9)-(16)), DIDIM (eqs. (25)-(30)), the Projection Method or maximum
        likelihood (Bona & Curatella 2005).
    settings : dict, optional
        Processing overrides (`fc_position`, `nd`, `decimation_cutoff`,
        `qd_threshold`); the defaults come from the data.
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
    update_gains : bool or str
        DIDIM only: the gain update of eq. (27): every step (True), the first
        step only (`"initial"`) or never (False).
    gains : str
        DIDIM only. `"assumed"`: the controller gains of the robot file, as the
        paper does. `"identify"`: the gains are first identified from the logged
        reference, position and torque, and DIDIM simulates with them (no gain
        update); the result's `gains` holds them with their %σ. Needs a logged
        reference.
    progress : callable, optional
        Called with the fraction done (0 to 1) during long steps.
    physical : bool
        IDIM: return the physically consistent WLS (PC-WLS; every link's
        pseudo-inertia positive semidefinite, Ia, Fv, Fc >= 0; Wensing, Kim &
        Slotine 2017) instead. DIDIM: PC-DIDIM, each Gauss-Newton step's WLS refitted
        under physical consistency (`result.physical` is the last step's fit).
        Needs `pip install "dynid[physical]"`.
    prior : str, optional
        Physical only: `"apriori"` adds `prior_weight` times the squared scaled
        distance to the robot file's a-priori values, `"geometric"` the entropic
        divergence of each link's pseudo-inertia from its a-priori one (Lee, Wensing
        & Park 2020). Default: none, the a-priori values only break ties.
    prior_weight : float
        Physical only: weight of `prior`.
    mass_tolerance : float, optional
        Physical only: keep each link mass within this fraction of its a-priori value.
    n_boot : int
        Physical only: parametric-bootstrap refits for the uncertainty.
    physical_set : str
        IDIM physical only: constrain the WLS of all base parameters (default) or
        the essential WLS.

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
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    robot = as_robot(robot)
    experiments = as_experiments(data, robot)
    if method != "idim" and len(experiments) > 1:
        raise InputError(f"method {method} identifies one recording at a time; "
                         f"{len(experiments)} were given")
    if physical and method not in ("idim", "didim"):
        raise InputError(f"physical=True works with methods idim and didim only, not {method!r}")
    if not physical and (prior is not None or mass_tolerance is not None):
        raise InputError("prior and mass_tolerance are options of the physically consistent fit: "
                         "pass physical=True (--physical)")
    if method == "idim":
        from dynid.analysis.estimators.idim import identify_idim
        if physical:
            from dynid.analysis.estimators.physical import require_cvxpy
            require_cvxpy()          # before the identification, not after it
        ident = experiments if len(experiments) > 1 else experiments[0]
        res = identify_idim(ident, robot, settings=settings, max_error_growth=max_error_growth,
                            progress=progress)
        if not physical:
            return res
        from dynid.analysis.estimators.physical import identify_physical
        return identify_physical(res, robot, prior=prior, prior_weight=prior_weight,
                                 mass_tolerance=mass_tolerance, n_boot=n_boot, which=physical_set)
    exp = experiments[0]
    if method == "didim":
        from dynid.analysis.estimators.didim import DEFAULT_MAX_ITER, identify_didim
        if robot.controller is None:
            raise InputError(f"DIDIM simulates the robot under its controller, but '{robot.name}' "
                             f"({robot.source}) has no [controller] table: add one to the robot file")
        if gains not in ("assumed", "identify"):
            raise InputError(f"gains must be 'assumed' or 'identify', got {gains!r} (--gains)")
        ref = reference or ("qr" if exp.qr is not None else "q")
        identified, controller = None, None
        if gains == "identify":
            from dynid.analysis.estimators.controller_gains import identify_gains
            if exp.qr is None:
                raise InputError(f"{exp.source}: the controller gains cannot be identified without the "
                                 "logged reference (columns qr1..qrn); use the gains of the robot file "
                                 "(--gains assumed) and read the DIDIM result as depending on them")
            identified = identify_gains(exp, robot)
            controller = identified.controller(robot)
            update_gains = False
            # With the real loop's gains, the paper's rough start (Ia = 1 ...) drives the simulated
            # robot into saturation on the first step; IDIM's estimate is a start in the right basin.
            from dynid.analysis.estimators.idim import identify_idim
            from dynid.analysis.processing.observation import SETTINGS_HELP
            # the start gets the settings IDIM shares with DIDIM (not v_s, substeps, transient ...)
            shared = None if settings is None else {k: v for k, v in settings.items() if k in SETTINGS_HELP}
            start = identify_idim(exp, robot, settings=shared, max_error_growth=max_error_growth)
            chi0 = dict(zip(start.base.names, start.wls.chi))
        else:
            chi0 = None
        if physical:
            from dynid.analysis.estimators.physical import require_cvxpy
            require_cvxpy()
        res = identify_didim(exp, robot, settings=settings, reference=ref, controller=controller, chi0=chi0,
                             max_iter=DEFAULT_MAX_ITER if max_iter is None else max_iter,
                             max_error_growth=max_error_growth, update_gains=update_gains,
                             progress=progress, physical=physical, prior=prior, prior_weight=prior_weight,
                             mass_tolerance=mass_tolerance, n_boot=n_boot)
        res.gains = identified
        if identified is not None:
            res.notices.append("controller gains identified from the logged reference, position and "
                               "torque (" + ", ".join(f"{n} {v:.4g}" for n, v in zip(identified.names,
                                                                                  identified.chi)) + ")")
        else:
            what = ("the logged reference" if exp.qr is not None else
                    "the measured position used as the reference (no reference logged)")
            res.notices.append(f"DIDIM simulated the loop with the controller gains assumed in the robot "
                               f"file ({robot.source}) tracking {what}: its parameters depend on those gains"
                               + ("" if exp.qr is None else "; --gains identify estimates them from the data"))
        return res
    if method == "projection":
        from dynid.analysis.estimators.projection import identify_projection
        return identify_projection(exp, robot, settings=settings)
    from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model
    if f0 is None:
        raise InputError("method ml needs f0, the fundamental frequency (Hz) of the periodic excitation "
                         "(--f0 on the command line)")
    if exp.n_samples * robot.n_joints > ML_MAX_VALUES:
        raise InputError(f"{exp.source}: {exp.n_samples} samples x {robot.n_joints} joints; maximum "
                         f"likelihood keeps every sample and is limited to {ML_MAX_VALUES:,} values: "
                         "resample or cut the recording (a TOML experiment file), or use IDIM")
    return maximum_likelihood(exp.t, exp.q, exp.tau, robot_model(robot), f0=f0, n_harmonics=ml_harmonics)
