"""Payload identification and drive gains (issue 28), judged by an independent Pinocchio plant.

The plant (tests/support/payload_plant.py on tests/support/independent_plant.py) carries a payload appended to
joint 6 by Pinocchio; its torques are Pinocchio's. dynid's model is the tx40 robot file without
its wrist coupling (the URDF plant has none). Seeds here are the tests' own (2000+), not the
benchmark's.
"""
import dataclasses
import json

import numpy as np
import pytest

import dynid
from dynid.analysis.data.experiment import Experiment
from dynid.analysis.estimators.drive_gains import identify_drive_gains
from dynid.analysis.estimators.payload import (
    PAYLOAD_NAMES,
    centre_held_torque,
    identify_payload,
    payload_frame,
    payload_link_values,
    physical_payload,
    transform_matrix,
)
from dynid.dynamics.regressor import regressor
from dynid.dynamics.robot import model_signature
from dynid.dynamics.urdf_writer import inertial_slice
from dynid.errors import IdentificationError, InputError
from dynid.provenance import dumps_json

pin = pytest.importorskip("pinocchio")
from tests.support import independent_plant as ip  # noqa: E402
from tests.support import payload_plant as pp  # noqa: E402

RATE = 1000.0


def _robot():
    return dataclasses.replace(dynid.load_robot("tx40"), couplings=[])


def _experiment(plant, duration, seed, **kw):
    ref = pp.wrist_reference(plant.limits, duration, RATE, seed, **kw)
    rec = pp.record(plant, ref, seed, rate=RATE)
    return Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"], fs=RATE, source=f"plant seed {seed}")


@pytest.fixture(scope="module")
def plant_data():
    rng = np.random.default_rng(2001)
    params, parts = pp.random_payload(rng)
    base, loaded, _ = pp.tx40_payload_plant(params)
    robot = _robot()
    eu = _experiment(base, 12.0, 2001)
    el = _experiment(loaded, 8.0, 2002)
    model = dynid.identify(eu, robot)
    return dict(robot=robot, params=params, parts=parts, eu=eu, el=el, model=model, loaded=loaded, base=base)


# ------------------------------------------------------------------ frames (Pinocchio oracle)
def test_payload_columns_in_an_offset_frame_match_pinocchio():
    """A payload described in a frame turned and moved from link 6: dynid's columns times T give
    the torque Pinocchio computes for the same body appended at that placement."""
    rng = np.random.default_rng(7)
    links, Ia, _, _ = ip.tx40_table2_parameters()
    model = ip.mdh_model(ip.TX40_MDH, links)
    params_f, _ = pp.random_payload(rng)
    rpy = rng.uniform(-1, 1, 3)
    xyz = np.array([0.01, -0.02, 0.065])
    link, R, p = payload_frame(_robot(), "flange", {"xyz": xyz, "rpy": rpy})
    assert np.allclose(R, pin.rpy.rpyToMatrix(*rpy))
    loaded = pin.Model(model)
    loaded.appendBodyToJoint(6, ip.inertia_from_khalil(params_f), pin.SE3(R, p))
    q, qd, qdd = (rng.uniform(-1.5, 1.5, (6, 6)) for _ in range(3))
    d0, d1 = model.createData(), loaded.createData()
    diff = np.array([pin.rnea(loaded, d1, *x) - pin.rnea(model, d0, *x) for x in zip(q, qd, qdd)])
    robot = _robot()
    W = regressor(robot, q, qd, qdd)[:, :, inertial_slice(robot, link)]
    assert np.abs(W @ transform_matrix(R, p) @ params_f - diff).max() < 1e-9 * np.abs(diff).max()


def test_frame_that_is_not_a_link_gets_one_clear_error():
    robot = _robot()
    for bad in ("wrist", "j9", 0, 7):
        with pytest.raises(InputError, match="not a link of robot 'tx40'"):
            payload_frame(robot, bad)
    assert payload_frame(robot, "j6")[0] == payload_frame(robot, "flange")[0] == payload_frame(robot, 6)[0] == 5
    with pytest.raises(InputError, match="not a link"):
        identify_payload("no-such-file.csv", robot, model={"parameters": []}, frame="tool0")


