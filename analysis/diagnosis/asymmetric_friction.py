"""Asymmetric friction of the full robot, in Bona & Curatella's coefficients.

Bona & Curatella (2005), eq. (2), give each joint friction coefficients that
depend on the sign of the velocity::

    tau_f = beta_v+ qd + beta_c+          (qd > 0)
    tau_f = beta_v- qd - beta_c-          (qd < 0)

(with positive `beta_c-` the friction opposes the motion; the paper prints
`+beta_c-`). dynid's symmetric model `Fv qd + Fc sign(qd) + Off` plus one
column `|qd|` (coefficient `dFv`) spans exactly the same functions, so the
asymmetric coefficients are linear combinations of identified parameters::

    beta_v+ = Fv + dFv      beta_v- = Fv - dFv
    beta_c+ = Fc + c        beta_c- = Fc - c

where `c` is the torque offset `Off_j` when the model has it (a constant
and `|sign(qd)|` are the same column outside the velocity dead zone: the
offset *is* the Coulomb asymmetry), else an extra column `|sign(qd)|`
(`dFc`). Their standard deviations follow from the covariance of the fit
(`a^T C a` for each combination), so no second identification is needed.

The extra columns are added to the essential model of an IDIM result by
`dynid.analysis.diagnosis.selection.fit_effects` on the same decimated system (same
filters, decimation and dead zone).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.diagnosis.effects import make_candidate
from dynid.analysis.diagnosis.selection import fit_effects
from dynid.analysis.estimators.least_squares import UNCERTAINTY_WORDS
from dynid.analysis.results import Result, notices_block, parameter_table
from dynid.analysis.units import parameter_unit, prismatic_joints
from dynid.provenance import json_safe
from dynid.ranges import check_joints

__all__ = ["AsymmetricFrictionResult", "asymmetric_friction"]

COLUMNS = ("Fv+", "Fv-", "Fc+", "Fc-")
#: two-sided 95 % normal quantile: a coefficient this many σ below zero is negative for the data
Z95 = 1.959963984540054


@dataclass(repr=False)
class AsymmetricFrictionResult(Result):
    """Per-joint asymmetric friction (eq. (2) of Bona & Curatella) with standard deviations."""

    robot_name: str
    joints: list                 # 1-based
    values: np.ndarray           # (n_joints, 4): Fv+, Fv-, Fc+, Fc-
    sigma: np.ndarray            # (n_joints, 4)
    fit: object                  # IdentificationResult of the essential model + |qd| columns
    rel_error_before: float
    notices: list = field(default_factory=list)
    prismatic: tuple = ()        # the robot's prismatic joints (1-based), for the units
    uncertainty: str = "classic"  # the covariance option of sigma (the identification's)

    def to_frame(self) -> pd.DataFrame:
        """One row per coefficient, indexed `Fv+1`, `Fv-1`, `Fc+1` ...: joint, value, std, %σ, unit."""
        rows = []
        for k, j in enumerate(self.joints):
            for c, name in enumerate(COLUMNS):
                v, sd = float(self.values[k, c]), float(self.sigma[k, c])
                rows.append({"name": f"{name}{j}", "joint": j, "value": v, "std": sd,
                             "rel_std_percent": 100.0 * sd / abs(v) if v != 0 else float("inf"),
                             "unit": parameter_unit(f"{name[:2]}{j}", frozenset(self.prismatic))})
        return pd.DataFrame(rows).set_index("name")

    def table2_frame(self) -> pd.DataFrame:
        """The layout of Table 2 of Bona & Curatella: one row per joint, `Fv+`, `sigma Fv+`, ...
        (Fv in N m s/rad, Fc in N m; N s/m and N on a prismatic joint)."""
        rows = {}
        for k, j in enumerate(self.joints):
            row = {}
            for c, name in enumerate(COLUMNS):
                row[name] = self.values[k, c]
                row[f"sigma {name}"] = self.sigma[k, c]
            rows[f"joint {j}"] = row
        return pd.DataFrame.from_dict(rows, orient="index")

    @property
    def rel_error(self) -> float:
        """Relative error of the model with the asymmetric friction (that of `fit`)."""
        return self.fit.rel_error

    def summary(self) -> str:
        lines = [f"Asymmetric friction of {self.robot_name} (Bona & Curatella 2005, eq. (2)); "
                 f"relative error {100 * self.rel_error_before:.3f} % -> {100 * self.fit.rel_error:.3f} %"]
        names = [f"{c}{j}" for j in self.joints for c in COLUMNS]
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = 100.0 * self.sigma.ravel() / np.abs(self.values.ravel())
        lines += parameter_table(names, [("value", self.values.ravel(), lambda x: f"{x:.5g}"),
                                         ("sigma", self.sigma.ravel(), lambda x: f"{x:.2g}"),
                                         ("%sigma", rel, "pct")], prismatic=frozenset(self.prismatic))
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return json_safe({
            "robot": self.robot_name, "model": "Bona & Curatella eq. (2)",
            "joints": [{"joint": j, **{name: {"value": self.values[k, c], "std": self.sigma[k, c],
                                              "unit": parameter_unit(f"{name[:2]}{j}", frozenset(self.prismatic))}
                                       for c, name in enumerate(COLUMNS)}}
                       for k, j in enumerate(self.joints)],
            "uncertainty": self.uncertainty,
            "rel_error_before": self.rel_error_before, "rel_error_after": self.fit.rel_error,
            "notices": self.notices,
        })


def asymmetric_friction(experiment, robot, idim_result, *, joints=None) -> AsymmetricFrictionResult:
    """Asymmetric viscous and Coulomb coefficients of every joint (see the module docstring).

    `experiment`: the recording `idim_result` was identified on (one
    recording); `joints`: 1-based joints (default all).
    """
    n = robot.n_joints
    joints = check_joints(joints, n, robot=robot.name)
    essential = list(idim_result.model.names)
    notices = []
    for c in robot.couplings:
        shared = [j for j in joints if j in c.joints]
        if shared and c.friction:
            notices.append(f"joints {shared} also carry the friction of motor {c.motor} (Fvm{c.motor}, "
                           f"Fcm{c.motor}, acting on the sum of their velocities), which is not in "
                           f"these per-joint coefficients")
    cands = [make_candidate("asymmetric_viscous", j) for j in joints]
    cands += [make_candidate("asymmetric_coulomb", j) for j in joints if f"Off{j}" not in essential]
    # the identification's covariance option (bootstrap by default): the coefficients' sigma as
    # the parameters' (the estimate is the same WLS whatever the option)
    uncertainty = getattr(idim_result, "uncertainty", "classic")
    fit, _ = fit_effects(experiment, robot, idim_result, cands, uncertainty=uncertainty)
    index = {name: i for i, name in enumerate(fit.names)}
    values = np.zeros((len(joints), 4))
    sigma = np.zeros((len(joints), 4))
    for k, j in enumerate(joints):
        def vec(*terms):
            a = np.zeros(len(fit.names))
            for name, coef in terms:
                if name in index:
                    a[index[name]] += coef
            return a
        c_name = f"Off{j}" if f"Off{j}" in index else f"dFc{j}"
        missing = [p for p in (f"Fv{j}", f"Fc{j}", f"dFv{j}", c_name) if p not in index]
        if missing:
            notices.append(f"joint {j}: {', '.join(missing)} not in the model (taken as 0: not "
                           "identifiable from these data or removed as inessential)")
        combos = [vec((f"Fv{j}", 1), (f"dFv{j}", 1)), vec((f"Fv{j}", 1), (f"dFv{j}", -1)),
                  vec((f"Fc{j}", 1), (c_name, 1)), vec((f"Fc{j}", 1), (c_name, -1))]
        for c, a in enumerate(combos):
            values[k, c] = a @ fit.chi
            sigma[k, c] = float(np.sqrt(max(a @ fit.cov @ a, 0.0)))
    prismatic = prismatic_joints(robot)
    negative = [f"{c}{j} = {values[k, i]:.4g} {parameter_unit(f'{c[:2]}{j}', prismatic)} "
                f"({abs(values[k, i]) / sigma[k, i]:.2g} σ)"
                for k, j in enumerate(joints) for i, c in enumerate(COLUMNS)
                if values[k, i] < 0 and sigma[k, i] > 0 and abs(values[k, i]) > Z95 * sigma[k, i]]
    if negative:
        # a friction that pushes the joint along its motion is no friction: on one side the
        # constant torque offset Off_j (or the rest of the model) is read as friction
        notices.append("physically impossible (negative friction, more than 1.96 σ below zero): "
                       + ", ".join(negative) + "; the Coulomb split takes the torque offset Off_j as "
                       "asymmetry where Off_j is in the model, and a dropped Fv_j leaves Fv+ = -Fv- = dFv_j: "
                       "read these coefficients as a shape of the residual, not as friction")
    notices.append(f"σ: {UNCERTAINTY_WORDS.get(uncertainty, uncertainty)} of the essential model with these "
                   "columns, as the identification's")
    return AsymmetricFrictionResult(robot_name=robot.name, joints=joints, values=values, sigma=sigma,
                                    fit=fit, rel_error_before=float(idim_result.model.rel_error),
                                    notices=notices, prismatic=tuple(sorted(prismatic)), uncertainty=uncertainty)
