"""The dynid command line: every subcommand's help, the robot command, exit codes."""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from dynid.reports.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_subcommand_help_runs_and_shows_examples(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "usage: dynid " + command in out
    assert "examples:" in out


def test_top_level_help_lists_commands_and_exit_codes(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command in out
    assert "exit codes" in out


def test_robot_tx40_prints_dh_and_base_parameters(capsys, tmp_path):
    out_json = tmp_path / "tx40.json"
    assert main(["robot", "tx40", "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert "modified DH" in out and "86 standard parameters" in out and "60 base parameters" in out
    assert "ZZ1R = ZZ1 + Ia1 + YY2 + YY3" in out
    doc = json.loads(out_json.read_text())
    assert len(doc["standard"]) == 86 and len(doc["base"]) == 60
    assert {"name", "relation"} <= set(doc["base"][0])
    assert doc["base"][0]["relation"].startswith("ZZ1R = ZZ1 + Ia1")


def test_robot_from_urdf_and_toml_files(capsys):
    assert main(["robot", str(ROOT / "dynamics" / "robots" / "kuka_lwr4.urdf")]) == 0
    assert "base parameters" in capsys.readouterr().out
    assert main(["robot", str(ROOT / "dynamics" / "robots" / "planar2.toml")]) == 0
    out = capsys.readouterr().out
    assert "13 base parameters" in out and "ZZ1R = ZZ1 + Ia1 + M2" in out


def test_unknown_robot_is_bad_input(capsys):
    assert main(["robot", "no_such_robot"]) == 2
    err = capsys.readouterr().err
    assert "no_such_robot" in err and "tx40" in err and "Traceback" not in err


def test_robot_file_typo_in_controller_is_named(tmp_path, capsys):
    text = (ROOT / "dynamics" / "robots" / "planar2.toml").read_text().replace("zeta =", "zetta =")
    f = tmp_path / "arm.toml"
    f.write_text(text)
    assert main(["robot", str(f)]) == 2
    err = capsys.readouterr().err
    assert "arm.toml" in err and "zetta" in err


def test_missing_command_prints_help_and_exits_2(capsys):
    assert main([]) == 2


def test_console_script_module_runs():
    out = subprocess.run([sys.executable, "-m", "dynid.reports.cli", "robot", "--list"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "tx40" in out.stdout


# the smallest valid command line of each subcommand; a new subcommand must be added here
MINIMAL_ARGS = {
    "robot": [], "demo": [],
    "identify": ["x", "--robot", "tx40"], "sample": ["x", "--robot", "tx40"],
    "diagnose": ["x", "--robot", "tx40"], "report": ["x", "--robot", "tx40", "--report", "r.html"],
    "simulate": ["--robot", "tx40", "--out", "x.csv"],
    "excite": ["--robot", "tx40", "--f0", "0.1", "--harmonics", "5"],
    "fleet": ["catalogue.csv", "--out", "store"],
    "payload": ["--robot", "tx40", "--loaded", "x", "--model", "m.json"],
}


def test_parser_is_consistent():
    parser = build_parser()
    assert set(MINIMAL_ARGS) == set(COMMANDS)
    for command in COMMANDS:
        args = parser.parse_args([command] + MINIMAL_ARGS[command])
        assert args.command == command and hasattr(args, "quiet") and hasattr(args, "debug")
        assert hasattr(args, "json"), f"{command} has no --json"


def test_simulate_then_identify_recovers_the_robot_file_values(tmp_path):
    csv, js = tmp_path / "run.csv", tmp_path / "id.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "10", "--out", str(csv), "--quiet"]) == 0
    header = csv.read_text().splitlines()[0].split(",")
    assert header == ["t", "q1", "q2", "qr1", "qr2", "tau1", "tau2"]
    assert main(["identify", str(csv), "--robot", "planar2", "--json", str(js), "--quiet"]) == 0
    est = {p["name"]: p for p in json.loads(js.read_text())["parameters"]}
    # planar2.toml a-priori values, regrouped (closed form): ZZ1R = ZZ1 + Ia1 + d2^2 M2
    expected = {"ZZ1R": 0.6667 + 0.05 + 2.0, "MX1R": 1.0 + 2.0, "ZZ2": 0.6667, "MX2": 1.0, "Ia2": 0.05}
    for name, value in expected.items():
        assert abs(est[name]["value"] - value) <= 3 * est[name]["std"] + 1e-3 * abs(value), name


def test_simulate_needs_a_controller(tmp_path, capsys):
    text = (ROOT / "dynamics" / "robots" / "planar2.toml").read_text()
    text = text[:text.index("[controller]")] + text[text.index("[apriori]"):]
    f = tmp_path / "noctl.toml"
    f.write_text(text)
    assert main(["simulate", "--robot", str(f), "--out", str(tmp_path / "x.csv")]) == 2
    assert "controller" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.slow
def test_sample_on_real_tx40_converges_and_writes_outputs(tmp_path):
    js, csv, html = tmp_path / "p.json", tmp_path / "p.csv", tmp_path / "p.html"
    code = main(["sample", str(ROOT / "examples" / "staubli_tx40" / "experiment.toml"), "--robot", "tx40",
                 "--json", str(js), "--csv", str(csv), "--report", str(html), "--quiet"])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["converged"] else 3)
    assert doc["converged"], doc.get("reason")
    assert csv.read_text().count("\n") > 1000
    assert "posterior" in html.read_text().lower()


def test_sample_reports_non_convergence_with_exit_3(tmp_path):
    js = tmp_path / "p.json"
    code = main(["sample", str(ROOT / "examples" / "staubli_tx40" / "experiment.toml"), "--robot", "tx40",
                 "--max-steps", "50", "--json", str(js), "--quiet"])
    assert code == 3
    assert json.loads(js.read_text())["converged"] is False


def test_identify_didim_from_reference_and_torque_only(tmp_path):
    import pandas as pd
    csv, js = tmp_path / "run.csv", tmp_path / "didim.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "10", "--out", str(csv), "--quiet"]) == 0
    frame = pd.read_csv(csv)
    frame.drop(columns=["q1", "q2"]).to_csv(csv, index=False)        # DIDIM needs no positions
    code = main(["identify", str(csv), "--robot", "planar2", "--method", "didim", "--json", str(js), "--quiet"])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["converged"] else 3)
    assert doc["method"] == "DIDIM" and doc["converged"]
    est = {p["name"]: p["value"] for p in doc["parameters"]}
    assert est["ZZ1R"] == pytest.approx(0.6667 + 0.05 + 2.0, rel=0.03)
    assert est["MX1R"] == pytest.approx(3.0, rel=0.03)


# A second full TX40 design (4 starts, ~10 s on an idle machine): the default suite checks the design's
# limits on a dense grid and its CSV export in tests/dynamics/test_excitation.py (same robot, f0 and
# harmonics), and the excite command's outputs in test_excite_json_to_stdout_is_the_only_stdout,
# tests/cli/test_cli_api.py::test_excite and tests/cli/test_output_schemas.py::test_excite_json.
@pytest.mark.slow
def test_excite_tx40_as_in_the_issue_respects_limits_in_the_written_csv(tmp_path):
    """`dynid excite --robot tx40 --f0 0.1 --harmonics 5 --out traj.csv --json ex.json`.

    The CSV is checked on its own: velocities within the robot file's limits,
    positions within the ranges, and q consistent with the integral of qd
    (trapezoid rule over the written samples, independent of the Fourier formulae).
    """
    import numpy as np
    import pandas as pd

    from dynid.dynamics.robot_file import load_robot
    traj, js = tmp_path / "traj.csv", tmp_path / "ex.json"
    assert main(["excite", "--robot", "tx40", "--f0", "0.1", "--harmonics", "5", "--out", str(traj),
                 "--json", str(js), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    assert np.shape(doc["a"]) == (6, 5) and np.shape(doc["b"]) == (6, 5) and len(doc["q0"]) == 6
    assert doc["feasible"] and doc["cond_result"] < doc["cond_start"]
    assert set(doc["margins"]) == {f"j{k}" for k in range(1, 7)}
    frame = pd.read_csv(traj)
    robot = load_robot("tx40")
    q_min, q_max, qd_max, qdd_max, _ = robot.limits()
    q = frame[[f"qr{k}" for k in range(1, 7)]].to_numpy()
    qd = frame[[f"qdr{k}" for k in range(1, 7)]].to_numpy()
    qdd = frame[[f"qddr{k}" for k in range(1, 7)]].to_numpy()
    t = frame["t"].to_numpy()
    assert t[-1] + (t[1] - t[0]) == pytest.approx(10.0)      # one whole period of 1 / f0
    assert np.all(q >= q_min) and np.all(q <= q_max)
    assert np.all(np.abs(qd) <= qd_max) and np.all(np.abs(qdd) <= qdd_max)
    q_int = q[0] + np.concatenate([np.zeros((1, 6)), np.cumsum((qd[1:] + qd[:-1]) / 2 * np.diff(t)[:, None], 0)])
    assert np.max(np.abs(q_int - q)) < 1e-4


def test_excite_json_to_stdout_is_the_only_stdout(capsys):
    assert main(["excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--starts", "1",
                 "--json", "-"]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)                 # nothing but the JSON on stdout
    assert doc["robot"] == "planar2" and doc["harmonics"] == 3
    assert "cond" in captured.err                  # the summary went to stderr


def test_identify_json_to_stdout(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--out", str(csv), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["identify", str(csv), "--robot", "planar2", "--json", "-"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {p["name"] for p in doc["parameters"]} >= {"ZZ1R", "MX1R", "ZZ2"}


def test_diagnose_finds_an_injected_torque_offset(tmp_path):
    """A constant 2 N m added to the logged torque of joint 2 of a simulated run,
    diagnosed without the Off_j columns: the offset (or its alias on these data,
    an asymmetric Coulomb term) is selected on joint 2, and the error drops."""
    import pandas as pd
    csv, js, html = tmp_path / "run.csv", tmp_path / "d.json", tmp_path / "d.html"
    assert main(["simulate", "--robot", "planar2", "--duration", "16", "--seed", "3", "--out", str(csv),
                 "--quiet"]) == 0
    frame = pd.read_csv(csv)
    frame["tau2"] += 2.0
    frame.to_csv(csv, index=False)
    assert main(["diagnose", str(csv), "--robot", "planar2", "--holdout", "4", "--no-offsets",
                 "--json", str(js), "--report", str(html), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    first = doc["selected"][0]
    assert first["joint"] == 2 and first["name"] in ("offset", "asymmetric_coulomb")
    err = doc["errors"]["validation"]
    assert err["after"]["rel_error"] < 0.8 * err["before"]["rel_error"]
    assert "diagnos" in html.read_text().lower()


def test_diagnose_rejects_unknown_effect_names_before_any_work(capsys):
    assert main(["diagnose", "nonexistent.csv", "--robot", "planar2", "--effects", "stribeck,gremlins"]) == 2
    assert "gremlins" in capsys.readouterr().err


def test_diagnose_says_it_takes_one_recording_before_loading_them(capsys):
    """A second recording got argparse's "unrecognized arguments" (a first-hour review)."""
    assert main(["diagnose", "nonexistent1.csv", "nonexistent2.csv", "--robot", "planar2"]) == 2
    err = capsys.readouterr().err
    assert "one recording at a time, 2 were given" in err and "--validation" in err and "not found" not in err


def test_report_runs_every_part_on_one_recording(tmp_path_factory):
    """`dynid simulate` then `dynid report` with every part, run once per session
    (tests/cli/test_output_schemas.py validates the same run's JSON)."""
    from shared_runs import planar2_full_report_run
    run = planar2_full_report_run(tmp_path_factory)
    js, html = run.folder / "r.json", run.folder / "r.html"
    assert js.exists(), run.stderr[-3000:]
    code = run.returncode
    doc = json.loads(js.read_text())
    assert code == (3 if doc["problems"] else 0)
    assert set(doc) >= {"parameters", "essential", "validation", "didim", "posterior", "diagnosis"}
    text = html.read_text()
    for word in ("DIDIM", "osterior", "iagnosis", "alidation"):
        assert word in text


def test_report_rejects_unknown_parts(capsys):
    assert main(["report", "x.csv", "--robot", "planar2", "--report", "r.html", "--skip", "didim,magic"]) == 2
    assert "magic" in capsys.readouterr().err
    # repeated --skip adds up (it used to keep only the last)
    assert main(["report", "x.csv", "--robot", "planar2", "--report", "r.html", "--skip", "didim",
                 "--skip", "magic"]) == 2
    assert "magic" in capsys.readouterr().err
    from dynid.analysis.further import check_parts
    assert check_parts(["didim,sample", "diagnose"]) == {"didim", "sample", "diagnose"}
    assert check_parts("didim, sample") == {"didim", "sample"} and check_parts(None) == set()


def test_identify_projection_method_recovers_the_robot_file_values(tmp_path):
    csv, js = tmp_path / "run.csv", tmp_path / "pm.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--out", str(csv), "--quiet"]) == 0
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "projection", "--json", str(js),
                 "--quiet"]) == 0
    est = {p["name"]: p for p in json.loads(js.read_text())["parameters"]}
    # closed-form regrouping of planar2.toml's a-priori values (as in the IDIM test above)
    for name, value in {"ZZ1R": 0.6667 + 0.05 + 2.0, "MX1R": 3.0, "ZZ2": 0.6667, "MX2": 1.0}.items():
        assert abs(est[name]["value"] - value) <= 3 * est[name]["std"], name
        assert est[name]["std"] < 0.25 * abs(value), name          # and the test has teeth


def test_identify_projection_needs_the_reference(tmp_path, capsys):
    import pandas as pd
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "4", "--out", str(csv), "--quiet"]) == 0
    pd.read_csv(csv).drop(columns=["qr1", "qr2"]).to_csv(csv, index=False)
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "projection"]) == 2
    assert "qr" in capsys.readouterr().err


def test_identify_asymmetric_friction_goes_to_json_and_report(tmp_path):
    csv, js, html = tmp_path / "run.csv", tmp_path / "a.json", tmp_path / "a.html"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--out", str(csv), "--quiet"]) == 0
    assert main(["identify", str(csv), "--robot", "planar2", "--asymmetric-friction", "--json", str(js),
                 "--report", str(html), "--quiet"]) == 0
    joints = json.loads(js.read_text())["asymmetric_friction"]["joints"]
    # planar2.toml: symmetric friction Fv1 = 0.5, Fc1 = 1.0 -> both signs alike
    for key, value in (("Fv+", 0.5), ("Fv-", 0.5), ("Fc+", 1.0), ("Fc-", 1.0)):
        assert abs(joints[0][key]["value"] - value) < 4 * joints[0][key]["std"] + 0.02 * value, key
    assert 'id="asymmetric-friction"' in html.read_text()


def test_missing_output_folder_is_refused_before_any_work_and_existing_files_survive(tmp_path, capsys):
    old = tmp_path / "a.json"
    old.write_text('{"old": true}')
    code = main(["identify", "no-such-data.csv", "--robot", "planar2", "--json", str(old),
                 "--report", str(tmp_path / "missing" / "x.html")])
    assert code == 2
    err = capsys.readouterr().err
    assert "--report" in err and "does not exist" in err
    assert old.read_text() == '{"old": true}'


def test_commit_outputs_is_all_or_none_and_keeps_existing_files(tmp_path):
    from dynid.errors import InputError
    from dynid.reports.cli import commit_outputs
    old = tmp_path / "a.json"
    old.write_text("old")
    with pytest.raises(InputError, match="cannot write"):
        commit_outputs([(old, "new"), (tmp_path / "gone" / "b.html", "x")], lambda m: None)
    assert old.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]      # no temporary files left