@pytest.mark.parametrize("mass", [0.0, -1.5, float("nan"), "heavy"])
def test_mass_not_positive_gets_one_clear_error(mass):
    with pytest.raises(InputError, match="mass"):
        identify_drive_gains("u.csv", "l.csv", _robot(), mass=mass)


def test_exactly_one_of_model_and_unloaded():
    with pytest.raises(InputError, match="exactly one"):
        identify_payload("l.csv", _robot())
    with pytest.raises(InputError, match="exactly one"):
        identify_payload("l.csv", _robot(), model={}, unloaded="u.csv")


# ------------------------------------------------------------------ identification
def test_robot_fixed_route_finds_the_payload(plant_data):
    d = plant_data
    r = identify_payload(d["el"], d["robot"], model=d["model"], physical=True)
    m, c, Ic = d["parts"]["mass"], d["parts"]["com"], d["parts"]["inertia_com"]
    assert abs(r.mass[0] - m) / m < 0.02
    assert np.linalg.norm(r.com - c) < 5e-3
    assert np.abs(r.inertia_com - Ic).max() < 0.2 * np.linalg.eigvalsh(Ic).max()
    # the common interface
    assert list(r.params.index) == list(PAYLOAD_NAMES)
    ci = r.conf_int()
    assert list(ci.columns) == ["lower", "upper"] and np.all(ci["lower"] < ci["upper"])
    assert "Verdict" in r.summary() and "constrained vs free" in r.summary()
    out = json.loads(dumps_json(r.to_dict()))
    assert out["method"] == "payload-robot-fixed" and len(out["parameters"]) == 10
    # the link-frame values of the flange frame are the values themselves
    assert np.allclose(payload_link_values(r), r.chi)


def test_global_route_finds_the_payload_and_the_robot(plant_data):
    d = plant_data
    r = identify_payload(d["el"], d["robot"], unloaded=d["eu"])
    m, c = d["parts"]["mass"], d["parts"]["com"]
    assert r.method == "payload-global"
    assert abs(r.mass[0] - m) / m < 0.02 and np.linalg.norm(r.com - c) < 5e-3
    assert r.robot_params is not None and len(r.robot_params.names) > 10


def test_robot_fixed_route_takes_the_json_of_an_identification(plant_data, tmp_path):
    d = plant_data
    path = tmp_path / "identified.json"
    d["model"].to_json(path)
    r = identify_payload(d["el"], d["robot"], model=str(path))
    assert abs(r.mass[0] - d["parts"]["mass"]) / d["parts"]["mass"] < 0.02
    # the JSON carries the WLS covariance: its σ are the object's (σ alone overstated them up to 8x)
    direct = identify_payload(d["el"], d["robot"], model=d["model"])
    assert np.allclose(r.bse.to_numpy(), direct.bse.to_numpy(), rtol=1e-9)
    assert np.array_equal(r.chi, direct.chi)
    # without it: the diagonal, and a notice that says so
    doc = json.loads(path.read_text())
    del doc["wls"]["covariance"]
    r_diag = identify_payload(d["el"], d["robot"], model=doc)
    assert any("without their correlations" in n for n in r_diag.notices)
    assert r_diag.bse["ML"] > r.bse["ML"]


def test_a_still_wrist_is_refused_naming_what_is_not_identified(plant_data):
    d = plant_data
    still = _experiment(d["loaded"], 6.0, 2003, still_wrist=True)
    with pytest.raises(IdentificationError) as e:
        identify_payload(still, d["robot"], model=d["model"])
    msg = str(e.value)
    assert "does not identify the payload" in msg and "estimated mass" in msg
    assert any(nm in msg for nm in PAYLOAD_NAMES[:6])          # an inertia names itself
    assert "q4" in msg and "q6" in msg and "wrist" in msg


