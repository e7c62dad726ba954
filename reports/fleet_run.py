"""One fleet run: identify every new recording on Dask, monitor the friction, write the report.

What `dynid.fleet.run` and `dynid fleet` do, in that order: the identification and the
store (dynid.analysis.fleet.engine), the wear monitor (dynid.analysis.fleet.health), then
the HTML/JSON fleet report (dynid.reports.fleet_report). It sits in reports because it
writes the report; the command line imports it from here.
"""
from __future__ import annotations

import contextlib
import os

from dynid.analysis.fleet.catalogue import input_files
from dynid.analysis.fleet.engine import FleetRun, identify_fleet
from dynid.analysis.fleet.health import DEFAULT_BASELINE, DEFAULT_FALSE_ALARM_RATE, check_monitor_options, monitor
from dynid.analysis.fleet.store import ResultStore
from dynid.errors import InputError
from dynid.outputs import check_output_formats, check_outputs
from dynid.progress import task
from dynid.reports.fleet_report import write_fleet_outputs

__all__ = ["run", "read_store"]


def read_store(store, keys=None):
    """The rows of a results store, as a DataFrame (one row per recording and parameter).

    Parameters
    ----------
    store : str or path
        The results store a fleet run wrote (a folder; docs/formats.md, "Fleet").
    keys : iterable of str, optional
        Only the results of these tasks (a run's `FleetRun.keys`: its catalogue's current
        rows); default every result in the store.

    Returns
    -------
    pandas.DataFrame
        One row per recording and parameter.
    """
    return ResultStore(store).read(keys=keys)


def _check_outside_store(outputs, store: ResultStore) -> None:
    """Refuse an output in the store's folder: the store's files are its own, and a later run
    would read a file of another kind among them."""
    for label, path in outputs:
        if path is None or os.fspath(path) == "-":
            continue
        target = os.path.realpath(path)
        root = os.path.realpath(store.root)
        if os.path.commonpath([root, target]) == root:
            raise InputError(f"{label} {os.fspath(path)} is inside the results store {store.root} (--out, "
                             f"store=), which holds only the store's own files; give {label} a path outside "
                             f"that folder")


def run(catalogue, store, *, scheduler: str | None = None, workers: int | None = None, client=None,
        settings: dict | None = None, diagnose: bool = False, parameters=("Fv", "Fc"),
        false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE, n_baseline: int = DEFAULT_BASELINE,
        report: str | os.PathLike | None = None, json: str | os.PathLike | None = None,
        progress=None, quiet_interrupt: bool = False) -> FleetRun:
    """Identify every new or changed recording of `catalogue` into `store`, then monitor the fleet.

    Before any work: the monitoring options are range-checked, the store needs a folder
    name, and no output may be an input (the catalogue, a recording, a robot file; through
    links or `..` too) or lie inside the store. The monitor and the report use the stored
    results of the catalogue's current rows only; results of rows no longer in it stay in
    the store, unused (`FleetRun.notices` says how many).

    Parameters
    ----------
    catalogue : str or path
        The fleet's catalogue (CSV: one row per recording; docs/formats.md, "Fleet").
    store : str or path
        The results store: recordings already in it, unchanged, are not identified again.
    scheduler : str, optional
        Address of a running Dask scheduler (`tcp://host:8786`).
    workers : int, optional
        Without a scheduler or client: the processes of a LocalCluster (default: this
        machine's cores).
    client : distributed.Client, optional
        A Dask client to use instead.
    settings : dict, optional
        IDIM's processing overrides (fc_position, nd, ...), for every recording.
    diagnose : bool
        Also run the residual diagnosis on every recording.
    parameters : sequence of str
        The base parameters to monitor, by family (`Fv`: every joint's) or by name (`Fv2`).
    false_alarm_rate, n_baseline
        The wear monitor's options (`monitor`).
    report, json : str or path, optional
        Write the fleet report (HTML) and its JSON there.
    progress : callable, optional
        `progress(done, total)` as recordings finish; without one the run reports through
        `dynid.progress` (silenced by `dynid.progress.silence()`).
    quiet_interrupt : bool
        Local workers that ignore Ctrl-C, for a program that ends with the run (the command
        line; it changes process-wide state, see `analysis.fleet.interrupt`).

    Returns
    -------
    FleetRun
        The recordings identified, skipped and failed, and `health`, the wear monitor's alarms.

    Raises
    ------
    InputError
        An option, the catalogue or a file of the store that cannot be used (`OutputError`:
        the store or an output cannot be written, e.g. the disk is full).
    """
    check_monitor_options(parameters, false_alarm_rate, n_baseline)
    store = ResultStore(store)
    if report is not None or json is not None:
        outputs = [("--report (report=)", report), ("--json (json=)", json)]
        check_outputs(outputs, input_files(catalogue))
        check_output_formats(outputs)
        _check_outside_store(outputs, store)
    # without a caller's callable, progress goes through dynid.progress (a bar on a terminal, log
    # records elsewhere, dynid.progress.silence() to turn it off), as the other long steps do
    with contextlib.nullcontext(progress) if progress is not None else task("fleet: identifying") as bar:
        result = identify_fleet(catalogue, store, scheduler=scheduler, workers=workers, client=client,
                                settings=settings, diagnose=diagnose, progress=bar,
                                quiet_interrupt=quiet_interrupt)
    frame = store.read(keys=result.keys)
    result.health = monitor(frame, parameters, false_alarm_rate=false_alarm_rate, n_baseline=n_baseline)
    if report is not None or json is not None:
        # matplotlib and the HTML template only when a report is asked for
        write_fleet_outputs(result, frame, html=report, json_path=json)
    return result
