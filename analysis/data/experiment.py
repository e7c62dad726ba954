"""Experiment data: loading, validating and holding one recorded robot trajectory.

Column format (CONVENTIONS.md, "Experiment data")
-------------------------------------------------
A table with one row per sample and the columns

    t                 time in s, strictly increasing
    q1 … qn           measured joint positions (rad, m for prismatic joints)
    qr1 … qrn         reference (commanded) joint positions
    qd1 … qdn         measured velocities, if logged
    qdd1 … qddn       measured accelerations, if logged
    tau1 … taun       joint torques (N·m) or forces (N)
    i1 … in           motor currents / control signals instead of torques;
                      tau = drive gain × i (the robot's ``drive_gains``)

read by :func:`load_experiment` from ``.csv``, ``.parquet``, ``.npz`` or ``.mat``.
In ``.npz`` and ``.mat`` files a key is either one column (``t``, ``q3``) or a 2-D
array ``q``, ``qr``, ``qd``, ``qdd``, ``tau`` or ``i`` of shape (N, n) that stands for
its n columns (an (n, N) array is transposed, with a notice). Names are case-sensitive.
Joints are numbered from 1 without gaps or leading zeros (``q0`` or ``q01`` is an
error, not a silently ignored column).

Rules checked on load (every failure is a :class:`dynid.errors.DataError` whose
message names the file, the column and the row, and says what to do):

* the file exists, is readable, is not empty and has a supported extension;
* ``t`` is present (unless an experiment TOML gives ``sampling_rate``), ``tau*`` or
  ``i*`` is present, and ``q*`` or ``qr*`` is present;
* no column name appears twice; every signal has the same joints 1..n without gaps,
  and n equals ``robot.n_joints`` (or ``n_joints``) when given;
* every used cell is a number (no text), finite (no empty cell, NaN or inf);
* ``t`` is strictly increasing and uniform: no time step differs from the median step
  by more than :data:`TIME_STEP_TOLERANCE` (1 %) of it. Steps longer than
  :data:`GAP_FACTOR` (1.5) × the median are reported as dropped samples or clock
  jumps. Irregular data must be resampled, e.g. with ``resample = true`` in a TOML.

Non-fatal findings go to :attr:`Experiment.notices`: ignored columns (anything not in
the convention, ``i*`` when ``tau*`` is also present), conversions (``tau = g·i``,
motor → joint side, scaling), skipped / dropped samples, resampling, the estimated
reference shift, and torque saturation (a joint whose ``|tau|`` sits at its maximum,
within a relative 1e-6, for at least :data:`SATURATION_FRACTION` (0.5 %) of the
samples in runs of at least :data:`SATURATION_MIN_RUN` (3) samples).

Row numbers in messages: for CSV, "data row k (file line L)": k counts the data rows
from 1 (the first line after the header is data row 1; blank lines are skipped) and L
is the line number an editor shows (the header is line 1 when it is the first line).
For the other formats, "row k (1-based sample number)".

Experiment description (``.toml``)
----------------------------------
For logs that are not in dynid's column format. Paths are relative to the TOML file.
All sections and keys are checked; an unknown key is an error (typos do not pass).

``[experiment]`` (these keys may also be written at the top of the file)
    ``name``            str, optional.
    ``file``            default data file for every section below. With no signal
                        section at all, this file is read in dynid's column format and
                        the options below apply to it.
    ``sampling_rate``   Hz; required when there is no time column ([time] / ``t``),
                        t = start_time + k / sampling_rate. With a time column it is
                        checked against the median step (1 %).
    ``start_time``      s, default 0, used with ``sampling_rate``.
    ``start_offset``    samples to skip at the start (default 0).
    ``resample``        bool (default false): linear interpolation of every signal onto
                        a uniform grid at the median time step, for irregular time
                        stamps. Done last, after ``start_offset`` and the reference shift.
    ``time_tolerance``  allowed relative deviation of a time step from the median
                        (default 0.01).

``[time]``: ``file``, ``column`` (or ``key``) naming a 1-D column/array in s,
``scale`` (e.g. 0.001 for ms).

Signal sections ``[positions]`` (q), ``[reference]`` (qr), ``[velocities]`` (qd),
``[accelerations]`` (qdd), ``[torques]`` (tau), ``[currents]`` (i → tau), keys:
    ``file``            data file (.csv, .parquet, .npz, .mat); default [experiment].file.
    ``columns``         list of n column names (CSV/Parquet), or of n 1-D arrays
                        (npz/mat), one per joint in joint order; or
    ``key``             one 2-D array of shape (N, n) in an npz/mat file.
    ``side``            "joint" (default) or "motor": motor-side signals are converted
                        through [transmission]: q = R⁻¹·q_m + position_offsets,
                        qd = R⁻¹·qd_m, qdd = R⁻¹·qdd_m, tau = Rᵀ·tau_m.
    ``scale``           number or list of n numbers multiplying the signal (default 1),
                        applied before the transmission.
    ``drive_gains``     ([torques], [currents]) list of n gains, signal → (motor)
                        torque, applied before the transmission. Default for
                        [currents]: ``robot.drive_gains``; for [torques]: 1.
    ``shift``           ([reference] only) 0 (default), an integer L, or "estimate":
                        pair measured q[i + L] with reference[i]. "estimate" picks the L
                        that minimises the mean square of q[i + L] − reference[i] over all
                        joints and overlapping samples, searching min_shift ≤ L ≤
                        max_shift (see below). For L > 0 the first L measured samples and the last L
                        reference samples have no partner and are dropped (for L < 0,
                        the reverse). L is recorded in the notices and in
                        ``meta["reference_shift"]``. The shift is applied to the raw
                        samples (after ``start_offset``, before resampling).
    ``min_shift``, ``max_shift``  ([reference] only) search range in samples,
                        defaults 0 and N // 4 (N after start_offset). L ≥ 0 by default
                        because the measurement follows the command. Keep the range below
                        one period of a periodic excitation: a shift by ± one period fits
                        as well (the KUKA trajectories repeat every ~1257 / ~2513 samples).

``[transmission]``  (only needed for ``side = "motor"``; see :mod:`dynid.analysis.data.transmission`)
    ``gear_ratios``     n numbers, the diagonal of R (q_motor = R · q_joint).
    ``couplings``       list of {motor = m, joint = j, ratio = r} (1-based): R[m, j] += r.
    ``position_offsets`` n numbers (rad) added to q (and a motor-side qr) after R⁻¹.

Example, the Stäubli TX40 recording (two CSV files without a time column, motor side)::

    [experiment]
    name = "Staubli TX40 excitation (FIGAROH)"
    sampling_rate = 5000.0
    [positions]
    file = "pos_read_data.csv"
    columns = ["Joint_1","Joint_2","Joint_3","Joint_4","Joint_5","Joint_6"]
    side = "motor"
    [torques]
    file = "curr_data.csv"
    columns = ["Joint_1","Joint_2","Joint_3","Joint_4","Joint_5","Joint_6"]
    side = "motor"
    drive_gains = [1,1,1,1,1,1]
    [transmission]
    gear_ratios = [32, 32, 45, -48, 45, 32]
    couplings = [{motor = 6, joint = 5, ratio = 32}]
    position_offsets = [0.0, -1.5707963267948966, 1.5707963267948966, 0.0, 0.0, 0.0]

Example, a KUKA LWR4+ npz (ROS time stamps, reference logged in the wrong unit and late)::

    [experiment]
    file = "measurements_1.npz"
    resample = true
    start_offset = 500
    [time]
    key = "times"
    [positions]
    key = "positions"
    [torques]
    key = "torques"
    [reference]
    key = "target_positions"
    scale = 57.29577951308232
    shift = "estimate"

Arrays or columns of a data file that no section uses are listed in a notice.
"""

