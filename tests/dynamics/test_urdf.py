"""URDF reading: dynid(read_urdf) against Pinocchio's own URDF parser, errors, fuzzing."""
import atexit
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from dynid.dynamics.regressor import regressor
from dynid.dynamics.robot import Robot
from dynid.dynamics.robot_file import load_robot, read_toml
from dynid.dynamics.urdf import read_urdf
from dynid.errors import RobotFileError
from tests.support.oracles import chi_from_values, pin, rel_err

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


def check_bounded_robot(robot):
    """Beyond check_valid_robot: with the readers' bounds, the regressor is finite on any robot read."""
    n = robot.n_joints
    assert n <= 64
    assert np.linalg.norm(robot.gravity) <= 100.0
    W = regressor(robot, *np.random.default_rng(1).normal(size=(3, 2, n)))
    assert np.isfinite(W).all()


_FUZZ_DIR = Path(tempfile.mkdtemp(prefix="dynid_urdf_fuzz_"))
atexit.register(shutil.rmtree, _FUZZ_DIR, ignore_errors=True)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")    # overflow on purpose (xyz="1e300 ...")
@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          derandomize=True, database=None)       # reproducible: the same 500 files every run
@example(SMALL.replace('<origin xyz="0.05 0 0"', '<origin xyz="1e154 0 0"'))
@example(SMALL.replace('<mass value="0.5"/>', '<mass value="-0.5"/>'))
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
    check_bounded_robot(robot)


# ------------------------------------------------------------------- chains: base / tip

def _inertia_args(k, mass):
    """A physically valid inertial (moments 0.01..0.03, any two above the third), rotated."""
    return (mass, f"{0.01 * k:.3f} {-0.02:.3f} {0.05 + 0.01 * k:.3f}", f"0.{k} -0.2 0.3",
            0.012 + 0.001 * k, 0.0005, -0.0003, 0.015, 0.0004, 0.01 + 0.0005 * k)


_ARM_AXES = ["0 0 1", "0 1 0", "1 0 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"]
_ARM_JOINTS = ["s0", "s1", "e0", "e1", "w0", "w1", "w2"]


def _baxter_arm(side, sign):
    """Fixed mount on the torso, 7 revolute joints, a fixed hand: Baxter's arm layout."""
    parts = [joint(f"{side}_torso_arm_mount", "fixed", "torso", f"{side}_arm_mount",
                   f"0.024 {sign * 0.22} 0.11", f"0 0 {sign * 0.78}"),
             link(f"{side}_arm_mount", *_inertia_args(1, 0.4))]
    prev = f"{side}_arm_mount"
    for k in range(7):
        cur = f"{side}_arm_link{k + 1}"
        parts += [joint(f"{side}_{_ARM_JOINTS[k]}", "revolute", prev, cur, f"0.05 {sign * 0.01} 0.12",
                        f"{0.3 * sign} 0.1 {-0.2 * k}", _ARM_AXES[k], dyn=(0.5 + 0.1 * k, 0.2)),
                  link(cur, *_inertia_args(k + 1, 4.0 - 0.4 * k))]
        prev = cur
    parts += [joint(f"{side}_hand_joint", "fixed", prev, f"{side}_hand", "0 0 0.08", "0 0 0.4"),
              link(f"{side}_hand", *_inertia_args(2, 0.6))]
    return parts


def baxter(sides=("left", "right"), head=True):
    """A Baxter-like tree: a torso, a moving head, two 7-joint arms on fixed branches."""
    parts = ['<?xml version="1.0"?>', '<robot name="baxter">', link("torso", *_inertia_args(3, 30.0))]
    if head:
        parts += [joint("head_pan", "revolute", "torso", "head", "0.06 0 0.68", axis="0 0 1"),
                  link("head", *_inertia_args(1, 0.5))]
    for side in sides:
        parts += _baxter_arm(side, 1 if side == "left" else -1)
    return "\n".join(parts + ["</robot>"])


