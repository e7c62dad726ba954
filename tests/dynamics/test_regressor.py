"""IDM_st(q, qd, qdd) against independent references.

References: Pinocchio's RNEA / CRBA / nonLinearEffects / generalized gravity on
models built without dynid's kinematics (tests/support/oracles.py), actuator and
coupling torques written out by hand, and the textbook double pendulum.
"""
from pathlib import Path

import numpy as np
import pytest

from dynid.dynamics.base_parameters import base_parameters

# the regressor route of M, N and tau (private oracles; dynid's public ones are
# dynid.dynamics.dynamic_model's): these tests check the regressor against Pinocchio
from dynid.dynamics.regressor import _bias_torque_via_regressor as bias_torque
from dynid.dynamics.regressor import _inverse_dynamics_via_regressor as inverse_dynamics
from dynid.dynamics.regressor import _mass_matrix_via_regressor as mass_matrix
from dynid.dynamics.regressor import gravity_torque, regressor, regressor_chunks
from dynid.dynamics.robot_file import load_robot, robot_from_dict
from tests.support.oracles import (
    actuator_torques,
    armature_matrix,
    chi_from_values,
    pin,
    pin_model_from_mdh,
    pin_torques,
    random_standard_parameters,
    rel_err,
)

pytestmark = pytest.mark.skipif(pin is None, reason="Pinocchio (pip package 'pin') not installed")

BACKENDS = ["numba", "numpy"]
N_SAMPLES = 1000
TOL = 1e-9
KUKA_URDF = str(Path(__file__).resolve().parents[2] / "dynamics" / "robots" / "kuka_lwr4.urdf")


def samples(n, N, rng, q_scale=np.pi):
    q = rng.uniform(-q_scale, q_scale, (N, n))
    qd = rng.normal(0.0, 2.0, (N, n))
    qdd = rng.normal(0.0, 5.0, (N, n))
    return q, qd, qdd


def tx40_actuators(chi, q, qd, qdd):
    """Actuator, friction, offset and wrist-coupling torques of the TX40, by hand.

    Rotor 6 turns with q5 + q6 (section 4 of the DIDIM paper): Ia6 enters M at
    (5,6) and (6,5), and Fvm6 w + Fcm6 sign(w), w = qd5 + qd6, loads joints 5 and 6.
    """
    p = {name: chi[k] for k, name in enumerate(load_robot("tx40").standard_names)}
    tau = np.zeros_like(q)
    for j in range(6):
        J = j + 1
        tau[:, j] = (p[f"Ia{J}"] * qdd[:, j] + p[f"Fv{J}"] * qd[:, j]
                     + p[f"Fc{J}"] * np.sign(qd[:, j]) + p[f"Off{J}"])
    w = qd[:, 4] + qd[:, 5]
    fm = p["Fvm6"] * w + p["Fcm6"] * np.sign(w)
    tau[:, 4] += p["Ia6"] * qdd[:, 5] + fm
    tau[:, 5] += p["Ia6"] * qdd[:, 4] + fm
    return tau


def tx40_rows():
    """Table 1 of the DIDIM paper, (sigma, alpha, d, theta, r): typed here, not read from dynid."""
    h = np.pi / 2
    return [(0, 0, 0, 0, 0), (0, -h, 0, 0, 0), (0, 0, 0.225, 0, 0.035),
            (0, h, 0, 0, 0.225), (0, -h, 0, 0, 0), (0, h, 0, 0, 0)]


# ----------------------------------------------------------------- random robots

