"""The fleet: catalogue, store, Dask engine (a worker killed mid-run), rerun, CUSUM, report, CLI."""
import json
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import dynid

pytest.importorskip("pyarrow")

from simulated_fleet import simulate_fleet

from dynid.analysis.fleet import health
from dynid.analysis.fleet.catalogue import read_catalogue
from dynid.analysis.fleet.engine import identify_fleet, import_distributed, plan
from dynid.analysis.fleet.store import RUN_COLUMNS, ResultStore
from dynid.analysis.fleet.task import identify_recording
from dynid.errors import InputError

N_DAYS = 6
N_REC = 3 * N_DAYS          # recordings of the small fleet


@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory):
    """3 robots x 6 days of simulated planar2 recordings, 2 of them corrupted (serial, ~1 s)."""
    folder = tmp_path_factory.mktemp("fleet")
    return simulate_fleet(folder, 3, N_DAYS, seed=5, n_corrupted=2)


def serial_store(catalogue, root):
    """The reference: every task run in this process, one after the other, into a store."""
    store = ResultStore(root)
    specs, _ = plan(catalogue, store)
    for spec in specs:
        store.write(identify_recording(spec))
    return store


@pytest.fixture(scope="module")
def small_store(small_fleet, tmp_path_factory):
    """The serial store of the small fleet, computed once (tests that write to a store copy it)."""
    return serial_store(small_fleet.catalogue, tmp_path_factory.mktemp("serial") / "store")


def copied(store, root):
    import shutil
    shutil.copytree(store.root, root)
    return ResultStore(root)


def comparable(frame):
    return frame.drop(columns=list(RUN_COLUMNS)).sort_values(["recording", "parameter"]).reset_index(drop=True)


# ------------------------------------------------------------------ catalogue
def test_catalogue_errors_name_column_and_row(tmp_path):
    p = tmp_path / "cat.csv"
    p.write_text("robot_id,timestamp,path\nR1,2026-01-01T00:00:00Z,a.npz\n")
    with pytest.raises(InputError, match="missing column.*robot"):
        read_catalogue(p)
    p.write_text("robot_id;timestamp;path;robot\nR1;2026-01-01T00:00:00Z;a.npz;planar2\n")
    with pytest.raises(InputError, match="separated by ';': a fleet catalogue is comma-separated"):
        read_catalogue(p)
    p.write_text("robot_id,timestamp,path,robot\nR1,2026-01-01T00:00:00Z,a.npz,planar2\n"
                 "R1,yesterday,b.npz,planar2\n")
    with pytest.raises(InputError, match=r"column timestamp, row 2: 'yesterday'"):
        read_catalogue(p)
    # read by a guess, these put a recording on another day without a word (1970-01-01, 3 February)
    for value, shown in (("1700000000", "1700000000 is not an ISO 8601.*seconds or milliseconds since 1970"),
                         ("1.7e9", "1700000000.0 is not an ISO 8601"), ("02/03/2026", "'02/03/2026' is not an ISO")):
        p.write_text(f"robot_id,timestamp,path,robot\nR1,{value},a.npz,planar2\n")
        with pytest.raises(InputError, match=f"column timestamp, row 1: {shown}"):
            read_catalogue(p)
    for value, day in (("\"2026-03-01t23:30:00,5z\"", "2026-03-01"), ("2026-03-01 23:30:00.25-02:00", "2026-03-02")):
        p.write_text(f"robot_id,timestamp,path,robot\nR1,{value},a.npz,planar2\n")
        assert read_catalogue(p)["day"].tolist() == [day]        # ISO 8601 in its other spellings
    p.write_text("robot_id,timestamp,path,robot,temperature2\nR1,2026-01-01T00:00:00Z,a.npz,planar2,warm\n")
    with pytest.raises(InputError, match="column temperature2, row 1"):
        read_catalogue(p)
    p.write_text("robot_id,timestamp,path,robot\nR/1,2026-01-01T00:00:00Z,a.npz,planar2\n")
    with pytest.raises(InputError, match="robot_id, row 1"):
        read_catalogue(p)


def test_catalogue_paths_relative_to_catalogue_and_days_utc(tmp_path):
    p = tmp_path / "cat.csv"
    p.write_text("robot_id,timestamp,path,robot,temperature\nR1,2026-01-01T23:30:00-02:00,sub/a.npz,planar2,30\n")
    frame = read_catalogue(p)
    assert frame["path"][0] == str(tmp_path / "sub" / "a.npz")
    assert frame["day"][0] == "2026-01-02"        # 23:30 at UTC-2 is 01:30 UTC the next day


def test_catalogue_near_miss_columns_ragged_rows_and_robot_files_are_refused(tmp_path):
    """Columns that would be silently ignored, a row shifted by an extra field, a robot file
    that is not there: each refused with the column or line (found by a bad-input hunt)."""
    p = tmp_path / "cat.csv"
    head = "robot_id,timestamp,path,robot"
    row = "R1,2026-01-01T00:00:00Z,a.npz,planar2"
    cases = [(f"{head},Temperature\n{row},20\n", r"column 'Temperature' is not read; write it 'temperature'"),
             (f"{head},temperature0\n{row},20\n", "temperature0: joints count from 1"),
             (f"{head},robot_id\n{row},R2\n", "column robot_id is given twice"),
             (f"{head},temperature_1\n{row},20\n", r"column 'temperature_1' is not read; write it 'temperature1'"),
             (f"{head}\n{row},extra\n", r"record 1 \(line 2 .*\) has 5 fields and the header 4"),
             (f"{head}\nR1,2026-01-01T00:00:00Z,a.npz,arm.toml\n",
              r"column robot, row 1: the robot file .*arm.toml does not exist \(a relative path is relative "
              r"to the catalogue's folder\)")]
    for text, message in cases:
        p.write_text(text)
        with pytest.raises(InputError, match=message):
            read_catalogue(p)
    # "nan" is not an empty cell; a robot may be called NA
    p.write_text(f"{head},temperature\n{row},nan\n")
    with pytest.raises(InputError, match="column temperature, row 1: 'nan' is not a temperature"):
        read_catalogue(p)
    p.write_text(f"{head}\n{row.replace('R1', 'NA')}\n")
    assert read_catalogue(p)["robot_id"][0] == "NA"
    # other columns are kept and not read; a row with fewer fields has empty ones, as pandas reads it
    p.write_text(f"{head},operator\n{row},ann\n{row.replace('a.npz', 'b.npz')}\n")
    frame = read_catalogue(p)
    assert frame["operator"][0] == "ann" and frame["operator"].isna()[1]


