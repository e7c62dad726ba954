"""The verdict: is the model identified, and how far can it be trusted?

`verdict` gathers, from an IDIM result (and its validation, and a
residual diagnosis if one was run), the few facts a reader needs before any
table:

* **held-out error on all samples** (`ValidationResult.rel_error`: every
  held-out decimated sample, τ̂ = W χ̂, nothing zeroed), per joint; joints
  whose relative error exceeds `joint_error_threshold` (default 20 %) are
  named, and the worst joint always is;
* **essential parameters not identified**: those with %σ = 100 σ/|χ̂| above
  `rel_std_threshold` (default 10 %);
* **residual whiteness and normality**, stated once, on the identification
  residual over the fitted (moving) rows: Ljung-Box (statistic and p at the
  lag of `dynid.analysis.statistics.residuals.analyze_residuals`) and
  Jarque-Bera / Shapiro-Wilk (`dynid.analysis.statistics.noise.normality`).
  A correlated residual is *not* taken as proof of a missing effect: the
  text points to the diagnosis and says what it found;
* **what the diagnosis named but did not add** (if it ran): its findings (a drift,
  with its size and CV gain: a change during one recording cannot predict another)
  and the effects cut by `max_effects` (with their CV gain and the `--max-effects`
  that includes them), one line, information only;
* **physical plausibility**: an identified parameter that must not be
  negative and is. The rule (simple on purpose): a parameter must be ≥ 0 when
  it is, or regroups with non-negative coefficients only, standard
  parameters of the non-negative kinds — masses `M`, diagonal inertias
  `XX`, `YY`, `ZZ`, rotor inertias `Ia`, viscous and Coulomb friction
  `Fv`, `Fc`, `Fvm`, `Fcm`. `ZZ2R = ZZ2 + Ia2 + 0.05 M3 + ...` is
  checked; `XX2R = XX2 - YY2 - ...` or anything with a first moment is not;
* **a-priori values** (`robot.apriori`, mapped to base parameters): an
  essential parameter more than `apriori_k` (default 3) standard
  deviations from its a-priori value is flagged;
* **data quality**: saturation notices, cond(W) (flagged above
  `cond_threshold` = 1000 for the unit-column scaling), the fraction of the
  equations in the velocity dead zone (identification and validation).

* **the other fits of the run** (`--physical`, `--effects`): one line saying that the
  verdict judges the unconstrained rigid-body model and quoting their relative errors,
  information only;

* **convergence** (DIDIM, maximum likelihood): an iterative method that stopped
  before its criterion was met (`converged` False) gives the estimate of its last
  step, not the method's answer; shown first.

Status: `"not identified"` when an iterative method did not converge, or the
held-out error on all samples exceeds `fail_rel_error` (default 30 %) or more
than half the essential parameters are not identified or a parameter is
physically impossible; `"identified
with reservations"` when anything else is flagged; `"identified"`
otherwise.

Each check is one function of `VerdictInputs` returning a `CheckOutcome`
(findings, reasons, failure, the `Verdict` fields it owns); `CHECKS` lists
them in the order their findings are shown, and `verdict` only composes them.
Adding a check is appending one function to `CHECKS`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import pandas as pd

from dynid.analysis.results import Result, p_phrase, percent
from dynid.analysis.statistics.residuals import analyze_residuals, residual_analysis
from dynid.analysis.units import parameter_kind, parameter_unit, prismatic_joints
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.excitation import apriori_parameters
from dynid.dynamics.robot import joint_label, joint_names_of
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["Verdict", "verdict", "CHECKS", "check_diagnosis", "VerdictInputs", "CheckOutcome", "parameter_unit", "must_be_nonnegative", "NONNEGATIVE_KINDS"]

#: standard-parameter kinds that are never negative (see the module docstring)
NONNEGATIVE_KINDS = ("M", "XX", "YY", "ZZ", "Ia", "Fv", "Fc", "Fvm", "Fcm")


def must_be_nonnegative(bp, standard_names, k) -> bool:
    """Whether base parameter `k` regroups non-negative kinds with non-negative coefficients."""
    row = np.asarray(bp.matrix)[k]
    nz = np.flatnonzero(np.abs(row) > 1e-12)
    if nz.size == 0:
        return False
    return all(row[i] > 0 and parameter_kind(standard_names[i]) in NONNEGATIVE_KINDS for i in nz)


@dataclass(repr=False)
class Verdict(Result):
    """What `verdict` concluded; `to_dict()` is the JSON `"verdict"`, `to_csv()` the table of
    the judged parameters (parameter, value, std, rel_std_percent, unit, flagged), `summary()` the findings."""

    status: str                                   # identified / identified with reservations / not identified
    identified: bool
    reasons: list = field(default_factory=list)   # why not plainly "identified"
    validation: dict = None                       # all-sample held-out error, per joint, flagged joints
    rel_std_threshold: float = 10.0
    parameters: list = field(default_factory=list)        # essential: name, value, unit, %σ, flagged
    not_identified: list = field(default_factory=list)    # names with %σ > threshold
    whiteness: dict = None
    normality: dict = None
    implausible: list = field(default_factory=list)       # negative where it must not be
    apriori: dict = None                                  # k, compared, flagged
    data_quality: list = field(default_factory=list)      # {"level", "text"}
    findings: list = field(default_factory=list)          # {"level", "text"}: the list shown first
    extra: dict = field(default_factory=dict)             # JSON blocks of checks added later

    @property
    def flagged_parameters(self):
        return list(self.not_identified)

    @property
    def flagged_joints(self):
        return [] if not self.validation else list(self.validation["flagged_joints"])

    def to_dict(self):
        return json_safe({
            "status": self.status, "identified": self.identified, "reasons": self.reasons,
            "validation": self.validation, "rel_std_threshold_percent": self.rel_std_threshold,
            "not_identified": self.not_identified, "parameters": self.parameters,
            "whiteness": self.whiteness, "normality": self.normality,
            "implausible": self.implausible, "apriori": self.apriori,
            "data_quality": self.data_quality, "findings": self.findings, **self.extra,
        })

    def summary(self):
        lines = [f"Verdict: {self.status.upper()}"]
        lines += [f"  [{f['level']}] {f['text']}" for f in self.findings]
        return "\n".join(lines)

    def to_frame(self):
        """The judged parameters, indexed by `parameter` as every other result's table: value,
        std, rel_std_percent, unit, flagged."""
        cols = ["name", "value", "std", "rel_std_percent", "unit", "flagged"]
        return (pd.DataFrame(self.parameters, columns=cols).set_index("name")
                .rename_axis("parameter"))

    def __repr__(self):
        flagged = len(self.not_identified)
        return (f"<Verdict {self.status!r}: {len(self.findings)} finding(s), {len(self.parameters)} "
                f"parameters judged, {flagged} above {self.rel_std_threshold:g} % sigma>")


def _pct(x):
    return f"{100 * float(x):.1f} %"


def _joint_names(robot, n):
    """`j1` .. `jn`, each with the robot file's name of the joint beside it when it has another:
    a URDF's names may count from 0 (`lwr_5_joint` is joint 6), the tables count from 1."""
    return [joint_label(k, name) for k, name in enumerate(joint_names_of(robot, n))]


