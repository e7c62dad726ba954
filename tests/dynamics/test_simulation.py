"""Compiled dynamics (dynid.dynamics.dynamic_model) and closed-loop simulation (dynid.dynamics.simulation).

The simulator is checked against an independent closed loop whose plant is
Pinocchio (tests/support/oracles.py: pin_closed_loop), against closed forms of a 1-dof
pendulum, and for its integration error against a 4x finer step.
"""
import dataclasses
import time

import numpy as np
import pytest

from dynid.analysis.data.synthetic import experiment_from_simulation
from dynid.dynamics import dynamic_model as dm
from dynid.dynamics.robot import Controller, Coupling, Joint, Robot, mdh_placement
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.simulation import (
    SimulationResult,
    friction_stiffness,
    simulate_closed_loop,
    simulate_torque,
)
from dynid.dynamics.trajectories import random_fourier_trajectory
from dynid.errors import InputError
from tests.support import oracles
from tests.support.oracles import regressor_inverse_dynamics

pin = oracles.pin
needs_pin = pytest.mark.skipif(pin is None, reason="pinocchio (pin) not installed")


# ----------------------------------------------------------------------------- fixtures

def tx40_like_parameters(robot, rng):
    """Physically plausible TX40 standard parameters: link masses/inertias of the
    right order of magnitude, actuator inertias and frictions of Table 2
    (Gautier, Janot, Vandanjon 2010)."""
    masses = [6.0, 7.0, 3.5, 2.0, 0.8, 0.15]
    com = [0.05, 0.12, 0.05, 0.04, 0.02, 0.01]
    spread = [0.15, 0.2, 0.1, 0.05, 0.02, 0.008]
    Ia = [0.9, 0.6, 0.083, 0.029, 0.053, 0.012]
    Fv = [8.71, 7.0, 2.37, 1.0, 2.52, 0.72]
    Fc = [7.69, 7.74, 6.6, 2.47, 2.77, 0.9]
    chi = np.zeros(robot.n_standard)
    for j in range(6):
        m = masses[j]
        c = rng.normal(0, com[j], 3)
        A = rng.normal(0, spread[j], (3, 3))
        I = A @ A.T + 1e-4 * np.eye(3) + m * (c @ c * np.eye(3) - np.outer(c, c))
        chi[14 * j:14 * j + 14] = [I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2],
                                   *(m * c), m, Ia[j], Fv[j], Fc[j], rng.normal(0, 0.3)]
    chi[84:] = [0.8, 1.6]                      # Fvm6, Fcm6
    return chi


def random_robot(rng, with_coupling=True):
    """4 joints, joint 2 prismatic, random placements; optionally a general coupling."""
    joints = []
    for k, sigma in enumerate([0, 1, 0, 0]):
        R, p = mdh_placement(*rng.uniform(-np.pi, np.pi, 1), rng.uniform(-0.3, 0.3),
                             rng.uniform(-np.pi, np.pi), rng.uniform(-0.3, 0.3))
        joints.append(Joint(name=f"j{k + 1}", sigma=sigma, R=R, p=p, q_limits=(-2.0, 2.0),
                            qd_max=2.0, qdd_max=10.0, tau_max=np.inf))
    couplings = [Coupling(motor=4, joints=(3, 4), coefficients=(0.5, -1.3))] if with_coupling else []
    ctrl = Controller(kind="pd", rate=2000.0, wn=np.full(4, 40.0), zeta=np.ones(4),
                      J_ap=np.full(4, 0.5), g_ap=np.ones(4))
    return Robot(name="random4", joints=joints, gravity=np.array([0.3, -1.0, -9.81]),
                 couplings=couplings, controller=ctrl)


@pytest.fixture(scope="module")
def tx40():
    return load_robot("tx40")


