"""The independent closed-loop plant (tests/support/independent_plant.py) is consistent,
deterministic, injects what its effect formulas say, and tracks its reference."""
import ast
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

import independent_plant as ip  # tests/ is on sys.path (conftest.py)

FS = 5000.0


@pytest.fixture(scope="module")
def tx40():
    return ip.tx40_plant("urdf")


@pytest.fixture(scope="module")
def rigid_run():
    """No friction, no effects, perfect sensors: 1 s of the TX40 URDF plant."""
    plant = ip.tx40_plant("urdf", friction=False)
    return plant, ip.run(plant, duration=1.0, rate=FS, seed=3, sensor=ip.PERFECT)


def _rnea_plus_armature(plant, q, qd, qdd):
    """rnea of a copy without armature, plus Ia qdd written out (independent of
    whether the Pinocchio version puts model.armature into rnea)."""
    m0 = pin.Model(plant.model)
    Ia = np.array(m0.armature)
    m0.armature = np.zeros(m0.nv)
    d0 = m0.createData()
    return np.array([pin.rnea(m0, d0, a, b, c) for a, b, c in zip(q, qd, qdd)]) + Ia * qdd


def test_module_imports_nothing_from_dynid():
    tree = ast.parse(Path(ip.__file__).read_text())
    roots = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    roots |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not roots & {"dynamics", "analysis", "reports", "oracles"}


def test_shared_data_found_by_walking_up():
    try:
        shared = ip.find_shared_data()
    except FileNotFoundError:
        pytest.skip("no shared/data folder above this checkout (a fresh clone elsewhere)")
    assert (shared.parent.name, shared.name) == ("shared", "data")
    if not ip.tx40_urdf_path(shared).exists():
        pytest.skip("TX40 URDF not in shared/data")
    assert ip.load_urdf_model(ip.tx40_urdf_path(shared)).nv == 6
    assert ip.load_urdf_model(ip.kuka_urdf_path()).nv == 7
    # the copy the TX40 example ships is the shared file
    assert ip.tx40_urdf_path().read_bytes() == ip.tx40_urdf_path(shared).read_bytes()


def test_mdh_model_has_the_urdf_kinematics(tx40):
    # Same joint origins and axes (URDF base 0.32 m up; joint 6 differs by a turn about z)
    mdh = ip.mdh_model(ip.TX40_MDH, np.zeros((6, 10)))
    du, dm = tx40.model.createData(), mdh.createData()
    for q in np.random.default_rng(0).uniform(-2, 2, (5, 6)):
        pin.forwardKinematics(tx40.model, du, q)
        pin.forwardKinematics(mdh, dm, q)
        for j in range(1, 7):
            assert np.allclose(du.oMi[j].translation - [0, 0, 0.32], dm.oMi[j].translation, atol=1e-9)
            assert np.allclose(du.oMi[j].rotation[:, 2], dm.oMi[j].rotation[:, 2], atol=1e-9)


def test_tx40_table2_links_are_physical():
    links, Ia, _, _ = ip.tx40_table2_parameters()
    for p in links:
        ev = np.linalg.eigvalsh(ip.inertia_from_khalil(p).inertia)
        assert ev.min() >= 0 and (ev.sum() - 2 * ev >= -1e-12).all()     # triangle inequalities
    # two of the Table 2 base parameters, by the regrouping formulas
    assert links[1, 6] + 0.225 * links[2, 9] == pytest.approx(2.11)      # MX2R
    assert links[1, 5] + Ia[1] + 0.050625 * links[2, 9] == pytest.approx(1.09)   # ZZ2R