def identification_residual(idim_result):
    """Residual of the essential model on the identification rows, NaN outside the fitted rows."""
    obs = idim_result.observation
    e = obs.tau - idim_result.predict(obs.W)
    mask = np.broadcast_to(np.asarray(obs.row_mask, dtype=bool), e.shape)
    return e, mask


def _estimate(result):
    """The estimate the verdict judges: an IDIM or DIDIM result's model, otherwise the result."""
    m = getattr(result, "model", None)
    return m if m is not None and hasattr(m, "rel_std") else result


def _fitted_residual(result):
    """`residual_analysis` of the residual on the rows the method fitted, or None.

    IDIM: τ − W χ̂ on the decimated identification rows. DIDIM: the measured
    minus the simulated-model torque on its decimated rows, with the simulated
    motion for the binned means. The Projection Method and maximum likelihood
    have no such residual of the torque equation alone (their noise model is
    another), so their whiteness is not judged here.
    """
    if getattr(result, "observation", None) is not None:
        e, _ = identification_residual(result)
        return residual_analysis(result.observation, e)
    if getattr(result, "tau_est_dec", None) is not None:
        t_dec = np.asarray(result.t_dec, dtype=float)
        t = np.asarray(result.t, dtype=float)
        q_sim = np.asarray(result.q_sim, dtype=float)
        qd_sim = np.gradient(q_sim, t, axis=0)
        q = np.column_stack([np.interp(t_dec, t, q_sim[:, j]) for j in range(q_sim.shape[1])])
        qd = np.column_stack([np.interp(t_dec, t, qd_sim[:, j]) for j in range(q_sim.shape[1])])
        e = np.asarray(result.tau_dec, dtype=float) - np.asarray(result.tau_est_dec, dtype=float)
        return analyze_residuals(e, t=t_dec, q=q, qd=qd, mask=result.row_mask)
    return None


def _base(result, robot):
    """The base parameters the estimate is expressed in (None if they cannot be told)."""
    bp = getattr(result, "base", None)
    if bp is None and robot is not None:
        bp = base_parameters(robot)
    names = list(getattr(_estimate(result), "names", []) or [])
    if bp is None or not set(names) <= set(bp.names):
        return None
    return bp


def _least_squares(result):
    """The least-squares fit whose cond(W) and dead zone describe the data, or None."""
    for attr in ("wls", "result", "stage2", "ls"):
        r = getattr(result, attr, None)
        if r is not None and hasattr(r, "cond"):
            return r
    return result if hasattr(result, "cond") else None


def _fitted_mask(result):
    obs = getattr(result, "observation", None)
    if obs is not None:
        return np.broadcast_to(np.asarray(obs.row_mask, dtype=bool), obs.tau.shape)
    mask = getattr(result, "row_mask", None)
    tau = getattr(result, "tau_dec", None)
    if mask is not None and tau is not None:
        return np.broadcast_to(np.asarray(mask, dtype=bool), np.shape(tau))
    return None


