"""Column names and values: from raw file columns to a checked Experiment.

Holds the column convention, parsing cells to numbers (messages name the file, the
column and the row), the finite / joint-count / time-column / saturation checks, and
`_assemble` (start_offset → reference shift → time checks / resampling →
saturation → `Experiment`).

Column format (docs/formats.md, section "Experiment data")
----------------------------------------------------------
A table with one row per sample and the columns

    t                 time in s, strictly increasing
    q1 … qn           measured joint positions (rad, m for prismatic joints)
    qr1 … qrn         reference (commanded) joint positions
    qd1 … qdn         measured velocities, if logged
    qdd1 … qddn       measured accelerations, if logged
    tau1 … taun       joint torques (N·m) or forces (N)
    i1 … in           motor currents / control signals instead of torques;
                      tau = drive gain × i (the robot's `drive_gains`)

read by `load_experiment` from `.csv`, `.parquet`, `.npz` or `.mat`.
In `.npz` and `.mat` files a key is either one column (`t`, `q3`) or a 2-D
array `q`, `qr`, `qd`, `qdd`, `tau` or `i` of shape (N, n) that stands for
its n columns (an (n, N) array is transposed, with a notice). Names are case-sensitive.
Joints are numbered from 1 without gaps or leading zeros (`q0` or `q01` is an
error, not a silently ignored column).

Rules checked on load (every failure is a `dynid.errors.DataError` whose
message names the file, the column and the row, and says what to do):

* the file exists, is readable, is not empty and has a supported extension;
* `t` is present (unless an experiment TOML gives `sampling_rate`), `tau*` or
  `i*` is present, and `q*` or `qr*` is present;
* no column name appears twice; every signal has the same joints 1..n without gaps,
  and n equals `robot.n_joints` (or `n_joints`) when given;
* every used cell is a number (no text), finite (no empty cell, NaN or inf);
* `t` is strictly increasing and uniform: no time step differs from the median step
  by more than `TIME_STEP_TOLERANCE` (1 %) of it. Steps longer than
  `GAP_FACTOR` (1.5) × the median are reported as dropped samples or clock
  jumps. Irregular data must be resampled, e.g. with `resample = true` in a TOML.

Non-fatal findings go to `Experiment.notices`: ignored columns (anything not in
the convention, `i*` when `tau*` is also present), conversions (`tau = g·i`,
motor → joint side, scaling), skipped / dropped samples, resampling, the estimated
reference shift, and torque saturation (a joint whose `|tau|` sits at its maximum,
within a relative 1e-6, for at least `SATURATION_FRACTION` (0.5 %) of the
samples in runs of at least `SATURATION_MIN_RUN` (3) samples).

Row numbers in messages: for CSV, "data row k (file line L)": k counts the data rows
from 1 (the first line after the header is data row 1; blank lines are skipped) and L
is the line number an editor shows (the header is line 1 when it is the first line).
For the other formats, "row k (1-based sample number)".
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from dynid.analysis.data import plausibility as _plaus
from dynid.analysis.data._format import _fmt, _short_list
from dynid.analysis.data.record import Experiment
from dynid.analysis.data.saturation import saturation_notices
from dynid.analysis.data.timebase import _check_time, _Options, _resample, estimate_shift
from dynid.errors import DataError

if TYPE_CHECKING:
    from dynid.analysis.data.readers import _RawFile

_STEMS = ("q", "qr", "qd", "qdd", "tau", "i")
_COLUMN_RE = re.compile(r"^(?:(t)|(qdd|qd|qr|q|tau|i)([1-9][0-9]*))$", re.ASCII)
_BAD_INDEX_RE = re.compile(r"^(qdd|qd|qr|q|tau|i)(0[0-9]*)$", re.ASCII)
_CONVENTION = "see docs/formats.md, section 'Experiment data'"


# --------------------------------------------------------------------------------------
# Columns and conversions
# --------------------------------------------------------------------------------------


@dataclass
class _Col:
    """One 1-D column of a raw file (possibly column j of a 2-D array)."""

    raw: _RawFile
    name: str
    j: int | None
    data: np.ndarray

    @property
    def label(self) -> str:
        if self.j is not None:
            return f"column {self.j + 1} of array '{self.name}'"
        return f"column '{self.name}'" if self.raw.tabular else f"array '{self.name}'"

    @property
    def where(self) -> str:
        return f"{self.raw.label}, {self.label}"

    def __len__(self) -> int:
        return int(self.data.shape[0])


_RELEASED = np.empty(0)


#: Rows copied at a time by `stack_columns`: the block of the (N, n) output and of its n
#: columns stays in cache (a few hundred kB for n <= 12).
STACK_BLOCK_ROWS = 8192


def stack_columns(cols) -> np.ndarray:
    """``np.column_stack`` of equal-length 1-D columns (the same array), copied in blocks of rows.

    ``np.column_stack`` writes the (N, n) result one column at a time, a strided pass over
    all of it per column; by blocks of `STACK_BLOCK_ROWS` rows each output row is written
    while it is in cache (about 2.5x faster on a 200,000-row, 6-joint log; benchmarks/io.py)."""
    cols = [np.asarray(c) for c in cols]
    if not cols or any(c.ndim != 1 or c.shape != cols[0].shape for c in cols):
        return np.column_stack(cols)
    out = np.empty((cols[0].size, len(cols)), dtype=np.result_type(*cols))
    for i in range(0, out.shape[0], STACK_BLOCK_ROWS):
        block = out[i:i + STACK_BLOCK_ROWS]
        for j, c in enumerate(cols):
            block[:, j] = c[i:i + STACK_BLOCK_ROWS]
    return out


def _release(raws, cols) -> None:
    """Drop the raw arrays once the signals are stacked: messages after that need only the
    columns' names and row numbers, and the raw copy would be a third of the peak memory."""
    for raw in raws:
        raw.arrays = dict.fromkeys(raw.arrays, _RELEASED)
    for c in cols:
        if c is not None:
            c.data = _RELEASED


