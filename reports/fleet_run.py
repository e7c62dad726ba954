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
from dynid.outputs import check_outputs
from dynid.progress import task
from dynid.reports.fleet_report import write_fleet_outputs

__all__ = ["run", "read_store"]


def read_store(store):
    """Every row of a results store, as a DataFrame (one row per recording and parameter).

    Returns
    -------
    pandas.DataFrame
        One row per recording and parameter.
    """
    return ResultStore(store).read()


def run(catalogue, store, *, scheduler: str | None = None, workers: int | None = None, client=None,
        settings: dict | None = None, diagnose: bool = False, parameters=("Fv", "Fc"),
        false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE, n_baseline: int = DEFAULT_BASELINE,
        report: str | os.PathLike | None = None, json: str | os.PathLike | None = None,
        progress=None, quiet_interrupt: bool = False) -> FleetRun:
    """Identify every new or changed recording of `catalogue` into `store`, then monitor the fleet.

    `scheduler`: address of a running Dask scheduler (`tcp://host:8786`); without one a
    LocalCluster of `workers` processes (default: this machine's cores) is started, or
    `client` (a `distributed.Client`) is used. `parameters`: the base parameters to
    monitor, by family (`Fv` = every joint's) or by name (`Fv2`). `report`/`json`:
    write the fleet report. `progress`: a callable `progress(done, total)`; without one,
    the run reports through `dynid.progress` (silenced by `dynid.progress.silence()`).
    `quiet_interrupt`: local workers that ignore Ctrl-C, for a program that ends with the
    run (the command line; it changes process-wide state, see `analysis.fleet.interrupt`).
    Returns the `FleetRun`, its `health` the alarms.

    Before any work: the monitoring options are range-checked, and no output may be
    an input (the catalogue, a recording, a robot file; through links or `..` too).

    Returns
    -------
    FleetRun
        The recordings identified, skipped and failed, and `health`, the wear monitor's alarms.
    """
    check_monitor_options(parameters, false_alarm_rate, n_baseline)
    if report is not None or json is not None:
        check_outputs([("report", report), ("json", json)], input_files(catalogue))
    # without a caller's callable, progress goes through dynid.progress (a bar on a terminal, log
    # records elsewhere, dynid.progress.silence() to turn it off), as the other long steps do
    with contextlib.nullcontext(progress) if progress is not None else task("fleet: identifying") as bar:
        result = identify_fleet(catalogue, store, scheduler=scheduler, workers=workers, client=client,
                                settings=settings, diagnose=diagnose, progress=bar,
                                quiet_interrupt=quiet_interrupt)
    frame = ResultStore(store).read()
    result.health = monitor(frame, parameters, false_alarm_rate=false_alarm_rate, n_baseline=n_baseline)
    if report is not None or json is not None:
        # matplotlib and the HTML template only when a report is asked for
        write_fleet_outputs(result, frame, html=report, json_path=json)
    return result