@dataclass
class VerdictInputs:
    """What every check reads: the result judged, its context and the thresholds.

    Built once by `verdict`; a check never modifies it. `params` is the
    table of the judged parameters (name, value, std, unit, %σ, flagged),
    shared by the checks that compare parameter values.
    """

    result: object
    validation: object
    robot: object
    diagnosis: object
    residuals: object
    estimate: object
    names: list              # joint names, one per joint
    n: int                   # number of joints
    kind: str                # "essential" or "base"
    params: list
    rel_std_threshold: float
    joint_error_threshold: float
    warn_rel_error: float
    fail_rel_error: float
    apriori_k: float
    alpha: float
    cond_threshold: float
    physical: object = None  # the physically consistent fit of the same run (--physical), quoted only
    effects: object = None   # the fit with effects beside the rigid body (--effects), quoted only

    @cached_property
    def base(self):
        return _base(self.result, self.robot)


@dataclass
class CheckOutcome:
    """What one check adds to the verdict.

    `findings` ({"level", "key", "text"}) are shown in the order of `CHECKS`;
    `reasons` say why the model is not plainly "identified"; `fail` makes it
    "not identified"; `fields` sets the `Verdict` attributes the check owns
    (a name that is not a `Verdict` attribute goes to `Verdict.extra`, hence
    to the JSON under that name).
    """

    findings: list = field(default_factory=list)
    reasons: list = field(default_factory=list)
    fail: bool = False
    fields: dict = field(default_factory=dict)


def _parameter_table(m, rel_std_threshold, prismatic=frozenset()):
    """One row per judged parameter: name, value, std, unit, %σ and whether %σ is above the
    threshold (`prismatic`: the robot's prismatic joints, for the units)."""
    params = []
    for name, v, s, r in zip(m.names, m.chi, m.bse.to_numpy(), m.rel_std.to_numpy()):
        bad = not (float(r) <= rel_std_threshold)
        params.append({"name": name, "value": float(v), "std": float(s), "unit": parameter_unit(name, prismatic),
                       "rel_std_percent": float(r), "flagged": bool(bad)})
    return params


def check_convergence(x: VerdictInputs) -> CheckOutcome:
    """An iterative method (DIDIM, ML) that did not converge: its estimate is its last step's."""
    if getattr(x.result, "converged", True) is not False:
        return CheckOutcome()
    method = str(getattr(x.result, "method", "") or type(x.result).__name__)
    why = str(getattr(x.result, "stop_reason", "") or "").strip().rstrip(".")
    if not why:      # a result without stop_reason: the optimiser's message among its notices
        why = next((str(n).split(": ", 1)[-1].rstrip(".") for n in getattr(x.result, "notices", []) or []
                    if "without convergence" in str(n)), "")
    advice = ("Raise the step limit (--max-iter), start from IDIM's estimate (dynid identify --method didim "
              "--gains identify, which identifies the loop's gains too; with the robot file's gains DIDIM "
              "starts from the paper's eq. (31)), or use IDIM's model."
              if method.upper().startswith("DIDIM") else
              "Check the excitation's fundamental frequency and harmonics (--f0, --ml-harmonics), average "
              "more periods, or use IDIM's model." if method.upper().startswith("ML") else
              "Use IDIM's model.")
    text = (f"{method} did NOT converge" + (f" ({why})" if why else "") + ": its estimate is that of its "
            f"last step, not the method's answer, and every figure below is that step's. {advice}")
    return CheckOutcome(findings=[{"level": "bad", "key": "convergence", "text": text}],
                        reasons=[f"{method} did not converge"], fail=True)


def check_validation(x: VerdictInputs) -> CheckOutcome:
    """Held-out error on all samples, per joint; the worst joint and those above the threshold."""
    validation, names, n = x.validation, x.names, x.n
    if validation is None:
        return _no_validation(x)
    jrel = np.asarray(validation.joint_rel_error, dtype=float)
    flagged_j = [names[j] for j in range(n) if jrel[j] > x.joint_error_threshold]
    worst = int(np.nanargmax(jrel))
    vinfo = {"rel_error": float(validation.rel_error),
             "joint_rel_error": [float(v) for v in jrel],
             "joints": names, "flagged_joints": flagged_j, "worst_joint": names[worst],
             "joint_error_threshold": x.joint_error_threshold,
             "moving_rel_error": float(getattr(validation, "moving_rel_error", np.nan)),
             "excluded_fraction": float(getattr(validation, "excluded_fraction", 0.0)),
             "n_samples": int(len(validation.t))}
    rel = validation.rel_error
    level = ("bad" if rel > x.fail_rel_error else
             "ok" if rel <= x.warn_rel_error and not flagged_j else "warn")
    per = ", ".join(f"{nm} {_pct(v)}" for nm, v in zip(names, jrel))
    text = (f"Held-out error on all {len(validation.t)} samples: {_pct(rel)} "
            f"(per joint {per}); worst {names[worst]}")
    if flagged_j:
        text += f"; above {_pct(x.joint_error_threshold)}: {', '.join(flagged_j)}"
    text += (f". On the moving samples only: {_pct(vinfo['moving_rel_error'])} "
             f"({_pct(vinfo['excluded_fraction'])} excluded: Coulomb friction's sign is "
             f"undetermined at rest).")
    out = CheckOutcome(findings=[{"level": level, "text": text, "key": "validation"}],
                       fields={"validation": vinfo})
    if rel > x.fail_rel_error:
        out.fail = True
        out.reasons.append(f"held-out error {_pct(rel)} > {_pct(x.fail_rel_error)}")
    elif rel > x.warn_rel_error:
        out.reasons.append(f"held-out error {_pct(rel)} > {_pct(x.warn_rel_error)}")
    if flagged_j:
        out.reasons.append(f"joints with held-out error > {_pct(x.joint_error_threshold)}: "
                           + ", ".join(flagged_j))
    return out