def test_plan_keys_follow_the_robot_file_and_the_data_a_toml_names(tmp_path):
    """A rerun recomputes a recording whose robot file or TOML-named data changed (the key
    held the paths and the TOML's own bytes only, so the store served the old results), and
    a relative robot path is the catalogue folder's, not the working directory's."""
    from dynid.dynamics.robots import __file__ as robots_init
    folder = tmp_path / "fleet"
    folder.mkdir()
    robot_text = (Path(robots_init).parent / "planar2.toml").read_text()
    (folder / "arm.toml").write_text(robot_text)
    (folder / "d1.csv").write_text("t,q1,q2,tau1,tau2\n0,0,0,0,0\n")
    (folder / "e1.toml").write_text('[experiment]\nfile = "d1.csv"\n')
    cat = folder / "cat.csv"
    cat.write_text("robot_id,timestamp,path,robot,temperature2,temperature3\n"
                   "R1,2026-01-01T00:00:00Z,e1.toml,arm.toml,20,\n")
    store = ResultStore(tmp_path / "store")
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)            # not the catalogue's folder
        specs, _ = plan(cat, store)
    finally:
        os.chdir(cwd)
    assert specs[0]["robot"] == str(folder / "arm.toml")
    key = specs[0]["key"]
    (folder / "arm.toml").write_text(robot_text.replace("d = 1.0", "d = 1.3", 1))
    assert plan(cat, store)[0][0]["key"] != key
    (folder / "arm.toml").write_text(robot_text)
    assert plan(cat, store)[0][0]["key"] == key
    (folder / "d1.csv").write_text("t,q1,q2,tau1,tau2\n0,0,0,1,0\n")
    assert plan(cat, store)[0][0]["key"] != key
    # a data file named in a table of its own ([torques] file = ...), as the TX40 example's
    (folder / "tau.csv").write_text("0,0\n")
    (folder / "e2.toml").write_text('[torques]\nfile = "tau.csv"\n')
    cat.write_text("robot_id,timestamp,path,robot\nR1,2026-01-01T00:00:00Z,e2.toml,planar2\n")
    key = plan(cat, store)[0][0]["key"]
    (folder / "tau.csv").write_text("0,1\n")
    assert plan(cat, store)[0][0]["key"] != key
    # a bundled name is the bundled robot, whatever file of that name the working folder holds
    (folder / "planar2").write_text("not a robot")
    key = plan(cat, store)[0][0]["key"]
    try:
        os.chdir(folder)
        assert plan(cat, store)[0][0]["key"] == key
    finally:
        os.chdir(cwd)
    # a temperature of a joint the robot does not have, named by the catalogue's own row number
    cat.write_text("robot_id,timestamp,path,robot,temperature3\nR2,2026-01-01T00:00:00Z,d1.csv,planar2,\n"
                   "R1,2026-01-01T00:00:00Z,e1.toml,arm.toml,20\n")
    with pytest.raises(InputError, match="column temperature3, row 2: the robot .*arm.toml has 2 joints"):
        plan(cat, store)
    # an empty joint temperature beside a shared one: each joint keeps its own, or the shared one
    cat.write_text("robot_id,timestamp,path,robot,temperature,temperature1,temperature2\n"
                   "R1,2026-01-01T00:00:00Z,e1.toml,arm.toml,30,20,\n")
    assert plan(cat, store)[0][0]["temperatures"] == [20.0, 30.0]


def test_missing_dask_says_how_to_install(monkeypatch, tmp_path, capsys):
    """The packages themselves (dynid is not on a package index), before the command line
    announces a cluster."""
    from dynid.reports.cli import main
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InputError, match=r'pip install "dask\[distributed\]>=[0-9.]+" "pyarrow>=[0-9.]+"'):
        import_distributed()
    assert main(["fleet", str(tmp_path / "catalogue.csv"), "--out", str(tmp_path / "store")]) == 2
    err = capsys.readouterr().err
    assert "Dask distributed, which is not installed" in err and "local cluster" not in err