def test_physical_payload_projects_a_non_physical_estimate():
    """A payload with a negative principal moment is moved onto the physical set; a CoM box binds."""
    m, c = 2.0, np.array([0.0, 0.02, 0.08])
    I_c = np.diag([0.01, 0.012, -0.002])
    I_o = I_c + m * (c @ c * np.eye(3) - np.outer(c, c))
    chi = np.array([I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m])
    cov = np.diag(np.r_[np.full(6, 1e-6), np.full(3, 1e-6), 1e-4])
    r = physical_payload(chi, cov)
    J = sum(v * E for v, E in zip(r.chi, __import__("dynid.dynamics.urdf_writer", fromlist=["x"])
                                  .pseudo_inertia_basis()))
    assert np.linalg.eigvalsh(J)[0] > -1e-7 and r.delta > 1 and r.active
    boxed = physical_payload(chi, cov, com_box=([-0.01, -0.01, 0.0], [0.01, 0.01, 0.05]))
    com = boxed.chi[6:9] / boxed.chi[9]
    assert np.all(com <= np.array([0.01, 0.01, 0.05]) + 1e-6) and any("box" in a for a in boxed.active)


@pytest.mark.slow
def test_drive_gains_with_a_known_mass(plant_data):
    d = plant_data
    k = np.array([1.05, 0.95, 1.08, 0.93, 1.02, 0.97])

    def scaled(e):
        return Experiment(t=e.t, q=e.q, qr=e.qr, tau=e.tau / k, fs=e.fs, source=e.source)
    r = identify_drive_gains(scaled(d["eu"]), scaled(d["el"]), d["robot"], mass=d["params"][9],
                             com=d["parts"]["com"])
    assert np.all(np.abs(r.factor - k) / k < 0.02)
    assert np.allclose(r.chi, r.factor * d["robot"].drive_gains)
    # the error of the final fit on the logged torque (it was the last step's, about 100 %)
    assert 0 < r.rel_error < 0.05
    assert "moved" in r.summary() and json.loads(dumps_json(r.to_dict()))["gains"][0]["joint"] == 1


def test_cli_payload_runs_and_refuses_a_bad_frame(plant_data, tmp_path, monkeypatch):
    from dynid.reports.cli import main
    d = plant_data
    paths = {}
    for name in ("eu", "el"):
        e = d[name]
        paths[name] = ip.write_csv(tmp_path / f"{name}.csv", {"t": e.t, "q": e.q, "qr": e.qr, "tau": e.tau})
    out = tmp_path / "payload.json"
    html = tmp_path / "payload.html"
    rc = main(["payload", "--robot", "tx40", "--loaded", str(paths["el"]), "--unloaded", str(paths["eu"]),
               "--json", str(out), "--report", str(html), "--quiet"])
    assert rc == 0
    res = json.loads(out.read_text())
    assert res["method"] == "payload-global" and abs(res["mass_kg"] - d["parts"]["mass"]) < 0.1 * d["parts"]["mass"]
    assert "Verdict" in html.read_text()
    # the command line is identify_payload called on the same files (numbers alike, versions aside)
    api = identify_payload([str(paths["el"])], dynid.load_robot("tx40"), unloaded=[str(paths["eu"])]).to_dict()
    assert [p_["value"] for p_ in res["parameters"]] == [p_["value"] for p_ in api["parameters"]]
    rc = main(["payload", "--robot", "tx40", "--loaded", str(paths["el"]), "--unloaded", str(paths["eu"]),
               "--frame", "tool0", "--quiet"])
    assert rc == 2


def test_cli_refuses_a_mass_that_is_not_positive(capsys):
    from dynid.reports.cli import main
    rc = main(["payload", "--robot", "tx40", "--loaded", "l.csv", "--unloaded", "u.csv", "--mass", "0", "--gains"])
    err = capsys.readouterr().err
    assert rc == 2 and "mass must be > 0 kg" in err and "Traceback" not in err
    rc = main(["payload", "--robot", "tx40", "--loaded", "l.csv", "--unloaded", "u.csv", "--gains"])
    assert rc == 2 and "--mass" in capsys.readouterr().err