def _no_validation(x: VerdictInputs) -> CheckOutcome:
    """No held-out data: say so, with the option that supplies it."""
    fitted = x.residuals is not None and np.isfinite(float(getattr(x.estimate, "rel_error", np.nan)))
    text = ("No held-out data: the model was not tested on data it was not "
            + (f"fitted to (identification error {_pct(x.estimate.rel_error)} on the fitted rows); "
               if fitted else "fitted to; ")
            + ("hold data out: --holdout or --validation of dynid identify, diagnose or report "
               "(Python: dynid.verdict(result, held_out))." if hasattr(x.result, "observation") else
               "the held-out check is IDIM's: validate the IDIM result of the same data (dynid identify "
               "--holdout; Python: dynid.verdict(idim_result, held_out))."))
    return CheckOutcome(findings=[{"level": "warn", "key": "validation", "text": text}],
                        reasons=["no validation data"])


def check_parameters(x: VerdictInputs) -> CheckOutcome:
    """The judged parameters and their %σ; more than half above the threshold fails."""
    m, thr = x.estimate, x.rel_std_threshold
    flagged = [p["name"] for p in x.params if p["flagged"]]
    out = CheckOutcome(fields={"parameters": x.params, "not_identified": flagged})
    if flagged:
        out.findings.append({"level": "warn", "key": "parameters",
                             "text": f"{len(flagged)} of {len(m.names)} {x.kind} parameters not identified "
                                     f"(%\u03c3 > {thr:g} %): {', '.join(flagged)}."})
        out.reasons.append(f"%\u03c3 > {thr:g} %: {', '.join(flagged)}")
        out.fail = len(flagged) > len(m.names) / 2
        if out.fail and x.kind == "base" and str(getattr(x.result, "method", "")).startswith("PC-"):
            # the same data can be "with reservations" under IDIM, which judges its essential set
            out.findings[-1]["text"] += (" This physically consistent fit is of every base parameter, the "
                                         "poorly excited ones too; IDIM's verdict judges its essential "
                                         "parameters (--physical-set essential constrains those).")
    else:
        out.findings.append({"level": "ok", "key": "parameters",
                             "text": f"All {len(m.names)} {x.kind} parameters have %\u03c3 \u2264 {thr:g} %."})
    return out


def _sigma_option(x: VerdictInputs) -> str:
    """The covariance behind the judged %σ: classic (eq. (14)), hac or bootstrap."""
    for obj in (x.estimate, x.result):
        option = getattr(obj, "uncertainty", None)
        if isinstance(option, str):
            return option
    settings = getattr(x.result, "settings", None)
    option = settings.get("uncertainty") if isinstance(settings, dict) else None
    return option if isinstance(option, str) else "classic"


def _whiteness(x: VerdictInputs) -> dict:
    """Ljung-Box on the fitted residual, with what the diagnosis found (if it ran)."""
    names, n, alpha, diagnosis = x.names, x.n, x.alpha, x.diagnosis
    lb = x.residuals.ljung_box
    lb_p = [float(v) for v in lb["p_value"]]
    corr = [names[j] for j in range(n) if np.isfinite(lb_p[j]) and lb_p[j] < alpha]
    white = {"test": "Ljung-Box", "lag": int(lb["lag"].iloc[0]),
             "statistic": [float(v) for v in lb["statistic"]], "p_value": lb_p,
             "correlated_joints": corr, "alpha": alpha,
             "residual": "identification, fitted (moving) rows"}
    option = _sigma_option(x)
    diag_text = ""
    if diagnosis is not None:
        sel = [f"{s.name} (joint {s.joint})" if getattr(s, "joint", None) else str(s.name)
               for s in diagnosis.selected]
        white["diagnosis_selected"] = sel
        flagged = sorted({int(u.joint) for u in (getattr(diagnosis, "unexplained", None) or [])})
        white["diagnosis_flagged_joints"] = flagged
        said = (f" its structure tests flag joint{'s' if len(flagged) > 1 else ''} "
                f"{', '.join(map(str, flagged))}: torque the model lacks that no candidate describes "
                "(the diagnosis names what it depends on)." if flagged else "")
        if sel:
            diag_text = f" The diagnosis added {', '.join(sel)}" + (";" + said if said else ".")
        elif said:
            diag_text = " The diagnosis added no effect from its candidates, but" + said
        else:
            diag_text = (" The diagnosis found no missing effect among the candidates it tested: the "
                         "correlation comes from the filtering and decimation, or from an effect it "
                         "does not model.")
    if corr:
        white["text"] = ("The identification residual (fitted rows) is correlated in time (Ljung-Box at lag "
                         f"{white['lag']}: " + ", ".join(f"{names[j]} {p_phrase(lb_p[j])}"
                                                         for j in range(n) if names[j] in corr)
                         + ("): %\u03c3 counts the samples as independent and is optimistic; "
                            if option == "classic" else
                            f"): %\u03c3 ({option} covariance) allows for that correlation, which the "
                            "papers' classic %\u03c3 ignores; ")
                         + ("see the diagnosis." + diag_text if diagnosis is not None else
                            "whether an effect is missing is what the diagnosis tests (dynid diagnose, "
                            "or the full report)."))
    else:
        white["text"] = (f"The identification residual (fitted rows) is white (Ljung-Box at lag {white['lag']}, "
                         f"every p \u2265 {alpha:g})."
                         + diag_text)
    return white


