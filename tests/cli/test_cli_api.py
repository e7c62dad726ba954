"""Every command-line subcommand is a function of the dynid package: the JSON each command
writes equals the JSON built from the public API (dynid.identify, dynid.validate,
dynid.verdict, dynid.run, dynid.sample, dynid.diagnose, dynid.report, dynid.demo,
dynid.simulate, dynid.excite) for the same inputs, version and timing fields aside."""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import dynid
from dynid.analysis import run as steps
from dynid.dynamics.base_parameters import base_parameters
from dynid.reports import cli_options
from dynid.reports.cli import COMMANDS, main

ROOT = Path(__file__).resolve().parents[2]

#: fields that differ from run to run by nature (package versions, clocks)
VOLATILE = ("versions", "seconds", "wall", "elapsed")


def _clean(doc):
    if isinstance(doc, dict):
        return {k: _clean(v) for k, v in doc.items() if not any(w in k for w in VOLATILE)}
    if isinstance(doc, list):
        return [_clean(v) for v in doc]
    return doc


def _same(cli_path, api_doc):
    cli = _clean(json.loads(cli_path.read_text()))
    api = _clean(json.loads(json.dumps(api_doc, default=str)))
    assert cli.keys() == api.keys()
    for key in cli:
        assert cli[key] == api[key], key


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A planar2 recording written by `dynid simulate`, and the API's simulation of the same."""
    folder = tmp_path_factory.mktemp("cli_api")
    csv, js = folder / "run.csv", folder / "sim.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--seed", "3", "--f0", "0.2",
                 "--harmonics", "5", "--noise-q", "1e-4", "--noise-tau", "0.3", "--out", str(csv),
                 "--json", str(js), "--quiet"]) == 0
    return csv, js


def test_every_subcommand_is_covered_here():
    # payload's CLI == API test is in tests/analysis/estimators/test_payload.py (it needs the payload plant's recordings)
    covered = {"robot", "simulate", "excite", "identify", "sample", "diagnose", "report", "demo", "fleet", "payload"}
    assert set(COMMANDS) == covered, "a new subcommand needs its CLI == API test in this file"


def test_gain_update_names_are_the_orchestrators():
    assert tuple(cli_options.GAIN_UPDATE_CHOICES) == tuple(steps.GAIN_UPDATES)


def test_torque_timing_names_are_the_recordings():
    from dynid.analysis.data.record import TORQUE_TIMINGS
    assert tuple(cli_options.TORQUE_TIMING_CHOICES) == TORQUE_TIMINGS


def test_robot(tmp_path):
    js = tmp_path / "r.json"
    assert main(["robot", "planar2", "--json", str(js), "--quiet"]) == 0
    robot = dynid.load_robot("planar2")
    bp = base_parameters(robot)
    doc = json.loads(js.read_text())
    assert doc["standard"] == robot.standard_names and doc["base"] == json.loads(json.dumps(bp.table()))
    assert doc["regrouping_matrix"] == bp.matrix.tolist()


def test_simulate(recording):
    csv, js = recording
    sim = dynid.simulate(dynid.load_robot("planar2"), 8.0, seed=3, f0=0.2, harmonics=5, noise_q=1e-4,
                         noise_tau=0.3)
    _same(js, dict(sim.to_dict(), csv=str(csv)))


def test_excite(tmp_path):
    js = tmp_path / "e.json"
    assert main(["excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--starts", "2",
                 "--criterion", "logdet", "--margin", "0.9", "--seed", "4", "--json", str(js), "--quiet"]) == 0
    res = dynid.excite("planar2", 0.2, 3, n_starts=2, criterion="logdet", margin=0.9, rng=4)
    _same(js, dict(res.to_dict(), csv=None))


