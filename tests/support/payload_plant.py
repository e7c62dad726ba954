"""An independent TX40 plant carrying a payload (test/benchmark-time only, Pinocchio).

Like `tests.independent_plant` (which this builds on) it imports nothing from dynid: the
payload is a rigid body with a full inertia tensor appended to joint 6 of the Pinocchio model
(`appendBodyToJoint`), so the plant's torques include it through Pinocchio's own RNEA/ABA.

Truth convention: ten parameters `[XX, XY, XZ, YY, YZ, ZZ, MX, MY, MZ, M]` about the link-6
frame of the TX40's modified DH table (Table 1 of Gautier, Janot & Vandanjon 2010), inertia
about that frame's origin, `MX..MZ = M c`. FIGAROH's tx40_mdh_modified.urdf puts its joint-6
frame at the same origin turned by pi about z (x and y reversed; checked against the MDH chain
by forward kinematics), so the body is appended with that placement (`MDH_IN_URDF6`).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

try:
    from tests.support import independent_plant as ip
except ImportError:  # run as a script from the tests folder
    import independent_plant as ip


#: the MDH link-6 frame in the URDF's joint-6 frame: a half turn about z
MDH_IN_URDF6 = pin.SE3(np.diag([-1.0, -1.0, 1.0]), np.zeros(3))


def random_payload(rng, mass=(1.0, 5.0), offset=(0.02, 0.15)):
    """A random rigid payload: (params (10,) about the joint-6 frame, dict of its parts).

    Mass uniform in `mass` kg; centre of mass at a distance uniform in `offset` m from the
    flange origin (random direction, kept on the tool side, z > 0); a solid box of sides
    uniform in 0.04..0.2 m, turned by a random rotation: a full inertia tensor.
    """
    m = rng.uniform(*mass)
    d = rng.normal(size=3)
    d[2] = abs(d[2]) + 0.3
    c = d / np.linalg.norm(d) * rng.uniform(*offset)
    a, b, h = rng.uniform(0.04, 0.2, 3)
    Ic_p = m / 12.0 * np.diag([b * b + h * h, a * a + h * h, a * a + b * b])
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    Ic = Q @ Ic_p @ Q.T
    I_o = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    params = np.array([I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2], *(m * c), m])
    return params, dict(mass=m, com=c, inertia_com=Ic)


def add_payload(plant, params, joint=6):
    """A copy of `plant` (an `independent_plant.Plant`) with the payload appended to `joint`."""
    model = pin.Model(plant.model)
    model.appendBodyToJoint(joint, ip.inertia_from_khalil(params), MDH_IN_URDF6 if joint == 6 else pin.SE3.Identity())
    A = plant.A if plant.full_armature else np.diag(plant.A)
    return ip.Plant(model, A, plant.friction, plant.effects + plant.sensor_effects, plant.limits,
                    name=plant.name + "+payload")


def tx40_payload_plant(params=None, seed=None, **kw):
    """(plant without payload, plant with it, params): the URDF TX40 of `independent_plant.tx40_plant`."""
    base = ip.tx40_plant("urdf", **kw)
    if params is None:
        params, _ = random_payload(np.random.default_rng(seed))
    return base, add_payload(base, params), np.asarray(params, dtype=float)


#: the drive gains' loaded excitation (docs/payload.md): the wrist as `wrist_reference`'s default, the arm
#: wider (half its half range), faster (0.8 of its speed limit) and at 0.3 Hz instead of one period per
#: 10 s. Why: with the mass alone the wrist gains' scale comes from the payload's inertia and first
#: moments as the arm joints (whose gains its mass fixes) see them, and joint 1's from the payload's
#: inertial torque (gravity acts along axis 1): both need the arm accelerating (seed 2034, 2 x 10 s
#: loaded: 95 % half-widths of joints 1, 4, 5, 6 0.99, 1.36, 1.19, 1.55 % -> 0.22, 1.02, 1.01, 1.12 %;
#: 2 x 30 s: 0.56, 0.82, 0.78, 0.88 % -> 0.15, 0.64, 0.57, 0.66 %; benchmarks/payload_gains_excitation.py)
DRIVE_GAIN_EXCITATION = dict(arm_amplitude=0.5, qd_fraction=0.8, arm_f0=0.3)


def wrist_reference(limits, duration, rate, seed, *, wrist_amplitude=0.6, arm_amplitude=0.3,
                    qd_fraction=0.5, wrist_qd_fraction=0.7, wrist_f0=0.4, arm_f0=None, still_wrist=False, **kw):
    """A multisine with the wrist (joints 4-6) swept wider and faster than the arm
    (`wrist_amplitude` of the half range, fundamental `wrist_f0` Hz, peak speed
    `wrist_qd_fraction` of the limit; the arm `arm_amplitude`, `qd_fraction`, fundamental
    `arm_f0`, by default one period per 10 s); `still_wrist` holds joints 4-6 nearly still
    (0.5 % of the range: a bad recording)."""
    ref = ip.multisine_reference(limits, duration, rate, seed, amplitude=arm_amplitude,
                                 qd_fraction=qd_fraction, f0=arm_f0, **kw)
    wide = ip.multisine_reference(limits, duration, rate, seed + 10_000,
                                  amplitude=0.005 if still_wrist else wrist_amplitude,
                                  qd_fraction=wrist_qd_fraction, f0=wrist_f0, **kw)
    for a in ("q", "qd", "qdd"):
        getattr(ref, a)[:, 3:] = getattr(wide, a)[:, 3:]
    return ref


def record(plant, reference, seed, *, rate=1000.0, sensor=None, wn=None):
    """Closed-loop recording of `plant` on `reference` (controller at `rate` Hz)."""
    ctrl = ip.default_controller(plant, rate, wn=wn)
    return ip.simulate(plant, ctrl, reference, sensor=sensor, seed=seed)