def _normality(x: VerdictInputs) -> dict:
    """Jarque-Bera and Shapiro-Wilk on the fitted residual, per joint."""
    names, n, alpha = x.names, x.n, x.alpha
    nm_tab = x.residuals.normality
    jb = [float(v) for v in nm_tab["jarque_bera_p"]]
    sw = [float(v) for v in nm_tab["shapiro_p"]]
    nongauss = [names[j] for j in range(n) if np.isfinite(jb[j]) and jb[j] < alpha]
    normal = {"jarque_bera_p": jb, "shapiro_p": sw,
              "excess_kurtosis": [float(v) for v in nm_tab["excess_kurtosis"]],
              "non_gaussian_joints": nongauss, "alpha": alpha,
              "residual": "identification, fitted (moving) rows"}
    normal["text"] = ("Identification residual (fitted rows) not Gaussian (Jarque-Bera p < " + f"{alpha:g}) on "
                      + ", ".join(f"{names[j]} ({p_phrase(jb[j])})" for j in range(n)
                                  if names[j] in nongauss) + "."
                      if nongauss else "Identification residual (fitted rows) Gaussian on every joint "
                                       f"(Jarque-Bera p \u2265 {alpha:g})"
                      + ("; the held-out samples are tested apart (Validation)." if x.validation is not None
                         else "."))
    return normal


def check_residual(x: VerdictInputs) -> CheckOutcome:
    """Whiteness and normality of the identification residual on the fitted rows (not a verdict of its own)."""
    if x.residuals is None:
        why = (f"{getattr(x.result, 'method', 'this method')}: no residual of the torque equation alone "
               "on fitted rows (its noise model is another); whiteness and normality are not judged here.")
        return CheckOutcome(
            findings=[{"level": "info", "key": "whiteness", "text": why}],
            fields={"whiteness": {"test": None, "text": why, "residual": None, "correlated_joints": []},
                    "normality": {"test": None, "text": why, "residual": None, "non_gaussian_joints": []}})
    white, normal = _whiteness(x), _normality(x)
    return CheckOutcome(
        findings=[{"level": "warn" if white["correlated_joints"] else "ok", "key": "whiteness",
                   "text": white["text"]},
                  {"level": "warn" if normal["non_gaussian_joints"] else "ok", "key": "normality",
                   "text": normal["text"]}],
        fields={"whiteness": white, "normality": normal})


def check_diagnosis(x: VerdictInputs) -> CheckOutcome:
    """What the diagnosis found but did not put in the model (issue 27 items 2 and 3), one line.

    Findings: time-varying effects (drift) named with their size and evidence, never added
    (a change during one recording cannot predict another); cut effects: candidates that
    pass the rule but were not tried because `max_effects` effects were added already, with
    their CV gain and the `--max-effects` that includes them. Information only: the status
    does not change. No line when the diagnosis did not run or has neither.
    """
    d = x.diagnosis
    findings = list(getattr(d, "findings", None) or [])
    cut = list(getattr(d, "cut", None) or [])
    if d is None or not (findings or cut):
        return CheckOutcome()
    parts = []
    if findings:
        parts.append("The diagnosis named, but did not add (a change during this recording cannot predict "
                     "another one): " + "; ".join(f"{f.label}: {f.size}, CV gain {100 * f.cv_gain:.1f} %"
                                                  for f in findings) + ".")
    k = None
    if cut:
        k = int((getattr(d, "settings", None) or {}).get("max_effects", 0))
        parts.append(f"Cut by max_effects = {k} (they pass the rule, not tried): "
                     + "; ".join(f"{r.label}, CV gain {100 * r.cv_gain:.1f} %" for r in cut)
                     + f"; include them with --max-effects {k + len(cut)}.")
    fields = {"diagnosis_findings": [f.to_dict() for f in findings],
              "diagnosis_cut": [{"label": r.label, "name": r.name, "joint": r.joint,
                                 "cv_gain": float(r.cv_gain), "statistic": float(r.statistic),
                                 "p_value": float(r.p_value)} for r in cut]}
    if cut:
        fields["diagnosis_include_cut_with"] = f"--max-effects {k + len(cut)}"
    return CheckOutcome(findings=[{"level": "info", "key": "diagnosis", "text": " ".join(parts)}],
                        fields=fields)


#: the normal 97.5 % quantile
_Z95 = 1.959963984540054