def test_identify_idim_with_holdout_is_identify_validate_verdict(recording, tmp_path):
    """The snippet of the guide: dynid.verdict(dynid.identify(train, robot), held_out)."""
    csv, _ = recording
    js = tmp_path / "i.json"
    assert main(["identify", str(csv), "--robot", "planar2", "--holdout", "2", "--nd", "5",
                 "--max-error-growth", "0.03", "--json", str(js), "--quiet"]) == 0
    robot = dynid.load_robot("planar2")
    train, held_out = dynid.holdout_split(dynid.load_experiment(str(csv), robot), 2.0)
    r = dynid.identify(train, robot, nd=5, max_error_growth=0.03)
    v = dynid.verdict(dynid.identify(train, robot, nd=5, max_error_growth=0.03), held_out)
    assert str(v) == v.summary() and v.status
    _same(js, dict(r.to_dict(), verdict=v.to_dict(), validation=dynid.validate(r, held_out).to_dict()))


def test_identify_options_are_run_options(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "o.json"
    assert main(["identify", str(csv), "--robot", "planar2", "--holdout", "2", "--qd-threshold", "0.01,0.02",
                 "--asymmetric-friction", "--csv", str(tmp_path / "p.csv"),
                 "--json", str(js), "--quiet"]) == 0
    run = dynid.run(str(csv), "planar2", holdout=2, qd_threshold="0.01,0.02", asymmetric_friction=True,
                    write=False)
    assert run.asymmetric_friction is not None
    _same(js, run.to_dict())
    assert str(run.verdict) in str(run)


@pytest.mark.slow
def test_identify_gravity_tilt(tmp_path):
    """planar2 moves in the plane of gravity (no tilt to see): the real LWR4+ recording."""
    data = str(ROOT / "examples" / "kuka_lwr4" / "recording_2.toml")
    js = tmp_path / "t.json"
    assert main(["identify", data, "--robot", "kuka_lwr4", "--gravity-tilt", "--json", str(js), "--quiet"]) == 0
    run = dynid.run(data, "kuka_lwr4", gravity_tilt=True, write=False)
    assert run.tilt is not None and run.robot is run.tilt.robot
    _same(js, run.to_dict())


def test_identify_physical_and_urdf(recording, tmp_path):
    pytest.importorskip("cvxpy")
    csv, _ = recording
    js, urdf = tmp_path / "p.json", tmp_path / "p.urdf"
    assert main(["identify", str(csv), "--robot", "planar2", "--validation", str(csv), "--physical",
                 "--bootstrap", "5", "--prior", "apriori", "--prior-weight", "0.5", "--urdf", str(urdf),
                 "--json", str(js), "--quiet"]) == 2            # the same file twice: refused
    train, held_out = tmp_path / "train.csv", tmp_path / "held.csv"
    robot = dynid.load_robot("planar2")
    a, b = dynid.holdout_split(dynid.load_experiment(str(csv), robot), 2.0)
    a.to_frame().to_csv(train, index=False, float_format="%.17g")
    b.to_frame().to_csv(held_out, index=False, float_format="%.17g")
    assert main(["identify", str(train), "--robot", "planar2", "--validation", str(held_out), "--physical",
                 "--bootstrap", "5", "--prior", "apriori", "--prior-weight", "0.5", "--urdf", str(urdf),
                 "--json", str(js), "--quiet"]) == 0
    run = dynid.run(str(train), "planar2", validation=str(held_out), physical=True, bootstrap=5,
                    prior="apriori", prior_weight=0.5, urdf=str(tmp_path / "api.urdf"), write=False)
    assert run.physical.idim is run.result and run.physical.validation is not None
    assert run.export.text == urdf.read_text()
    _same(js, run.to_dict())


def test_identify_didim(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "d.json"
    code = main(["identify", str(csv), "--robot", "planar2", "--method", "didim", "--max-iter", "2",
                 "--gain-update", "initial", "--json", str(js), "--quiet"])
    assert code in (0, 3)
    r = dynid.identify(str(csv), "planar2", "didim", max_iter=2, gain_update="initial")
    assert any("gains assumed in the robot file" in n for n in r.notices)
    _same(js, dict(r.to_dict(), verdict=dynid.verdict(r).to_dict()))


def test_identify_projection(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "pm.json"
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "projection", "--json", str(js),
                 "--quiet"]) == 0
    r = dynid.identify(str(csv), "planar2", "projection")
    _same(js, dict(r.to_dict(), verdict=dynid.verdict(r).to_dict()))


@pytest.mark.slow
def test_identify_ml(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "ml.json"
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "ml", "--f0", "0.2",
                 "--ml-harmonics", "5", "--json", str(js), "--quiet"]) == 0
    r = dynid.identify(str(csv), "planar2", "ml", f0=0.2, ml_harmonics=5)
    _same(js, dict(r.to_dict(), verdict=dynid.verdict(r).to_dict()))


