"""The fleet engine: plan the tasks, run them on Dask distributed, store each result as it arrives.

Dask is the scheduler (no process pool of dynid's own): with no address a
`LocalCluster` of worker *processes* with one thread each is started on this
machine (the kernels are NumPy and numba: processes, not threads, scale them);
with an address (`tcp://host:8786`) the run uses that cluster. One task per
recording, submitted with its store key as the Dask key; a task whose worker
dies is rescheduled by Dask on another worker (`distributed.scheduler.allowed-failures`
times), and since each task writes its result under its deterministic file
name, a retried task can neither be lost nor stored twice.

The workers write the results themselves (the store must be a folder they can
all write, as the recordings must be files they can all read): a single client
writing every result would become the bottleneck of a large cluster, and on a
small machine it would steal a core from the workers.
"""
from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass, field

import pandas as pd

from dynid.analysis.fleet import interrupt
from dynid.analysis.fleet.catalogue import (
    ROW,
    joint_temperature,
    read_catalogue,
    referenced,
    temperature_columns,
)
from dynid.analysis.fleet.store import ResultStore
from dynid.analysis.fleet.task import MAX_SAMPLES, file_hash, identify_recording, retry_failure, task_key
from dynid.analysis.results import Result
from dynid.dynamics.robot_file import is_bundled_name
from dynid.errors import InputError, OutputError, install_hint
from dynid.provenance import json_safe, versions
from dynid.ranges import check_range


def import_distributed():
    """The `distributed` module, or an InputError saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise InputError(f"the fleet runs on Dask distributed, which is not installed: {install_hint('fleet')}") from None
    return distributed


@dataclass(repr=False)
class FleetRun(Result):
    """What one run did.

    A result like the others: `summary()` (also `str()`), `to_dict()`/`to_json()` (what
    `dynid fleet --json` writes, without its per-robot table, which the report layer builds
    from the store) and `to_frame()`/`to_csv()` (the recordings that failed).
    """

    store: str
    n_recordings: int
    n_computed: int
    n_skipped: int               # already in the store under the same key
    errors: list                 # (robot_id, recording, message) of the tasks that failed this run
    wall_seconds: float
    task_seconds: list = field(default_factory=list)   # per computed task, as measured in the task
    workers: int = 0
    health: object = None        # FleetHealth, when monitored
    keys: frozenset | None = None  # the store keys of the catalogue's rows: the results the run uses
    n_unused: int = 0            # results stored for rows no longer in the catalogue (kept, not used)

    @property
    def n_failed(self) -> int:
        """Recordings of this run that could not be identified."""
        return len(self.errors)

    @property
    def n_identified(self) -> int:
        """Recordings of this run identified (computed and not failed)."""
        return self.n_computed - self.n_failed

    @property
    def notices(self) -> list:
        """What the run left aside, in words."""
        if not self.n_unused:
            return []
        return [f"{self.n_unused} result(s) in the store are of rows no longer in the catalogue (removed, or "
                f"their robot_id or path changed): not used by the monitor or the report, and left in the store"]

    def current(self, frame):
        """The rows of the store's `frame` that belong to the catalogue's current rows (all of them
        when the run does not know those)."""
        return frame if self.keys is None else frame[frame["key"].isin(self.keys)]

    def summary_line(self) -> str:
        return "\n  ".join([f"{self.n_recordings} recordings: {self.n_identified} identified, {self.n_skipped} "
                             f"already in the store, {self.n_failed} failed ({self.wall_seconds:.1f} s)"]
                            + self.notices)

    def summary(self) -> str:
        """The counts, each failed recording with its error, and the wear monitor's summary."""
        lines = [f"dynid fleet, store {self.store}", "  " + self.summary_line()]
        lines += [f"  failed: {robot} {path}: " + str(message).replace("\n", "\n    ")
                  for robot, path, message in self.errors]
        if self.health is not None:
            lines += ["  " + line for line in self.health.summary().splitlines()]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<FleetRun {self.summary_line().splitlines()[0]}>"

    def to_frame(self) -> pd.DataFrame:
        """The recordings of this run that could not be identified (`robot_id, recording, error`)."""
        return pd.DataFrame(self.errors, columns=["robot_id", "recording", "error"])

    def to_dict(self) -> dict:
        out = {"store": self.store, "n_recordings": self.n_recordings, "n_computed": self.n_computed,
               "n_identified": self.n_identified, "n_failed": self.n_failed,
               "n_skipped": self.n_skipped, "n_errors": len(self.errors),
               "errors": [{"robot_id": r, "recording": p, "error": m} for r, p, m in self.errors],
               "n_unused": self.n_unused, "notices": self.notices,
               "wall_seconds": self.wall_seconds, "workers": self.workers}
        if self.health is not None:
            out["health"] = self.health.to_dict()
        return json_safe(out)


