"""dynid at fleet scale: identify many robots' recordings on Dask and watch their friction for wear.

::

    import dynid.fleet
    run = dynid.fleet.run("catalogue.csv", "store/", workers=2, report="fleet.html")
    run.health.alarms          # robot, joint, parameter, day of onset, size of the change

Needs the `fleet` extra (`pip install "dynid[fleet]"`: Dask distributed and
pyarrow). The catalogue and store formats are in docs/formats.md; the method
(IDIM per recording, Page's CUSUM on the temperature-compensated friction) in
docs/guide.md, "Fleets".
"""
from __future__ import annotations

import os

from dynid.analysis.fleet.catalogue import read_catalogue
from dynid.analysis.fleet.engine import FleetRun, identify_fleet, plan, start_client
from dynid.analysis.fleet.health import DEFAULT_BASELINE, DEFAULT_FALSE_ALARM_RATE, FleetHealth, monitor
from dynid.analysis.fleet.simulated import simulate_fleet
from dynid.analysis.fleet.store import ResultStore

__all__ = ["run", "read_store", "monitor", "simulate_fleet", "read_catalogue", "plan", "start_client",
           "FleetRun", "FleetHealth", "ResultStore"]


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
        progress=None) -> FleetRun:
    """Identify every new or changed recording of `catalogue` into `store`, then monitor the fleet.

    `scheduler`: address of a running Dask scheduler (`tcp://host:8786`); without one a
    LocalCluster of `workers` processes (default: this machine's cores) is started, or
    `client` (a `distributed.Client`) is used. `parameters`: the base parameters to
    monitor, by family (`Fv` = every joint's) or by name (`Fv2`). `report`/`json`:
    write the fleet report. Returns the `FleetRun`, its `health` the alarms.

    Returns
    -------
    FleetRun
        What was identified, skipped or failed, the store's rows and the fleet's
        health (alarms per robot and parameter).
    """
    result = identify_fleet(catalogue, store, scheduler=scheduler, workers=workers, client=client,
                            settings=settings, diagnose=diagnose, progress=progress)
    frame = ResultStore(store).read()
    result.health = monitor(frame, parameters, false_alarm_rate=false_alarm_rate, n_baseline=n_baseline)
    if report is not None or json is not None:
        from dynid.reports.fleet_report import write_fleet_outputs
        write_fleet_outputs(result, frame, html=report, json_path=json)
    return result
