"""The fleet results store: Parquet files partitioned by robot and day (docs/formats.md, "Fleet store").

Layout: `STORE/robot_id=<id>/day=<YYYY-MM-DD>/<recording id>__<key>.parquet`, one
file per task, written to a temporary name and renamed (`dynid.outputs.staged_path`),
so a reader sees a task's result whole or not at all, and a task retried after a
worker died writes the same file again instead of a second one. `<key>`
hashes (robot, recording, data hash, dynid version, options): a rerun computes
only the tasks whose key has no file. `<recording id>` hashes (robot,
recording): when a recording's data changes, its new result replaces the old.
"""
from __future__ import annotations

import glob
import hashlib
import os
import re

import numpy as np
import pandas as pd

from dynid.errors import InputError
from dynid.outputs import staged_path

_FILE = re.compile(r"^([0-9a-f]{16})__([0-9a-f]{24})\.parquet$")

#: columns of the store, one row per (recording, parameter); an error is one row with no parameter
COLUMNS = ["key", "robot_id", "recording", "robot", "timestamp", "day", "data_hash", "experiment_hash",
           "version", "status", "error", "n_samples", "rel_error", "parameter", "joint", "value", "sigma",
           "essential", "essential_value", "essential_sigma", "temperature", "effects", "task_seconds", "task_cpu_seconds"]
#: columns that depend on the run (machine, load), not on the inputs
RUN_COLUMNS = ("task_seconds", "task_cpu_seconds")


def _pyarrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise InputError('the fleet results store is Parquet, which needs pyarrow: pip install "dynid[fleet]"') from None
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

    def _files(self):
        return glob.glob(os.path.join(glob.escape(self.root), "robot_id=*", "day=*", "*.parquet"))

    def keys(self) -> set:
        """The keys of the tasks stored (one file each)."""
        out = set()
        for f in self._files():
            m = _FILE.match(os.path.basename(f))
            if m:
                out.add(m.group(2))
        return out

    def path_for(self, result: dict) -> str:
        return os.path.join(self.root, f"robot_id={result['robot_id']}", f"day={result['day']}",
                            f"{recording_id(result['robot_id'], result['path'])}__{result['key']}.parquet")

    def write(self, result: dict) -> str:
        """Write one task's result atomically; drop the recording's results under other keys."""
        pa, pq = _pyarrow()
        target = self.path_for(result)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        table = pa.Table.from_pandas(result_frame(result), preserve_index=False)
        with staged_path(target) as tmp:
            pq.write_table(table, tmp)
        rid = recording_id(result["robot_id"], result["path"])
        pattern = os.path.join(glob.escape(os.path.join(self.root, f"robot_id={result['robot_id']}")), "day=*",
                               f"{rid}__*.parquet")
        for old in glob.glob(pattern):
            if old != target:
                os.unlink(old)       # the same recording's result under an older key (data or version changed)
        return target

    def read(self) -> pd.DataFrame:
        """Every stored row (an empty frame with the store's columns when there is none)."""
        files = sorted(self._files())
        if not files:
            return pd.DataFrame(columns=COLUMNS)
        pa, pq = _pyarrow()
        import pyarrow.dataset as ds
        table = ds.dataset(files, format="parquet").to_table()
        frame = table.to_pandas()
        return frame.sort_values(["robot_id", "timestamp", "recording", "parameter"],
                                 kind="stable").reset_index(drop=True)