def test_only_json_goes_to_stdout(capsys):
    assert main(["excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--out", "-"]) == 2
    assert "only --json" in capsys.readouterr().err


def test_options_that_need_idim_are_refused_with_other_methods(capsys):
    assert main(["identify", "x.csv", "--robot", "planar2", "--method", "didim", "--holdout", "2"]) == 2
    assert "--holdout" in capsys.readouterr().err
    assert main(["identify", "x.csv", "--robot", "planar2", "--method", "projection", "--urdf", "m.urdf"]) == 2
    assert "--urdf" in capsys.readouterr().err


def test_excite_refuses_a_sampling_rate_below_the_harmonics(capsys):
    assert main(["excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--fs", "1",
                 "--out", "x.csv"]) == 2
    assert "--fs" in capsys.readouterr().err


def test_demo_refuses_a_negative_duration(capsys):
    assert main(["demo", "--duration", "-1", "--report", "x.html"]) == 2
    assert "--duration" in capsys.readouterr().err


def test_demo_takes_its_didim_options(capsys, monkeypatch):
    """`demo --max-iter` and `--gain-update` were parsed and dropped (DIDIM ran its default number of steps)."""
    assert main(["demo", "--max-iter", "0", "--report", "x.html"]) == 2
    assert "--max-iter" in capsys.readouterr().err
    from dynid.reports import pipeline
    seen = {}
    monkeypatch.setattr(pipeline, "run_demo", lambda **kw: (_ for _ in ()).throw(SystemExit(seen.update(kw))))
    monkeypatch.setattr(pipeline, "_report_settings",
                        lambda settings, options, _f=pipeline._report_settings: seen.update(s=_f(settings, options))
                        or seen["s"])
    with pytest.raises(SystemExit):
        pipeline.demo(max_iter=3, gain_update="every")
    assert seen["s"].max_iter == 3 and seen["s"].gain_update == "every"


