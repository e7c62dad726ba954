"""Asymmetric friction of the full robot (Bona & Curatella eq. (2)) from the symmetric model + |qd|."""
import dataclasses

import numpy as np
import pytest

from dynid.analysis.data.synthetic import apriori_parameters, simulate_experiment
from dynid.analysis.diagnosis.asymmetric_friction import asymmetric_friction
from dynid.analysis.estimators.idim import identify_idim
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import random_fourier_trajectory
from dynid.errors import InputError

# Added to the logged torque: Fv+ = Fv + dFv, Fv- = Fv - dFv, Fc+ = Fc + dFc, Fc- = Fc - dFc
D_FV = np.array([0.2, -0.1])
D_FC = np.array([0.4, 0.15])


@pytest.fixture(scope="module")
def asymmetric_run():
    robot = load_robot("planar2")
    bp = base_parameters(robot)
    chi = apriori_parameters(robot, bp)
    rng = np.random.default_rng(2)
    traj = random_fourier_trajectory(robot, 0.1, 8, rng)
    exp = simulate_experiment(robot, chi, traj, 30.0, rng=rng, q_noise=1e-6, tau_noise=0.05)
    # the unmodelled friction, from the velocity of the (nearly noise-free) measured motion
    qd = np.gradient(exp.q, exp.t, axis=0)
    exp = dataclasses.replace(exp, tau=exp.tau + D_FV * np.abs(qd) + D_FC * np.abs(np.sign(qd)))
    fv = np.array([chi[robot.standard_names.index(f"Fv{j}")] for j in (1, 2)])
    fc = np.array([chi[robot.standard_names.index(f"Fc{j}")] for j in (1, 2)])
    truth = np.column_stack([fv + D_FV, fv - D_FV, fc + D_FC, fc - D_FC])
    res = identify_idim(exp, robot)
    return robot, exp, res, truth


def test_asymmetric_coefficients_are_recovered_with_honest_sigma(asymmetric_run):
    robot, exp, res, truth = asymmetric_run
    a = asymmetric_friction(exp, robot, res)
    print("\n" + a.summary())
    z = (a.values - truth) / a.sigma
    assert np.all(np.abs(z) < 4), z
    assert np.all(np.abs(a.values - truth) < 0.03 * np.abs(truth)), a.values - truth
    # the symmetric model cannot express it: the extra |qd| column lowers the error
    assert a.fit.rel_error < 0.9 * a.rel_error_before
    doc = a.to_dict()
    assert doc["joints"][0]["Fv+"]["value"] == pytest.approx(a.values[0, 0])
    frame = a.to_frame()
    assert list(frame.index[:4]) == ["Fv+1", "Fv-1", "Fc+1", "Fc-1"]
    assert frame.loc["Fv+1", "value"] == pytest.approx(a.values[0, 0])
    assert frame.loc["Fv+1", "std"] == pytest.approx(a.sigma[0, 0])
    assert list(frame["unit"][:4]) == ["N m s/rad", "N m s/rad", "N m", "N m"]


def test_symmetric_friction_gives_equal_coefficients(asymmetric_run):
    robot = asymmetric_run[0]
    bp = base_parameters(robot)
    chi = apriori_parameters(robot, bp)
    rng = np.random.default_rng(5)
    traj = random_fourier_trajectory(robot, 0.1, 8, rng)
    sym = simulate_experiment(robot, chi, traj, 20.0, rng=rng, q_noise=1e-5, tau_noise=0.05)
    a = asymmetric_friction(sym, robot, identify_idim(sym, robot))
    dv, dc = a.values[:, 0] - a.values[:, 1], a.values[:, 2] - a.values[:, 3]
    sv = np.hypot(a.sigma[:, 0], a.sigma[:, 1])
    sc = np.hypot(a.sigma[:, 2], a.sigma[:, 3])
    assert np.all(np.abs(dv) < 4 * sv) and np.all(np.abs(dc) < 4 * sc)


def test_bad_joint_numbers_are_refused(asymmetric_run):
    robot, exp, res, _ = asymmetric_run
    with pytest.raises(InputError, match=r"joint numbers 1\.\.2"):
        asymmetric_friction(exp, robot, res, joints=[3])


def test_negative_friction_on_a_real_arm_is_flagged():
    """LWR4+ recording 1: Fc+7 = -0.26 N m (27 σ) and Fv+2 = -4.06 N m s/rad were printed as they
    were, without a word and with σ of an unnamed kind."""
    from pathlib import Path

    from dynid.analysis.data.experiment import load_experiment
    data = Path(__file__).resolve().parents[3] / "examples" / "kuka_lwr4" / "recording_1.toml"
    robot = load_robot("kuka_lwr4")
    exp = load_experiment(data, robot)
    res = asymmetric_friction(exp, robot, identify_idim(exp, robot))
    impossible = [n for n in res.notices if n.startswith("physically impossible")]
    assert impossible and "Fc+7 = -0.2598 N m" in impossible[0]
    assert any(n.startswith("σ: eq. (14) of the essential model") for n in res.notices)


def test_the_coefficients_take_the_identifications_covariance(asymmetric_run):
    """With the identification's bootstrap (dynid identify's default) the coefficients' σ are the
    bootstrap's too, and say so; the values are the same WLS (they were eq. (14)'s whatever the run's)."""
    robot, exp, res, _ = asymmetric_run
    classic = asymmetric_friction(exp, robot, identify_idim(exp, robot))
    boot = asymmetric_friction(exp, robot, identify_idim(exp, robot, uncertainty="bootstrap"))
    assert np.allclose(boot.values, classic.values, rtol=1e-10, atol=1e-12)
    assert not np.allclose(boot.sigma, classic.sigma)
    assert any(n.startswith("σ: circular block bootstrap") for n in boot.notices)
