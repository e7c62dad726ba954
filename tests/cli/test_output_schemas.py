"""Every command's `--json` output validates against its published JSON Schema
(docs/schema/*.json, described in docs/formats.md, "Outputs").

The schemas require the stable core of each document and allow other keys, so a command
may add to its JSON without breaking them; removing or retyping a required key fails here.
The commands run as a user runs them (the `dynid` console script of this venv: its entry point
in a process of its own, forked from one that has imported dynid, see `run`), on a short
simulated recording of the bundled two-joint `planar2`.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

jsonschema = pytest.importorskip("jsonschema", reason='the schema tests need pip install ".[test]"')

ROOT = Path(__file__).resolve().parents[2]
SCHEMAS = ROOT / "docs" / "schema"
DYNID = Path(sys.executable).parent / "dynid"


def schema(name):
    doc = json.loads((SCHEMAS / f"{name}.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(doc)
    return doc


def check(name, document):
    """Raise with every violation listed (not only the first)."""
    errors = sorted(jsonschema.Draft202012Validator(schema(name)).iter_errors(document), key=lambda e: list(e.path))
    assert not errors, "\n".join(f"{list(e.path)}: {e.message[:200]}" for e in errors)


#: what the console script runs (its entry point, dynid.reports.cli:main)
CONSOLE_CODE = "import sys; from dynid.reports.cli import main; sys.exit(main())"
_FORKED = []


@pytest.fixture(scope="module", autouse=True)
def _close_forked_cli():
    yield
    while _FORKED:
        _FORKED.pop().close()


def run(folder, *args, timeout=600):
    """`dynid ARGS --quiet` in `folder`: forked from a server that has imported dynid once
    (tests/support/forked_cli.py; the console script's entry point, with its path as argv[0]),
    or the console script itself where fork is unavailable or DYNID_TEST_FRESH_PROCESSES=1."""
    import forked_cli
    if not DYNID.exists():
        pytest.skip(f"no dynid console script beside {sys.executable}: pip install . first")
    argv = [*map(str, args), "--quiet"]
    answer = None
    if forked_cli.enabled():
        env = dict(os.environ)
        if not _FORKED:
            _FORKED.append(forked_cli.ForkedCli(CONSOLE_CODE, env, forked_cli.NO_LIMIT))
        answer = _FORKED[0].run(argv, folder, env, timeout, argv0=str(DYNID))
    if answer is None:
        proc = subprocess.run([str(DYNID), *argv], cwd=folder, capture_output=True, text=True, timeout=timeout)
    else:
        code, out, err, _ = answer
        assert code is not None, f"dynid {' '.join(argv)}: no answer within {timeout} s"
        proc = subprocess.CompletedProcess([str(DYNID), *argv], code, out.decode(), err.decode())
    assert proc.returncode in (0, 3), f"dynid {' '.join(args)}: exit {proc.returncode}\n{proc.stderr[-3000:]}"
    return proc


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with a short closed-loop recording of planar2 (and the simulate JSON)."""
    path = tmp_path_factory.mktemp("schemas")
    run(path, "simulate", "--robot", "planar2", "--duration", "6", "--seed", "4", "--out", "p2.csv",
        "--json", "simulate.json")
    return path


def load(path):
    return json.loads(Path(path).read_text(encoding="utf-8"))


def test_every_command_with_json_has_a_schema():
    names = {p.stem for p in SCHEMAS.glob("*.json")}
    assert names == {"robot", "simulate", "excite", "identify", "sample", "diagnose", "report", "fleet", "payload",
                     "drive_gains"}
    for name in names:
        doc = schema(name)
        assert doc["required"] and doc.get("additionalProperties", True) is True, name


def test_robot_json(folder):
    run(folder, "robot", "planar2", "--json", "robot.json")
    check("robot", load(folder / "robot.json"))


def test_simulate_json(folder):
    check("simulate", load(folder / "simulate.json"))


def test_excite_json(folder):
    run(folder, "excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--starts", "1",
        "--out", "traj.csv", "--json", "excite.json")
    check("excite", load(folder / "excite.json"))


def test_identify_json_to_stdout(folder):
    proc = run(folder, "identify", "p2.csv", "--robot", "planar2", "--holdout", "2", "--json", "-")
    doc = json.loads(proc.stdout)
    check("identify", doc)
    assert doc["validation"]["all_samples"]["rel_error"] == doc["validation"]["rel_error"]


@pytest.mark.parametrize("method, extra", [("didim", ()), ("projection", ()),
                                           ("ml", ("--f0", "0.5", "--ml-harmonics", "3"))])
def test_identify_json_of_the_other_methods(folder, method, extra):
    data = "p2.csv"
    if method == "ml":          # ML needs a recording periodic at its f0 (three periods of 0.5 Hz)
        data = "p2ml.csv"
        run(folder, "simulate", "--robot", "planar2", "--duration", "6", "--seed", "4", "--f0", "0.5",
            "--harmonics", "3", "--out", data)
    run(folder, "identify", data, "--robot", "planar2", "--method", method, *extra, "--json", f"{method}.json")
    check("identify", load(folder / f"{method}.json"))


def test_payload_json(tmp_path):
    """The TX40 (a 2-joint arm cannot turn a payload about three axes): a simulated payload found by
    the robot-fixed route, as docs/payload.md's "Try it" does, shorter."""
    run(tmp_path, "simulate", "--robot", "tx40", "--duration", "8", "--seed", "1", "--out", "empty.csv")
    run(tmp_path, "simulate", "--robot", "tx40", "--duration", "8", "--seed", "2", "--payload", "2,0,0,0.05",
        "--out", "loaded.csv")
    run(tmp_path, "identify", "empty.csv", "--robot", "tx40", "--json", "id.json")
    run(tmp_path, "payload", "--robot", "tx40", "--loaded", "loaded.csv", "--model", "id.json", "--json", "payload.json")
    doc = load(tmp_path / "payload.json")
    check("payload", doc)
    assert doc["method"] == "payload-robot-fixed" and abs(doc["mass_kg"] - 2.0) < 0.1
    # the drive gains with that payload known: `payload --gains` writes a document of its own
    run(tmp_path, "payload", "--robot", "tx40", "--loaded", "loaded.csv", "--unloaded", "empty.csv", "--mass", "2",
        "--com", "0,0,0.05", "--gains", "--json", "gains.json")
    doc = load(tmp_path / "gains.json")
    check("drive_gains", doc)
    assert doc["method"] == "drive-gains" and [g["joint"] for g in doc["gains"]] == [1, 2, 3, 4, 5, 6]
    # the robot file's gains are the simulation's: every 95 % interval holds 1 but at most one
    assert sum(g["lower_95"] <= 1.0 <= g["upper_95"] for g in doc["gains"]) >= 5


def test_sample_json(folder):
    run(folder, "sample", "p2.csv", "--robot", "planar2", "--max-seconds", "3", "--allow-unconverged",
        "--json", "sample.json")
    check("sample", load(folder / "sample.json"))


def _shared_run(run_once, tmp_path_factory):
    """The once-per-session command run of tests/support/shared_runs.py, which must end in 0 or 3."""
    if not DYNID.exists():
        pytest.skip(f"no dynid console script beside {sys.executable}: pip install . first")
    done = run_once(tmp_path_factory)
    assert done.returncode in (0, 3), f"exit {done.returncode}\n{done.stderr[-3000:]}"
    return done


def test_diagnose_json(tmp_path_factory):
    """`dynid diagnose p2.csv --robot planar2 --holdout 2 --report diag.html --json diagnose.json` on the
    same simulated recording as `folder`, run once per session (tests/reports/test_browser.py
    screenshots its report)."""
    from shared_runs import planar2_diagnose_run
    diag = _shared_run(planar2_diagnose_run, tmp_path_factory)
    check("diagnose", load(diag.folder / "diagnose.json"))


def test_report_json(tmp_path_factory):
    """`dynid report` with every part (IDIM, validation, DIDIM, posterior, diagnosis) on a simulated
    planar2 recording, run once per session (tests/cli/test_cli.py checks the same run's parts); a
    report with parts skipped is test_demo_json's."""
    from shared_runs import planar2_full_report_run
    full = _shared_run(planar2_full_report_run, tmp_path_factory)
    doc = load(full.folder / "r.json")
    check("report", doc)
    check("diagnose", dict(doc["diagnosis"], verdict=doc["verdict"]))    # the nested part, as diagnose writes it


def test_demo_json(tmp_path_factory):
    """`dynid demo --skip didim,sample,diagnose --duration 5 --seed 2 --report demo.html --json demo.json`, run
    once per session (tests/reports/test_browser.py reads the same run)."""
    from shared_runs import demo_idim_run
    demo = _shared_run(demo_idim_run, tmp_path_factory)
    check("report", load(demo.folder / "demo.json"))


def _fleet_catalogue(folder):
    """Two planar2 recordings of one robot, a day apart (the folder's simulated p2.csv, cut two ways)."""
    lines = (folder / "p2.csv").read_text().splitlines(keepends=True)
    rows = ["robot_id,timestamp,path,robot,temperature"]
    for k, cut in enumerate((len(lines) // 2, len(lines))):
        (folder / f"fleet{k}.csv").write_text("".join(lines[:1] + lines[1 + k:cut]))
        rows.append(f"R1,2026-03-0{k + 1}T08:00:00Z,fleet{k}.csv,planar2,{30 + k}")
    (folder / "fleet.csv").write_text("\n".join(rows) + "\n")
    return folder / "fleet.csv"


def test_fleet_json_in_process(folder):
    """The fleet's JSON (dynid.reports.fleet_report.fleet_json, what --json writes) from a store
    filled in this process, without Dask."""
    pytest.importorskip("pyarrow")
    from dynid.analysis.fleet.engine import FleetRun, plan
    from dynid.analysis.fleet.health import monitor
    from dynid.analysis.fleet.store import ResultStore
    from dynid.analysis.fleet.task import identify_recording
    from dynid.reports.fleet_report import fleet_json
    store = ResultStore(folder / "fleet-store-serial")
    specs, _ = plan(str(_fleet_catalogue(folder)), store)
    for spec in specs:
        store.write(identify_recording(spec))
    frame = store.read()
    health = monitor(frame, ["Fv", "Fc"], false_alarm_rate=1e-4, n_baseline=3)
    run = FleetRun(store=str(store.root), n_recordings=len(specs), n_computed=len(specs), n_skipped=0, errors=[],
                   wall_seconds=0.0, workers=1, health=health)
    doc = json.loads(json.dumps(fleet_json(run, frame, health), allow_nan=False))
    check("fleet", doc)
    assert doc["n_identified"] == 2 and [r["robot_id"] for r in doc["robots"]] == ["R1"]


@pytest.mark.slow
def test_fleet_json(folder):
    pytest.importorskip("distributed")
    _fleet_catalogue(folder)
    run(folder, "fleet", "fleet.csv", "--out", "fleet-store", "--workers", "1", "--json", "fleet.json")
    check("fleet", load(folder / "fleet.json"))


def test_a_schema_rejects_a_document_without_its_core():
    """The check above can fail: a document missing a required key, or with a wrong type, is refused."""
    with pytest.raises(AssertionError, match="verdict"):
        check("identify", {"method": "IDIM", "robot": "r", "source": "s", "settings": {}, "parameters": [],
                           "rel_error": 0.1, "versions": {"dynid": "0"}, "data_hash": "x", "notices": []})
    with pytest.raises(AssertionError, match="rel_error"):
        check("identify", {"method": "IDIM", "robot": "r", "source": "s", "settings": {}, "parameters": [],
                           "rel_error": "small", "versions": {"dynid": "0"}, "data_hash": "x", "notices": [],
                           "verdict": {"status": "identified", "identified": True, "reasons": [], "findings": []}})
