"""The fleet catalogue: one row per recording (docs/formats.md, "Fleet catalogue").

Columns: `robot_id` (text), `timestamp` (ISO 8601, UTC when no zone is given),
`path` (the recording, relative paths are relative to the catalogue's folder),
`robot` (bundled name such as `tx40` or a robot file) and optionally the
temperatures logged with the recording: `temperature` (one value for every
joint) or `temperature1` .. `temperatureN` (degrees Celsius, per joint).
"""
from __future__ import annotations

import os
import re

import numpy as np
import pandas as pd

from dynid.errors import InputError

REQUIRED = ("robot_id", "timestamp", "path", "robot")
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
                frame = pd.read_csv(path, dtype={"robot_id": str, "path": str, "robot": str})
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
    missing = [c for c in REQUIRED if c not in frame.columns]
    if missing:
        raise InputError(f"{label}: missing column(s) {', '.join(missing)}; a fleet catalogue needs "
                         f"{', '.join(REQUIRED)} (optional: temperature or temperature1..N)")
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
        raise InputError(f"{label}: column robot_id, row {k + 1}: {frame['robot_id'].iloc[k]!r} must be letters, "
                         f"digits, '_', '.' or '-' (it names a folder of the results store)")
    ts = pd.to_datetime(frame["timestamp"], errors="coerce", utc=True)
    if ts.isna().any():
        k = int(np.argmax(ts.isna().to_numpy()))
        raise InputError(f"{label}: column timestamp, row {k + 1}: {frame['timestamp'].iloc[k]!r} is not a "
                         f"date and time; write ISO 8601 such as 2026-03-01T08:30:00Z")
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
    real = frame["path"].map(os.path.realpath)
    dup = real.duplicated()
    if dup.any():
        k = int(np.argmax(dup.to_numpy()))
        first = int(np.argmax((real == real.iloc[k]).to_numpy()))
        how = "" if frame["path"].iloc[k] == frame["path"].iloc[first] else \
            f" (as {frame['path'].iloc[first]!r} in row {first + 1}, through a link)"
        raise InputError(f"{label}: row {k + 1} repeats the recording {frame['path'].iloc[k]!r}{how}; each "
                         f"recording is listed once (stored twice, it would count twice in the wear monitor)")
    return frame.sort_values(["robot_id", "timestamp"], kind="stable").reset_index(drop=True)


#: the largest recording TOML read for the data file it refers to
_TOML_PEEK_BYTES = 1 << 20


def _referenced(path: str) -> list:
    """Files an experiment TOML names (`file`, `urdf`), relative to its folder."""
    if not path.lower().endswith(".toml"):
        return []
    try:
        if not os.path.isfile(path) or os.path.getsize(path) > _TOML_PEEK_BYTES:
            return []
        import tomllib
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except Exception:           # noqa: BLE001 - the task reports a bad file properly later
        return []
    tables = [doc] + [v for k, v in doc.items() if k == "experiment" and isinstance(v, dict)]
    return [os.path.join(os.path.dirname(path), t[key]) for t in tables for key in ("file", "urdf")
            if isinstance(t.get(key), str) and t[key] and "\0" not in t[key]]


def input_files(catalogue, frame=None) -> list:
    """`(what, path)` of every file a fleet run reads: the catalogue, each recording (and the
    data file a recording TOML names) and each robot file; for the output guard."""
    out = []
    if not isinstance(catalogue, pd.DataFrame):
        out.append(("the catalogue", os.fspath(catalogue)))
        folder = os.path.dirname(os.path.abspath(os.fspath(catalogue)))
    else:
        folder = os.getcwd()
    frame = read_catalogue(catalogue) if frame is None else frame
    for path in dict.fromkeys(frame["path"]):
        out.append(("the recording", path))
        out += [(f"the data file of {path}", ref) for ref in _referenced(path)]
    for robot in dict.fromkeys(frame["robot"]):
        for cand in dict.fromkeys([robot, os.path.join(folder, robot)]):
            if os.path.isfile(cand):
                out.append(("the robot file", cand))
                out += [(f"the file named by {cand}", ref) for ref in _referenced(cand)]
    return out
