"""The covariance options of IDIM (classic / HAC / block bootstrap) and the cross-recording agreement."""
import dataclasses

import numpy as np
import pytest
import statsmodels.api as sm
from scipy import stats
from scipy.linalg import solve_triangular

from dynid.analysis.estimators import agreement as ag
from dynid.analysis.estimators import hac
from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters
from dynid.errors import InputError


def _ar1(rng, shape, phi):
    e = rng.standard_normal(shape)
    x = np.empty(shape)
    x[0] = e[0] / np.sqrt(1 - phi**2)
    for k in range(1, shape[0]):
        x[k] = phi * x[k - 1] + e[k]
    return x * np.sqrt(1 - phi**2)


def _system(rng, N=400, phi=0.0, smooth=True):
    """Two joints, three parameters; regressors smooth in time (as decimated robot data)."""
    t = np.arange(N) / 50.0
    W3 = np.zeros((N, 2, 3))
    W3[:, 0, 0] = np.sin(2.1 * t + rng.uniform(0, 6))
    W3[:, 0, 1] = np.cos(0.7 * t) if smooth else rng.standard_normal(N)
    W3[:, 1, 1] = np.sin(1.3 * t + 1.0)
    W3[:, 1, 2] = 1.0 + 0.5 * np.cos(3.1 * t)
    chi = np.array([1.0, -2.0, 0.5])
    tau = W3 @ chi + _ar1(rng, (N, 2), phi) * np.array([0.1, 0.3])
    return W3, tau, chi


def test_hac_is_statsmodels_newey_west_for_one_joint():
    # oracle: statsmodels' OLS with cov_type HAC, same lags, small-sample correction
    rng = np.random.default_rng(1)
    W3, tau, _ = _system(rng, phi=0.7)
    X, y = W3[:, 0, :2], tau[:, 0]
    fit = sm.OLS(y, X).fit(cov_type="HAC", cov_kwds={"maxlags": 6, "use_correction": True})
    chi = np.linalg.lstsq(X, y, rcond=None)[0]
    cov, info = hac.hac_covariance(X[:, None, :], y[:, None], np.ones((X.shape[0], 1), bool), chi,
                                   np.ones(1), np.linalg.inv(X.T @ X), bandwidth=7.0)
    assert info["nlags"] == 6
    np.testing.assert_allclose(cov, fit.cov_params(), rtol=1e-10)


def test_options_keep_the_estimate_and_record_their_name():
    rng = np.random.default_rng(2)
    W3, tau, _ = _system(rng, phi=0.8)
    names = ["a", "b", "c"]
    ref = ls.wls(W3, tau, names)
    for opt in ("hac", "bootstrap"):
        r = ls.wls(W3, tau, names, uncertainty=opt)
        np.testing.assert_array_equal(r.chi, ref.chi)
        assert r.settings["least_squares"]["uncertainty"]["uncertainty"] == opt
        assert any(opt in n for n in r.notices)
        assert not np.allclose(r.bse.to_numpy(), ref.bse.to_numpy())
    assert ref.settings["least_squares"]["uncertainty"]["uncertainty"] == "classic"


def test_bad_option_and_reduction_are_clear_errors():
    rng = np.random.default_rng(3)
    W3, tau, _ = _system(rng)
    with pytest.raises(InputError, match="uncertainty must be one of"):
        ls.ols(W3, tau, ["a", "b", "c"], uncertainty="robust")
    with pytest.raises(InputError, match="needs the samples"):
        red = ls.reduce_system(W3, tau, ["a", "b", "c"])
        ls._ols_system(red.system(), ls.RANK_RTOL, None, None, None, ("hac", None, 100, 0))


def test_essential_set_does_not_depend_on_the_option():
    rng = np.random.default_rng(4)
    W3, tau, _ = _system(rng, phi=0.8)
    W3 = np.concatenate([W3, 1e-3 * rng.standard_normal(W3.shape[:2] + (2,))], axis=2)
    names = ["a", "b", "c", "d", "e"]
    ref = essential_parameters(W3, tau, names, ls.wls)
    for opt in ("hac", "bootstrap"):
        e = essential_parameters(W3, tau, names, ls.wls, uncertainty=opt)
        assert e.essential == ref.essential
        np.testing.assert_array_equal(e.result.chi, ref.result.chi)
        assert e.result.settings["least_squares"]["uncertainty"]["uncertainty"] == opt