def test_consistent_with_rnea_plus_armature(rigid_run):
    plant, rec = rigid_run
    q, qd, qdd, tau = rec["q_true"], rec["qd_true"], rec["qdd_true"], rec["tau"]
    assert np.array_equal(rec["q"], q) and np.array_equal(tau, rec["tau_applied"])
    # with the plant's own acceleration at the tick: exact
    exact = _rnea_plus_armature(plant, q, qd, qdd)
    assert np.abs(exact - tau).max() < 1e-9 * np.abs(tau).max()
    # with qd, qdd from central differences of the true positions at the controller
    # rate: what an identification sees; measured 0.1 % of the RMS torque per joint
    T = 1.0 / FS
    qd_c = (q[2:] - q[:-2]) / (2 * T)
    qdd_c = (q[2:] - 2 * q[1:-1] + q[:-2]) / T ** 2
    r = _rnea_plus_armature(plant, q[1:-1], qd_c, qdd_c) - tau[1:-1]
    rms = lambda x: np.sqrt((x ** 2).mean(axis=0))
    assert (rms(r) < 0.01 * rms(tau)).all()


def test_same_seed_same_recording(tx40):
    a, b, c = (ip.run(tx40, duration=0.3, rate=FS, seed=s) for s in (7, 7, 8))
    for k in ("t", "q", "qr", "tau", "q_true"):
        assert np.array_equal(a[k], b[k])
    assert not np.array_equal(a["tau"], c["tau"]) and not np.array_equal(a["qr"], c["qr"])


def test_tracking_error_small_with_default_gains(tx40):
    rec = ip.run(tx40, duration=2.0, rate=FS, seed=0)
    e = rec["q_true"] - rec["qr"]
    assert np.sqrt((e ** 2).mean(axis=0)).max() < 5e-3          # measured <= 2 mrad
    assert np.abs(rec["qr"] - rec["q"]).max() < 0.02
    # the reference: within the joint limits, zero mean velocity over the run
    lim = tx40.limits
    assert (rec["qr"] >= lim["lower"]).all() and (rec["qr"] <= lim["upper"]).all()
    assert np.abs(rec["qdr"][:-1].mean(axis=0)).max() < 1e-3


def test_gains_are_the_documented_pole_placement():
    g = ip.closed_loop_gains(J=[2.0, 0.5], wn=[100.0, 50.0], zeta=0.7, integral_ratio=0.2)
    for j, (J, wn) in enumerate([(2.0, 100.0), (0.5, 50.0)]):
        p = 0.2 * wn
        want = np.poly([-p, *np.roots([1, 2 * 0.7 * wn, wn ** 2])]).real * J
        assert np.allclose([J, g["Kd"][j], g["Kp"][j], g["Ki"][j]], want)


def test_controller_law_reproduced_from_the_recording(rigid_run):
    # tau = Kp e + Kd (qdr - qd) + Ki I, I = I0 + T cumsum(e), I0 = g(q0) / Ki
    plant, rec = rigid_run
    g = rec["gains"]
    e = rec["qr"] - rec["q_true"]
    integ = plant.gravity(rec["q_true"][0]) / g["Ki"] + np.cumsum(e, axis=0) / FS
    u = g["Kp"] * e + g["Kd"] * (rec["qdr"] - rec["qd_true"]) + g["Ki"] * integ
    assert np.allclose(u, rec["tau_command"], rtol=0, atol=1e-6)


def test_measured_feedback_law():
    # velocity = backward difference of the measured positions (here exact ones)
    plant = ip.tx40_plant("urdf")
    rec = ip.run(plant, duration=1.0, rate=1000.0, seed=0, sensor=ip.PERFECT,
                 feedback="measured")
    g, q = rec["gains"], rec["q"]
    v = np.vstack([rec["qd_true"][:1], np.diff(q, axis=0) * 1000.0])
    e = rec["qr"] - q
    integ = plant.gravity(q[0]) / g["Ki"] + np.cumsum(e, axis=0) / 1000.0
    u = g["Kp"] * e + g["Kd"] * (rec["qdr"] - v) + g["Ki"] * integ
    assert np.allclose(u, rec["tau_command"], rtol=0, atol=1e-6)
    assert np.sqrt(((q - rec["qr"]) ** 2).mean(axis=0)).max() < 0.05
    assert rec["substeps"] > 4            # chosen for the friction's stiffness at 1 kHz


