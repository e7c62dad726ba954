"""Convert Gaz et al.'s Franka Emika Panda log to a CSV in dynid's column format.

    python examples/franka_panda/convert.py [--data DIR] OUT.csv

The log (``rbt_log/`` of marcocognetti/FrankaEmikaPandaDynModel, GPL-3.0; see
PROVENANCE.md beside it) is four text files with one number per line:

* ``exciting_traj_time.txt``: N time stamps (s);
* ``exciting_traj_positions.txt``, ``..._velocity.txt``, ``..._torques.txt``: 7 N
  values each, sample-major (sample k on lines 7k+1 ... 7k+7, joints 1..7).

The CSV has the columns ``t, q1..q7, qd1..qd7, tau1..tau7`` on the ORIGINAL time
stamps: nothing is resampled here. The stamps are irregular (mean 1.02 ms, sd 0.19 ms),
which dynid's loader refuses for a bare CSV; load the CSV through
``experiment.toml`` (beside this script, ``resample = true``: linear interpolation onto
a uniform grid at the median step) placed next to it.

A wrong layout raises :class:`dynid.errors.DataError` with one message naming the
file and the line: a non-numeric or empty line, a line count that is not a multiple of
7, or files whose sample counts differ.

``DIR`` defaults to the first ``shared/data/franka-panda-gaz`` found in the parent
directories of the repository (or ``$DYNID_SHARED_DATA/franka-panda-gaz``).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
if str(ROOT) not in sys.path:           # run as a script from anywhere: use this checkout
    sys.path.insert(0, str(ROOT))

from dynid.errors import DataError  # noqa: E402

N_JOINTS = 7
DATASET = "franka-panda-gaz"
FILES = {"t": "exciting_traj_time.txt", "q": "exciting_traj_positions.txt",
         "qd": "exciting_traj_velocity.txt", "tau": "exciting_traj_torques.txt"}


def find_data(explicit=None):
    """The data folder: ``explicit`` if given, else ``$DYNID_SHARED_DATA/franka-panda-gaz``,
    else the first ``shared/data/franka-panda-gaz`` in a parent directory of the repository.
    Returns a Path, or None when nothing is found (``explicit`` is returned as given)."""
    if explicit is not None:
        return Path(explicit)
    env = os.environ.get("DYNID_SHARED_DATA")
    if env and (Path(env) / DATASET).is_dir():
        return Path(env) / DATASET
    for parent in ROOT.parents:
        cand = parent / "shared" / "data" / DATASET
        if cand.is_dir():
            return cand
    return None


def missing_data_message(where=None):
    return ("the Franka Panda data of Gaz et al. were not found"
            + (f" in {where}" if where else " (looked for shared/data/franka-panda-gaz in the "
               "parent directories of the repository and in $DYNID_SHARED_DATA)")
            + ". They are not shipped with dynid (GPL-3.0): get them from "
            "https://github.com/marcocognetti/FrankaEmikaPandaDynModel, put the four "
            "exciting_traj_*.txt logs in DIR/rbt_log/ and get_GravityVector.m, "
            "get_FrictionTorque.m, Load_Franka_DH.m in DIR/model/, and give --data DIR.")


def read_column(path, label=None):
    """The numbers of a one-value-per-line file, as a list of floats.

    Raises DataError naming the file and the (1-based) line of the first line that is
    empty or not a finite number.
    """
    path = Path(path)
    label = label or str(path)
    try:
        text = path.read_text(encoding="ascii")
    except FileNotFoundError:
        raise DataError(f"{label}: file not found; give the folder holding rbt_log/ with "
                        f"--data DIR") from None
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[:exc.start].count(b"\n") + 1
        raise DataError(f"{label}, line {line}: not plain ASCII text; the log must hold one "
                        f"number per line") from None
    lines = text.split("\n")
    if lines and lines[-1] == "":          # the final newline
        lines.pop()
    values = []
    for k, line in enumerate(lines, start=1):
        s = line.strip()
        try:
            v = float(s)
        except ValueError:
            what = "an empty line" if not s else f"{s[:40]!r} is not a number"
            raise DataError(f"{label}, line {k}: {what}; the log must hold one number per "
                            f"line") from None
        if not math.isfinite(v):
            raise DataError(f"{label}, line {k}: {s!r} is not a finite number")
        values.append(v)
    if not values:
        raise DataError(f"{label}: the file is empty")
    return values


def read_log(src_dir):
    """The log as a dict of numpy arrays t (N,), q, qd, tau (N, 7), with checked layout."""
    import numpy as np

    src = Path(src_dir)
    log = src / "rbt_log" if (src / "rbt_log").is_dir() else src
    if not (log / FILES["t"]).is_file():
        raise DataError(missing_data_message(src))
    t = np.asarray(read_column(log / FILES["t"]))
    n = t.size
    out = {"t": t}
    for key in ("q", "qd", "tau"):
        path = log / FILES[key]
        vals = read_column(path)
        if len(vals) % N_JOINTS:
            raise DataError(f"{path}, line {len(vals)}: the file has {len(vals)} lines, not a "
                            f"multiple of {N_JOINTS} (one line per joint, sample-major); the last "
                            f"sample is incomplete")
        if len(vals) != N_JOINTS * n:
            m = min(len(vals), N_JOINTS * n) + 1
            where = (f"{path}, line {m}" if len(vals) > N_JOINTS * n
                     else f"{path}, line {len(vals)}")
            raise DataError(f"{where}: {len(vals) // N_JOINTS} samples ({len(vals)} lines) but "
                            f"{log / FILES['t']} has {n} time stamps; every file must hold the "
                            f"same samples ({N_JOINTS} lines per time stamp)")
        out[key] = np.asarray(vals).reshape(n, N_JOINTS)
    return out


def convert(src_dir, out_path):
    """Write the log of ``src_dir`` (the dataset folder or its rbt_log/) to ``out_path`` (CSV).

    Columns ``t, q1..q7, qd1..qd7, tau1..tau7``, original time stamps, numbers written with
    ``repr`` precision (the round trip is exact). Returns the number of samples.
    """
    log = read_log(src_dir)
    header = ["t"] + [f"{s}{j}" for s in ("q", "qd", "tau") for j in range(1, N_JOINTS + 1)]
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".part")
    with open(tmp, "w", encoding="ascii", newline="\n") as f:
        f.write(",".join(header) + "\n")
        for k in range(log["t"].size):
            row = [log["t"][k], *log["q"][k], *log["qd"][k], *log["tau"][k]]
            f.write(",".join(repr(float(v)) for v in row) + "\n")
    os.replace(tmp, out_path)
    return int(log["t"].size)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="CSV file to write")
    ap.add_argument("--data", help="dataset folder (holding rbt_log/), default: searched")
    args = ap.parse_args(argv)
    src = find_data(args.data)
    try:
        if src is None:
            raise DataError(missing_data_message())
        n = convert(src, args.out)
    except DataError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {n} samples from {src}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