def plan(catalogue, store: ResultStore, *, settings=None, diagnose=False, max_samples=MAX_SAMPLES):
    """(all task specs, the specs not yet in `store`) of a catalogue."""
    version = versions().get("dynid", "?")
    frame = read_catalogue(catalogue)
    options = {"settings": repr(sorted((settings or {}).items())), "diagnose": bool(diagnose),
               "max_samples": int(max_samples)}
    have = store.keys()
    specs = []
    hashes = _data_hashes(frame, catalogue)
    robots = _robot_hashes(frame, catalogue)
    for row, h in zip(frame.to_dict("records"), hashes):
        n_temps = max([int(c[11:]) for c in row if c.startswith("temperature") and c[11:].isdigit()] or [0])
        temps = [joint_temperature(row, j) for j in range(1, n_temps + 1)]
        if not temps and "temperature" in row:
            temps = [joint_temperature(row, 1)]     # one value: every joint (repeated by the store)
        ts = row["timestamp"].isoformat()
        # a robot file's content is part of the key (a bundled robot's is the dynid version's)
        robot_hash = {"robot_hash": robots[row["robot"]]} if robots[row["robot"]] else {}
        key = task_key(row["robot_id"], row["path"], h, version,
                       {**options, "robot": row["robot"], "timestamp": ts, "temperatures": repr(temps),
                        **robot_hash})
        specs.append({"key": key, "robot_id": row["robot_id"], "path": row["path"], "robot": row["robot"],
                      "timestamp": ts, "day": row["day"], "data_hash": h, "version": version,
                      "temperatures": temps, "settings": settings, "diagnose": bool(diagnose),
                      "max_samples": int(max_samples), "shared_temperature": "temperature" in row})
    return specs, [s for s in specs if s["key"] not in have]


def _label(catalogue):
    return "the catalogue" if not isinstance(catalogue, (str, os.PathLike)) else os.fspath(catalogue)


def _content_hash(path) -> str:
    """A file's hash, with those of the files it names (an experiment TOML's data file, a robot
    file's URDF) when there are any: the data behind a recording or robot, not its description."""
    h = file_hash(path)
    refs = referenced(path)
    if not refs:
        return h
    parts = [h]
    for ref in refs:
        try:
            parts.append(file_hash(ref))
        except OSError as exc:          # the task will say the file is missing
            parts.append(f"unreadable:{exc.strerror}")
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()


def _robot_hashes(frame, catalogue) -> dict:
    """Each robot of the catalogue loaded once, before any task (a bad robot file is one error,
    not one per recording on a started cluster), and its content hash ("" for a bundled robot)."""
    from dynid.dynamics.robot_file import load_robot
    from dynid.errors import DynidError
    label = _label(catalogue)
    out = {}
    for robot in dict.fromkeys(frame["robot"]):
        rows = frame.index[frame["robot"] == robot]
        try:
            n = load_robot(robot).n_joints
        except DynidError as exc:
            raise InputError(f"{label}: row {frame[ROW][rows[0]]}, robot {robot}: {exc}") from None
        for col in temperature_columns(frame):
            j = int(col[11:] or 0)
            if j > n and frame.loc[rows, col].notna().any():
                k = int(frame.loc[rows, col].notna().idxmax())
                raise InputError(f"{label}: column {col}, row {frame[ROW][k]}: the robot {robot} has {n} joints; "
                                 f"give temperature1..temperature{n}")
        out[robot] = "" if is_bundled_name(robot) else _content_hash(robot)
    return out