def test_sample(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "s.json"
    main(["sample", str(csv), "--robot", "planar2", "--seed", "2", "--max-steps", "300", "--walkers", "40",
          "--max-seconds", "600", "--json", str(js), "--quiet", "--allow-unconverged"])
    r = dynid.identify(str(csv), "planar2")
    post = dynid.sample(r, seed=2, max_steps=300, n_walkers=40, max_seconds=600)
    _same(js, dict(post.to_dict(), verdict=dynid.verdict(r).to_dict()))


@pytest.mark.slow
def test_diagnose(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "g.json"
    assert main(["diagnose", str(csv), "--robot", "planar2", "--holdout", "2", "--effects", "offset,stribeck",
                 "--max-effects", "1", "--alpha", "0.05", "--json", str(js), "--quiet"]) == 0
    robot = dynid.load_robot("planar2")
    train, held_out = dynid.holdout_split(dynid.load_experiment(str(csv), robot), 2.0)
    r = dynid.identify(train, robot)
    diag = dynid.diagnose(train, robot, validation=held_out, idim_result=r, effects=["offset", "stribeck"],
                          max_effects=1, alpha=0.05)
    r = diag.idim if diag.idim is not None else r
    validation = dynid.validate(r, held_out)
    v = steps.verdict_of(r, validation, diagnosis=diag)
    _same(js, dict(diag.to_dict(), verdict=v.to_dict(), validation=validation.to_dict()))


def test_report(recording, tmp_path):
    csv, _ = recording
    js = tmp_path / "f.json"
    assert main(["report", str(csv), "--robot", "planar2", "--holdout", "2", "--skip", "sample,diagnose",
                 "--max-iter", "2", "--gain-update", "every", "--report", str(tmp_path / "f.html"),
                 "--json", str(js), "--quiet"]) in (0, 3)
    out = dynid.report(str(csv), "planar2", holdout=2, skip=("sample", "diagnose"), max_iter=2,
                       gain_update="every")
    assert dynid.verdict(out) is out.verdict
    assert any("gains assumed in the robot file" in n for n in out.didim.notices)
    _same(js, out.to_dict())


def test_demo(tmp_path_factory):
    """`dynid demo --skip didim,sample,diagnose --duration 5 --seed 2 --report demo.html --json demo.json`
    (a seed other than the default, so that the option is seen to reach the demo): the
    console script's run that tests/cli/test_output_schemas.py and tests/reports/test_browser.py read
    (made once per session), or `main` in this process where there is no console script."""
    from shared_runs import DEMO_IDIM_ARGS, DYNID, demo_idim_run
    if DYNID.exists():
        run = demo_idim_run(tmp_path_factory)
        assert run.returncode == 0, run.stderr[-3000:]
        folder = run.folder
    else:
        folder = tmp_path_factory.mktemp("demo")
        assert main([str(folder / a) if a.startswith("demo.") else a for a in DEMO_IDIM_ARGS]) == 0
    out = dynid.demo(seed=2, duration=5, skip=("didim", "sample", "diagnose"))
    _same(folder / "demo.json", out.to_dict())


@pytest.mark.slow
def test_fleet(tmp_path):
    pytest.importorskip("distributed")
    from simulated_fleet import simulate_fleet

    import dynid.fleet
    cat = simulate_fleet(tmp_path / "fleet", 2, 5, seed=5, n_corrupted=0).catalogue
    js = tmp_path / "fleet.json"
    assert main(["fleet", str(cat), "--out", str(tmp_path / "cli"), "--workers", "1", "--baseline", "3",
                 "--json", str(js), "--quiet"]) == 0
    dynid.fleet.run(str(cat), tmp_path / "api", workers=1, n_baseline=3, json=tmp_path / "api.json")
    cli, api = (_clean(json.loads(p.read_text())) for p in (js, tmp_path / "api.json"))
    assert cli["robots"] and cli["robots"] == api["robots"]     # per robot: parameters, alarms
    assert {k: v for k, v in cli.items() if k not in ("store", "robots")} == \
        {k: v for k, v in api.items() if k not in ("store", "robots")}


def test_renamed_keywords_still_work_with_a_warning(recording):
    csv, _ = recording
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        settings = steps.settings_from(None, update_gains="initial", n_boot=7)
    assert settings.gain_update == "initial" and settings.bootstrap == 7
    assert [w.category for w in caught] == [DeprecationWarning, DeprecationWarning]
    with pytest.raises(dynid.InputError, match="not both"), pytest.warns(DeprecationWarning):
        steps.settings_from(None, update_gains=True, gain_update="none")


def test_a_misspelt_keyword_is_named_with_its_near_miss():
    """identify, sample and the run's options say which keyword was meant; a settings key that is no
    processing setting is bad input (it was a DataError, the class of unreadable data files)."""
    import dynid
    from dynid.errors import DataError, InputError
    with pytest.raises(TypeError, match=r"'max_iters' \(did you mean 'max_iter'\?\)"):
        dynid.identify("x.csv", "planar2", max_iters=3)
    with pytest.raises(TypeError, match=r"'holdot'.*dynid.holdout_split"):
        dynid.identify("x.csv", "planar2", holdot=3)
    with pytest.raises(TypeError, match=r"sample\(\) got an unexpected keyword argument 'max_step' "
                                        r"\(did you mean 'max_steps'\?\)"):
        dynid.sample(object(), max_step=3)
    with pytest.raises(InputError, match=r"holdot \(did you mean 'holdout'\?\)"):
        dynid.run("x.csv", "planar2", holdot=3)
    exp = dynid.simulate("planar2", duration=2.0, seed=1).experiment
    with pytest.raises(InputError, match=r"fc_positon \(did you mean 'fc_position'\?\)") as info:
        dynid.identify(exp, "planar2", settings={"fc_positon": 50})
    assert not isinstance(info.value, DataError)


def test_identify_and_sample_report_progress_without_a_callable(monkeypatch):
    """Long work is not silent in Python: without progress=, identify and sample hand the estimator
    one of dynid.progress's reporters (a bar, or a line on stderr every 10 s); a given one is kept."""
    from dynid.analysis import identify as ident
    from dynid.analysis.sampling import sample as sampling
    seen = []
    monkeypatch.setattr(ident, "identify_step", lambda *a, progress=None, **k: seen.append(progress))
    exp = dynid.simulate("planar2", duration=2.0, seed=1).experiment
    dynid.identify(exp, "planar2")
    mine = lambda f: None   # noqa: E731
    dynid.identify(exp, "planar2", progress=mine)
    monkeypatch.setattr(sampling, "sample_idim", lambda r, **k: seen.append(k["progress"]))
    dynid.sample(object())
    assert callable(seen[0]) and seen[1] is mine and callable(seen[2])


def test_diagnose_reports_progress_without_a_callable(monkeypatch):
    from dynid.analysis.diagnosis import selection
    seen = []
    monkeypatch.setattr(selection, "diagnose", lambda *a, progress=None, **k: seen.append(progress))
    dynid.diagnose(dynid.simulate("planar2", duration=2.0, seed=1).experiment, "planar2")
    assert callable(seen[0])


def test_diagnose_refuses_several_recordings():
    """It diagnosed the first and dropped the others without a word."""
    exp = dynid.simulate("planar2", duration=2.0, seed=1).experiment
    with pytest.raises(dynid.InputError, match="one recording at a time, 2 were given"):
        dynid.diagnose([exp, exp], "planar2")


def test_a_recording_that_does_not_move_is_named():
    """A still validation recording got the dead-zone message without its file name (a bad-input hunt)."""
    import dataclasses

    import numpy as np
    exp = dynid.simulate("planar2", duration=3.0, seed=1).experiment
    still = dataclasses.replace(exp, q=np.broadcast_to(exp.q[:1], exp.q.shape).copy(), source="still.csv")
    with pytest.raises(dynid.DataError, match="still.csv: no joint moves"):
        dynid.identify(still, "planar2")


def test_a_holdout_that_leaves_too_little_says_so():
    """A --holdout that took most of the recording got "excite a richer trajectory" (a bad-input hunt)."""
    exp = dynid.simulate("planar2", duration=4.0, seed=1).experiment
    with pytest.raises(dynid.IdentificationError, match=r"--holdout 3.9 s leaves the first 0.0\d+ s"):
        dynid.run(exp, "planar2", holdout=3.9)


def test_a_run_that_did_not_converge_names_the_outputs_that_say_so(recording, tmp_path, capsys):
    """Exit 3 says which outputs carry it: the JSON does, a CSV has no field for it (it holds the
    last step's values); "the outputs say so" was wrong for a CSV alone."""
    csv, _ = recording
    args = ["identify", str(csv), "--robot", "planar2", "--method", "didim", "--max-iter", "1", "--quiet"]
    assert main(args + ["--csv", str(tmp_path / "d.csv"), "--json", str(tmp_path / "d.json")]) == 3
    err = capsys.readouterr().err
    assert "DIDIM did not converge" in err and "the JSON says so" in err, err
    assert "the CSV holds the last step's values, with no mark of it" in err, err
    assert json.loads((tmp_path / "d.json").read_text())["converged"] is False
    assert main(args + ["--csv", str(tmp_path / "e.csv")]) == 3          # --quiet: no summary either
    err = capsys.readouterr().err
    assert "no output file says so (--json would); the CSV holds" in err, err
    assert main([a for a in args if a != "--quiet"] + ["--csv", str(tmp_path / "f.csv")]) == 3
    captured = capsys.readouterr()
    assert "its summary says so; the CSV holds" in captured.err and "DID NOT CONVERGE" in captured.out


def test_diagnose_without_an_identification_reports_the_runs_sigma():
    """dynid.diagnose identified with the classic σ when given no identification, where
    dynid.identify and `dynid diagnose` report the bootstrap's; the decisions do not change."""
    sim = dynid.simulate("planar2", duration=6.0, seed=3)
    train, held_out = dynid.holdout_split(sim.experiment, 2.0)
    default = dynid.diagnose(train, "planar2", validation=held_out, effects=["offset", "stribeck"], max_effects=1)
    classic = dynid.diagnose(train, "planar2", validation=held_out, effects=["offset", "stribeck"], max_effects=1,
                             uncertainty="classic")
    assert default.settings["parameters_uncertainty"] == "bootstrap"
    assert classic.settings["parameters_uncertainty"] == "classic"
    assert [s.name for s in default.selected] == [s.name for s in classic.selected]
    assert np.array_equal(default.model_after.chi, classic.model_after.chi)
    assert not np.allclose(default.model_after.bse, classic.model_after.bse)
    with pytest.raises(dynid.InputError, match="uncertainty must be one of"):
        dynid.diagnose(train, "planar2", uncertainty="robust")