def pendulum(m=2.0, l=0.5, Ia=0.0):
    """1-dof pendulum in a vertical plane: point mass m at x = l, gravity -y."""
    robot = Robot(name="pendulum", joints=[Joint(name="j1", tau_max=np.inf)],
                  gravity=np.array([0.0, -9.81, 0.0]),
                  controller=Controller(kind="pd", rate=1000.0, wn=np.array([30.0]),
                                        zeta=np.array([1.0]), J_ap=np.array([0.5]),
                                        g_ap=np.array([1.0])))
    chi = np.zeros(14)
    chi[[3, 5]] = m * l * l                      # YY, ZZ of the point mass about the axis
    chi[6] = m * l                               # MX
    chi[9] = m
    chi[10] = Ia
    return robot, chi


# ----------------------------------------------------------------------------- (a) dynamics vs Pinocchio

def _pin_reference(robot, chi, q, qd, qdd):
    model = oracles.pin_model_from_robot(robot, chi)
    data = model.createData()
    A = oracles.armature_matrix(robot, chi)
    tau = np.empty_like(q)
    M = np.empty(q.shape + (q.shape[1],))
    for s in range(q.shape[0]):
        tau[s] = pin.rnea(model, data, q[s], qd[s], qdd[s]) + oracles.actuator_torques(
            robot, chi, q[s], qd[s], qdd[s])
        Ms = np.array(pin.crba(model, data, q[s]))
        M[s] = np.triu(Ms) + np.triu(Ms, 1).T + A
    return tau, M


@needs_pin
@pytest.mark.parametrize("which", ["tx40", "random"])
def test_rnea_and_mass_matrix_match_pinocchio(which, tx40):
    rng = np.random.default_rng(11)
    robot = tx40 if which == "tx40" else random_robot(rng)
    chi = oracles.random_standard_parameters(robot, rng)
    n = robot.n_joints
    q, qd, qdd = (rng.uniform(-2, 2, (40, n)) for _ in range(3))
    tau_ref, M_ref = _pin_reference(robot, chi, q, qd, qdd)

    tau = dm.inverse_dynamics(robot, chi, q, qd, qdd)             # exact sign (v_s = 0)
    assert np.max(np.abs(tau - tau_ref)) <= 1e-10 * np.max(np.abs(tau_ref))
    M = dm.mass_matrix(robot, chi, q)
    assert np.max(np.abs(M - M_ref)) <= 1e-10 * np.max(np.abs(M_ref))
    assert np.array_equal(M, np.swapaxes(M, 1, 2))                  # exactly symmetric
    # the regressor route agrees too
    tau_w = regressor_inverse_dynamics(robot, chi, q, qd, qdd)
    assert np.max(np.abs(tau - tau_w)) <= 1e-10 * np.max(np.abs(tau_ref))
    # N(q, qd) and the direct model of eq. (17) invert the inverse model
    N = dm.bias_torque(robot, chi, q, qd)
    assert np.allclose(np.einsum("sij,sj->si", M, qdd) + N, tau, rtol=0, atol=1e-10 * np.abs(tau).max())
    qdd_fd = dm.forward_dynamics(robot, chi, q, qd, tau)
    assert np.max(np.abs(qdd_fd - qdd)) <= 1e-9 * np.max(np.abs(qdd))
    # one sample in, one sample out
    assert dm.forward_dynamics(robot, chi, q[0], qd[0], tau[0]).shape == (n,)


@needs_pin
@pytest.mark.parametrize("which", ["tx40", "random"])
def test_crba_mass_matrix_matches_pinocchio(which, tx40):
    """The CRBA of the simulator's `crba=True` mode against pin.crba (with a prismatic joint and
    a general coupling on the random robot), and its closed loop against the default one's."""
    rng = np.random.default_rng(12)
    robot = tx40 if which == "tx40" else random_robot(rng)
    chi = oracles.random_standard_parameters(robot, rng)
    n = robot.n_joints
    q = rng.uniform(-2, 2, (40, n))
    _, M_ref = _pin_reference(robot, chi, q, np.zeros_like(q), np.zeros_like(q))
    model, ws = dm.model_arrays(robot, chi).kernel_args(), dm._workspace(n)
    for s in range(q.shape[0]):
        dm._mass_crba(model, ws, q[s], True)
        M = ws[7]
        assert np.max(np.abs(M - M_ref[s])) <= 1e-12 * np.max(np.abs(M_ref[s]))
        assert np.array_equal(M, M.T)
    traj = random_fourier_trajectory(robot, 0.5, 3, rng)
    t = np.arange(401) / robot.controller.rate
    a = simulate_closed_loop(robot, chi, t, traj, v_s=0.05, substeps=2)
    b = simulate_closed_loop(robot, chi, t, traj, v_s=0.05, substeps=2, crba=True)
    assert not np.array_equal(a.qdd, b.qdd)             # the other algorithm ran ...
    assert np.max(np.abs(a.qdd - b.qdd)) <= 1e-10 * np.max(np.abs(a.qdd))   # ... to the same motion
    assert np.max(np.abs(a.q - b.q)) <= 1e-12


