"""A decoupled COMAU Smart-3 S2: the per-joint values of Bona & Curatella (2005), Tables 1-3.

Provenance: B. Bona, A. Curatella, "Closed-loop rigid model identification of
an industrial robot", IFAC 2005, section 3 (file
`/work/shared/papers/bona-curatella-2005-closed-loop-comau.txt`). The paper
estimated these values on the real robot; dynid's simulated robot uses them
as its *true* values, so that dynid's estimates can be checked against them.
Units: the paper gives units only in Table 3; Table 2 is taken as N m s/rad
(viscous) and N m (Coulomb), Table 1's `k` in N m; angles are stored in rad
(Table 1 prints degrees).

* Table 1 (gravity, eq. (23), joints 2 and 3): `k2 = -0.7823` N m,
  `qoff2 = 7.5 deg`; `k3 = 0.4097` N m, `qoff3 = 25 deg`.
* Table 2 (friction, eq. (2)): `Fv+`, `Fv-` (beta^{v+}, beta^{v-}),
  `Fc+`, `Fc-` (beta^{c+}, beta^{c-}), joints 1-6.
* Table 3 (eq. (21)): `ZZ` (Gamma^zz, the equivalent inertia M_i), joints 1-6,
  `MX`, `MY` (mx, my), joints 2-6.

Two set-ups. Tables 1 and 3 cannot describe the same gravity: Table 3's
first moments of joint 2 give a gravity torque of amplitude
`g0 |(MX2, MY2)| = 397` N m, Table 1 gives `|k2| = 0.78` N m. The simulated
robot therefore has the gravity of the *set-up* of each experiment:

* `"sweep"` (sections 3.2.1-3.2.2, constant-velocity and bang-bang
  experiments): joints 1, 4, 5, 6 with their axes parallel to gravity (no
  gravity torque, as the paper arranges), joints 2 and 3 with eq. (23) and
  Table 1;
* `"identification"` (sections 3.4-3.5, excitation and validation): gravity
  `g0 (MX cos q - MY sin q)` from Table 3 for joints 2-6 (axis horizontal),
  none for joint 1 (vertical axis, no first moments in Table 3).

Inertia and friction are the same in both.

Sensor noise and controller are dynid's choices (the paper gives neither):
`TORQUE_NOISE`, `POSITION_NOISE`, `CONTROL_BANDWIDTH_HZ`,
sampling at 1 kHz as in section 3.3.
"""
from __future__ import annotations

import math

import numpy as np

from .joint_model import G0, JointModel, JointPID

__all__ = ["N_JOINTS", "TABLE1", "TABLE2", "TABLE3", "GRAVITY_JOINTS", "FIRST_MOMENT_JOINTS",
           "true_model", "true_values", "controller", "TORQUE_NOISE", "POSITION_NOISE",
           "CONTROL_BANDWIDTH_HZ", "VELOCITY_FILTER_HZ", "RATE", "SETUPS"]

N_JOINTS = 6
RATE = 1000.0                     # Hz, section 3.3
SETUPS = ("sweep", "identification")

#: Table 1: joint -> (k [N m], q_off [rad]).
TABLE1 = {2: (-0.7823, math.radians(7.5)), 3: (0.4097, math.radians(25.0))}
GRAVITY_JOINTS = tuple(TABLE1)

#: Table 2: joint -> (beta^{v+}, beta^{v-}, beta^{c+}, beta^{c-}).
TABLE2 = {
    1: (31.8757, 26.0000, 16.1376, 15.0676),
    2: (36.6197, 73.0530, 65.4187, 45.9598),
    3: (10.6964, 11.5955, 13.3809, 11.3347),
    4: (3.0686, 3.1806, 2.0526, 1.9685),
    5: (3.5672, 3.2386, 1.7545, 1.7161),
    6: (1.8245, 1.9985, 2.4545, 2.4161),
}

#: Table 3: joint -> (Gamma^zz [kg m^2], mx [kg m], my [kg m]); joint 1 has no first moments.
TABLE3 = {
    1: (28.7822, None, None),
    2: (64.1881, 39.9920, 6.0617),
    3: (7.4838, 2.8006, -5.6097),
    4: (0.2844, -0.0257, 0.0063),
    5: (0.3541, -0.0518, 0.1428),
    6: (0.4601, 0.0313, -0.0194),
}
FIRST_MOMENT_JOINTS = tuple(j for j, v in TABLE3.items() if v[1] is not None)

#: Torque-log noise per joint [N m] (white, Gaussian): about 1-3 % of each joint's torque range.
TORQUE_NOISE = np.array([1.0, 3.0, 0.5, 0.05, 0.05, 0.05])
#: Encoder noise [rad]: a 20-bit encoder's quantisation is 6e-6 rad.
POSITION_NOISE = 2e-6
#: Closed-loop bandwidth of the PID (triple pole), below the 3 Hz resonance the paper quotes.
CONTROL_BANDWIDTH_HZ = 2.5
#: Low-pass of the controller's differenced-position velocity.
VELOCITY_FILTER_HZ = 50.0


def _column(table, k, n=N_JOINTS):
    return np.array([0.0 if table.get(j) is None or table[j][k] is None else table[j][k]
                     for j in range(1, n + 1)])


def true_model(setup="identification") -> JointModel:
    """The simulated robot's `JointModel` in `setup` ("sweep" or "identification")."""
    fr = [_column(TABLE2, k) for k in range(4)]
    inertia = _column(TABLE3, 0)
    if setup == "sweep":
        k, qoff = _column(TABLE1, 0), _column(TABLE1, 1)
        gs, gc = JointModel.gravity_from_sinusoid(k, qoff)
    elif setup == "identification":
        gs, gc = JointModel.gravity_from_first_moments(_column(TABLE3, 1), _column(TABLE3, 2), G0)
    else:
        raise ValueError(f"setup must be one of {SETUPS}, got {setup!r}")
    return JointModel(inertia, fr[0], fr[1], fr[2], fr[3], gs, gc,
                      name=f"COMAU Smart-3 S2, decoupled (Bona & Curatella 2005), {setup} set-up")


def true_values() -> dict:
    """Parameter name -> true value, with dynid's names (`k2`, `qoff2` [rad], `Fv+1` ...,
    `ZZ1`, `MX2`, `MY2`)."""
    out = {}
    for j, (k, qoff) in TABLE1.items():
        out[f"k{j}"], out[f"qoff{j}"] = k, qoff
    for j, row in TABLE2.items():
        for sym, v in zip(("Fv+", "Fv-", "Fc+", "Fc-"), row):
            out[f"{sym}{j}"] = v
    for j, (zz, mx, my) in TABLE3.items():
        out[f"ZZ{j}"] = zz
        if mx is not None:
            out[f"MX{j}"], out[f"MY{j}"] = mx, my
    return out


def controller(bandwidth_hz=CONTROL_BANDWIDTH_HZ, velocity_filter_hz=VELOCITY_FILTER_HZ) -> JointPID:
    """The robot's joint PID (gains from the true inertia: the controller is part of the robot)."""
    return JointPID.triple_pole(_column(TABLE3, 0), bandwidth_hz, velocity_filter_hz)