def random_robot(seed):
    """A random serial robot (3-7 joints, revolute and prismatic, arbitrary MDH), TOML-like dict."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 8))
    sigma = rng.integers(0, 2, n)
    sigma[rng.choice(n, 2, replace=False)] = [0, 1]        # at least one of each
    joints = []
    for k in range(n):
        joints.append({"name": f"a{k + 1}", "sigma": int(sigma[k]),
                       "alpha": float(rng.uniform(-np.pi, np.pi)), "d": float(rng.normal(0, 0.4)),
                       "theta": float(rng.uniform(-np.pi, np.pi)), "r": float(rng.normal(0, 0.4))})
    g = rng.normal(size=3)
    doc = {"name": f"random{seed}", "gravity": list(9.81 * g / np.linalg.norm(g)), "joints": joints}
    if seed % 2 == 0:      # a transmission coupling with non-unit coefficients
        doc["couplings"] = [{"motor": n, "joints": [n - 1, n],
                             "coefficients": [float(rng.uniform(0.5, 2)), float(rng.uniform(0.5, 2))],
                             "friction": True}]
    rows = [(jt["sigma"], jt["alpha"], jt["d"], jt["theta"], jt["r"]) for jt in joints]
    return doc, rows


RANDOM_SEEDS = [11, 12, 13, 14, 15, 16]


@pytest.fixture(scope="module")
def tx40():
    return load_robot("tx40")


@pytest.fixture(scope="module")
def kuka():
    return load_robot("kuka_lwr4")


# ---------------------------------------------------------------- 1. vs Pinocchio RNEA

@pytest.mark.parametrize("backend", BACKENDS)
def test_tx40_regressor_matches_pinocchio_rnea(tx40, backend):
    rng = np.random.default_rng(1)
    chi = random_standard_parameters(tx40, rng)
    model = pin_model_from_mdh(tx40_rows(), [0, 0, -9.81], chi)
    q, qd, qdd = samples(6, N_SAMPLES, rng)
    ref = pin_torques(model, q, qd, qdd) + tx40_actuators(chi, q, qd, qdd)
    tau = regressor(tx40, q, qd, qdd, backend=backend) @ chi
    assert rel_err(tau, ref) <= TOL


def test_tx40_coupling_is_visible(tx40):
    """The coupling terms are not zero: dropping them makes the comparison fail."""
    rng = np.random.default_rng(2)
    chi = random_standard_parameters(tx40, rng)
    q, qd, qdd = samples(6, 50, rng)
    model = pin_model_from_mdh(tx40_rows(), [0, 0, -9.81], chi)
    no_coupling = pin_torques(model, q, qd, qdd)
    for j in range(6):
        Ia, Fv, Fc, Off = chi[14 * j + 10:14 * j + 14]
        no_coupling[:, j] += Ia * qdd[:, j] + Fv * qd[:, j] + Fc * np.sign(qd[:, j]) + Off
    tau = regressor(tx40, q, qd, qdd) @ chi
    assert rel_err(tau, no_coupling) > 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_kuka_urdf_inertials_match_pinocchio(kuka, backend):
    """dynid's chi from the URDF (a-priori values) reproduces Pinocchio's URDF model."""
    model = pin.buildModelFromUrdf(KUKA_URDF)
    assert model.nv == kuka.n_joints == 7
    chi = chi_from_values(kuka, kuka.apriori)
    rng = np.random.default_rng(3)
    # Ia and Off are not in the URDF: add random ones on both sides
    for j in range(7):
        chi[14 * j + 10] = rng.uniform(0.01, 1.0)
        chi[14 * j + 13] = rng.normal()
    q, qd, qdd = samples(7, N_SAMPLES, rng)
    Ia, Off = chi[10::14][:7], chi[13::14][:7]
    # friction from Pinocchio's own reading of <dynamics damping friction>
    ref = (pin_torques(model, q, qd, qdd) + Ia * qdd + model.damping * qd
           + model.friction * np.sign(qd) + Off)
    tau = regressor(kuka, q, qd, qdd, backend=backend) @ chi
    assert rel_err(tau, ref) <= TOL


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", RANDOM_SEEDS)
def test_random_serial_robot_matches_pinocchio(seed, backend):
    doc, rows = random_robot(seed)
    robot = robot_from_dict(doc, f"random{seed}.toml")
    assert set(robot.sigma) == {0, 1}
    rng = np.random.default_rng(100 + seed)
    chi = random_standard_parameters(robot, rng)
    model = pin_model_from_mdh(rows, doc["gravity"], chi)
    q, qd, qdd = samples(robot.n_joints, N_SAMPLES, rng)
    q[:, robot.sigma == 1] *= 0.3                      # prismatic travel in metres
    ref = pin_torques(model, q, qd, qdd)
    ref += np.array([actuator_torques(robot, chi, q[i], qd[i], qdd[i]) for i in range(len(q))])
    tau = regressor(robot, q, qd, qdd, backend=backend) @ chi
    assert rel_err(tau, ref) <= TOL


@pytest.mark.parametrize("coupling", [dict(motor=3, joints=(1, 2)), dict(motor=2, joints=(1, 2, 3))])
def test_a_coupling_outside_the_robot_is_refused(coupling):
    """The compiled kernel indexes with the coupling's joints unchecked: a hand-built robot's
    coupling past its joints wrote another column's entries (or past the scratch) silently."""
    from dynid.dynamics.robot import Coupling
    from dynid.errors import InputError
    robot = load_robot("planar2")
    k = len(coupling["joints"])
    robot.couplings = [Coupling(coefficients=(1.0,) * k, friction=False, **coupling)]
    q = np.zeros((5, 2))
    with pytest.raises(InputError, match=r"coupling of motor .* joint number 1\.\.2"):
        regressor(robot, q, q, q)


def test_backends_agree(tx40):
    rng = np.random.default_rng(4)
    q, qd, qdd = samples(6, 200, rng)
    a = regressor(tx40, q, qd, qdd, backend="numba")
    b = regressor(tx40, q, qd, qdd, backend="numpy")
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())