def _data_hashes(frame, catalogue) -> list:
    """The data hash of each row; refuses non-regular files (before reading them: a FIFO or
    /dev/zero would never end) and byte-identical copies of one recording."""
    import stat
    label = _label(catalogue)
    hashes, first = [], {}
    for k, path in enumerate(frame["path"]):
        try:
            mode = os.stat(path).st_mode
        except OSError as exc:            # the task will report it; a rerun retries once it exists
            hashes.append(f"unreadable:{exc.strerror}")
            continue
        if not stat.S_ISREG(mode):
            raise InputError(f"{label}: row {frame[ROW][k]}: the recording {path} is not a regular file (a FIFO, a "
                             f"device or a folder); give the file the data was saved to")
        try:
            h = _content_hash(path)
        except OSError as exc:
            hashes.append(f"unreadable:{exc.strerror}")
            continue
        if h in first:
            j = first[h]
            raise InputError(f"{label}: row {frame[ROW][k]}: the recording {path} has the same bytes as row "
                             f"{frame[ROW][j]}'s "
                             f"{frame['path'].iloc[j]}: a copy of one recording would be stored and counted "
                             f"twice by the wear monitor; list each recording once")
        first[h] = k
        hashes.append(h)
    return hashes


def _expand_shared(spec, result):
    # one `temperature` column stands for every joint: repeat it once the joint count is known
    if spec.get("shared_temperature") and result.get("names") and len(result["temperatures"]) == 1:
        n = max([int("".join(ch for ch in nm if ch.isdigit()) or 0) for nm in result["names"]] or [1])
        result["temperatures"] = result["temperatures"] * n
    return result


def start_client(scheduler=None, workers=None, *, quiet_interrupt=False):
    """(client, cluster or None): a Client of `scheduler`, or of a new LocalCluster of `workers`.

    `quiet_interrupt`: the local workers ignore Ctrl-C, which this process handles alone
    (`analysis.fleet.interrupt`; it changes process-wide state: for a program that ends with
    the run, such as the command line).
    """
    distributed = import_distributed()
    if scheduler:
        try:
            return distributed.Client(scheduler, timeout="20s"), None
        except OSError as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler} ({exc}); start one with "
                             f"`dask scheduler` or leave --scheduler out for a local cluster") from None
        except (ValueError, TypeError) as exc:      # not an address at all
            raise InputError(f"--scheduler (scheduler=) {scheduler!r} is not a Dask scheduler address ({exc}); "
                             f"give one such as tcp://host:8786, or leave it out for a local cluster") from None
    n = check_local_workers(workers, scheduler) or os.cpu_count() or 1
    options = dict(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40)
    if quiet_interrupt and interrupt.available():
        cluster = interrupt.start_local_cluster(distributed, **options)
    else:
        cluster = distributed.LocalCluster(**options)
    return distributed.Client(cluster), cluster


def check_local_workers(workers, scheduler=None):
    """`workers` (None for this machine's cores), refused when a local cluster of them is absurd.

    More than 4 worker processes per core only compete for memory and time; a larger
    cluster is a scheduler's (`scheduler=`), to which `workers` does not apply.
    """
    if workers is None:
        return None
    workers = check_range("workers", workers)
    cores = os.cpu_count() or 1
    if scheduler is None and workers > 4 * cores:
        raise InputError(f"--workers (workers=) {workers}: a local cluster of more than {4 * cores} worker "
                         f"processes on {cores} cores only competes for memory and time; give at most "
                         f"{4 * cores}, or a scheduler (--scheduler ADDRESS, scheduler=) for a larger cluster")
    return workers


def identify_and_store(spec: dict, store_root: str) -> dict:
    """The Dask task: identify one recording, write its result to the store, return a summary.

    A store that cannot be written (the disk is full) is the summary's `write_error`, not an
    exception: Dask would log a raised one on the worker's console before the client says it.
    """
    result = _expand_shared(spec, identify_recording(spec))
    summary = {k: result[k] for k in ("key", "status", "error", "task_seconds", "task_cpu_seconds") if k in result}
    try:
        ResultStore(store_root).write(result)
    except OutputError as exc:
        summary["write_error"] = str(exc)
    return summary


