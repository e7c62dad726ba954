"""Recordings identified together, or validated against each other, share one sampling rate.

The processing (filter cut-offs, decimation factor `nd`) is chosen once, on the first
recording, and applied to the others; at another rate it would mean other frequencies, or
be impossible (a cut-off above the decimated Nyquist frequency). Hence one clear error
naming the recordings and their rates, before any processing.
"""
from __future__ import annotations

from dynid.analysis.data.timebase import TIME_STEP_TOLERANCE
from dynid.errors import DataError

__all__ = ["check_same_rate", "check_rate_matches"]


def check_same_rate(experiments, role: str = "a recording") -> None:
    """Raise `DataError` when a recording's rate differs from the first one's (which sets the
    processing) by more than TIME_STEP_TOLERANCE (`check_rate_matches`); `role` names them."""
    exps = [e for e in experiments if e is not None and getattr(e, "fs", None)]
    for exp in exps[1:]:
        check_rate_matches(exp, exps[0].fs, role, exps[0].source or exps[0].name)


def check_rate_matches(experiment, fs, role: str, against: str) -> None:
    """Raise `DataError` when `experiment` is not sampled at `fs` (Hz), the rate `against` was
    processed at (within TIME_STEP_TOLERANCE); nothing when either rate is unknown."""
    if not (fs and getattr(experiment, "fs", None)):
        return
    if abs(experiment.fs - fs) > TIME_STEP_TOLERANCE * fs:
        raise DataError(
            f"{experiment.source or experiment.name}: {role} is sampled at {experiment.fs:g} Hz, but "
            f"{against} at {fs:g} Hz: it is processed with the same filters and decimation, which "
            f"need the same sampling rate. Resample it to {fs:g} Hz."
        )