# ------------------------------------------------------------------ task and store
def test_task_reports_corrupted_logs_and_identifies_the_rest(small_fleet, small_store):
    store = small_store
    frame = store.read()
    per_rec = frame.drop_duplicates("key")
    assert len(per_rec) == N_REC and per_rec["key"].is_unique
    failed = per_rec[per_rec["status"] == "error"]
    assert sorted(failed["recording"]) == sorted(small_fleet.corrupted)
    assert all(rec in msg for rec, msg in zip(failed["recording"], failed["error"]))   # names the file
    ok = frame[(frame["status"] == "ok") & (frame["parameter"] == "Fv1")]
    assert np.all(ok["sigma"] > 0) and np.all(np.abs(ok["value"] - 0.5) < 0.25)   # planar2's Fv1 = 0.5 +-20 %
    # the stored sigma is the classic one the health settings name (fleet.json), not identify's default
    row = ok.iloc[0]
    classic = dynid.identify(row["recording"], row["robot"], uncertainty="classic").wls
    assert row["sigma"] == pytest.approx(float(classic.bse["Fv1"]), rel=1e-9)
    assert row["value"] == pytest.approx(float(classic.params["Fv1"]), rel=1e-9)
    assert set(frame["effects"]) == {""}                 # no diagnosis unless asked for
    # partitioned by robot and day, one file per recording
    files = sorted(p.relative_to(store.root).parts[:2] for p in __import__("pathlib").Path(store.root).rglob("*.parquet"))
    assert len(files) == N_REC and files[0][0] == "robot_id=R000" and files[0][1].startswith("day=2026-03-")


def test_streamed_long_recording_agrees_with_whole(small_fleet, tmp_path):
    specs, _ = plan(small_fleet.catalogue, ResultStore(tmp_path / "s"))
    spec = next(s for s in specs if s["path"] not in small_fleet.corrupted)
    whole = identify_recording(spec)
    streamed = identify_recording({**spec, "max_samples": 1200})     # blocks of 1000 samples
    assert whole["status"] == streamed["status"] == "ok"
    for name in ("Fv1", "Fc1", "Fv2", "Fc2"):
        k = whole["names"].index(name)
        assert abs(streamed["value"][k] - whole["value"][k]) < 3 * whole["sigma"][k]


def test_long_recording_reduced_chunk_by_chunk_equals_its_decimated_system_in_memory(small_fleet, tmp_path):
    """The task's streamed path (W never held) against WLS/essential set on the same decimated W, held."""
    from dynid.analysis.data.experiment import load_experiment
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators import streamed
    from dynid.analysis.estimators.essential import essential_parameters
    from dynid.analysis.fleet import task
    from dynid.analysis.processing import streaming
    specs, _ = plan(small_fleet.catalogue, ResultStore(tmp_path / "s"))
    spec = next(s for s in specs if s["path"] not in small_fleet.corrupted)
    robot, bp = task._robot(spec["robot"])
    exp = load_experiment(spec["path"], robot)
    held = {}
    real = streamed.reduce_stream

    def both(chunks, *args, **kw):      # the same blocks, through both paths
        chunks = list(chunks)
        held["obs"] = streaming.observe_stream(iter(chunks), *args, **kw)
        return real(iter(chunks), *args, **kw)
    task.reduce_stream = both           # the name the task calls
    try:
        wls, ess, n_raw = task._identify(exp, robot, bp, None, 1200)
    finally:
        task.reduce_stream = real
    obs = held["obs"]
    ref = ls.wls(obs.W, obs.tau, list(bp.names), row_mask=obs.row_mask)
    ref_ess = essential_parameters(obs.W, obs.tau, list(bp.names), ls.wls, row_mask=obs.row_mask)
    assert n_raw == exp.q.shape[0] and wls.n_rows == ref.n_rows
    np.testing.assert_allclose(wls.chi, ref.chi, rtol=1e-10)
    np.testing.assert_allclose(wls.bse.to_numpy(), ref.bse.to_numpy(), rtol=1e-10)
    assert abs(wls.rel_error / ref.rel_error - 1) < 1e-10
    assert ess.essential == ref_ess.essential
    np.testing.assert_allclose(ess.result.chi, ref_ess.result.chi, rtol=1e-10)


def test_rerun_with_nothing_changed_computes_nothing(small_fleet, small_store, tmp_path):
    store = copied(small_store, tmp_path / "store")
    before = {p: os.stat(p).st_mtime_ns for p in store._files()}
    # an unreachable scheduler: the run fails if it tries to compute anything
    run = identify_fleet(small_fleet.catalogue, store, scheduler="tcp://127.0.0.1:9")
    assert (run.n_computed, run.n_skipped) == (0, N_REC)
    assert {p: os.stat(p).st_mtime_ns for p in store._files()} == before
    # a changed recording is recomputed, and only it
    specs, todo = plan(small_fleet.catalogue, store)
    target = next(s["path"] for s in specs if s["path"] not in small_fleet.corrupted)
    original = open(target, "rb").read()
    data = dict(np.load(target))
    data["tau"] = data["tau"] * 1.01
    try:
        np.savez(target, **data)
        _, todo = plan(small_fleet.catalogue, store)
    finally:                # the module's fleet and store stay as they were for the other tests
        with open(target, "wb") as f:
            f.write(original)
    assert [s["path"] for s in todo] == [target]


def test_killed_worker_loses_and_duplicates_nothing(small_fleet, small_store, tmp_path):
    distributed = pytest.importorskip("distributed")
    reference = comparable(small_store.read())
    killed = []
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as cluster, distributed.Client(cluster) as client:
        pids = client.run(os.getpid)

        def kill_one(done, total):
            # after the third result, SIGKILL a worker that is processing a task right now
            if done == 3 and not killed:
                busy = [w for w, keys in client.processing().items() if keys]
                assert busy, "no worker was busy mid-run"
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
        run = identify_fleet(small_fleet.catalogue, tmp_path / "dask", client=client, progress=kill_one)
        assert killed and run.n_computed == N_REC
        assert set(client.run(os.getpid).values()) != set(pids.values())   # the nanny started a new worker
    stored = ResultStore(tmp_path / "dask")
    assert len(stored._files()) == N_REC
    frame = stored.read()
    assert frame.drop_duplicates("key")["recording"].is_unique and frame["recording"].nunique() == N_REC
    pd.testing.assert_frame_equal(comparable(frame), reference, check_exact=False, rtol=1e-12, atol=0)