def test_smooth_sign_friction():
    robot, chi = pendulum()
    chi[12] = 3.0                                                   # Fc
    q = np.zeros((3, 1))
    qd = np.array([[0.005], [0.0], [-0.02]])
    z = np.zeros((3, 1))
    rigid = dm.inverse_dynamics(robot, np.where(np.arange(14) == 12, 0.0, chi), q, qd, z)
    exact = dm.inverse_dynamics(robot, chi, q, qd, z) - rigid
    smooth = dm.inverse_dynamics(robot, chi, q, qd, z, v_s=0.01) - rigid
    assert np.allclose(exact[:, 0], 3.0 * np.sign(qd[:, 0]))
    assert np.allclose(smooth[:, 0], 3.0 * np.tanh(qd[:, 0] / 0.01))


def test_forward_dynamics_rejects_indefinite_mass_matrix():
    robot, chi = pendulum()
    chi[[3, 5, 10]] = [-1.0, -1.0, -0.5]
    with pytest.raises(InputError, match="positive definite"):
        dm.forward_dynamics(robot, chi, [0.1], [0.0], [0.0])


# ----------------------------------------------------------------------------- (b) simulator vs Pinocchio loop

@needs_pin
@pytest.mark.slow
def test_tx40_closed_loop_matches_pinocchio_loop(tx40, capsys):
    """5 s of TX40 closed-loop tracking at 5 kHz: dynid's compiled loop against a
    plain-Python loop on Pinocchio (same controller, ZOH and RK4 step)."""
    rng = np.random.default_rng(3)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.2, 5, rng)
    fs = tx40.controller.rate
    assert fs == 5000.0
    t = np.arange(int(5.0 * fs) + 1) / fs
    qr, qdr, _ = traj.evaluate(t)
    # DIDIM gain update: J_j = max_q M_jj(q) over the trajectory (eq. (27)), kd_scale = J / J_ap
    J = np.max(np.diagonal(dm.mass_matrix(tx40, chi, qr[::100]), axis1=1, axis2=2), axis=0)
    kds = J / tx40.controller.J_ap
    v_s = 0.05      # h*lambda ~ 0.9 at 5 kHz for these wrist frictions (0.01 needs substeps=3)

    res = simulate_closed_loop(tx40, chi, t, qr, qdr, kd_scale=kds, v_s=v_s)
    start = time.perf_counter()
    Q, QD, QDD, TAU = oracles.pin_closed_loop(tx40, chi, t, qr, qdr, qr[0], qdr[0],
                                              kd_scale=kds, v_s=v_s)
    t_pin = time.perf_counter() - start
    fine = simulate_closed_loop(tx40, chi, t, qr, qdr, kd_scale=kds, v_s=v_s, substeps=4)

    dq = np.max(np.abs(res.q - Q))
    assert dq <= 1e-6
    assert np.max(np.abs(res.tau - TAU)) <= 1e-6 * np.max(np.abs(TAU))
    assert np.max(np.abs(res.qdd - QDD)) <= 1e-6 * np.max(np.abs(QDD))
    e4q = np.max(np.abs(res.q - fine.q))
    e4qd = np.max(np.abs(res.qd - fine.qd))
    e4tau = np.max(np.abs(res.tau - fine.tau))
    assert e4q <= 1e-6
    assert res.stiffness < 2.5
    assert res.q.shape == (t.size, 6) and np.array_equal(res.t, t)
    # the loop tracks: bounded error, closed-loop stable
    assert np.max(np.abs(res.tracking_error)) < 1.0
    with capsys.disabled():
        print(f"\n[tx40 5 s @ 5 kHz] max|q_dynid - q_pin| = {dq:.2e} rad; "
              f"RK4 h=T vs T/4: |dq| {e4q:.2e} rad, |dqd| {e4qd:.2e} rad/s, |dtau| {e4tau:.2e} N m; "
              f"pinocchio loop {t_pin:.1f} s")


