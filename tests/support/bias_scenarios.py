"""Simulated data for the closed-loop and errors-in-variables bias campaigns.

Shared by ``tests/analysis/estimators/test_projection.py``, ``tests/analysis/estimators/test_maximum_likelihood.py``
and ``benchmarks/bias_campaign.py``. The robot is a one-joint pendulum in a
vertical plane described by a dynid robot file, simulated by dynid's
closed-loop simulator (PD + velocity feedforward).

Closed-loop noise (:func:`closed_loop_run`). Two coloured noises enter the loop:

* a torque disturbance d acting on the joint. dynid's simulator has no
  disturbance input, but with its PD law ``u = Kv (kp (qr - q) - qd + qdr)``
  giving the simulator the reference ``qr + delta`` (velocity ``qdr +
  delta'``) makes the robot receive ``u + d`` with ``d = Kv (kp delta +
  delta')``, exactly; the recorded control is ``u = tau_sim - d``;
* position-sensor noise v that the controller sees: reference ``qr - v``
  (velocity ``qdr - v'``) means the controller acts on ``q + v``; the
  recorded position is ``q + v``.

Both are white Gaussian noise low-passed (zero phase) and scaled; d has most
of its power above the loop bandwidth, where the robot's acceleration responds
to it: that is what biases plain LS (the regressor's qdd is correlated with
the equation error -d).
"""
from __future__ import annotations

import os
import tempfile
from functools import cache, lru_cache

import numpy as np
from scipy import ndimage

from dynid.analysis.processing.signals import derivatives, lowpass_filtfilt
from dynid.dynamics.trajectories import FourierTrajectory

PENDULUM_TOML = """
name = "pendulum1"
description = "One revolute joint in a vertical plane (bias campaigns)"
gravity = [0.0, -9.81, 0.0]

[[joints]]
name = "joint"
sigma = 0
q_limits = [-3.1416, 3.1416]
qd_max = 12.0
qdd_max = 100.0
tau_max = 1000.0

[controller]
kind = "pd"
rate = 500.0
wn = [10.0]
zeta = [1.0]
J_ap = [1.0]

[apriori]
source = "illustrative: uniform 1 m rod of 2 kg, 0.05 kg m^2 rotor"
values = { ZZ1 = 0.6667, MX1 = 1.0, M1 = 2.0, Ia1 = 0.05, Fv1 = 0.5, Fc1 = 1.0 }
"""

F0 = 0.5            # Hz, fundamental of the excitation
HARMONICS = 5


@cache
def pendulum():
    """(robot, base parameters, true standard parameters, true base parameters)."""
    from dynid.analysis.data.synthetic import apriori_parameters
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot

    fd, path = tempfile.mkstemp(suffix=".toml", prefix="dynid-pendulum-")
    with os.fdopen(fd, "w") as fh:
        fh.write(PENDULUM_TOML)
    try:
        robot = load_robot(path)
    finally:
        os.unlink(path)
    bp = base_parameters(robot)
    chi = apriori_parameters(robot, bp)
    return robot, bp, chi, bp.from_standard(chi)


def excitation(seed=3):
    rng = np.random.default_rng(seed)
    return FourierTrajectory(F0, rng.normal(size=(1, HARMONICS)), rng.normal(size=(1, HARMONICS)), [0.3])


def _coloured(rng, N, fs, fc, std):
    x = lowpass_filtfilt(rng.normal(size=(N, 1)), fs, fc)
    return x * (std / x.std())


def dead_zone(qd, threshold=0.1, guard=25):
    """True where usable: |qd| >= threshold, widened by ``guard`` samples (as IDIM does)."""
    still = np.abs(qd) < threshold
    still = ndimage.binary_dilation(still, structure=np.ones((2 * guard + 1, 1), dtype=bool))
    return ~still


def closed_loop_run(seed, *, duration=8.0, fs=500.0, dist_std=6.0, dist_fc=15.0, q_noise=1e-3,
                    q_noise_fc=8.0, tau_noise=0.2, fc_position=20.0, edge=100):
    """One closed-loop recording with noise fed back; returns the IDIM system pieces.

    Returns dict with ``W`` (N, 1, b) from the measured positions (filtered at
    ``fc_position``, central differences), ``u`` (N, 1) recorded control,
    ``r`` (N, 1) reference, ``keep`` (N, 1) dead-zone mask, ``names``, ``beta``.
    """
    from dynid.dynamics.base_parameters import base_regressor
    from dynid.dynamics.simulation import simulate_closed_loop

    robot, bp, chi, beta = pendulum()
    c = robot.controller
    Kv = float(np.asarray(c.J_ap)[0]) * 2 * float(np.asarray(c.zeta)[0]) * float(np.asarray(c.wn)[0])
    kp = float(np.asarray(c.wn)[0]) / (2 * float(np.asarray(c.zeta)[0]))
    tr = excitation()
    t = np.arange(int(round(duration * fs))) / fs
    qr, qdr, _ = tr.evaluate(t)
    rng = np.random.default_rng(seed)
    v = _coloured(rng, t.size, fs, q_noise_fc, q_noise)
    vd = np.gradient(v, 1 / fs, axis=0)
    delta = lowpass_filtfilt(rng.normal(size=(t.size, 1)), fs, dist_fc)
    delta_d = np.gradient(delta, 1 / fs, axis=0)
    scale = dist_std / (Kv * (kp * delta + delta_d)).std()
    delta, delta_d = delta * scale, delta_d * scale
    d = Kv * (kp * delta + delta_d)
    sim = simulate_closed_loop(robot, chi, t, qr - v + delta, qdr - vd + delta_d, q0=qr[0], qd0=qdr[0],
                               rate=fs, feedforward=True, v_s=0.01, substeps=2)
    u = sim.tau - d
    # torque of an integrating sensor centred on the sample (see dynid.analysis.data.synthetic)
    u[1:] = 0.5 * (u[1:] + u[:-1])
    u = u + rng.normal(size=u.shape) * tau_noise
    der = derivatives(sim.q + v, fs, fc_position)
    sl = slice(edge, t.size - edge)
    W = base_regressor(robot, bp, der.q[sl], der.qd[sl], der.qdd[sl])
    return {"W": W, "u": u[sl], "r": qr[sl], "keep": dead_zone(der.qd[sl]), "names": list(bp.names),
            "beta": beta, "fs": fs}


@lru_cache(maxsize=4)
def periodic_motion(duration=4.0, fs=200.0, warmup=2.0):
    """Noise-free closed-loop motion in periodic steady state: (t, q_true, tau_true)."""
    from dynid.dynamics.simulation import simulate_closed_loop

    robot, bp, chi, beta = pendulum()
    tr = excitation()
    tt = np.arange(int(round((duration + warmup) * fs))) / fs
    qr, qdr, _ = tr.evaluate(tt)
    # the controller rate follows fs; a PD at 10 rad/s is slow enough for 200 Hz
    sim = simulate_closed_loop(robot, chi, tt, qr, qdr, q0=qr[0], qd0=qdr[0], rate=fs, feedforward=True,
                               v_s=0.01, substeps=4)
    skip = int(round(warmup * fs))
    tau = sim.tau.copy()
    tau[1:] = 0.5 * (tau[1:] + tau[:-1])
    t = tt[skip:] - tt[skip]
    return t, sim.q[skip:].copy(), tau[skip:].copy()