# ------------------------------------------------------------------ health
def test_cusum_threshold_gives_the_asked_false_alarm_rate():
    """Run lengths of the one-sided CUSUM on N(0,1) noise against Siegmund's ARL0 (the threshold's input)."""
    rng = np.random.default_rng(0)
    k, arl0 = 0.5, 200.0
    h = health.cusum_threshold(1 / arl0, k)
    runs = []
    for _ in range(150):
        z = rng.normal(size=3000)
        s, t = 0.0, None
        for i, v in enumerate(z):
            s = max(0.0, s + v - k)
            if s > h:
                t = i + 1
                break
        runs.append(t or 3000)
    assert 0.75 * arl0 < np.mean(runs) < 1.33 * arl0


def _synthetic_store(rng, n_robots=12, n_days=30, c=-0.01, step=0.25, worn=("R03", "Fv2", 15)):
    rows = []
    for r in range(n_robots):
        rid = f"R{r:02d}"
        level = {"Fv1": rng.uniform(0.4, 0.6), "Fv2": rng.uniform(0.25, 0.35)}
        for d in range(n_days):
            T = 30 + 8 * np.sin(rng.uniform(0, 2 * np.pi))
            for name, v0 in level.items():
                v = v0 * (1 + c * (T - 25)) * (1 + (step if (rid, name) == worn[:2] and d >= worn[2] else 0))
                rows.append({"status": "ok", "robot_id": rid, "parameter": name, "joint": int(name[-1]),
                             "timestamp": pd.Timestamp("2026-01-01", tz="UTC") + pd.Timedelta(days=d, hours=9),
                             "day": f"2026-01-{d + 1:02d}", "recording": f"{rid}-{d}",
                             "value": v + rng.normal(0, 0.01 * v0), "sigma": 0.01 * v0, "temperature": T})
    return pd.DataFrame(rows)


def test_monitor_finds_the_step_with_its_onset_size_and_the_temperature_coefficient():
    frame = _synthetic_store(np.random.default_rng(3))
    h = health.monitor(frame, false_alarm_rate=1e-4)
    assert abs(h.temperature_coefficients["Fv2"] + 0.01) < 0.001
    assert [(a.robot_id, a.parameter, a.direction) for a in h.alarms] == [("R03", "Fv2", "increase")]
    a = h.alarms[0]
    assert a.onset_day == "2026-01-16" and a.alarm_day in ("2026-01-16", "2026-01-17")
    assert abs(a.rel_size - 0.25) < 0.05 and a.joint == 2
    assert a.unit == ""               # no robot file to read the joint type from: no unit guessed
    frame["robot"] = "planar2"
    assert health.monitor(frame, false_alarm_rate=1e-4).alarms[0].to_dict()["unit"] == "N m s/rad"


def test_fleet_health_and_run_are_results_with_summary_and_exports(tmp_path):
    """The monitor's and the run's results have the interface of every result: str() is the
    summary (with the alarm and its unit), to_json() is to_dict(), to_csv() writes a table."""
    from dynid.analysis.fleet.engine import FleetRun
    from dynid.analysis.results import Result
    frame = _synthetic_store(np.random.default_rng(3))
    frame["robot"] = "planar2"
    h = health.monitor(frame, false_alarm_rate=1e-4)
    assert isinstance(h, Result) and str(h) == h.summary()
    text = h.summary()
    assert text.startswith("Fleet health: 1 alarm(s) on 1 robot(s)")
    assert "R03 joint 2 Fv2: increase of" in text and "N m s/rad" in text and "since 2026-01-16" in text
    assert json.loads(h.to_json()) == json.loads(json.dumps(h.to_dict()))
    h.to_csv(tmp_path / "history.csv")
    back = pd.read_csv(tmp_path / "history.csv")
    assert len(back) == len(h.history) and {"robot_id", "parameter", "compensated"} <= set(back)
    assert repr(h) == "<FleetHealth 1 alarm(s) on 1 robot(s)>"
    run = FleetRun(store="s", n_recordings=3, n_computed=2, n_skipped=1, wall_seconds=1.0, health=h,
                   errors=[("R01", "R01_d02.npz", "DataError: column tau2 has NaN in row 7")])
    assert str(run).splitlines()[1].strip().startswith("3 recordings: 1 identified, 1 already in the store, 1 failed")
    assert "failed: R01 R01_d02.npz: DataError" in str(run) and "Fleet health: 1 alarm" in str(run)
    assert run.to_frame().to_dict("records") == [{"robot_id": "R01", "recording": "R01_d02.npz",
                                                 "error": "DataError: column tau2 has NaN in row 7"}]
    assert json.loads(run.to_json())["n_failed"] == 1
    assert repr(run) == "<FleetRun 3 recordings: 1 identified, 1 already in the store, 1 failed (1.0 s)>"


def test_temperature_compensation_is_what_makes_a_small_change_visible():
    """The test of the compensation: uncompensated, the daily cycle (+-8 %) is scatter that hides an 8 % step."""
    frame = _synthetic_store(np.random.default_rng(3), step=0.08)
    comp = health.monitor(frame, false_alarm_rate=1e-4)
    raw = health.monitor(frame, false_alarm_rate=1e-4, compensate=False)
    assert [(a.robot_id, a.parameter, a.alarm_day) for a in comp.alarms] == [("R03", "Fv2", "2026-01-16")]
    assert raw.alarms == []
    assert raw.scatter_ratio["Fv2"] > 4 * comp.scatter_ratio["Fv2"]
    assert 0.8 < comp.scatter_ratio["Fv2"] < 1.25      # compensated: the scatter is the model's sigma