def test_coverage_with_ar1_noise_hac_and_bootstrap_beat_classic():
    # 150 replicates of AR(1) noise (phi 0.8, smooth regressors): classic is too narrow
    hits = {o: 0 for o in ls.UNCERTAINTY}
    n = 0
    for seed in range(150):
        rng = np.random.default_rng(100 + seed)
        W3, tau, chi = _system(rng, phi=0.8)
        for o in ls.UNCERTAINTY:
            r = ls.wls(W3, tau, ["a", "b", "c"], uncertainty=o, n_boot=150, seed=seed)
            hits[o] += int(np.sum(np.abs(r.chi - chi) <= 1.96 * r.bse.to_numpy()))
        n += 3
    cover = {o: h / n for o, h in hits.items()}
    assert cover["classic"] < 0.80
    assert 0.85 <= cover["hac"] <= 0.99
    assert 0.85 <= cover["bootstrap"] <= 0.99


def test_groups_keep_lags_inside_each_recording():
    rng = np.random.default_rng(5)
    W3, tau, _ = _system(rng, phi=0.8)
    names = ["a", "b", "c"]
    one = ls.wls(W3, tau, names, uncertainty="hac")
    two = ls.wls(W3, tau, names, uncertainty="hac", groups=np.repeat([0, 1], 200))
    assert not np.allclose(one.bse.to_numpy(), two.bse.to_numpy())
    with pytest.raises(InputError, match="groups"):
        ls.wls(W3, tau, names, uncertainty="hac", groups=np.zeros(3))


def test_andrews_bandwidth_grows_with_correlation():
    rng = np.random.default_rng(6)
    white = rng.standard_normal((500, 2))
    red = _ar1(rng, (500, 2), 0.9)
    assert hac.andrews_bandwidth(white) < 3 < hac.andrews_bandwidth(red)
    assert hac.block_length(white) <= 3 < 10 < hac.block_length(red)


# ------------------------------------------------------------------ agreement
def test_pairwise_agreement_counts_by_hand():
    chis = [np.array([1.0, 10.0, 0.0]), np.array([1.1, 10.0, 0.0]), np.array([1.0, 12.0, 0.0])]
    sig = [np.array([0.05, 0.5, 1.0])] * 3
    a = ag.pairwise_agreement(chis, sig, names=["x", "y", "z"])
    # z is never identified (%sigma inf); x: 0.1/0.0707 = 1.41, 0, 1.41; y: 0, 2.83, 2.83
    assert a["pairs"] == 6
    assert a["within_95"] == pytest.approx(4 / 6)
    assert a["median_abs_z"] == pytest.approx(np.sqrt(2))


def test_equality_test_and_random_effects():
    rng = np.random.default_rng(7)
    K, p = 4, 3
    truth = np.array([1.0, 2.0, 3.0])
    sig = np.full((K, p), 0.1)
    same = truth + 0.1 * rng.standard_normal((K, p))
    eq = ag.equality_test(same, [np.diag(s**2) for s in sig])
    # diagonal covariances: Cochran's Q summed over the parameters, exactly chi2 on (K - 1) p dof
    assert eq["dof"] == pytest.approx(9) and eq["scale"] == pytest.approx(1) and eq["p_value"] > 0.001
    assert eq["chi2"] == pytest.approx(eq["per_parameter"]["q"].sum())
    spread = same + np.array([[0.0], [1.0], [-1.0], [0.5]])
    eq2 = ag.equality_test(spread, [np.diag(s**2) for s in sig])
    assert eq2["p_value"] < 1e-6
    re = ag.random_effects(spread, sig)
    # DerSimonian-Laird by hand for parameter 0
    x, v = spread[:, 0], sig[:, 0] ** 2
    w = 1 / v
    mu = (w * x).sum() / w.sum()
    Q = (w * (x - mu) ** 2).sum()
    t2 = max(0.0, (Q - (K - 1)) / (w.sum() - (w**2).sum() / w.sum()))
    ws = 1 / (v + t2)
    assert re["tau"][0] == pytest.approx(np.sqrt(t2))
    assert re["pooled"][0] == pytest.approx((ws * x).sum() / ws.sum())
    assert re["std"][0] == pytest.approx(np.sqrt(1 / ws.sum()))
    # recordings that agree better than their σ say (Q < K - 1): tau² truncated at 0, the pooled σ is the
    # fixed-effect one (statsmodels' negative tau² gave a smaller one, or NaN)
    close = truth + np.array([[0.01], [-0.01], [0.005], [0.0]])
    re0 = ag.random_effects(close, sig)
    assert np.all(re0["tau"] == 0) and np.allclose(re0["std"], 0.1 / np.sqrt(K))
    a = ag.agreement(spread, sig, [np.diag(s**2) for s in sig], ["a", "b", "c"])
    line = ag.agreement_verdict(a)
    assert "do NOT agree" in line and "chi2" in line
    b = ag.agreement(same, sig, [np.diag(s**2) for s in sig], ["a", "b", "c"])
    assert "agree within" in ag.agreement_verdict(b) or b.within_95 < 0.9
    # the line says which test decided when only one of them fails
    both = dataclasses.replace(a, within_95=0.95, p_value=1e-6)
    assert "pair by pair but NOT all together" in ag.agreement_verdict(both)
    untested = dataclasses.replace(a, within_95=0.95, p_value=float("nan"))    # a chi2 test that could not run rejects nothing
    assert "agree within their intervals" in ag.agreement_verdict(untested)
    few = dataclasses.replace(a, pairs=3, within_95=1.0, p_value=0.014)     # the LWR4+ recording 1 alone
    assert "on weak evidence (only 3 pairwise differences)" in ag.agreement_verdict(few)
    assert "weak" not in ag.agreement_verdict(dataclasses.replace(few, pairs=ag.MIN_PAIRS))
    pairs = dataclasses.replace(a, pairs=ag.MIN_PAIRS, within_95=0.5, p_value=0.5)
    assert "too few pairwise differences" in ag.agreement_verdict(pairs) and "rejects" not in \
        ag.agreement_verdict(pairs).split(":")[0]
    # 5 of 6 inside and the chi2 test not rejecting (LWR4+ recording 2's segments): chance, not a
    # disagreement; it said "do NOT agree ... the intervals of one recording are optimistic"
    chance = dataclasses.replace(a, pairs=6, within_95=5 / 6, p_value=0.533)
    line = ag.agreement_verdict(chance)
    assert "cannot be told apart from agreeing: 1 of only 6" in line and "26 %" in line
    assert "NOT" not in line and "optimistic" not in line