# ----------------------------------------------------------------------------- effects

N = 400
RNG = np.random.default_rng(11)
T_ = np.linspace(0.0, 4.0, N)
Q = RNG.uniform(-1, 1, (N, 6))
QD = RNG.uniform(-2, 2, (N, 6))
QDD = RNG.uniform(-10, 10, (N, 6))
TR = RNG.uniform(-30, 30, (N, 6))
G = RNG.uniform(-20, 20, (N, 6))
E = 0.01

# name, params, expected torque on the named joint (column 3, 0-based 2)
FORMULAS = [
    ("stribeck", dict(joint=3, Fs=2.0, vs=0.1, v_eps=E),
     lambda: 2.0 * np.exp(-(QD[:, 2] / 0.1) ** 2) * np.tanh(QD[:, 2] / E)),
    ("asymmetric_coulomb", dict(joint=3, Fc_pos=1.5, Fc_neg=0.5, v_eps=E),
     lambda: np.where(QD[:, 2] > 0, 1.5, 0.5) * np.tanh(QD[:, 2] / E)),
    ("asymmetric_viscous", dict(joint=3, Fv_pos=2.0, Fv_neg=1.0),
     lambda: np.where(QD[:, 2] > 0, 2.0, 1.0) * QD[:, 2]),
    ("position_ripple", dict(joint=3, A=0.4, k=3, phi=0.2), lambda: 0.4 * np.sin(3 * Q[:, 2] + 0.2)),
    ("spring", dict(joint=3, k=5.0, q0=0.1), lambda: 5.0 * (Q[:, 2] - 0.1)),
    ("coupling", dict(joint=3, source=1, c=0.3, signal="qd"), lambda: 0.3 * QD[:, 0]),
    ("coupling", dict(joint=3, source=2, c=0.05, signal="qdd"), lambda: 0.05 * QDD[:, 1]),
    ("drift", dict(joint=3, rate=0.25), lambda: 0.25 * T_),
    ("load_friction", dict(joint=3, mu=0.02, v_eps=E), lambda: 0.02 * np.abs(TR[:, 2]) * np.tanh(QD[:, 2] / E)),
    ("load_friction", dict(joint=3, mu=0.02, load="gravity", v_eps=E),
     lambda: 0.02 * np.abs(G[:, 2]) * np.tanh(QD[:, 2] / E)),
    ("offset", dict(joint=3, value=-0.7), lambda: np.full(N, -0.7)),
    ("friction_warmup", dict(joint=3, Fv=2.0, Fc=3.0, drop=0.25, tc=2.0, v_eps=E),
     lambda: -0.25 * (1 - np.exp(-T_ / 2.0)) * (2.0 * QD[:, 2] + 3.0 * np.tanh(QD[:, 2] / E))),
    ("high_order_ripple", dict(joint=3, A=[0.3, 0.1], k=[50, 100], phi=[0.0, 1.0]),
     lambda: 0.3 * np.sin(50 * Q[:, 2]) + 0.1 * np.sin(100 * Q[:, 2] + 1.0)),
    ("torque_step", dict(joint=3, value=1.2, t_step=1.5), lambda: np.where(T_ >= 1.5, 1.2, 0.0)),
    ("velocity_dependent_ripple", dict(joint=3, A=0.2, k=6, phi=0.0, v_ref=0.5),
     lambda: 0.2 * np.abs(QD[:, 2]) / 0.5 * np.sin(6 * Q[:, 2])),
    ("gravity_compensation_spring", dict(joint=3, k=15.0, phi=0.3), lambda: 15.0 * np.sin(Q[:, 2] + 0.3)),
]