@needs_pin
def test_pid_feedforward_and_aba_path_match_pinocchio_loop():
    """Random 4-joint robot with a prismatic joint and no coupling (oracle plant:
    pin.aba with model.armature), PID with anti-windup and velocity feedforward."""
    rng = np.random.default_rng(5)
    robot = random_robot(rng, with_coupling=False)
    robot.controller = dataclasses.replace(robot.controller, kind="pid", ki=np.full(4, 2000.0))
    for jt in robot.joints:
        jt.tau_max = 30.0
    chi = oracles.random_standard_parameters(robot, rng)
    traj = random_fourier_trajectory(robot, 0.5, 3, rng)
    t = np.arange(1001) / robot.controller.rate
    qr, qdr, _ = traj.evaluate(t)
    q0 = qr[0] + 0.05                                 # start off the reference
    res = simulate_closed_loop(robot, chi, t, qr, qdr, q0=q0, feedforward=True, v_s=0.02,
                               substeps=2, kd_scale=[1.0, 2.0, 0.5, 1.5])
    Q, QD, QDD, TAU = oracles.pin_closed_loop(robot, chi, t, qr, qdr, q0, qdr[0], feedforward=True,
                                              v_s=0.02, substeps=2, kd_scale=[1.0, 2.0, 0.5, 1.5])
    assert np.max(np.abs(res.q - Q)) <= 1e-8
    assert np.max(np.abs(res.tau - TAU)) <= 1e-8 * np.max(np.abs(TAU))
    assert np.all(np.abs(res.tau) <= 30.0 + 1e-12)
    assert res.saturation.max() > 0                    # the torque saturates ...
    # ... and the anti-windup clamp of the integral engages (|I| = tau_max / (g Ki))
    Imax = 30.0 / (0.5 * np.array([1.0, 2.0, 0.5, 1.5]) * 2000.0)
    integ, clamped = np.zeros(4), 0
    for k in range(t.size):
        integ = np.clip(integ + (t[1] - t[0]) * (qr[k] - res.q[k]), -Imax, Imax)
        clamped += np.count_nonzero(np.abs(integ) >= Imax)
    assert clamped > 0


def test_kd_scale_restores_the_designed_loop():
    """A pure inertia J = 4 J_ap: with kd_scale = J / J_ap the step response is the
    designed critically damped one, 1 - (1 + wn t) exp(-wn t)."""
    robot, chi = pendulum()
    robot.gravity = np.zeros(3)
    chi[:] = 0.0
    chi[10] = 2.0                                   # Ia = 4 * J_ap
    t = np.arange(501) / robot.controller.rate       # 0.5 s at 1 kHz
    qr = np.full((t.size, 1), 0.1)
    res = simulate_closed_loop(robot, chi, t, qr, np.zeros_like(qr), q0=[0.0], qd0=[0.0],
                               kd_scale=4.0, v_s=0.0)
    wn = 30.0
    design = 0.1 * (1 - (1 + wn * t) * np.exp(-wn * t))
    assert np.max(np.abs(res.q[:, 0] - design)) < 0.01 * 0.1    # ZOH delay ~ wn T / 2
    unscaled = simulate_closed_loop(robot, chi, t, qr, np.zeros_like(qr), q0=[0.0], qd0=[0.0],
                                    v_s=0.0)
    assert np.max(np.abs(unscaled.q[:, 0] - design)) > 0.05 * 0.1


