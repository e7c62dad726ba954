"""DIDIM when the controller gains are not known: the gains identified from (qr, q, tau) on
closed-loop data of an independent plant (Pinocchio, its own integrator, PID and friction law,
gains unknown to dynid), then DIDIM with them, against IDIM on the same data."""
import dataclasses

import numpy as np
import pytest

import dynid
from dynid.analysis.data.experiment import Experiment
from dynid.analysis.estimators.controller_gains import identify_gains
from dynid.errors import InputError

ip = pytest.importorskip("independent_plant")


@pytest.fixture(scope="module")
def plant_run():
    plant = ip.tx40_plant("table2", coupled_wrist=True)
    # ten harmonics: with five, DIDIM from the identified gains diverged (the estimate of a step
    # could not be simulated) on this plant; the gains themselves were as good
    rec = ip.run(plant, duration=8.0, rate=5000.0, seed=3, sensor=ip.Sensor(q_noise=2e-5, tau_noise=0.2),
                 n_harmonics=10)
    robot = dynid.load_robot("tx40")
    # the structure is known (a PID with velocity feed-forward); the gains are not
    robot.controller = dataclasses.replace(robot.controller, kind="pid", ki=np.zeros(6))
    exp = Experiment(t=rec["t"], q=rec["q"], qr=rec["qr"], tau=rec["tau"], fs=5000.0,
                     source="independent plant", name="independent plant")
    return rec, robot, exp


def test_gains_are_recovered_from_the_control_law(plant_run):
    rec, robot, exp = plant_run
    g = identify_gains(exp, robot)
    assert g.feedforward and g.integral
    # Every gain within 2 % or 2.5 of its own sigma. Kp and Ki are within 2 % on every joint.
    # Kd of joints 1-2 (large inertias, small velocity errors against 2e-5 rad of encoder noise
    # differentiated) has a sigma of 1.5-2.2 %: measured here +1.4 % and +2.1 %; on seeds 4-8
    # Kd1 +4.4 (2.1 sigma), -1.0, +0.5, +0.5, +1.3 % and Kd2 -0.7, +0.4, +0.1, +1.8, 0.0 %
    # The 2 % is not met for Kd1-2 on every seed: their sigma is that large on 8 s of data.
    for kind in ("Kp", "Kd", "Ki"):
        err = g.gain(kind) / np.asarray(rec["gains"][kind]) - 1
        rel = np.array([g.rel_std[f"{kind}{j + 1}"] for j in range(6)]) / 100
        print(kind, "relative error", np.round(err, 4), "sigma", np.round(rel, 4))
        assert np.all(np.abs(err) < np.maximum(0.02, 2.5 * rel)), (kind, err, rel)
        if kind != "Kd":
            assert np.all(np.abs(err) < 0.02), (kind, err)
    # the plain least squares, biased by the encoder noise in the regressors
    plain = identify_gains(exp, robot, noise_q=0.0)
    assert np.abs(plain.gain("Kd")[0] / rec["gains"]["Kd"][0] - 1) > 0.1
    # None is the default's "estimated", never a NaN; nonsense is refused
    np.testing.assert_array_equal(identify_gains(exp, robot, noise_q=None).chi, g.chi)
    for bad in ("loud", -1e-5, float("nan"), True):
        with pytest.raises(InputError, match="noise_q"):
            identify_gains(exp, robot, noise_q=bad)


@pytest.mark.slow
def test_didim_with_identified_gains_agrees_with_idim(plant_run):
    rec, robot, exp = plant_run
    idim = dynid.identify(exp, robot)
    didim = dynid.identify(exp, robot, "didim", gains="identify")
    assert didim.converged and didim.gains is not None
    assert any("identified from the logged reference" in n for n in didim.notices)
    close = []
    for n in idim.names:
        if n in didim.names:
            a, b = idim.params[n], didim.params[n]
            s = max(idim.bse[n], didim.bse[n])
            close.append(abs(b - a) <= max(0.02 * abs(a), 2 * s))
    print(f"DIDIM (identified gains) vs IDIM: {sum(close)} of {len(close)} within 2 % or 2 sigma; "
          f"relative error {didim.model.rel_error:.4f} (IDIM {idim.model.rel_error:.4f})")
    assert sum(close) >= len(close) - 1
    assert didim.model.rel_error < 0.01
    # with the gains assumed in tx40.toml (wn = 60, PD) the simulated loop is another robot's
    assumed = dynid.identify(exp, robot, "didim", gains="assumed", update_gains="initial")
    assert assumed.model.rel_error > 3 * didim.model.rel_error
    assert any("depend on those gains" in n for n in assumed.notices)


def test_gains_need_a_logged_reference(plant_run):
    _, robot, exp = plant_run
    no_ref = dataclasses.replace(exp, qr=None)
    with pytest.raises(dynid.InputError, match="reference"):
        dynid.identify(no_ref, robot, "didim", gains="identify")