def panda(fingers=True, mimic=True):
    """A Panda-like arm: 7 joints, fixed flange link8, fixed hand with two sibling prismatic fingers."""
    # the right angles to full precision, as franka_description's xacro expands ${pi/2}: Pinocchio
    # reads "1.5708" literally, dynid as pi/2 (test_a_rounded_right_angle_is_the_right_angle)
    h = repr(np.pi / 2)
    rpys = ["0 0 0", f"-{h} 0 0", f"{h} 0 0", f"{h} 0 0", f"-{h} 0 0", f"{h} 0 0", f"{h} 0 0"]
    xyzs = ["0 0 0.333", "0 0 0", "0 -0.316 0", "0.0825 0 0", "-0.0825 0.384 0", "0 0 0", "0.088 0 0"]
    parts = ['<?xml version="1.0"?>', '<robot name="panda">', link("link0", *_inertia_args(2, 2.9))]
    for k in range(7):
        parts += [joint(f"joint{k + 1}", "revolute", f"link{k}", f"link{k + 1}", xyzs[k], rpys[k], "0 0 1",
                        dyn=(0.3, 0.1)),
                  link(f"link{k + 1}", *_inertia_args(k + 1, 3.0 - 0.3 * k))]
    parts += [joint("joint8", "fixed", "link7", "link8", "0 0 0.107"), link("link8"),
              joint("hand_joint", "fixed", "link8", "hand", "0 0 0", "0 0 -0.7854"),
              link("hand", *_inertia_args(3, 0.73))]
    if fingers:
        for k, (side, y) in enumerate((("left", "1"), ("right", "-1")), start=1):
            j = joint(f"finger_joint{k}", "prismatic", "hand", f"{side}finger", "0 0 0.0584", axis=f"0 {y} 0")
            if mimic and k == 2:
                j = j.replace("</joint>", '<mimic joint="finger_joint1"/></joint>')
            parts += [j, link(f"{side}finger", *_inertia_args(1, 0.015))]
    return "\n".join(parts + ["</robot>"])


def assert_same_dynamics_as_pinocchio(robot, urdf_path, seed=41):
    """dynid's robot and Pinocchio's model of ``urdf_path`` give the same inverse dynamics."""
    model = pin.buildModelFromUrdf(str(urdf_path))
    assert robot.n_joints == model.nv
    assert robot.joint_names == [str(n) for n in list(model.names)[1:]]
    rng = np.random.default_rng(seed)
    g = rng.normal(size=3)
    g *= 9.81 / np.linalg.norm(g)
    robot.gravity = g
    model.gravity.linear = g
    chi = chi_from_values(robot, robot.apriori)
    n = robot.n_joints
    N = 300
    q = rng.uniform(-np.pi, np.pi, (N, n))
    qd, qdd = rng.normal(0, 2, (N, n)), rng.normal(0, 5, (N, n))
    data = model.createData()
    ref = np.array([pin.rnea(model, data, pin_configuration(model, q[i]), qd[i], qdd[i]).copy()
                    for i in range(N)])
    ref += model.damping * qd + model.friction * np.sign(qd)
    assert rel_err(regressor(robot, q, qd, qdd) @ chi, ref) <= 1e-9


def test_baxter_without_tip_is_refused_naming_the_moving_branches(tmp_path):
    """Before: arms on fixed branches beside the moving head loaded as a 1-joint robot."""
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, baxter(), "baxter.urdf"))
    assert_helpful(exc, "baxter.urdf", "torso", "serial chain", "'head_pan'", "'left_s0'", "'right_s0'",
                   "tip")
    # without the head, the two arms alone (both behind fixed joints) are refused too
    with pytest.raises(RobotFileError) as exc:
        load_robot(write(tmp_path, baxter(head=False), "arms.urdf"))
    assert_helpful(exc, "arms.urdf", "'left_s0'", "'right_s0'", "left_arm_link7")


