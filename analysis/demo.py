"""The demo: a simulated Stäubli TX40 identified by IDIM, as in section 5 of the DIDIM paper.

The simulated robot's essential parameters are the values of Table 2 of
Gautier, Janot, Vandanjon (2010); the rest of its base parameters are zero
except Ia6 (see `dynid.analysis.data.synthetic`). It tracks a random Fourier-series
reference under the PD controller of `tx40.toml` at 5 kHz; the recorded q
and tau carry white noise. A second, different reference serves for
validation.
"""
from __future__ import annotations

import numpy as np

from dynid.analysis.data.synthetic import simulate_experiment, tx40_true_parameters
from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY, identify_idim
from dynid.analysis.statistics.validation import validate
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.dynamics.trajectories import random_fourier_trajectory

# Sensor noise of the demo (standard deviations at 5 kHz): an encoder-like
# position noise, and a torque noise of about 2-3 % of each joint's torque range.
Q_NOISE = 4e-5                                   # rad
TAU_NOISE = [2.0, 2.0, 0.7, 0.25, 0.4, 0.25]    # N m
F0 = 0.1                                         # Hz, fundamental of the references
HARMONICS = 10
VALIDATION_DURATION = 10.0


def demo_data(seed=1, duration=20.0):
    """(robot, bp, beta_true, identification Experiment, validation Experiment)."""
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    beta, chi = tx40_true_parameters(robot, bp)
    rng = np.random.default_rng(seed)
    traj_id = random_fourier_trajectory(robot, F0, HARMONICS, rng)
    traj_val = random_fourier_trajectory(robot, F0, HARMONICS, rng)
    # fast: the simulator's CRBA and adaptive substeps (DIDIM's), a third of the CPU of the
    # uniform steps, whose states they match to 1.5e-10 rad (the noise: 4e-5 rad)
    ident = simulate_experiment(robot, chi, traj_id, duration, rng=rng, q_noise=Q_NOISE, fast=True,
                                tau_noise=TAU_NOISE, name=f"simulated TX40, identification (seed {seed})")
    valid = simulate_experiment(robot, chi, traj_val, VALIDATION_DURATION, rng=rng, q_noise=Q_NOISE,
                                fast=True, tau_noise=TAU_NOISE,
                                name=f"simulated TX40, validation (seed {seed})")
    return robot, bp, beta, ident, valid


def run_demo(seed=1, duration=20.0, say=print, uncertainty=DEFAULT_UNCERTAINTY):
    robot, bp, beta, ident, valid = demo_data(seed, duration)
    say(f"simulated the TX40: {duration:g} s for identification, {VALIDATION_DURATION:g} s for validation")
    result = identify_idim(ident, robot, bp=bp, uncertainty=uncertainty)
    result.truth = dict(zip(bp.names, beta))
    validation = validate(result, valid, robot)
    return result, robot, ident, validation, valid