def _killed(spec: dict) -> dict:
    """The result of a task whose worker died on every try (stored as a failure to retry)."""
    return {**{k: spec[k] for k in ("key", "robot_id", "path", "robot", "timestamp", "day", "data_hash",
                                    "version")},
            "temperatures": spec["temperatures"], "task_seconds": float("nan"), "task_cpu_seconds": float("nan"),
            **retry_failure(spec, "the worker running it died on every try (out of memory? a crash in a "
                                  "native library? killed?)")}


def _stored_or_killed(store: ResultStore, spec: dict) -> dict:
    """A task whose worker died: its failure to retry, written now; or, when the worker had
    stored the task's result before dying, that result's status (the store keeps it)."""
    result = _killed(spec)
    if store.write(result).endswith(".retry.parquet"):
        return result
    stored = store.read(keys=[spec["key"]])
    status = str(stored["status"].iloc[0]) if len(stored) else "ok"
    error = stored["error"].iloc[0] if len(stored) and status != "ok" else None
    return {**result, "status": status, "error": error, "retry": False}


def execute(specs, store: ResultStore, client, *, progress=None):
    """Run `specs` on `client`; each task writes its result to `store` as it completes.

    Returns (summaries, errors): per task its key, status, error and times. A task
    that keeps killing its workers ends as a failure to retry of its recording (written
    by the client); the rest goes on. A store that cannot be written stops the run
    (its tasks cancelled) with the OutputError.
    """
    distributed = import_distributed()
    futures = client.map(identify_and_store, specs, store_root=store.root,
                         key=[f"dynid-fleet-{s['key']}" for s in specs], pure=False)
    by_key = {f.key: s for f, s in zip(futures, specs)}
    results, errors = [], []
    try:
        for done, fut in enumerate(distributed.as_completed(futures), 1):
            spec = by_key[fut.key]
            try:
                result = fut.result()
            except distributed.KilledWorker:
                result = _stored_or_killed(store, spec)
            if "write_error" in result:
                raise OutputError(result["write_error"])
            results.append(result)
            if result["status"] != "ok":
                errors.append((spec["robot_id"], spec["path"], result["error"]))
            fut.release()
            if progress is not None:
                progress(done, len(specs))
    except OutputError:
        client.cancel(futures)      # a client of someone's cluster would run them on after the run
        raise
    return results, errors


def identify_fleet(catalogue, store, *, scheduler=None, workers=None, client=None, settings=None,
                   diagnose=False, max_samples=MAX_SAMPLES, progress=None, quiet_interrupt=False) -> FleetRun:
    """Identify every recording of `catalogue` not yet in `store` (the store is updated).

    `quiet_interrupt`: as in `start_client`; an interrupted run also stops its local workers
    and closes the cluster with Dask's loggers quiet.
    """
    t0 = time.perf_counter()
    if client is None:
        workers = check_local_workers(workers, scheduler)      # before the catalogue is read
    store = store if isinstance(store, ResultStore) else ResultStore(store)
    specs, todo = plan(catalogue, store, settings=settings, diagnose=diagnose, max_samples=max_samples)
    own = None
    n_workers = 0
    if todo:
        store.check_writable()          # before the cluster starts: the workers write into it
        created = client is None
        if created:
            client, own = start_client(scheduler, workers, quiet_interrupt=quiet_interrupt)
        former = {}
        try:
            with interrupt.noted_ctrl_c() as pressed:
                try:
                    n_workers = len(client.scheduler_info().get("workers", {}))
                    results, errors = execute(todo, store, client, progress=progress)
                except RuntimeError:
                    if not pressed:
                        raise
                    raise KeyboardInterrupt from None   # Ctrl-C inside a lock of Dask's client
        except KeyboardInterrupt:
            if own is not None and quiet_interrupt:
                interrupt.stop_after_interrupt(own, former)
            raise
        finally:
            try:
                if created:     # our client of someone's scheduler is closed too, not left connected
                    client.close()
                if own is not None:
                    own.close()
            finally:
                interrupt.restore_logs(former)
    else:
        results, errors = [], []
    keys = frozenset(s["key"] for s in specs)
    return FleetRun(store=store.root, n_recordings=len(specs), n_computed=len(results),
                    n_skipped=len(specs) - len(todo), errors=errors, wall_seconds=time.perf_counter() - t0,
                    task_seconds=[r["task_seconds"] for r in results], workers=n_workers, keys=keys,
                    n_unused=len(store.unused(keys)))