@needs_pin
def test_baxter_left_arm_chain_matches_pinocchio(tmp_path):
    full = write(tmp_path, baxter(), "baxter.urdf")
    robot = read_urdf(full, tip="left_arm_link7")
    assert robot.n_joints == 7
    assert robot.joint_names == [f"left_{j}" for j in _ARM_JOINTS]
    # the fixed hand below the tip is merged into link 7; the mount (fixed to the torso) is ground
    assert robot.apriori["M7"] == pytest.approx(4.0 - 0.4 * 6 + 0.6)
    assert any("head_pan" in s and "right_s0" in s and "do not change" in s for s in robot.notices)
    # Pinocchio on a URDF holding only that chain
    only = write(tmp_path, baxter(sides=("left",), head=False), "left_only.urdf")
    assert_same_dynamics_as_pinocchio(robot, only)
    # the same through load_robot, with the tip at the hand, and from the mount as base
    same = load_robot(full, tip="left_hand")
    assert same.apriori == robot.apriori and same.joint_names == robot.joint_names
    mounted = load_robot(full, base="left_arm_mount", tip="left_arm_link7")
    assert mounted.apriori == robot.apriori
    for a, b in zip(mounted.joints[1:], robot.joints[1:]):
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.p, b.p)
    assert any("not below the base" in s for s in mounted.notices)
    (above,) = read_urdf(full, base="left_arm_link3", tip="left_arm_link7").notices
    assert "'left_e0'" in above and "'left_e1'" not in above


def test_panda_fingers_refused_without_tip(tmp_path):
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, panda(), "panda.urdf"))
    assert_helpful(exc, "panda.urdf", "hand", "'finger_joint1'", "'finger_joint2'", "tip")


@needs_pin
@pytest.mark.parametrize("tip", ["link8", "hand"])
def test_panda_arm_chain_matches_pinocchio(tmp_path, tip):
    robot = load_robot(write(tmp_path, panda(), "panda.urdf"), tip=tip)
    assert robot.joint_names == [f"joint{k}" for k in range(1, 8)]
    assert robot.apriori["M7"] == pytest.approx(3.0 - 0.3 * 6 + 0.73)     # hand merged, fingers not
    (note,) = robot.notices
    assert "finger_joint1" in note and "finger_joint2" in note and "NOT" in note and "0.03 kg" in note
    assert "chain" in robot.provenance["kinematics"] and tip in robot.provenance["kinematics"]
    assert_same_dynamics_as_pinocchio(robot, write(tmp_path, panda(fingers=False), "arm_only.urdf"))
    # the arm without fingers needs no tip and gives the same robot
    plain = read_urdf(tmp_path / "arm_only.urdf")
    assert plain.apriori == robot.apriori and plain.notices == []


def test_chain_selection_errors(tmp_path):
    path = write(tmp_path, baxter(), "baxter.urdf")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, tip="left_arm_link9")
    assert_helpful(exc, "baxter.urdf", "tip", "left_arm_link9", "not a link", "did you mean")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, base="pelvis", tip="left_arm_link7")
    assert_helpful(exc, "baxter.urdf", "base", "pelvis")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, base="left_arm_link3", tip="right_arm_link7")
    assert_helpful(exc, "baxter.urdf", "right_arm_link7", "not below base", "left_arm_link3")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, base="left_arm_link5", tip="left_arm_link2")      # tip above the base
    assert_helpful(exc, "baxter.urdf", "not below base")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, base="torso", tip="torso")
    assert_helpful(exc, "baxter.urdf", "tip", "base")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, tip="left_arm_mount")                           # only fixed joints
    assert_helpful(exc, "baxter.urdf", "no revolute or prismatic joint")
    with pytest.raises(RobotFileError) as exc:
        load_robot("tx40", tip="j6")
    assert_helpful(exc, "tx40", "urdf")


def test_mimic_joint_on_the_chain_is_refused(tmp_path):
    path = write(tmp_path, panda(), "panda.urdf")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path, tip="rightfinger")
    assert_helpful(exc, "panda.urdf", "finger_joint2", "mimic", "base/tip")
    # the non-mimic finger is a legal 8th joint
    assert read_urdf(path, tip="leftfinger").joint_names[-1] == "finger_joint1"


def test_floating_joint_needs_a_base(tmp_path):
    text = SMALL.replace('<link name="base"></link>',
                         '<link name="world"></link><joint name="float" type="floating">'
                         '<parent link="world"/><child link="base"/></joint><link name="base"></link>')
    assert text != SMALL
    path = write(tmp_path, text, "floating_base.urdf")
    with pytest.raises(RobotFileError) as exc:
        read_urdf(path)
    assert_helpful(exc, "floating_base.urdf", "float", "floating", "base")
    assert read_urdf(path, base="base").joint_names == ["j1", "j2"]