def _release_columns(raw, cols) -> None:
    for c in cols:
        if c.name in raw.arrays:
            raw.arrays[c.name] = _RELEASED
        c.data = _RELEASED


def _cell(v) -> float:
    if isinstance(v, str):
        s = v.strip()
        return float(s) if s else math.nan
    if v is None:
        return math.nan
    if isinstance(v, (bytes, bytearray)):
        s = bytes(v).decode("utf-8", "replace").strip()
        return float(s) if s else math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        if v is not v or str(v) in ("<NA>", "NaT", "nan", "None"):
            return math.nan
        raise


def _to_float(col: _Col) -> np.ndarray:
    """Float values of a column; DataError naming the first non-numeric cell."""
    a = col.data
    kind = a.dtype.kind
    if kind == "b" or (kind == "O" and col.raw.kind != "csv"  # CSV cells are text
                       and any(isinstance(v, (bool, np.bool_)) for v in a)):
        k = 0 if kind == "b" else next(i for i, v in enumerate(a) if isinstance(v, (bool, np.bool_)))
        raise DataError(
            f"{col.where}, {col.raw.row(k)}: {str(bool(a[k]))!r} is not a number (the column "
            "holds true/false values, which dynid does not read as 0/1). Store the signal "
            "as numbers."
        )
    if kind in "fiu":
        return a.astype(float, copy=False)
    if kind == "O" and col.raw.kind == "csv":
        try:  # float() of every text cell at C speed; empty cells and text need the loop
            return a.astype(float)
        except (TypeError, ValueError, OverflowError):
            pass
    if kind == "c":
        raise DataError(
            f"{col.where} holds complex numbers. Store the real values only."
        )
    if kind in "Mm":
        raise DataError(
            f"{col.where} holds dates/durations; only the time column 't' may. "
            "Store plain numbers."
        )
    if kind not in "OUS":
        raise DataError(f"{col.where} is not numeric (dtype {a.dtype}). Store plain numbers.")
    out = np.empty(a.shape[0], dtype=float)
    bad: list[int] = []
    for k, v in enumerate(a):
        try:
            out[k] = _cell(v)
        except (TypeError, ValueError, OverflowError):
            bad.append(k)
            out[k] = math.nan
    if bad:
        k = bad[0]
        text = a[k]
        if isinstance(text, str) and len(text) > 40:
            text = text[:40] + "…"
        more = f" ({len(bad)} non-numeric cells in this column)" if len(bad) > 1 else ""
        raise DataError(
            f"{col.where}, {col.raw.row(k)}: {text!r} is not a number{more}. Fix or delete "
            "that value (numbers use '.' as the decimal point; missing values must be "
            "filled or their rows removed)."
        )
    return out