def test_feedforward_reduces_the_velocity_lag(tx40):
    """Without feedforward the PD lags by ~qdr / kp; with it, the friction-free robot
    lags by ~qddr / wn^2."""
    rng = np.random.default_rng(8)
    chi = tx40_like_parameters(tx40, rng)
    for j in range(6):
        chi[14 * j + 11:14 * j + 14] = 0.0               # Fv, Fc, Off
    chi[84:] = 0.0
    traj = random_fourier_trajectory(tx40, 0.5, 3, rng, margin=0.5)
    t = np.arange(2501) / tx40.controller.rate
    J = np.max(np.diagonal(dm.mass_matrix(tx40, chi, traj.evaluate(t[::50])[0]), axis1=1, axis2=2), 0)
    kw = dict(kd_scale=J / tx40.controller.J_ap, v_s=0.05)
    pd = simulate_closed_loop(tx40, chi, t, traj, **kw)
    ff = simulate_closed_loop(tx40, chi, t, traj, feedforward=True, **kw)
    lag = np.abs(pd.tracking_error).max(axis=0)
    err = np.abs(ff.tracking_error).max(axis=0)
    assert np.all(err < lag) and err.max() < 0.2 * lag.max()
    # what is left is the acceleration lag ~ qddr / wn^2
    assert err.max() < 2 * np.abs(ff.qdd).max() / 60.0 ** 2


def test_integration_error_against_finer_step(tx40, capsys):
    rng = np.random.default_rng(4)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.3, 4, rng)
    t = np.arange(5001) / tx40.controller.rate
    errs = {}
    for v_s, sub in ((0.05, 1), (0.01, 3)):
        a = simulate_closed_loop(tx40, chi, t, traj, v_s=v_s, substeps=sub)
        b = simulate_closed_loop(tx40, chi, t, traj, v_s=v_s, substeps=4 * sub)
        errs[(v_s, sub)] = np.max(np.abs(a.q - b.q))
        assert errs[(v_s, sub)] < 1e-6
    with capsys.disabled():
        print("\n[tx40 1 s @ 5 kHz] max|q(h) - q(h/4)|: "
              + ", ".join(f"v_s={k[0]}, substeps={k[1]}: {e:.1e} rad" for k, e in errs.items()))


def test_stiff_friction_warns(tx40):
    rng = np.random.default_rng(4)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.3, 4, rng)
    t = np.arange(51) / tx40.controller.rate
    with pytest.warns(RuntimeWarning, match="substeps >= "):
        res = simulate_closed_loop(tx40, chi, t, traj, v_s=0.01)
    assert res.stiffness > 2.5 and res.notes


# ----------------------------------------------------------------------------- (c) closed forms

def test_pendulum_small_angle_period():
    m, l, Ia = 2.0, 0.5, 0.05
    robot, chi = pendulum(m, l, Ia)
    theta0 = 0.01
    dt = 1e-3
    t = np.arange(0, 3.0 + dt / 2, dt)
    res = simulate_torque(robot, chi, t, np.zeros((t.size, 1)), [-np.pi / 2 + theta0], [0.0],
                          v_s=0.0)
    x = res.q[:, 0] + np.pi / 2
    # upward zero crossings, linearly interpolated
    k = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    tc = t[k] - x[k] * dt / (x[k + 1] - x[k])
    period = np.mean(np.diff(tc))
    J = m * l * l + Ia
    closed = 2 * np.pi * np.sqrt(J / (m * 9.81 * l)) * (1 + theta0 ** 2 / 16)
    assert abs(period - closed) / closed < 1e-5


def test_pendulum_energy_is_conserved_in_open_loop():
    m, l, Ia = 2.0, 0.5, 0.05
    robot, chi = pendulum(m, l, Ia)
    J = m * l * l + Ia
    t = np.arange(2001) * 1e-3                        # 2 s, h = 1 ms
    res = simulate_torque(robot, chi, t, np.zeros((t.size, 1)), [0.3], [1.0], v_s=0.0)
    E = 0.5 * J * res.qd[:, 0] ** 2 + m * 9.81 * l * np.sin(res.q[:, 0])
    assert np.max(np.abs(E - E[0])) / abs(E[0]) < 1e-8
    # qdd reported at the samples is the model's acceleration
    assert np.allclose(res.qdd[:, 0], -m * 9.81 * l * np.cos(res.q[:, 0]) / J, atol=1e-12)