def test_toml_selects_a_urdf_chain(tmp_path):
    write(tmp_path, baxter(), "baxter.urdf")
    (tmp_path / "left.toml").write_text('name = "baxter_left"\nurdf = "baxter.urdf"\n'
                                        'tip = "left_arm_link7"\n')
    robot = load_robot(tmp_path / "left.toml")
    assert robot.n_joints == 7 and robot.joint_names[0] == "left_s0" and robot.notices
    assert load_robot(tmp_path / "left.toml", tip="left_arm_link7").apriori == robot.apriori
    with pytest.raises(RobotFileError) as exc:
        load_robot(tmp_path / "left.toml", tip="right_arm_link7")
    assert_helpful(exc, "left.toml", "tip", "right_arm_link7", "left_arm_link7")
    (tmp_path / "plain.toml").write_text('name = "baxter"\nurdf = "baxter.urdf"\n')
    assert read_toml(tmp_path / "plain.toml", tip="right_arm_link7").joint_names[0] == "right_s0"
    with pytest.raises(RobotFileError) as exc:
        read_toml(tmp_path / "plain.toml")
    assert_helpful(exc, "baxter.urdf", "serial chain", "tip")
    (tmp_path / "nourdf.toml").write_text('name = "x"\ntip = "l1"\n[[joints]]\n')
    with pytest.raises(RobotFileError) as exc:
        read_toml(tmp_path / "nourdf.toml")
    assert_helpful(exc, "nourdf.toml", "tip", "urdf")


# ------------------------------------------------------------------- XML, files, names

BILLION_LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">'
                  + "".join(f'<!ENTITY lol{k} "{("&lol" + str(k - 1 if k > 1 else "") + ";") * 10}">'
                            for k in range(1, 10))
                  + ']>\n<robot name="&lol9;"><link name="base"/></robot>')
EXTERNAL_ENTITY = ('<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n'
                   '<robot name="&xxe;"><link name="base"/></robot>')


@pytest.mark.parametrize("text", [BILLION_LAUGHS, EXTERNAL_ENTITY], ids=["billion_laughs", "external"])
def test_xml_attacks_are_refused(tmp_path, text):
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "attack.urdf"))
    assert_helpful(exc, "attack.urdf", "entities")


def test_missing_defusedxml_is_a_clear_error(tmp_path, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "defusedxml", None)
    monkeypatch.setitem(sys.modules, "defusedxml.ElementTree", None)
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, SMALL, "small.urdf"))
    assert_helpful(exc, "small.urdf", "defusedxml", "install")


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="no named pipes here")
def test_fifo_device_and_huge_files_are_refused_before_reading(tmp_path):
    import os
    os.mkfifo(tmp_path / "pipe.urdf")          # opening it for reading would block forever
    with pytest.raises(RobotFileError) as exc:
        read_urdf(tmp_path / "pipe.urdf")
    assert_helpful(exc, "pipe.urdf", "FIFO", "not a regular file")
    with pytest.raises(RobotFileError) as exc:
        load_robot(tmp_path / "pipe.urdf")
    assert_helpful(exc, "pipe.urdf", "FIFO")
    if os.path.exists("/dev/zero"):            # endless: reading it would never stop
        (tmp_path / "zero.urdf").symlink_to("/dev/zero")
        with pytest.raises(RobotFileError) as exc:
            load_robot(tmp_path / "zero.urdf")
        assert_helpful(exc, "zero.urdf", "device")
    with open(tmp_path / "huge.urdf", "wb") as fh:   # sparse: no disk used
        fh.truncate(17 * 2 ** 20)
    with pytest.raises(RobotFileError) as exc:
        read_urdf(tmp_path / "huge.urdf")
    assert_helpful(exc, "huge.urdf", "16 MiB")


