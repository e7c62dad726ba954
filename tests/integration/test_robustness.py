"""Reproducible runs and interrupted runs: what a user scripting dynid relies on."""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from dynid.reports.cli import main

ROOT = Path(__file__).resolve().parents[2]
TX40 = ROOT / "examples" / "staubli_tx40" / "experiment.toml"


def test_same_command_twice_gives_byte_identical_json(tmp_path):
    outs = []
    for k in range(2):
        js = tmp_path / f"run{k}.json"
        assert main(["identify", str(TX40), "--robot", "tx40", "--holdout", "3",
                     "--json", str(js), "--quiet"]) == 0
        outs.append(js.read_bytes())
    assert outs[0] == outs[1]


@pytest.mark.slow
def test_demo_same_seed_byte_identical_json(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    for js in (a, b):
        assert main(["demo", "--seed", "3", "--duration", "8", "--report", str(js.with_suffix(".html")),
                     "--json", str(js), "--quiet"]) == 0
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".html").read_bytes() == b.with_suffix(".html").read_bytes()


def _started(proc, marker, timeout=180.0):
    """The lines of proc's stderr up to (and with) the first one holding `marker`, read in a thread
    (the rest is collected too, for the assertions); None if it never came."""
    lines, seen = [], threading.Event()

    def read():
        for line in proc.stderr:
            lines.append(line)
            if marker in line:
                seen.set()
        seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    seen.wait(timeout)
    return lines, reader


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_killed_identify_leaves_no_partial_output(tmp_path, sig):
    report, js = tmp_path / "out.html", tmp_path / "out.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "dynid.reports.cli", "identify", str(TX40), "--robot", "tx40",
                             "--report", str(report), "--json", str(js)],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # signal once the run is under way (its data loaded), not after a fixed sleep: on a loaded
    # machine the interpreter was still starting after 2 s, and a SIGINT then is Python's own
    # (exit -2), before dynid runs at all
    lines, reader = _started(proc, "loaded ")
    time.sleep(0.2)                   # the identification itself takes a second or two
    proc.send_signal(sig)
    proc.wait(timeout=60)
    reader.join(timeout=10)
    proc.stdout.close()
    err = "".join(lines)
    if proc.returncode == 0:
        pytest.skip("the run finished before the signal arrived on this machine")
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []          # no report, no JSON, no temp file


def test_fleet_run_reports_progress_through_dynid_progress(tmp_path, monkeypatch, caplog):
    """dynid.fleet.run without a progress callable reports through dynid.progress (log records off a
    terminal), like the other long steps; dynid.progress.silence() turns it off."""
    import logging

    from dynid import progress as P
    from dynid.analysis.fleet.engine import FleetRun
    from dynid.reports import fleet_run

    def fake_identify(catalogue, store, *, progress=None, **kw):
        for done in (1, 2):
            progress(done, 2)
        return FleetRun(store=str(store), n_recordings=2, n_computed=2, n_skipped=0, errors=[], wall_seconds=0.0)

    monkeypatch.setattr(fleet_run, "identify_fleet", fake_identify)
    monkeypatch.setattr(fleet_run, "monitor", lambda *a, **k: None)
    monkeypatch.setattr(fleet_run, "ResultStore", lambda root: type("S", (), {"read": lambda self, keys=None: None,
                                                                           "root": str(root)})())
    monkeypatch.setattr(fleet_run, "task", lambda label: P.task(label, delay=0.0, log_every=0.0,
                                                                 stream=__import__("io").StringIO()))
    caplog.set_level(logging.INFO, logger="dynid.progress")
    P.enable(True)
    try:
        fleet_run.run(tmp_path / "cat.csv", tmp_path / "store")
        assert any("fleet" in r.getMessage() for r in caplog.records), [r.getMessage() for r in caplog.records]
        caplog.clear()
        P.silence()
        fleet_run.run(tmp_path / "cat.csv", tmp_path / "store")
        assert not caplog.records
    finally:
        P.enable(True)
        P._ENABLED = None
