"""The fleet results store: Parquet files partitioned by robot and day (docs/formats.md, "Fleet store").

Layout: `STORE/robot_id=<id>/day=<YYYY-MM-DD>/<recording id>__<key>.parquet`, one
file per task, written to a temporary name and renamed (`dynid.outputs.staged_path`),
so a reader sees a task's result whole or not at all, and a task retried after a
worker died writes the same file again instead of a second one. `<key>`
hashes (robot, recording, data hash, dynid version, options): a rerun computes
only the tasks whose key has no file. `<recording id>` hashes (robot,
recording): when a recording's data changes, its new result replaces the old.

A failure that is not a property of the recording (its worker died, an OSError,
out of memory) is stored as `<recording id>__<key>.retry.parquet`: read with the
rest, so the report lists it as failed, but not among `keys()`, so the next run
computes the task again. Only files of these two names are the store's; anything
else in the folder is neither read nor counted.
"""
from __future__ import annotations

import glob
import hashlib
import os
import re

import numpy as np
import pandas as pd

from dynid.errors import InputError, OutputError, install_hint
from dynid.outputs import _write_error, staged_path

_FILE = re.compile(r"^([0-9a-f]{16})__([0-9a-f]{24})(\.retry)?\.parquet$")

#: columns of the store, one row per (recording, parameter); an error is one row with no parameter
COLUMNS = ["key", "robot_id", "recording", "robot", "timestamp", "day", "data_hash", "experiment_hash",
           "version", "status", "error", "n_samples", "rel_error", "parameter", "joint", "value", "sigma",
           "essential", "essential_value", "essential_sigma", "temperature", "effects", "task_seconds", "task_cpu_seconds"]
#: columns that depend on the run (machine, load), not on the inputs
RUN_COLUMNS = ("task_seconds", "task_cpu_seconds")
#: the type of every column as `result_frame` writes it (pandas' strings are `string` or `large_string`,
#: its times `[ns]` or `[us]`, by version: both are the store's); checked before the files are joined
_INTEGER_COLUMNS = ("n_samples", "joint")
_FLOAT_COLUMNS = ("rel_error", "value", "sigma", "essential_value", "essential_sigma", "temperature",
                  "task_seconds", "task_cpu_seconds")


def _pyarrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise InputError(f"the fleet results store is Parquet, which needs pyarrow: {install_hint('fleet')}") from None
    return pa, pq


def recording_id(robot_id: str, recording: str) -> str:
    return hashlib.sha256(f"{robot_id}\0{recording}".encode()).hexdigest()[:16]


def _joint_of(name: str) -> int:
    m = re.search(r"(\d+)[A-Z]?$", name)
    return int(m.group(1)) if m else 0


def result_frame(result: dict) -> pd.DataFrame:
    """The store rows of one task result (see `dynid.analysis.fleet.task.identify_recording`)."""
    temps = result.get("temperatures") or []
    common = {"key": result["key"], "robot_id": result["robot_id"], "recording": result["path"],
              "robot": result["robot"], "timestamp": pd.Timestamp(result["timestamp"]), "day": result["day"],
              "data_hash": result["data_hash"], "experiment_hash": result.get("experiment_hash", ""),
              "version": result["version"], "status": result["status"], "error": result.get("error", ""),
              "n_samples": int(result.get("n_samples", 0)), "rel_error": float(result.get("rel_error", np.nan)),
              "effects": "; ".join(result.get("effects", [])), "task_seconds": float(result["task_seconds"]),
              "task_cpu_seconds": float(result.get("task_cpu_seconds", np.nan))}
    if result["status"] != "ok":
        rows = [{**common, "parameter": "", "joint": 0, "value": np.nan, "sigma": np.nan, "essential": False,
                 "essential_value": np.nan, "essential_sigma": np.nan, "temperature": np.nan}]
    else:
        rows = []
        for k, name in enumerate(result["names"]):
            j = _joint_of(name)
            rows.append({**common, "parameter": name, "joint": j, "value": result["value"][k],
                         "sigma": result["sigma"][k], "essential": bool(result["essential"][k]),
                         "essential_value": result["essential_value"][k],
                         "essential_sigma": result["essential_sigma"][k],
                         "temperature": float(temps[j - 1]) if 0 < j <= len(temps) else np.nan})
    frame = pd.DataFrame(rows, columns=COLUMNS)
    frame["timestamp"] = pd.to_datetime(frame["timestamp"], utc=True)
    return frame