def test_control_characters_in_names_are_refused(tmp_path):
    # XML 1.0 forbids C0 controls (ESC, BEL) even as &#27;: the parser refuses them
    text = SMALL.replace('<robot name="small">', '<robot name="&#27;]0;TITLE&#7;">')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "esc.urdf"))
    assert "\x1b" not in str(exc.value) and "esc.urdf" in str(exc.value)
    # C1 controls (CSI) and bidirectional overrides are legal XML: dynid refuses them
    for label, old, new, field in [
            ("csi", '<robot name="small">', '<robot name="&#x9b;31m">', "robot name"),
            ("bidi", 'joint name="j2"', 'joint name="j&#x202e;2"', "joint name"),
            ("linkname", 'link name="l1"', 'link name="l&#x85;1"', "link name")]:
        text = SMALL.replace(old, new)
        assert text != SMALL
        with pytest.raises(RobotFileError) as exc:
            read_urdf(write(tmp_path, text, f"{label}.urdf"))
        assert_helpful(exc, f"{label}.urdf", field, "control character")
        assert not any(c in str(exc.value) for c in "\x9b\u202e\x85"), str(exc.value)


def test_duplicate_link_and_fixed_joint_names(tmp_path):
    text = SMALL.replace("</robot>", '<link name="l1"/></robot>')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "duplink.urdf"))
    assert_helpful(exc, "duplink.urdf", "'l1'", "unique")
    text = SMALL.replace('joint name="tool_joint"', 'joint name="j1"')
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "dupjoint.urdf"))
    assert_helpful(exc, "dupjoint.urdf", "'j1'", "unique")


# ------------------------------------------------------------------- impossible robots

L1 = link("l1", 1.0, "0 0 0.1", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005)
assert L1 in SMALL


def small_with_l1(*inertia):
    return SMALL.replace(L1, link("l1", *inertia))


@pytest.mark.parametrize("label, inertia, fields", [
    ("negative_mass", (-1.0, "0 0 0.1", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005), ["mass", "negative"]),
    ("heavy", (2e5, "0 0 0.1", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005), ["mass", "100000 kg"]),
    ("not_pd", (1.0, "0 0 0.1", "0 0 0", 0.01, 0, 0, -0.01, 0, 0.005), ["positive definite"]),
    ("not_pd_offdiag", (1.0, "0 0 0.1", "0 0 0", 0.01, 0.02, 0, 0.01, 0, 0.005), ["positive definite"]),
    ("triangle", (1.0, "0 0 0.1", "0.3 0.2 0.1", 0.001, 0, 0, 0.001, 0, 0.01), ["triangle inequality"]),
    ("massless_inertia", (0.0, "0 0 0.1", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005), ["mass 0"]),
    ("huge_inertia", (1.0, "0 0 0.1", "0 0 0", 2e5, 0, 0, 2e5, 0, 2e5), ["ixx", "100000 kg m^2"]),
    ("far_com", (1.0, "0 0 150", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005), ["inertial origin", "100 m"]),
])
def test_impossible_inertials_are_refused(tmp_path, label, inertia, fields):
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, small_with_l1(*inertia), f"{label}.urdf"))
    assert_helpful(exc, f"{label}.urdf", "link 'l1'", "joint 'j1'", *fields)


def test_limiting_inertials_are_legal(tmp_path):
    """A massless frame (mass 0, inertia 0), a point mass and a thin rod are legal."""
    massless = read_urdf(write(tmp_path, small_with_l1(0.0, "0 0 0.1", "0 0 0", 0, 0, 0, 0, 0, 0), "a.urdf"))
    assert "M1" not in massless.apriori
    point = read_urdf(write(tmp_path, small_with_l1(1.0, "0 0 0.1", "0 0 0", 0, 0, 0, 0, 0, 0), "b.urdf"))
    assert point.apriori["M1"] == 1.0 and point.apriori["ZZ1"] == 0.0
    assert point.apriori["XX1"] == pytest.approx(0.01)               # m c^2 about the joint frame
    rod = read_urdf(write(tmp_path, small_with_l1(1.0, "0 0 0.1", "0.3 0 0", 0.02, 0, 0, 0.02, 0, 0), "c.urdf"))
    assert rod.apriori["M1"] == 1.0
    # a disk: izz = ixx + iyy exactly, also with rounding in the last digit
    disk = small_with_l1(1.0, "0 0 0.1", "0 0 0", 0.0033333, 0, 0, 0.0033333, 0, 0.0066667)
    assert read_urdf(write(tmp_path, disk, "d.urdf")).apriori["M1"] == 1.0


