"""The payload written as a link of the URDF / MJCF, checked by replay (Pinocchio, MuJoCo).

The rigid-body torques of the exported model with its payload link must be dynid's with the
payload's ten parameters added to its link's (the payload's columns, eq. (2)).
"""
import numpy as np
import pytest

import dynid
from dynid.analysis.estimators.payload import transform_matrix
from dynid.dynamics.mjcf_writer import mjcf_text
from dynid.dynamics.regressor import regressor
from dynid.dynamics.urdf_writer import inertial_slice, urdf_text
from dynid.errors import InputError

pin = pytest.importorskip("pinocchio")
mujoco = pytest.importorskip("mujoco")


def _rigid_set(robot, rng):
    chi = np.zeros(robot.n_standard)
    names = robot.standard_names
    for k in range(1, robot.n_joints + 1):
        m = rng.uniform(1.0, 4.0)
        c = rng.normal(0, 0.05, 3)
        I_o = np.diag(rng.uniform(0.02, 0.03, 3)) + m * (c @ c * np.eye(3) - np.outer(c, c))
        for sym, v in zip(("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M"),
                          (I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m)):
            chi[names.index(f"{sym}{k}")] = v
    return chi


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(11)
    robot = dynid.load_robot("tx40")
    chi = _rigid_set(robot, rng)
    m, c = 2.5, np.array([0.02, -0.03, 0.09])
    Ic = np.array([[0.010, 0.001, -0.0005], [0.001, 0.012, 0.0008], [-0.0005, 0.0008, 0.006]])
    I_f = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    pf = np.array([I_f[0, 0], I_f[0, 1], I_f[0, 2], I_f[1, 1], I_f[1, 2], I_f[2, 2], *(m * c), m])
    # described in a tool frame 6.5 cm along z6, turned by 30 degrees about it
    a = np.pi / 6
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    values = transform_matrix(R, [0, 0, 0.065]) @ pf
    with_payload = chi.copy()
    with_payload[inertial_slice(robot, 5)] += values
    q, qd, qdd = (rng.uniform(-1.5, 1.5, (8, 6)) for _ in range(3))
    expected = regressor(robot, q, qd, qdd) @ with_payload
    return robot, chi, {"link": 6, "values": values, "name": "gripper"}, (q, qd, qdd), expected


def test_pinocchio_replays_the_urdf_with_its_payload(setup, tmp_path):
    robot, chi, payload, (q, qd, qdd), expected = setup
    path = tmp_path / "r.urdf"
    path.write_text(urdf_text(robot, chi, payload=payload))
    assert "gripper_joint" in path.read_text()
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    got = np.array([pin.rnea(model, data, *x) for x in zip(q, qd, qdd)])
    assert np.abs(got - expected).max() < 1e-8 * np.abs(expected).max()
    # without the payload it is another model: the check can fail
    bare = tmp_path / "b.urdf"
    bare.write_text(urdf_text(robot, chi))
    mb = pin.buildModelFromUrdf(str(bare))
    db = mb.createData()
    off = np.array([pin.rnea(mb, db, *x) for x in zip(q, qd, qdd)])
    assert np.abs(off - expected).max() > 1e-2


def test_mujoco_replays_the_mjcf_with_its_payload(setup):
    robot, chi, payload, (q, qd, qdd), expected = setup
    model = mujoco.MjModel.from_xml_string(mjcf_text(robot, chi, payload=payload))
    assert model.nv == robot.n_joints and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "gripper") > 0
    model.jnt_limited[:] = 0
    for arr in (model.dof_armature, model.dof_damping, model.dof_frictionloss,
                model.tendon_armature, model.tendon_damping, model.tendon_frictionloss):
        arr[:] = 0.0
    data = mujoco.MjData(model)
    got = np.empty_like(q)
    for k in range(len(q)):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, data)
        got[k] = data.qfrc_inverse
    assert np.abs(got - expected).max() < 1e-7 * np.abs(expected).max()


@pytest.mark.parametrize("payload, words", [({"link": 9, "values": np.r_[np.zeros(9), 1.0]}, "not a link"),
                                            ({"link": 6, "values": np.zeros(10)}, "positive mass"),
                                            ({"values": np.zeros(10)}, "payload must be")])
def test_writers_refuse_a_bad_payload(setup, payload, words):
    robot, chi, *_ = setup
    for write in (urdf_text, mjcf_text):
        with pytest.raises(InputError, match=words):
            write(robot, chi, payload=payload)
