"""URDF reading: dynid(read_urdf) against Pinocchio's own URDF parser, errors, fuzzing."""
import atexit
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dynamics.errors import RobotFileError
from dynamics.regressor import regressor
from dynamics.robot import Robot
from dynamics.robot_file import load_robot, read_toml
from dynamics.urdf import read_urdf
from tests.oracles import chi_from_values, pin, rel_err

needs_pin = pytest.mark.skipif(pin is None, reason="Pinocchio (pip package 'pin') not installed")


def inertial(mass, xyz, rpy, ixx, ixy, ixz, iyy, iyz, izz):
    return (f'<inertial><origin xyz="{xyz}" rpy="{rpy}"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial>')


def link(name, *inertia):
    return f'<link name="{name}">{inertial(*inertia) if inertia else ""}</link>'


def joint(name, kind, parent, child, xyz="0 0 0", rpy="0 0 0", axis=None, limit=True, dyn=None):
    s = f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
    s += f'<origin xyz="{xyz}" rpy="{rpy}"/>'
    if axis:
        s += f'<axis xyz="{axis}"/>'
    if limit and kind in ("revolute", "prismatic"):
        s += '<limit lower="-2" upper="2" effort="50" velocity="3"/>'
    if dyn:
        s += f'<dynamics damping="{dyn[0]}" friction="{dyn[1]}"/>'
    return s + "</joint>"


# A chain with non-z axes (-y, x, an oblique unit axis, -z), rpy origins everywhere, a
# prismatic joint, a continuous joint, a massive fixed link in the middle and a fixed tool.
OBLIQUE = "\n".join([
    '<?xml version="1.0"?>', '<robot name="oblique">',
    link("world_base"),
    joint("mount", "fixed", "world_base", "base", "0.1 -0.2 0.3", "0.1 0.2 -0.3"),
    link("base", 3.0, "0 0 0.05", "0 0 0", 0.02, 0, 0, 0.02, 0, 0.02),
    joint("j1", "revolute", "base", "l1", "0 0.05 0.2", "0.3 -0.2 0.5", "0 -1 0", dyn=(1.1, 0.7)),
    link("l1", 2.5, "0.03 -0.02 0.11", "0.2 0.1 -0.4", 0.031, 0.002, -0.001, 0.027, 0.003, 0.012),
    joint("j2", "revolute", "l1", "l2", "0.02 0.01 0.25", "-0.4 0.25 0.1", "1 0 0", dyn=(0.9, 0.4)),
    link("l2", 1.8, "0.1 0.01 -0.02", "0.5 -0.3 0.2", 0.011, -0.001, 0.002, 0.025, 0.0015, 0.021),
    joint("mid", "fixed", "l2", "l2b", "0.2 -0.03 0.04", "0.7 0.1 -0.6"),
    link("l2b", 0.7, "0.01 0.02 0.03", "0.1 0.2 0.3", 0.004, 0.0005, 0.0002, 0.003, -0.0004, 0.005),
    joint("j3", "prismatic", "l2b", "l3", "0.05 0.0 0.1", "0.2 -0.5 0.3", "0.48 0.6 0.64", dyn=(3.0, 2.0)),
    link("l3", 1.2, "-0.02 0.04 0.06", "-0.3 0.2 0.1", 0.009, 0.001, -0.002, 0.011, 0.0007, 0.006),
    joint("j4", "continuous", "l3", "l4", "0.0 0.1 0.05", "0.0 0.4 -0.2", "0 0 -1", dyn=(0.2, 0.1)),
    link("l4", 0.9, "0.01 -0.01 0.04", "0.3 0.3 0.3", 0.003, 0.0002, 0.0001, 0.004, -0.0003, 0.002),
    joint("tool_joint", "fixed", "l4", "tool", "0.01 0.02 0.12", "1.0 -0.5 0.2"),
    link("tool", 0.6, "0.0 0.03 0.05", "0.2 0.0 0.4", 0.002, 0.0001, -0.0002, 0.0015, 0.0001, 0.001),
    "</robot>"])

