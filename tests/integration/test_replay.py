"""Replay: the URDF and the MJCF written for a PC-WLS model, read by Pinocchio and MuJoCo,
reproduce dynid's predicted torques on held-out data (TX40 and LWR4+ real data, panda simulated).

dynid's prediction is its model at the held-out states (q, qd, qdd of the processed
recording): the standard regressor times the PC standard set. Pinocchio's ``rnea`` (from
the URDF) is the rigid body; the joint terms are added from the URDF's own fields
(``<dynamics damping friction>``) and its ``<dynid:parameters>`` (Ia, Off). MuJoCo's
``mj_inverse`` (from the MJCF) is checked rigid body first (armature, damping and
frictionloss set to 0), then armature + damping against Ia qdd + Fv qd, then its dry
friction, a soft constraint, against Fc sign(qd) where the joint moves; finally the whole
MuJoCo torque (+ Off, which MJCF has no field for) against dynid's prediction.

The LWR4+ again with a linear spring on every joint fitted beside the PC rigid body
(``--effects spring:all``, issue 15): the MJCF's joint stiffness against Ks q in closed
form, and MuJoCo's whole torque against dynid's prediction of that effects model.
"""
from pathlib import Path

import numpy as np
import pytest

import dynid
from dynid.analysis.diagnosis.physical_fit import effect_candidates, effect_design, identify_physical_effects
from dynid.analysis.estimators.physical import identify_physical
from dynid.analysis.processing.observation import observe
from dynid.dynamics.mjcf_writer import mjcf_text
from dynid.dynamics.regressor import regressor
from dynid.dynamics.urdf_writer import read_extra_parameters, urdf_text

pin = pytest.importorskip("pinocchio")
mujoco = pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parents[2]


def _kuka():
    robot = dynid.load_robot("kuka_lwr4")
    here = ROOT / "examples" / "kuka_lwr4"
    rec = {i: dynid.load_experiment(here / f"recording_{i}.toml", robot) for i in (1, 2, 3)}
    return robot, [rec[2], rec[3]], rec[1]


def _tx40():
    robot = dynid.load_robot("tx40")
    exp = dynid.load_experiment(ROOT / "examples" / "staubli_tx40" / "experiment.toml", robot)
    t_split = exp.t[-1] - 4.0
    return robot, exp.segment(None, t_split), exp.segment(t_split, None)


def _a_rigid_body_set(robot, rng):
    """A physically consistent truth: random masses, centres of mass, inertias, rotors, friction."""
    chi = np.zeros(robot.n_standard)
    names = robot.standard_names
    for k in range(1, robot.n_joints + 1):
        m = rng.uniform(1.0, 4.0)
        c = rng.normal(0, 0.05, 3)
        I_o = np.diag(rng.uniform(0.02, 0.03, 3)) + m * (c @ c * np.eye(3) - np.outer(c, c))
        for sym, v in zip(("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M"),
                          (I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m)):
            chi[names.index(f"{sym}{k}")] = v
        chi[names.index(f"Ia{k}")] = rng.uniform(0.01, 0.1)
        chi[names.index(f"Fv{k}")] = rng.uniform(0.1, 1.0)
        chi[names.index(f"Fc{k}")] = rng.uniform(0.1, 1.0)
    return chi


def _panda():
    """The Panda has no published a-priori parameters: simulated with a random physical truth."""
    from dynid.analysis.data.synthetic import simulate_experiment
    from dynid.dynamics.trajectories import random_fourier_trajectory
    robot = dynid.load_robot("panda")
    rng = np.random.default_rng(4)
    chi = _a_rigid_body_set(robot, rng)
    runs = [simulate_experiment(robot, chi, random_fourier_trajectory(robot, 0.1, 6, rng), d, rng=rng,
                                tau_noise=0.2, q_noise=1e-5) for d in (10.0, 5.0)]
    return robot, runs[0], runs[1]


CASES = {"kuka_lwr4": _kuka, "tx40": _tx40, "panda": _panda}


@pytest.fixture(scope="module", params=sorted(CASES))
def replay(request, tmp_path_factory):
    robot, ident, held = CASES[request.param]()
    res = dynid.identify(ident, robot)
    pc = identify_physical(res, robot, n_boot=0)
    obs = observe(held, robot, res.base, dict(res.settings, qd_threshold=0.0))
    chi = pc.standard
    tmp = tmp_path_factory.mktemp(request.param)
    (tmp / "m.urdf").write_text(urdf_text(robot, chi))
    (tmp / "m.xml").write_text(mjcf_text(robot, chi))
    predicted = regressor(robot, obs.q, obs.qd, obs.qdd) @ chi
    return robot, pc, obs, tmp, predicted