def _describe_bad(col: _Col, values: np.ndarray, k: int) -> str:
    v = col.data[k]
    if isinstance(v, str) and not v.strip():
        return "an empty cell"
    if v is None:
        return "an empty cell"
    x = values[k]
    if math.isnan(x):
        return "NaN"
    return "+inf" if x > 0 else "-inf"


def _check_finite(items: list[tuple[_Col, np.ndarray]]) -> None:
    """DataError naming the column, first row and count of NaN / inf / empty cells."""
    found = []
    for order, (col, v) in enumerate(items):
        bad = ~np.isfinite(v)
        if bad.any():
            idx = np.flatnonzero(bad)
            found.append((int(idx[0]), order, col, v, idx.size))
    if not found:
        return
    found.sort(key=lambda f: (f[0], f[1]))
    k, _, col, v, count = found[0]
    msg = (
        f"{col.where}: {count} missing or non-finite value(s) (empty cell, NaN or inf); "
        f"the first is {_describe_bad(col, v, k)} at {col.raw.row(k)}."
    )
    if len(found) > 1:
        others = ", ".join(
            f"{c.label} ({n}, first at {c.raw.row(kk)})" for kk, _, c, _, n in found[1:4]
        )
        if len(found) > 4:
            others += f" and {len(found) - 4} more column(s)"
        msg += f" Also affected: {others}."
    msg += (
        " Remove those rows or fill the gaps (for example by interpolation), then load "
        "again."
    )
    raise DataError(msg)


def _time_values(col: _Col) -> tuple[np.ndarray, str | None]:
    a = col.data
    if a.dtype.kind == "M":
        if np.isnat(a).any():
            k = int(np.flatnonzero(np.isnat(a))[0])
            raise DataError(
                f"{col.where}: missing time stamp (NaT) at {col.raw.row(k)}. Remove that row."
            )
        t = (a - a[0]) / np.timedelta64(1, "s")
        note = f"{col.where}: date-time stamps converted to s since the first sample"
        return t.astype(float), note
    if a.dtype.kind == "m":
        if np.isnat(a).any():
            k = int(np.flatnonzero(np.isnat(a))[0])
            raise DataError(
                f"{col.where}: missing time (NaT) at {col.raw.row(k)}. Remove that row."
            )
        return (a / np.timedelta64(1, "s")).astype(float), f"{col.where}: durations converted to s"
    t = _to_float(col)
    # a view into the file's table (fast CSV path) would keep the whole table alive
    return (t.copy() if t.base is not None else t), None



def _span(stem: str, idx) -> str:
    idx = sorted(idx)
    if idx == list(range(1, len(idx) + 1)) and len(idx) > 2:
        return f"{stem}1..{stem}{idx[-1]}"
    return ", ".join(f"{stem}{k}" for k in idx)


