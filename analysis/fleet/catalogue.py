"""The fleet catalogue: one row per recording (docs/formats.md, "Fleet catalogue").

Columns: `robot_id` (text), `timestamp` (ISO 8601, UTC when no zone is given),
`path` (the recording), `robot` (bundled name such as `tx40` or a robot file;
relative paths of both are relative to the catalogue's folder) and optionally the
temperatures logged with the recording: `temperature` (one value for every
joint) or `temperature1` .. `temperatureN` (degrees Celsius, per joint). Other
columns are kept and not read, except near-misses of these names (`Temperature`,
`temperature0`, a name given twice), which are refused.
"""
from __future__ import annotations

import csv
import os
import re

import numpy as np
import pandas as pd

from dynid.dynamics.robot_file import bundled_robots, is_bundled_name
from dynid.errors import InputError
from dynid.outputs import referenced_files

REQUIRED = ("robot_id", "timestamp", "path", "robot")
#: the column `read_catalogue` adds: each row's 1-based number in the catalogue as given
ROW = "_catalogue_row"
_TEMP = re.compile(r"^temperature(\d*)$")
#: accepted joint temperatures, degrees Celsius: a gearbox's lubricant works from -40 to ~150 degC;
#: the margin takes sensors in the cold and a motor winding's hot spot
MIN_TEMPERATURE, MAX_TEMPERATURE = -100.0, 300.0
#: characters a robot_id may hold: it names a folder of the store
_ID_OK = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def temperature_columns(frame) -> list:
    """The catalogue's temperature columns, `temperature` first then by joint number."""
    cols = [c for c in frame.columns if _TEMP.match(str(c))]
    return sorted(cols, key=lambda c: int(_TEMP.match(c).group(1) or 0))


def joint_temperature(row, joint: int):
    """Temperature of `joint` (1-based) in a catalogue row: its own column, else `temperature`."""
    for col in (f"temperature{joint}", "temperature"):
        if col in row and row[col] is not None and np.isfinite(row[col]):
            return float(row[col])
    return float("nan")


def _check_fields(path: str) -> None:
    """No record of a CSV catalogue has more fields than its header: pandas reads a row with
    one field more as an index and shifts the row's values one column to the left."""
    with open(path, newline="", encoding="utf-8", errors="replace") as fh:
        rows = csv.reader(fh)
        header = next(rows, None)
        if header is None:
            return
        for line, rec in enumerate(rows, start=2):
            if len(rec) > len(header):      # fewer fields: pandas leaves the missing ones empty
                raise InputError(f"{path}: record {line - 1} (line {line} without quoted line breaks) has "
                                 f"{len(rec)} fields and the header {len(header)} ({', '.join(header)}); give "
                                 f"every row at most one value per column")


def _check_columns(frame, label: str) -> None:
    """Near-misses of the catalogue's column names are refused: read as other columns, they
    would be silently ignored (a temperature compensation that does not happen)."""
    cols = [str(c) for c in frame.columns]
    known = set(REQUIRED)
    for c in cols:
        twice = re.match(r"^(.*)\.(\d+)$", c)
        if twice and twice.group(1) in cols and (twice.group(1) in known or _TEMP.match(twice.group(1))):
            raise InputError(f"{label}: column {twice.group(1)} is given twice; keep one")
        if c in known or (_TEMP.match(c) and c != "temperature0"):
            continue
        plain = re.sub(r"^temperature_(\d+)$", r"temperature\1", c.strip().lower().replace(" ", "_").replace("-", "_"))
        if c == "temperature0" or plain == "temperature0":
            raise InputError(f"{label}: column {c}: joints count from 1 (temperature1 is joint 1's)")
        if (plain in known or _TEMP.match(plain)) and plain not in cols:    # a near-miss, not a second column
            raise InputError(f"{label}: column {c!r} is not read; write it {plain!r} (column names are "
                             f"lower case: {', '.join(REQUIRED)}, temperature or temperature1..N)")


def _robot_path(robot: str, folder: str) -> str:
    """A bundled robot's name as it is; a robot file's path relative to the catalogue's folder."""
    if is_bundled_name(robot):
        return robot
    return robot if os.path.isabs(robot) else os.path.normpath(os.path.join(folder, robot))


