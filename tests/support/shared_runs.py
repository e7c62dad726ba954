"""Command-line runs that several test files read, made once per test session.

Under `pytest -n 2 --dist loadfile` the files that read one run may sit on different workers:
the first to ask runs the command (in a subprocess, as a user runs it) in a folder beside the
workers' temporary folders; the other waits on a file lock and reads the same outputs. Where no
lock is available (no fcntl) every caller runs the command itself, in its own folder.

Each run returns its folder, its exit code and its stderr, so every test keeps its own
assertion on how the command ended.
"""
from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

try:
    import fcntl
except ImportError:                     # pragma: no cover (not POSIX): no sharing
    fcntl = None

ROOT = Path(__file__).resolve().parents[2]
TX40_EXPERIMENT = ROOT / "examples" / "staubli_tx40" / "experiment.toml"
DYNID = Path(sys.executable).parent / "dynid"


@dataclass(frozen=True)
class Run:
    folder: Path
    returncode: int
    stderr: str


def _shared_root(tmp_path_factory) -> Path:
    base = tmp_path_factory.getbasetemp()
    # xdist gives each worker <basetemp>/popen-gwN; their parent is the session's
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def _run_all(commands: list[list[str]], folder: Path) -> tuple[int, str]:
    """The commands in order, in `folder`; the first that fails ends the run."""
    for argv in commands:
        proc = subprocess.run(argv, cwd=folder, capture_output=True, text=True, timeout=900)
        if proc.returncode not in (0, 3):      # 3: finished, with problems listed in its outputs
            break
    return proc.returncode, f"{' '.join(argv[1:])}: {proc.stderr}"


def once_in_folder(tmp_path_factory, key: str, make) -> Run:
    """`make(folder)` -> (exit code, stderr), called once per session for `key` (see the module's text)."""
    if fcntl is None:
        folder = tmp_path_factory.mktemp(key)
        return Run(folder, *make(folder))
    folder = _shared_root(tmp_path_factory) / f"shared-{key}"
    with open(f"{folder}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            done = folder / "returncode"
            if not done.exists():
                folder.mkdir(exist_ok=True)
                code, err = make(folder)
                (folder / "stderr").write_text(err)
                done.write_text(str(code))      # written last: the run is complete
            return Run(folder, int(done.read_text()), (folder / "stderr").read_text())
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _once(tmp_path_factory, key: str, *commands: list[str]) -> Run:
    return once_in_folder(tmp_path_factory, key, lambda folder: _run_all(list(commands), folder))


#: the arguments of `demo_idim_run` (tests/cli/test_cli_api.py runs them in its own process where
#: there is no console script)
DEMO_IDIM_ARGS = ["demo", "--skip", "didim,sample,diagnose", "--duration", "5", "--seed", "2",
                  "--report", "demo.html", "--json", "demo.json", "--quiet"]


def demo_idim_run(tmp_path_factory) -> Run:
    """`dynid demo --skip didim,sample,diagnose --duration 5 --seed 2 --report demo.html --json demo.json --quiet`
    with the console script of this venv (tests/cli/test_output_schemas.py skips when it is missing;
    tests/cli/test_cli_api.py then runs the command in its own process)."""
    return _once(tmp_path_factory, "demo-idim", [str(DYNID), *DEMO_IDIM_ARGS])


def tx40_identify_run(tmp_path_factory) -> Run:
    """`dynid identify examples/staubli_tx40/experiment.toml --robot tx40 --holdout 3 --json out.json
    --report out.html --quiet` on the real TX40 recording."""
    return _once(tmp_path_factory, "tx40-identify",
                 [sys.executable, "-m", "dynid.reports.cli", "identify", str(TX40_EXPERIMENT), "--robot", "tx40",
                  "--holdout", "3", "--json", "out.json", "--report", "out.html", "--quiet"])


def planar2_diagnose_run(tmp_path_factory) -> Run:
    """`dynid simulate --robot planar2 --duration 6 --seed 4 --out p2.csv`, then `dynid diagnose p2.csv
    --robot planar2 --holdout 2 --report diag.html --json diagnose.json --quiet`, with the console script
    of this venv; the returned code is the first failing command's, else the diagnosis'."""
    return _once(tmp_path_factory, "planar2-diagnose",
                 [str(DYNID), "simulate", "--robot", "planar2", "--duration", "6", "--seed", "4", "--out", "p2.csv",
                  "--quiet"],
                 [str(DYNID), "diagnose", "p2.csv", "--robot", "planar2", "--holdout", "2", "--report", "diag.html",
                  "--json", "diagnose.json", "--quiet"])


def planar2_full_report_run(tmp_path_factory) -> Run:
    """`dynid simulate --robot planar2 --duration 12 --out run.csv`, then `dynid report run.csv --robot
    planar2 --holdout 3 --max-seconds 20 --report r.html --json r.json --quiet`: every part of the report
    (IDIM, validation, DIDIM, posterior, diagnosis). The console script of this venv, or
    `python -m dynid.reports.cli` where there is none."""
    dynid = [str(DYNID)] if DYNID.exists() else [sys.executable, "-m", "dynid.reports.cli"]
    return _once(tmp_path_factory, "planar2-report",
                 [*dynid, "simulate", "--robot", "planar2", "--duration", "12", "--out", "run.csv", "--quiet"],
                 [*dynid, "report", "run.csv", "--robot", "planar2", "--holdout", "3", "--max-seconds", "20",
                  "--report", "r.html", "--json", "r.json", "--quiet"])