def _robot_joints(robot, n_joints) -> tuple[int | None, str]:
    """Expected joint count and how to name its origin in messages."""
    if robot is not None:
        try:
            n = int(robot.n_joints)
        except (AttributeError, TypeError, ValueError):
            raise DataError(f"robot must be a Robot (dynid.load_robot(...)), a bundled robot's name or a "
                            f"robot file's path; got {type(robot).__name__} {robot!r:.60}.") from None
        name = getattr(robot, "name", "?")
        if n_joints is not None and int(n_joints) != n:
            raise DataError(
                f"n_joints = {n_joints} contradicts robot '{name}', which has {n} joints. "
                "Pass only one of them."
            )
        return n, f"robot '{name}' has {n} joints"
    if n_joints is not None:
        if (isinstance(n_joints, bool) or not isinstance(n_joints, (int, np.integer))
                or n_joints < 1):
            raise DataError(f"n_joints must be a positive whole number, got {n_joints!r}.")
        return int(n_joints), f"{int(n_joints)} joints were expected (n_joints)"
    return None, ""


def _drive_gains(robot, n: int, where: str) -> tuple[np.ndarray, str]:
    if robot is None:
        return np.ones(n), "no robot given: drive gains taken as 1"
    g = getattr(robot, "drive_gains", None)
    name = getattr(robot, "name", "?")
    if g is None:
        return np.ones(n), f"robot '{name}' has no drive gains: taken as 1"
    g = np.asarray(g, dtype=float).reshape(-1)
    if g.shape != (n,):
        raise DataError(
            f"robot '{name}' has {g.size} drive gains but {where} has {n} joints. Fix the "
            "robot description."
        )
    return g, f"drive gains of robot '{name}'"



def _assemble(
    *,
    t: np.ndarray | None,
    time_col: _Col | None,
    signals: dict[str, np.ndarray],
    opts: _Options,
    notices: list[str],
    source: str,
    meta: dict,
    shift=None,
    max_shift: int | None = None,
    min_shift: int | None = None,
    shift_where: str = "",
    robot=None,
    cols_of: dict | None = None,
    beside=None,
) -> Experiment:
    """start_offset → reference shift → plausibility (robot limits, spikes) → time checks /
    resampling → rate check → saturation.

    `cols_of`: signal → the joint columns (`_Col`) it came from, or None, for
    naming the column and row in messages. `beside`: an executor for part of the spike check
    (`plausibility.spike_notices`), which then runs beside the time and saturation checks.
    """
    n_raw = next(iter(signals.values())).shape[0]
    rows = np.arange(n_raw)
    if t is None:
        fs = float(opts.sampling_rate)
        t = opts.start_time + np.arange(n_raw) / fs
        meta["time_from"] = "sampling_rate"
        notices.append(f"no time column: t = {_fmt(opts.start_time)} s + k / {_fmt(fs)} Hz")
    else:
        meta["time_from"] = time_col.where
    if opts.start_offset:
        k = opts.start_offset
        if k > n_raw - 2:
            raise DataError(
                f"{opts.where}: start_offset = {k} leaves fewer than 2 of the {n_raw} "
                "samples. Lower start_offset."
            )
        t, rows = t[k:], rows[k:]
        signals = {s: a[k:] for s, a in signals.items()}
        notices.append(f"skipped the first {k} samples (start_offset = {k})")
        meta["start_offset"] = k
    if shift is not None and "qr" in signals:
        t, rows, signals = _shift_reference(t, rows, signals, shift, min_shift, max_shift, shift_where,
                                            notices, meta)
    _plaus.check_limits(signals, rows, robot, cols_of, source, notices)
    with _plaus.spike_notices(signals, rows, cols_of, source, beside) as spikes:
        at = len(notices)          # the spike notices go here, before the time checks' ones
        raw = dict(signals)        # the jumps are named on the rows as read, before any resampling
        t, signals, step = _time_and_rate(t, time_col, rows, signals, opts, robot, notices, meta)
        tau = signals["tau"]
        saturation_notices(tau, notices, source)
        found = spikes.result()
        _plaus.position_jumps(raw, rows, cols_of, source, found, skip=spikes.flagged(), robot=robot)
        notices[at:at] = found
    notices += _plaus.logged_derivative_notices(t, signals, cols_of, source)
    # the rate Experiment would take from the same median step of t
    fs = float(opts.sampling_rate) if time_col is None else 1.0 / step
    exp = Experiment(
        fs=fs,
        t=t,
        q=signals.get("q"),
        qr=signals.get("qr"),
        qd=signals.get("qd"),
        qdd=signals.get("qdd"),
        tau=tau,
        source=source,
        notices=notices,
        name=opts.name,
        meta=meta,
    )
    return exp


