"""The drive gains' excitation: the arm must accelerate in the loaded recordings (issue 28, the 1 % bar).

With the mass alone, joint 1's gain (gravity acts along its axis) and the wrist gains (a payload
near the wrist centre) take their scale from the payload's torque as the arm joints see it, so an
arm moving slowly leaves them weak whatever the wrist does (drive_gains module doc, docs/payload.md).
Seed 2034 of benchmarks/payload.py (a development seed): a 1.2 kg payload 28 mm from the flange.
"""
import dataclasses

import numpy as np
import pytest

import dynid
from dynid.analysis.data.experiment import Experiment
from dynid.analysis.estimators.drive_gains import identify_drive_gains


@pytest.mark.slow
def test_an_accelerating_arm_fixes_joint_1_and_the_wrist_gains():
    pytest.importorskip("pinocchio")
    from tests.support import payload_plant as pp
    seed, rate, seconds = 2034, 2000.0, 6.0
    robot = dataclasses.replace(dynid.load_robot("tx40"), couplings=[])
    params, _ = pp.random_payload(np.random.default_rng(seed))
    base, loaded, _ = pp.tx40_payload_plant(params)
    kt = np.random.default_rng(seed + 7).uniform(0.9, 1.1, 6)

    def one(plant, s, **kw):
        rec = pp.record(plant, pp.wrist_reference(plant.limits, seconds, rate, s, **kw), s, rate=rate)
        return Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"] / kt, fs=rate, source=str(s))
    u = one(base, 1)
    half = {}
    for name, kw in (("slow arm", {}), ("drive-gain excitation", pp.DRIVE_GAIN_EXCITATION)):
        r = identify_drive_gains(u, [one(loaded, 2, **kw), one(loaded, 3, **kw)], robot, mass=params[9], zoh=True)
        half[name] = 1.96 * r.factor_std / r.factor
    # joint 1 sees the payload only through its inertial torque: several times narrower
    assert half["drive-gain excitation"][0] < 0.5 * half["slow arm"][0]
    # the wrist gains: narrower too (measured 0.75-0.85 x on 2 x 10 s). Whether the intervals cover is the
    # benchmark's question (20 seeds x 6 gains): on recordings this short one gain can sit near 3 sigma
    # (here joint 4 of the drive-gain excitation, z -3.2; docs/payload.md)
    assert np.all(half["drive-gain excitation"][3:] < half["slow arm"][3:])