def read_catalogue(catalogue) -> pd.DataFrame:
    """The validated catalogue (a DataFrame) from a `.csv` / `.parquet` path or a DataFrame.

    Paths become absolute (relative to the catalogue's folder), timestamps UTC,
    and a `day` column (`YYYY-MM-DD`, UTC) is added. Errors name the file,
    the column and the row (1-based data row).
    """
    if isinstance(catalogue, pd.DataFrame):
        frame, label, folder = catalogue.copy(), "the catalogue", os.getcwd()
    else:
        path = os.fspath(catalogue)
        label, folder = path, os.path.dirname(os.path.abspath(path))
        ext = os.path.splitext(path)[1].lower()
        if not os.path.isfile(path):
            raise InputError(f"{path}: fleet catalogue not found; give a .csv or .parquet table with columns "
                             + ", ".join(REQUIRED))
        try:
            if ext == ".csv":
                _check_fields(path)
                # only an empty cell is missing: pandas' default also reads "NA", "nan", "None" ... as
                # missing, which made a robot called NA an empty robot_id and a "nan" temperature "not logged"
                frame = pd.read_csv(path, dtype={"robot_id": str, "path": str, "robot": str},
                                    keep_default_na=False, na_values=[""])
            elif ext == ".parquet":
                frame = pd.read_parquet(path)
            else:
                raise InputError(f"{path}: a fleet catalogue is a .csv or .parquet file, not '{ext}'")
        except InputError:
            raise
        except pd.errors.EmptyDataError:
            raise InputError(f"{path}: the fleet catalogue is empty; write a header line with the columns "
                             + ", ".join(REQUIRED) + " and one row per recording") from None
        except Exception as exc:  # pandas/pyarrow parse errors: say which file
            raise InputError(f"{path}: cannot read the fleet catalogue ({type(exc).__name__}: {exc}); it must be "
                             f"a CSV (or Parquet) table with the columns {', '.join(REQUIRED)}") from None
    _check_columns(frame, label)
    missing = [c for c in REQUIRED if c not in frame.columns]
    if missing:
        # one column whose name holds another separator: the file is not comma-separated
        sep = next((s for s in (";", "\t", "|") if len(frame.columns) == 1 and s in str(frame.columns[0])), None)
        hint = (f"; the columns seem to be separated by {sep!r}: a fleet catalogue is comma-separated"
                if sep else "")
        raise InputError(f"{label}: missing column(s) {', '.join(missing)}; a fleet catalogue needs "
                         f"{', '.join(REQUIRED)} (optional: temperature or temperature1..N){hint}")
    if frame.empty:
        raise InputError(f"{label}: the catalogue has no recordings")
    for col in ("robot_id", "path", "robot"):
        bad = frame[col].isna() | (frame[col].astype(str).str.strip() == "")
        if bad.any():
            raise InputError(f"{label}: column {col}, row {int(np.argmax(bad.to_numpy())) + 1} is empty")
        frame[col] = frame[col].astype(str).str.strip()
    bad_id = ~frame["robot_id"].map(lambda s: bool(_ID_OK.match(s)))
    if bad_id.any():
        k = int(np.argmax(bad_id.to_numpy()))
        raise InputError(f"{label}: column robot_id, row {k + 1}: {frame['robot_id'].iloc[k]!r} must start with a "
                         f"letter or digit and hold only letters, digits, '_', '.' or '-' (it names a folder "
                         f"of the results store)")
    raw = frame["timestamp"]
    if pd.api.types.is_datetime64_any_dtype(raw):       # a Parquet catalogue's timestamps
        ts = pd.to_datetime(raw, utc=True)
    else:
        # ISO 8601 only: a number (Unix seconds? milliseconds?) or 02/03/2026 (day or month first?)
        # is read by a guess, and a wrong guess puts the recording on another day, silently
        # ISO 8601 also allows a decimal comma and lower-case t and z, which pandas does not read
        ts = pd.to_datetime(raw.map(lambda v: None if pd.isna(v) else str(v).strip().replace(",", ".").upper()),
                            format="ISO8601", errors="coerce", utc=True)
    if ts.isna().any():
        k = int(np.argmax(ts.isna().to_numpy()))
        value = raw.iloc[k]
        hint = ("; a number is not read as a time (seconds or milliseconds since 1970?): convert it, e.g. "
                "pandas.to_datetime(t, unit='s', utc=True).isoformat()"
                if isinstance(value, (int, float, np.number)) and not pd.isna(value) else "")
        shown = repr(value) if isinstance(value, str) else str(value)
        raise InputError(f"{label}: column timestamp, row {k + 1}: {shown} is not an ISO 8601 date and time; "
                         f"write e.g. 2026-03-01T08:30:00Z (UTC when no offset is given){hint}")
    frame["timestamp"] = ts
    frame["day"] = ts.dt.strftime("%Y-%m-%d")
    for col in temperature_columns(frame):
        values = pd.to_numeric(frame[col], errors="coerce")
        bad = values.isna() & frame[col].notna()
        if bad.any():
            k = int(np.argmax(bad.to_numpy()))
            raise InputError(f"{label}: column {col}, row {k + 1}: {frame[col].iloc[k]!r} is not a "
                             f"temperature in degrees Celsius (leave it empty when not logged)")
        out_of_range = ~(values.isna() | ((values >= MIN_TEMPERATURE) & (values <= MAX_TEMPERATURE)))
        if out_of_range.any():
            k = int(np.argmax(out_of_range.to_numpy()))
            raise InputError(f"{label}: column {col}, row {k + 1}: {values.iloc[k]:g} is not a joint "
                             f"temperature in degrees Celsius (accepted: {MIN_TEMPERATURE:g} to "
                             f"{MAX_TEMPERATURE:g}; leave it empty when not logged)")
        frame[col] = values.astype(float)
    frame["path"] = [p if os.path.isabs(p) else os.path.normpath(os.path.join(folder, p))
                     for p in frame["path"]]
    frame["robot"] = [_robot_path(r, folder) for r in frame["robot"]]
    for k, robot in enumerate(frame["robot"]):
        if not is_bundled_name(robot) and not os.path.isfile(robot):
            raise InputError(f"{label}: column robot, row {k + 1}: the robot file {robot} does not exist "
                             f"(a relative path is relative to the catalogue's folder); give a robot file "
                             f"or one of the bundled robots: {', '.join(bundled_robots())}")
    real = frame["path"].map(os.path.realpath)
    dup = real.duplicated()
    if dup.any():
        k = int(np.argmax(dup.to_numpy()))
        first = int(np.argmax((real == real.iloc[k]).to_numpy()))
        how = "" if frame["path"].iloc[k] == frame["path"].iloc[first] else \
            f" (as {frame['path'].iloc[first]!r} in row {first + 1}, through a link)"
        raise InputError(f"{label}: row {k + 1} repeats the recording {frame['path'].iloc[k]!r}{how}; each "
                         f"recording is listed once (stored twice, it would count twice in the wear monitor)")
    frame[ROW] = np.arange(1, len(frame) + 1)       # the errors after sorting name the file's row
    return frame.sort_values(["robot_id", "timestamp"], kind="stable").reset_index(drop=True)


def referenced(path: str) -> list:
    """Files an experiment or robot TOML names (`file`, `urdf`, in any table), relative to its folder."""
    return [ref for _, ref in referenced_files(path) if "\0" not in ref]


def input_files(catalogue, frame=None) -> list:
    """`(what, path)` of every file a fleet run reads: the catalogue, each recording (and the
    data file a recording TOML names) and each robot file; for the output guard."""
    out = []
    if not isinstance(catalogue, pd.DataFrame):
        out.append(("the catalogue", os.fspath(catalogue)))
    frame = read_catalogue(catalogue) if frame is None else frame
    for path in dict.fromkeys(frame["path"]):
        out.append(("the recording", path))
        out += [(f"the data file of {path}", ref) for ref in referenced(path)]
    for robot in dict.fromkeys(frame["robot"]):
        if not is_bundled_name(robot) and os.path.isfile(robot):
            out.append(("the robot file", robot))
            out += [(f"the file named by {robot}", ref) for ref in referenced(robot)]
    return out