def check_plausibility(x: VerdictInputs) -> CheckOutcome:
    """A parameter that must not be negative and is (see `must_be_nonnegative`) fails."""
    bp = x.base
    std_names = list(getattr(x.robot, "standard_names", []) or []) if x.robot is not None else []
    implausible = []
    if std_names and bp is not None:
        index = {nm: k for k, nm in enumerate(bp.names)}
        for p in x.params:
            k = index.get(p["name"])
            if k is not None and p["value"] < 0 and must_be_nonnegative(bp, std_names, k):
                implausible.append({"name": p["name"], "value": p["value"], "unit": p["unit"],
                                    "n_sigma": abs(p["value"]) / p["std"] if p["std"] > 0 else np.inf,
                                    "relation": bp.relations[k]})
    # a negative value within its 95 % interval of zero is zero as far as the data say, not impossible
    noise = [q for q in implausible if q["n_sigma"] <= _Z95]
    implausible = [q for q in implausible if q["n_sigma"] > _Z95]
    out = CheckOutcome(fields={"implausible": implausible, "negative_within_uncertainty": noise})

    def listed(qs):
        return ", ".join(f"{q['name']} = {q['value']:.4g} {q['unit']} ({q['n_sigma']:.2g} σ)" for q in qs)
    if implausible:
        out.fail = True
        out.findings.append({"level": "bad", "key": "plausibility",
                             "text": "Physically impossible (negative mass, inertia or friction, more than 1.96 σ "
                                     "below zero): " + listed(implausible) + "."})
        out.reasons.append("negative " + ", ".join(q["name"] for q in implausible))
    if noise:
        out.findings.append({"level": "info", "key": "plausibility",
                             "text": "Negative but within 1.96 σ of zero (zero as far as the data say, not "
                                     "identified): " + listed(noise) + "."})
    if not implausible and not noise:
        out.findings.append({"level": "ok", "key": "plausibility",
                             "text": "No identified mass, diagonal or rotor inertia, or friction "
                                     "coefficient is negative."})
    return out


def _apriori_comparison(x: VerdictInputs, bp) -> dict:
    """Each judged parameter with an a-priori value: its distance in σ, flagged beyond `apriori_k`."""
    k_sigma = x.apriori_k
    try:
        _, beta, missing = apriori_parameters(x.robot, bp)
    except Exception as exc:          # a-priori values that do not map: say so, no verdict
        return {"k": k_sigma, "compared": [], "flagged": [], "error": str(exc)}
    index = {nm: k for k, nm in enumerate(bp.names)}
    compared, far = [], []
    for p in x.params:
        if p["name"] in missing or p["name"] not in index:
            continue
        a = float(beta[index[p["name"]]])
        ns = abs(p["value"] - a) / p["std"] if p["std"] > 0 else np.inf
        compared.append({"name": p["name"], "value": p["value"], "apriori": a,
                         "n_sigma": ns, "unit": p["unit"], "flagged": bool(ns > k_sigma)})
        if ns > k_sigma:
            far.append(p["name"])
    return {"k": k_sigma, "compared": compared, "flagged": far,
            "source": str((getattr(x.robot, "provenance", {}) or {}).get("apriori", ""))}


def check_apriori(x: VerdictInputs) -> CheckOutcome:
    """Parameters far from the robot file's a-priori values (information, never a failure)."""
    bp = x.base
    if x.robot is None or bp is None or not getattr(x.robot, "apriori", None):
        return CheckOutcome(fields={"apriori": None})
    ap = _apriori_comparison(x, bp)
    out = CheckOutcome(fields={"apriori": ap})
    if ap.get("compared"):
        far, k, n_cmp = ap["flagged"], x.apriori_k, len(ap["compared"])
        out.findings.append({"level": "info" if far else "ok", "key": "apriori",
                             "text": (f"{len(far)} of {n_cmp} {x.kind} parameters with an "
                                      f"a-priori value are more than {k:g} \u03c3 from it: "
                                      + ", ".join(far) + "." if far else
                                      f"All {n_cmp} {x.kind} parameters with an a-priori "
                                      f"value are within {k:g} \u03c3 of it.")})
    return out


def _conditioning(ls_fit, cond_threshold):
    cs = float(getattr(ls_fit, "cond_scaled", np.nan))
    c = float(ls_fit.cond)
    return {"level": "warn" if cs > cond_threshold else "ok",
            "text": f"cond(W) = {c:.3g} ({cs:.3g} with unit columns"
                    + (f", above {cond_threshold:g}: poorly exciting data" if cs > cond_threshold else "")
                    + ")" + (f", W of all {len(ls_fit.names)} parameters of the {_fit_label(ls_fit)}"
                             if getattr(ls_fit, "names", None) else "") + "."}


def _fit_label(ls_fit):
    """What the judged cond(W) belongs to, for the reader of a summary that shows another model's."""
    method = str(getattr(ls_fit, "method", "") or "fit")
    return f"{method} fit" if "fit" not in method.lower() else method


def _dead_zone(mask, validation):
    dz = 1.0 - float(mask.mean()) if mask is not None else 0.0
    vz = float(validation.excluded_fraction) if validation is not None else 0.0
    parts = []
    if mask is not None:
        parts.append(f"{_pct(dz)} of the decimated identification equations are left out "
                     "(velocity dead zone, not fitted)")
    if validation is not None:
        parts.append(f"{_pct(vz)} of the held-out ones" if mask is not None else
                     f"{_pct(vz)} of the held-out equations are in the velocity dead zone")
    return {"level": "warn" if max(dz, vz) > 0.3 else "ok",
            "text": "; ".join(parts) + (": the moving-sample error leaves out much of the motion"
                                        if max(dz, vz) > 0.3 else "") + "."}