@pytest.mark.parametrize("label, old, new, fields", [
    ("reversed", 'lower="-2" upper="2"', 'lower="2" upper="-2"', ["lower", "upper"]),
    ("equal", 'lower="-2" upper="2"', 'lower="1" upper="1"', ["lower", "upper", "fixed"]),
    ("velocity", 'velocity="3"', 'velocity="-3"', ["velocity", "negative"]),
    ("effort", 'effort="50"', 'effort="-50"', ["effort", "negative"]),
    ("far_origin", '<origin xyz="0 0 0.1"', '<origin xyz="0 0 101"', ["origin xyz", "100 m"]),
])
def test_bad_limits_and_origins_are_refused(tmp_path, label, old, new, fields):
    """Before: reversed limits and negative velocity/effort were silently dropped."""
    assert old in SMALL
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, SMALL.replace(old, new, 1), f"{label}.urdf"))
    assert_helpful(exc, f"{label}.urdf", "joint 'j1'", *fields)


def test_zero_velocity_and_effort_mean_no_limit(tmp_path):
    robot = read_urdf(write(tmp_path, SMALL.replace('effort="50" velocity="3"', 'effort="0" velocity="0"'),
                            "zero.urdf"))
    assert robot.joints[0].qd_max == np.inf and robot.joints[0].tau_max == np.inf


def _chain_urdf(n_moving, n_fixed_side=0):
    parts = ['<?xml version="1.0"?>', '<robot name="long">', link("l0")]
    for k in range(n_moving):
        parts += [joint(f"j{k + 1}", "revolute", f"l{k}", f"l{k + 1}", "0 0 0.1", axis="0 0 1"),
                  link(f"l{k + 1}", 1.0, "0 0 0.05", "0 0 0", 0.01, 0, 0, 0.01, 0, 0.005)]
    prev = "l1"
    for k in range(n_fixed_side):
        parts += [joint(f"s{k}", "fixed", prev, f"s{k}", "0 0.001 0"),
                  link(f"s{k}", 0.001, "0 0 0", "0 0 0", 1e-6, 0, 0, 1e-6, 0, 1e-6)]
        prev = f"s{k}"
    return "\n".join(parts + ["</robot>"])


def test_joint_and_link_counts_are_bounded(tmp_path):
    """Before: a 1000-joint URDF took 6.5 GiB in the regressor."""
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, _chain_urdf(1000), "long.urdf"))
    assert_helpful(exc, "long.urdf", "1000 moving joints", "64")
    assert read_urdf(write(tmp_path, _chain_urdf(64), "ok.urdf")).n_joints == 64
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, _chain_urdf(2, 10_000), "many.urdf"))
    assert_helpful(exc, "many.urdf", "10000 links")


def test_deep_fixed_branch_is_merged_without_recursion(tmp_path):
    """Before: a fixed side branch 3000 links deep raised RecursionError."""
    robot = read_urdf(write(tmp_path, _chain_urdf(2, 3000), "deep.urdf"))
    assert robot.n_joints == 2
    assert robot.apriori["M1"] == pytest.approx(1.0 + 3000 * 0.001)
    assert robot.apriori["M2"] == 1.0


def _right_angle_arm(rpy2):
    return "\n".join([
        '<?xml version="1.0"?>', '<robot name="arm">', link("base"),
        joint("j1", "revolute", "base", "l1", "0 0 0.3", "0 0 0", "0 0 1"),
        link("l1", 2.0, "0.02 0.03 0.1", "0 0 0", 0.02, 0.001, 0.0, 0.03, 0.002, 0.015),
        joint("j2", "revolute", "l1", "l2", "0 0 0.1", rpy2, "0 0 1"),
        link("l2", 1.5, "0.15 0 0.01", "0 0 0", 0.01, 0.0, 0.001, 0.02, 0.0, 0.02),
        joint("j3", "revolute", "l2", "l3", "0.4 0 0", "0 0 0", "0 0 1"),
        link("l3", 1.0, "0.05 0.02 0", "0 0 0", 0.004, 0.0003, 0.0, 0.005, 0.0002, 0.006),
        "</robot>"])


