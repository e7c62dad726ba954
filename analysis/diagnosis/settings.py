"""The settings of a residual diagnosis in one object (the keyword arguments of
dynid.analysis.diagnosis.selection.diagnose, which builds it)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from dynid.analysis.diagnosis.effects import check_effect_names
from dynid.analysis.estimators.least_squares import check_uncertainty
from dynid.errors import InputError

__all__ = ["DiagnosisSettings"]


@dataclass(frozen=True)
class DiagnosisSettings:
    """What a diagnosis considers and how it decides (see `diagnose` for each field).

    Parameters
    ----------
    effects : names of the effects to consider (None: all of EFFECT_NAMES).
    max_effects : most effects added by the greedy forward selection.
    alpha : family-wise level of the LR test at each step (Bonferroni over the candidates).
    folds, gap : blocked cross-validation: contiguous blocks, guard in decimated samples
        ("auto": the decimation filter's half length).
    exclude_parameters : base parameters removed from the model before identifying.
    joints : 1-based joints whose effects are considered (None: all).
    residual_analysis : compute the residual analyses before/after (for reports).
    confirm_on_validation : keep an effect only if it lowers the validation error.
    max_error_growth : essential-parameter criterion of the identification.
    structure_tests, hidden_tests, physical_tests : run the catalogue-free structure tests,
        the a-priori (hidden-effect) tests, the physically consistent tests.
    start_model : "essential", "base" or a list of base-parameter names.
    base_guard : a candidate must also be significant against the full base model.
    max_tries : passing candidates tried per step until one is kept.
    reselect_essential : re-select the essential set on the torque less the selected effects.
    processing : processing overrides of the identification (identify_idim's settings).
    gear_ratios : (n,) gear ratios of the joints' motors, to name a line at a harmonic of the
        motor turn (None: from the data description's [transmission], when there is one).
    rest_phases : with validation data, score the friction-at-rest candidates (rest.py).
    uncertainty : covariance of the identification made here ("classic", "hac", "bootstrap");
        the final model's σ take it, the decisions are taken on the classic one.
    """

    effects: tuple | None = None
    max_effects: int = 3
    alpha: float = 0.01
    folds: int = 5
    gap: int | str = "auto"
    exclude_parameters: tuple | None = None
    joints: tuple | None = None
    residual_analysis: bool = True
    confirm_on_validation: bool = True
    max_error_growth: float = 0.02
    structure_tests: bool = True
    start_model: object = "essential"
    base_guard: bool = True
    max_tries: int = 5
    hidden_tests: bool = True
    physical_tests: bool = True
    reselect_essential: bool = True
    processing: dict | None = None
    gear_ratios: tuple | None = None
    rest_phases: bool = True
    uncertainty: str = "classic"

    def checked(self) -> DiagnosisSettings:
        """These settings with the effect names checked and expanded.

        Raises
        ------
        InputError
            An unknown effect name, `max_effects < 0`, `alpha` outside (0, 1) or
            fewer than 3 folds.
        """
        check_uncertainty(self.uncertainty)
        effects = check_effect_names(self.effects)
        if self.max_effects < 0:
            raise InputError(f"max_effects must be >= 0, got {self.max_effects}")
        if not 0 < self.alpha < 1:
            raise InputError(f"alpha must be in (0, 1), got {self.alpha}")
        folds = int(self.folds)
        if folds < 3:
            raise InputError(f"folds must be >= 3, got {self.folds}")
        return dataclasses.replace(self, effects=effects, folds=folds)