# ------------------------------------------------------------------ report and command line
def test_cli_fleet_rerun_writes_report_and_json(small_fleet, small_store, tmp_path, capsys):
    from dynid.reports.cli import main
    copied(small_store, tmp_path / "store")
    rc = main(["fleet", small_fleet.catalogue, "--out", str(tmp_path / "store"), "--scheduler", "tcp://127.0.0.1:9",
               "--baseline", "4", "--report", str(tmp_path / "f.html"), "--json", str(tmp_path / "f.json")])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert f"{N_REC} recordings: 0 identified, {N_REC} already in the store, 0 failed" in out   # the result: stdout
    html = (tmp_path / "f.html").read_text()
    assert "Fleet overview" in html and "table class=\"data sortable\"" in html and "<script>" in html
    assert "src=\"http" not in html and "href=\"http" not in html          # self-contained
    doc = json.loads((tmp_path / "f.json").read_text())
    assert doc["n_recordings"] == N_REC and len(doc["robots"]) == 3
    assert "alarms" in doc["health"]
    assert doc["health"]["settings"]["uncertainty"] == "classic"     # the store's sigma, named


def _sub_catalogue(fleet, folder, n_good, n_bad=1):
    """A catalogue of ``n_good`` recordings of ``fleet`` and ``n_bad`` corrupted ones (absolute paths)."""
    frame = pd.read_csv(fleet.catalogue)
    frame["path"] = [str((os.path.dirname(fleet.catalogue) / __import__("pathlib").Path(p)).resolve())
                     for p in frame["path"]]
    bad = frame["path"].isin([str(__import__("pathlib").Path(p).resolve()) for p in fleet.corrupted])
    sub = pd.concat([frame[~bad].head(n_good), frame[bad].head(n_bad)])
    folder.mkdir(parents=True, exist_ok=True)
    sub.to_csv(folder / "catalogue.csv", index=False)
    return str(folder / "catalogue.csv"), list(sub["path"])


@pytest.fixture
def tcp_cluster():
    """An in-process LocalCluster on TCP: a running scheduler to give --scheduler the address of (~1 s)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                                  dashboard_address=":0", silence_logs=40) as cluster:
        yield cluster


def test_scheduler_address_cli_and_api_give_the_serial_results(small_fleet, small_store, tmp_path, tcp_cluster,
                                                                capsys):
    from dynid.fleet import run
    from dynid.reports.cli import main
    catalogue, paths = _sub_catalogue(small_fleet, tmp_path / "cat", 2)
    serial = small_store.read()
    reference = comparable(serial[serial["recording"].isin(paths)])
    assert reference["recording"].nunique() == 3
    address = tcp_cluster.scheduler_address
    assert address.startswith("tcp://")
    clients = len(tcp_cluster.scheduler.clients)
    rc = main(["fleet", catalogue, "--out", str(tmp_path / "cli"), "--scheduler", address, "--baseline", "3"])
    out, err = capsys.readouterr()
    # issue 31: a failed recording is counted as failed, not identified, and the run exits 2 (the rest is stored)
    assert rc == 2, err
    assert f"on {address}" in err and "3 recordings: 2 identified, 0 already in the store, 1 failed" in out
    assert "1 of 3 recordings could not be identified" in err
    api = run(catalogue, tmp_path / "api", scheduler=address, n_baseline=3)
    assert (api.n_computed, api.workers, len(api.errors)) == (3, 1, 1)
    # the tasks ran on that scheduler (under the engine's keys), and its clients were closed after
    assert tcp_cluster.scheduler.task_prefixes["dynid-fleet"].state_counts["memory"] == 6
    assert len(tcp_cluster.scheduler.clients) == clients
    for store in ("cli", "api"):
        frame = ResultStore(tmp_path / store).read()
        assert sorted(frame["recording"].unique()) == sorted(paths)
        pd.testing.assert_frame_equal(comparable(frame), reference, check_exact=False, rtol=1e-12, atol=0)


def test_diagnose_stores_the_effect_a_recording_has(small_fleet, tmp_path, tcp_cluster, capsys):
    """--diagnose: a spring added to joint 1's torque is named in the store; the option is part of the key.

    (Without it no diagnosis runs: test_task_reports_corrupted_logs... checks the empty effects.)"""
    from dynid.reports.cli import main
    catalogue, paths = _sub_catalogue(small_fleet, tmp_path / "cat", 1, n_bad=0)
    data = dict(np.load(paths[0]))
    data["tau"][:, 0] += 2.0 * data["q"][:, 0]          # Ks1 = 2 N m/rad, not in the model
    np.savez(paths[0].replace(".npz", "-spring.npz"), **data)
    frame = pd.read_csv(catalogue)
    frame["path"] = [paths[0].replace(".npz", "-spring.npz")]
    frame.to_csv(catalogue, index=False)
    store = tmp_path / "store"
    assert main(["fleet", catalogue, "--out", str(store), "--scheduler", tcp_cluster.scheduler_address,
                 "--baseline", "3", "--diagnose"]) == 0
    assert "1 recordings: 1 identified, 0 already in the store, 0 failed" in capsys.readouterr().out
    stored = ResultStore(store).read().drop_duplicates("key")
    assert list(stored["effects"]) == ["spring (joint 1)"]
    # the option is part of the key: without it, the recording is still to compute (and with it, not)
    assert len(plan(catalogue, ResultStore(store))[1]) == 1
    assert plan(catalogue, ResultStore(store), diagnose=True)[1] == []


def test_cli_fleet_bad_catalogue_is_an_input_error(tmp_path, capsys):
    from dynid.reports.cli import main
    rc = main(["fleet", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "store")])
    assert rc == 2 and "nope.csv: fleet catalogue not found" in capsys.readouterr().err


def test_store_reads_with_pandas_as_the_docs_say(small_store):
    """docs/formats.md: the folder names repeat robot_id and day, so a generic reader turns off
    Hive partitioning discovery (else pyarrow cannot merge the two robot_id types)."""
    frame = pd.read_parquet(small_store.root, partitioning=None)
    ours = small_store.read()
    assert len(frame) == len(ours) and set(frame.columns) == set(ours.columns)


def test_monitor_unknown_parameter_or_nothing_identified_is_an_input_error_not_a_crash():
    """Issue 31: these raised a TypeError from inside pandas."""
    frame = _synthetic_store(np.random.default_rng(1), n_robots=3, n_days=12)
    with pytest.raises(InputError, match=r"--parameters.*Xx is not a base parameter.*Fv1, Fv2"):
        health.monitor(frame, ["Xx"])
    with pytest.raises(InputError, match=r"Fv9 is not a base parameter"):
        health.monitor(frame, ["Fv", "Fv9"])
    failed = frame.assign(status="error", parameter="")
    h = health.monitor(failed)
    assert h.alarms == [] and h.n_monitored == 0 and "no recording was identified" in h.status_line()
    h = health.monitor(frame, n_baseline=12)          # every robot's history is its baseline
    assert h.n_monitored == 0 and "not monitored" in h.status_line() and "--baseline" in h.status_line()


@pytest.mark.slow
@pytest.mark.parametrize("marker", ["on a local cluster", "progress: identifying"])
def test_ctrl_c_stops_a_local_fleet_without_a_traceback(small_fleet, tmp_path, marker):
    """Ctrl-C, which the terminal sends to every process of the group (the workers too), while the
    workers start and mid-run: one message, exit 130, no worker's traceback, no process left behind.
    Before, a worker still importing printed its KeyboardInterrupt traceback under dynid's message."""
    import subprocess
    import time

    from signalled import signal_when
    pytest.importorskip("distributed")
    code = "import sys; from dynid.reports.cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, "fleet", str(small_fleet.catalogue), "--out",
                             str(tmp_path / "store"), "--workers", "2"], cwd=tmp_path, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    err, _ = signal_when(proc, marker, lambda: os.killpg(proc.pid, signal.SIGINT))
    assert proc.returncode == 130, f"exit {proc.returncode} (the run ended before the signal?)\n{err}"
    assert "dynid: interrupted; the recordings finished so far are in the store" in err, err
    assert "Traceback" not in err and "ERROR" not in err, err
    deadline = time.monotonic() + 20       # exited workers wait for init to reap them
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        pytest.fail("worker processes outlived the interrupted run by 20 s")