# ------------------------------------------------- 2. M, N, G against Pinocchio

def _pin_mng(model, q, qd):
    data = model.createData()
    M, nle, g = [], [], []
    for i in range(len(q)):
        Mi = pin.crba(model, data, q[i]).copy()
        M.append(np.triu(Mi) + np.triu(Mi, 1).T)
        nle.append(pin.nonLinearEffects(model, data, q[i], qd[i]).copy())
        g.append(pin.computeGeneralizedGravity(model, data, q[i]).copy())
    return np.array(M), np.array(nle), np.array(g)


def _mng_cases():
    tx40 = load_robot("tx40")
    rng = np.random.default_rng(5)
    chi = random_standard_parameters(tx40, rng)
    yield "tx40", tx40, chi, pin_model_from_mdh(tx40_rows(), [0, 0, -9.81], chi)
    kuka = load_robot("kuka_lwr4")
    chi = chi_from_values(kuka, kuka.apriori)
    chi[10::14][:7] = rng.uniform(0.01, 1.0, 7)
    chi[13::14][:7] = rng.normal(size=7)
    yield "kuka_lwr4", kuka, chi, pin.buildModelFromUrdf(KUKA_URDF)
    doc, rows = random_robot(14)
    robot = robot_from_dict(doc)
    chi = random_standard_parameters(robot, rng)
    yield "random14", robot, chi, pin_model_from_mdh(rows, doc["gravity"], chi)


MNG = {name: (robot, chi, model) for name, robot, chi, model in _mng_cases()}


@pytest.mark.parametrize("name", list(MNG))
def test_mass_gravity_bias_match_pinocchio(name):
    robot, chi, model = MNG[name]
    n = robot.n_joints
    rng = np.random.default_rng(6)
    q, qd, _ = samples(n, 100, rng)
    M_ref, nle_ref, g_ref = _pin_mng(model, q, qd)
    M_ref = M_ref + armature_matrix(robot, chi)
    fr = np.array([actuator_torques(robot, chi, q[i], qd[i], np.zeros(n)) for i in range(len(q))])

    M = mass_matrix(robot, chi, q)
    assert np.allclose(M, np.swapaxes(M, 1, 2), rtol=0, atol=1e-12)
    assert rel_err(M.reshape(len(q), -1), M_ref.reshape(len(q), -1)) <= TOL
    assert rel_err(gravity_torque(robot, chi, q), g_ref) <= TOL
    assert rel_err(bias_torque(robot, chi, q, qd), nle_ref + fr) <= TOL


def test_tx40_mass_matrix_has_rotor6_off_diagonal():
    robot, chi, model = MNG["tx40"]
    q = np.random.default_rng(7).uniform(-3, 3, (20, 6))
    data = model.createData()
    M = mass_matrix(robot, chi, q)
    Ia = chi[10::14][:6]
    for i in range(len(q)):
        ref = pin.crba(model, data, q[i]).copy()
        ref = np.triu(ref) + np.triu(ref, 1).T + np.diag(Ia)
        ref[4, 5] += Ia[5]          # rotor 6 turns with q5 + q6
        ref[5, 4] += Ia[5]
        np.testing.assert_allclose(M[i], ref, rtol=1e-10, atol=1e-12)


# --------------------------------------------------- 3. planar 2R closed form

def double_pendulum(p, q, qd, qdd, g=9.81, d2=1.0):
    """Textbook double pendulum in a vertical plane, gravity along -y of the base.

    Link j's frame turns with q1 (+ q2); ZZj about the frame origin, (MXj, MYj)
    first moments in the link frame, M2 at the elbow, d2 the length of link 1.
    """
    q1, q2 = q[:, 0], q[:, 1]
    s1, c1 = np.sin(q1), np.cos(q1)
    s2, c2 = np.sin(q2), np.cos(q2)
    s12, c12 = np.sin(q1 + q2), np.cos(q1 + q2)
    a = d2 * (p["MX2"] * c2 - p["MY2"] * s2)
    h = d2 * (p["MX2"] * s2 + p["MY2"] * c2)
    M11 = p["ZZ1"] + p["Ia1"] + p["M2"] * d2 ** 2 + p["ZZ2"] + 2 * a
    M12 = p["ZZ2"] + a
    M22 = p["ZZ2"] + p["Ia2"]
    C1 = -h * (2 * qd[:, 0] * qd[:, 1] + qd[:, 1] ** 2)
    C2 = h * qd[:, 0] ** 2
    G2 = g * (p["MX2"] * c12 - p["MY2"] * s12)
    G1 = g * (p["MX1"] * c1 - p["MY1"] * s1 + p["M2"] * d2 * c1) + G2
    tau = np.stack([M11 * qdd[:, 0] + M12 * qdd[:, 1] + C1 + G1,
                    M12 * qdd[:, 0] + M22 * qdd[:, 1] + C2 + G2], axis=1)
    for j in (1, 2):
        tau[:, j - 1] += (p[f"Fv{j}"] * qd[:, j - 1] + p[f"Fc{j}"] * np.sign(qd[:, j - 1])
                          + p[f"Off{j}"])
    return tau