def _time_and_rate(t, time_col, rows, signals, opts, robot, notices, meta):
    """The time column's checks (and resampling), the sampling rate's and the joint speeds';
    returns (t, signals, the median time step of t or None without a time column)."""
    step = None
    if time_col is not None:
        resample, step = _check_time(t, time_col, rows, opts, notices)
        if resample:
            t, signals = _resample(t, signals, notices, time_col.where)
            meta["resampled"] = True
            step = float(np.median(np.diff(t)))
        if opts.sampling_rate is not None:
            fs_file = 1.0 / step
            if abs(fs_file - opts.sampling_rate) > opts.time_tolerance * opts.sampling_rate:
                raise DataError(
                    f"{opts.where}: sampling_rate = {_fmt(opts.sampling_rate)} Hz but the "
                    f"time column {time_col.where} gives {_fmt(fs_file)} Hz. Remove "
                    "sampling_rate (the time column is used) or correct it."
                )
    _plaus.check_rate(t, signals, robot,
                      time_col.where if time_col is not None
                      else f"{opts.where}: t (from sampling_rate)", notices, step=step)
    return t, signals, step


def _shift_reference(t, rows, signals, shift, min_shift, max_shift, shift_where, notices, meta):
    """The reference qr moved by L samples against the measured signals (`shift`: a number of
    samples, or "estimate": least squares over [min_shift, max_shift], default 0 … n/4), the
    samples without a partner dropped: (t, rows, signals), a notice and meta entries."""
    n = t.size
    if shift == "estimate":
        if "q" not in signals:
            raise DataError(
                f"{shift_where}: shift = \"estimate\" compares the reference with the "
                "measured positions, but there is no [positions] section. Add one, or "
                "give the shift as a number of samples."
            )
        lo = 0 if min_shift is None else min_shift
        hi = n // 4 if max_shift is None else max_shift
        if max(abs(lo), abs(hi)) > n // 2:
            # a few overlapping samples fit better than the true shift's many: the estimate would
            # take one and leave nothing to identify
            raise DataError(
                f"{shift_where}: min_shift / max_shift = {lo} / {hi} samples reach beyond half of the "
                f"{n} samples: an estimated shift needs most of the recording to overlap. Keep them "
                f"within ±{n // 2} (the default max_shift is {n // 4}, a quarter of the recording)."
            )
        L, _ = estimate_shift(signals["q"], signals["qr"], hi, lo)
        how = (f"estimated by least squares over shifts {max(lo, -(n - 2))}…"
               f"{min(hi, n - 2)} samples")
    else:
        L = int(shift)
        how = "as given"
        if abs(L) > n - 2:
            raise DataError(
                f"{shift_where}: shift = {L} leaves fewer than 2 of the {n} samples. "
                "Use a smaller shift."
            )
    if L > 0:
        meas, ref = slice(L, n), slice(0, n - L)
    elif L < 0:
        meas, ref = slice(0, n + L), slice(-L, n)
    else:
        meas = ref = slice(0, n)
    qr = signals["qr"][ref]
    t, rows = t[meas], rows[meas]
    signals = {s: (qr if s == "qr" else a[meas]) for s, a in signals.items()}
    rms_text = ""
    if "q" in signals:
        d = signals["q"] - signals["qr"]
        rms = float(np.sqrt(np.mean(d**2)))
        meta["reference_shift_rms"] = rms
        per = ", ".join(f"{x:.3g}" for x in np.sqrt(np.mean(d**2, axis=0)))
        rms_text = f"; RMS of q − qr after the shift {rms:.4g} rad (per joint {per})"
    meta["reference_shift"] = L
    if L >= 0:
        dropped = (f"the first {L} measured samples and the last {L} reference samples "
                   "have no partner and were dropped")
    else:
        dropped = (f"the first {-L} reference samples and the last {-L} measured samples "
                   "have no partner and were dropped")
    notices.append(
        f"reference shifted by L = {L} samples (measured q[i + L] ≈ reference[i]), "
        f"{how}{rms_text}; {dropped}"
    )
    return t, rows, signals