# ------------------------------------------------------------------ torque timing (zoh)
def test_centre_held_torque_is_the_mean_of_successive_commands():
    t = np.arange(5) / 100.0
    tau = np.column_stack([np.arange(5.0), np.arange(5.0) ** 2])
    e = Experiment(t=t, q=np.zeros((5, 2)), tau=tau, fs=100.0, source="held")
    c = centre_held_torque(e)
    assert np.allclose(c.tau[1:], 0.5 * (tau[1:] + tau[:-1])) and np.allclose(c.tau[0], tau[0])
    assert np.allclose(e.tau, tau)                       # the input is left alone
    assert any("zoh" in n for n in c.notices)


def test_global_route_with_centred_torques_finds_the_payload(plant_data):
    """The plant holds each command over the next period: the centred timing (zoh) is its own."""
    d = plant_data
    r = identify_payload(d["el"], d["robot"], unloaded=d["eu"], zoh=True)
    m, c, Ic = d["parts"]["mass"], d["parts"]["com"], d["parts"]["inertia_com"]
    assert r.settings["zoh"] is True
    assert abs(r.mass[0] - m) / m < 0.02 and np.linalg.norm(r.com - c) < 5e-3
    assert np.abs(r.inertia_com - Ic).max() < 0.2 * np.linalg.eigvalsh(Ic).max()
    assert any("centred" in n for n in r.notices)


# ------------------------------------------------------------------ identify_gains in the description
def _currents_toml(tmp_path, extra):
    n = 50
    cols = {"t": np.arange(n) / 100.0}
    cols.update({f"q{j}": np.sin(np.arange(n) / 10.0 + j) for j in range(1, 7)})
    cols.update({f"i{j}": np.cos(np.arange(n) / 10.0 + j) for j in range(1, 7)})
    import pandas as pd
    pd.DataFrame(cols).to_csv(tmp_path / "d.csv", index=False)
    path = tmp_path / "e.toml"
    path.write_text('file = "d.csv"\n[time]\ncolumn = "t"\n[positions]\ncolumns = ["q1","q2","q3","q4","q5","q6"]\n'
                    '[currents]\ncolumns = ["i1","i2","i3","i4","i5","i6"]\n' + extra)
    return path


@pytest.mark.parametrize("extra, joints", [("identify_gains = true\n", [1, 2, 3, 4, 5, 6]),
                                           ("identify_gains = [4, 6]\n", [4, 6]),
                                           ("identify_gains = false\n", None), ("", None)])
def test_description_marks_the_gains_to_identify(tmp_path, extra, joints):
    from dynid.analysis.estimators.drive_gains import _described_joints
    e = dynid.load_experiment(_currents_toml(tmp_path, extra), _robot())
    assert e.meta.get("identify_gains") == joints
    assert e.meta["drive_gains"] == list(_robot().drive_gains)
    assert _described_joints([e, e]) == joints


@pytest.mark.parametrize("extra, words", [("identify_gains = [0, 7]\n", "distinct joints 1..6"),
                                          ("identify_gains = [4, 4]\n", "distinct joints 1..6"),
                                          ("identify_gains = \"yes\"\n", "true, false or a list")])
def test_description_refuses_a_bad_identify_gains(tmp_path, extra, words):
    from dynid.errors import DataError
    with pytest.raises(DataError, match=words) as e:
        dynid.load_experiment(_currents_toml(tmp_path, extra), _robot())
    assert "[currents]" in str(e.value)