from __future__ import annotations

import csv
import hashlib
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dynid.analysis.data import transmission as _tr
from dynid.errors import DataError

__all__ = [
    "Experiment",
    "load_experiment",
    "estimate_shift",
    "SIGNALS",
    "TIME_STEP_TOLERANCE",
    "GAP_FACTOR",
    "SATURATION_FRACTION",
    "SATURATION_MIN_RUN",
]

#: Signal names of the column convention, in the order they are stored.
SIGNALS = ("q", "qr", "qd", "qdd", "tau")
#: Largest allowed relative deviation of a time step from the median step.
TIME_STEP_TOLERANCE = 0.01
#: A time step longer than this × the median is reported as dropped samples / clock jump.
GAP_FACTOR = 1.5
#: Fraction of samples at max |tau| (in long enough runs) that triggers a saturation notice.
SATURATION_FRACTION = 0.005
#: Shortest run of consecutive samples at max |tau| that counts as saturation.
SATURATION_MIN_RUN = 3
#: Relative tolerance for "at its maximum".
SATURATION_REL_TOL = 1e-6

_EXTENSIONS = (".csv", ".parquet", ".npz", ".mat", ".toml")
_STEMS = ("q", "qr", "qd", "qdd", "tau", "i")
_COLUMN_RE = re.compile(r"^(?:(t)|(qdd|qd|qr|q|tau|i)([1-9][0-9]*))$", re.ASCII)
_BAD_INDEX_RE = re.compile(r"^(qdd|qd|qr|q|tau|i)(0[0-9]*)$", re.ASCII)
_CONVENTION = "see CONVENTIONS.md, section 'Experiment data'"
_MAX_LIST = 8


# --------------------------------------------------------------------------------------
# The Experiment object
# --------------------------------------------------------------------------------------


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _fmt_t(x: float) -> str:
    """A time value: all digits down to 0.1 ms for large (epoch) stamps."""
    return f"{x:.4f}" if abs(x) >= 1e4 else f"{x:.6g}"