def test_recording_agreement_segments_and_recordings():
    from types import SimpleNamespace

    from dynid.analysis.estimators.idim import recording_agreement
    rng = np.random.default_rng(8)
    W3, tau, _ = _system(rng, N=600)
    obs = SimpleNamespace(W=W3, tau=tau, row_mask=np.ones(tau.shape, bool), n_samples=600)
    names = ["a", "b", "c"]
    a, why = recording_agreement(obs, names, np.zeros(600, int), None)
    # dof: (K - 1) p, less what the correlations between the parameters take
    assert why == "" and a.kind == "segments" and a.k == 3 and 5 < a.dof <= 6
    # white noise, the right model: the segments agree
    assert a.p_value > 1e-3
    b, _ = recording_agreement(obs, names, np.repeat([0, 1], 300), None, "hac")
    assert b.kind == "recordings" and b.k == 2 and b.uncertainty == "hac"
    # a recording whose segments excite nothing in common: skipped with a notice
    W = W3.copy()
    W[:200, :, 2] = 0.0
    obs2 = SimpleNamespace(W=W, tau=tau, row_mask=np.ones(tau.shape, bool), n_samples=600)
    c, why = recording_agreement(obs2, ["a", "b", "c"], np.zeros(600, int), None)
    assert c is not None and c.left_out == ["c"]


def test_segment_agreement_leaves_out_what_absorbs_a_column_one_segment_cannot_identify():
    """A friction of a joint that does not reverse within one segment is there a combination of
    the offsets (the TX40's Fcm6 = 1.04 Off6 + 0.96 Off5): that segment fits without it, its
    offsets take its torque, and they are not compared; the other segments keep the column, and
    the right model agrees (fitting every segment without it made the offsets and the rest
    disagree at p ~ 1e-30 on dynid simulate's TX40)."""
    from types import SimpleNamespace

    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.idim import recording_agreement
    rng = np.random.default_rng(3)
    N = 900
    t = np.arange(N) / 50.0
    W = np.zeros((N, 1, 5))
    W[:, 0, 0] = 1.0                                           # off_a
    W[:, 0, 1] = np.where(t < 6.0, 1.0, np.sign(np.sin(1.7 * t)))   # fc_b: constant in segment 1
    W[:, 0, 2] = np.sin(2.3 * t)                               # c
    W[:, 0, 3] = np.cos(0.9 * t + 0.4)                         # e
    W[:, 0, 4] = np.sign(np.sin(0.8 * t + 0.3))                # fd: reverses everywhere
    chi = np.array([0.3, 2.0, 1.0, -0.5, 0.8])
    tau = W @ chi + 0.05 * rng.standard_normal((N, 1))
    obs = SimpleNamespace(W=W, tau=tau, row_mask=np.ones(tau.shape, bool), n_samples=N)
    names = ["off_a", "fc_b", "c", "e", "fd"]
    seg1 = np.zeros(tau.shape, bool)
    seg1[:300] = True
    own, aliased = ls.identifiable_and_aliased(W, seg1)
    # fc_b = off_a there: one of them is left out, the other takes its torque
    assert len(own) == 4 and {2, 3, 4} < set(own.tolist()) and aliased.size == 1
    assert {int(aliased[0]), *(set(range(5)) - set(own.tolist()))} == {0, 1}
    a, why = recording_agreement(obs, names, np.zeros(N, int), None)
    assert why == "" and a.left_out == ["off_a", "fc_b"] and a.names == ["c", "e", "fd"]
    assert a.p_value > 1e-3 and a.within_95 == 1.0


