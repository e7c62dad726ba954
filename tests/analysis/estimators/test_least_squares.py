"""Tests of dynid.analysis.estimators.least_squares (eqs. (9)-(16)), dynid.analysis.results and dynid.provenance."""

import json
import math

import numpy as np
import pandas as pd
import pytest

import dynid.analysis.results as results_mod
import dynid.outputs as outputs
import dynid.provenance as provenance
from dynid.analysis.estimators.least_squares import RANK_RTOL, ols, stack, wls
from dynid.errors import IdentificationError, InputError
from dynid.outputs import atomic_write_bytes, atomic_write_text
from dynid.provenance import data_hash, dumps_json, versions

N, n, b = 400, 3, 8
NAMES = [f"P{i}" for i in range(b)]


def problem(seed=0, N=N, n=n, b=b):
    rng = np.random.default_rng(seed)
    W3 = rng.standard_normal((N, n, b))
    chi = rng.uniform(0.5, 3.0, b) * rng.choice([-1, 1], b)
    return W3, chi


# ------------------------------------------------------------------ stacking
def test_stack_is_joint_major():
    W3, _ = problem()
    tau = np.arange(N * n, dtype=float).reshape(N, n)
    W, Y, joint = stack(W3, tau)
    assert W.shape == (n * N, b) and Y.shape == (n * N,)
    # Rows 0..N-1 are joint 1 (eq. (10)), then joint 2...
    np.testing.assert_array_equal(W[:N], W3[:, 0, :])
    np.testing.assert_array_equal(W[N : 2 * N], W3[:, 1, :])
    np.testing.assert_array_equal(Y[N : 2 * N], tau[:, 1])
    np.testing.assert_array_equal(joint, np.repeat(np.arange(n), N))


# ----------------------------------------------------------------------- OLS
def test_ols_matches_lstsq_and_naive_covariance():
    W3, chi = problem(1)
    rng = np.random.default_rng(11)
    tau = W3 @ chi + 0.1 * rng.standard_normal((N, n))
    res = ols(W3, tau, NAMES)
    W, Y, _ = stack(W3, tau)
    ref = np.linalg.lstsq(W, Y, rcond=None)[0]
    np.testing.assert_allclose(res.chi, ref, rtol=1e-10, atol=1e-12)
    e = Y - W @ ref
    s2 = e @ e / (n * N - b)  # eq. (13)
    np.testing.assert_allclose(res.sigma_rho**2, s2, rtol=1e-10)
    np.testing.assert_allclose(res.cov, s2 * np.linalg.inv(W.T @ W), rtol=1e-8, atol=1e-14)  # eq. (14)
    np.testing.assert_allclose(res.bse.to_numpy(), np.sqrt(np.diag(res.cov)))
    np.testing.assert_allclose(res.rel_std.to_numpy(), 100 * res.bse.to_numpy() / np.abs(res.chi))  # eq. (15)
    np.testing.assert_allclose(res.rel_error, np.linalg.norm(e) / np.linalg.norm(Y), rtol=1e-10)
    E = e.reshape(n, N)
    np.testing.assert_allclose(res.residual, E.T, atol=1e-12)
    np.testing.assert_allclose(res.rms, np.sqrt((E**2).mean(axis=1)), rtol=1e-10)
    np.testing.assert_allclose(
        res.joint_rel_error, np.linalg.norm(E, axis=1) / np.linalg.norm(tau, axis=0), rtol=1e-10
    )
    np.testing.assert_allclose(res.cond, np.linalg.cond(W), rtol=1e-8)
    Ws = W / np.linalg.norm(W, axis=0)
    np.testing.assert_allclose(res.cond_scaled, np.linalg.cond(Ws), rtol=1e-8)
    assert res.n_samples == N and res.n_joints == n and res.n_rows == n * N and res.dof == n * N - b
    np.testing.assert_allclose(res.predict(W3), W3 @ res.chi)
    v, s = res["P3"]
    assert v == res.chi[3] and s == res.bse.to_numpy()[3]
    with pytest.raises(KeyError, match="P0"):
        res["nope"]


