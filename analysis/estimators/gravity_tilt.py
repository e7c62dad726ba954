"""The direction of gravity (a base tilt) identified with the IDIM base parameters.

A robot file gives the gravity vector `g0` in the base frame; a base mounted a few
mrad off level makes the true vector `g(theta) = R(theta) g0`, `R` the rotation
by the rotation vector `(theta_x, theta_y, 0)` about the base x and y axes (|g|
kept). The IDIM model `Y = W(g) chi + rho` (eq. (9) of Gautier, Janot, Vandanjon
2010) is then a separable nonlinear least-squares problem: linear in the base
parameters `chi`, nonlinear in the two angles. It is solved by Gauss-Newton on the
joint problem in `(chi, theta)`: each step is the per-joint WLS (eq. (16)) of the
system augmented with the two columns `J_i chi = (dW/dtheta_i) chi`, whose last two
coefficients are the step in `theta`; at convergence the covariance of those two
coefficients (eq. (14) of that augmented WLS) is the covariance of the separable
nonlinear LS with the base parameters profiled out (Golub & Pereyra 1973; Seber &
Wild 1989, sec. 14.7).

The regressor is affine in `g` (Newton-Euler with the base acceleration `-g`),
and so is the decimated, dead-zoned observation, so `W(g) = W(0) + sum_k g_k G_k`
with `G_k = W(e_k) - W(0)`: four observations per recording, then every step and
its Jacobian are exact and cheap.

The base parameters are those of the robot with a tilted gravity (what IDIM uses
afterwards with `GravityTiltResult.robot`). With a vertical first axis a tilt
makes the first moments of link 1 (`MX1`, `MY1R`) identifiable, which a level
gravity hides; the test of "no tilt" therefore has `2 + (those parameters)`
degrees of freedom: the likelihood ratio of the WLS, `(S0 - S1) / sigma_rho1^2`
(weighted residual sums with the final weights), against chi-square.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.processing.observation import concatenate, observe
from dynid.analysis.results import ParameterResults, deprecated_alias, p_phrase, parameter_table
from dynid.dynamics.base_parameters import base_parameters
from dynid.errors import IdentificationError, InputError
from dynid.provenance import json_safe

__all__ = ["GravityTiltResult", "gravity_tilt", "tilted_gravity"]

NAMES = ("tilt_x", "tilt_y")
# a generic tilt direction, for the base-parameter set of a tilted gravity
_PROBE = (0.3, 0.2)


def tilted_gravity(g0, theta):
    """`R(theta) g0`: `g0` rotated by the rotation vector `(theta_x, theta_y, 0)` [rad]."""
    return Rotation.from_rotvec([float(theta[0]), float(theta[1]), 0.0]).apply(np.asarray(g0, float))


def _dg_dtheta(g0, theta, h=1e-7):
    """(3, 2) derivative of `tilted_gravity` in `theta` (central differences of a
    3-vector: exact to ~1e-9 relative)."""
    out = np.zeros((3, 2))
    for i in range(2):
        e = np.zeros(2)
        e[i] = h
        out[:, i] = (tilted_gravity(g0, theta + e) - tilted_gravity(g0, theta - e)) / (2 * h)
    return out


@dataclass(eq=False, repr=False)
class GravityTiltResult(ParameterResults):
    """The gravity tilt of the base and the fits of the level and tilted models.

    `chi` [rad] (`params`, names `tilt_x`, `tilt_y`; `theta` is deprecated): rotation
    about the base x and y axes of the robot file's gravity `gravity0`; `cov` (2, 2) its
    covariance (separable nonlinear LS, base parameters profiled: the tilt block of the
    augmented WLS at convergence).
    """

    robot_name: str
    chi: np.ndarray
    cov: np.ndarray
    gravity0: np.ndarray
    gravity: np.ndarray
    rel_error_before: float      # WLS, level gravity, ||Y - W chi|| / ||Y||
    rel_error_after: float       # WLS, tilted gravity
    weighted_rss_before: float   # sum of (rho_j / sigma_j)^2, final sigma_j, level gravity
    weighted_rss_after: float
    lr_statistic: float
    lr_dof: int
    p_value: float
    iterations: int
    converged: bool
    robot: object                # the Robot with the tilted gravity
    wls: object                  # IdentificationResult of the augmented WLS at convergence
    added_parameters: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)   # the processing settings (IDIM's)
    notices: list = field(default_factory=list)
    method = "gravity tilt"
    names = list(NAMES)

    theta = deprecated_alias("params (a pandas Series) or chi (the array)", lambda r: r.chi)
    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r.bse.to_numpy())

    @property
    def angle(self):
        """Angle between the robot file's gravity and the estimated one [rad]."""
        return float(np.hypot(*self.chi))

    def summary(self) -> str:
        t, s = 1e3 * self.chi, 1e3 * self.bse.to_numpy()
        verdict = "rejected" if self.p_value < 0.01 else "not rejected"
        lines = [f"Gravity tilt of robot '{self.robot_name}' (Gauss-Newton, base parameters profiled; "
                 f"{self.iterations} steps{'' if self.converged else ', NOT converged'})",
                 f"  about base x: {t[0]:+.3f} ± {s[0]:.3f} mrad, about base y: {t[1]:+.3f} ± {s[1]:.3f} mrad "
                 f"(|tilt| {1e3 * self.angle:.3f} mrad = {math.degrees(self.angle):.3f} deg)",
                 "  gravity: (" + ", ".join(f"{v:+.4f}" for v in self.gravity0) + ") -> ("
                 + ", ".join(f"{v:+.4f}" for v in self.gravity) + ") m/s^2",
                 f"  WLS relative error {100 * self.rel_error_before:.3f} % -> {100 * self.rel_error_after:.3f} %; "
                 f"weighted residual {self.weighted_rss_before:.1f} -> {self.weighted_rss_after:.1f}",
                 f"  likelihood ratio of 'no tilt': chi2 = {self.lr_statistic:.1f}, {self.lr_dof} dof, "
                 f"{p_phrase(self.p_value)} ({verdict} at 1 %)"]
        lines += ["  " + x for x in parameter_table(self.names, [("value", self.chi, "num"),
                                                                 ("sigma", self.bse.to_numpy(), "num")],
                                                          prismatic=self._prismatic())]
        if self.added_parameters:
            lines.append(f"  base parameters a tilt makes identifiable: {', '.join(self.added_parameters)} "
                         f"(counted in the dof)")
        lines += [f"  note: {m}" for m in self.notices]
        return "\n".join(lines)

    def sentence(self) -> str:
        """The estimate in one sentence (for a report paragraph).

        Returns
        -------
        str
            One sentence with the tilt angles [mrad] and their standard deviations.
        """
        t, s = 1e3 * self.chi, 1e3 * self.bse.to_numpy()
        return (f"Tilt {t[0]:+.2f} \u00b1 {s[0]:.2f} mrad about the base x axis and {t[1]:+.2f} \u00b1 "
                f"{s[1]:.2f} mrad about the base y axis; gravity (" + ", ".join(f"{v:+.4f}" for v in self.gravity)
                + f") m/s\u00b2; WLS relative error {100 * self.rel_error_before:.3f} % level, "
                f"{100 * self.rel_error_after:.3f} % tilted; likelihood ratio of no tilt \u03c7\u00b2 = "
                f"{self.lr_statistic:.1f} on {self.lr_dof} dof ({p_phrase(self.p_value)}).")

    def to_dict(self) -> dict:
        return json_safe({
            "method": self.method, "robot": self.robot_name,
            # the interface's records (as every result's), beside the named fields below
            "parameters": self._records(),
            "model": "g = R(theta) g0, R the rotation vector (theta_x, theta_y, 0) about the base axes",
            "theta_rad": list(self.chi), "std_rad": list(self.bse.to_numpy()), "cov": self.cov,
            "angle_rad": self.angle,
            "gravity_file": list(self.gravity0), "gravity": list(self.gravity),
            "rel_error_before": self.rel_error_before, "rel_error_after": self.rel_error_after,
            "weighted_rss_before": self.weighted_rss_before, "weighted_rss_after": self.weighted_rss_after,
            "likelihood_ratio": {"statistic": self.lr_statistic, "dof": self.lr_dof, "p_value": self.p_value,
                                 "hypothesis": "no tilt (the robot file's gravity)"},
            "added_parameters": self.added_parameters,
            "iterations": self.iterations, "converged": self.converged, "settings": self.settings,
            "covariance": "separable nonlinear LS, base parameters profiled (augmented WLS, eq. (14))",
            "notices": self.notices,
        })