# Fixed side branches: a sensor hanging off l1 beside a fixed middle joint that leads on to
# more moving joints, and a last link with two massive fixed children (tool and camera,
# the camera on a further fixed mount).
BRANCHED = "\n".join([
    '<?xml version="1.0"?>', '<robot name="branched">',
    link("base"),
    joint("j1", "revolute", "base", "l1", "0 0 0.3", "0 0 0", "0 0 1"),
    link("l1", 2.0, "0.02 0.03 0.1", "0.1 0 0", 0.02, 0.001, 0.0, 0.03, 0.002, 0.015),
    joint("sensor_joint", "fixed", "l1", "sensor", "0.05 0.05 0.05", "0.3 0.2 0.1"),
    link("sensor", 0.4, "0.01 0 0", "0 0 0", 0.001, 0, 0, 0.001, 0, 0.001),
    joint("flange", "fixed", "l1", "l1b", "0 0 0.2", "0.5 0 0"),
    link("l1b", 0.5, "0 0.01 0.02", "0 0 0", 0.002, 0, 0, 0.002, 0, 0.002),
    joint("j2", "revolute", "l1b", "l2", "0.3 0 0", "-0.2 0.3 0.1", "0 1 0"),
    link("l2", 1.5, "0.15 0 0.01", "0 0.2 0", 0.01, 0.0, 0.001, 0.02, 0.0, 0.02),
    joint("j3", "revolute", "l2", "l3", "0.3 0 0", "0.1 -0.2 0.3", "1 0 0"),
    link("l3", 1.0, "0.05 0.02 0", "0 0 0.3", 0.004, 0.0003, 0.0, 0.005, 0.0002, 0.006),
    joint("tool_joint", "fixed", "l3", "tool", "0.1 0 0", "0 0.4 0"),
    link("tool", 0.8, "0.02 0 0.03", "0 0 0", 0.003, 0, 0, 0.003, 0, 0.002),
    joint("camera_mount", "fixed", "l3", "mount", "0 0.05 0", "0.2 0 0"),
    link("mount", 0.1, "0 0 0.01", "0 0 0", 0.0001, 0, 0, 0.0001, 0, 0.0001),
    joint("camera_joint", "fixed", "mount", "camera", "0 0 0.03", "0 0 0.7"),
    link("camera", 0.3, "0.01 0 0", "0 0 0", 0.0005, 0, 0, 0.0004, 0, 0.0003),
    "</robot>"])


def write(tmp, text, name="robot.urdf"):
    p = Path(tmp) / name
    p.write_text(text, encoding="utf-8")
    return p


def pin_configuration(model, q):
    """Pinocchio q from joint angles: continuous joints are (cos, sin) pairs."""
    out = np.zeros(model.nq)
    for k, jm in enumerate(list(model.joints)[1:]):
        if jm.nq == 2:
            out[jm.idx_q:jm.idx_q + 2] = [np.cos(q[k]), np.sin(q[k])]
        else:
            out[jm.idx_q] = q[k]
    return out


@needs_pin
@pytest.mark.parametrize("text", [OBLIQUE, BRANCHED], ids=["oblique", "branched"])
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_urdf_robot_matches_pinocchio_urdf_model(tmp_path, text, backend):
    path = write(tmp_path, text)
    robot = read_urdf(path)
    model = pin.buildModelFromUrdf(str(path))
    assert robot.n_joints == model.nv
    assert robot.joint_names == [str(n) for n in list(model.names)[1:]]
    rng = np.random.default_rng(41)
    g = rng.normal(size=3)
    g *= 9.81 / np.linalg.norm(g)
    robot.gravity = g
    model.gravity.linear = g
    chi = chi_from_values(robot, robot.apriori)
    n = robot.n_joints
    chi[10::14][:n] = rng.uniform(0.01, 0.5, n)        # Ia, Off: not in a URDF
    chi[13::14][:n] = rng.normal(size=n)
    N = 1000
    q = rng.uniform(-np.pi, np.pi, (N, n))
    q[:, robot.sigma == 1] *= 0.2
    qd, qdd = rng.normal(0, 2, (N, n)), rng.normal(0, 5, (N, n))
    data = model.createData()
    ref = np.array([pin.rnea(model, data, pin_configuration(model, q[i]), qd[i], qdd[i]).copy()
                    for i in range(N)])
    ref += (chi[10::14][:n] * qdd + model.damping * qd + model.friction * np.sign(qd)
            + chi[13::14][:n])
    tau = regressor(robot, q, qd, qdd, backend=backend) @ chi
    assert rel_err(tau, ref) <= 1e-9