@pytest.mark.parametrize("backend", BACKENDS)
def test_planar2_matches_closed_form(backend):
    robot = load_robot("planar2")
    rng = np.random.default_rng(8)
    chi = rng.normal(size=robot.n_standard)       # generic values, all 28 (XX.. must not matter)
    p = dict(zip(robot.standard_names, chi))
    q, qd, qdd = samples(2, N_SAMPLES, rng)
    tau = regressor(robot, q, qd, qdd, backend=backend) @ chi
    assert rel_err(tau, double_pendulum(p, q, qd, qdd)) <= TOL
    np.testing.assert_allclose(inverse_dynamics(robot, chi, q, qd, qdd), tau, rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------- 5. chunking

@pytest.mark.parametrize("backend", BACKENDS)
def test_chunking_does_not_change_the_regressor(tx40, backend):
    rng = np.random.default_rng(9)
    q, qd, qdd = samples(6, 53, rng)
    full = regressor(tx40, q, qd, qdd, chunk=10_000, backend=backend)
    small = regressor(tx40, q, qd, qdd, chunk=7, backend=backend)
    if backend == "numba":
        np.testing.assert_array_equal(small, full)      # per-sample arithmetic: bit-identical
    else:
        np.testing.assert_allclose(small, full, rtol=1e-13, atol=1e-13 * np.abs(full).max())
    idx = rng.permutation(tx40.n_standard)[:23]
    sub = regressor(tx40, q, qd, qdd, columns=idx, chunk=7, backend=backend)
    np.testing.assert_allclose(sub, full[:, :, idx], rtol=1e-13, atol=1e-13 * np.abs(full).max())


def test_regressor_chunks_cover_the_recording(tx40):
    rng = np.random.default_rng(10)
    q, qd, qdd = samples(6, 31, rng)
    bp = base_parameters(tx40)
    full = regressor(tx40, q, qd, qdd)
    seen = np.zeros(31, dtype=int)
    for sl, W in regressor_chunks(tx40, q, qd, qdd, columns=bp.independent, chunk=8):
        assert W.shape == (sl.stop - sl.start, 6, bp.n_base)
        np.testing.assert_array_equal(W, full[sl][:, :, bp.independent])
        seen[sl] += 1
    assert (seen == 1).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_out_buffer_is_written_and_returned(tx40, backend):
    rng = np.random.default_rng(11)
    q, qd, qdd = samples(6, 29, rng)
    full = regressor(tx40, q, qd, qdd, backend=backend)
    buf = np.full(full.shape, np.nan)                    # stale contents must not survive
    assert regressor(tx40, q, qd, qdd, out=buf, chunk=8, backend=backend) is buf
    np.testing.assert_array_equal(buf, regressor(tx40, q, qd, qdd, chunk=8, backend=backend))
    idx = [85, 3, -1, 14]
    sub = np.full((29, 6, 4), np.nan)
    regressor(tx40, q, qd, qdd, columns=idx, out=sub, backend=backend)
    np.testing.assert_array_equal(sub, regressor(tx40, q, qd, qdd, backend=backend)[:, :, idx])
    with pytest.raises(ValueError, match="shape"):
        regressor(tx40, q, qd, qdd, out=np.empty((29, 6, 4)), backend=backend)
    with pytest.raises(ValueError, match="C-contiguous"):
        regressor(tx40, q, qd, qdd, columns=idx, out=np.empty((29, 6, 8))[:, :, ::2], backend=backend)


def test_column_route_is_the_same_whatever_ran_before(tx40):
    """The columns route reuses one scratch buffer per thread: calls of every size, in any
    order, give the columns of the full regressor (out-of-range columns still raise)."""
    rng = np.random.default_rng(12)
    bp = base_parameters(tx40)
    q, qd, qdd = samples(6, 70, rng)
    full = regressor(tx40, q, qd, qdd)
    for n, chunk in ((70, 16), (5, 16), (70, 64), (3, 2), (70, 100), (41, 100)):
        W = regressor(tx40, q[:n], qd[:n], qdd[:n], columns=bp.independent, chunk=chunk)
        np.testing.assert_array_equal(W, full[:n][:, :, bp.independent])
    with pytest.raises(IndexError):
        regressor(tx40, q, qd, qdd, columns=[0, 86])
