"""Experiment data: the `Experiment` record and `load_experiment`.

`load_experiment` reads one recorded robot trajectory, checks it and returns an
`Experiment`. The file formats, column names, units and the experiment TOML
schema are documented in docs/formats.md. The loader is split by concept:

* `dynid.analysis.data.record`: the `Experiment` record itself (re-exported here);
* `dynid.analysis.data.readers`: CSV / Parquet / npz / MAT file → raw named columns;
* `dynid.analysis.data.columns`: column names, parsing to numbers, finite /
  joint-count checks, assembling an Experiment;
* `dynid.analysis.data.saturation`: the torque saturation notice;
* `dynid.analysis.data.timebase`: time checks, resampling, `estimate_shift`;
* `dynid.analysis.data.description`: the TOML experiment description schema;
* `dynid.analysis.data.transmission`: motor side → joint side.

Every failure is a `dynid.errors.DataError` whose message names the file, the
column and the row; non-fatal findings go to `Experiment.notices`.
"""

from __future__ import annotations

from pathlib import Path, PurePath

from dynid.analysis.data.columns import _from_columns
from dynid.analysis.data.description import _load_toml
from dynid.analysis.data.readers import _READERS, _build_beside, _read_data_file
from dynid.analysis.data.record import SIGNALS, Experiment
from dynid.analysis.data.saturation import SATURATION_FRACTION, SATURATION_MIN_RUN, SATURATION_REL_TOL
from dynid.analysis.data.timebase import GAP_FACTOR, TIME_STEP_TOLERANCE, _Options, estimate_shift
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DataError

#: the extensions of the data files `load_experiment` reads (besides a .toml description)
DATA_EXTENSIONS = frozenset(_READERS)

__all__ = [
    "DATA_EXTENSIONS",
    "Experiment",
    "load_experiment",
    "estimate_shift",
    "SIGNALS",
    "TIME_STEP_TOLERANCE",
    "GAP_FACTOR",
    "SATURATION_FRACTION",
    "SATURATION_MIN_RUN",
    "SATURATION_REL_TOL",
]

# --------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------


def load_experiment(path, robot=None, *, n_joints: int | None = None) -> Experiment:
    """Read and validate an experiment file.

    Parameters
    ----------
    path:
        `.csv`, `.parquet`, `.npz` or `.mat` in dynid's column format, or a
        `.toml` experiment description (schema in docs/formats.md, section
        "Experiment description (TOML)", and `dynid.analysis.data.description`).
    robot:
        Optional robot (a Robot, a bundled robot's name or a robot file's path); only
        `n_joints`, `name` and `drive_gains` are used (the
        joint count is checked; currents `i*` become torques through the gains).
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
    if isinstance(robot, (str, PurePath)):      # a bundled name or a robot file, as identify() takes
        robot = load_robot(robot)
    label = str(path)
    ext = p.suffix.lower()
    if ext == ".toml":
        return _load_toml(p, label, robot, n_joints)
    if p.is_dir():
        raise DataError(f"{label} is a folder, not a recording: give a data file (.csv, .parquet, .npz, .mat) "
                        "or an experiment description (.toml) in it")
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
    opts = _Options(name=p.stem, where=label)
    # a CSV read by pandas gets a thread for the checks to share (benchmarks/io.py)
    raw = _read_data_file(p, label, beside=True)
    return _build_beside(raw, lambda r: _from_columns(r, robot, n_joints, opts, label, [], {}))