# --------------------------------------------------------------------------------------
# Column-format files
# --------------------------------------------------------------------------------------


def _collect_columns(raw: _RawFile, notices: list[str]) -> dict[str, _Col]:
    """Convention columns of a raw file, with 2-D npz/mat arrays expanded."""
    cols: dict[str, _Col] = {}
    origin: dict[str, str] = {}
    ignored: list[str] = []

    def add(name: str, col: _Col):
        if name in cols:
            raise DataError(
                f"{raw.label}: the column '{name}' is given twice ({origin[name]} and "
                f"{col.label}). Keep one of them."
            )
        cols[name] = col
        origin[name] = col.label

    for key in list(raw.unreadable):
        if _COLUMN_RE.match(key) or key in _STEMS:
            raise DataError(
                f"{raw.label}: array '{key}' cannot be read ({raw.unreadable[key]}). "
                "Store it as a plain numeric array (no objects, no pickles)."
            )
        ignored.append(f"'{key}' (unreadable)")

    if raw.tabular:
        for name in raw.arrays:
            if _BAD_INDEX_RE.match(name):
                _bad_index(raw, name)
            if _COLUMN_RE.match(name):
                add(name, _Col(raw, name, None, raw.arrays[name]))
            else:
                ignored.append(f"'{name}'")
    else:
        n_ref = _reference_length(raw)
        for key, a in raw.arrays.items():
            if _BAD_INDEX_RE.match(key):
                _bad_index(raw, key)
            if (_COLUMN_RE.match(key) or key in _STEMS) and _not_an_array_of_numbers(a):
                raise DataError(
                    f"{raw.label}: '{key}' is not an array of numbers ({_kind_of(a)}); store each signal as a "
                    "numeric array (in MATLAB a full double matrix: full(...), no struct, cell or sparse "
                    "matrix), or export CSV."
                )
            if _COLUMN_RE.match(key):
                if a.ndim == 2 and 1 in a.shape:
                    a = a.reshape(-1)
                if a.ndim != 1:
                    raise DataError(
                        f"{raw.label}: array '{key}' has shape {a.shape}; a single column "
                        f"needs shape (N,). Store '{key}' as a 1-D array."
                    )
                add(key, _Col(raw, key, None, a))
            elif key in _STEMS:
                if a.ndim == 1:
                    a = a[:, None]
                if a.ndim != 2:
                    raise DataError(
                        f"{raw.label}: array '{key}' has shape {a.shape}; expected (N, n), "
                        "one row per sample and one column per joint."
                    )
                if n_ref is not None and a.shape[0] != n_ref and a.shape[1] == n_ref:
                    a = a.T
                    notices.append(
                        f"{raw.label}: array '{key}' was stored as (n, N) = {a.T.shape}; "
                        "transposed to one row per sample"
                    )
                for j in range(a.shape[1]):
                    add(f"{key}{j + 1}", _Col(raw, key, j, a[:, j]))
            else:
                ignored.append(f"'{key}'" + ("" if a.ndim else " (a single number)"))
    if ignored:
        notices.append(
            f"{raw.label}: ignored {'columns' if raw.tabular else 'arrays'} not in the dynid "
            f"convention: {_short_list(ignored)} ({_CONVENTION})"
        )
    return cols


def _not_an_array_of_numbers(a: np.ndarray) -> bool:
    """A MATLAB struct or sparse matrix (scipy gives a 0-d object array), a cell (an object
    array), or a NumPy structured array: their shapes and joint counts would be read as the
    signal's."""
    if a.dtype.names is not None:
        return True
    if a.dtype != object:
        return False
    # an object array of plain numbers (a cell of scalars) is read as numbers, as before
    return a.ndim == 0 or not all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool)
                                  for v in a.flat)