def test_ctrl_c_inside_a_lock_of_dasks_client_is_an_interruption(small_fleet, tmp_path, monkeypatch):
    """A Ctrl-C landing inside a lock's release in Dask's client code surfaces as
    `RuntimeError: cannot release un-acquired lock` (seen once in the slow Ctrl-C test):
    dynid fleet called it an internal error. With a Ctrl-C pressed it is an interruption."""
    import signal

    from dynid.analysis.fleet import engine

    def interrupted_execute(todo, store, client, progress=None):
        try:
            signal.raise_signal(signal.SIGINT)   # to this thread: another may take a kill()
        except KeyboardInterrupt:
            pass
        raise RuntimeError("cannot release un-acquired lock")

    class Client:
        def scheduler_info(self):
            return {"workers": {}}

        def close(self):
            pass

    monkeypatch.setattr(engine, "execute", interrupted_execute)
    # the note of a Ctrl-C needs Python's own handler (a terminal's, CI's); a test run started in the
    # background of a non-interactive shell inherits SIGINT ignored, where the note (rightly) stays off
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            engine.identify_fleet(small_fleet.catalogue, tmp_path / "store", client=Client())
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)

    def failing_execute(todo, store, client, progress=None):
        raise RuntimeError("a real bug")
    monkeypatch.setattr(engine, "execute", failing_execute)
    with pytest.raises(RuntimeError, match="a real bug"):
        engine.identify_fleet(small_fleet.catalogue, tmp_path / "store2", client=Client())


# ------------------------------------------------------------------ store hygiene and failures
def test_results_of_rows_no_longer_in_the_catalogue_are_kept_but_not_used(small_fleet, tmp_path):
    """A row removed and a row whose robot_id was corrected: their old results stayed in the store and
    were counted by the monitor and the report (robot A with 3 recordings of 2 rows)."""
    from dynid.fleet import run
    from dynid.reports.fleet_report import fleet_json
    catalogue, _ = _sub_catalogue(small_fleet, tmp_path / "cat", 4, n_bad=0)
    store = serial_store(catalogue, tmp_path / "store")
    rows = pd.read_csv(catalogue).iloc[1:].reset_index(drop=True)       # the first row removed
    rows.loc[0, "robot_id"] = "R999"                                    # and a robot_id corrected
    rows.to_csv(catalogue, index=False)
    serial_store(catalogue, store.root)                 # the renamed row's result, without a cluster
    result = run(catalogue, store.root, scheduler="tcp://127.0.0.1:9", n_baseline=3, json=tmp_path / "f.json")
    assert (result.n_computed, result.n_unused) == (0, 2)
    assert "2 result(s) in the store are of rows no longer in the catalogue" in result.summary_line()
    assert len(store._files()) == 5                     # kept on disk, not used
    for doc in (json.loads((tmp_path / "f.json").read_text()),
                fleet_json(result, store.read(), result.health)):     # --json -: the whole store is read
        assert {r["robot_id"]: r["recordings"] for r in doc["robots"]} == rows["robot_id"].value_counts().to_dict()
        assert doc["health"]["settings"]["n_identified"] == 3 and doc["n_unused"] == 2