def _per_joint(robot, chi, sym):
    return np.array([chi[robot.standard_names.index(f"{sym}{j + 1}")] for j in range(robot.n_joints)])


def _rigid(robot, chi):
    out = chi.copy()
    for j in range(robot.n_joints):
        for s in ("Ia", "Fv", "Fc", "Off"):
            out[robot.standard_names.index(f"{s}{j + 1}")] = 0.0
    for c in robot.couplings:
        for nm in c.parameter_names:
            out[robot.standard_names.index(nm)] = 0.0
    return out


def _rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_the_model_exported_is_physical(replay):
    robot, pc, *_ = replay
    assert pc.consistent and all(lk["consistent"] for lk in pc.links)


def test_pinocchio_replays_the_urdf(replay):
    robot, pc, obs, tmp, predicted = replay
    model = pin.buildModelFromUrdf(str(tmp / "m.urdf"))
    # URDF has no gravity field: the file puts -g along world -z, its size is the consumer's
    # (Pinocchio's 9.81; the Panda's file says 9.80665)
    model.gravity.linear = np.array([0.0, 0.0, -np.linalg.norm(robot.gravity)])
    data = model.createData()
    assert model.nq == robot.n_joints
    rnea = np.array([pin.rnea(model, data, q, qd, qdd) for q, qd, qdd in zip(obs.q, obs.qd, obs.qdd)])
    rigid = regressor(robot, obs.q, obs.qd, obs.qdd) @ _rigid(robot, pc.standard)
    assert _rel(rnea, rigid) < 1e-8
    # the joint terms as the file holds them (URDF dynamics + dynid:parameters)
    import xml.etree.ElementTree as ET
    root = ET.parse(tmp / "m.urdf").getroot()
    dyn = {j.get("name"): j.find("dynamics") for j in root.findall("joint") if j.get("type") != "fixed"}
    extra = read_extra_parameters(tmp / "m.urdf")
    Fv = np.array([float(dyn[jn.name].get("damping")) for jn in robot.joints])
    Fc = np.array([float(dyn[jn.name].get("friction")) for jn in robot.joints])
    Ia = np.array([extra[f"Ia{j + 1}"] for j in range(robot.n_joints)])
    off = np.array([extra[f"Off{j + 1}"] for j in range(robot.n_joints)])
    total = rnea + Ia * obs.qdd + Fv * obs.qd + Fc * np.sign(obs.qd) + off
    # a coupled rotor (TX40 wrist) has no URDF field: its terms, eq. (33) of Gautier, Janot &
    # Vandanjon 2010, from the values the file keeps in <dynid:parameters>
    for c in robot.couplings:
        idx = np.asarray(c.joints) - 1
        coef = np.asarray(c.coefficients, dtype=float)
        cm = coef[list(c.joints).index(c.motor)]
        w = obs.qd[:, idx] @ coef
        for a, ka in zip(idx, coef):
            total[:, a] += sum(ka * kb / cm ** 2 * Ia[c.motor - 1] * obs.qdd[:, b]
                               for b, kb in zip(idx, coef) if b != a)
            total[:, a] += ka * (extra[f"Fvm{c.motor}"] * w + extra[f"Fcm{c.motor}"] * np.sign(w))
    assert _rel(total, predicted) < 1e-8


def _inverse(model, obs):
    data = mujoco.MjData(model)
    out = np.empty_like(obs.q)
    for k in range(len(obs.q)):
        data.qpos[:], data.qvel[:], data.qacc[:] = obs.q[k], obs.qd[k], obs.qdd[k]
        mujoco.mj_inverse(model, data)
        out[k] = data.qfrc_inverse
    return out


def _columns(robot, *kinds):
    return [i for i, nm in enumerate(robot.standard_names) if nm.rstrip("0123456789") in kinds]