# ----------------------------------------------------------------------------- interfaces

def test_result_frame_and_reference_resampling(tx40):
    rng = np.random.default_rng(2)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.5, 2, rng)
    t_ref = np.arange(101) / 1000.0                   # reference at 1 kHz, controller at 5 kHz
    qr, qdr, _ = traj.evaluate(t_ref)
    res = simulate_closed_loop(tx40, chi, t_ref, qr, qdr, v_s=0.05)
    assert isinstance(res, SimulationResult)
    assert res.t.size == 501 and np.allclose(np.diff(res.t), 2e-4)
    assert any("interpolated" in s for s in res.notes)
    assert np.allclose(res.qr[::5], qr)
    frame = res.to_frame()
    assert list(frame.columns[:2]) == ["t", "q1"]
    assert {"qr6", "qd3", "qdd1", "tau6"} <= set(frame.columns)
    assert len(frame) == 501
    # a sampled reference without qdr: its finite difference gives the initial velocity
    t = np.arange(201) / 5000.0
    res2 = simulate_closed_loop(tx40, chi, t, traj.evaluate(t)[0], v_s=0.05)
    assert np.allclose(res2.qd[0], traj.evaluate(0.0)[1], atol=1e-5)
    assert any("finite difference" in s for s in res2.notes)


def test_to_experiment(tx40):
    pytest.importorskip("dynid.analysis.data.experiment")
    rng = np.random.default_rng(2)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.5, 2, rng)
    res = simulate_closed_loop(tx40, chi, np.arange(101) / 5000.0, traj, v_s=0.05)
    exp = experiment_from_simulation(res)
    assert exp.n_joints == 6 and exp.n_samples == 101 and np.allclose(exp.fs, 5000.0)


# ----------------------------------------------------------------------------- (e) bad input

def test_bad_input(tx40):
    rng = np.random.default_rng(0)
    chi = oracles.random_standard_parameters(tx40, rng)
    t = np.arange(11) / 5000.0
    qr = np.zeros((11, 6))
    with pytest.raises(InputError, match="standard parameters"):
        dm.inverse_dynamics(tx40, chi[:-1], qr, qr, qr)
    with pytest.raises(InputError, match="columns"):
        dm.mass_matrix(tx40, chi, np.zeros((3, 5)))
    with pytest.raises(InputError, match="shape"):
        dm.forward_dynamics(tx40, chi, np.zeros((3, 6)), np.zeros((4, 6)), np.zeros((3, 6)))
    with pytest.raises(InputError, match="non-finite"):
        dm.inverse_dynamics(tx40, chi, np.full(6, np.nan), np.zeros(6), np.zeros(6))
    no_ctrl = dataclasses.replace(tx40, controller=None)
    with pytest.raises(InputError, match="no controller"):
        simulate_closed_loop(no_ctrl, chi, t, qr)
    with pytest.raises(InputError, match=r"expected \(11, 6\)"):
        simulate_closed_loop(tx40, chi, t, qr[:, :5])
    with pytest.raises(InputError, match="qdr"):
        simulate_closed_loop(tx40, chi, t, qr, qr[:10])
    with pytest.raises(InputError, match="increasing"):
        simulate_closed_loop(tx40, chi, t[::-1], qr)
    with pytest.raises(InputError, match="substeps"):
        simulate_closed_loop(tx40, chi, t, qr, substeps=0)
    with pytest.raises(InputError, match="v_s"):
        simulate_closed_loop(tx40, chi, t, qr, v_s=-1.0)
    with pytest.raises(InputError, match="kd_scale"):
        simulate_closed_loop(tx40, chi, t, qr, kd_scale=[1, 1, 1, 1, 1, -1])
    with pytest.raises(InputError, match="kd_scale"):
        simulate_closed_loop(tx40, chi, t, qr, kd_scale=[1, 1])
    with pytest.raises(InputError, match="q0"):
        simulate_closed_loop(tx40, chi, t, qr, q0=np.zeros(4))
    with pytest.raises(InputError, match="rate"):
        simulate_closed_loop(tx40, chi, t, qr, rate=0.0)
    with pytest.raises(InputError, match="tau"):
        simulate_torque(tx40, chi, t, np.zeros((10, 6)), np.zeros(6), np.zeros(6))
    with pytest.raises(InputError, match="positive definite"):
        bad = chi.copy()
        bad[10] = -100.0
        simulate_torque(tx40, bad, t, np.zeros((11, 6)), np.zeros(6), np.zeros(6))