@pytest.mark.parametrize("name, params, formula", FORMULAS, ids=[f"{f[0]}-{i}" for i, f in enumerate(FORMULAS)])
def test_effect_adds_its_formula(name, params, formula):
    eff = ip.make_effect(name, **params)
    out = eff(T_, Q, QD, QDD, TR, {"gravity": G})
    assert out.shape == Q.shape and np.allclose(np.delete(out, 2, axis=1), 0.0)
    assert np.allclose(out[:, 2], formula(), rtol=1e-12, atol=1e-12)
    one = eff(T_[5], Q[5], QD[5], QDD[5], TR[5], {"gravity": G[5]})    # one sample
    assert np.allclose(one, out[5])


def test_every_registered_effect_has_a_formula_test():
    tested = {f[0] for f in FORMULAS} | {"backlash_hysteresis", "temperature", "time_delay",
                                         "coupled_motor_friction"}
    assert set(ip.EFFECTS) == tested
    assert all(ip.EFFECTS[k].__doc__ for k in ip.EFFECTS)


def test_backlash_hysteresis_is_a_dahl_state():
    eff = ip.make_effect("backlash_hysteresis", joint=1, F=2.0, width=0.01)
    q = np.concatenate([np.linspace(0, 0.1, 51), np.linspace(0.1, 0.0, 51)[1:]])[:, None]
    out = eff(0.0, q, 0 * q, 0 * q, 0 * q, {})[:, 0]
    z, want = 0.0, []
    for dq in np.diff(q[:, 0], prepend=q[0, 0])[1:]:
        z = np.sign(dq) + (z - np.sign(dq)) * np.exp(-abs(dq) / 0.01)
        want.append(2.0 * z)
    assert np.allclose(out[1:], want) and out[0] == 0.0
    assert out[50] == pytest.approx(2.0, abs=1e-3) and out[-1] == pytest.approx(-2.0, abs=1e-3)
    assert 0 < out[51] < 2.0            # just after the reversal: still on the old side


def test_temperature_heats_and_lowers_friction():
    eff = ip.make_effect("temperature", joint=1, Fv=2.0, Fc=1.0, kappa=0.01, C=10.0, tc=50.0)
    t = np.arange(0, 5, 0.01)
    qd = np.full((t.size, 1), 1.0)
    out = eff(t, 0 * qd, qd, 0 * qd, 0 * qd, {})[:, 0]
    P = 2.0 + np.tanh(1.0 / ip.V_EPS)                    # W at qd = 1 rad/s
    T = np.zeros(t.size)
    for i in range(1, t.size):
        T[i] = T[i - 1] + 0.01 * (P / 10.0 - T[i - 1] / 50.0)
    assert np.allclose(out, -0.01 * T * P)


def test_coupled_motor_friction_acts_on_both_joints():
    eff = ip.make_effect("coupled_motor_friction", joints=(5, 6), Fv=0.8, Fc=1.6, v_eps=E)
    out = eff(T_, Q, QD, QDD, TR, {})
    w = QD[:, 4] + QD[:, 5]
    f = 0.8 * w + 1.6 * np.tanh(w / E)
    assert np.allclose(out[:, 4], f) and np.allclose(out[:, 5], f) and np.allclose(out[:, :4], 0)