def test_mujoco_replays_the_mjcf(replay):
    robot, pc, obs, tmp, predicted = replay
    chi = pc.standard
    model = mujoco.MjModel.from_xml_path(str(tmp / "m.xml"))
    assert model.nv == robot.n_joints and model.ntendon == len(robot.couplings)
    lo_hi = np.array([j.q_limits for j in robot.joints])
    limited = np.all(np.isfinite(lo_hi), axis=1)
    np.testing.assert_allclose(model.jnt_range[limited], lo_hi[limited])
    # limits are a constraint too: where a recording grazes a limit (the simulated Panda's
    # closed loop does) mj_inverse adds its force; dynid's model has none, so they are off here
    model.jnt_limited[:] = 0
    full = _inverse(model, obs)
    for arr in (model.dof_armature, model.dof_damping, model.dof_frictionloss,
                model.tendon_armature, model.tendon_damping, model.tendon_frictionloss):
        arr[:] = 0.0
    rigid_mj = _inverse(model, obs)
    W = regressor(robot, obs.q, obs.qd, obs.qdd)
    rigid = W @ _rigid(robot, chi)
    assert _rel(rigid_mj, rigid) < 1e-8
    # armature + damping (and a coupled rotor's tendon): dynid's Ia, Fv (Fvm) columns
    smooth = _columns(robot, "Ia", "Fv", "Fvm")
    coulomb = _columns(robot, "Fc", "Fcm")
    friction = (full - rigid_mj) - W[:, :, smooth] @ chi[smooth]
    dry = W[:, :, coulomb] @ chi[coulomb]
    # MuJoCo's dry friction (a soft constraint) never exceeds its bound, and is dynid's
    # Fc sign(qd) where the joint (and a rotor it is coupled to) moves
    bound = np.abs(W[:, :, coulomb]).max(axis=0) @ np.abs(chi[coulomb])
    assert np.all(np.abs(friction) <= bound * (1 + 1e-6) + 1e-9)
    moving = np.abs(obs.qd) > 0.05
    for c in robot.couplings:
        w = obs.qd[:, np.asarray(c.joints) - 1] @ np.asarray(c.coefficients, dtype=float)
        moving[:, np.asarray(c.joints) - 1] &= (np.abs(w) > 0.05)[:, None]
    assert moving.sum() > 50           # (the TX40 recording ends at rest)
    off = np.abs(friction - dry) > 0.01 * np.abs(dry) + 1e-9
    assert off[moving].mean() < 0.01
    # the whole torque (Off added: MJCF has no field for it): on every held-out sample but
    # for the dry friction, which at rest is MuJoCo's (at most Fc, no sign jump), not Fc sign(qd)
    total = full + _per_joint(robot, chi, "Off")
    assert _rel(total - friction + dry, predicted) < 1e-8
    rows = moving.all(axis=1)
    assert rows.sum() > 20 and _rel(total[rows], predicted[rows]) < 0.01


# ------------------------------------------------------------------ the LWR4+ with its springs
@pytest.fixture(scope="module")
def replay_springs():
    """PC-WLS of the LWR4+ with a spring Ks_j q_j on every joint (issue 15), identified on
    recordings 2 + 3, its MJCF with the springs, and recording 1 held out: dynid's prediction
    of that model is the effect design's ``[W, C] @ x_pc`` (as ``held_out_errors`` builds it)."""
    robot, ident, held = _kuka()
    res = dynid.identify(ident, robot)
    candidates = effect_candidates("spring:all", robot.n_joints)
    fit = identify_physical_effects(ident, robot, res, candidates, n_boot=0)
    springs = {c.joint: float(k) for c, k in zip(candidates, fit.theta_pc)}
    settings = dict(res.settings, qd_threshold=0.0)
    obs = observe(held, robot, res.base, settings)
    W, _, _, names = effect_design(held, robot, res.base, settings, candidates)
    assert names[res.base.n_base:] == [f"Ks{j}" for j in springs]
    return robot, fit, springs, obs, mjcf_text(robot, fit.physical.standard, springs=springs), W @ fit.x_pc


def _model(xml, *zeroed):
    """The MJCF's model, joint limits off (see test_mujoco_replays_the_mjcf), ``zeroed`` fields 0."""
    model = mujoco.MjModel.from_xml_string(xml)
    model.jnt_limited[:] = 0
    for name in zeroed:
        getattr(model, name)[:] = 0.0
    return model