def _observations(experiments, robot, bp, settings):
    """Decimated observations of `W(0)` and `G_k = W(e_k) - W(0)`, k = x, y, z."""
    def obs_at(g, s):
        r = dataclasses.replace(robot, gravity=np.asarray(g, float))
        first = observe(experiments[0], r, bp, s)
        return concatenate([first] + [observe(e, r, bp, first.settings) for e in experiments[1:]])
    o0 = obs_at(np.zeros(3), settings)
    G = [obs_at(e, o0.settings).W - o0.W for e in np.eye(3)]
    return o0, np.stack(G, axis=-1)        # (M, n, b, 3)


def gravity_tilt(experiments, robot, *, settings=None, max_iter=20, tol=1e-3):
    """Estimate the base tilt (see the module docstring) from IDIM recordings.

    `experiments`: a recording or a list (stacked as by IDIM); `settings`: the
    processing overrides of IDIM. Gauss-Newton stops when the step is below `tol`
    standard deviations of each angle. Raises `InputError` when the tilt is
    not identifiable from these data with this robot (e.g. a single vertical axis:
    its torque does not see gravity's direction apart from link 1's first moments).
    """
    experiments = list(experiments) if isinstance(experiments, (list, tuple)) else [experiments]
    g0 = np.asarray(robot.gravity, dtype=float)
    if not np.linalg.norm(g0) > 0:
        raise InputError(f"robot '{robot.name}' has no gravity (gravity = {list(g0)}): there is no "
                         "direction of gravity to estimate")
    bp_level = base_parameters(robot)
    bp = base_parameters(dataclasses.replace(robot, gravity=tilted_gravity(g0, _PROBE)))
    added = [n for n in bp.names if n not in bp_level.names]
    level_cols = [k for k, n in enumerate(bp.names) if n in bp_level.names]
    obs, G = _observations(experiments, robot, bp, settings)
    names = list(bp.names)
    mask = obs.row_mask

    def W_at(theta):
        return obs.W + G @ tilted_gravity(g0, theta)

    def not_identifiable(exc):
        return InputError(
            f"the direction of gravity is not identifiable from these data with robot "
            f"'{robot.name}': the torques a tilt about the base x and y axes would cause are "
            f"not separable from the base parameters ({exc}). Use a robot whose joints carry "
            "gravity torques in several directions, or drop the tilt estimate")

    def fit(theta, joint_sigma=None):
        W = W_at(theta)
        level = not np.any(theta)
        cols = level_cols if level else list(range(len(names)))
        try:
            return ls.wls(W[:, :, cols], obs.tau, [names[k] for k in cols], row_mask=mask,
                          joint_sigma=joint_sigma), W, cols
        except IdentificationError as exc:
            if level:                        # the plain IDIM of these data fails: say it as IDIM does
                raise
            raise not_identifiable(exc) from None

    def augmented(theta, chi_full):
        W = W_at(theta)
        cols = level_cols if not np.any(theta) else list(range(len(names)))
        J = G @ _dg_dtheta(g0, theta)                       # (M, n, b, 2)
        Jchi = np.einsum("mnbk,b->mnk", J[:, :, cols, :], chi_full[cols])
        try:
            return ls.wls(np.concatenate([W[:, :, cols], Jchi], axis=2), obs.tau,
                          [names[k] for k in cols] + list(NAMES), row_mask=mask), cols
        except IdentificationError as exc:
            raise not_identifiable(exc) from None

    theta = np.zeros(2)
    fit0, _, _ = fit(theta)
    chi_full = np.zeros(len(names))
    chi_full[level_cols] = fit0.chi
    converged, steps = False, 0
    while steps < max_iter:
        steps += 1
        aug, cols = augmented(theta, chi_full)
        step = aug.chi[-2:]
        theta = theta + step
        chi_full = np.zeros(len(names))
        chi_full[cols] = aug.chi[:-2]
        if np.all(np.abs(step) <= tol * np.maximum(aug.bse.to_numpy()[-2:], 1e-12)):
            converged = True
            break
    # the covariance at the solution (the last step is below tol sigma: the same point)
    aug, _ = augmented(theta, chi_full)
    fit1, _, _ = fit(theta)
    cov = aug.cov[-2:, -2:]
    sig = fit1.joint_sigma
    f0_fixed, _, _ = fit(np.zeros(2), joint_sigma=sig)
    rss = lambda f: float(f.sigma_rho ** 2 * f.dof)      # eq. (13): the weighted residual sum
    s0, s1 = rss(f0_fixed), rss(fit1)
    dof = 2 + len(added)
    lr = max((s0 - s1) / (s1 / fit1.dof), 0.0)
    g = tilted_gravity(g0, theta)
    notices = []
    if not converged:
        notices.append(f"Gauss-Newton did not converge in {max_iter} steps; the last step was "
                       f"{np.abs(step / aug.bse.to_numpy()[-2:]).max():.2g} sigma")
    return GravityTiltResult(
        robot_name=robot.name, chi=theta, cov=cov, gravity0=g0, gravity=g,
        rel_error_before=float(fit0.rel_error), rel_error_after=float(fit1.rel_error),
        weighted_rss_before=s0, weighted_rss_after=s1, lr_statistic=float(lr), lr_dof=dof,
        p_value=float(stats.chi2.sf(lr, dof)), iterations=steps, converged=converged,
        robot=dataclasses.replace(robot, gravity=g, notices=list(robot.notices) + [
            f"gravity rotated from the robot file's by the estimated base tilt ({1e3 * theta[0]:+.2f}, "
            f"{1e3 * theta[1]:+.2f}) mrad about the base x and y axes"]), wls=aug, added_parameters=added, settings=dict(obs.settings),
        notices=notices)
