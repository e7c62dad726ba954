"""URDF export of an identified model.

`export_urdf(result, robot)` chooses one physically consistent
standard-parameter set for the identified base parameters
(`dynid.analysis.estimators.standard_set.choose_standard_set`: closest to the
identified values in the metric of their covariance, then closest to the
a-priori values), writes it as URDF text (`dynid.dynamics.urdf_writer`), reads
that text back with dynid's own URDF reader and checks that it gives the
same base parameters, and reports how the chosen set predicts the
identification data next to the identified model.

Use::

    exp = export_urdf(idim_result, robot)
    exp.write("arm_identified.urdf")          # the URDF (atomic)
    exp.to_dict()                             # choice, checks, per-link consistency (JSON)
    exp.section()                             # a report Section (id "urdf-export")

The set is the global optimum of a semidefinite program (cvxpy + Clarabel,
`dynid[physical]`; the log-Cholesky local search without it). With
`physical=` a PC-WLS result (`dynid.analysis.estimators.physical`), its
standard set is written instead. `mjcf_of` gives the same set as MuJoCo
MJCF (`dynid.dynamics.mjcf_writer`). With `effects=` a PC fit of the rigid body
with linear springs (`dynid.analysis.diagnosis.physical_fit.identify_physical_effects`,
`spring` effects only: `effect_springs`), the MJCF holds the springs too, as
joint `stiffness`; a URDF has no field for them.

For the command line: `dynid identify ... --urdf PATH [--mjcf PATH] [--physical]`
calls `export_urdf(result, robot, physical=...)` and writes the texts with the
other outputs; `dynid identify ... --physical --effects spring:all --mjcf PATH`
calls `export_urdf(result, robot, physical=effects.physical, effects=effects)`.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from dynid.analysis.estimators.standard_set import choose_standard_set
from dynid.dynamics.mjcf_writer import mjcf_text
from dynid.dynamics.urdf import read_urdf
from dynid.dynamics.urdf_writer import read_extra_parameters, urdf_text, urdf_unrepresentable
from dynid.errors import InputError
from dynid.outputs import atomic_write_text
from dynid.provenance import json_safe
from dynid.reports import tables as T
from dynid.reports.html import Section, bullets, join, para

__all__ = ["UrdfExport", "export_urdf", "round_trip", "mjcf_of", "effect_springs"]


@dataclass
class UrdfExport:
    robot_name: str
    text: str                     # the URDF
    standard_set: object          # dynid.analysis.estimators.standard_set.StandardSet
    which: str                    # "essential" or "base"
    round_trip_error: float       # max |beta(URDF read back) - beta(chosen set)|
    prediction: dict              # identification data: rel. error of the model and of the set
    unrepresentable: dict         # name -> value of parameters only in <dynid:parameters>
    notices: list = field(default_factory=list)
    springs: dict = field(default_factory=dict)   # joint (1-based) -> Ks, written in the MJCF only

    @property
    def consistent(self) -> bool:
        return self.standard_set.consistent

    @property
    def reproduces(self) -> bool:
        return self.standard_set.reproduces

    def write(self, path) -> None:
        atomic_write_text(path, self.text)

    def to_dict(self) -> dict:
        d = self.standard_set.to_dict()
        d.update({"which": self.which, "round_trip_error": self.round_trip_error,
                  "prediction": self.prediction, "urdf_extension_parameters": self.unrepresentable,
                  "notices": self.notices + d.get("notices", [])})
        if self.springs:
            d["mjcf_springs"] = {f"Ks{j}": k for j, k in self.springs.items()}
        return json_safe(d)

    def section(self, *, id="urdf-export", title="URDF export: a physically consistent standard set"):
        # the HTML report only: writing a URDF needs neither jinja2 nor matplotlib
        ss = self.standard_set
        p = self.prediction
        verdict = ("reproduces the identified parameters" if ss.reproduces else
                   f"does NOT reproduce the identified parameters exactly (\u03c7\u00b2 = {ss.chi2:.4g})")
        body = join(
            para("Base parameters are combinations of standard ones, so a URDF needs a choice. "
                 "Chosen: the physically consistent standard set (every link's pseudo-inertia "
                 "positive definite: mass > 0, inertia about the centre of mass positive definite, "
                 "triangle inequality; rotor inertias \u2265 0) closest to the identified "
                 f"{self.which} parameters in the metric of their WLS covariance, and among equally "
                 "close sets the one closest to the a-priori values of the robot file."),
            para(f"Result: {'consistent' if ss.consistent else 'NOT consistent'}; {verdict}. "
                 f"Relative torque error on the identification data: identified model "
                 f"{100 * p['rel_error_identified_model']:.2f} %, URDF set "
                 f"{100 * p['rel_error_chosen_set']:.2f} %. Read back by dynid's URDF reader, the "
                 f"file gives the chosen base parameters to {self.round_trip_error:.2g}."),
            para("URDF has no field for " + (", ".join(self.unrepresentable) or "nothing") +
                 "; they are written in the file's <dynid:parameters> element (URDF parsers ignore "
                 "it) and in the JSON.", cls="hint"),
        )
        if self.springs:
            ks = ", ".join(f"Ks{j} = {k:.4g}" for j, k in self.springs.items())
            with_springs = 100 * p.get("rel_error_chosen_set_with_springs", float("nan"))
            body = join(body, para(
                "The MJCF holds the linear springs fitted with this rigid body (--effects) as joint "
                "stiffness, springref 0 (MuJoCo's passive force \u2212stiffness\u00b7q, which the drive "
                f"balances with dynid's Ks\u00b7q): {ks} [N m/rad; N/m on a prismatic joint]. With "
                f"them the set's relative error on the identification data is {with_springs:.2f} %; "
                "the URDF set alone (above) is the rigid body without them, a different model."))
        notes = self.notices + ss.notices
        if notes:
            body = join(body, bullets(notes, cls="notices"))
        links = pd.DataFrame([{"link": l["link"], "mass": l["mass"],
                               "min_principal_moment": (l["principal_moments"] or [np.nan])[0],
                               "pseudo_inertia_min_eig": l["pseudo_inertia_min_eig"],
                               "consistent": l["consistent"]} for l in ss.links]).set_index("link")
        t_links = T.make_table(links, f"tab-{id}-links", "Physical consistency of each link of the URDF set",
                               formats={"consistent": "bool"},
                               labels={"mass": "mass [kg]", "min_principal_moment":
                                       "smallest principal moment [kg m\u00b2]",
                                       "pseudo_inertia_min_eig": "smallest eigenvalue of J"})
        tgt = ss.target.copy()
        t_target = T.make_table(tgt, f"tab-{id}-targets", "Identified and URDF-set base parameters",
                                labels={"identified": "identified", "std": "\u03c3",
                                        "chosen": "URDF set", "deviation_sigma": "deviation [\u03c3]"})
        std = ss.frame()
        t_std = T.make_table(std, f"tab-{id}-standard", "Standard parameters written (a-priori and chosen)")
        return Section(id, title, body, tables=[t_target, t_links, t_std])


def mjcf_of(export, robot) -> str:
    """The MJCF text of the standard set of `export` and its springs (`dynid.dynamics.mjcf_writer`)."""
    with_springs = " with the linear joint springs fitted with it" if export.springs else ""
    return mjcf_text(robot, export.standard_set.chi, springs=export.springs,
                     comment=f"dynid identification of {robot.name}: physically consistent standard set "
                             f"({export.which}){with_springs}; {export.standard_set.message}")


def effect_springs(effects) -> dict:
    """`{joint (1-based): Ks}` of the PC fit `effects` (an
    `EffectsFit`): the springs an MJCF can hold.

    Every effect must be a `spring` (MuJoCo's joint stiffness); any other has no MJCF field
    and is refused, and so is a fit without its physically consistent part (the springs go
    with the PC rigid body, `theta_pc` of eq. (2) there).
    """
    if effects.physical is None:
        raise InputError("the springs of --effects are written with the physically consistent rigid "
                         "body they were fitted with: add --physical")
    other = sorted({(r["effect"], r["joint"]) for r in effects.effects() if r["effect"] != "spring"})
    if other:
        raise InputError("MJCF has no field for the effect(s) " + ", ".join(
            f"{e} on joint {j}" for e, j in other) + " of --effects; only spring (joint stiffness) "
            "can be written: drop the others from --effects, or drop --mjcf")
    return {int(r["joint"]): float(r["pc"]) for r in effects.effects()}


def _masked_errors(tau, tau_hat, mask):
    """Relative error norm and per-joint RMS over the rows the identification used."""
    mask = np.asarray(mask, dtype=bool)
    res = np.where(mask, tau - tau_hat, 0.0)
    rel = float(np.linalg.norm(res) / np.linalg.norm(np.where(mask, tau, 0.0)))
    rms = np.sqrt(np.sum(res ** 2, axis=0) / np.maximum(mask.sum(axis=0), 1))
    return rel, rms


def _identified(result, which):
    """Target base vector, covariance and listed names of an IDIM or DIDIM result."""
    wls = getattr(result, "wls", None) or result.result       # IDIMResult.wls / DIDIMResult.result
    model = result.model
    if which == "essential":
        beta = np.zeros(result.base.n_base)
        beta[result.columns(model.names)] = model.chi
        return beta, wls.cov, list(model.names)
    if which == "base":
        return np.asarray(wls.chi, dtype=float), wls.cov, list(result.base.names)
    raise ValueError(f"which must be 'essential' or 'base', got {which!r}")


def round_trip(text, robot, bp):
    """Base parameters (b,) of a URDF text written by `urdf_text`, read back by dynid."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.urdf"
        path.write_text(text)
        back = read_urdf(path)
        extra = read_extra_parameters(path)
    if back.standard_names[:14 * back.n_joints] != robot.standard_names[:14 * robot.n_joints]:
        raise RuntimeError("the URDF read back has other joints than the robot it was written from")
    values = dict(back.apriori)
    values.update(extra)
    chi = np.array([values.get(n, 0.0) for n in robot.standard_names])
    return bp.from_standard(chi), back


def export_urdf(result, robot, *, which="essential", max_nfev=400, comment=None, physical=None,
                effects=None) -> UrdfExport:
    """A URDF of `robot` holding a physically consistent standard set for `result`.

    `result`: an `dynid.analysis.estimators.idim.IDIMResult` (or a DIDIM result);
    `which`: reproduce the `"essential"` model (default; the others at 0,
    where consistency allows) or all `"base"` parameters of the WLS; the set
    is the SDP's global optimum (`choose_standard_set`).
    `physical`: a `dynid.analysis.estimators.physical.PhysicalResult` of
    `result`: its standard set is written (the PC-WLS fit itself, `which` = "physical").
    `effects`: the `EffectsFit` whose PC fit
    `physical` is (springs only, `effect_springs`): its springs go into the MJCF
    (`mjcf_of`), not the URDF, and the prediction gains the set with them.
    """
    springs = {}
    if effects is not None:
        springs = effect_springs(effects)
        if physical is not effects.physical:
            raise InputError("export_urdf: physical must be the PC fit of effects (effects.physical)")
    if physical is not None:
        which = "physical"
        beta_hat = _identified(result, "essential")[0]     # the identified model, for the comparison
        ss = physical.to_standard_set()
    else:
        beta_hat, cov, listed = _identified(result, which)
        ss = choose_standard_set(robot, result.base, beta_hat, cov, target_names=listed, max_nfev=max_nfev)
    note = comment or (f"dynid identification of {robot.name}: physically consistent standard set "
                       f"for the identified {which} parameters; data hash "
                       f"{getattr(result, 'data_hash', '') or '?'}")
    text = urdf_text(robot, ss.chi, comment=note)
    beta_back, _ = round_trip(text, robot, result.base)
    err = float(np.max(np.abs(beta_back - ss.beta)))
    notices = []
    if robot.couplings:
        notices.append("the robot has coupled joints (" + ", ".join(
            f"motor {c.motor} turns joints {list(c.joints)}" for c in robot.couplings) +
            "): URDF cannot describe the coupled rotor; its parameters are in <dynid:parameters>")
    obs = getattr(result, "observation", None)
    prediction = {}
    if obs is not None:
        rel_i, rms_i = _masked_errors(obs.tau, obs.W @ beta_hat, obs.row_mask)
        rel_c, rms_c = _masked_errors(obs.tau, obs.W @ ss.beta, obs.row_mask)
        prediction = {"rel_error_identified_model": rel_i, "rel_error_chosen_set": rel_c,
                      "rms_identified_model": list(rms_i), "rms_chosen_set": list(rms_c)}
    if springs:
        # the MJCF's model: the PC rigid body plus the springs, on the stacked design's rows
        prediction["rel_error_chosen_set_with_springs"] = effects.rel_error_pc
        notices.append("the MJCF holds the springs of --effects as joint stiffness (springref 0): "
                       + ", ".join(f"Ks{j} = {k:.4g}" for j, k in springs.items())
                       + "; a URDF has no field for them")
    extras = {n: float(v) for n, v in zip(ss.names, ss.chi) if n in set(urdf_unrepresentable(robot))}
    return UrdfExport(robot_name=robot.name, text=text, standard_set=ss, which=which,
                      round_trip_error=err, prediction=prediction, unrepresentable=extras,
                      notices=notices, springs=springs)
