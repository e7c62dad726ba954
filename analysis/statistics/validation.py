"""Validation: predict the torques of another recording and judge the residual.

The identified model predicts τ̂ = W χ̂ on data it was not fitted to (a second
recording or a held-out time segment), processed with the *same* filter and
decimation settings.

**All samples first.** The headline numbers (`rel_error`, `rms`,
`joint_rel_error`; JSON `validation.all_samples`) are over ALL held-out
decimated samples: the held-out system is built with the velocity dead zone
OFF (`qd_threshold = 0`), so τ is the measured torque and τ̂ the model's
prediction everywhere, nothing zeroed. Beside them, the error over the
*moving* samples (JSON `validation.moving_samples`): the same system with
the training dead zone applied (rows where a joint is slow zeroed in W and τ
before decimation, rows whose window kept < half its samples dropped), scored
on the rows the estimator would use. Those rows are excluded from the fit
because Coulomb friction's sign is undetermined at rest; the excluded fraction
is reported with it.

Per joint the residual's normality (`normality`, the one computation of
`dynid.analysis.statistics.noise`) on all samples, and on the moving rows.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.data.experiment import load_experiment
from dynid.analysis.data.rates import check_rate_matches
from dynid.analysis.data.record import checked_experiment, recording_of
from dynid.analysis.processing.observation import observe
from dynid.analysis.processing.prediction import prediction_errors
from dynid.analysis.results import Result, percent
from dynid.analysis.statistics.noise import normality as _normality
from dynid.analysis.units import prismatic_joints
from dynid.dynamics.robot import Robot
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DataError, InputError
from dynid.provenance import json_safe

#: why the moving-sample figure leaves rows out
DEAD_ZONE_REASON = "Coulomb friction's sign is undetermined at rest"


def normality(residual):
    """Per-joint noise-PDF checks of a residual (N, n), index `joint` = 1..n.

    The one normality computation of dynid
    (`dynid.analysis.statistics.noise.normality`): n, mean, std, skew,
    `excess_kurtosis`, Jarque-Bera, Shapiro-Wilk on an evenly spaced
    subsample of at most 5000 samples. NaN samples (not fitted / not
    predicted) are left out.
    """
    return _normality(residual)


@dataclass(repr=False)
class ValidationResult(Result):
    """Prediction of a recording by an identified model (all samples first)."""

    source: str
    t: np.ndarray
    tau: np.ndarray                  # (M, n) measured torque, all decimated samples
    tau_hat: np.ndarray              # (M, n) predicted W chi_hat, all samples
    rel_error: float                 # over ALL samples
    rms: np.ndarray                  # per joint, all samples
    joint_rel_error: np.ndarray      # per joint, all samples
    noise: pd.DataFrame              # normality of the all-sample residual
    notices: list = field(default_factory=list)
    mask: np.ndarray = None          # (M, n) moving rows (the estimator's row_mask)
    moving_rel_error: float = float("nan")
    moving_rms: np.ndarray = None
    moving_joint_rel_error: np.ndarray = None
    noise_moving: pd.DataFrame = None
    tau_moving: np.ndarray = None    # dead-zone system: zeroed tau (NaN outside mask)
    tau_hat_moving: np.ndarray = None
    prismatic: tuple = ()            # the robot's prismatic joints (1-based): their RMS is in N

    @property
    def residual(self):
        """τ − τ̂ on all samples (nothing zeroed)."""
        return self.tau - self.tau_hat

    @property
    def residual_moving(self):
        """Residual of the dead-zone system on the moving rows, NaN elsewhere."""
        if self.tau_moving is None:
            return self.residual
        return self.tau_moving - self.tau_hat_moving

    @property
    def moving_fraction(self) -> float:
        """Fraction of the (row, joint) equations that are moving (used)."""
        return 1.0 if self.mask is None else float(np.mean(self.mask))

    @property
    def excluded_fraction(self) -> float:
        return 1.0 - self.moving_fraction

    @property
    def excluded_per_joint(self) -> np.ndarray:
        n = self.tau.shape[1]
        return np.zeros(n) if self.mask is None else 1.0 - np.mean(self.mask, axis=0)

    def _moving_joint_rel_error(self):
        return (self.moving_joint_rel_error if self.moving_joint_rel_error is not None
                else np.full(self.tau.shape[1], np.nan))

    def to_frame(self) -> pd.DataFrame:
        """One row per joint: RMS and its unit (N m, N for a prismatic joint), relative errors
        (all samples, moving ones; fractions), excluded fraction, Jarque-Bera p on all samples.

        Returns
        -------
        pandas.DataFrame
            Index `joint` = 1..n.
        """
        prismatic = set(self.prismatic)
        unit = ["N" if j in prismatic else "N m" for j in range(1, self.tau.shape[1] + 1)]
        return pd.DataFrame({"rms": self.rms, "unit": unit, "rel_error": self.joint_rel_error,
                             "moving_rel_error": self._moving_joint_rel_error(),
                             "excluded_fraction": self.excluded_per_joint,
                             "jarque_bera_p": self.noise["jarque_bera_p"].to_numpy()},
                            index=pd.Index(range(1, self.tau.shape[1] + 1), name="joint"))

    def summary(self):
        """The held-out errors as text: overall, per joint, and on the moving samples alone.

        Returns
        -------
        str
        """
        lines = [f"Validation on {self.source}: {len(self.t)} decimated samples",
                 f"  all samples: relative error ||tau - tau_hat|| / ||tau|| = {percent(self.rel_error)}",
                 f"  moving samples only: {percent(self.moving_rel_error)} ({100 * self.excluded_fraction:.1f} % "
                 f"of the equations excluded: {DEAD_ZONE_REASON})",
                 "  joint   RMS [N m]   rel. error (all)   rel. error (moving)   excluded   JB p (all)"]
        mj = self._moving_joint_rel_error()
        ex = self.excluded_per_joint
        for j in range(self.tau.shape[1]):
            lines.append(f"  {j + 1:5d}   {self.rms[j]:9.4g}   {percent(self.joint_rel_error[j]):>16}   "
                         f"{percent(mj[j]):>19}   {100 * ex[j]:6.1f} %   "
                         f"{self.noise['jarque_bera_p'].iloc[j]:.3g}")
        return "\n".join(lines)

    def to_dict(self):
        """The held-out errors, JSON-safe: the `validation` block of `dynid identify --json`.

        Returns
        -------
        dict
        """
        mj = self.moving_joint_rel_error
        return json_safe({
            "source": self.source, "n_samples": int(len(self.t)),
            "all_samples": {"rel_error": self.rel_error, "rms_per_joint": list(self.rms),
                            "joint_rel_error": list(self.joint_rel_error),
                            "n_samples": int(len(self.t)),
                            "noise": self.noise.reset_index().to_dict(orient="records"),
                            "what": "all held-out decimated samples, tau_hat = W chi_hat, "
                                    "no dead-zone zeroing"},
            "moving_samples": {"rel_error": self.moving_rel_error,
                               "fraction": self.moving_fraction,
                               "excluded_fraction": self.excluded_fraction,
                               "excluded_per_joint": list(self.excluded_per_joint),
                               "rms_per_joint": None if self.moving_rms is None else list(self.moving_rms),
                               "joint_rel_error": None if mj is None else list(mj),
                               "noise": (None if self.noise_moving is None else
                                         self.noise_moving.reset_index().to_dict(orient="records")),
                               "reason": f"rows in the velocity dead zone are excluded: {DEAD_ZONE_REASON}"},
            # compatibility: the top-level numbers are the all-samples ones
            "rel_error": self.rel_error, "rms_per_joint": list(self.rms),
            "joint_rel_error": list(self.joint_rel_error),
            "rel_error_note": "rel_error, rms_per_joint and joint_rel_error are over ALL samples "
                              "(= all_samples)",
            "noise": self.noise.reset_index().to_dict(orient="records"),
            "notices": self.notices})


def _validatable(result):
    """The IDIM-like result `validate` needs (a run's identification unwrapped), or an InputError:
    the held-out system is built with the identification's processing (filters, decimation)."""
    if callable(getattr(result, "data_hash", None)) or isinstance(result, (str, bytes)) or hasattr(result, "__fspath__"):
        raise InputError(f"validate: the first argument is held-out data ({type(result).__name__}), not a result: "
                         "the order is validate(result, held_out)")
    inner = getattr(result, "result", None)
    if getattr(result, "base", None) is None and inner is not None:
        result = inner
    settings = getattr(result, "settings", None)
    if (getattr(result, "base", None) is None or not isinstance(settings, dict) or "fc_position" not in settings
            or not callable(getattr(result, "predict", None))):
        what = getattr(result, "method", None) or type(result).__name__
        raise InputError(f"validate: this {type(result).__name__} ({what}) cannot be validated on held-out data "
                         "here: validation rebuilds the held-out system with IDIM's processing, which only an "
                         "IDIM result (dynid.identify(..., method='idim')) or its PC-WLS fit carries. Validate "
                         "the IDIM result of the same data")
    return result


def validate(idim_result, experiment, robot=None):
    """Predict `experiment` with the essential model of `idim_result`.

    `experiment` may be a path; `robot` defaults to the one identified.
    The held-out system is built twice with the identification's settings:
    with the dead zone off (all samples: the headline numbers) and with it
    on (moving samples, the rows an estimator would use).

    Parameters
    ----------
    idim_result : IDIMResult
        An IDIM result or its PC-WLS fit (`dynid.identify(..., method="idim")`); the
        IDIM result of what `dynid.run` or `dynid.report` returned is taken from it.
    experiment : Experiment or path
        The held-out recording, not the identification data; a path is read with
        `dynid.load_experiment` for `robot`.
    robot : Robot, bundled name or robot file path, optional
        Default None: the robot of `idim_result` (a robot of another name is refused).

    Returns
    -------
    ValidationResult
        Measured and predicted torques on the held-out samples, the relative error
        ||tau - tau_hat|| / ||tau|| and per-joint RMS [N m] on all samples and on the
        moving ones, and the normality tests of the residual.
    """
    idim_result = _validatable(idim_result)
    if robot is not None and not isinstance(robot, Robot):
        robot = load_robot(robot)       # a bundled name or a robot file, as everywhere else
    experiment = recording_of(experiment)
    identified = getattr(idim_result.base, "robot_name", None)
    if robot is not None and identified and getattr(robot, "name", identified) != identified:
        raise InputError(f"validate: the result identifies robot '{identified}', but robot= is "
                         f"'{getattr(robot, 'name', robot)}'; validate with the robot identified")
    if robot is None:
        robot = getattr(idim_result, "robot", None)
        if robot is None:
            raise InputError("validate: this result does not carry its robot; pass robot=")
    if isinstance(experiment, (str, bytes)) or hasattr(experiment, "__fspath__"):
        experiment = load_experiment(experiment, robot)
    if not callable(getattr(experiment, "data_hash", None)):
        raise InputError(f"validate: the held-out data must be an Experiment or a file path, not "
                         f"{type(experiment).__name__}")
    experiment = checked_experiment(experiment, 0, robot)
    if getattr(idim_result, "data_hash", None) and experiment.data_hash() == idim_result.data_hash:
        raise InputError("validate: the held-out recording is the identification data: validating on it says "
                         "nothing about the model; give another recording, or split one with "
                         "dynid.holdout_split")
    settings = dict(idim_result.settings)
    check_rate_matches(experiment, settings.get("fs"), "the held-out recording", "the identification data")
    try:
        full = observe(experiment, robot, idim_result.base, dict(settings, qd_threshold=0.0))
    except InputError as exc:
        if getattr(exc, "min_samples", None) is None:
            raise
        # built with the identification's processing (its nd), the held-out part must be as long as
        # the decimation filter: say so in terms of the held-out data, not of "a longer record"
        fs = float(experiment.fs)
        need = (exc.min_samples + experiment.n_samples - exc.n_samples) / fs   # the filter's edges too
        raise InputError(f"the held-out data ({experiment.n_samples} samples, {experiment.n_samples / fs:.3g} s) "
                         f"are too short for the identification's processing: decimating by nd = {exc.nd} as "
                         f"the identification did needs about {need:.3g} s. Hold out more "
                         "(--holdout SECONDS, holdout= in Python) or give a longer --validation recording") from None
    tau_hat = idim_result.predict(full.W)
    rel, rms, jrel = prediction_errors(full.tau, tau_hat)
    n = full.tau.shape[1]
    thr = settings.get("qd_threshold") or 0.0
    dz = thr == "auto" if isinstance(thr, str) else bool(np.any(np.asarray(thr, dtype=float) > 0))
    notices = list(full.notices)
    if dz:
        mov = observe(experiment, robot, idim_result.base, settings)
        if mov.tau.shape != full.tau.shape or not np.allclose(mov.t, full.t):
            raise DataError("validate: the dead-zone and the all-sample systems have different rows")
        mask = np.broadcast_to(np.asarray(mov.row_mask, dtype=bool), mov.tau.shape).copy()
        that_m = idim_result.predict(mov.W)
        mrel, mrms, mjrel = prediction_errors(mov.tau, that_m, mask)
        tau_m = np.where(mask, mov.tau, np.nan)
        that_m = np.where(mask, that_m, np.nan)
        notices += [n_ for n_ in mov.notices if n_ not in notices]
    else:
        mask = np.ones((full.tau.shape[0], n), dtype=bool)
        mrel, mrms, mjrel = rel, rms, jrel
        tau_m, that_m = full.tau, tau_hat
    out = ValidationResult(source=str(experiment.source), t=full.t, tau=full.tau, tau_hat=tau_hat,
                           rel_error=rel, rms=rms, joint_rel_error=jrel,
                           noise=normality(full.tau - tau_hat), notices=notices, mask=mask,
                           moving_rel_error=mrel, moving_rms=mrms, moving_joint_rel_error=mjrel,
                           tau_moving=tau_m, tau_hat_moving=that_m,
                           prismatic=tuple(sorted(prismatic_joints(robot))))
    out.noise_moving = normality(tau_m - that_m)
    return out
