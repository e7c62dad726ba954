"""`simulate(..., payload=...)` / `dynid simulate --payload`: the last link carries a sphere.

Its parameters are checked against Pinocchio, which appends the payload as a rigid body of its
own (mass, centre of mass, inertia about it) to the last joint; the recording is then what
`identify_payload` finds the payload in.
"""
import json

import numpy as np
import pytest

import dynid
from dynid.analysis.data.synthetic import PAYLOAD_RADIUS, add_payload
from dynid.analysis.estimators.payload import identify_payload
from dynid.dynamics.regressor import regressor
from dynid.errors import InputError
from tests.support.oracles import actuator_torques, pin, pin_model_from_robot, random_standard_parameters

needs_pin = pytest.mark.skipif(pin is None, reason="Pinocchio (pip package 'pin') not installed")


@needs_pin
def test_payload_parameters_match_a_body_appended_in_pinocchio():
    robot = dynid.load_robot("tx40")
    chi = random_standard_parameters(robot, np.random.default_rng(2))    # every link a rigid body
    mass, com = 2.5, np.array([0.03, -0.02, 0.07])
    loaded, doc = add_payload(robot, chi, (mass, com))
    model = pin_model_from_robot(robot, chi)
    inertia = pin.Inertia(mass, com, 0.4 * mass * PAYLOAD_RADIUS ** 2 * np.eye(3))
    model.appendBodyToJoint(model.njoints - 1, inertia, pin.SE3.Identity())
    data = model.createData()
    rng = np.random.default_rng(3)
    q, qd, qdd = rng.uniform(-2, 2, (3, 40, robot.n_joints))
    ref = np.array([pin.rnea(model, data, q[i], qd[i], qdd[i]) + actuator_torques(robot, loaded, q[i], qd[i], qdd[i])
                    for i in range(len(q))])
    tau = regressor(robot, q, qd, qdd) @ loaded
    assert np.max(np.abs(tau - ref)) <= 1e-9 * np.max(np.abs(ref))
    assert doc["parameters"]["ML"] == mass and doc["parameters"]["MZL"] == pytest.approx(mass * com[2])


def test_the_payload_is_found_in_the_simulated_recording():
    robot = dynid.load_robot("tx40")
    empty = dynid.simulate(robot, 12.0, seed=1).experiment
    rec = dynid.simulate(robot, 12.0, seed=2, payload=(2.0, (0.0, 0.0, 0.05)))
    assert "payload on link 6: 2 kg" in rec.summary() and json.loads(rec.to_json())["payload"]["mass"] == 2.0
    r = identify_payload(rec.experiment, robot, model=dynid.identify(empty, robot))
    z = (r.chi - np.array([rec.payload["parameters"][n] for n in r.names])) / r.bse.to_numpy()
    assert abs(r.mass[0] - 2.0) < 0.01 and np.linalg.norm(r.com - [0, 0, 0.05]) < 2e-3
    assert np.all(np.abs(z) < 4), dict(zip(r.names, np.round(z, 2)))


@pytest.mark.parametrize("payload, match", [(-1.0, "above 0"), ((2.0, (0, 0, 5.0)), "more than 2 m"),
                                            ((2.0, (0, 0)), "three finite"), ("heavy", "a mass in kg")])
def test_a_bad_payload_is_named(payload, match):
    with pytest.raises(InputError, match=match):
        dynid.simulate("planar2", 1.0, payload=payload)


def test_the_command_line_takes_a_payload(tmp_path, capsys):
    from dynid.reports.cli import main
    out, doc = tmp_path / "loaded.csv", tmp_path / "loaded.json"
    assert main(["simulate", "--robot", "planar2", "--duration", "2", "--payload", "1.5,0.1,0,0",
                 "--out", str(out), "--json", str(doc), "--quiet"]) == 0
    assert json.loads(doc.read_text())["payload"]["com"] == [0.1, 0.0, 0.0]
    capsys.readouterr()
    assert main(["simulate", "--robot", "planar2", "--payload", "1.5,0.1", "--out", str(out)]) == 2
    assert "KG or KG,X,Y,Z" in capsys.readouterr().err