def test_drive_gains_take_the_marks_and_gains_of_the_descriptions(tmp_path):
    from dynid.analysis.estimators.drive_gains import _common_gains, _described_joints
    a = dynid.load_experiment(_currents_toml(tmp_path, "identify_gains = [4, 5]\ndrive_gains = [1, 1, 1, 2, 2, 2]\n"),
                              _robot())
    b = dynid.load_experiment(_currents_toml(tmp_path, "identify_gains = [5, 6]\n"), _robot())
    with pytest.raises(InputError, match="different joints"):
        _described_joints([a, b])
    # recordings computed with other gains are brought to the first one's
    g, (a2, b2) = _common_gains([a, b], _robot())
    assert np.allclose(g, [1, 1, 1, 2, 2, 2]) and a2 is a
    assert np.allclose(b2.tau, b.tau * g / _robot().drive_gains)


# ------------------------------------------------------------------ the full report's payload section
def test_payload_sections_carry_a_verdict(plant_data):
    from dynid.reports.payload_section import payload_html, payload_refusal_section, payload_status
    d = plant_data
    r = identify_payload(d["el"], d["robot"], model=d["model"], physical=True)
    status, reasons = payload_status(r)
    assert status == "identified" and not reasons
    page = payload_html(r)
    assert "Verdict: identified" in page and "MXL" in page and "constrained" in page
    # what the summary and docs/payload.md give: %sigma, the moments about the centre of mass, and
    # the robot-fixed route's check of the model on the loaded recording
    assert "%\u03c3</th>" in page and "principal moments" in page
    # the parameter table and the SDP-vs-free table come with their CSV, every value in full and
    # with its unit (the page's footer says downloads are embedded)
    import io
    import re
    import urllib.parse

    import pandas as pd
    uri = re.search(r'href="data:text/csv;charset=utf-8,([^"]*)" download="tab-payload.csv"', page)
    csv = pd.read_csv(io.StringIO(urllib.parse.unquote(uri.group(1))), index_col=0)
    assert list(csv.index) == list(r.names) and list(csv["unit"])[-1] == "kg"
    assert np.allclose(csv["value"], r.chi, rtol=1e-12) and np.allclose(csv["std"], r.bse, rtol=1e-12)
    assert np.allclose(csv["rel_std_percent"], r.rel_std, rtol=1e-12)
    assert 'download="tab-payload-physical.csv"' in page
    assert f"{100 * r.loaded_error:.3g} %, of the model on its own data" in page
    refused = payload_refusal_section("the recording does not identify XXL", ["l.csv"])
    assert refused.id == "payload" and "not identified" in str(refused.html_body) and "XXL" in str(refused.html_body)


@pytest.mark.slow
def test_full_report_has_a_payload_section_with_a_verdict(plant_data):
    from dynid.reports.pipeline import _payload_part, report
    from dynid.reports.progress import Reporter
    d = plant_data
    out = report(d["eu"], d["robot"], payload=d["el"], skip=("didim", "sample", "diagnose"))
    assert abs(out.payload.mass[0] - d["parts"]["mass"]) / d["parts"]["mass"] < 0.02
    html = out.html
    assert 'id="payload"' in html and "Verdict: identified" in html
    doc = out.to_dict()
    assert doc["payload"]["method"] == "payload-robot-fixed" and "Payload identification" in out.summary()
    # a recording without a payload: a section saying what is not identified and why, not a crash
    out.sections = [s for s in out.sections if s.id != "payload"]
    none = _payload_part(out, d["eu"], d["robot"], None, Reporter(quiet=True))
    assert isinstance(none.payload, str) and "not identified" in str(none.sections[-1].html_body)
    assert none.to_dict()["payload"]["refused"] and any("payload" in p for p in none.problems)


def test_cli_report_takes_payload_recordings():
    from dynid.reports.cli_options import build_parser
    args = build_parser().parse_args(["report", "u.csv", "--robot", "tx40", "--report", "r.html",
                                      "--payload", "l.csv"])
    assert args.payload == ["l.csv"]
    args = build_parser().parse_args(["payload", "--robot", "tx40", "--loaded", "l.csv", "--unloaded", "u.csv",
                                      "--zoh", "--mass", "2", "--gains"])
    assert args.zoh and args.gains == "marked"