def test_ols_is_accurate_on_badly_scaled_columns():
    # Column scales spanning 1e-4..1e4 (inertia vs friction): the covariance via
    # R^-1 must still match a high-accuracy reference.
    W3, chi = problem(2)
    scale = np.logspace(-4, 4, b)
    W3 = W3 * scale
    chi = chi / scale
    rng = np.random.default_rng(3)
    tau = W3 @ chi + 0.01 * rng.standard_normal((N, n))
    res = ols(W3, tau, NAMES)
    W, Y, _ = stack(W3, tau)
    Ws = W / scale
    ref = np.linalg.lstsq(Ws, Y, rcond=None)[0] / scale
    np.testing.assert_allclose(res.chi, ref, rtol=1e-9)
    covs = np.linalg.inv(Ws.T @ Ws) / np.outer(scale, scale)
    np.testing.assert_allclose(res.cov, res.sigma_rho**2 * covs, rtol=1e-8)
    assert res.cond > 1e7 and res.cond_scaled < 10


def test_ols_sigma_matches_monte_carlo_spread():
    W3, chi = problem(4)
    true_sigma = 0.2
    estimates, reported, sig_rho = [], [], []
    for seed in range(200):
        rng = np.random.default_rng(1000 + seed)
        tau = W3 @ chi + true_sigma * rng.standard_normal((N, n))
        res = ols(W3, tau, NAMES)
        estimates.append(res.chi)
        reported.append(res.bse.to_numpy())
        sig_rho.append(res.sigma_rho)
    empirical = np.std(estimates, axis=0, ddof=1)
    mean_reported = np.mean(reported, axis=0)
    np.testing.assert_allclose(mean_reported, empirical, rtol=0.15)
    assert abs(np.mean(sig_rho) / true_sigma - 1) < 0.05
    # The estimates are unbiased.
    assert np.all(np.abs(np.mean(estimates, axis=0) - chi) < 4 * empirical / np.sqrt(200))