def test_urdf_masses_and_limits(tmp_path):
    robot = read_urdf(write(tmp_path, OBLIQUE))
    ap = robot.apriori
    # l2 + the fixed l2b belong to joint 2; l4 + tool to joint 4; 'base' is fixed to the ground
    assert [ap[f"M{k}"] for k in range(1, 5)] == pytest.approx([2.5, 1.8 + 0.7, 1.2, 0.9 + 0.6])
    assert robot.sigma.tolist() == [0, 0, 1, 0]
    assert robot.joints[0].q_limits == (-2.0, 2.0) and robot.joints[0].tau_max == 50.0
    assert robot.joints[3].q_limits == (-np.inf, np.inf)            # continuous
    assert (ap["Fv1"], ap["Fc1"], ap["Fv3"], ap["Fc3"]) == (1.1, 0.7, 3.0, 2.0)
    branched = read_urdf(write(tmp_path, BRANCHED, "b.urdf")).apriori
    assert [branched[f"M{k}"] for k in (1, 2, 3)] == pytest.approx([2.0 + 0.4 + 0.5, 1.5, 1.0 + 0.8 + 0.1 + 0.3])


def test_bundled_kuka_reads_through_toml():
    robot = load_robot("kuka_lwr4")
    assert robot.n_joints == 7 and robot.controller is not None
    assert robot.apriori["M7"] == pytest.approx(0.3)


# ------------------------------------------------------------------- errors

ACTION_WORDS = ("must", "required", "allowed", "give", "use ", "remove", "fix", "check", "add ",
                "save", "one of", "make")


def assert_helpful(exc, *fields):
    msg = str(exc.value)
    for f in fields:
        assert f in msg, f"{f!r} not in message: {msg}"
    assert any(w in msg.lower() for w in ACTION_WORDS), f"message does not say what to do: {msg}"


SMALL = "\n".join([
    '<?xml version="1.0"?>', '<robot name="small">', link("base"),
    joint("j1", "revolute", "base", "l1", "0 0 0.1", "0 0 0", "0 0 1", dyn=(0.5, 0.2)),
    link("l1", 1.0, "0 0 0.1", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005),
    joint("j2", "prismatic", "l1", "l2", "0.2 0 0", "0.1 0 0", "1 0 0"),
    link("l2", 0.5, "0.05 0 0", "0 0 0", 0.002, 0, 0, 0.002, 0, 0.002),
    joint("tool_joint", "fixed", "l2", "tool", "0.1 0 0", "0 0 0"),
    link("tool", 0.2, "0 0 0.02", "0 0 0", 0.0005, 0, 0, 0.0005, 0, 0.0005),
    "</robot>"])


def test_small_urdf_is_valid(tmp_path):
    robot = read_urdf(write(tmp_path, SMALL, "small.urdf"))
    assert robot.n_joints == 2 and robot.sigma.tolist() == [0, 1]


def test_error_not_xml(tmp_path):
    p = write(tmp_path, "this is not <xml", "notxml.urdf")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(p)
    assert_helpful(exc, "notxml.urdf", "line 1")


def test_error_two_root_links(tmp_path):
    text = SMALL.replace("</robot>", '<link name="stray"/></robot>')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "tworoots.urdf"))
    assert_helpful(exc, "tworoots.urdf", "root link", "stray")


def test_error_branching_moving_joints(tmp_path):
    text = SMALL.replace("</robot>", joint("jx", "revolute", "l1", "other", axis="0 0 1")
                         + link("other", 0.1, "0 0 0", "0 0 0", 1e-4, 0, 0, 1e-4, 0, 1e-4) + "</robot>")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "branch.urdf"))
    assert_helpful(exc, "branch.urdf", "l1", "serial")


