"""Noise PDF checks (Bona & Curatella 2005, section 3.4 and Fig. 5).

Sample size of the false-rejection / power tests: 2000, the samples of one
averaged period in the paper (10 s resampled at 200 Hz).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dynid.analysis.processing.averaging import average_periods
from dynid.analysis.statistics.noise import compare_noise, noise_pdf, noise_pdf_tests
from dynid.errors import InputError
from dynid.provenance import dumps_json

N_SAMPLES = 2000
SEEDS = range(200)
SIGMA = 0.3


def rejection_rate(draw, **kwargs):
    rej = [not noise_pdf_tests(draw(np.random.default_rng(s)), **kwargs).gaussian[0] for s in SEEDS]
    return float(np.mean(rej))


def test_gaussian_noise_rejected_at_the_nominal_rate():
    rate = rejection_rate(lambda rng: rng.normal(0.0, SIGMA, N_SAMPLES))
    assert 0.02 <= rate <= 0.08, rate


def test_laplace_noise_of_the_same_sigma_rejected():
    b = SIGMA / math.sqrt(2.0)             # Laplace scale with standard deviation SIGMA
    rate = rejection_rate(lambda rng: rng.laplace(0.0, b, N_SAMPLES))
    assert rate >= 0.90, rate


def test_the_all_tests_rule_would_reject_too_often():
    # why the default verdict uses one primary test: requiring all four to accept
    # rejects Gaussian noise well above alpha
    rate = rejection_rate(lambda rng: rng.normal(0.0, SIGMA, N_SAMPLES), rule="all")
    assert rate > 0.08
    rate_b = rejection_rate(lambda rng: rng.normal(0.0, SIGMA, N_SAMPLES), rule="bonferroni")
    assert rate_b <= 0.08


def test_table_contents_and_shapes():
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.normal(0, 1, 3000), rng.laplace(0, 1, 3000), rng.uniform(-1, 1, 3000)])
    res = noise_pdf_tests(x, names=["a", "b", "c"], unit="N m", label="torque noise")
    tab = res.table
    assert list(tab.index) == ["a", "b", "c"]
    assert list(res.gaussian) == [True, False, False]
    assert tab.loc["b", "excess_kurtosis"] == pytest.approx(3.0, abs=0.8)      # Laplace: excess 3
    assert tab.loc["c", "excess_kurtosis"] == pytest.approx(-1.2, abs=0.2)     # uniform: -1.2
    assert tab.loc["a", "std"] == pytest.approx(1.0, abs=0.05)
    for t in ("jarque_bera", "shapiro", "anderson", "lilliefors"):
        assert tab.loc["b", f"{t}_reject"] and 0 <= tab.loc["a", f"{t}_p"] <= 1
    d = json.loads(dumps_json(res.to_dict()))
    assert d["rule"] == "primary" and len(d["joints"]) == 3
    assert "torque noise" in res.summary()
    # long series: Shapiro on an evenly spaced subsample of at most 5000
    long = noise_pdf_tests(np.random.default_rng(1).normal(size=12_001))
    assert long.table["shapiro_n"].iloc[0] <= 5000 and long.table["n"].iloc[0] == 12_001
    # NaN ignored, constant column untestable
    y = np.random.default_rng(2).normal(size=(500, 2))
    y[::7, 0] = np.nan
    y[:, 1] = 1.0
    r = noise_pdf_tests(y)
    assert r.table["n"].iloc[0] == 500 - len(range(0, 500, 7)) and r.gaussian[1] is None
    with pytest.raises(InputError):
        noise_pdf_tests(x, alpha=1.5)
    with pytest.raises(InputError):
        noise_pdf_tests(x, rule="majority")


def test_pdf_curves_integrate_to_one():
    x = np.random.default_rng(3).normal(2.0, 0.5, (4000, 2))
    for p in noise_pdf(x):
        assert np.sum(p["density"] * np.diff(p["edges"])) == pytest.approx(1.0)
        assert np.trapezoid(p["kde"], p["x"]) == pytest.approx(1.0, abs=0.02)
        assert np.trapezoid(p["normal"], p["x"]) == pytest.approx(1.0, abs=0.02)
        assert p["mean"] == pytest.approx(2.0, abs=0.03) and p["std"] == pytest.approx(0.5, abs=0.02)


def test_compare_noise_in_torque_units_and_as_snr():
    rng = np.random.default_rng(4)
    tau_n = rng.normal(size=(5000, 2)) * [0.2, 0.05]
    q_n = rng.normal(size=(5000, 2)) * [1e-4, 1e-4]
    c = compare_noise(tau_n, q_n, sensitivity=[1000.0, 1000.0])      # N m/rad
    assert c.mode == "sensitivity" and c.dominant == ["torque", "position"]
    assert c.table["ratio"].iloc[0] == pytest.approx(2.0, rel=0.05)
    t = np.linspace(0, 6 * np.pi, 5000, endpoint=False)     # whole periods: RMS = amplitude / sqrt 2
    tau_sig = np.column_stack([np.sin(t), np.sin(t)]) * 10.0
    q_sig = np.column_stack([np.sin(t), np.sin(t)]) * 1e-3
    c2 = compare_noise(tau_n, q_n, tau_signal=tau_sig, q_signal=q_sig)
    # SNR tau: 10/sqrt2/0.2 = 35, 141; SNR q: 1e-3/sqrt2/1e-4 = 7.1 -> position dominates both
    assert c2.mode == "snr" and c2.dominant == ["position", "position"]
    assert c2.table["snr_q_db"].iloc[0] == pytest.approx(20 * math.log10(7.07), abs=0.3)
    c3 = compare_noise(np.array([0.2, 0.05]), np.array([1e-4, 1e-3]), sensitivity=500.0, as_sigma=True)
    assert c3.dominant == ["torque", "position"]
    assert "dominant" in c.summary() and json.loads(dumps_json(c2.to_dict()))["mode"] == "snr"
    with pytest.raises(InputError):
        compare_noise(tau_n, q_n)


def test_averaged_experiment_noise_is_gaussian_and_torque_dominates():
    """Pipeline of section 3.4: 25 periods averaged, noise PDFs, torque vs position (Fig. 5)."""
    f0, fs, M, n = 0.1, 200.0, 25, 2
    t = np.arange(int(M * fs / f0)) / fs
    k = np.arange(1, 6)
    q = np.stack([np.sin(2 * np.pi * f0 * k[None, :] * t[:, None] + j).sum(1) * 0.3 for j in range(n)], 1)
    tau = 20.0 * q + 3.0 * np.sign(np.cos(2 * np.pi * f0 * t + 0.3))[:, None]   # no zero on a sample
    rng = np.random.default_rng(6)   # each verdict falsely rejects with 5 % probability: a seed without
    sig_q, sig_tau = 2e-5, np.array([0.2, 0.1])
    avg = average_periods(t, {"q": q + rng.normal(size=q.shape) * sig_q,
                              "tau": tau + rng.normal(size=tau.shape) * sig_tau}, 1 / f0, align_on="q")
    assert np.all(avg.shifts == 0)
    tests_tau = noise_pdf_tests(avg.noise["tau"], label="torque noise", unit="N m")
    tests_q = noise_pdf_tests(avg.noise["q"], label="position noise", unit="rad")
    assert all(tests_tau.gaussian) and all(tests_q.gaussian)
    assert np.all(np.abs(tests_tau.table["excess_kurtosis"]) < 0.2) and np.all(np.abs(tests_tau.table["skew"]) < 0.1)
    assert np.allclose(tests_tau.table["std"], sig_tau, rtol=0.05)
    cmp_ = compare_noise(avg.noise["tau"], avg.noise["q"], tau_signal=avg.mean["tau"],
                         q_signal=avg.mean["q"])
    assert cmp_.dominant == ["torque", "torque"]
    from dynid.reports.bona_section import noise_section
    from dynid.reports.html import render_sections

    sec = noise_section(tests_tau, tests_q, comparison=cmp_, averaging=avg)
    html = render_sections([sec], title="noise")
    assert 'id="fig-noise-pdf"' in html and 'id="tab-noise-comparison"' in html
    assert "Torque noise dominates on 2 of 2 joints" in html
    # torque-only layout
    sec2 = noise_section(tests_tau, id="noise-tau")
    assert len(sec2.figures) == 1 and len(sec2.tables) == 1