def test_effects_enter_the_plant_torque():
    # In closed loop the applied torque is rigid body + friction + effects at each tick
    effects = [ip.make_effect("position_ripple", joint=1, A=1.0, k=4.0),
               ip.make_effect("stribeck", joint=2, Fs=3.0, vs=0.05),
               ip.make_effect("torque_step", joint=3, value=2.0, t_step=0.2),
               ip.make_effect("gravity_compensation_spring", joint=2, k=20.0)]
    plant = ip.tx40_plant("urdf", effects=effects)
    rec = ip.run(plant, duration=0.4, rate=FS, seed=1, sensor=ip.PERFECT)
    q, qd, qdd = rec["q_true"], rec["qd_true"], rec["qdd_true"]
    rest = rec["tau"] - _rnea_plus_armature(plant, q, qd, qdd) - plant.friction(qd)
    t = rec["t"]
    want = np.zeros_like(q)
    want[:, 0] = np.sin(4 * q[:, 0])
    want[:, 1] = 3.0 * np.exp(-(qd[:, 1] / 0.05) ** 2) * np.tanh(qd[:, 1] / ip.V_EPS) + 20.0 * np.cos(q[:, 1])
    want[:, 2] = np.where(t >= 0.2, 2.0, 0.0)
    assert np.allclose(rest, want, rtol=0, atol=1e-8)
    assert np.allclose(rec["tau_effects"], want, rtol=0, atol=1e-8)


def test_time_delay_shifts_only_the_recorded_torque():
    plain = ip.run(ip.tx40_plant("urdf"), duration=0.3, rate=FS, seed=2, sensor=ip.PERFECT)
    plant = ip.tx40_plant("urdf", effects=[ip.make_effect("time_delay", delay=1e-3, joints=[2])])
    late = ip.run(plant, duration=0.3, rate=FS, seed=2, sensor=ip.PERFECT)
    assert np.array_equal(plain["q_true"], late["q_true"])
    assert np.array_equal(np.delete(plain["tau"], 1, 1), np.delete(late["tau"], 1, 1))
    assert np.allclose(late["tau"][5:, 1], plain["tau"][:-5, 1])        # 1 ms = 5 samples
    assert np.all(late["tau"][:5, 1] == plain["tau"][0, 1])


# ----------------------------------------------------------------------------- variants, output


def test_table2_coupled_wrist_and_kuka_run():
    plant = ip.tx40_plant("table2", coupled_wrist=True)
    assert plant.full_armature and plant.A[4, 5] == plant.A[5, 5] == 0.012
    rec = ip.run(plant, duration=0.3, rate=FS, seed=0, sensor=ip.PERFECT)
    exact = plant.rigid_torque(rec["q_true"], rec["qd_true"], rec["qdd_true"])
    rest = rec["tau"] - exact - plant.friction(rec["qd_true"])
    w = rec["qd_true"][:, 4] + rec["qd_true"][:, 5]
    assert np.allclose(rest[:, 5], 0.8 * w + 1.6 * np.tanh(w / ip.V_EPS), atol=1e-8)
    kuka = ip.kuka_plant()
    rec = ip.run(kuka, duration=1.0, rate=1000.0, seed=0, log_every=2)
    assert rec["q"].shape == (501, 7) and rec["rate"] == 500.0
    assert np.sqrt(((rec["q_true"] - rec["qr"]) ** 2).mean()) < 5e-3


def test_stiff_friction_is_refused():
    plant = ip.Plant(ip.tx40_plant("urdf").model, np.full(6, 0.01),
                     ip.FrictionLaw(np.zeros(6), np.full(6, 5.0), v_eps=1e-3))
    ref = ip.multisine_reference(plant.limits, 0.02, 1000.0)
    with pytest.raises(ValueError, match="substeps"):
        ip.simulate(plant, ip.default_controller(plant, 1000.0), ref, substeps=4)
    assert ip.simulate(plant, ip.default_controller(plant, 1000.0), ref)["substeps"] > 4


def test_write_csv_in_dynids_format(tmp_path, tx40):
    rec = ip.run(tx40, duration=0.01, rate=FS, seed=0)
    path = ip.write_csv(tmp_path / "run.csv", rec)
    lines = path.read_text().splitlines()
    assert lines[0] == "t," + ",".join(f"{s}{j}" for s in ("q", "qr", "tau") for j in range(1, 7))
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    assert data.shape == (51, 19)
    assert np.allclose(data[:, 0], rec["t"]) and np.allclose(data[:, 13:], rec["tau"], rtol=1e-11)