def test_progress_chunks_give_exactly_the_single_call_result():
    """Reporting progress splits the compiled loop into chunks; the state (q, qd, PID
    integral) carries over, so the result is bit-identical to one call."""
    from dynid.dynamics.robot_file import load_robot
    from dynid.dynamics.simulation import simulate_closed_loop
    from dynid.dynamics.trajectories import random_fourier_trajectory
    robot = load_robot("planar2")
    chi = robot.standard_vector({k: v for k, v in robot.apriori.items() if k in robot.standard_names})
    traj = random_fourier_trajectory(robot, 0.2, 5, np.random.default_rng(3))
    pid = dataclasses.replace(robot.controller, kind="pid", ki=np.array([20.0, 30.0]))
    t = np.arange(20_000) / robot.controller.rate
    one = simulate_closed_loop(robot, chi, t, traj, feedforward=True, controller=pid)
    seen = []
    chunked = simulate_closed_loop(robot, chi, t, traj, feedforward=True, controller=pid,
                                   progress=seen.append)
    assert len(seen) == 10 and seen[-1] == 1.0 and np.all(np.diff(seen) > 0)
    for a, b in ((one.q, chunked.q), (one.qd, chunked.qd), (one.qdd, chunked.qdd), (one.tau, chunked.tau)):
        assert np.array_equal(a, b)


def _zoh_closed_loop_solve_ivp(robot, chi, t, qr, qdr, v_s):
    """The PD loop of the simulator (no feedforward, no saturation) with the plant integrated by
    scipy's DOP853 at tight tolerances over each held-torque period: the reference solution."""
    from scipy.integrate import solve_ivp

    model = dm.model_arrays(robot, chi).kernel_args()
    c = robot.controller
    kp = c.wn / (2 * c.zeta)
    Kv = c.J_ap / c.g_ap * 2 * c.zeta * c.wn
    n = robot.n_joints
    acc = np.empty((1, n))

    def rhs(_, y, tau):
        dm._forward_dynamics_batch(model, y[None, :n], y[None, n:], tau[None], v_s, acc)
        return np.concatenate([y[n:], acc[0]])

    y = np.concatenate([qr[0], qdr[0]])
    Q = np.empty((t.size, n))
    for k in range(t.size):
        Q[k] = y[:n]
        if k + 1 < t.size:
            tau = robot.drive_gains * Kv * (kp * (qr[k] - y[:n]) - y[n:])
            y = solve_ivp(rhs, (t[k], t[k + 1]), y, method="DOP853", rtol=1e-10, atol=1e-12,
                          args=(tau,)).y[:, -1]
    return Q


def _reversal_case(tx40):
    """TX40 tracking sines whose every joint reverses within 40 ms, at DIDIM's v_s = 0.00625 and
    the substeps that keep h lambda <= 1.5."""
    chi = tx40_like_parameters(tx40, np.random.default_rng(4))
    rate, v_s = tx40.controller.rate, 0.00625
    t = np.arange(201) / rate
    phase = np.linspace(1.2, 1.5, 6)                          # reference reversals at 3-15 ms
    A = np.array([0.2, 0.2, 0.3, 0.5, 0.5, 0.8])
    w = 2 * np.pi * 4.0
    qr, qdr = A * np.sin(w * t[:, None] + phase), A * w * np.cos(w * t[:, None] + phase)
    m = int(np.ceil(friction_stiffness(tx40, chi, qr[0], 1 / rate, v_s) / 1.5))
    assert m >= 4                                             # the substeps matter here
    return chi, t, qr, qdr, v_s, m


