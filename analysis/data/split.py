"""Splitting one recording into identification and held-out validation parts, or into
time blocks for cross-validation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynid.analysis.data.record import recording_of
from dynid.errors import InputError

#: fewest samples either side of a hold-out split keeps (the filters and the decimation need
#: some; far fewer would say nothing either way)
MIN_PART_SAMPLES = 64


def _fmt_s(x: float) -> str:
    return f"{x:.6g}"


def holdout_split(experiment, seconds: float):
    """`(identification, held_out)`: the last `seconds` of `experiment` are held out.

    The split is at `t[-1] - seconds`; the identification part is `t < t_split`
    and the held-out part `t >= t_split` (`Experiment.segment`), so no
    sample is in both.

    Parameters
    ----------
    experiment : Experiment or the result of `dynid.simulate`
        The recording to split (`dynid.load_experiment` reads one from a file).
    seconds : float
        Length held out at the end of the recording, s: positive, and leaving 64
        samples (`MIN_PART_SAMPLES`) or more in each part.

    Returns
    -------
    identification : Experiment
        The samples with `t < t[-1] - seconds`.
    held_out : Experiment
        The last `seconds`.
    """
    experiment = recording_of(experiment)
    if not hasattr(experiment, "segment") or not hasattr(experiment, "t"):
        raise InputError(f"holdout_split: the recording must be an Experiment (dynid.load_experiment(path) "
                         f"reads a file), not {type(experiment).__name__}")
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        raise InputError(f"holdout must be a number of seconds, got {seconds!r}") from None
    if not seconds > 0:
        raise InputError(f"holdout must be a positive number of seconds, got {seconds:g}")
    t_split = experiment.t[-1] - seconds
    if not experiment.t[0] < t_split:
        raise InputError(f"holdout {seconds:g} s leaves nothing to identify in the recording "
                         f"{experiment.source or experiment.name} ({_fmt_s(experiment.t[-1] - experiment.t[0])} s "
                         "from its first to its last sample): hold out less")
    n_held = int(np.count_nonzero(experiment.t >= t_split))
    n_ident = experiment.t.size - n_held
    if experiment.t.size < 2 * MIN_PART_SAMPLES:
        raise InputError(f"the recording {experiment.source} has {experiment.t.size} samples: too short to hold "
                         f"out a part ({MIN_PART_SAMPLES} samples at least on each side); validate on another "
                         f"recording (--validation) or record longer")
    if min(n_ident, n_held) < MIN_PART_SAMPLES:
        short, fix = (("identification part", "hold out less") if n_ident < n_held else
                      ("held-out part", "hold out more"))
        raise InputError(f"holdout {seconds:g} s of the {experiment.duration:.3g} s recording {experiment.source} "
                         f"leaves {min(n_ident, n_held)} samples in the {short} (at least {MIN_PART_SAMPLES} "
                         f"are needed): {fix}")
    return experiment.segment(None, t_split), experiment.segment(t_split, None)


@dataclass(frozen=True)
class Fold:
    """One fold of `blocked_folds`: `block` (0-based), the scored time `span`
    `[start, end)`, the `test` recording (the span widened by the margin) and the
    `train` recordings (the rest of the record, `gap` away from `test`)."""

    block: int
    span: tuple
    test: object
    train: list


def blocked_folds(experiment, k: int, *, margin: float = 0.0, gap: float = 0.0) -> list:
    """Blocked (h-block) cross-validation folds of one recording, cut in time.

    The time that processing keeps, `[t0 + margin, t_end - margin]` (`margin`: what the
    position filter and the decimation drop at each end of a recording, in s), is cut into
    `k` blocks of equal duration. Fold `i` predicts block `i` from the rest: its test
    recording holds the samples of `[c_i - margin, c_(i+1) + margin)` (the whole record's
    start / end for the first / last block), so that once processed its samples are those of
    block `i`; its training recordings are the contiguous parts of the record that end
    `gap` seconds before the test recording starts or start `gap` after it ends. No raw
    sample is in both, and `gap` keeps samples that a filter applied before the recording
    (e.g. by a recording script) couples out of the training data (the h-block
    cross-validation of Burman, Chow & Nolan 1994, Biometrika 81(2), 351-358, for
    dependent data). A training part no longer than `2 margin` (nothing left once
    processed) is left out.
    """
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2:
        raise InputError(f"blocked cross-validation needs a whole number of blocks k >= 2, got {k!r}")
    try:
        margin, gap = float(margin), float(gap)
    except (TypeError, ValueError):
        raise InputError(f"margin and gap must be numbers of seconds, got {margin!r}, {gap!r}") from None
    if not (margin >= 0 and gap >= 0):
        raise InputError(f"margin and gap must be >= 0 s, got {margin:g} and {gap:g}")
    t = experiment.t
    lo, hi = t[0] + margin, t[-1] - margin
    edges = np.linspace(lo, hi, k + 1)
    n_min = int(np.min(np.diff(np.searchsorted(t, edges)))) if hi > lo else 0
    if n_min < 2:
        raise InputError(f"{experiment.source or 'the recording'} ({experiment.duration:.3g} s) is too short "
                         f"for {k} blocks after a margin of {margin:g} s at each end: every block needs 2 "
                         "samples or more; use fewer blocks")
    folds = []
    for i in range(k):
        start = None if i == 0 else float(edges[i] - margin)
        end = None if i == k - 1 else float(edges[i + 1] + margin)
        train = []
        if start is not None and start - gap - t[0] > 2 * margin:
            train.append(experiment.segment(None, start - gap))
        if end is not None and t[-1] - (end + gap) > 2 * margin:
            train.append(experiment.segment(end + gap, None))
        if not train:
            raise InputError(f"block {i + 1} of {k} of {experiment.source or 'the recording'}: nothing is left "
                             f"to train on with a margin of {margin:g} s and a gap of {gap:g} s; use more "
                             "blocks, or a smaller margin or gap")
        folds.append(Fold(block=i, span=(float(edges[i]), float(edges[i + 1])),
                          test=experiment.segment(start, end), train=train))
    return folds
