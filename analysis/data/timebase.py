"""The time base of an experiment: time-column checks, resampling and reference shift.

* `_check_time`: `t` strictly increasing and uniform within
  `TIME_STEP_TOLERANCE` of the median step; steps longer than `GAP_FACTOR` ×
  the median are named as dropped samples or clock jumps.
* `_resample`: linear interpolation onto a uniform grid at the median step
  (`resample = true` in an experiment TOML).
* `estimate_shift`: the integer sample shift between measured and reference
  positions, by least squares (`shift = "estimate"` in `[reference]`).

The rules are described in docs/formats.md, section "Experiment data".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from dynid.analysis.data._format import _fmt, _fmt_t, _short_list
from dynid.errors import DataError

if TYPE_CHECKING:
    from dynid.analysis.data.columns import _Col

__all__ = ["estimate_shift", "TIME_STEP_TOLERANCE", "GAP_FACTOR", "MAX_RESAMPLE_STEP"]

#: Largest allowed relative deviation of a time step from the median step.
TIME_STEP_TOLERANCE = 0.01
#: A time step longer than this × the median is reported as dropped samples / clock jump.
GAP_FACTOR = 1.5
#: a time column whose steps are 0 this often is too coarse (not a few duplicated rows)
COARSE_TIME_FRACTION = 0.25
#: `resample = true` interpolates across steps up to this × the median (the Panda's ROS
#: stamps reach 8.8 ×), or up to MAX_RESAMPLE_GAP seconds when that is longer (a scheduler's
#: hiccup in a 1 kHz log); a longer step is a gap, and a straight line across it would be
#: fitted as if the robot had moved that way.
MAX_RESAMPLE_STEP = 20.0
MAX_RESAMPLE_GAP = 0.05


class IrregularTimeSteps(DataError):
    """Time steps that are not uniform (no gap): resampling onto the median step would make them so,
    which callers that can resample name in their own terms."""


@dataclass
class _Options:
    """Loader options (an experiment TOML's [experiment] table, or the defaults)."""

    name: str = ""
    sampling_rate: float | None = None
    start_time: float = 0.0
    start_offset: int = 0
    resample: bool = False
    time_tolerance: float = TIME_STEP_TOLERANCE
    where: str = ""  # the TOML file, for messages about options


def _check_time(t: np.ndarray, col: _Col, rows: np.ndarray, opts: _Options,
                notices: list[str]) -> tuple[bool, float]:
    """Validate the time column; (True if the caller must resample, the median time step)."""
    with np.errstate(over="ignore", invalid="ignore"):
        dt = np.diff(t)
    if not np.all(np.isfinite(dt)):
        k = int(np.flatnonzero(~np.isfinite(dt))[0])
        raise DataError(
            f"{col.where}: the time values at {col.raw.row(rows[k + 1])} are too large to "
            "take differences. Store time in s relative to the start of the recording."
        )
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = int(back[0])
        what = "repeats" if dt[k] == 0 else "goes back"
        repeats = int(np.count_nonzero(dt == 0))
        if repeats >= max(COARSE_TIME_FRACTION * dt.size, 10):
            # not a few duplicated rows: time stamps coarser than the sampling (float32 keeps ~7
            # digits, so epoch seconds in float32 do not even resolve a second; or rounded when written)
            raise DataError(
                f"{col.where}: time does not advance in {repeats} of its {dt.size} steps (first at "
                f"{col.raw.row(rows[k + 1])}, t = {_fmt_t(t[k + 1])}): the time stamps are coarser than "
                "the sampling, they have too few digits for their size (float32 values keep ~7 digits; "
                "or rounded when written). Store time as float64 with enough decimals, or in s relative "
                "to the start of the recording."
            )
        raise DataError(
            f"{col.where}: time {what} at {col.raw.row(rows[k + 1])}: t = {_fmt_t(t[k + 1])} "
            f"follows t = {_fmt_t(t[k])} at {col.raw.row(rows[k])} ({back.size} such step(s) "
            "in all). Time must be strictly increasing: sort the rows by time and remove "
            "repeated samples."
        )
    med = float(np.median(dt))
    if not (med > 0 and math.isfinite(1.0 / med)):
        raise DataError(
            f"{col.where}: the median time step {med!r} s is too small. Store time in s."
        )
    dev = np.abs(dt - med) / med
    tol = opts.time_tolerance
    gaps = np.flatnonzero(dt > GAP_FACTOR * med)
    gap_text = ""
    if gaps.size:
        gap_text = (
            f" Dropped samples or clock jumps (steps longer than {GAP_FACTOR} × the median) "
            f"before: "
            + _short_list(
                [f"{col.raw.row(rows[k + 1])} ({dt[k] * 1e3:.4g} ms)" for k in gaps], 5
            )
            + "."
        )
    if not (dev > tol).any():
        if opts.resample:
            notices.append(
                f"resample = true, but the time steps of {col.where} are already uniform "
                f"within {tol:.3g} of the median: not resampled"
            )
        return False, med
    n_off = int((dev > tol).sum())
    holes = np.flatnonzero(dt > max(MAX_RESAMPLE_STEP * med, MAX_RESAMPLE_GAP))
    if holes.size:
        k = int(holes[0])
        raise DataError(
            f"{col.where}: the recording has a gap: {_fmt(dt[k] * 1e3)} ms ({dt[k] / med:.0f} median steps) "
            f"between {col.raw.row(rows[k])} and {col.raw.row(rows[k + 1])}"
            + (f", and {holes.size - 1} more as long" if holes.size > 1 else "")
            + ". Resampling (--resample, resample = true) fills only steps up to "
            + f"{_fmt(max(MAX_RESAMPLE_STEP * med, MAX_RESAMPLE_GAP) * 1e3)} ms: across a gap it would invent "
            + "the motion the recording lacks. Split the recording at its gaps (one file per part) and give "
            + "the parts as separate recordings."
        )
    if opts.resample:
        notices.append(
            f"{col.where}: irregular time steps ({_fmt(dt.min() * 1e3)} … "
            f"{_fmt(dt.max() * 1e3)} ms, median {_fmt(med * 1e3)} ms; {n_off} of "
            f"{dt.size} steps off by more than {tol:.1%})." + gap_text
        )
        return True, med
    k = int(np.argmax(dev))
    steps = np.unique(dt)
    # jitter takes many values; a handful is the rounding of the stamps (float32 at t ~ 1000 s
    # steps by 61 us), which resampling would also follow, but the cause is the storage
    rounded = (f" The steps take only {steps.size} values ({', '.join(_fmt(s * 1e3) for s in steps)} ms): "
               "the time stamps are rounded, too few digits for their size (float32 values keep ~7 "
               "digits); store time as float64, or in s relative to the start of the recording."
               if steps.size <= 4 else "")
    raise IrregularTimeSteps(
        f"{col.where}: irregular time steps{rounded and ' (rounded time stamps)'}: the median step is {_fmt(med * 1e3)} ms but "
        f"the step to {col.raw.row(rows[k + 1])} from the row before is {_fmt(dt[k] * 1e3)} ms "
        f"({dev[k]:.1%} off; the tolerance is {tol:.2%}). {n_off} of {dt.size} "
        f"steps are off by more than the tolerance.{gap_text}{rounded} "
        + (f"Set `resample = true` in {opts.where} (linear interpolation at the median step)."
           if opts.where.endswith("[experiment]") else
           "Resample the data onto a uniform time grid, or load it through an experiment TOML with "
           "`resample = true` in [experiment] (linear interpolation at the median step).")
    )


#: resampling may make at most this many times the recorded samples: more means a gap
#: (interpolating across it would invent the data and could take any amount of memory)
MAX_RESAMPLE_GROWTH = 2.0


def _resample(t: np.ndarray, signals: dict[str, np.ndarray], notices: list[str], where: str = "the time column"):
    dt = np.diff(t)
    med = float(np.median(dt))
    span = (t[-1] - t[0]) / med
    if not span <= MAX_RESAMPLE_GROWTH * t.size:
        k = int(np.argmax(dt))
        raise DataError(
            f"{where}: resampling at the median step {_fmt(med * 1e3)} ms would make {span:.3g} samples from "
            f"{t.size} (at most {MAX_RESAMPLE_GROWTH:g}x): the longest step, {_fmt(dt[k])} s after sample "
            f"{k + 1}, is a gap in the recording, not jitter. Split the recording at its gaps and load "
            "the parts as separate recordings."
        )
    k = int(math.floor(span * (1 + 1e-12)))
    grid = t[0] + med * np.arange(k + 1)
    grid = grid[grid <= t[-1]]
    out = {}
    for s in list(signals):
        a = signals.pop(s)          # the caller's copy goes as its resampled one is made
        out[s] = np.empty((grid.size, a.shape[1]))
        for j in range(a.shape[1]):
            out[s][:, j] = np.interp(grid, t, a[:, j])
        del a
    notices.append(
        f"resampled {t.size} samples with irregular time steps onto a uniform grid of "
        f"{grid.size} samples at the median step {_fmt(med * 1e3)} ms "
        f"({_fmt(1 / med)} Hz) by linear interpolation"
    )
    return grid, out


def estimate_shift(measured, reference, max_shift: int | None = None,
                   min_shift: int = 0) -> tuple[int, float]:
    """Integer sample shift L with `measured[i + L] ≈ reference[i]`, by least squares.

    Minimises the mean over joints and overlapping samples of
    `(measured[i + L] − reference[i])²` for `min_shift ≤ L ≤ max_shift`.
    Defaults: `min_shift = 0` (causal: the measurement follows the command, never
    precedes it) and `max_shift = N // 4` (at least three quarters of the record
    overlap). Both are capped at ±(N − 2). The range matters for periodic excitation
    trajectories: a shift by a whole period (or minus one) fits about as well, so keep
    the range below one period. Ties go to the smallest |L|. The cross terms are
    computed by FFT; the best candidates are re-evaluated directly.

    Returns `(L, rms)`: the shift in samples and the RMS difference at that shift.
    """
    m = np.asarray(measured, dtype=float)
    r = np.asarray(reference, dtype=float)
    if m.ndim == 1:
        m = m[:, None]
    if r.ndim == 1:
        r = r[:, None]
    if m.shape != r.shape:
        raise DataError(
            f"estimate_shift: measured {m.shape} and reference {r.shape} differ in shape."
        )
    n, c = m.shape
    if n < 3:
        raise DataError("estimate_shift needs at least 3 samples.")
    hi = n // 4 if max_shift is None else int(max_shift)
    lo = int(min_shift)
    hi = max(-(n - 2), min(hi, n - 2))
    lo = max(-(n - 2), min(lo, n - 2))
    if lo > hi:
        raise DataError(
            f"estimate_shift: min_shift = {min_shift} is larger than max_shift = {max_shift}."
        )
    size = 1
    while size < 2 * n:
        size *= 2
    corr = np.zeros(size)
    for j in range(c):
        corr += np.fft.irfft(np.fft.rfft(m[:, j], size) * np.conj(np.fft.rfft(r[:, j], size)), size)
    cm = np.concatenate([[0.0], np.cumsum((m**2).sum(axis=1))])
    cr = np.concatenate([[0.0], np.cumsum((r**2).sum(axis=1))])
    lags = np.arange(lo, hi + 1)
    cost = np.empty(lags.size)
    for idx, L in enumerate(lags):
        if L >= 0:
            ov = n - L
            sm, sr, x = cm[n] - cm[L], cr[ov], corr[L]
        else:
            K = -L
            ov = n - K
            sm, sr, x = cm[ov], cr[n] - cr[K], corr[size - K]
        cost[idx] = (sm + sr - 2 * x) / (ov * c)

    def direct(L: int) -> float:
        if L >= 0:
            d = m[L:] - r[: n - L]
        else:
            d = m[: n + L] - r[-L:]
        return float(np.mean(d**2))

    cand = lags[np.argsort(cost, kind="stable")[: min(7, lags.size)]]
    exact = sorted((direct(int(L)), abs(int(L)), int(L)) for L in cand)
    best_cost, _, best = exact[0]
    return best, math.sqrt(max(best_cost, 0.0))