@pytest.mark.parametrize("failure", [OSError(5, "Input/output error"), MemoryError()])
def test_a_failure_of_the_machine_is_not_the_recordings_result(small_fleet, tmp_path, monkeypatch, failure):
    """An OSError or MemoryError in the task was stored under its final key: never retried. Now it is
    read as a failure (the report lists it) but the next run computes the recording again; a bad
    recording (a DynidError) stays stored as before."""
    from dynid.analysis.fleet import task
    catalogue, paths = _sub_catalogue(small_fleet, tmp_path / "cat", 2, n_bad=1)
    store = ResultStore(tmp_path / "store")
    specs, _ = plan(catalogue, store)
    real = task.load_experiment

    def flaky(path, robot):
        if path == paths[0]:
            raise failure
        return real(path, robot)
    monkeypatch.setattr(task, "load_experiment", flaky)
    for spec in specs:
        store.write(identify_recording(spec))
    frame = store.read().drop_duplicates("key").set_index("recording")
    assert frame.loc[paths[0], "status"] == "error" and "the next run tries it again" in frame.loc[paths[0], "error"]
    assert frame.loc[paths[2], "status"] == "error" and "tries it again" not in frame.loc[paths[2], "error"]
    assert [s["path"] for s in plan(catalogue, store)[1]] == [paths[0]]
    monkeypatch.undo()
    store.write(identify_recording(next(s for s in specs if s["path"] == paths[0])))
    assert plan(catalogue, store)[1] == [] and len(store._files()) == 3       # the retry replaced
    assert store.read().set_index("recording").loc[paths[0], "status"].eq("ok").all()


def test_a_worker_that_died_is_retried_by_the_next_run(small_fleet, tmp_path, tcp_cluster, monkeypatch):
    """A KilledWorker was stored as the recording's error under its final key: the rerun said
    "already in the store" and exited 0. Now it is a failure of this run, and the rerun computes it."""
    import types

    distributed = pytest.importorskip("distributed")
    from dynid.analysis.fleet import engine
    catalogue, paths = _sub_catalogue(small_fleet, tmp_path / "cat", 2, n_bad=0)
    real = engine.identify_and_store

    def dies_on_the_first(spec, store_root):
        if spec["path"] == paths[0]:
            gone = types.SimpleNamespace(address="tcp://127.0.0.1:9")
            raise distributed.KilledWorker(f"dynid-fleet-{spec['key']}", gone, 0)
        return real(spec, store_root)
    monkeypatch.setattr(engine, "identify_and_store", dies_on_the_first)
    address = tcp_cluster.scheduler_address
    first = identify_fleet(catalogue, tmp_path / "store", scheduler=address)
    assert first.n_failed == 1 and "died" in first.errors[0][2] and "tries it again" in first.errors[0][2]
    monkeypatch.undo()
    rerun = identify_fleet(catalogue, tmp_path / "store", scheduler=address)
    assert (rerun.n_computed, rerun.n_skipped, rerun.n_failed) == (1, 1, 0)
    frame = ResultStore(tmp_path / "store").read()
    assert len(ResultStore(tmp_path / "store")._files()) == 2 and set(frame["status"]) == {"ok"}


def test_a_worker_that_died_after_storing_its_result_is_no_failure(small_fleet, tmp_path, tcp_cluster, monkeypatch):
    """A worker that stored the task's result and then died: the result stands in the store, so
    the run counts the task as done (it said "failed, the next run tries it again", and the next
    run skipped it)."""
    import types

    distributed = pytest.importorskip("distributed")
    from dynid.analysis.fleet import engine
    catalogue, paths = _sub_catalogue(small_fleet, tmp_path / "cat", 2, n_bad=0)
    real = engine.identify_and_store

    def dies_after_storing(spec, store_root):
        out = real(spec, store_root)
        if spec["path"] == paths[0]:
            gone = types.SimpleNamespace(address="tcp://127.0.0.1:9")
            raise distributed.KilledWorker(f"dynid-fleet-{spec['key']}", gone, 0)
        return out
    monkeypatch.setattr(engine, "identify_and_store", dies_after_storing)
    run = identify_fleet(catalogue, tmp_path / "store", scheduler=tcp_cluster.scheduler_address)
    assert run.n_failed == 0 and not run.errors
    assert not [f for f in ResultStore(tmp_path / "store")._files() if f.endswith(".retry.parquet")]


def test_store_reads_only_its_own_files_and_names_one_it_cannot_read(small_store, tmp_path):
    """A stray .parquet in the store made every later run an "internal error (ArrowInvalid ...)"."""
    store = copied(small_store, tmp_path / "store")
    day = Path(store._files()[0]).parent
    (day / "notes.parquet").write_text("not Parquet")                      # not a name of the store's
    pd.DataFrame({"a": [1]}).to_parquet(Path(store.root) / "summary.parquet")
    pd.testing.assert_frame_equal(store.read(), small_store.read())
    assert store.keys() == small_store.keys()
    own = sorted(store._files())
    Path(own[0]).write_bytes(b"torn")
    with pytest.raises(InputError, match=rf"{Path(own[0]).name}: this file of the fleet store cannot be read.*"
                                         rf"move it out of the store"):
        store.read()
    os.unlink(own[0])
    pd.DataFrame({"a": [1]}).to_parquet(own[1])            # a store's name, not the store's columns
    with pytest.raises(InputError, match=rf"{Path(own[1]).name}: .*\(it has no column key"):
        store.read()