def _kind_of(a: np.ndarray) -> str:
    if a.dtype.names is not None:
        return f"a structured array with fields {', '.join(a.dtype.names)}"
    if a.ndim == 0:
        return f"a {type(a.item()).__name__} object"
    return f"an array of Python objects (a MATLAB cell?) of shape {a.shape}"


def _reference_length(raw: _RawFile) -> int | None:
    a = raw.arrays.get("t")
    if a is not None and a.ndim >= 1 and a.size == max(a.shape):
        return int(a.size)
    for key, a in raw.arrays.items():
        if _COLUMN_RE.match(key) and a.ndim >= 1 and a.size == max(a.shape):
            return int(a.size)
    for key, a in raw.arrays.items():
        if key in _STEMS and a.ndim == 2:
            return int(a.shape[0])
    return None


def _bad_index(raw: _RawFile, name: str) -> None:
    m = _BAD_INDEX_RE.match(name)
    stem, digits = m.group(1), m.group(2)
    if int(digits) == 0:
        hint = (f"joints are numbered from 1 ({stem}1..{stem}n), not from 0. Renumber the "
                "columns (q0 → q1, q1 → q2, ...)")
    else:
        hint = f"write joint numbers without leading zeros ('{stem}{int(digits)}')"
    raise DataError(f"{raw.label}: column '{name}': {hint}.")


def _from_columns(raw: _RawFile, robot, n_joints, opts: _Options, source: str,
                  notices: list[str], meta: dict) -> Experiment:
    """An Experiment from a file in dynid's column format (t, q1..qn, tau1..taun ...)."""
    notices.extend(raw.notices)
    cols = _collect_columns(raw, notices)
    by_stem, present = _by_stem(cols)
    n = _joint_columns(raw, present, robot, n_joints)
    _required_signals(raw, cols, present, opts, notices)
    used = [(s, k, cols[by_stem[s][k]]) for s, idx in present.items() for k in idx]
    tcol = _check_sample_counts(raw, cols.get("t"), used)
    t, values = _column_values(tcol, used, robot, notices)
    signals, cols_of = {}, {}
    for s, idx in present.items():
        stem_cols = [cols[by_stem[s][k]] for k in idx]
        signals[s] = stack_columns([values.pop((s, k)) for k in idx])
        cols_of["tau" if s == "i" else s] = stem_cols
        _release_columns(raw, stem_cols)       # signal by signal: the peak holds one raw copy less
    _release([raw], cols.values())
    if "tau" not in signals:
        g, origin = _drive_gains(robot, n, raw.label)
        signals["tau"] = signals.pop("i") * g
        notices.append(
            f"{raw.label}: tau computed as drive gain × current (tau_j = g_j · i_j, "
            f"g = [{', '.join(_fmt(x) for x in g)}], {origin})"
        )
    return _assemble(t=t, time_col=tcol, signals=signals, opts=opts, notices=notices,
                     source=source, meta=meta, robot=robot, cols_of=cols_of, beside=raw.beside)


def _by_stem(cols: dict) -> tuple[dict, dict]:
    """({stem: {joint: column name}}, {stem: sorted joints} of the stems present)."""
    by_stem: dict[str, dict[int, str]] = {s: {} for s in _STEMS}
    for name in cols:
        m = _COLUMN_RE.match(name)
        if m.group(2):
            by_stem[m.group(2)][int(m.group(3))] = name
    return by_stem, {s: sorted(d) for s, d in by_stem.items() if d}