def check_data_quality(x: VerdictInputs) -> CheckOutcome:
    """Saturation and glitch notices, a constant or stuck torque channel, maximum likelihood's motion
    that is not periodic at its f0, cond(W) and the fraction of equations in the velocity dead zone."""
    notices = (list(getattr(x.result, "notices", []) or [])
               + list(getattr(x.validation, "notices", []) or []))
    sat = [s for s in notices if "saturat" in s.lower()]
    # maximum likelihood's trajectory model (eq. (17)) that misses the motion: its estimates are biased
    # (not the notice of how many harmonics BIC chose, "latent trajectory: K = ...")
    latent = [s for s in notices if re.search(r"latent trajectory \(.*(misses part of the motion|not periodic)", s)]
    # one-sample spikes and jumps the loader found (dynid.analysis.data.plausibility)
    # (in the measured q and tau: IDIM does not use the reference qr)
    glitch = [s for s in notices if re.search(r"isolated spike in (q|tau)\d|\bq\d+ jumps by", s)]
    # a torque channel that is constant or barely varies (dynid.analysis.data.saturation): stuck or
    # not logged, and the fit reads it as a joint that needs no torque (ZZ1R 70 % off on planar2).
    # A reason, not a failure: a joint held on its brake in a per-joint campaign looks the same.
    stuck = [s for s in notices if re.search(r"\btau\d+ (is constant|barely varies)", s)]
    dq = [{"level": "warn", "text": s} for s in dict.fromkeys(sat + latent + glitch + stuck)]
    ls_fit = _least_squares(x.result)
    if ls_fit is not None:
        dq.append(_conditioning(ls_fit, x.cond_threshold))
    mask = _fitted_mask(x.result)
    if mask is not None or x.validation is not None:
        dq.append(_dead_zone(mask, x.validation))
    return CheckOutcome(findings=[dict(d, key="data") for d in dq],
                        reasons=(["saturation"] if sat else []) + (
                            ["the motion is not periodic at maximum likelihood's f0"] if latent else []) + (
                            ["glitches in the data"] if glitch else []) + (
                            ["a torque channel that is constant or barely varies"] if stuck else []),
                        fields={"data_quality": dq})


#: the checks, in the order their findings are shown; a new check is one
#: function `VerdictInputs -> CheckOutcome` appended here
def check_agreement(x: VerdictInputs) -> CheckOutcome:
    """Do the recordings (or three segments of one) agree within their intervals (issue 26)?

    Information only: the verdict's status does not change, but a disagreement says the
    intervals of one recording are optimistic (model error differs between trajectories).
    """
    a = getattr(x.result, "agreement", None)
    if a is None:
        return CheckOutcome()
    # as the line says: a chi2 test that could not be computed (NaN) rejects nothing
    level = "ok" if a.agrees else "info"
    return CheckOutcome(findings=[{"level": level, "key": "agreement", "text": x.result.agreement_line}])


def _effects_part(fx):
    """(text, JSON block) of the fit with effects beside the rigid body (`--effects`)."""
    v, both = fx.validation or {}, fx.physical is not None
    held = (f", {percent(v['rel_error_wls'])}" + (f" ({percent(v['rel_error_pc'])})" if both else "") + " held out"
            if v else "")
    text = (f"with the effects {fx.spec} (--effects): {percent(fx.rel_error_wls)}"
            + (f" (physically consistent: {percent(fx.rel_error_pc)})" if both else "") + held)
    return text, {"spec": fx.spec, "rel_error_wls": fx.rel_error_wls,
                  "rel_error_pc": fx.rel_error_pc if both else None,
                  "held_out_rel_error_wls": v.get("rel_error_wls"), "held_out_rel_error_pc": v.get("rel_error_pc")}


def _physical_part(pc, with_effects):
    """(text, JSON block) of the physically consistent fit (`--physical`); its errors are the
    effects' line's when it was fitted with them."""
    v = pc.validation or {}
    if with_effects:
        text = f"its physically consistent fit (--physical): {pc.verdict_line()}"
    else:
        text = (f"the physically consistent fit (--physical): {pc.verdict_line()}; {percent(pc.rel_error)}"
                + (f", {percent(v['rel_error_pc'])} held out" if v else "")
                + f" (unconstrained, all base parameters: {percent(pc.wls_rel_error)}"
                + (f", {percent(v['rel_error_wls'])}" if v else "") + ")")
    return text, {"chi2": pc.chi2, "dof": pc.dof, "p_value": pc.p_value, "consistent": pc.consistent,
                  "rel_error": pc.rel_error, "held_out_rel_error": v.get("rel_error_pc")}


