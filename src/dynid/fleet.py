"""dynid at fleet scale: identify many robots' recordings on Dask and watch their friction for wear.

::

    import dynid.fleet
    run = dynid.fleet.run("catalogue.csv", "store/", workers=2, report="fleet.html")
    run.health.alarms          # robot, joint, parameter, day of onset, size of the change

Needs the `fleet` extra (`pip install ".[fleet]"` in the source folder: Dask distributed and
pyarrow). The catalogue and store formats are in docs/formats.md; the method
(IDIM per recording, Page's CUSUM on the temperature-compensated friction) in
docs/guide.md, "Fleets".
"""
from __future__ import annotations

# A facade: the names live in analysis/fleet (identification, store, monitoring) and in
# reports/fleet_run.py (run: identify, monitor, write the report), the top of the layers.
from dynid.analysis.fleet.catalogue import read_catalogue
from dynid.analysis.fleet.engine import FleetRun, plan, start_client
from dynid.analysis.fleet.health import FleetHealth, monitor
from dynid.analysis.fleet.store import ResultStore
from dynid.reports.fleet_run import read_store, run

__all__ = ["run", "read_store", "monitor", "read_catalogue", "plan", "start_client",
           "FleetRun", "FleetHealth", "ResultStore"]
