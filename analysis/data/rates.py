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


def check_same_rate(experiments, roles=None) -> None:
    """Raise `DataError` when the recordings' rates differ by more than TIME_STEP_TOLERANCE.

    Parameters
    ----------
    experiments : sequence of Experiment
        The recordings, the first one the reference (its rate sets the processing).
    roles : sequence of str, optional
        What each recording is, for the message ("the data", "the --validation recording").
    """
    exps = [e for e in experiments if e is not None and getattr(e, "fs", None)]
    if len(exps) < 2:
        return
    roles = list(roles) if roles is not None else ["the recording"] * len(exps)
    ref = exps[0]
    for exp, role in zip(exps[1:], roles[1:]):
        if abs(exp.fs - ref.fs) > TIME_STEP_TOLERANCE * ref.fs:
            raise DataError(
                f"{exp.source or exp.name}: {role} is sampled at {exp.fs:g} Hz, but {ref.source or ref.name} "
                f"at {ref.fs:g} Hz: recordings processed together (filters and decimation are chosen on "
                f"the first) must share one sampling rate. Resample one of them to the other's rate, or "
                f"identify them separately."
            )


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
