"""Splitting one recording into identification and held-out validation parts."""
from __future__ import annotations

from dynid.errors import InputError


def holdout_split(experiment, seconds: float):
    """``(identification, held_out)``: the last ``seconds`` of ``experiment`` are held out.

    The split is at ``t[-1] - seconds``; the identification part is ``t < t_split``
    and the held-out part ``t >= t_split`` (:meth:`Experiment.segment`), so no
    sample is in both.
    """
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        raise InputError(f"holdout must be a number of seconds, got {seconds!r}") from None
    if not seconds > 0:
        raise InputError(f"holdout must be a positive number of seconds, got {seconds:g}")
    t_split = experiment.t[-1] - seconds
    if not experiment.t[0] < t_split:
        raise InputError(f"holdout {seconds:g} s is longer than the recording {experiment.source} "
                         f"({experiment.duration:.3g} s): hold out less")
    return experiment.segment(None, t_split), experiment.segment(t_split, None)