def test_the_mjcf_holds_the_springs(replay_springs):
    robot, fit, springs, _, xml, _ = replay_springs
    assert fit.physical.consistent
    model = _model(xml)
    Ks = np.array([springs[j + 1] for j in range(robot.n_joints)])
    np.testing.assert_array_equal(model.jnt_stiffness, Ks)
    np.testing.assert_array_equal(model.qpos_spring, 0.0)
    # these data give a negative Ks4: the anti-spring is replayed below too
    assert Ks.min() < 0 < Ks.max()
    assert "negative stiffness on joint(s) 4" in xml


def test_mujoco_replays_the_springs(replay_springs):
    robot, fit, springs, obs, xml, predicted = replay_springs
    chi = fit.physical.standard
    Ks = np.array([springs[j + 1] for j in range(robot.n_joints)])
    off = _per_joint(robot, chi, "Off")
    full = _inverse(_model(xml), obs)
    no_springs = _inverse(_model(xml, "jnt_stiffness"), obs)
    rigid_mj = _inverse(_model(xml, "jnt_stiffness", "dof_armature", "dof_damping", "dof_frictionloss"), obs)
    # the spring part alone, closed form: the drive balances MuJoCo's -stiffness (q - springref)
    # with +Ks q
    spring = Ks * obs.q
    assert np.abs(spring).max() > 0.1
    np.testing.assert_allclose(full - no_springs, spring, rtol=0, atol=1e-12)
    # the rest as in test_mujoco_replays_the_mjcf: the rigid body exactly, then the dry friction
    # (a soft constraint) within Fc, and Fc sign(qd) where the joint moves
    W = regressor(robot, obs.q, obs.qd, obs.qdd)
    assert _rel(rigid_mj, W @ _rigid(robot, chi)) < 1e-8
    smooth, coulomb = _columns(robot, "Ia", "Fv"), _columns(robot, "Fc")
    friction = (no_springs - rigid_mj) - W[:, :, smooth] @ chi[smooth]
    dry = W[:, :, coulomb] @ chi[coulomb]
    assert np.all(np.abs(friction) <= np.abs(_per_joint(robot, chi, "Fc")) * (1 + 1e-6) + 1e-9)
    moving = np.abs(obs.qd) > 0.05
    assert (np.abs(friction - dry) > 0.01 * np.abs(dry) + 1e-9)[moving].mean() < 0.01
    # the whole MuJoCo torque (+ Off) against dynid's prediction of the effects model on the
    # held-out recording, where every joint moves (measured 0.06 %; the decimated design is not
    # W at the decimated states, so not to 1e-8)
    rows = moving.all(axis=1)
    assert rows.sum() > 100
    assert _rel((full + off)[rows], predicted[rows]) < 0.01
    # the rigid body without its springs is another model: 2.2 % from that prediction
    assert _rel((no_springs + off)[rows], predicted[rows]) > 0.01


@pytest.mark.parametrize("springs, words", [
    ({0: 1.0}, "spring on joint 0"), ({3: 1.0}, "joints of 'planar2' are 1..2"),
    ({"1": 1.0}, "spring on joint '1'"), ({1: float("nan")}, "Ks1 = nan is not finite"),
    ({2: "stiff"}, "Ks2 = 'stiff' is not a number")])
def test_mjcf_text_refuses_springs_it_cannot_write(springs, words):
    from dynid.errors import InputError
    robot = dynid.load_robot("planar2")
    chi = _a_rigid_body_set(robot, np.random.default_rng(0))
    with pytest.raises(InputError, match=words.replace(".", r"\.").replace("(", r"\(")):
        mjcf_text(robot, chi, springs=springs)


def test_effect_springs_refuses_what_mjcf_cannot_hold():
    """The Python path of the CLI's refusal: an effect other than spring, or no PC fit."""
    from types import SimpleNamespace

    from dynid.errors import InputError
    from dynid.reports.urdf_export import effect_springs
    rows = [{"effect": "spring", "joint": 1, "pc": 0.5}, {"effect": "position_ripple", "joint": 2, "pc": 0.1}]
    with pytest.raises(InputError, match="no field for the effect.s. position_ripple on joint 2"):
        effect_springs(SimpleNamespace(physical=object(), effects=lambda: rows))
    with pytest.raises(InputError, match="add --physical"):
        effect_springs(SimpleNamespace(physical=None, effects=lambda: rows[:1]))
    assert effect_springs(SimpleNamespace(physical=object(), effects=lambda: rows[:1])) == {1: 0.5}