def test_outputs_inside_the_store_are_refused_before_work(small_fleet, tmp_path, capsys):
    """`--json STORE/robot_id=A/day=.../res.parquet` was written into the store (and then read as one of its files)."""
    from dynid.fleet import run
    from dynid.reports.cli import main
    store = tmp_path / "st"
    (store / "robot_id=A").mkdir(parents=True)
    # an unreachable scheduler: a run that starts any work fails with another message
    offline = ["--scheduler", "tcp://127.0.0.1:9"]
    for opt, path in (("--json", store / "robot_id=A" / "res.parquet"), ("--report", store / "r.html")):
        rc = main(["fleet", small_fleet.catalogue, "--out", str(store), opt, str(path), *offline])
        assert rc == 2 and f"{opt} (" in (err := capsys.readouterr().err) and "inside the results store" in err
        assert not path.exists()
    with pytest.raises(InputError, match="inside the results store"):
        run(small_fleet.catalogue, store, json=store / ".." / "st" / "f.json", scheduler="tcp://127.0.0.1:9")
    assert [p.name for p in store.rglob("*")] == ["robot_id=A"]


def test_an_empty_store_name_is_refused_not_taken_for_the_current_folder(small_fleet, tmp_path, monkeypatch,
                                                                          capsys):
    from dynid.fleet import run
    from dynid.reports.cli import main
    monkeypatch.chdir(tmp_path)
    rc = main(["fleet", small_fleet.catalogue, "--out", "", "--scheduler", "tcp://127.0.0.1:9"])
    assert rc == 2 and "--out (store=) '': the folder name is empty" in capsys.readouterr().err
    with pytest.raises(InputError, match="folder name is empty"):
        run(small_fleet.catalogue, "", scheduler="tcp://127.0.0.1:9")
    assert list(tmp_path.iterdir()) == []         # nothing written in the current folder


def test_a_full_disk_while_storing_is_one_clear_error(small_fleet, tmp_path, tcp_cluster, monkeypatch, capsys,
                                                      caplog):
    """It printed Dask's "Compute Failed" block, then "internal error (OSError: [Errno 28] ...)"."""
    import errno

    import pyarrow.parquet as pq

    from dynid.reports.cli import main
    catalogue, _ = _sub_catalogue(small_fleet, tmp_path / "cat", 2, n_bad=0)

    def full(table, where, **options):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(pq, "write_table", full)
    rc = main(["fleet", catalogue, "--out", str(tmp_path / "store"), "--scheduler", tcp_cluster.scheduler_address])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "dynid fleet: error: cannot write " in err and str(tmp_path / "store") in err and "the disk is full" in err
    assert "internal error" not in err and "Compute Failed" not in err + caplog.text
    assert ResultStore(tmp_path / "store")._files() == []


def test_a_store_file_whose_column_has_another_type_is_named_with_the_column(small_fleet, small_store, tmp_path,
                                                                             capsys):
    """`value` saved as text made `dynid fleet` and `read_store` an "internal error (ArrowTypeError: Unable to
    merge: Field value has incompatible types ...)", naming no file (bad-input hunt, B1)."""
    import dynid.fleet
    from dynid.reports.cli import main
    store = copied(small_store, tmp_path / "store")
    bad = sorted(store._files())[0]
    frame = pd.read_parquet(bad)
    frame["value"] = frame["value"].astype(str)
    frame.to_parquet(bad)
    message = (rf"{Path(bad).name}: this file of the fleet store cannot be read \(its column value is "
               rf"(large_)?string, where the store's is double\).*move it out of the store")
    with pytest.raises(InputError, match=message):
        store.read()
    with pytest.raises(InputError, match=message):
        dynid.fleet.read_store(store.root)
    rc = main(["fleet", small_fleet.catalogue, "--out", store.root, "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert rc == 2 and "internal error" not in err and Path(bad).name in err and "its column value is" in err
    # a column given twice is named too (pyarrow's KeyError was another internal error)
    import pyarrow.parquet as pq
    table = pq.read_table(sorted(store._files())[1])
    pq.write_table(table.append_column("sigma", table["sigma"]), sorted(store._files())[1])
    os.unlink(bad)
    with pytest.raises(InputError, match=r"\(its column sigma appears 2 times\)"):
        store.read()


def test_store_files_of_other_string_time_and_integer_widths_read_together(small_store, tmp_path):
    """pandas writes `string` or `large_string`, times in [ns] or [us], by version: a store written by two
    versions is one store (the type check of B1 must not refuse it, nor the join fail)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    store = copied(small_store, tmp_path / "store")
    f = sorted(store._files())[0]
    table = pq.read_table(f)
    narrow = {pa.types.is_large_string: pa.string(), pa.types.is_timestamp: pa.timestamp("ns", tz="UTC"),
              pa.types.is_int64: pa.int32()}
    fields = []
    for field in table.schema:
        to = next((ty for test, ty in narrow.items() if test(field.type)), field.type)
        fields.append(pa.field(field.name, to))
    pq.write_table(table.cast(pa.schema(fields)), f)
    pd.testing.assert_frame_equal(store.read(), small_store.read(), check_dtype=False)
