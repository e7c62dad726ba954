"""Finite Fourier series trajectories (Bona & Curatella 2005, eqs. (17)-(19))."""
import numpy as np
import pytest

from dynid.dynamics.robot import Joint, Robot
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import FourierTrajectory, random_fourier_trajectory
from dynid.errors import InputError


def test_closed_form_of_one_harmonic():
    f0 = 0.25
    w = 2 * np.pi * f0
    traj = FourierTrajectory(f0, [[0.6, 0.0]], [[0.2, 0.0]], [0.1])
    t = np.linspace(0, 7, 101)
    q, qd, qdd = traj.evaluate(t)
    assert np.allclose(q[:, 0], 0.6 / w * np.sin(w * t) - 0.2 / w * np.cos(w * t) + 0.1)
    assert np.allclose(qd[:, 0], 0.6 * np.cos(w * t) + 0.2 * np.sin(w * t))
    assert np.allclose(qdd[:, 0], -0.6 * w * np.sin(w * t) + 0.2 * w * np.cos(w * t))
    assert traj.period == 4.0 and traj.harmonics == 2 and traj.n_joints == 1


def test_analytic_derivatives_equal_finite_differences():
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(0.1, rng.normal(size=(3, 5)), rng.normal(size=(3, 5)), [0.1, -0.2, 0.3])
    t = np.linspace(0, 10, 57)
    h = 1e-5
    q, qd, qdd = traj.evaluate(t)
    qp, qdp, _ = traj.evaluate(t + h)
    qm, qdm, _ = traj.evaluate(t - h)
    assert np.max(np.abs((qp - qm) / (2 * h) - qd)) < 1e-7 * np.max(np.abs(qd))
    assert np.max(np.abs((qdp - qdm) / (2 * h) - qdd)) < 1e-7 * np.max(np.abs(qdd))
    # periodic, mean position q0
    assert np.allclose(traj.evaluate(t + traj.period)[0], q, atol=1e-12)
    tg = np.arange(1000) * traj.period / 1000
    assert np.allclose(traj.evaluate(tg)[0].mean(axis=0), traj.q0, atol=1e-12)
    # scalar time
    q1, qd1, qdd1 = traj.evaluate(2.5)
    assert q1.shape == (3,) and np.allclose(q1, traj.evaluate([2.5])[0][0])


@pytest.mark.parametrize("name", ["tx40", "planar2", "kuka_lwr4"])
def test_random_trajectory_respects_every_limit(name):
    robot = load_robot(name)
    q_min, q_max, qd_max, qdd_max, _ = robot.limits()
    for seed in range(3):
        margin = 0.9
        traj = random_fourier_trajectory(robot, 0.1, 6, np.random.default_rng(seed), margin=margin)
        # a grid denser than the one used for scaling, and offset from it
        t = 0.123 + np.linspace(0, 2 * traj.period, 60001)
        q, qd, qdd = traj.evaluate(t)
        mid = 0.5 * (q_min + q_max)
        half = 0.5 * (q_max - q_min)
        assert np.allclose(traj.q0, np.where(np.isfinite(mid), mid, 0.0))
        assert np.all(np.abs(q - mid) <= margin * half)
        assert np.all(q >= q_min) and np.all(q <= q_max)
        assert np.all(np.abs(qd) <= margin * qd_max)
        assert np.all(np.abs(qdd) <= margin * qdd_max)
        # and each joint uses its range: one of the three limits is reached
        use = np.max(np.stack([np.abs(q - mid).max(0) / (margin * half),
                               np.abs(qd).max(0) / (margin * qd_max),
                               np.abs(qdd).max(0) / (margin * qdd_max)]), axis=0)
        assert np.all(use > 0.999)


def test_random_trajectory_is_reproducible():
    robot = load_robot("tx40")
    a = random_fourier_trajectory(robot, 0.2, 4, 7)
    b = random_fourier_trajectory(robot, 0.2, 4, np.random.default_rng(7))
    assert np.array_equal(a.a, b.a) and np.array_equal(a.b, b.b)


def test_to_frame():
    traj = FourierTrajectory(0.5, np.ones((2, 3)), np.zeros((2, 3)), [0.0, 1.0])
    t = np.arange(5) * 0.01
    frame = traj.to_frame(t)
    assert list(frame.columns) == ["t", "qr1", "qr2", "qdr1", "qdr2", "qddr1", "qddr2"]
    assert np.allclose(frame["qr2"], traj.evaluate(t)[0][:, 1])
    assert list(traj.to_frame(t, derivatives=False).columns) == ["t", "qr1", "qr2"]
    ts, q, qd, qdd = traj.sample(100.0)
    assert ts.size == 201 and q.shape == (201, 2)


def test_bad_input():
    with pytest.raises(InputError, match="f0"):
        FourierTrajectory(0.0, np.ones((2, 3)), np.ones((2, 3)), [0, 0])
    with pytest.raises(InputError, match="shape"):
        FourierTrajectory(1.0, np.ones((2, 3)), np.ones((2, 2)), [0, 0])
    with pytest.raises(InputError, match="q0"):
        FourierTrajectory(1.0, np.ones((2, 3)), np.ones((2, 3)), [0, 0, 0])
    with pytest.raises(InputError, match="finite"):
        FourierTrajectory(1.0, np.full((1, 1), np.nan), np.ones((1, 1)), [0])
    robot = load_robot("tx40")
    with pytest.raises(InputError, match="n_harmonics"):
        random_fourier_trajectory(robot, 0.1, 0, 0)
    with pytest.raises(InputError, match="n_harmonics"):
        random_fourier_trajectory(robot, 0.1, 2.5, 0)
    with pytest.raises(InputError, match="margin"):
        random_fourier_trajectory(robot, 0.1, 3, 0, margin=1.5)
    with pytest.raises(InputError, match="rng"):
        random_fourier_trajectory(robot, 0.1, 3, "seed")
    free = Robot(name="free", joints=[Joint(name="j1")])
    with pytest.raises(InputError, match="no finite position"):
        random_fourier_trajectory(free, 0.1, 3, 0)
