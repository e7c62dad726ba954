"""Result objects of a residual diagnosis (dynid.analysis.diagnosis.selection.diagnose):
the ranked candidates, the selection steps, the effects added, the errors before and
after, and `DiagnosisResult` (its terminal text is built in
dynid.analysis.diagnosis.summary_text).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.diagnosis.effects import Candidate
from dynid.analysis.diagnosis.summary_text import diagnosis_summary, effect_unit, fmt_p, nonlinear_text
from dynid.analysis.results import HeldParameters, Result
from dynid.analysis.units import prismatic_of
from dynid.provenance import json_safe, versions

__all__ = ["RankedEffect", "DiagnosisStep", "SelectedEffect", "Errors", "errors_of", "DiagnosisResult",
           "params_records", "fmt_p", "nonlinear_text"]

# ======================================================================= results
@dataclass
class RankedEffect:
    """One effect on one joint, scored against a model (the best value of its nonlinear parameter)."""

    name: str
    joint: int | None
    nonlinear: dict
    params: list
    cv_gain: float               # fraction of held-out weighted squared error removed
    folds_better: int            # held-out blocks where the candidate predicts better
    n_folds: int
    statistic: float             # LR with the effective sample size
    p_raw: float                 # chi2_k.sf(LR)
    p_value: float               # Bonferroni-adjusted (x m)
    ic_gain: float               # LR - k ln(n_eff)
    n_eff: float                 # effective sample size of the candidate model's residual
    passes: bool                 # meets the selection rule
    selected: bool = False
    step: int = 0                # step it was scored at
    aliases: list = field(default_factory=list)   # names of effects with the same columns
    candidate: Candidate = None
    fold_errors: np.ndarray = None
    base_p: float = float("nan")  # Bonferroni p against the full base model (base_guard)

    @property
    def label(self):
        return self.candidate.label if self.candidate is not None else f"{self.name} ({self.joint})"

    def to_dict(self):
        return {"name": self.name, "joint": self.joint, "nonlinear": self.nonlinear,
                "parameters": list(self.params), "statistic": self.statistic,
                "statistic_kind": "likelihood ratio with effective sample size (chi2_k under H0)",
                "p_value": self.p_value, "p_value_unadjusted": self.p_raw,
                "ic_gain": self.ic_gain, "cv_gain": self.cv_gain,
                "folds_better": self.folds_better, "n_folds": self.n_folds, "n_eff": self.n_eff,
                "passes_rule": self.passes, "selected": self.selected, "step": self.step,
                "p_value_vs_full_base_model": self.base_p,
                "aliases": list(self.aliases)}


@dataclass
class DiagnosisStep:
    """One round of the greedy selection."""

    step: int
    ranking: list                 # RankedEffect per (effect, joint), best first
    n_candidates: int             # m, candidates scored (Bonferroni)
    skipped: list                 # labels of candidates already in the model's span
    accepted: bool
    reason: str
    runner_up: RankedEffect | None = None
    gap: float = float("nan")     # cv_gain(winner) - cv_gain(runner-up)
    confidence: float = float("nan")   # fraction of blocks where the winner beats the runner-up
    chosen: RankedEffect | None = None   # the candidate tried last (the one added if accepted)
    tried: list = field(default_factory=list)   # (label, outcome) of the candidates tried
    # (label, why) of the ripples a spring of their joint was tried before (rule.spring_before_ripple)
    reordered: list = field(default_factory=list)

    @property
    def winner(self):
        """The effect added at this step, else the best-ranked candidate."""
        if self.chosen is not None:
            return self.chosen
        return self.ranking[0] if self.ranking else None

    def to_dict(self):
        return {"step": self.step, "accepted": self.accepted, "reason": self.reason,
                "n_candidates": self.n_candidates,
                "winner": None if self.winner is None else self.winner.to_dict(),
                "runner_up": None if self.runner_up is None else self.runner_up.to_dict(),
                "gap": self.gap, "confidence": self.confidence,
                "tried": [{"candidate": a, "outcome": b} for a, b in self.tried],
                "reordered": [{"candidate": a, "why": b} for a, b in self.reordered],
                "skipped_in_model_span": list(self.skipped)}


@dataclass
class SelectedEffect:
    """An effect added to the model, with its identified parameters."""

    name: str
    joint: int | None
    nonlinear: dict
    params: list
    values: np.ndarray
    sigma: np.ndarray
    step: int
    candidate: Candidate
    torque_rms: np.ndarray = None    # RMS of its torque per joint (identification rows)
    note: str = ""                   # when the fitted sign contradicts the effect's name
    kind: str = "effect"             # or "coulomb_onset" (see notes.onset_note)
    title: str = ""                  # the name it is reported under (notes.effect_title)

    @property
    def label(self):
        """The candidate's label under the effect's title (a Stribeck form with Fs < 0 is a rise)."""
        lab = self.candidate.label
        if self.title and self.title != self.name and lab.startswith(self.name):
            return self.title + lab[len(self.name):]
        return lab

    @property
    def rel_sigma(self):
        with np.errstate(divide="ignore", invalid="ignore"):
            return 100.0 * self.sigma / np.abs(self.values)

    def to_dict(self, prismatic=frozenset()):
        return {"name": self.name, "joint": self.joint, "nonlinear": self.nonlinear, "step": self.step,
                "parameters": [{"name": p, "value": v, "std": s, "rel_std_percent": r,
                                "unit": effect_unit(p, prismatic)}
                               for p, v, s, r in zip(self.params, self.values, self.sigma,
                                                     self.rel_sigma)],
                "note": self.note or None, "kind": self.kind, "title": self.title or self.name,
                "label": self.label,
                "torque_rms_per_joint": None if self.torque_rms is None else list(self.torque_rms)}


@dataclass
class Errors:
    """Relative error norm and per-joint RMS of a model on one data set (rows used)."""

    rel_error: float
    rms: np.ndarray
    joint_rel_error: np.ndarray

    def to_dict(self):
        return {"rel_error": self.rel_error, "rms_per_joint": list(self.rms),
                "joint_rel_error": list(self.joint_rel_error)}


def errors_of(tau, tau_hat, mask):
    r = np.where(mask, tau - tau_hat, 0.0)
    y = np.where(mask, tau, 0.0)
    cnt = np.maximum(mask.sum(axis=0), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return Errors(rel_error=float(np.linalg.norm(r) / np.linalg.norm(y)),
                      rms=np.sqrt((r ** 2).sum(axis=0) / cnt),
                      joint_rel_error=np.linalg.norm(r, axis=0) / np.linalg.norm(y, axis=0))


@dataclass(repr=False)
class DiagnosisResult(HeldParameters, Result):
    """What `diagnose` found. `ranking` is from most to least likely."""

    robot_name: str
    source: str
    ranking: list                  # RankedEffect: selected first (in order), then the rest
    steps: list                    # DiagnosisStep
    selected: list                 # SelectedEffect
    model_before: object           # IdentificationResult (essential WLS)
    model_after: object            # IdentificationResult (essential + effects, WLS)
    errors: dict                   # {"identification": {"before", "after"}, "validation": ... | None}
    settings: dict
    idim: object = None            # IDIMResult the diagnosis started from
    residuals: dict = field(default_factory=dict)   # ResidualAnalysis: "identification_before", ...
    validation_source: str = ""
    notices: list = field(default_factory=list)
    data_hash: str = ""
    path: list = field(default_factory=list)   # errors after each step (see diagnose)
    structure: object = None       # StructureResult: catalogue-free tests of the final residual
    hidden_tests: list = field(default_factory=list)   # HiddenEffect: a-priori prior tests (hidden.py)
    findings: list = field(default_factory=list)   # Finding: named, not added (findings.py)
    cut: list = field(default_factory=list)        # RankedEffect passing the rule, cut by max_effects
    rest: object = None            # RestPhases: held-out error at rest, before/after (rest.py)

    @property
    def hidden(self):
        """Effects the base parameters absorbed, found through the a-priori values (list of
        reported `HiddenEffect`)."""
        return [h for h in self.hidden_tests if h.reported]

    @property
    def unexplained(self):
        """Joints whose final residual has structure no selected effect explains (list of
        `Unexplained`)."""
        return [] if self.structure is None else list(self.structure.unexplained)

    @property
    def effects(self):
        """The selected effects that are effects of the robot (`kind == "effect"`): without the
        Coulomb onsets, which are kept in the model but say the velocity dead zone is narrower
        than the friction's smooth onset (`onset_note`)."""
        return [e for e in self.selected if e.kind == "effect"]

    @property
    def method(self) -> str:
        return "residual diagnosis"

    @property
    def names(self):
        """The parameters of the model after the diagnosis (`model_after`)."""
        return self.model_after.names

    @property
    def rel_error(self) -> float:
        return self.model_after.rel_error

    def _held(self):
        # params, bse, conf_int, d["Ks2"]: those of the model after the diagnosis, as to_frame
        return self.model_after

    def to_frame(self):
        """The parameters of the model after the diagnosis (`model_after.to_frame()`).

        Returns
        -------
        pandas.DataFrame
            One row per parameter: value, std, rel_std_percent.
        """
        return self.model_after.to_frame()

    @property
    def selected_names(self):
        return [(s.name, s.joint) for s in self.selected]

    def summary(self):
        """The diagnosis as text (dynid.analysis.diagnosis.summary_text).

        Returns
        -------
        str
            The overview first (verdict, effects added, findings, flagged joints, cut
            effects, errors before and after), then the steps.
        """
        return diagnosis_summary(self)

    def __str__(self):
        return self.summary()

    def to_dict(self):
        errs = {}
        for key in ("identification", "validation"):
            e = self.errors.get(key)
            errs[key] = None if e is None else {"before": e["before"].to_dict(),
                                                "after": e["after"].to_dict()}
        return json_safe({
            "method": "residual diagnosis (greedy forward selection, blocked CV + n_eff LR test)",
            "robot": self.robot_name,
            "source": self.source,
            "validation_source": self.validation_source or None,
            "settings": self.settings,
            "effects": [r.to_dict() for r in self.ranking],
            "selected": [s.to_dict(prismatic_of(self)) for s in self.selected],
            "steps": [s.to_dict() for s in self.steps],
            "errors": errs,
            "path": [{"step": p["step"], "added": p["added"],
                      "identification": p["identification"].to_dict(),
                      "validation": None if p["validation"] is None else p["validation"].to_dict()}
                     for p in self.path],
            "parameters_before": params_records(self.model_before),
            "parameters": params_records(self.model_after),
            "rel_error": self.model_after.rel_error,
            "rms_per_joint": list(self.model_after.rms),
            "versions": versions(),
            "data_hash": self.data_hash,
            "notices": self.notices,
            "unexplained": [u.to_dict() for u in self.unexplained],
            "structure": None if self.structure is None else self.structure.to_dict(),
            "hidden": [h.to_dict() for h in self.hidden],
            "hidden_tests": [h.to_dict() for h in self.hidden_tests],
            "findings": [f.to_dict() for f in self.findings],
            "cut_by_max_effects": [dict(r.to_dict(), label=r.label,
                                        include_with=f"--max-effects {self.settings['max_effects'] + k + 1}")
                                   for k, r in enumerate(self.cut)],
            "flagged": [{"joint": u.joint, "hypothesis": u.hypothesis, "mechanism": u.mechanism}
                        for u in self.unexplained],
            "rest_phases": None if self.rest is None else self.rest.to_dict(),
        })


def params_records(res):
    return res._records()