def test_error_joint_refers_to_missing_link(tmp_path):
    text = SMALL.replace('<child link="tool"/>', '<child link="toool"/>')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "missing.urdf"))
    assert_helpful(exc, "missing.urdf", "tool_joint", "toool")


def test_error_floating_joint(tmp_path):
    text = SMALL.replace('name="j2" type="prismatic"', 'name="j2" type="floating"')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "floating.urdf"))
    assert_helpful(exc, "floating.urdf", "j2", "floating")


def test_error_unreadable_and_missing_urdf(tmp_path):
    (tmp_path / "adir.urdf").mkdir()
    with pytest.raises(RobotFileError) as exc:
        read_urdf(tmp_path / "adir.urdf")
    assert_helpful(exc, "adir.urdf")
    with pytest.raises(RobotFileError) as exc:
        load_robot(tmp_path / "nothere.urdf")
    assert_helpful(exc, "nothere.urdf")


def test_error_fixed_branch_loop(tmp_path):
    """Fixed joints forming a cycle on a side branch: an error, not a RecursionError."""
    text = SMALL.replace("</robot>", "".join([
        joint("s1", "fixed", "l1", "sa"), link("sa", 0.1, "0 0 0", "0 0 0", 1e-4, 0, 0, 1e-4, 0, 1e-4),
        joint("s2", "fixed", "sa", "sb"), link("sb", 0.1, "0 0 0", "0 0 0", 1e-4, 0, 0, 1e-4, 0, 1e-4),
        joint("s3", "fixed", "sb", "sa")]) + "</robot>")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "loop.urdf"))
    assert_helpful(exc, "loop.urdf")


def test_error_joint_names(tmp_path):
    for label, text in [("noname", SMALL.replace('joint name="j2"', "joint")),
                        ("emptyname", SMALL.replace('joint name="j2"', 'joint name=""')),
                        ("dupname", SMALL.replace('joint name="j2"', 'joint name="j1"'))]:
        with pytest.raises(RobotFileError) as exc:
            read_urdf(write(tmp_path, text, f"{label}.urdf"))
        assert_helpful(exc, f"{label}.urdf", "name")


@pytest.mark.filterwarnings("ignore::RuntimeWarning")    # the zero-axis check's norm overflows
def test_huge_axis_is_normalised(tmp_path):
    a = read_urdf(write(tmp_path, SMALL.replace('axis xyz="1 0 0"', 'axis xyz="1e300 1e300 0"'), "a.urdf"))
    b = read_urdf(write(tmp_path, SMALL.replace('axis xyz="1 0 0"', 'axis xyz="1 1 0"'), "b.urdf"))
    np.testing.assert_allclose(a.joints[1].R, b.joints[1].R, atol=1e-15)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_error_overflowing_numbers(tmp_path):
    text = SMALL.replace('<origin xyz="0.05 0 0"', '<origin xyz="1e200 0 0"')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "huge.urdf"))
    assert_helpful(exc, "huge.urdf", "j2")


def test_toml_with_urdf_errors(tmp_path):
    write(tmp_path, SMALL, "small.urdf")
    (tmp_path / "r.toml").write_text('name = "r"\nurdf = "small.urdf"\n[[joints]]\nalpha = 1.0\n'
                                     '[[joints]]\nname = "b"\n')
    with pytest.raises(RobotFileError) as exc:
        read_toml(tmp_path / "r.toml")
    assert_helpful(exc, "r.toml", "joints[1]", "URDF")
    (tmp_path / "r2.toml").write_text('name = "r"\nurdf = 3\n')
    with pytest.raises(RobotFileError) as exc:
        read_toml(tmp_path / "r2.toml")
    assert_helpful(exc, "r2.toml", "urdf")
    (tmp_path / "r3.toml").write_text('name = "r"\nurdf = "small.urdf"\n'
                                      '[[joints]]\nname = "a"\nqd_max = 2.0\n[[joints]]\nname = "b"\n')
    robot = read_toml(tmp_path / "r3.toml")
    assert robot.joint_names == ["a", "b"] and robot.joints[0].qd_max == 2.0