@dataclass(eq=False)
class Experiment:
    """One recorded trajectory, uniformly sampled, in joint space.

    Attributes
    ----------
    t : (N,) time in s, strictly increasing, uniform within the tolerance.
    q, qr, qd, qdd : (N, n) or None, measured / reference positions, velocities,
        accelerations.
    tau : (N, n) joint torques (computed as drive gain × current when the file had
        only ``i*``).
    fs : sampling rate in Hz, 1 / median time step.
    source : the file(s) the data came from.
    notices : what the loader ignored, converted, dropped or noticed.
    name : a name for reports (from a TOML ``[experiment] name``, else the file stem).
    meta : loader facts, e.g. ``reference_shift`` (samples), ``reference_shift_rms``
        (rad), ``start_offset``, ``resampled``, ``time_from``.
    """

    t: np.ndarray
    q: np.ndarray | None = None
    qr: np.ndarray | None = None
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    tau: np.ndarray | None = None
    fs: float | None = None
    source: str = ""
    notices: list[str] = field(default_factory=list)
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1:
            raise DataError(f"Experiment.t must be 1-D, got shape {t.shape}.")
        if t.size < 2:
            raise DataError(f"An experiment needs at least 2 samples, got {t.size}.")
        self.t = t
        if self.tau is None:
            raise DataError("An experiment needs joint torques (tau); none were given.")
        n = None
        for name in SIGNALS:
            a = getattr(self, name)
            if a is None:
                continue
            a = np.asarray(a, dtype=float)
            if a.ndim == 1:
                a = a[:, None]
            if a.ndim != 2 or a.shape[0] != t.size:
                raise DataError(
                    f"Experiment.{name} has shape {a.shape}; expected ({t.size}, n) "
                    "with one row per time sample."
                )
            if n is None:
                n = a.shape[1]
            elif a.shape[1] != n:
                raise DataError(
                    f"Experiment.{name} has {a.shape[1]} columns but the other signals "
                    f"have {n}: every signal needs one column per joint."
                )
            setattr(self, name, a)
        if self.fs is None:
            step = float(np.median(np.diff(t)))
            if not step > 0:
                raise DataError("Experiment.t must be strictly increasing.")
            self.fs = 1.0 / step
        self.fs = float(self.fs)
        self.notices = list(self.notices)
        self.meta = dict(self.meta)

    # ---- sizes -----------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        """Number of joints n (columns of ``tau``)."""
        return int(self.tau.shape[1])

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.size)

    @property
    def duration(self) -> float:
        """Time span ``t[-1] - t[0]`` in s."""
        return float(self.t[-1] - self.t[0])

    @property
    def signals(self) -> tuple[str, ...]:
        """Names of the signals present, among q, qr, qd, qdd, tau."""
        return tuple(s for s in SIGNALS if getattr(self, s) is not None)

    # ---- operations ------------------------------------------------------------------
    def segment(self, t_start: float | None = None, t_end: float | None = None) -> Experiment:
        """The samples with ``t_start <= t < t_end`` as a new Experiment.

        ``None`` means the start / end of the record. The window is half-open, so
        ``segment(None, a)`` and ``segment(a, None)`` split the record without overlap
        (e.g. identification and held-out validation data).
        """
        lo = -math.inf if t_start is None else float(t_start)
        hi = math.inf if t_end is None else float(t_end)
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise DataError(
                f"segment({t_start!r}, {t_end!r}) of {self.source or 'the experiment'}: "
                "t_start must be smaller than t_end."
            )
        keep = (self.t >= lo) & (self.t < hi)
        idx = np.flatnonzero(keep)
        if idx.size < 2:
            raise DataError(
                f"segment({t_start!r}, {t_end!r}) of {self.source or 'the experiment'} "
                f"holds {idx.size} sample(s); the data span t = {_fmt_t(self.t[0])} … "
                f"{_fmt_t(self.t[-1])} s. Choose a window inside that span with at least "
                "2 samples."
            )
        sl = slice(int(idx[0]), int(idx[-1]) + 1)
        arrays = {s: (None if getattr(self, s) is None else getattr(self, s)[sl].copy())
                  for s in SIGNALS}
        meta = dict(self.meta)
        meta["segment"] = (t_start, t_end)
        return Experiment(
            t=self.t[sl].copy(),
            fs=self.fs,
            source=self.source,
            notices=self.notices
            + [f"segment t ∈ [{'start' if t_start is None else _fmt_t(lo)}, "
               f"{'end' if t_end is None else _fmt_t(hi)}) s: samples {sl.start + 1}.."
               f"{sl.stop} of {self.n_samples} kept"],
            name=self.name,
            meta=meta,
            **arrays,
        )

    def data_hash(self) -> str:
        """SHA-256 (hex) of the arrays t, q, qr, qd, qdd, tau: names, dtypes, shapes and
        little-endian bytes. Deterministic across runs and platforms; independent of
        source, notices and meta."""
        h = hashlib.sha256(b"dynid-experiment-v1\0")
        for name in ("t",) + SIGNALS:
            a = getattr(self, name)
            h.update(name.encode() + b"\0")
            if a is None:
                h.update(b"none\0")
                continue
            a = np.ascontiguousarray(a, dtype=np.dtype(a.dtype).newbyteorder("<"))
            h.update(f"{a.dtype.str}{a.shape}\0".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def to_frame(self):
        """The data as a pandas DataFrame in the column convention (t, q1.., tau1..)."""
        import pandas as pd

        cols = {"t": self.t}
        for s in SIGNALS:
            a = getattr(self, s)
            if a is not None:
                for j in range(a.shape[1]):
                    cols[f"{s}{j + 1}"] = a[:, j]
        return pd.DataFrame(cols)

    def summary(self) -> str:
        """A short text: source, N, fs, duration, signals and per-joint ranges."""
        lines = []
        title = f"Experiment '{self.name}'" if self.name else "Experiment"
        lines.append(f"{title} from {self.source or '(memory)'}")
        lines.append(
            f"  {self.n_joints} joints, {self.n_samples} samples at {self.fs:.6g} Hz "
            f"(step {1e3 / self.fs:.4g} ms), duration {self.duration:.6g} s "
            f"(t = {_fmt_t(self.t[0])} … {_fmt_t(self.t[-1])} s)"
        )
        absent = [s for s in SIGNALS if getattr(self, s) is None]
        lines.append(
            "  signals: " + ", ".join(self.signals)
            + (f" (absent: {', '.join(absent)})" if absent else "")
        )
        qd, qd_note = self.qd, ""
        if qd is None and self.q is not None:
            qd, qd_note = np.gradient(self.q, self.t, axis=0), " (from q)"
        head = f"  {'joint':>5}"
        if self.q is not None:
            head += f"  {'q min … max [rad]':>24}"
        if qd is not None:
            head += f"  {('qd min … max [rad/s]' + qd_note):>30}"
        head += f"  {'tau min … max [N·m]':>26}"
        lines.append(head)
        for j in range(self.n_joints):
            row = f"  {j + 1:>5}"
            if self.q is not None:
                row += f"  {self.q[:, j].min():>11.4g} … {self.q[:, j].max():<10.4g}"
            if qd is not None:
                row += f"  {qd[:, j].min():>14.4g} … {qd[:, j].max():<13.4g}"
            row += f"  {self.tau[:, j].min():>12.4g} … {self.tau[:, j].max():<11.4g}"
            lines.append(row)
        if self.notices:
            lines.append(f"  notices ({len(self.notices)}):")
            lines.extend(f"    - {m}" for m in self.notices)
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (
            f"Experiment(name={self.name!r}, n_joints={self.n_joints}, "
            f"n_samples={self.n_samples}, fs={self.fs:.6g}, signals={self.signals}, "
            f"source={self.source!r})"
        )


# --------------------------------------------------------------------------------------
# Raw file readers
# --------------------------------------------------------------------------------------


class _RawFile:
    """The named arrays of one data file, with the file's row-numbering convention."""

    def __init__(self, path: Path, label: str, kind: str):
        self.path = path
        self.label = label
        self.kind = kind  # csv | parquet | npz | mat
        self.arrays: dict[str, np.ndarray] = {}
        self.unreadable: dict[str, str] = {}
        self.line_of_row: list[int] | None = None
        self.notices: list[str] = []

    @property
    def tabular(self) -> bool:
        return self.kind in ("csv", "parquet")

    def row(self, k: int) -> str:
        if self.line_of_row is not None:
            return f"data row {k + 1} (file line {self.line_of_row[k]})"
        return f"row {k + 1} (1-based sample number)"

    def add(self, name: str, array, where: str) -> None:
        if name in self.arrays or name in self.unreadable:
            raise DataError(
                f"{self.label}: the column name '{name}' appears twice ({where}). "
                "Rename or delete one of them."
            )
        self.arrays[name] = array


def _check_file(path: Path, label: str) -> None:
    """Exists, is a file and is not empty (for formats read by a library)."""
    try:
        st_ = path.stat()
    except FileNotFoundError:
        rel = "" if path.is_absolute() else f" (a relative path is taken relative to {Path.cwd()})"
        raise DataError(f"{label}: file not found. Check the path{rel}.") from None
    except OSError as e:
        raise DataError(f"{label} cannot be read: {e.strerror or e}.") from None
    if path.is_dir():
        raise DataError(f"{label} is a folder, not a file. Give the data file itself.")
    if st_.st_size == 0:
        raise DataError(f"{label} is empty. Export the recording again.")


def _read_bytes(path: Path, label: str) -> bytes:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        rel = "" if path.is_absolute() else f" (a relative path is taken relative to {Path.cwd()})"
        raise DataError(f"{label}: file not found. Check the path{rel}.") from None
    except IsADirectoryError:
        raise DataError(f"{label} is a folder, not a file. Give the data file itself.") from None
    except PermissionError:
        raise DataError(f"{label} cannot be read: permission denied.") from None
    except OSError as e:
        raise DataError(f"{label} cannot be read: {e.strerror or e}.") from None
    if not data.strip():
        raise DataError(f"{label} is empty. Export the recording again.")
    return data


def _read_csv(path: Path, label: str) -> _RawFile:
    data = _read_bytes(path, label)
    if b"\0" in data:
        raise DataError(
            f"{label} is not a text file (it contains NUL bytes). Export the data as a "
            "comma-separated text file, or use the matching extension (.parquet, .npz, .mat)."
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise DataError(
            f"{label}: line {line} is not valid UTF-8 text (byte {e.start}). "
            "Save the file as UTF-8 CSV."
        ) from None
    raw = _RawFile(path, label, "csv")
    lines = re.split(r"\r\n|\r|\n", text)
    reader = csv.reader(lines)
    header: list[str] | None = None
    header_line = 0
    rows: list[list[str]] = []
    line_of_row: list[int] = []
    blank: list[int] = []
    while True:
        ln = reader.line_num + 1  # first line of the next row (quoted fields may span lines)
        try:
            row = next(reader)
        except StopIteration:
            break
        except csv.Error as e:
            raise DataError(
                f"{label}, file line {ln}: cannot be parsed as CSV ({e}). Fix that line "
                "(check the quotes)."
            ) from None
        if not row or (len(row) == 1 and not row[0].strip()):
            if header is not None:
                blank.append(ln)
            continue
        if header is None:
            header, header_line = [c.strip() for c in row], ln
            continue
        rows.append(row)
        line_of_row.append(ln)
    if header is None:
        raise DataError(f"{label} is empty. Export the recording again.")
    while header and header[-1] == "":
        header.pop()
    if not header:
        raise DataError(
            f"{label}, file line {header_line}: the header line has no column names. "
            "The first line must name the columns (t, q1..qn, tau1..taun; "
            f"{_CONVENTION})."
        )
    if len(header) == 1 and any(s in header[0] for s in (";", "\t", "|")):
        sep = next(s for s in (";", "\t", "|") if s in header[0])
        raise DataError(
            f"{label}, file line {header_line}: the columns seem to be separated by "
            f"{sep!r}; dynid reads comma-separated files. Export with ',' as the column "
            "separator and '.' as the decimal point."
        )
    if all(_is_number(h) for h in header if h):
        raise DataError(
            f"{label}, file line {header_line}: the first line holds numbers, not column "
            "names. Add a header line naming the columns (t, q1..qn, tau1..taun; "
            f"{_CONVENTION}), or describe the file in an experiment TOML."
        )
    # blank lines at the very end are normal; others are reported
    if blank and rows:
        last = line_of_row[-1]
        inner = [b for b in blank if b < last]
        if inner:
            raw.notices.append(
                f"{label}: skipped {len(inner)} blank line(s) among the data (file line(s) "
                f"{_short_list(inner)})"
            )
    if not rows:
        raise DataError(
            f"{label} has a header line but no data rows. Export the recording again."
        )
    h = len(header)
    for k, row in enumerate(rows):
        if len(row) > h:
            extra = row[h:]
            if all(not c.strip() for c in extra):
                del row[h:]
            else:
                raise DataError(
                    f"{label}, {_csv_row(line_of_row, k)}: {len(row)} values but the "
                    f"header names {h} columns. Remove the extra values, or name the "
                    "extra columns in the header."
                )
        if len(row) < h:
            raise DataError(
                f"{label}, {_csv_row(line_of_row, k)}: {len(row)} value(s) but the header "
                f"names {h} columns: the row is truncated (column '{header[len(row)]}' and "
                "after are missing). Complete or delete that line."
            )
    raw.line_of_row = line_of_row
    columns = list(zip(*rows))
    first_pos: dict[str, int] = {}
    for c, name in enumerate(header):
        if name == "":
            raw.notices.append(f"{label}: column {c + 1} has no name in the header; ignored")
            continue
        if name in first_pos:
            raise DataError(
                f"{label}, file line {header_line}: the column name '{name}' appears twice "
                f"(columns {first_pos[name] + 1} and {c + 1} of the header). Rename or "
                "delete one of them."
            )
        first_pos[name] = c
        raw.arrays[name] = np.array(columns[c], dtype=object)
    return raw


def _csv_row(line_of_row: list[int], k: int) -> str:
    return f"data row {k + 1} (file line {line_of_row[k]})"


def _is_number(s: str) -> bool:
    try:
        float(s)
    except (ValueError, TypeError):
        return False
    return True


def _read_parquet(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        import pandas as pd
    except ImportError:
        raise DataError(
            f"{label}: reading Parquet needs pandas and pyarrow: pip install pandas pyarrow"
        ) from None
    try:
        df = pd.read_parquet(path)
    except ImportError:
        raise DataError(
            f"{label}: reading Parquet files needs pyarrow. Install it with "
            "`pip install pyarrow`, or export the data as CSV."
        ) from None
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file
        raise DataError(
            f"{label} is not a readable Parquet file ({type(e).__name__}: "
            f"{str(e).splitlines()[0] if str(e) else ''}). Export it again."
        ) from None
    raw = _RawFile(path, label, "parquet")
    for c, name in enumerate(df.columns):
        sname = str(name).strip()
        s = df.iloc[:, c]
        if sname == "":
            raw.notices.append(f"{label}: column {c + 1} has no name; ignored")
            continue
        if sname in raw.arrays:
            raise DataError(
                f"{label}: the column name '{sname}' appears twice. Rename or delete one "
                "of them."
            )
        if isinstance(s.dtype, pd.DatetimeTZDtype):
            s = s.dt.tz_convert(None)
        kind = s.dtype.kind if isinstance(s.dtype, np.dtype) else None
        if kind in ("M", "m"):
            raw.arrays[sname] = s.to_numpy()
        elif pd.api.types.is_numeric_dtype(s.dtype) and not pd.api.types.is_bool_dtype(s.dtype):
            try:
                raw.arrays[sname] = s.to_numpy(dtype=float, na_value=np.nan)
            except (TypeError, ValueError):
                raw.arrays[sname] = s.to_numpy(dtype=object)
        else:
            raw.arrays[sname] = s.to_numpy(dtype=object)
    if len(df) == 0:
        raise DataError(f"{label} has columns but no rows. Export the recording again.")
    return raw


def _read_npz(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        f = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001
        raise DataError(
            f"{label} is not a readable .npz archive ({type(e).__name__}: "
            f"{str(e).splitlines()[0] if str(e) else ''}). Save it with "
            "numpy.savez(path, t=..., q=..., tau=...)."
        ) from None
    if not hasattr(f, "files"):
        raise DataError(
            f"{label} holds a single array, not an .npz archive of named arrays. Save it "
            "with numpy.savez(path, t=..., q=..., tau=...)."
        )
    raw = _RawFile(path, label, "npz")
    with f:
        for key in f.files:
            try:
                a = f[key]
            except Exception as e:  # noqa: BLE001 - object arrays, corrupt members
                first = str(e).splitlines()[0] if str(e) else ""
                raw.unreadable[key] = f"{type(e).__name__}: {first}"
                continue
            raw.arrays[key] = np.asarray(a)
    if not raw.arrays and not raw.unreadable:
        raise DataError(f"{label} holds no arrays. Save the data with numpy.savez.")
    return raw


def _read_mat(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        import scipy.io
    except ImportError:
        raise DataError(f"{label}: reading .mat files needs scipy: pip install scipy") from None
    try:
        d = scipy.io.loadmat(path, squeeze_me=True)
    except NotImplementedError:
        raise DataError(
            f"{label} is a MATLAB v7.3 (HDF5) file, which scipy cannot read. Save it "
            "from MATLAB with save(..., '-v7'), or export CSV."
        ) from None
    except Exception as e:  # noqa: BLE001
        raise DataError(
            f"{label} is not a readable MATLAB .mat file ({type(e).__name__}: "
            f"{str(e).splitlines()[0] if str(e) else ''}). Save it with save(..., '-v7')."
        ) from None
    raw = _RawFile(path, label, "mat")
    for key, a in d.items():
        if key.startswith("__"):
            continue
        raw.arrays[key] = np.asarray(a)
    if not raw.arrays:
        raise DataError(f"{label} holds no variables.")
    return raw


_READERS = {".csv": _read_csv, ".parquet": _read_parquet, ".npz": _read_npz, ".mat": _read_mat}


def _read_data_file(path: Path, label: str) -> _RawFile:
    ext = path.suffix.lower()
    if ext not in _READERS:
        raise DataError(
            f"{label}: unknown data file extension '{path.suffix}'. Supported: "
            ".csv, .parquet, .npz, .mat (and .toml experiment descriptions). If it is a "
            "comma-separated table, rename it to .csv."
        )
    return _READERS[ext](path, label)


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
    if kind in "fiub":
        return a.astype(float)
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
    return _to_float(col), None


def _short_list(items, limit: int = _MAX_LIST) -> str:
    items = list(items)
    s = ", ".join(str(x) for x in items[:limit])
    if len(items) > limit:
        s += f", … ({len(items) - limit} more)"
    return s


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
            raise DataError("The robot object has no valid n_joints.") from None
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


# --------------------------------------------------------------------------------------
# Options, time checks, shift, saturation
# --------------------------------------------------------------------------------------


@dataclass
class _Options:
    name: str = ""
    sampling_rate: float | None = None
    start_time: float = 0.0
    start_offset: int = 0
    resample: bool = False
    time_tolerance: float = TIME_STEP_TOLERANCE
    where: str = ""  # the TOML file, for messages about options


def _check_time(t: np.ndarray, col: _Col, rows: np.ndarray, opts: _Options,
                notices: list[str]) -> bool:
    """Validate the time column; True if the caller must resample."""
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
        return False
    n_off = int((dev > tol).sum())
    if opts.resample:
        notices.append(
            f"{col.where}: irregular time steps ({_fmt(dt.min() * 1e3)} … "
            f"{_fmt(dt.max() * 1e3)} ms, median {_fmt(med * 1e3)} ms; {n_off} of "
            f"{dt.size} steps off by more than {tol:.1%})." + gap_text
        )
        return True
    k = int(np.argmax(dev))
    raise DataError(
        f"{col.where}: irregular time steps: the median step is {_fmt(med * 1e3)} ms but "
        f"the step to {col.raw.row(rows[k + 1])} from the row before is {_fmt(dt[k] * 1e3)} ms "
        f"({dev[k]:.1%} off; the tolerance is {tol:.2%}). {n_off} of {dt.size} "
        f"steps are off by more than the tolerance.{gap_text} Resample the data onto a "
        "uniform time grid, or load it through an experiment TOML with `resample = true` "
        "in [experiment] (linear interpolation at the median step)."
    )


def _resample(t: np.ndarray, signals: dict[str, np.ndarray], notices: list[str]):
    med = float(np.median(np.diff(t)))
    k = int(math.floor((t[-1] - t[0]) / med * (1 + 1e-12)))
    grid = t[0] + med * np.arange(k + 1)
    grid = grid[grid <= t[-1]]
    out = {}
    for s, a in signals.items():
        out[s] = np.column_stack([np.interp(grid, t, a[:, j]) for j in range(a.shape[1])])
    notices.append(
        f"resampled {t.size} samples with irregular time steps onto a uniform grid of "
        f"{grid.size} samples at the median step {_fmt(med * 1e3)} ms "
        f"({_fmt(1 / med)} Hz) by linear interpolation"
    )
    return grid, out


def estimate_shift(measured, reference, max_shift: int | None = None,
                   min_shift: int = 0) -> tuple[int, float]:
    """Integer sample shift L with ``measured[i + L] ≈ reference[i]``, by least squares.

    Minimises the mean over joints and overlapping samples of
    ``(measured[i + L] − reference[i])²`` for ``min_shift ≤ L ≤ max_shift``.
    Defaults: ``min_shift = 0`` (causal: the measurement follows the command, never
    precedes it) and ``max_shift = N // 4`` (at least three quarters of the record
    overlap). Both are capped at ±(N − 2). The range matters for periodic excitation
    trajectories: a shift by a whole period (or minus one) fits about as well, so keep
    the range below one period. Ties go to the smallest |L|. The cross terms are
    computed by FFT; the best candidates are re-evaluated directly.

    Returns ``(L, rms)``: the shift in samples and the RMS difference at that shift.
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
    exact = sorted(((direct(int(L)), abs(int(L)), int(L)) for L in cand))
    best_cost, _, best = exact[0]
    return best, math.sqrt(max(best_cost, 0.0))


def _saturation_notices(tau: np.ndarray, notices: list[str], what: str) -> None:
    n_samples = tau.shape[0]
    for j in range(tau.shape[1]):
        x = tau[:, j]
        if x.max() == x.min():
            notices.append(
                f"joint {j + 1}: tau{j + 1} is constant ({_fmt(x[0])}) throughout {what}: "
                "check that the joint was driven and its torque logged"
            )
            continue
        a = np.abs(x)
        top = float(a.max())
        at = a >= top * (1 - SATURATION_REL_TOL)
        d = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        lens = ends - starts
        long = lens >= SATURATION_MIN_RUN
        count = int(lens[long].sum())
        if count and count >= SATURATION_FRACTION * n_samples:
            notices.append(
                f"joint {j + 1}: |tau{j + 1}| sits at its maximum {_fmt(top)} for {count} "
                f"samples ({100 * count / n_samples:.2g} % of the record, "
                f"{int(long.sum())} run(s) of ≥ {SATURATION_MIN_RUN} samples): the drive "
                "was probably saturated (current limit). Clipped torques do not follow "
                "the model: exclude those samples or excite less."
            )


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
) -> Experiment:
    """start_offset → reference shift → time checks / resampling → saturation."""
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
    if time_col is not None:
        if _check_time(t, time_col, rows, opts, notices):
            t, signals = _resample(t, signals, notices)
            meta["resampled"] = True
        if opts.sampling_rate is not None:
            fs_file = 1.0 / float(np.median(np.diff(t)))
            if abs(fs_file - opts.sampling_rate) > opts.time_tolerance * opts.sampling_rate:
                raise DataError(
                    f"{opts.where}: sampling_rate = {_fmt(opts.sampling_rate)} Hz but the "
                    f"time column {time_col.where} gives {_fmt(fs_file)} Hz. Remove "
                    "sampling_rate (the time column is used) or correct it."
                )
    tau = signals["tau"]
    _saturation_notices(tau, notices, source)
    fs = None
    if time_col is None:
        fs = float(opts.sampling_rate)
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
    notices.extend(raw.notices)
    cols = _collect_columns(raw, notices)
    by_stem: dict[str, dict[int, str]] = {s: {} for s in _STEMS}
    for name in cols:
        m = _COLUMN_RE.match(name)
        if m.group(2):
            by_stem[m.group(2)][int(m.group(3))] = name
    present = {s: sorted(d) for s, d in by_stem.items() if d}
    # gaps
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
        raise DataError(
            f"{who} but {raw.label} has {_span(first, present[first])}. Load the data with "
            "the robot it was recorded on, or remove the extra columns."
        )
    # required signals
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
    # values
    used: list[tuple[str, int, _Col]] = []
    for s, idx in present.items():
        for k in idx:
            used.append((s, k, cols[by_stem[s][k]]))
    lengths = {len(c) for _, _, c in used}
    tcol = cols.get("t")
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
    _check_finite(items)
    signals = {}
    for s, idx in present.items():
        signals[s] = np.column_stack([values[(s, k)] for k in idx])
    if "tau" not in signals:
        g, origin = _drive_gains(robot, n, raw.label)
        signals["tau"] = signals.pop("i") * g
        notices.append(
            f"{raw.label}: tau computed as drive gain × current (tau_j = g_j · i_j, "
            f"g = [{', '.join(_fmt(x) for x in g)}], {origin})"
        )
    return _assemble(t=t, time_col=tcol, signals=signals, opts=opts, notices=notices,
                     source=source, meta=meta)


# --------------------------------------------------------------------------------------
# TOML experiment descriptions
# --------------------------------------------------------------------------------------

_EXPERIMENT_KEYS = {"name", "file", "sampling_rate", "start_time", "start_offset",
                    "resample", "time_tolerance"}
_SECTIONS = {"positions": "q", "reference": "qr", "velocities": "qd",
             "accelerations": "qdd", "torques": "tau", "currents": "i"}
_SECTION_KEYS = {"file", "key", "columns", "side", "scale"}
_EXTRA_KEYS = {"torques": {"drive_gains"}, "currents": {"drive_gains"},
               "reference": {"shift", "max_shift", "min_shift"}}
_TIME_KEYS = {"file", "key", "column", "scale"}
_TRANSMISSION_KEYS = {"gear_ratios", "couplings", "position_offsets"}


class _Toml:
    """Typed access to a parsed TOML with messages naming file, section and key."""

    def __init__(self, label: str):
        self.label = label

    def err(self, section: str | None, msg: str) -> DataError:
        where = f"{self.label}, [{section}]" if section else self.label
        return DataError(f"{where}: {msg}")

    def check_keys(self, section: str, table: dict, allowed: set[str]) -> None:
        if not isinstance(table, dict):
            raise self.err(None, f"'{section}' must be a table [{section}], got {table!r}.")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.err(
                section,
                f"unknown key(s) {', '.join(repr(u) for u in unknown)}. Allowed: "
                f"{', '.join(sorted(allowed))} (see analysis/experiment.py for the schema).",
            )

    def string(self, section, table, key, default=None):
        v = table.get(key, default)
        if v is not None and not isinstance(v, str):
            raise self.err(section, f"{key} must be a string, got {v!r}.")
        return v

    def number(self, section, table, key, default=None, positive=False):
        v = table.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(section, f"{key} must be a finite number, got {v!r}.")
        if positive and not v > 0:
            raise self.err(section, f"{key} must be positive, got {v!r}.")
        return float(v)

    def integer(self, section, table, key, default=None, minimum=None):
        v = table.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(section, f"{key} must be a whole number, got {v!r}.")
        if minimum is not None and v < minimum:
            raise self.err(section, f"{key} must be ≥ {minimum}, got {v}.")
        return v

    def numbers(self, section, table, key, n=None):
        v = table.get(key)
        if v is None:
            return None
        if not isinstance(v, list) or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in v
        ):
            raise self.err(section, f"{key} must be a list of numbers, got {v!r}.")
        if n is not None and len(v) != n:
            raise self.err(
                section, f"{key} has {len(v)} entries but there are {n} joints; give one per joint."
            )
        return np.asarray(v, dtype=float)


def _load_toml(path: Path, label: str, robot, n_joints) -> Experiment:
    data = _read_bytes(path, label)
    try:
        doc = tomllib.loads(data.decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise DataError(f"{label} is not UTF-8 text. Save it as UTF-8.") from None
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{label} is not valid TOML: {e}. Fix the syntax there.") from None
    tk = _Toml(label)
    base = path.parent

    # --- [experiment], optionally at the top level
    top = {k: v for k, v in doc.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in doc.items() if isinstance(v, dict)}
    allowed_tables = {"experiment", "time", "transmission"} | set(_SECTIONS)
    unknown = sorted(set(tables) - allowed_tables)
    if unknown:
        raise tk.err(
            None,
            f"unknown section(s) {', '.join(f'[{u}]' for u in unknown)}. Allowed: "
            f"{', '.join(f'[{a}]' for a in sorted(allowed_tables))}.",
        )
    unknown = sorted(set(top) - _EXPERIMENT_KEYS)
    if unknown:
        raise tk.err(
            None,
            f"unknown top-level key(s) {', '.join(repr(u) for u in unknown)}. Allowed: "
            f"{', '.join(sorted(_EXPERIMENT_KEYS))} (or put them under [experiment]).",
        )
    exp = dict(tables.get("experiment", {}))
    tk.check_keys("experiment", exp, _EXPERIMENT_KEYS)
    both = sorted(set(top) & set(exp))
    if both:
        raise tk.err(
            None, f"{', '.join(both)} given both at the top and in [experiment]; keep one."
        )
    exp.update(top)
    S = "experiment"
    opts = _Options(
        name=tk.string(S, exp, "name", "") or path.stem,
        sampling_rate=tk.number(S, exp, "sampling_rate", positive=True),
        start_time=tk.number(S, exp, "start_time", 0.0),
        start_offset=tk.integer(S, exp, "start_offset", 0, minimum=0),
        resample=exp.get("resample", False),
        time_tolerance=tk.number(S, exp, "time_tolerance", TIME_STEP_TOLERANCE, positive=True),
        where=f"{label}, [experiment]",
    )
    if not isinstance(opts.resample, bool):
        raise tk.err(S, f"resample must be true or false, got {opts.resample!r}.")
    default_file = tk.string(S, exp, "file")
    notices: list[str] = []
    meta: dict = {"description": label}

    def resolve(f: str) -> tuple[Path, str]:
        p = Path(f)
        if not p.is_absolute():
            p = base / p
        return p, str(p)

    sections = {s: tables[s] for s in _SECTIONS if s in tables}
    if not sections and "time" not in tables:
        # the data file is in dynid's column format
        if default_file is None:
            raise tk.err(
                None,
                "describes no data. Give [experiment] file = \"...\" (a file in dynid's "
                "column format) or [positions] / [torques] sections.",
            )
        if "transmission" in tables:
            raise tk.err(
                "transmission",
                "applies to [positions] / [torques] sections with side = \"motor\"; this "
                "file has none.",
            )
        p, plabel = resolve(default_file)
        if p.suffix.lower() == ".toml":
            raise tk.err(S, "file must be a data file, not another TOML.")
        raw = _read_referenced(p, plabel, f"{label}, [experiment]")
        return _from_columns(raw, robot, n_joints, opts, f"{label} (data: {plabel})", notices, meta)

    # --- signal sections
    raws: dict[str, _RawFile] = {}
    used_names: dict[str, set[str]] = {}

    def raw_for(section: str, table: dict) -> _RawFile:
        f = tk.string(section, table, "file", default_file)
        if f is None:
            raise tk.err(section, "no data file: give file = \"...\" here or in [experiment].")
        p, plabel = resolve(f)
        if plabel not in raws:
            raws[plabel] = _read_referenced(p, plabel, f"{label}, [{section}]")
            used_names[plabel] = set()
            notices.extend(raws[plabel].notices)
        return raws[plabel]

    def available(raw: _RawFile) -> str:
        names = list(raw.arrays)
        return _short_list([f"'{x}'" for x in names], 15)

    def select(section: str, table: dict, single: bool = False) -> list[_Col]:
        raw = raw_for(section, table)
        key = table.get("key")
        cols = table.get("columns")
        if single:
            key2 = table.get("column")
            if key is not None and key2 is not None:
                raise tk.err(section, "give either key or column, not both.")
            key = key if key is not None else key2
            if key is None:
                raise tk.err(section, "name the time column: column = \"...\" (or key = \"...\").")
            if not isinstance(key, str):
                raise tk.err(section, f"column must be a string, got {key!r}.")
        else:
            if (key is None) == (cols is None):
                raise tk.err(
                    section,
                    "give exactly one of columns = [\"...\", ...] (one column per joint) "
                    "or key = \"...\" (a 2-D array of shape (N, n) in an npz/mat file).",
                )
        if cols is not None:
            if not isinstance(cols, list) or not cols or not all(isinstance(c, str) for c in cols):
                raise tk.err(section, f"columns must be a non-empty list of names, got {cols!r}.")
            dup = sorted({c for c in cols if cols.count(c) > 1})
            if dup:
                raise tk.err(section, f"columns lists {', '.join(map(repr, dup))} twice.")
            out = []
            for c in cols:
                out.append(_lookup(raw, c, section, tk, available, one_d=True))
                used_names[raw.label].add(c)
            return out
        if not isinstance(key, str):
            raise tk.err(section, f"key must be a string, got {key!r}.")
        if raw.tabular and not single:
            raise tk.err(
                section,
                f"key = {key!r}: {raw.label} is a table; name its columns with "
                "columns = [\"...\", ...], one per joint.",
            )
        col = _lookup(raw, key, section, tk, available, one_d=single)
        used_names[raw.label].add(key)
        if single:
            return [col]
        a = col.data
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2:
            raise tk.err(
                section,
                f"array '{key}' of {raw.label} has shape {a.shape}; expected (N, n), one row "
                "per sample and one column per joint.",
            )
        return [_Col(raw, key, j, a[:, j]) for j in range(a.shape[1])]

    # time
    time_col = None
    t = None
    if "time" in tables:
        tt = tables["time"]
        tk.check_keys("time", tt, _TIME_KEYS)
        time_col = select("time", tt, single=True)[0]
        t, note = _time_values(time_col)
        if note:
            notices.append(note)
        _check_finite([(time_col, t)])
        tscale = tk.number("time", tt, "scale", 1.0, positive=True)
        if tscale != 1.0:
            t = t * tscale
            notices.append(f"time scaled by {_fmt(tscale)} ([time] scale)")
    elif opts.sampling_rate is None:
        raise tk.err(
            None,
            "no time: give [experiment] sampling_rate = ... (Hz) or a [time] section naming "
            "the time column.",
        )

    if "torques" not in sections and "currents" not in sections:
        raise tk.err(None, "no [torques] (or [currents]) section: torques are required.")
    if "torques" in sections and "currents" in sections:
        raise tk.err(None, "give either [torques] or [currents], not both.")
    if "positions" not in sections and "reference" not in sections:
        raise tk.err(None, "no [positions] (or [reference]) section: positions are required.")

    values: dict[str, np.ndarray] = {}
    sides: dict[str, str] = {}
    section_cols: dict[str, list[_Col]] = {}
    for s, table in sections.items():
        tk.check_keys(s, table, _SECTION_KEYS | _EXTRA_KEYS.get(s, set()))
        cols = select(s, table)
        items = [(c, _to_float(c)) for c in cols]
        _check_finite(items)
        values[s] = np.column_stack([v for _, v in items])
        section_cols[s] = cols
        side = tk.string(s, table, "side", "joint")
        if side not in ("joint", "motor"):
            raise tk.err(s, f"side must be \"joint\" or \"motor\", got {side!r}.")
        sides[s] = side

    # joint counts
    ns = {s: v.shape[1] for s, v in values.items()}
    if len(set(ns.values())) > 1:
        raise tk.err(
            None,
            "the sections disagree on the number of joints: "
            + ", ".join(f"[{s}] has {k}" for s, k in ns.items())
            + ". Give one column per joint in every section.",
        )
    n = next(iter(ns.values()))
    expected, who = _robot_joints(robot, n_joints)
    if expected is not None and n != expected:
        s0 = next(iter(values))
        raise DataError(
            f"{who} but {label} gives {n} columns in [{s0}] ({section_cols[s0][0].raw.label}). "
            "Load the data with the robot it was recorded on, or fix the column lists."
        )
    # lengths
    lens = {s: v.shape[0] for s, v in values.items()}
    if time_col is not None:
        lens["time"] = t.size
    if len(set(lens.values())) > 1:
        raise tk.err(
            None,
            "the sections have different numbers of samples: "
            + ", ".join(
                f"[{s}] {k} ({(time_col if s == 'time' else section_cols[s][0]).raw.label})"
                for s, k in lens.items()
            )
            + ". Every signal needs one value per sample.",
        )
    if next(iter(lens.values())) < 2:
        raise tk.err(None, "the data have fewer than 2 samples.")

    # scale and gains
    for s, table in sections.items():
        sc = table.get("scale")
        if sc is not None:
            if isinstance(sc, list):
                sc = tk.numbers(s, table, "scale", n)
            else:
                sc = tk.number(s, table, "scale")
            values[s] = values[s] * sc
            notices.append(f"[{s}] scaled by {sc if np.isscalar(sc) else list(sc)}")
        if s in ("torques", "currents"):
            g = tk.numbers(s, table, "drive_gains", n)
            if g is None and s == "currents":
                g, origin = _drive_gains(robot, n, label)
                notices.append(
                    f"[currents]: torque = drive gain × current, g = "
                    f"[{', '.join(_fmt(x) for x in g)}] ({origin})"
                )
            elif g is not None:
                notices.append(
                    f"[{s}]: drive gains [{', '.join(_fmt(x) for x in g)}] applied "
                    "(signal → torque)"
                )
            if g is not None:
                values[s] = values[s] * g

    # transmission
    motor = [s for s in sections if sides[s] == "motor"]
    R = offsets = None
    if "transmission" in tables:
        tr = tables["transmission"]
        tk.check_keys("transmission", tr, _TRANSMISSION_KEYS)
        if "gear_ratios" not in tr:
            raise tk.err("transmission", "gear_ratios is required (one per joint).")
        ratios = tk.numbers("transmission", tr, "gear_ratios", n)
        couplings = tr.get("couplings", [])
        if not isinstance(couplings, list):
            raise tk.err("transmission", f"couplings must be a list, got {couplings!r}.")
        try:
            R = _tr.reduction_matrix(list(ratios), couplings)
        except DataError as e:
            raise tk.err("transmission", str(e)) from None
        offsets = tk.numbers("transmission", tr, "position_offsets", n)
        if not motor:
            notices.append(
                f"{label}: [transmission] given but no section has side = \"motor\"; unused"
            )
    if motor and R is None:
        raise tk.err(
            motor[0],
            "side = \"motor\" needs a [transmission] section (gear_ratios, couplings, "
            "position_offsets) to convert to the joint side.",
        )
    for s in motor:
        if s in ("positions", "reference"):
            values[s] = _tr.joint_from_motor_positions(values[s], R, offsets)
            how = "q = R⁻¹·q_motor" + (" + position_offsets" if offsets is not None else "")
        elif s in ("velocities", "accelerations"):
            values[s] = _tr.joint_from_motor_velocities(values[s], R)
            how = "R⁻¹·(motor signal)"
        else:
            values[s] = _tr.joint_from_motor_torques(values[s], R)
            how = "tau = Rᵀ·tau_motor"
        notices.append(f"[{s}]: motor side converted to joint side, {how}")

    # unused data
    for plabel, raw in raws.items():
        unused = [k for k in raw.arrays if k not in used_names[plabel]]
        unused += [k for k in raw.unreadable]
        if unused:
            notices.append(
                f"{plabel}: not used by {label}: {_short_list([repr(u) for u in unused])}"
            )

    signals = {_SECTIONS[s]: v for s, v in values.items()}
    if "i" in signals:
        signals["tau"] = signals.pop("i")
    shift = max_shift = min_shift = None
    if "reference" in sections:
        rt = sections["reference"]
        shift = rt.get("shift", 0)
        if not (shift == "estimate" or (isinstance(shift, int) and not isinstance(shift, bool))):
            raise tk.err(
                "reference",
                f"shift must be a whole number of samples or \"estimate\", got {shift!r}.",
            )
        max_shift = tk.integer("reference", rt, "max_shift", None)
        min_shift = tk.integer("reference", rt, "min_shift", None)
        if min_shift is not None and max_shift is not None and min_shift > max_shift:
            raise tk.err("reference", f"min_shift = {min_shift} exceeds max_shift = {max_shift}.")
        if shift == 0:
            shift = None
    files = ", ".join(raws)
    return _assemble(
        t=t, time_col=time_col, signals=signals, opts=opts, notices=notices,
        source=f"{label} (data: {files})", meta=meta, shift=shift, max_shift=max_shift,
        min_shift=min_shift,
        shift_where=f"{label}, [reference]",
    )


def _read_referenced(p: Path, plabel: str, where: str) -> _RawFile:
    """Read a data file named in a TOML; errors also say where the name came from."""
    try:
        return _read_data_file(p, plabel)
    except DataError as e:
        hint = (" Paths in an experiment TOML are relative to the TOML file's folder."
                if "not found" in str(e) else "")
        raise DataError(f"{where} names a data file that cannot be used: {e}{hint}") from None


def _lookup(raw: _RawFile, name: str, section: str, tk: _Toml, available, one_d: bool) -> _Col:
    if name in raw.unreadable:
        raise tk.err(
            section,
            f"array '{name}' of {raw.label} cannot be read ({raw.unreadable[name]}). Store "
            "it as a plain numeric array.",
        )
    if name not in raw.arrays:
        raise tk.err(
            section,
            f"{raw.label} has no {'column' if raw.tabular else 'array'} '{name}'. "
            f"Available: {available(raw)}.",
        )
    a = raw.arrays[name]
    if one_d:
        if a.ndim == 2 and 1 in a.shape:
            a = a.reshape(-1)
        if a.ndim != 1:
            raise tk.err(
                section,
                f"'{name}' of {raw.label} has shape {a.shape}; a single column of shape "
                "(N,) is needed here (use key = ... for a 2-D array).",
            )
    return _Col(raw, name, None, a)


# --------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------


def load_experiment(path, robot=None, *, n_joints: int | None = None) -> Experiment:
    """Read and validate an experiment file.

    Parameters
    ----------
    path:
        ``.csv``, ``.parquet``, ``.npz`` or ``.mat`` in dynid's column format, or a
        ``.toml`` experiment description (schema in this module's docstring).
    robot:
        Optional robot; only ``n_joints``, ``name`` and ``drive_gains`` are used (the
        joint count is checked; currents ``i*`` become torques through the gains).
    n_joints:
        Expected joint count when no robot is given.

    Returns
    -------
    Experiment

    Raises
    ------
    DataError
        For every problem with the file, with a message naming the file, column and row.
    """
    try:
        p = Path(path)
    except TypeError:
        raise DataError(f"load_experiment needs a file path, got {path!r}.") from None
    label = str(path)
    ext = p.suffix.lower()
    if ext == ".toml":
        return _load_toml(p, label, robot, n_joints)
    if ext not in _READERS:
        if not p.exists():
            raise DataError(
                f"{label}: file not found (and '{p.suffix}' is not a supported extension: "
                ".csv, .parquet, .npz, .mat, .toml)."
            )
        raise DataError(
            f"{label}: unknown extension '{p.suffix}'. Supported: .csv, .parquet, .npz, "
            ".mat, .toml. If it is a comma-separated table, rename it to .csv."
        )
    raw = _read_data_file(p, label)
    opts = _Options(name=p.stem, where=label)
    return _from_columns(raw, robot, n_joints, opts, label, [], {})