def test_rel_sigma_is_inf_or_nan_safe_and_json_null(tmp_path):
    W3, chi = problem(5)
    tau = np.zeros((N, n))  # χ̂ = 0 and σ = 0: %σ is undefined, rel_error is 0/0
    res = ols(W3, tau, NAMES)
    assert np.all(np.isnan(res.rel_std.to_numpy()))
    assert math.isnan(res.rel_error)
    import dataclasses

    res2 = dataclasses.replace(res, cov=np.eye(b))  # σ = 1, χ̂ = 0 → %σ = inf
    assert np.all(np.isinf(res2.rel_std.to_numpy()))
    d = json.loads(dumps_json(res2.to_dict()))
    assert d["rel_error"] is None
    assert all(p["rel_std_percent"] is None and p["value"] == 0.0 for p in d["parameters"])
    res2.to_json(tmp_path / "r.json")
    text = (tmp_path / "r.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert "inf" in res2.summary()


# ----------------------------------------------------------------------- WLS
SIGMAS = np.array([0.05, 1.0, 0.1])  # joint 2 is very noisy


def hetero_tau(W3, chi, seed, sigmas=SIGMAS):
    rng = np.random.default_rng(seed)
    return W3 @ chi + sigmas * rng.standard_normal(W3.shape[:2])


def test_wls_estimates_joint_sigma():
    W3, chi = problem(6)
    for seed in range(20):
        res = wls(W3, hetero_tau(W3, chi, seed), NAMES)
        np.testing.assert_allclose(res.joint_sigma, SIGMAS, rtol=0.10)
        assert res.method == "WLS"
        # The weighted system has unit error variance when the σ_j are right.
        assert abs(res.sigma_rho - 1) < 0.1


def test_wls_joint_sigma_dof_is_unbiased_for_short_records():
    # r_j = 30, b_j = 8: σ_j² = ‖ρ^j‖²/(r_j - b_j) of the per-joint OLS (eq. (16))
    # is unbiased; dividing by r_j would make it 27 % too small, and the joint
    # OLS residual with r_j - b_j would be biased too.
    W3, chi = problem(7, N=30)
    est = []
    for seed in range(400):
        rng = np.random.default_rng(seed)
        tau = W3 @ chi + 0.3 * rng.standard_normal((30, n))
        est.append(wls(W3, tau, NAMES).joint_sigma ** 2)
    np.testing.assert_allclose(np.mean(est, axis=0), 0.09, rtol=0.06)


def test_joint_sigma_ignores_a_column_at_rounding_level():
    # A regrouped parameter that joint 1 does not see can reach its rows as rounding (ZZ2R in
    # the TX40's joint-1 rows at 1e-19 of the largest column). Scaled to unit norm it would be
    # a column of noise taking a dof and part of the residual: σ_1 must be that of exact zeros.
    W3, chi = problem(9, N=60)
    W3[:, 0, 5:] = 0.0
    rng = np.random.default_rng(1)
    tau = W3 @ chi + 0.3 * rng.standard_normal((60, n))
    exact = wls(W3, tau, NAMES).joint_sigma
    noisy = W3.copy()
    noisy[:, 0, 5:] = 1e-19 * rng.standard_normal((60, 3))
    np.testing.assert_allclose(wls(noisy, tau, NAMES).joint_sigma, exact, rtol=1e-12)


def test_joint_sigma_does_not_depend_on_a_parameters_units():
    # a real column 1e-13 times the others (a parameter in other units) is not rounding
    W3, chi = problem(10)
    tau = W3 @ chi + 0.1 * np.random.default_rng(2).standard_normal((N, n))
    scaled = W3.copy()
    scaled[:, :, 0] *= 1e-13
    np.testing.assert_allclose(wls(scaled, tau, NAMES).joint_sigma, wls(W3, tau, NAMES).joint_sigma,
                               rtol=1e-9)


def test_wls_beats_ols_with_one_noisy_joint_and_reports_right_sigma():
    W3, chi = problem(8)
    o, w, w_sig = [], [], []
    for seed in range(100):
        tau = hetero_tau(W3, chi, 500 + seed)
        o.append(ols(W3, tau, NAMES).chi)
        r = wls(W3, tau, NAMES)
        w.append(r.chi)
        w_sig.append(r.bse.to_numpy())
    var_o = np.var(o, axis=0, ddof=1)
    var_w = np.var(w, axis=0, ddof=1)
    assert np.all(var_w < 0.5 * var_o)
    np.testing.assert_allclose(np.mean(w_sig, axis=0), np.sqrt(var_w), rtol=0.2)


def test_wls_statistics_are_in_original_units_and_joint_sigma_can_be_fixed():
    W3, chi = problem(9)
    tau = hetero_tau(W3, chi, 1)
    res = wls(W3, tau, NAMES)
    np.testing.assert_allclose(res.residual, tau - W3 @ res.chi)
    np.testing.assert_allclose(res.rms, np.sqrt((res.residual**2).mean(axis=0)))
    np.testing.assert_allclose(res.rms, SIGMAS, rtol=0.1)
    fixed = wls(W3, tau, NAMES, joint_sigma=SIGMAS)
    np.testing.assert_allclose(fixed.joint_sigma, SIGMAS)
    # Reference: weighted lstsq by hand.
    W, Y, joint = stack(W3, tau)
    wrow = 1 / SIGMAS[joint]
    ref = np.linalg.lstsq(W * wrow[:, None], Y * wrow, rcond=None)[0]
    np.testing.assert_allclose(fixed.chi, ref, rtol=1e-10)
    with pytest.raises(InputError, match="joint_sigma"):
        wls(W3, tau, NAMES, joint_sigma=[1.0, -1.0, 1.0])


# ------------------------------------------------------------ masks / joints
def test_row_mask_and_joint_subset():
    W3, chi = problem(10)
    tau = hetero_tau(W3, chi, 2)
    mask = np.ones(N, dtype=bool)
    mask[::3] = False
    tau_bad = tau.copy()
    tau_bad[0, 1] = np.nan  # excluded by the mask, so allowed
    res = ols(W3, tau_bad, NAMES, row_mask=mask, joints=[0, 2])
    W, Y, joint = stack(W3[mask][:, [0, 2]], tau[mask][:, [0, 2]])
    np.testing.assert_allclose(res.chi, np.linalg.lstsq(W, Y, rcond=None)[0], rtol=1e-10)
    assert res.n_rows == 2 * mask.sum()
    assert np.isfinite(res.rms[0]) and np.isnan(res.rms[1])
    assert any("excluded" in t for t in res.notices)
    with pytest.raises(InputError, match="non-finite.*sample 0, joint 2"):
        ols(W3, tau_bad, NAMES)
    with pytest.raises(InputError, match="boolean"):
        ols(W3, tau, NAMES, row_mask=mask.astype(int))
    with pytest.raises(InputError, match="joints"):
        ols(W3, tau, NAMES, joints=[3])


def test_input_errors():
    W3, chi = problem(11)
    tau = W3 @ chi
    with pytest.raises(InputError, match="tau has shape"):
        ols(W3, tau[:, :2], NAMES)
    with pytest.raises(InputError, match="8 columns"):
        ols(W3, tau, NAMES[:-1])
    with pytest.raises(InputError, match="duplicate.*P1"):
        ols(W3, tau, NAMES[:2] + ["P1"] + NAMES[3:])
    with pytest.raises(IdentificationError, match="more rows than"):
        ols(W3[:2], tau[:2], NAMES)
    res = ols(W3, tau, NAMES)
    with pytest.raises(InputError, match="predict"):
        res.predict(W3[:, :, :3])


# ------------------------------------------------------------ rank deficiency
def test_duplicated_column_raises_naming_both():
    W3, chi = problem(12)
    W3[:, :, 5] = W3[:, :, 2]
    tau = W3 @ chi
    with pytest.raises(IdentificationError) as exc:
        ols(W3, tau, NAMES)
    msg = str(exc.value)
    assert "'P2'" in msg and "'P5'" in msg
    assert "1 of 8 parameters" in msg
    assert "remove" in msg and "base parameters" in msg
    for name in ("P0", "P1", "P3", "P4", "P6", "P7"):
        assert f"'{name}'" not in msg


def test_scaled_near_duplicate_column_is_caught():
    W3, chi = problem(13)
    rng = np.random.default_rng(0)
    W3[:, :, 6] = 1e-3 * (W3[:, :, 1] + 1e-10 * rng.standard_normal((N, n)))
    with pytest.raises(IdentificationError, match="'P6'.*'P1'|'P1'.*'P6'"):
        wls(W3, W3 @ chi + 0.1, NAMES, joint_sigma=np.ones(n))
    # A tiny but independent column is not rank deficiency.
    W3[:, :, 6] = 1e-6 * rng.standard_normal((N, n))
    ols(W3, W3 @ chi + 0.1 * rng.standard_normal((N, n)), NAMES)


def test_zero_column_raises_naming_it():
    W3, chi = problem(14)
    W3[:, :, 4] = 0.0
    tau = W3 @ chi
    with pytest.raises(IdentificationError, match=r"'P4': its column of W is all zero.*excite") as exc:
        ols(W3, tau, NAMES)
    assert "'P0'" not in str(exc.value)


def test_column_only_in_excluded_joint():
    W3, chi = problem(15)
    W3[:, [0, 1], 7] = 0.0  # P7 acts on joint 3 only, e.g. Fv3
    tau = W3 @ chi
    with pytest.raises(IdentificationError, match="'P7'.*excluded.*joint 3"):
        ols(W3, tau, NAMES, joints=[0, 1])
    assert RANK_RTOL < 1e-7


def test_friction_of_joint_moving_one_way_names_joint():
    W3, chi = problem(16)
    W3[:, :, 6] = 0.0
    W3[:, :, 7] = 0.0
    v = np.abs(W3[:, 2, 0]) + 0.1  # joint 3 never reverses: Fc3 = sign(v) = 1
    W3[:, 2, 6] = v
    W3[:, 2, 7] = np.sign(v)
    W3[:, :, 5] = 0.0
    W3[:, 2, 5] = 1.0  # an offset on joint 3 duplicates Fc3
    with pytest.raises(IdentificationError, match="joint 3") as exc:
        ols(W3, W3 @ chi, NAMES)
    assert "'P5'" in str(exc.value) and "'P7'" in str(exc.value)


# --------------------------------------------------------- results / output
def test_summary_frame_dict():
    W3, chi = problem(17)
    tau = hetero_tau(W3, chi, 3)
    res = wls(W3, tau, NAMES, settings={"decimation": 10, "cutoff_hz": np.float64(5.0)})
    text = res.summary()
    for piece in ("WLS", "Samples N:", "400", "cond(W)", "sigma_rho", "%sigma", "P7", "sigma_j"):
        assert piece in text
    frame = res.to_frame()
    assert list(frame.columns) == ["value", "std", "rel_std_percent", "unit"]
    assert list(frame.index) == NAMES
    d = res.to_dict()
    for key in (
        "method", "settings", "parameters", "rel_error", "rms_per_joint", "joint_rel_error",
        "cond", "sigma_rho", "n_samples", "versions", "data_hash", "notices",
    ):
        assert key in d
    assert d["settings"]["decimation"] == 10 and d["settings"]["least_squares"]["estimator"] == "WLS"
    assert set(d["parameters"][0]) == {"name", "value", "std", "rel_std_percent", "unit"}
    assert d["versions"]["numpy"] == np.__version__
    assert d["versions"]["dynid"]
    assert len(d["data_hash"]) == 64
    json.dumps(d, allow_nan=False)
    with pytest.raises(InputError, match="settings"):
        ols(W3, tau, NAMES, settings={"bad": object()})


def test_to_json_is_deterministic(tmp_path):
    W3, chi = problem(18)
    tau = hetero_tau(W3, chi, 4)
    ols(W3, tau, NAMES).to_json(tmp_path / "a.json")
    ols(W3.copy(), tau.copy(), NAMES).to_json(tmp_path / "b.json")
    a = (tmp_path / "a.json").read_bytes()
    assert a == (tmp_path / "b.json").read_bytes()
    assert b"timestamp" not in a
    d = json.loads(a)
    assert d["method"] == "OLS"
    res = ols(W3, tau, NAMES)
    res.to_csv(tmp_path / "a.csv")
    res.to_csv(tmp_path / "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    frame = pd.read_csv(tmp_path / "a.csv", index_col=0)
    np.testing.assert_allclose(frame["value"].to_numpy(), res.chi, rtol=1e-15)
    # A different data set gives a different hash.
    tau[0, 0] += 1e-9
    assert ols(W3, tau, NAMES).data_hash != res.data_hash


def test_failed_serialisation_leaves_no_file(tmp_path, monkeypatch):
    W3, chi = problem(19)
    res = ols(W3, W3 @ chi + 0.1, NAMES)

    def boom(*a, **k):
        raise RuntimeError("serialisation failed")

    monkeypatch.setattr(results_mod, "dumps_json", boom)
    with pytest.raises(RuntimeError):
        res.to_json(tmp_path / "r.json")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_old_file_and_no_temp(tmp_path, monkeypatch):
    W3, chi = problem(20)
    res = ols(W3, W3 @ chi + 0.1, NAMES)
    target = tmp_path / "r.json"
    target.write_text("old")

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(provenance.os, "replace", boom)
    with pytest.raises(OSError):
        res.to_json(target)
    with pytest.raises(OSError):
        res.to_csv(target)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_atomic_writers_and_hash(tmp_path):
    atomic_write_text(tmp_path / "t.txt", "a\nb\n")
    assert (tmp_path / "t.txt").read_bytes() == b"a\nb\n"
    atomic_write_bytes(tmp_path / "t.bin", b"\x00\x01")
    assert (tmp_path / "t.bin").read_bytes() == b"\x00\x01"
    with pytest.raises(ValueError):
        with outputs.atomic_open(tmp_path / "u.txt") as fh:
            fh.write("partial")
            raise ValueError("writer failed")
    assert not (tmp_path / "u.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.bin", "t.txt"]
    a = np.arange(6.0)
    assert data_hash(a) == data_hash(a.copy())
    assert data_hash(a) != data_hash(a.reshape(2, 3))
    assert data_hash(a) != data_hash(a.astype(np.float32))
    assert data_hash(a) == data_hash(a.astype(">f8"))
    assert data_hash(a, None) != data_hash(a)
    v = versions()
    assert list(v)[0] == "dynid" and set(v) >= {"numpy", "scipy", "pandas", "statsmodels", "emcee", "matplotlib", "jinja2"}