def test_identify_maximum_likelihood_recovers_the_robot_file_values(tmp_path):
    csv, js, html = tmp_path / "run.csv", tmp_path / "ml.json", tmp_path / "ml.html"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--out", str(csv), "--quiet"]) == 0
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "ml", "--f0", "0.1",
                 "--ml-harmonics", "20", "--json", str(js), "--report", str(html), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    est = {p["name"]: p for p in doc["parameters"]}
    for name, value in {"ZZ1R": 0.6667 + 0.05 + 2.0, "MX1R": 3.0, "ZZ2": 0.6667, "MX2": 1.0}.items():
        assert abs(est[name]["value"] - value) <= 4 * est[name]["std"] + 2e-3 * value, name
    assert 'id="maximum-likelihood"' in html.read_text()


def test_identify_ml_needs_f0(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "2", "--out", str(csv), "--quiet"]) == 0
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "ml"]) == 2
    assert "--f0" in capsys.readouterr().err


def test_didim_coulomb_sign_width_option(tmp_path, capsys):
    """--v-s reaches DIDIM's simulation (the JSON's settings say it), and is refused for other methods."""
    csv, js = tmp_path / "run.csv", tmp_path / "didim.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "10", "--out", str(csv), "--quiet"]) == 0
    code = main(["identify", str(csv), "--robot", "planar2", "--method", "didim", "--v-s", "0.02",
                 "--json", str(js), "--quiet"])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["converged"] else 3)
    assert doc["settings"]["v_s"] == 0.02 and doc["settings"]["v_s_choice"] == "given"
    # the default is "auto": the JSON says which v_s was used and how it was chosen
    code = main(["identify", str(csv), "--robot", "planar2", "--method", "didim", "--v-s", "auto",
                 "--json", str(js), "--quiet"])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["converged"] else 3)
    assert doc["settings"]["v_s"] > 0 and doc["settings"]["v_s_choice"].startswith("auto")
    capsys.readouterr()
    assert main(["identify", str(csv), "--robot", "planar2", "--method", "didim", "--v-s", "sharp"]) == 2
    assert "Traceback" not in capsys.readouterr().err
    assert main(["identify", str(csv), "--robot", "planar2", "--v-s", "0.02", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--v-s" in err and "Traceback" not in err


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_fits_a_screen_and_help_all_lists_every_option(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    short = capsys.readouterr().out
    assert len(short.splitlines()) <= 60, f"dynid {command} --help: {len(short.splitlines())} lines"
    with pytest.raises(SystemExit) as exc:
        main([command, "--help-all"])
    assert exc.value.code == 0
    full = capsys.readouterr().out
    sub = next(a for a in build_parser(full=True)._actions if hasattr(a, "choices") and a.choices
               and command in a.choices).choices[command]
    for action in sub._actions:
        for option in action.option_strings:
            assert option in full, f"dynid {command} --help-all lacks {option}"
    # plain help texts: no benchmark figures ("biased Ia3 by 3-6 %"), metavars in words, defaults shown
    assert "independent plant" not in full and "MAX_ITER" not in full
    if command in ("identify", "report", "demo"):      # one DIDIM default, written in each help
        from dynid.analysis.estimators.didim import DEFAULT_MAX_ITER
        assert "--max-iter N" in full and f"(default: {DEFAULT_MAX_ITER})" in " ".join(full.split())


def test_resample_identifies_a_log_with_irregular_time_steps(tmp_path, capsys):
    import numpy as np
    import pandas as pd
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "4", "--out", str(csv), "--quiet"]) == 0
    frame = pd.read_csv(csv)
    step = frame["t"][1] - frame["t"][0]
    frame["t"] += np.random.default_rng(0).uniform(-0.3, 0.3, len(frame)) * step
    jitter = tmp_path / "jitter.csv"
    frame.to_csv(jitter, index=False, float_format="%.10g")
    assert main(["identify", str(jitter), "--robot", "planar2", "--quiet"]) == 2
    assert "--resample" in capsys.readouterr().err
    js = tmp_path / "r.json"
    assert main(["identify", str(jitter), "--robot", "planar2", "--resample", "--holdout", "1",
                 "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "held out: the last 1 s" in out and out.index("Verdict") < out.index("IDIM identification")
    doc = json.loads(js.read_text())
    assert "resampled" in doc["source"] and any("resampled" in n for n in doc["notices"])


def test_off_a_terminal_long_steps_log_their_progress(tmp_path):
    """stderr redirected (a log, a batch job): a step longer than a second says it is alive
    ("progress: ..."); --quiet says nothing."""
    exe = str(Path(sys.executable).parent / "dynid")
    if not Path(exe).exists():
        pytest.skip("no dynid console script beside this interpreter")
    # 8 s of the TX40 at 5 kHz: several seconds of simulation, well beyond the one-second delay
    args = [exe, "simulate", "--robot", "tx40", "--out", str(tmp_path / "s.csv"), "--duration"]
    run = subprocess.run(args + ["8"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "progress: closed-loop simulation (8 s):" in run.stderr and "done after" in run.stderr
    quiet = subprocess.run(args + ["2", "--quiet"], capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0 and "progress" not in quiet.stderr


def test_every_help_example_parses():
    """Each `dynid ...` line in the commands' --help examples is a command line the parser takes
    (`dynid report ... --skip didim` without the required --report exited 2)."""
    import shlex

    from dynid.reports import cli_options
    parser = cli_options.build_parser(full=True)
    lines = [line.strip() for name in dir(cli_options) if name.startswith("EPILOG_")
             for line in getattr(cli_options, name).splitlines() if line.strip().startswith("dynid ")]
    assert len(lines) > 10
    for line in lines:
        command = line.split("  ")[0]              # the demo's examples carry a comment after two spaces
        try:
            parser.parse_args(shlex.split(command)[1:])
        except SystemExit as e:
            raise AssertionError(f"the help example does not parse: {command}") from e


def _doc_commands():
    """Every `dynid ...` command line in the README, docs/*.md and the examples' READMEs (fenced
    blocks; continued lines joined; redirections and pipes cut off)."""
    import re
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    files = [root / "README.md", *sorted((root / "docs").glob("*.md")), *sorted((root / "examples").glob("*/README.md"))]
    out = []
    for f in files:
        for block in re.findall(r"```[^\n]*\n(.*?)```", f.read_text(encoding="utf-8"), re.S):
            text = re.sub(r"\\\n\s*", " ", block)
            for line in text.splitlines():
                line = line.strip().removeprefix("$ ")
                if line.startswith("dynid "):
                    out.append((f.relative_to(root).as_posix(), re.split(r"\s+(?:#|>|2>|\||&&|;)", line)[0].strip()))
    return out


def test_every_documented_command_parses():
    """The commands the docs show are command lines the parser takes (`--com-box -0.1,...` in
    docs/payload.md failed: argparse reads the leading '-' as an option)."""
    import shlex

    from dynid.reports import cli_options
    parser = cli_options.build_parser(full=True)
    commands = _doc_commands()
    assert len(commands) > 15
    bad = []
    for where, command in commands:
        try:
            parser.parse_args(shlex.split(command)[1:])
        except SystemExit:
            bad.append(f"{where}: {command}")
    assert not bad, "documented commands that do not parse:\n" + "\n".join(bad)


def test_options_of_another_method_or_of_the_physical_fit_are_refused(capsys):
    """They were ignored without a word (found by a bad-input hunt); refused before any data is read."""
    import dynid
    from dynid.errors import InputError
    from dynid.reports.cli import main
    cases = [(["--f0", "0.1"], "--f0 is an option of --method ml, not of --method idim"),
             (["--max-iter", "3", "--gains", "identify"], "--max-iter, --gains are options of --method didim"),
             (["--method", "didim", "--ml-harmonics", "3"], "--ml-harmonics is an option of --method ml"),
             (["--bootstrap", "50"], "--bootstrap is an option of the physically consistent fit"),
             (["--physical", "--bootstrap", "1"], "--bootstrap 1: give 0 .* or at least 2 refits")]
    for extra, message in cases:
        assert main(["identify", "no-such-data.csv", "--robot", "planar2", *extra]) == 2
        err = capsys.readouterr().err
        assert re.search(message, err) and "Traceback" not in err, err
    with pytest.raises(InputError, match="--prior-weight is an option of the physically consistent fit"):
        dynid.identify("no-such-data.csv", "planar2", prior_weight=2.0)


@pytest.mark.parametrize("command,says", [
    ("fleet", "the recordings finished so far are in the store"),
    ("identify", "no partial output was written"),
])
def test_an_interruption_says_what_it_left(tmp_path, monkeypatch, capsys, command, says):
    """A fleet's store keeps every recording finished before Ctrl-C (its results are written as they
    come); any other command leaves nothing."""
    def interrupted(args, say):
        raise KeyboardInterrupt
    monkeypatch.setitem(COMMANDS, command, interrupted)
    (tmp_path / "cat.csv").write_text("robot_id,timestamp,path,robot\n")
    argv = {"fleet": ["fleet", str(tmp_path / "cat.csv"), "--out", str(tmp_path / "store")],
            "identify": ["identify", str(tmp_path / "cat.csv"), "--robot", "planar2"]}[command]
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert f"dynid: interrupted; {says}" in err, err


@pytest.mark.parametrize("argv", [["simulate", "--robot", "planar2", "--duration", "1"],
                                  ["excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3"]])
def test_out_of_simulate_and_excite_must_be_a_csv_path(tmp_path, capsys, argv):
    """`--out x.parquet` wrote CSV text that no loader could read back (found by a bad-input hunt)."""
    out = tmp_path / "x.parquet"
    assert main(argv + ["--out", str(out)]) == 2
    assert "give a path ending in .csv" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_an_empty_effects_list_is_refused(tmp_path, capsys, command):
    """diagnose --effects "" considered every effect, identify none, both without a word."""
    (tmp_path / "r.csv").write_text("t,q1,tau1\n")
    assert main([command, str(tmp_path / "r.csv"), "--robot", "planar2", "--effects", ""]) == 2
    assert "names no effect" in capsys.readouterr().err


def test_an_output_named_as_another_outputs_format_is_refused(tmp_path, capsys):
    """`--mjcf arm.urdf` wrote MJCF that `dynid robot arm.urdf` could not read; a name of no known
    format (`--json result.txt`) is the user's choice."""
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "2", "--out", str(csv), "--quiet"]) == 0
    for opt, name in (("--mjcf", "arm.urdf"), ("--json", "r.html"), ("--csv", "p.json"), ("--report", "r.csv")):
        assert main(["identify", str(csv), "--robot", "planar2", opt, str(tmp_path / name)]) == 2
        assert f"{opt} " in capsys.readouterr().err and not (tmp_path / name).exists()