def test_full_report_refuses_zoh_on_its_logged_torque_model():
    """The report's model comes from the torque as logged: centring only the payload's is refused."""
    from dynid.reports.pipeline import _payload_part
    from dynid.reports.progress import Reporter
    with pytest.raises(InputError, match="same timing"):
        _payload_part(None, "l.csv", _robot(), {"zoh": True}, Reporter(quiet=True))
    with pytest.raises(InputError, match="unknown option"):
        _payload_part(None, "l.csv", _robot(), {"mass": 2.0}, Reporter(quiet=True))


def test_a_robot_that_cannot_turn_a_payload_about_three_axes_is_told_so(tmp_path, capsys):
    """A planar arm: the payload's out-of-plane parameters have zero columns whatever the motion.
    The error named each of them twice (null vectors of the SVD beside the zero columns) and
    advised rotating a wrist the robot does not have."""
    from dynid.reports.cli import main
    for seed, extra in ((4, []), (5, ["--payload", "1,0,0,0.05"])):
        assert main(["simulate", "--robot", "planar2", "--duration", "6", "--seed", str(seed), *extra,
                     "--out", str(tmp_path / f"r{seed}.csv"), "--quiet"]) == 0
    assert main(["identify", str(tmp_path / "r4.csv"), "--robot", "planar2", "--json", str(tmp_path / "id.json"),
                 "--quiet"]) == 0
    capsys.readouterr()
    code = main(["payload", "--robot", "planar2", "--loaded", str(tmp_path / "r5.csv"), "--model",
                 str(tmp_path / "id.json"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "never feel the payload parameters XXL, XYL, XZL, YYL, YZL, MZL" in err
    assert err.count("XXL") == 1 and "wrist" not in err


def test_a_recording_without_a_payload_says_none_was_found(plant_data):
    """The unloaded plant on another trajectory, with the model of the first: the refusal said the
    parameters were poorly identified and advised rotating the wrist, without a word on the mass;
    it now says no payload is there when the mass is zero within its interval, and states the
    estimated mass in any case."""
    d = plant_data
    empty = _experiment(d["base"], 8.0, 2004)
    with pytest.raises(IdentificationError) as e:
        identify_payload(empty, d["robot"], model=d["model"])
    msg = str(e.value)
    assert "kg" in msg and ("no payload found on link 6" in msg or "estimated mass" in msg)
    if "no payload found" in msg:
        assert "wrist" not in msg


def test_a_model_that_does_not_describe_the_loaded_recording_is_not_identified(plant_data, tmp_path):
    """The independent plant's payload (Pinocchio), the robot fixed: with the matching model the
    payload fit leaves about the model's own error and the verdict is the payload's; with a robot
    file whose joint 3 is 0.1 m off, or a joint's torque lost, the verdict said "identified"
    while the payload took up the model's error (found by a bad-input hunt)."""
    d = plant_data
    good = identify_payload(d["el"], d["robot"], model=d["model"])
    assert not good.model_misfit and good.loaded_error < 2 * good.model_error
    assert good.verdict().startswith("payload on link 6")
    lost = Experiment(t=d["el"].t, q=d["el"].q, qr=d["el"].qr, tau=d["el"].tau * [1, 1, 1, 1, 1, 0],
                      fs=d["el"].fs, source="joint 6 torque lost")
    bad = identify_payload(lost, d["robot"], model=d["model"])
    assert bad.model_misfit and bad.verdict().startswith("NOT identified: the robot model does not describe")
    assert "held-out error" in bad.verdict() and "--unloaded" in bad.verdict()
    out = json.loads(dumps_json(bad.to_dict()))
    assert out["loaded_error"] > 3 * out["model_error"] and out["verdict"].startswith("NOT identified")
    # the report's verdict says the same (it said "identified" beside the NOT of the text)
    from dynid.reports.payload_section import NOT_IDENTIFIED, payload_status
    assert payload_status(bad)[0] == NOT_IDENTIFIED and payload_status(good)[0] != NOT_IDENTIFIED


def test_a_com_box_the_data_do_not_fit_is_said_in_the_verdict(plant_data):
    """A box that excludes the centre of mass moved the constrained payload to ~0 kg while the
    verdict read "physically consistent as identified" (found by a bad-input hunt)."""
    d = plant_data
    c = d["parts"]["com"]
    inside = identify_payload(d["el"], d["robot"], model=d["model"], physical=True,
                              com_box=(c - 0.02, c + 0.02))
    assert "do NOT fit the --com-box" not in inside.verdict()
    outside = identify_payload(d["el"], d["robot"], model=d["model"], physical=True,
                               com_box=(c + 1.0, c + 2.0))
    assert "the data do NOT fit the --com-box" in outside.verdict()


def test_report_refuses_a_payload_the_robot_cannot_feel_before_any_work():
    """`dynid report --payload` on a planar arm ran every method, then failed with exit 3; the
    structural check needs no data (found by a bad-input hunt)."""
    from dynid.analysis.estimators.payload import unfelt_parameters
    from dynid.reports import pipeline
    assert unfelt_parameters("planar2") == ["XXL", "XYL", "XZL", "YYL", "YZL", "MZL"]
    assert unfelt_parameters("tx40") == []
    with pytest.raises(InputError, match="--payload: the joints of robot 'planar2' never feel"):
        pipeline.report("no-such-recording.csv", "planar2", payload="no-such-payload.csv")


def test_a_model_identified_on_other_kinematics_is_refused(plant_data, tmp_path):
    """A model carries the signature of the robot it was identified on: the same name with joint 4's
    r 2 cm off, or with other drive gains, is refused (object, dict and JSON alike), other limits
    are not, and a model written without a signature (an earlier dynid) is taken as before."""
    d = plant_data
    assert d["model"].to_dict()["robot_signature"] == model_signature(d["robot"])
    joints = [dataclasses.replace(j) for j in d["robot"].joints]
    joints[3] = dataclasses.replace(joints[3], p=joints[3].p + [0.0, 0.0, 0.02])
    moved = dataclasses.replace(d["robot"], joints=joints, source="moved.toml")
    path = tmp_path / "identified.json"
    d["model"].to_json(path)
    geared = dataclasses.replace(d["robot"], joints=[dataclasses.replace(j, drive_gain=2.0 * j.drive_gain)
                                                     for j in d["robot"].joints], source="geared.toml")
    for model in (d["model"], d["model"].to_dict(), str(path)):
        for other in (moved, geared):        # other base parameters; the same ones (it was taken)
            with pytest.raises(InputError, match=rf"differ from those of the robot given \({other.source}\)"):
                identify_payload(d["el"], other, model=model)
    slow = dataclasses.replace(d["robot"], joints=[dataclasses.replace(j, qd_max=1.0) for j in d["robot"].joints])
    assert model_signature(slow) == model_signature(d["robot"])
    old = d["model"].to_dict()
    del old["robot_signature"]
    assert identify_payload(d["el"], d["robot"], model=old).mass[0] > 0


def test_a_model_identified_with_a_base_tilt_is_named_as_such():
    """With --gravity-tilt the model's robot has the estimated gravity: the refusal says so and gives the
    vector to put in the robot file (it said to give the file the model was identified with: a review)."""
    from dynid.analysis.estimators.payload import _check_signature
    robot = _robot()
    g = np.array([-0.0047, 0.0063, -9.81])
    tilted = model_signature(dataclasses.replace(robot, gravity=g))
    with pytest.raises(InputError, match=r"estimated base tilt .*-0.0047, 0.0063, -9.81"):
        _check_signature(tilted, robot, "id.json", list(g))
    with pytest.raises(InputError, match="differ from those of the robot given"):
        _check_signature(tilted, robot, "id.json", [0.0, 0.0, -9.81])
    _check_signature(model_signature(robot), robot, "id.json", list(g))      # the same robot: taken