def test_agreement_is_a_result_with_the_pooled_estimate():
    """`Agreement` has the interface of every result: the pooled (random-effects) estimate as
    params/bse/conf_int with units, summary(), to_frame(), and the JSON block of the identify JSON."""
    import json

    from statsmodels.stats.meta_analysis import combine_effects
    chis = np.array([[0.5, 2.0, 1.0], [0.7, 2.1, 1.2], [0.4, 1.9, 0.8]])
    sig = np.array([[0.05, 0.1, 0.1], [0.05, 0.1, 0.1], [0.05, 0.1, 0.1]])
    a = ag.agreement(chis, sig, [np.diag(s**2) for s in sig], ["ZZ1R", "Fv1", "Fc1"], uncertainty="hac")
    # DerSimonian-Laird by statsmodels, independently of dynid's wrapping
    r = combine_effects(chis[:, 0], sig[:, 0] ** 2, method_re="dl")
    assert a.params["ZZ1R"] == pytest.approx(r.mean_effect_re) and a.bse["ZZ1R"] == pytest.approx(r.sd_eff_w_re)
    ci = a.conf_int()
    assert ci.loc["ZZ1R", "upper"] - ci.loc["ZZ1R", "lower"] == pytest.approx(2 * 1.959964 * r.sd_eff_w_re, rel=1e-6)
    assert a.between_std.index.equals(a.params.index) and a.between_std["ZZ1R"] >= 0
    assert a["Fv1"].unit == "N m s/rad" and a.to_frame().loc["ZZ1R", "unit"] == "kg m²"
    assert list(a.to_frame().columns) == ["value", "std", "rel_std_percent", "between_std", "p_value", "unit"]
    text = a.summary()
    assert a.verdict in text and "ZZ1R" in text and "hac covariance" in text
    block = json.loads(a.to_json())
    assert block["verdict"] == a.verdict and block["uncertainty"] == "hac"
    assert block["pooled"] == pytest.approx(list(a.params)) and block["names"] == ["ZZ1R", "Fv1", "Fc1"]
    assert a.to_csv().splitlines()[0].startswith("parameter,value,std")


def test_agreement_figure_renders_the_figures():
    from dynid.reports.agreement_figure import agreement_figure
    rng = np.random.default_rng(9)
    chis = 5 + rng.normal(size=(3, 10))
    sig = np.full((3, 10), 0.2)
    a = ag.agreement(chis, sig, [np.diag(s**2) for s in sig], [f"p{k}" for k in range(10)])
    f = agreement_figure(a)
    assert f.kind == "svg" and f"{a.pairs} pairs" in str(f.markup)


def test_bootstrap_without_the_per_sample_matrices_is_the_same(monkeypatch):
    rng = np.random.default_rng(10)
    W3, tau, _ = _system(rng, phi=0.5)
    names = ["a", "b", "c"]
    held = ls.wls(W3, tau, names, uncertainty="bootstrap", n_boot=60)
    monkeypatch.setattr(hac, "MAX_BOOT_BYTES", 0)
    summed = ls.wls(W3, tau, names, uncertainty="bootstrap", n_boot=60)
    np.testing.assert_allclose(summed.cov, held.cov, rtol=1e-8)