def _check_adaptive_against(tx40, chi, t, qr, qdr, v_s, m, ref, what, capsys):
    kw = dict(v_s=v_s, saturate=False)
    uniform = simulate_closed_loop(tx40, chi, t, qr, qdr, substeps=m, **kw)
    adaptive = simulate_closed_loop(tx40, chi, t, qr, qdr, substeps=m, adaptive=True, **kw)
    with pytest.warns(RuntimeWarning, match="substeps >= "):
        single = simulate_closed_loop(tx40, chi, t, qr, qdr, substeps=1, **kw)
    assert np.all((np.diff(np.sign(uniform.qd), axis=0) != 0).any(axis=0))   # every joint reverses
    err = {name: np.max(np.abs(r.q - ref)) for name, r in
           (("uniform", uniform), ("adaptive", adaptive), ("single", single))}
    assert err["uniform"] < 1e-8                              # the reference resolves the reversals
    assert err["adaptive"] <= 2 * err["uniform"] + 1e-10, err
    assert err["single"] > 20 * err["adaptive"], err
    assert adaptive.adaptive and not uniform.adaptive and np.isnan(uniform.refined)
    assert 0 < adaptive.refined < 0.5                        # the saving: most periods take 1 step
    assert adaptive.stiffness == uniform.stiffness            # the same warning logic
    with capsys.disabled():
        print(f"\n[tx40 40 ms @ 5 kHz, v_s {v_s}, {m} substeps] max|q - q_{what}|: "
              + ", ".join(f"{k} {e:.1e} rad" for k, e in err.items())
              + f"; adaptive refined {adaptive.refined:.0%} of the periods")


def test_adaptive_substeps_error_against_finer_step(tx40, capsys):
    """Adaptive substeps (all of them only near velocity reversals) against the uniform RK4 with
    4x the substeps: the error is of the order of the uniform substeps' (<= 2x + 1e-10 rad),
    while one step per period everywhere is far off (the friction is stiff at the reversals)."""
    chi, t, qr, qdr, v_s, m = _reversal_case(tx40)
    ref = simulate_closed_loop(tx40, chi, t, qr, qdr, substeps=4 * m, v_s=v_s, saturate=False).q
    _check_adaptive_against(tx40, chi, t, qr, qdr, v_s, m, ref, "4x finer", capsys)


@pytest.mark.slow
def test_adaptive_substeps_error_against_solve_ivp(tx40, capsys):
    """The same against a reference solution of the zero-order-hold loop that shares no
    integrator with the simulator (scipy solve_ivp, DOP853, rtol 1e-10)."""
    chi, t, qr, qdr, v_s, m = _reversal_case(tx40)
    ref = _zoh_closed_loop_solve_ivp(tx40, chi, t, qr, qdr, v_s)
    _check_adaptive_against(tx40, chi, t, qr, qdr, v_s, m, ref, "solve_ivp", capsys)


def test_adaptive_is_opt_in_and_off_when_it_cannot_help(tx40):
    """Default: every period gets all substeps (bit-identical to before); with one substep or a
    viscous friction that makes a whole period's step stiff, adaptive changes nothing."""
    rng = np.random.default_rng(4)
    chi = tx40_like_parameters(tx40, rng)
    traj = random_fourier_trajectory(tx40, 0.3, 4, rng)
    t = np.arange(101) / tx40.controller.rate
    a = simulate_closed_loop(tx40, chi, t, traj, v_s=0.05, substeps=1)
    b = simulate_closed_loop(tx40, chi, t, traj, v_s=0.05, substeps=1, adaptive=True)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)
    chi[11] = 1e4                                             # Fv1: T lambda ~ 1.5 > 0.5
    c = simulate_closed_loop(tx40, chi, t, traj, v_s=0.05, substeps=2)
    d = simulate_closed_loop(tx40, chi, t, traj, v_s=0.05, substeps=2, adaptive=True)
    assert np.array_equal(c.q, d.q) and not d.adaptive and "adaptive substeps off" in d.notes[-1]
