"""Tests of simulated experiments (dynid.analysis.data.synthetic)."""

import warnings

import numpy as np

import dynid
from dynid.analysis.data.synthetic import simulate_experiment, tx40_true_parameters
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import random_fourier_trajectory


def test_fast_simulation_is_the_uniform_one_within_the_integrators_error():
    """`fast=True` (CRBA, adaptive substeps: the demo's) gives the uniform steps' states to the
    RK4 error level, with the same noise draws; the accuracy of the adaptive steps themselves is
    checked against finer steps in tests/dynamics/test_simulation.py."""
    robot = load_robot("tx40")
    _, chi = tx40_true_parameters(robot, base_parameters(robot))
    traj = random_fourier_trajectory(robot, 0.1, 10, np.random.default_rng(1))
    runs = {fast: simulate_experiment(robot, chi, traj, 2.0, rng=np.random.default_rng(3), q_noise=4e-5,
                                      tau_noise=0.5, fast=fast) for fast in (False, True)}
    slow, fast = runs[False], runs[True]
    dq = np.abs(fast.meta["true_q"] - slow.meta["true_q"]).max()
    assert 0 < dq < 1e-8                     # another integrator, the same trajectory
    np.testing.assert_allclose(fast.q - fast.meta["true_q"], slow.q - slow.meta["true_q"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(fast.tau - fast.meta["true_tau"], slow.tau - slow.meta["true_tau"], rtol=0,
                               atol=1e-12)


def test_simulated_recording_has_the_results_interface(tmp_path):
    """summary(), to_json() and to_csv(): the CSV is the recording `load_experiment` reads back."""
    import json

    import dynid
    sim = dynid.simulate("planar2", duration=2.0, seed=2)
    assert "planar2" in sim.summary() and str(sim) == sim.summary()
    assert json.loads(sim.to_json(tmp_path / "sim.json"))["seed"] == 2
    sim.to_csv(tmp_path / "sim.csv")
    back = dynid.load_experiment(tmp_path / "sim.csv", "planar2")
    np.testing.assert_allclose(back.q, sim.experiment.q, atol=1e-9)
    np.testing.assert_allclose(back.tau, sim.experiment.tau, rtol=1e-9, atol=1e-9)


def test_stiff_friction_gets_enough_substeps():
    """The LWR4+ with its controller at 200 Hz: the smoothed friction is stiff for 4 RK4 substeps
    (h*lambda ~ 3.1 > 2.5); the simulated recording takes more instead of warning."""
    import dataclasses
    lwr = dynid.load_robot("kuka_lwr4")
    slow = dataclasses.replace(lwr, controller=dataclasses.replace(lwr.controller, rate=200.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        rec = dynid.simulate(slow, 2.0, seed=1)
    assert not any("chatter" in n for n in rec.experiment.notices)