@pytest.mark.parametrize("gufunc", [True, False], ids=["gufunc", "loop"])
def test_batched_refits_are_each_replicate_s_alone_and_leave_the_singular_ones_out(monkeypatch, gufunc):
    # the replicates' refits in batched LAPACK calls: the same numbers as each alone; a zero
    # diagonal (a parameter no drawn sample excites) or a matrix that is not positive definite
    # is left out and counted, and the others keep their refits
    if not gufunc:
        monkeypatch.setattr(hac, "_cholesky_lo", None)
    rng = np.random.default_rng(26)
    X = rng.standard_normal((5, 40, 4))
    A_all = np.einsum("rts,rtk->rsk", X, X)
    c_all = rng.standard_normal((5, 4))
    x, failed = hac._solve_all(A_all, c_all)
    np.testing.assert_allclose(x, np.linalg.solve(A_all, c_all[..., None])[..., 0], rtol=1e-10)
    assert failed == 0
    alone = np.array([hac._solve_all(A_all[r:r + 1], c_all[r:r + 1])[0][0] for r in range(5)])
    assert np.array_equal(x, alone)
    # the numbers of scipy's Cholesky solve on the same scaled system, to the last bit
    d = np.sqrt(np.einsum("rii->ri", A_all))
    L = np.linalg.cholesky(A_all / (d[:, :, None] * d[:, None, :]))
    y = solve_triangular(L, (c_all / d)[..., None], lower=True)
    assert np.array_equal(x, solve_triangular(np.swapaxes(L, 1, 2), y, lower=False)[..., 0] / d)
    A_all[2, 1, :] = A_all[2, :, 1] = 0.0
    x, failed = hac._solve_all(A_all, c_all)
    assert failed == 1 and np.array_equal(x, alone[[0, 1, 3, 4]])
    A_all[3, 0, 1] = A_all[3, 1, 0] = 2 * np.sqrt(A_all[3, 0, 0] * A_all[3, 1, 1])
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(A_all[3])
    x, failed = hac._solve_all(A_all, c_all)
    assert failed == 2 and np.array_equal(x, alone[[0, 1, 4]])
    x, failed = hac._solve_all(A_all[2:4], c_all[2:4])
    assert failed == 2 and x.shape == (0, 4)


def test_bootstrap_falls_back_to_hac_when_blocks_cannot_identify(monkeypatch):
    # too few replicates refitted (a parameter excited by a handful of samples): the sandwich
    # stands in, and the result says so
    def refuse(*args, **kwargs):
        raise ValueError("only 3 of 50 bootstrap replicates could be refitted")

    monkeypatch.setattr(hac, "bootstrap_covariance", refuse)
    rng = np.random.default_rng(12)
    W3, tau, _ = _system(rng, N=300)
    r = ls.ols(W3, tau, ["a", "b", "c"], uncertainty="bootstrap", n_boot=50)
    unc = r.settings["least_squares"]["uncertainty"]
    assert unc["uncertainty"] == "hac" and unc["requested"] == "bootstrap"
    assert any("was asked for" in n and "3 of 50" in n for n in r.notices)
    h = ls.ols(W3, tau, ["a", "b", "c"], uncertainty="hac")
    np.testing.assert_allclose(r.cov, h.cov)


def test_one_default_for_the_cli_the_settings_and_identify():
    # the parser does not import the numerical modules: its copy of the choices and of the
    # default must be the library's
    from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY
    from dynid.analysis.run import Settings
    from dynid.reports import cli_options
    from dynid.reports.cli_options import build_parser
    assert tuple(cli_options.UNCERTAINTY_CHOICES) == ls.UNCERTAINTY
    assert cli_options.UNCERTAINTY_DEFAULT == DEFAULT_UNCERTAINTY == Settings().uncertainty
    args = build_parser(full=True).parse_args(["identify", "x.csv", "--robot", "tx40"])
    assert args.uncertainty == DEFAULT_UNCERTAINTY


def test_identification_report_shows_the_agreement():
    # the pipeline's identification report carries the agreement section (figure and table)
    # when the result has an agreement, and none when it has not
    from types import SimpleNamespace

    from dynid.reports.html import render_sections
    from dynid.reports.render import idim_extra_sections
    rng = np.random.default_rng(13)
    chis = 5 + rng.normal(size=(3, 4))
    sig = np.full((3, 4), 0.2)
    a = ag.agreement(chis, sig, [np.diag(s**2) for s in sig], ["ZZ1R", "Fv1", "Fc1", "Off1"], kind="segments",
                     uncertainty="hac", left_out=["Ia6"])
    result = SimpleNamespace(agreement=a, agreement_line=ag.agreement_verdict(a))
    ident = SimpleNamespace(tilt=None, asymmetric_friction=None, physical=None, effects=None, export=None,
                            result=result)
    sections = idim_extra_sections(ident)
    assert [s.id for s in sections] == ["agreement"]
    html = render_sections(sections, title="t")
    assert 'id="fig-agreement"' in html or "fig-agreement" in html
    assert "tab-agreement" in html and "kg m²" in html and "Ia6" in html and "hac covariance" in html
    assert ag.agreement_verdict(a)[:40] in html
    ident.result = SimpleNamespace(agreement=None)
    assert idim_extra_sections(ident) == []


