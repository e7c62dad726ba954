"""The drive gains' dead zone and weak-gain notice (issue 28, the 1 % bar).

The gains' scale rests on the known payload's small torque, so the smooth Coulomb transition of
the independent plant (`Fc tanh(qd / 0.01)`, unmodelled by eq. (3)'s `Fc sign(qd)`) that IDIM's
1 % dead zone leaves in the equations biased them by about 1 % (seed 311 of
benchmarks/payload.py, the development seed of that investigation; docs/payload.md).
"""
import dataclasses

import numpy as np
import pytest

import dynid
from dynid.analysis.data.experiment import Experiment
from dynid.analysis.estimators.drive_gains import (
    DEAD_ZONE_FRACTION,
    WEAK_GAIN_HALFWIDTH,
    _gain_settings,
    _weak_gain_notice,
    identify_drive_gains,
)


def _robot():
    return dataclasses.replace(dynid.load_robot("tx40"), couplings=[])


def _sines(fs=1000.0, seconds=4.0):
    t = np.arange(int(fs * seconds)) / fs
    amp = np.array([0.2, 0.3, 0.4, 0.5, 0.6, 0.7])
    w = 2 * np.pi * np.array([0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
    q = amp * np.sin(w * t[:, None])
    return Experiment(t=t, q=q, qr=q, tau=np.zeros_like(q), fs=fs, source="sines"), amp * w


def test_dead_zone_is_a_fraction_of_each_joints_peak_speed():
    e, peak = _sines()
    settings, notice = _gain_settings(e, _robot(), None)
    assert np.allclose(settings["qd_threshold"], DEAD_ZONE_FRACTION * peak, rtol=0.01)
    assert f"{100 * DEAD_ZONE_FRACTION:g} %" in notice and "qd_threshold" in notice


@pytest.mark.parametrize("given", [0.02, "auto", [0.01] * 6])
def test_a_given_qd_threshold_is_kept(given):
    e, _ = _sines()
    settings, notice = _gain_settings(e, _robot(), {"qd_threshold": given, "nd": 10})
    assert settings == {"qd_threshold": given, "nd": 10} and notice is None


def test_weak_gain_notice_names_only_the_wide_gains():
    k = np.array([1.0, 1.0, 1.0])
    std = np.array([0.1, 0.6, 0.2]) * WEAK_GAIN_HALFWIDTH          # half-widths 0.2, 1.2, 0.4 x the limit
    note = _weak_gain_notice([1, 4, 6], k, std)
    assert "joint 4" in note and "joint 1" not in note and "joint 6" not in note and "com=" in note
    assert _weak_gain_notice([1, 4, 6], k, std / 2) is None


@pytest.mark.slow
def test_gains_are_unbiased_where_idims_dead_zone_biased_them():
    """Seed 311's payload (1.6 kg, 38 mm from the wrist centre): one noise-free motion, three draws of
    the sensor noise (2e-5 rad, 0.2 N m). Mean error of the gains that share the payload's scale
    (joints 1, 4, 5, 6) over the draws: about -1 % with IDIM's dead zone, near 0 with the gains' own."""
    pytest.importorskip("pinocchio")
    from tests.support import independent_plant as ip
    from tests.support import payload_plant as pp
    seed, rate = 311, 2000.0
    params, _ = pp.random_payload(np.random.default_rng(seed))
    base, loaded, _ = pp.tx40_payload_plant(params)
    recs = [pp.record(plant, pp.wrist_reference(plant.limits, dur, rate, s), s, rate=rate, sensor=ip.PERFECT)
            for plant, dur, s in ((base, 20.0, 2 * seed + 1), (loaded, 10.0, 2 * seed + 2))]
    kt = np.random.default_rng(seed + 7).uniform(0.9, 1.1, 6)
    errs = {"auto": [], None: []}
    for d in range(3):
        rng = np.random.default_rng(10_000 + d)
        u, lo = (Experiment(t=r["t"], q=r["q"] + 2e-5 * rng.standard_normal(r["q"].shape), qr=r["qr"],
                            tau=(r["tau"] + 0.2 * rng.standard_normal(r["tau"].shape)) / kt, fs=rate, source="draw")
                 for r in recs)
        for zone in errs:
            res = identify_drive_gains(u, lo, _robot(), mass=params[9], zoh=True,
                                       settings=None if zone is None else {"qd_threshold": zone})
            errs[zone].append(100 * (res.factor - kt) / kt)
    shared = [0, 3, 4, 5]
    assert np.mean(np.array(errs["auto"])[:, shared]) < -0.6          # the bias the dead zone removes
    assert abs(np.mean(np.array(errs[None])[:, shared])) < 0.35


def test_gauss_newton_reports_the_error_of_its_fit_on_the_logged_torque():
    """tau_j = a_j (X_j theta + known_j) + noise: the rel_error is ||noise|| / ||tau|| (it was the last
    Gauss-Newton step's fit of the residual, about 100 %)."""
    import numpy as np

    from dynid.analysis.estimators.drive_gains import _gauss_newton
    rng = np.random.default_rng(4)
    M, n, p = 600, 2, 3
    X = rng.normal(size=(M, n, p))
    known = rng.normal(size=(M, n))
    theta, a = np.array([1.0, -2.0, 0.5]), np.array([1.0 / 1.05, 1.0])
    clean = a * (X @ theta + known)
    tau = clean + rng.normal(0, 0.05, size=(M, n))
    mask = np.ones((M, n), dtype=bool)
    est, cov, rel_error, lags = _gauss_newton(X, tau, known, [0], ["P1", "P2", "P3"], mask)
    expected = np.linalg.norm(tau - clean) / np.linalg.norm(tau)
    assert np.allclose(est[:p], theta, atol=0.02) and abs(1 / est[p] - 1.05) < 0.01
    assert rel_error == pytest.approx(expected, rel=0.05) and rel_error < 0.05