def _joint_columns(raw: _RawFile, present: dict, robot, n_joints) -> int | None:
    """The number of joints: every signal numbered 1..n without gaps, all with one n, the robot's."""
    for s, idx in present.items():
        missing = sorted(set(range(1, idx[-1] + 1)) - set(idx))
        if missing:
            raise DataError(
                f"{raw.label} has {_span(s, idx)} but no "
                f"{', '.join(f'{s}{k}' for k in missing)}: every signal needs one column "
                "per joint, numbered 1..n without gaps. Add the missing column(s) or "
                "renumber them."
            )
    counts = {s: len(idx) for s, idx in present.items()}
    if len(set(counts.values())) > 1:
        first = next(iter(present))
        parts = _span(first, present[first]) + " but " + ", ".join(
            _span(s, present[s]) for s in present if counts[s] != counts[first]
        )
        raise DataError(
            f"{raw.label} has {parts}: the signals disagree on the number of joints. Every "
            "signal (q, qr, qd, qdd, tau, i) needs one column per joint; add the missing "
            "columns or remove the extra ones."
        )
    n = next(iter(counts.values()), None)
    expected, who = _robot_joints(robot, n_joints)
    if expected is not None and n is not None and n != expected:
        first = next(iter(present))
        missing = f"{n + 1}" if n + 1 == expected else f"{n + 1}..{expected}"
        fix = ("remove the extra columns" if n > expected else
               f"add the columns of joint{'' if n + 1 == expected else 's'} {missing} to every signal "
               f"({', '.join(f'{stem}{missing}' for stem in present)})")
        raise DataError(
            f"{who} but {raw.label} has {_span(first, present[first])}. Load the data with "
            f"the robot it was recorded on, or {fix}."
        )
    return n


def _required_signals(raw: _RawFile, cols: dict, present: dict, opts: _Options, notices: list[str]) -> None:
    """Time (or a sampling rate), torques (or currents) and positions; tau wins over i."""
    problems = []
    if "t" not in cols and opts.sampling_rate is None:
        problems.append(
            "no time column 't' (add a column 't' in s, or describe the file in an "
            "experiment TOML with [experiment] sampling_rate)"
        )
    if "tau" not in present and "i" not in present:
        problems.append("no torque columns tau1..taun (or currents i1..in)")
    if "q" not in present and "qr" not in present:
        problems.append("no position columns q1..qn (or reference positions qr1..qrn)")
    if problems:
        found = ", ".join(f"'{k}'" for k in list(raw.arrays)[:12])
        raise DataError(
            f"{raw.label}: " + "; ".join(problems)
            + f". Columns found: {found or 'none'}. Names are case-sensitive ({_CONVENTION})."
        )
    if "tau" in present and "i" in present:
        notices.append(
            f"{raw.label}: both tau and i columns are present: tau is used, "
            f"{_span('i', present['i'])} ignored"
        )
        del present["i"]


def _check_sample_counts(raw: _RawFile, tcol, used) -> _Col | None:
    """Every column (and t) with one length of at least 2; returns the time column."""
    lengths = {len(c) for _, _, c in used}
    if tcol is not None:
        if tcol.data.ndim != 1:
            raise DataError(f"{tcol.where} must be 1-D.")
        lengths.add(len(tcol))
    if len(lengths) > 1:
        ref = tcol if tcol is not None else used[0][2]
        other = next(c for _, _, c in used if len(c) != len(ref))
        raise DataError(
            f"{raw.label}: {ref.label} has {len(ref)} samples but {other.label} has "
            f"{len(other)}. Every column needs one value per sample."
        )
    n_rows = lengths.pop()
    if n_rows < 2:
        raise DataError(
            f"{raw.label} has {n_rows} sample(s); at least 2 are needed. Export the whole "
            "recording."
        )
    return tcol


def _column_values(tcol, used, robot, notices: list[str]):
    """(t or None, {(stem, joint): float values}), checked finite and of plausible magnitude."""
    values = {}
    items = []
    t = None
    if tcol is not None:
        t, note = _time_values(tcol)
        if note:
            notices.append(note)
        items.append((tcol, t))
    for s, k, c in used:
        v = _to_float(c)
        values[(s, k)] = v
        items.append((c, v))
    if not all(c.raw.finite for c, _ in items):
        _check_finite(items)
    _plaus.check_magnitude([(c, v) for c, v in items if c is not tcol], robot)
    return t, values