def test_essential_robust_sigma_adds_the_bias_of_the_removed_parameters():
    # d = chi_e - chi_base,e equals the omitted-variable bias A chi_d of nested weighted LS
    # (computed here with numpy on the weighted rows); the robust essential covariance is the
    # full model's for the same parameters plus d d', classic is left as eq. (14)
    rng = np.random.default_rng(14)
    W3, tau, _ = _system(rng, phi=0.8)
    # "d" is mostly "a" (so its %sigma is large and it is removed) with a true value of 0.5:
    # removing it shifts "a" by about 1.5 of its sigma
    dcol = 0.5 * W3[:, :, 0] + 0.05 * np.sin(np.arange(W3.shape[0]) / 7.0)[:, None]
    W3 = np.concatenate([W3, dcol[:, :, None], 1e-3 * rng.standard_normal(W3.shape[:2] + (1,))], axis=2)
    tau = tau + 0.5 * dcol
    names = ["a", "b", "c", "d", "e"]
    e = essential_parameters(W3, tau, names, ls.wls, uncertainty="hac")
    cols = [names.index(n) for n in e.essential]
    drop = [k for k in range(5) if k not in cols]
    w = 1.0 / e.base.joint_sigma
    X = (W3 * w[None, :, None]).transpose(1, 0, 2).reshape(-1, 5)
    A = np.linalg.lstsq(X[:, cols], X[:, drop], rcond=None)[0]
    d = e.result.chi - e.base.chi[cols]
    assert e.removed == ["e", "d"] and np.max(np.abs(d) / e.base.bse.to_numpy()[cols]) > 1.0
    np.testing.assert_allclose(d, A @ e.base.chi[drop], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(e.result.cov, e.base.cov[np.ix_(cols, cols)] + np.outer(d, d), rtol=1e-10)
    own = ls.wls(W3[:, :, cols], tau, e.essential, joint_sigma=e.base.joint_sigma, uncertainty="hac")
    assert e.result.bse.to_numpy()[0] > own.bse.to_numpy()[0]   # "a", the parameter the removal shifts
    assert "selection_bias" in e.result.settings["least_squares"]["uncertainty"]
    assert any("bias of removing the others" in n for n in e.result.notices)
    classic = essential_parameters(W3, tau, names, ls.wls)
    np.testing.assert_allclose(classic.result.cov, ls.wls(W3[:, :, cols], tau, e.essential,
                                                          joint_sigma=e.base.joint_sigma).cov)


# ------------------------------------------------ bootstrap block length and samples
def test_politis_white_block_is_the_ar1_value_and_arch_rule():
    # the population value for an AR(1) of coefficient phi is (6 phi^2 / (1 - phi^2)^2)^(1/3) T^(1/3)
    # (Politis & White 2004); white noise needs blocks of about one sample
    rng = np.random.default_rng(20)
    T, phi = 4000, 0.8
    red = _ar1(rng, (T, 6), phi)
    population = (6 * phi**2 / (1 - phi**2) ** 2) ** (1 / 3) * T ** (1 / 3)
    assert abs(hac.politis_white_block(red) - population) < 0.25 * population
    assert hac.politis_white_block(rng.standard_normal((T, 6))) <= 3
    # two recordings: the median over both, no block longer than a third of the shorter one
    assert hac.politis_white_block(red[:60], np.repeat([0, 1], 30)) <= 10


def test_politis_white_block_agrees_with_arch():
    # arch.bootstrap.optimal_block_length (Patton, Politis & White 2009), column by column
    arch = pytest.importorskip("arch.bootstrap")
    x = _ar1(np.random.default_rng(23), (2000, 5), 0.9)
    ours = [hac._pw_one(x[:, k]) for k in range(5)]
    theirs = arch.optimal_block_length(x)["circular"].to_numpy()
    np.testing.assert_allclose(ours, theirs, rtol=0.15)


def _offset_beside_fast_columns(rng, T=400, s=6):
    """An offset (constant column), a fast column correlated with it (mean 0.9) and fast ones."""
    W3 = np.ones((T, 1, s))
    W3[:, 0, 1:] = rng.standard_normal((T, s - 1))
    W3[:, 0, 1] += 0.9
    return W3


def test_a_slow_parameter_gets_its_own_longer_block():
    # AR(1) 0.8 noise: the offset's error is the mean of the noise, correlated over tens of
    # samples, while most score columns are nearly white, so the scores' median block (a few
    # samples) cuts the offset's correlation. Its own block (Politis & White on its influence
    # series) widens its interval; truth known (Monte Carlo, no dynid simulator). Column 1's
    # score carries the offset's slow part (its mean is 0.9) but its influence series, B^-1 g,
    # does not: it keeps the common block, which the scores alone would not give it.
    rng = np.random.default_rng(24)
    T, s, reps = 400, 6, 200
    chi = np.arange(1.0, s + 1)
    hits = {"politis-white": 0, "politis-white-scores": 0}
    offset_long = column1_common = 0
    for rep in range(reps):
        W3 = _offset_beside_fast_columns(rng, T, s)
        tau = W3 @ chi + _ar1(rng, (T, 1), 0.8) * 0.2
        r = ls.ols(W3, tau, [f"p{k}" for k in range(s)])
        sig, info = {}, {}
        for rule in hits:
            cov, info[rule] = hac.bootstrap_covariance(W3, tau, np.ones(tau.shape, bool), r.chi, np.ones(1),
                                                       n_boot=150, seed=rep, block=rule)
            sig[rule] = np.sqrt(np.diag(cov))
            hits[rule] += int(abs(r.chi[0] - chi[0]) <= 1.96 * sig[rule][0])
        own, common = info["politis-white"]["parameter_blocks"], info["politis-white"]["block"]
        offset_long += own[0] > common
        column1_common += own[1] == common
        # the parameters on the common block keep its spread exactly
        on_common = np.array(own) == common
        np.testing.assert_array_equal(sig["politis-white"][on_common], sig["politis-white-scores"][on_common])
    assert offset_long >= 0.9 * reps and column1_common >= 0.75 * reps
    # 64-78 % with the common block, 85-90 % with the offset's own (over data seeds; a block
    # bootstrap of 400 samples stays a little short of 95 %)
    assert hits["politis-white-scores"] / reps <= 0.78
    assert hits["politis-white"] / reps >= 0.82
    assert (hits["politis-white"] - hits["politis-white-scores"]) / reps >= 0.1


def test_a_longer_block_that_cannot_be_refitted_is_given_up_and_said(monkeypatch):
    # when a longer block's replicates cannot be refitted, its parameters fall back to the
    # longest shorter block that could be, and the notice says their sigma may be optimistic
    rng = np.random.default_rng(25)
    W3 = _offset_beside_fast_columns(rng)
    tau = W3 @ np.arange(1.0, 7.0) + _ar1(rng, (400, 1), 0.8) * 0.2
    names = [f"p{k}" for k in range(6)]
    free = ls.wls(W3, tau, names, uncertainty="bootstrap", n_boot=100)
    info = free.settings["least_squares"]["uncertainty"]
    common, longest = info["block"], max(info["parameter_blocks"].values())
    assert longest > common and info["longer_blocks_failed"] == []
    real = hac._replicates

    def refuse_long(Wt, A, c, parts, block, n_boot, rng):
        D, failed = real(Wt, A, c, parts, block, n_boot, rng)
        return (D[:0], n_boot) if block == longest else (D, failed)

    monkeypatch.setattr(hac, "_replicates", refuse_long)
    r = ls.wls(W3, tau, names, uncertainty="bootstrap", n_boot=100)
    info = r.settings["least_squares"]["uncertainty"]
    assert info["longer_blocks_failed"] == [longest] and longest not in info["parameter_blocks"].values()
    assert info["failed_longer"] >= 100
    assert any(f"blocks of {longest} given up" in n for n in r.notices)
    np.testing.assert_array_equal(r.chi, free.chi)


def test_bootstrap_of_a_segment_is_that_of_the_segment_alone():
    # the samples a row mask leaves without equations are not drawn: a segment of a system
    # (agreement.segments) gets the bootstrap of that segment cut out, draw for draw
    rng = np.random.default_rng(21)
    W3, tau, _ = _system(rng, N=400, phi=0.8)
    names = ["a", "b", "c"]
    mask = np.zeros(tau.shape, bool)
    mask[100:300] = True
    seg = ls.wls(W3, tau, names, row_mask=mask, uncertainty="bootstrap", n_boot=80, seed=4)
    cut = ls.wls(W3[100:300], tau[100:300], names, uncertainty="bootstrap", n_boot=80, seed=4)
    np.testing.assert_array_equal(seg.chi, cut.chi)
    np.testing.assert_allclose(seg.cov, cut.cov, rtol=1e-9)
    info = seg.settings["least_squares"]["uncertainty"]
    assert info["samples"] == 200 and info["block_rule"] == "politis-white" and info["spread"] == "percentile"


def test_bootstrap_percentile_sigma_is_robust_to_a_few_wild_replicates():
    # a design whose third parameter is excited only in one short stretch: replicates that miss
    # most of it are nearly singular and land far out; they inflate the replicates' variance,
    # not the 95 % interval (the percentile half-width), and the percentile sigma still covers
    rng = np.random.default_rng(22)
    hits = {"percentile": 0, "cov": 0}
    width = {"percentile": [], "cov": []}
    n = 0
    for seed in range(30):
        W3, tau, chi = _system(rng, N=300, phi=0.6)
        burst = np.zeros(300)
        burst[140:150] = np.hanning(10)
        W3[:, 1, 2] = burst
        tau = W3 @ chi + _ar1(rng, tau.shape, 0.6) * np.array([0.1, 0.3])
        r = ls.wls(W3, tau, ["a", "b", "c"])
        w = 1.0 / r.joint_sigma
        for spread in hits:
            cov, _ = hac.bootstrap_covariance(W3, tau, np.ones(tau.shape, bool), r.chi, w, n_boot=100,
                                              seed=seed, spread=spread)
            s = np.sqrt(np.diag(cov))
            hits[spread] += int(np.sum(np.abs(r.chi - chi) <= 1.96 * s))
            width[spread].append(s[2] / r.bse.to_numpy()[2])
        n += 3
    assert hits["percentile"] / n >= 0.9
    assert np.median(width["percentile"]) < np.median(width["cov"])


def _wald_pinv(chis, covs):
    """The overall test as it was: sum_k d_k' V_k^+ d_k about the GLS mean, chi2 on (K - 1) p dof."""
    P = np.array([np.linalg.pinv(C) for C in covs])
    mu = np.linalg.lstsq(P.sum(axis=0), np.einsum("kij,kj->i", P, chis), rcond=None)[0]
    d = chis - mu
    return float(stats.chi2.sf(np.einsum("ki,kij,kj->", d, P, d), (len(chis) - 1) * chis.shape[1]))


def test_equality_test_size_with_correlated_and_estimated_covariances():
    """Under H0 the overall test rejects at its level, with correlated covariances and with
    covariances estimated from few effective samples (a HAC or bootstrap covariance of a short
    segment): the Wald form, which inverts them, rejected a true H0 most of the time (Monte Carlo
    against the chi2 distribution, not against dynid's own simulator)."""
    rng = np.random.default_rng(11)
    K, p, n, nu = 3, 20, 600, 30
    covs = []
    for _ in range(K):
        A = rng.standard_normal((p, p)) * np.linspace(0.1, 3.0, p)
        covs.append(A @ A.T / p + 0.01 * np.eye(p))
    chol = [np.linalg.cholesky(C) for C in covs]
    reject = {"exact": 0, "estimated": 0, "wald_estimated": 0}
    for _ in range(n):
        chis = np.array([c @ rng.standard_normal(p) for c in chol])
        est = [np.cov((c @ rng.standard_normal((p, nu))).T, rowvar=False) for c in chol]
        reject["exact"] += ag.equality_test(chis, covs)["p_value"] < 0.05
        reject["estimated"] += ag.equality_test(chis, est)["p_value"] < 0.05
        reject["wald_estimated"] += _wald_pinv(chis, est) < 0.05
    assert 0.025 <= reject["exact"] / n <= 0.08
    assert reject["estimated"] / n <= 0.10
    assert reject["wald_estimated"] / n >= 0.5
    # and it still sees one part shifted on one parameter: the per-parameter Q at 5 sigma of the
    # difference, the overall test (40 dof, of which correlations leave about 20) at 10
    chis = np.array([c @ rng.standard_normal(p) for c in chol])
    for shift, per_parameter, overall in ((5, True, None), (10, True, True)):
        moved = chis.copy()
        moved[0, 3] += shift * np.sqrt(covs[0][3, 3] + covs[1][3, 3])
        eq = ag.equality_test(moved, covs)
        assert eq["dof"] < (K - 1) * p
        assert (eq["per_parameter"]["p_value"][3] < 0.01) == per_parameter
        assert overall is None or (eq["p_value"] < 0.01) == overall


def test_agreement_with_a_parameter_of_zero_variance():
    """A part that gives a parameter σ = 0 made the χ² test raise LinAlgError; its per-parameter Q
    is now NaN and the rest is computed. Agreement compares by identity, as every result."""
    import copy
    chis = np.array([[1.0, 2.0], [1.1, 2.0], [0.9, 2.0]])
    sig = np.array([[0.1, 0.0], [0.1, 0.0], [0.1, 0.0]])
    a = ag.agreement(chis, sig, [np.diag(s**2) for s in sig], ["M1", "XX2"])
    assert np.isfinite(a.chi2) and np.isnan(a.per_parameter_p_value["XX2"])
    assert np.isfinite(a.per_parameter_p_value["M1"]) and a.summary()
    b = copy.deepcopy(a)
    assert a != b and a == a and hash(a)