# ------------------------------------------------------------------- fuzzing

GARBAGE_NUMBERS = st.one_of(
    st.sampled_from(["", "nan", "inf", "-inf", "1e400", "1e300", "-1e300", "1e-320", "abc", "1,2",
                     "0x10", "1 2", "1 2 3 4", "0 0 0", "  ", "1e", "--1", "0.0.0", "1e200", "1e160",
                     "-1e155", "0", "-0", "-5", "1e-200"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet="0123456789.-+eE naif", max_size=12),
)
_ATTR = re.compile(r'\s[a-z_]+="[^"]*"')
_NUMBER = re.compile(r'(?<=[" ])-?[0-9]+(?:\.[0-9]*)?(?:e-?[0-9]+)?(?=[" ])')
_ELEMENT = re.compile(r"<(joint|link|origin|axis|inertial|mass|inertia|limit|dynamics|parent|child)\b[^>]*?/?>")


@st.composite
def mutated_urdf(draw):
    text = SMALL
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["drop_attr", "number", "number", "number", "truncate",
                                   "drop_element", "dup_element", "type", "insert"]))
        if op == "drop_attr":
            spans = [m.span() for m in _ATTR.finditer(text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:a] + text[b:]
        elif op == "number":
            spans = [m.span() for m in _NUMBER.finditer(text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:a] + draw(GARBAGE_NUMBERS).replace('"', "") + text[b:]
        elif op == "truncate":
            text = text[:draw(st.integers(0, len(text)))]
        elif op == "drop_element":
            spans = [m.span() for m in _ELEMENT.finditer(text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:a] + text[b:]
        elif op == "dup_element":
            spans = [m.span() for m in _ELEMENT.finditer(text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:b] + text[a:b] + text[b:]
        elif op == "type":
            kinds = [m.span(1) for m in re.finditer(r'type="([a-z]*)"', text)]
            if kinds:
                a, b = draw(st.sampled_from(kinds))
                text = text[:a] + draw(st.sampled_from(
                    ["fixed", "revolute", "prismatic", "continuous", "floating", "planar", "", "Revolute"])) + text[b:]
        else:
            pos = draw(st.integers(0, len(text)))
            text = text[:pos] + draw(st.text(max_size=8)) + text[pos:]
    return text


def check_valid_robot(robot):
    """What 'a valid Robot' means for the fuzzers: usable by the regressor, finite."""
    assert isinstance(robot, Robot)
    n = robot.n_joints
    assert n >= 1
    assert len(set(robot.joint_names)) == n
    assert len(set(robot.standard_names)) == robot.n_standard
    for jt in robot.joints:
        assert jt.sigma in (0, 1)
        assert np.isfinite(jt.R).all() and np.isfinite(jt.p).all()
        np.testing.assert_allclose(jt.R @ jt.R.T, np.eye(3), atol=1e-9)
    assert np.isfinite(robot.gravity).all()
    assert all(np.isfinite(v) for v in robot.apriori.values())
    W = regressor(robot, *np.random.default_rng(0).normal(size=(3, 2, n)))
    assert W.shape == (2, n, robot.n_standard)
    # the readers accept any finite length (1e308 m overflows the regressor): judge
    # finiteness of the columns on plausible geometry only
    if max(np.abs(jt.p).max() for jt in robot.joints) < 1e6 and np.abs(robot.gravity).max() < 1e6:
        assert np.isfinite(W).all()


_FUZZ_DIR = Path(tempfile.mkdtemp(prefix="dynid_urdf_fuzz_"))
atexit.register(shutil.rmtree, _FUZZ_DIR, ignore_errors=True)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")    # overflow on purpose (xyz="1e300 ...")
@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_urdf())
def test_fuzzed_urdf_gives_robot_or_robot_file_error(text):
    path = _FUZZ_DIR / "fuzz.urdf"
    path.write_text(text, encoding="utf-8")
    try:
        robot = read_urdf(path)
    except RobotFileError as exc:
        assert "fuzz.urdf" in str(exc)
        return
    check_valid_robot(robot)