@pytest.mark.parametrize("written", ["1.5708", "1.571", "1.57", "-1.5708", "3.1416"])
def test_a_rounded_right_angle_is_the_right_angle(tmp_path, written):
    """A joint origin's rpy written to a few decimals (1.5708 for pi/2) gives the base parameters of
    the exact angle (with 1.5708 taken literally, Ia2 stayed apart from ZZ2R: 26 base parameters
    instead of 25 and cond(W) ~ 6e6), and a notice names the joint."""
    from dynid.dynamics.base_parameters import base_parameters
    exact = read_urdf(write(tmp_path, _right_angle_arm(f"{np.pi / 2 * round(float(written) / (np.pi / 2))!r} 0 0"),
                            "exact.urdf"))
    rounded = read_urdf(write(tmp_path, _right_angle_arm(f"{written} 0 0"), "rounded.urdf"))
    assert base_parameters(rounded).names == base_parameters(exact).names
    assert any("j2" in n and f'rpy="{written} 0 0"' in n for n in rounded.notices), rounded.notices
    assert not any("pi/2" in n for n in exact.notices)
    rng = np.random.default_rng(5)
    q, qd, qdd = (rng.normal(size=(50, 3)) for _ in range(3))
    assert np.array_equal(regressor(rounded, q, qd, qdd), regressor(exact, q, qd, qdd))


@pytest.mark.parametrize("written", [repr(np.pi / 2 + 0.002), "1.5703", "1.570800", "0.0005", "-0.0001"])
def test_an_angle_that_is_not_a_rounded_right_angle_is_kept(tmp_path, written):
    """A skew the file means (0.002 rad off, a calibrated 1.5703), a small offset (0.0005), or pi/2 written
    with digits beyond its rounding (1.570800): kept as written."""
    robot = read_urdf(write(tmp_path, _right_angle_arm(f"{written} 0 0")))
    assert not any("pi/2" in n for n in robot.notices)
    multiple = np.pi / 2 * round(float(written) / (np.pi / 2))
    exact = read_urdf(write(tmp_path, _right_angle_arm(f"{multiple!r} 0 0"), "exact.urdf"))
    rng = np.random.default_rng(6)
    q, qd, qdd = (rng.normal(size=(20, 3)) for _ in range(3))
    assert not np.array_equal(regressor(robot, q, qd, qdd), regressor(exact, q, qd, qdd))


@needs_pin
def test_a_rounded_right_angle_gives_pinocchios_dynamics_of_the_exact_angle(tmp_path):
    """Checked outside dynid: the arm written with 1.5708 has the inverse dynamics Pinocchio computes
    for the same arm written with pi/2 to full precision (and not those of 1.5708 taken literally)."""
    rounded = read_urdf(write(tmp_path, _right_angle_arm("1.5708 0 0"), "rounded.urdf"))
    assert_same_dynamics_as_pinocchio(rounded, write(tmp_path, _right_angle_arm(f"{np.pi / 2!r} 0 0"), "exact.urdf"))
    with pytest.raises(AssertionError):
        assert_same_dynamics_as_pinocchio(rounded, write(tmp_path, _right_angle_arm("1.5708 0 0"), "literal.urdf"))


@pytest.mark.parametrize("old,new,words", [
    # as urdfdom: an <inertia> without ixx gave the a-priori XX of that link 0 (exit 0)
    ('<inertia ixx="0.002" ', '<inertia ', ["'l2'", "has no ixx", "all six"]),
    # a velocity of 1e-6 (a unit slip) made the loader blame the recording's time column
    ('velocity="3"', 'velocity="1e-6"', ["j1", "velocity", "too small"]),
])
def test_a_missing_moment_or_a_velocity_limit_below_a_mrad_per_second_is_refused(tmp_path, old, new, words):
    text = SMALL.replace(old, new, 1)
    assert text != SMALL
    with pytest.raises(RobotFileError) as exc:
        read_urdf(write(tmp_path, text, "bad.urdf"))
    assert_helpful(exc, "bad.urdf", *words)
