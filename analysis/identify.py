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

from dynid.analysis.run import (  # noqa: F401 - as_robot, as_experiments, METHODS: public here since 0.1
    METHODS,
    ML_MAX_VALUES,
    Settings,
    as_experiments,
    as_robot,
    identify_step,
    settings_from,
)
from dynid.errors import InputError


def identify(data, robot, method: str = "idim", *, settings=None, max_error_growth: float = 0.02,
             f0: float | None = None, ml_harmonics: int | None = None, reference: str | None = None,
             max_iter: int | None = None, gain_update: str | None = None, gains: str = "assumed", progress=None,
             physical: bool = False, prior: str | None = None, prior_weight: float = 1.0,
             mass_tolerance: float | None = None, bootstrap: int | None = None, physical_set: str = "base",
             **options):
    """Identify the dynamic parameters of `robot` from `data` with `method`.

    Step 3 of the orchestrator (dynid.analysis.run.identify_step); `dynid.run` runs the
    whole of `dynid identify` (hold-out, tilt, effects, verdict ...).

    Parameters
    ----------
    data : path, Experiment, or a list of them
        The identification recording(s). IDIM stacks several recordings; the
        other methods take one.
    robot : Robot, bundled name ('tx40') or path to a .toml / .urdf
    method : 'idim' (default), 'didim', 'projection' or 'ml'
    settings : dict or Settings, optional
        Processing overrides by the observation's names (fc_position, nd,
        f_decimation_cutoff, qd_threshold), or a dynid.analysis.run.Settings; the
        defaults come from the data. The keywords fc, nd, decimation_cutoff,
        qd_threshold and v_s (the command line's names) do the same.
    max_error_growth : float
        Essential-parameter rule: stop removing parameters before the relative
        error grows by more than this fraction (IDIM, DIDIM).
    f0, ml_harmonics : ML only: fundamental frequency (Hz) of the periodic
        excitation and the number of harmonics of the latent trajectory.
    reference : DIDIM only: 'qr' (the logged reference, default when logged) or 'q'.
    max_iter : DIDIM only: the most Gauss-Newton steps.
    gain_update : DIDIM only: the eq. (27) gain update 'every' step (default), 'initial'
        (the first simulation only) or 'none'. The old keyword update_gains (True,
        'initial', False) still works, with a DeprecationWarning.
    gains : DIDIM only. 'assumed': the controller gains of the robot file, as the
        paper does. 'identify': the gains are identified from the logged reference,
        position and torque first (dynid.analysis.estimators.controller_gains.identify_gains),
        DIDIM simulates with them and no gain update (they are the real loop's); the
        result's gains holds them with their %sigma. Without a logged reference the
        gains cannot be identified. Either way the result's notices say which gains
        DIDIM simulated with.
    progress : callable(fraction), optional
    physical : IDIM: return the physically consistent WLS (PC-WLS) instead. DIDIM: PC-DIDIM,
        each Gauss-Newton step's WLS refitted under physical consistency (result.physical
        is the last step's PC fit; prior, prior_weight and mass_tolerance apply to
        every step, bootstrap to the last one).
    prior, prior_weight : physical only: 'apriori' adds prior_weight times the
        squared scaled distance to the robot file's a-priori values, 'geometric' the
        entropic divergence of each link's pseudo-inertia from its a-priori one (Lee, Wensing
        & Park 2020; dynid.analysis.estimators.physical.pc_wls) (default: none,
        the a-priori values only break ties).
    mass_tolerance : physical only: keep each link mass within this fraction of its
        a-priori value.
    bootstrap : physical only: parametric-bootstrap refits for the uncertainty (the old
        keyword n_boot still works, with a DeprecationWarning).
    physical_set : IDIM physical only: 'base' (the WLS of all base parameters, default) or
        'essential' (the essential WLS) is constrained.
    **options
        fc, nd, decimation_cutoff, qd_threshold, v_s (processing, as on the command line).

    Returns
    -------
    ParameterResults
        IDIMResult, DIDIMResult, ProjectionResult, the ML result or (physical) PhysicalResult.

    Raises
    ------
    InputError
        A bad option, or a method that does not apply (DIDIM without a controller ...).
    """
    allowed = {"fc", "nd", "decimation_cutoff", "qd_threshold", "v_s", "update_gains", "n_boot"}
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise TypeError(f"identify() got an unexpected keyword argument {unknown[0]!r}")
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    given = dict(method=method, max_error_growth=max_error_growth, f0=f0, ml_harmonics=ml_harmonics,
                 reference=reference, max_iter=max_iter, gain_update=gain_update, gains=gains,
                 physical=physical, prior=prior, prior_weight=prior_weight, mass_tolerance=mass_tolerance,
                 bootstrap=bootstrap, physical_set=physical_set)
    # None: not given (the Settings default, or a deprecated keyword's value); with a Settings,
    # only the keywords that differ from identify's defaults change it
    given = {k: v for k, v in given.items() if v is not None and not (
        isinstance(settings, Settings) and v == _DEFAULTS.get(k))}
    s = settings_from(settings, **given, **options)
    robot = as_robot(robot)
    return identify_step(as_experiments(data, robot), robot, s, progress=progress)


_DEFAULTS = {"method": "idim", "max_error_growth": 0.02, "gains": "assumed", "physical": False,
             "prior_weight": 1.0, "physical_set": "base"}