class ResultStore:
    """The Parquet results store at `root` (created on first write)."""

    def __init__(self, root):
        if os.fspath(root) == "":      # abspath would make it the current folder
            raise InputError("--out (store=) '': the folder name is empty; give --out (store=) the results "
                             "store's folder")
        self.root = os.path.abspath(os.fspath(root))
        if os.path.exists(self.root) and not os.path.isdir(self.root):
            raise InputError(f"{self.root}: the fleet store must be a folder, and this is a file")

    def check_writable(self) -> None:
        """InputError naming the store when a file cannot be created in it (read-only, no space ...)."""
        import tempfile
        try:
            os.makedirs(self.root, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=self.root, prefix=".dynid-probe-")
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise InputError(f"--out (store=) {self.root}: the results store cannot be written "
                             f"({exc.strerror or exc}); give a folder this user can write on a "
                             f"writable file system") from None

    def _files(self) -> list:
        """The store's own files (see the module's notes), found by their names."""
        pattern = os.path.join(glob.escape(self.root), "robot_id=*", "day=*", "*.parquet")
        return [f for f in glob.glob(pattern) if _FILE.match(os.path.basename(f))]

    @staticmethod
    def _key_of(path: str) -> tuple:
        """(the task key, whether it is a failure to retry) of one of the store's files."""
        m = _FILE.match(os.path.basename(path))
        return m.group(2), m.group(3) is not None

    def keys(self) -> set:
        """The keys of the tasks stored for good (one file each; a failure to retry is not one)."""
        return {key for key, retry in map(self._key_of, self._files()) if not retry}

    def unused(self, keys) -> list:
        """The store's files of tasks not among `keys`: catalogue rows removed or changed since."""
        keys = set(keys)
        return [f for f in self._files() if self._key_of(f)[0] not in keys]

    def path_for(self, result: dict) -> str:
        name = f"{recording_id(result['robot_id'], result['path'])}__{result['key']}"
        return os.path.join(self.root, f"robot_id={result['robot_id']}", f"day={result['day']}",
                            name + (".retry.parquet" if result.get("retry") else ".parquet"))

    def write(self, result: dict) -> str:
        """Write one task's result atomically; drop the recording's results under other keys.

        Raises
        ------
        OutputError
            The file cannot be written (the disk is full ...), worded as every output's.
        """
        pa, pq = _pyarrow()
        target = self.path_for(result)
        final = self.path_for({**result, "retry": False})
        if target != final and os.path.exists(final):
            return final        # a worker that died after storing its result: the result stands
        table = pa.Table.from_pandas(result_frame(result), preserve_index=False)
        try:
            os.makedirs(os.path.dirname(target), exist_ok=True)
            with staged_path(target) as tmp:
                pq.write_table(table, tmp)
            self._drop_older(result, target)
        except OutputError:
            raise
        except OSError as exc:
            raise _write_error(target, exc) from None
        return target

    def _drop_older(self, result: dict, target: str) -> None:
        # the same recording's result under an older key (data or version changed), or its failure to retry
        rid = recording_id(result["robot_id"], result["path"])
        pattern = os.path.join(glob.escape(os.path.join(self.root, f"robot_id={result['robot_id']}")), "day=*",
                               f"{rid}__*.parquet")
        for old in glob.glob(pattern):
            if old != target and _FILE.match(os.path.basename(old)):
                os.unlink(old)

    def read(self, keys=None) -> pd.DataFrame:
        """The stored rows, sorted by robot, time, recording and parameter.

        Parameters
        ----------
        keys : iterable of str, optional
            Read only the results of these tasks (a catalogue's current rows); default: all.

        Returns
        -------
        pandas.DataFrame
            One row per recording and parameter (the store's columns, empty when there is none).

        Raises
        ------
        InputError
            Naming a file of the store that cannot be read.
        """
        files = sorted(self._files())
        if keys is not None:
            keys = set(keys)
            files = [f for f in files if self._key_of(f)[0] in keys]
        if not files:
            return pd.DataFrame(columns=COLUMNS)
        pa, pq = _pyarrow()
        # each file's types checked against the store's column kinds (_read_file, _wrong_types): "permissive"
        # then only joins the widths of one kind (string and large_string, [ns] and [us] times, int32 and int64)
        table = pa.concat_tables([_read_file(pq, f) for f in files], promote_options="permissive")
        frame = table.to_pandas()
        return frame.sort_values(["robot_id", "timestamp", "recording", "parameter"],
                                 kind="stable").reset_index(drop=True)


def _read_file(pq, path: str):
    """One file of the store, as a pyarrow Table of the store's columns."""
    try:
        table = pq.ParquetFile(path).read(columns=COLUMNS)
        problem = None
    except Exception as exc:    # noqa: BLE001 - whatever pyarrow says of a damaged or foreign file
        problem = f"{type(exc).__name__}: {exc}"
    else:
        missing = [c for c in COLUMNS if c not in table.column_names]   # pyarrow leaves them out silently
        wrong = _wrong_types(table.schema) if not missing else []
        if not missing and not wrong:
            return table
        problem = "it has no column " + ", ".join(missing) if missing else "; ".join(wrong)
    raise InputError(f"{path}: this file of the fleet store cannot be read ({problem}); dynid writes its "
                     f"files whole, so it was damaged or put there by something else: move it out of the "
                     f"store, and the next run identifies its recording again")


def _expected_type(name: str) -> str:
    """The type of the store's column `name`, as a message names it."""
    if name in _INTEGER_COLUMNS:
        return "int64"
    if name in _FLOAT_COLUMNS:
        return "double"
    return {"essential": "bool", "timestamp": "timestamp[us, tz=UTC]"}.get(name, "string")


def _wrong_types(schema) -> list:
    """What is wrong with the types of the store's columns in `schema` (a file's), one text per column:
    a column of another kind than the store's, or one given twice."""
    pa, _ = _pyarrow()
    t = pa.types
    kinds = {"int64": t.is_integer, "double": t.is_floating, "bool": t.is_boolean,
             "timestamp[us, tz=UTC]": lambda ty: t.is_timestamp(ty) and ty.tz == "UTC",
             "string": lambda ty: t.is_string(ty) or t.is_large_string(ty)}     # a string_view joins neither
    wrong = []
    for name in COLUMNS:
        found = schema.get_all_field_indices(name)
        if len(found) != 1:
            wrong.append(f"its column {name} appears {len(found)} times")
            continue
        got = schema.field(found[0]).type
        want = _expected_type(name)
        if not t.is_null(got) and not kinds[want](got):     # a column of nulls only joins any type
            wrong.append(f"its column {name} is {got}, where the store's is {want}")
    return wrong