def check_other_fits(x: VerdictInputs) -> CheckOutcome:
    """The other fits of the same run (`--physical`, `--effects`), one line: the verdict judges
    the unconstrained rigid-body model, and the line says so and quotes theirs (the relative
    errors on the identification data and, held out, on all samples), so that a reader who
    asked for them does not take the verdict for theirs. Information only."""
    if x.physical is None and x.effects is None:
        return CheckOutcome()
    model = "its essential parameters" if x.kind == "essential" else "all its base parameters"
    judged = (f"The verdict judges the unconstrained rigid-body model ({model}): relative error "
              f"{percent(getattr(x.estimate, 'rel_error', np.nan))} on the identification data"
              + (f", {percent(x.validation.rel_error)} held out (all samples)" if x.validation is not None else ""))
    parts, block = [], {"judged": f"rigid body, unconstrained ({x.kind} parameters)"}
    if x.effects is not None:
        text, block["effects"] = _effects_part(x.effects)
        parts.append(text)
    if x.physical is not None:
        text, block["physical"] = _physical_part(x.physical, x.effects is not None)
        parts.append(text)
    return CheckOutcome(findings=[{"level": "info", "key": "other_fits",
                                   "text": judged + ". Beside it, " + "; ".join(parts) + "."}],
                        fields={"other_fits": block})


CHECKS = [check_convergence, check_validation, check_parameters, check_residual, check_diagnosis, check_plausibility, check_apriori,
          check_data_quality, check_agreement, check_other_fits]


def _inputs(result, validation, robot, diagnosis, residuals, physical=None, effects=None,
            **thresholds) -> VerdictInputs:
    robot = robot if robot is not None else getattr(result, "robot", None)
    m = _estimate(result)
    if not all(hasattr(m, a) for a in ("names", "chi", "bse", "rel_std")):
        # a posterior, an essential model alone, a per-joint campaign: no identification to judge
        raise InputError(
            f"verdict: {type(result).__name__} is not an identification the verdict judges. Give the "
            "result of dynid.identify or dynid.run (IDIM, DIDIM, Projection Method, ML, or the physically "
            "consistent fit); the verdict of an IDIM result judges its essential model, and a posterior's "
            "identification is the one it sampled")
    if residuals is None:
        residuals = _fitted_residual(result)
    n = (residuals.normality.shape[0] if residuals is not None else
         len(validation.joint_rel_error) if validation is not None else
         int(getattr(robot, "n_joints", 0) or getattr(result, "n_joints", 0) or 0))
    return VerdictInputs(
        result=result, validation=validation, robot=robot, diagnosis=diagnosis, residuals=residuals,
        estimate=m, names=_joint_names(robot, n), n=n,
        kind=judged_kind(result),
        params=_parameter_table(m, thresholds["rel_std_threshold"], prismatic_joints(robot)), physical=physical,
        effects=effects, **thresholds)


def judged_kind(result) -> str:
    """Which parameters the verdict of `result` judges: "essential" (IDIM, DIDIM: their essential
    model) or "base" (the Projection Method, ML: every base parameter)."""
    return "essential" if getattr(result, "essential", None) is not None else "base"


def verdict(idim_result, validation=None, *, robot=None, diagnosis=None, residuals=None, physical=None,
            effects=None, rel_std_threshold=10.0, joint_error_threshold=0.20, warn_rel_error=0.10,
            fail_rel_error=0.30, apriori_k=3.0, alpha=0.05, cond_threshold=1000.0,
            checks=None) -> Verdict:
    """The verdict of an identification (see the module docstring for every rule).

    Parameters
    ----------
    idim_result : ParameterResults
        IDIM and DIDIM are judged on their essential model; the Projection
        Method and maximum likelihood on their estimate, without the residual
        whiteness (see `_fitted_residual`).
    validation : ValidationResult, optional
        The held-out validation.
    robot : Robot, optional
        Defaults to the result's robot.
    diagnosis : DiagnosisResult, optional
        Only its conclusion is quoted.
    residuals : ResidualAnalysis, optional
        A precomputed analysis of the identification residual (computed here otherwise).
    physical, effects : PhysicalResult, EffectsFit, optional
        The physically consistent fit and the fit with effects of the same run: quoted in one
        line (`check_other_fits`), not judged.
    rel_std_threshold : float
        In percent; the error thresholds are fractions.
    checks : list of callables, optional
        The checks to run, `CHECKS` by default.

    Returns
    -------
    Verdict
        Status, reasons and findings in the order of the checks.
    """
    x = _inputs(idim_result, validation, robot, diagnosis, residuals, physical, effects,
                rel_std_threshold=rel_std_threshold, joint_error_threshold=joint_error_threshold,
                warn_rel_error=warn_rel_error, fail_rel_error=fail_rel_error, apriori_k=apriori_k,
                alpha=alpha, cond_threshold=cond_threshold)
    findings, reasons, fields, fail = [], [], {}, False
    for check in (CHECKS if checks is None else checks):
        out = check(x)
        findings += out.findings
        reasons += out.reasons
        fields.update(out.fields)
        fail = fail or out.fail
    own = set(Verdict.__dataclass_fields__)
    status = "not identified" if fail else ("identified with reservations" if reasons else "identified")
    return Verdict(status=status, identified=not fail, reasons=reasons,
                   rel_std_threshold=float(rel_std_threshold), findings=findings,
                   extra={k: v for k, v in fields.items() if k not in own},
                   **{k: v for k, v in fields.items() if k in own})
