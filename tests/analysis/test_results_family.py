"""One results family: every result class has the base of dynid.analysis.results.

Every result is built here from small arrays (no simulation, no dynamics), so the whole
file runs in a few seconds: summary() carries a unit on its parameter table, to_json()
round-trips to_dict(), to_csv() writes the result's table, conf_int(alpha) is the only
interval (the posterior's too), repr() is one line, r[name] is the parameter's record, and
the deprecated raw accessors warn.
"""
import json
import math
import warnings
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import dynid
from dynid.analysis.decoupled.campaign import DecoupledIdentification
from dynid.analysis.decoupled.repeated import RepeatedEstimate
from dynid.analysis.diagnosis.asymmetric_friction import AsymmetricFrictionResult
from dynid.analysis.diagnosis.results import DiagnosisResult
from dynid.analysis.estimators.controller_gains import GainsResult
from dynid.analysis.estimators.didim import DIDIMResult
from dynid.analysis.estimators.drive_gains import DriveGainResult
from dynid.analysis.estimators.essential import essential_parameters
from dynid.analysis.estimators.gravity_tilt import GravityTiltResult
from dynid.analysis.estimators.idim import IDIMResult
from dynid.analysis.estimators.least_squares import ols, wls
from dynid.analysis.estimators.maximum_likelihood import MLResult
from dynid.analysis.estimators.payload import PayloadResult
from dynid.analysis.estimators.payload_physical import PAYLOAD_NAMES, PhysicalPayload
from dynid.analysis.estimators.physical import PhysicalResult
from dynid.analysis.estimators.projection import ProjectionResult
from dynid.analysis.results import Parameter, Result, notices_block, parameter_table
from dynid.analysis.run import Identification, Settings
from dynid.analysis.sampling.sample import sample_linear
from dynid.analysis.statistics.validation import ValidationResult, normality
from dynid.analysis.statistics.verdict import Verdict
from dynid.analysis.units import parameter_unit
from dynid.reports.pipeline import FullReport

NAMES = ["ZZ1R", "Fv1", "Fc1", "MX2R", "M2", "Off2"]
TRUE = np.array([1.2, 0.8, 2.5, 0.4, 3.0, -0.3])


@pytest.fixture(scope="module")
def system():
    rng = np.random.default_rng(7)
    W3 = rng.normal(size=(300, 2, len(NAMES)))
    tau = W3 @ TRUE + rng.normal(scale=[0.05, 0.08], size=(300, 2))
    return W3, tau


def _cov(chi, rel=0.02):
    return np.diag((rel * np.abs(chi) + 1e-3) ** 2)


def _idim(system):
    W3, tau = system
    o, w = ols(W3, tau, NAMES), wls(W3, tau, NAMES)
    ess = essential_parameters(W3, tau, NAMES, estimator=wls)
    base = SimpleNamespace(names=NAMES, n_base=len(NAMES), relations=[f"{n} = {n}" for n in NAMES],
                           table=lambda: [{"name": n} for n in NAMES])
    obs = SimpleNamespace(n_raw=3000, n_samples=300)
    return IDIMResult(robot_name="toy", base=base, ols=o, wls=w, essential=ess, observation=obs,
                      settings={"fc_position": 20.0, "nd": 10}, notices=["a notice of the run"])


def _didim(system):
    W3, tau = system
    w = wls(W3, tau, NAMES)
    idim = _idim(system)
    history = pd.DataFrame({"iteration": [1, 2], "rel_error": [0.02, 0.01]})
    z = np.zeros((10, 2))
    return DIDIMResult(robot_name="toy", base=idim.base, result=w, essential=None, history=history,
                       converged=True, stop_reason="small step", settings={"fs": 100.0, "nd": 10,
                       "f_decimation_cutoff": 4.0, "v_s": 0.01}, initial=TRUE, kd_scale=np.ones(2),
                       t=np.arange(10) / 100, q_sim=z, qr=z, tau=z, tau_sim=z, tau_ddm=z, t_dec=np.arange(2),
                       tau_dec=z[:2], tau_est_dec=z[:2], W_dec=W3[:2], row_mask=np.ones((2, 2), bool))


def _projection(system):
    W3, tau = system
    return ProjectionResult(names=NAMES, chi=TRUE, cov=_cov(TRUE), m1=[2, 2], m2=[2, 2], corr=np.zeros(2),
                            max_xcorr=np.zeros(2), max_xcorr_lag=np.zeros(2), fir_rank=[5, 5], n_samples=300,
                            n_rows=600, rel_error=0.03, rel_error_projected=0.02, hac_lags=4,
                            ls=wls(W3, tau, NAMES))


def _ml(system):
    return MLResult(names=NAMES, chi=TRUE, cov=_cov(TRUE), theta_ls=TRUE, sigma_q=np.ones(2),
                    sigma_tau=np.ones(2), sigma_tau_given=False, n_harmonics=3, f0=0.1,
                    coefficients=np.zeros((2, 7)), nll=1.0, converged=True, n_evaluations=10, n_samples=300,
                    n_joints=2, rms_q=np.ones(2), rms_tau=np.ones(2), elapsed=0.1)


def _physical(system):
    c = _cov(TRUE)
    return PhysicalResult(robot_name="toy", names=NAMES, chi=TRUE, cov=c, standard_names=NAMES, standard=TRUE,
                          apriori=TRUE, wls_chi=TRUE * 1.01, wls_cov=c, chi2=0.5, dof=1, p_value=0.5,
                          active=[], links=[], prior=None, prior_weight=0.0, mass_tolerance=None, n_boot=0,
                          rel_error=0.02, wls_rel_error=0.019)


_POSTERIOR = {}


def _posterior(system):
    if "r" not in _POSTERIOR:                          # emcee: sampled once for the module
        _POSTERIOR["r"] = _sample(system)
    return _POSTERIOR["r"]


def _sample(system):
    W3, tau = system
    return sample_linear(W3[:, :1, :2], (tau[:, 0] - W3[:, 0, 2:] @ TRUE[2:])[:, None], NAMES[:2], seed=1, n_walkers=16,
                         criteria={"first_batch": 300})


def _repeated(system):
    rng = np.random.default_rng(1)
    names = ["k1", "qoff1", "Fv+1"]
    return RepeatedEstimate(kind="gravity", names=names, estimates=[1.0, 0.1, 0.5] + 0.01 * rng.normal(size=(5, 3)),
                            joints=[1, 1, 1])


def _per_joint(system):
    r = _repeated(system)
    return DecoupledIdentification(gravity=r, friction=r, inertia=r)


def _validation(system):
    W3, tau = system
    res = tau - W3 @ TRUE
    return ValidationResult(source="held-out.csv", t=np.arange(300) / 100.0, tau=tau, tau_hat=tau - res,
                            rel_error=0.05, rms=np.array([0.05, 0.08]), joint_rel_error=np.array([0.04, 0.06]),
                            noise=normality(res))


def _tilt(system):
    W3, tau = system
    return GravityTiltResult(robot_name="toy", chi=np.array([1e-3, -2e-3]), cov=np.diag([1e-8, 1e-8]),
                             gravity0=np.array([0, 0, -9.81]), gravity=np.array([0.01, 0.02, -9.81]),
                             rel_error_before=0.03, rel_error_after=0.02, weighted_rss_before=10.0,
                             weighted_rss_after=5.0, lr_statistic=5.0, lr_dof=2, p_value=0.08, iterations=3,
                             converged=True, robot=None, wls=wls(W3, tau, NAMES))


def _asymmetric(system):
    W3, tau = system
    return AsymmetricFrictionResult(robot_name="toy", joints=[1, 2], values=np.full((2, 4), 0.5),
                                    sigma=np.full((2, 4), 0.01), fit=wls(W3, tau, NAMES), rel_error_before=0.03)


def _diagnosis(system):
    W3, tau = system
    w = wls(W3, tau, NAMES)
    return DiagnosisResult(robot_name="toy", source="x.csv", ranking=[], steps=[], selected=[], model_before=w,
                           model_after=w, errors={}, settings={"max_effects": 3, "n_candidates": 0, "effects": [],
                                                                 "folds": 5, "gap": 10, "alpha": 0.01})


def _payload(system):
    chi = np.array([0.01, 0, 0, 0.01, 0, 0.01, 0.02, 0.0, 0.05, 1.0])
    return PayloadResult(method="WLS (robot fixed)", names=list(PAYLOAD_NAMES), chi=chi, cov=_cov(chi),
                         robot_name="toy", link=1, frame="flange", R=np.eye(3), p=np.zeros(3), T=np.eye(10),
                         joint_sigma=np.ones(2), rel_error=0.02, n_rows=600, hac_lags=3,
                         singular_ratio=np.ones(10), sources=["a.csv"])


def _physical_payload(system):
    chi = np.array([0.01, 0, 0, 0.01, 0, 0.01, 0.02, 0.0, 0.05, 1.0])
    return PhysicalPayload(names=list(PAYLOAD_NAMES), chi=chi, cov=_cov(chi), delta=0.0, active=[], com_box=None,
                           status="optimal")


def _drive_gains(system):
    g = np.array([1.5, 2.0])
    return DriveGainResult(names=["g1", "g2"], chi=g * 1.01, cov=_cov(g), joints=[1, 2], g_file=g,
                           factor=np.full(2, 1.01), factor_std=np.full(2, 0.001), known={"M": 1.0}, other={},
                           robot_name="toy", sources=["a.csv"], rel_error=0.02, hac_lags=3)


def _controller_gains(system):
    k = np.array([100.0, 10.0, 80.0, 8.0])
    return GainsResult(names=["Kp1", "Kd1", "Kp2", "Kd2"], chi=k, cov=_cov(k), n_joints=2, feedforward=False,
                       integral=False, rel_error=np.array([0.01, 0.02]), n_rows=300)


def _verdict():
    return Verdict(status="identified", identified=True, findings=[{"level": "ok", "text": "fine"}])


def _run(system):
    return Identification(settings=Settings(), robot=SimpleNamespace(name="toy"), experiments=[],
                          result=_idim(system), verdict=_verdict(), validation=_validation(system))


def _full_report(system):
    return FullReport(result=_idim(system), robot=SimpleNamespace(name="toy"), experiments=[],
                      validation=_validation(system), _verdict=_verdict())


PARAMETER_RESULTS = {"idim": _idim, "didim": _didim, "projection": _projection, "ml": _ml, "physical": _physical,
                     "posterior": _posterior, "repeated": _repeated, "per-joint": _per_joint, "tilt": _tilt,
                     "payload": _payload, "physical-payload": _physical_payload, "drive-gains": _drive_gains,
                     "controller-gains": _controller_gains}
OTHER_RESULTS = {"validation": _validation, "asymmetric-friction": _asymmetric, "diagnosis": _diagnosis,
                 "run": _run, "full-report": _full_report}


@pytest.fixture(scope="module", params=sorted({**PARAMETER_RESULTS, **OTHER_RESULTS}))
def result(request, system):
    make = {**PARAMETER_RESULTS, **OTHER_RESULTS}[request.param]
    return make(system)


def test_every_result_has_the_base(result, tmp_path):
    assert isinstance(result, Result)
    text = result.summary()
    assert str(result) == text and len(text) > 40
    line = repr(result)
    assert "\n" not in line and len(line) < 160 and line.startswith(f"<{type(result).__name__}")
    assert "array(" not in line
    doc = result.to_dict()
    text_json = result.to_json(tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text()) == json.loads(text_json) == json.loads(
        json.dumps(doc, allow_nan=False))
    frame = result.to_frame()
    csv = result.to_csv(tmp_path / "r.csv")
    assert (tmp_path / "r.csv").read_text() == csv and len(pd.read_csv(tmp_path / "r.csv")) == len(frame)


@pytest.mark.parametrize("key", sorted(PARAMETER_RESULTS))
def test_parameter_results_share_records_units_and_intervals(key, system):
    r = PARAMETER_RESULTS[key](system)
    assert isinstance(r, dynid.ParameterResults)
    names = list(r.names)
    text = r.summary()
    units = [parameter_unit(n) for n in names]
    assert any(units), names
    assert "unit" in text and all(u in text for u in units if u)
    rec = r[names[0]]
    value, std = rec                                  # unpacks as (value, std), as r[name] always did
    assert isinstance(rec, Parameter) and rec.name == names[0] and rec.unit == units[0]
    assert value == pytest.approx(r.params.iloc[0]) and std == pytest.approx(r.bse.iloc[0])
    assert rec["value"] == value and set(rec.to_dict()) == {"name", "value", "std", "rel_std_percent", "unit"}
    with pytest.raises(KeyError, match="no parameter"):
        r["nope"]
    ci = r.conf_int(0.1)
    assert list(ci.columns) == ["lower", "upper"] and list(ci.index) == names
    assert not hasattr(r, "interval") or key == "posterior"
    # the JSON's flat "parameters" list: one record per parameter with its value and sigma
    doc = r.to_dict()
    records = doc.get("parameters") if isinstance(doc.get("parameters"), list) else None
    if records is not None and records and isinstance(records[0], dict) and "std" in records[0]:
        assert [p["name"] for p in records][:len(names)] == names[:len(records)]
        assert records[0]["std"] == pytest.approx(std)
    assert key not in ("tilt", "drive-gains") or records is not None, doc.keys()


def test_posterior_intervals_are_conf_int_and_interval_is_deprecated(system):
    post = _posterior(system)
    ci = post.conf_int(alpha=0.5).to_numpy()
    with pytest.warns(DeprecationWarning, match="conf_int"):
        old = post.interval(0.5)
    np.testing.assert_allclose(old, ci)
    np.testing.assert_allclose(post.conf_int(0.05).to_numpy(), post.ci95)
    assert post[post.names[0]].value == pytest.approx(post.mean[0])
    assert post.draws(post.names[0]).shape == (post.n_samples,)


@pytest.mark.parametrize("key, attr, new", [
    ("idim-model", "sigma", "bse"), ("idim-model", "rel_sigma", "rel_std"), ("ml", "theta", "params"),
    ("ml", "sigma", "bse"), ("ml", "rel_sigma", "rel_std"), ("projection", "sigma", "bse"),
    ("projection", "rel_sigma", "rel_std"), ("physical", "sigma", "bse"), ("tilt", "theta", "params"),
    ("tilt", "sigma", "bse"),
    # what dynid.identify returns: the accessors were gone without a word (AttributeError)
    ("idim", "sigma", "bse"), ("idim", "rel_sigma", "rel_std"), ("didim", "sigma", "bse")])
def test_raw_accessors_warn_and_give_the_same_numbers(key, attr, new, system):
    r = _idim(system).model if key == "idim-model" else PARAMETER_RESULTS[key](system)
    with pytest.warns(DeprecationWarning, match=new):
        old = getattr(r, attr)
    np.testing.assert_array_equal(old, getattr(r, new).to_numpy())


def test_no_deprecated_accessor_fires_inside_dynid(system, tmp_path):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*deprecated and will be removed in the next release")
        for make in {**PARAMETER_RESULTS, **OTHER_RESULTS}.values():
            r = make(system)
            r.summary(), r.to_dict(), repr(r)


def test_table_builder_and_notices_block():
    lines = parameter_table(["ZZ1R", "Fv2", "MXL", "tilt_x"], [("value", [1.0, 2.0, 3.0, 4.0], "num")])
    assert lines[0].split() == ["Parameter", "unit", "value"]
    assert "kg m\u00b2" in lines[2] and "N m s/rad" in lines[3] and "kg m" in lines[4] and "rad" in lines[5]
    block = notices_block(["126 of 1668 equations were excluded by row_mask/joints."], ["x", "x"])
    assert block[0] == "Notices:" and len(block) == 3
    assert "row_mask" not in "\n".join(block) and "7.6 %" in block[1]


def test_summaries_print_relative_errors_in_percent(system):
    text = _idim(system).summary()
    assert "relative error ||Y - W chi|| / ||Y||: OLS" in text and " %, WLS " in text
    assert text.count("Notices:") == 1
    assert math.isfinite(_idim(system).model.rel_error)


def test_percent_reads_huge_errors_by_their_order():
    from dynid.analysis.results import percent
    assert percent(0.0433888) == "4.34 %" and percent(99.0) == "9900.00 %"
    assert percent(2.5235669e29) == "2.52e+31 %" and percent(-1e5) == "-1e+07 %"


def test_a_summary_of_several_results_has_one_notices_block_at_the_end():
    from dynid.analysis.results import gathered_notices, notices_block
    assert notices_block(["a remark"]) == ["Notices:", "  - a remark"]
    with gathered_notices() as remarks:
        first = notices_block(["a remark", "a shared remark"])
        second = notices_block(["a shared remark", "late"])
    assert first == second == []
    assert notices_block(remarks) == ["Notices:", "  - a remark", "  - a shared remark", "  - late"]
    assert notices_block(["outside again"]) == ["Notices:", "  - outside again"]


def test_one_p_value_text_everywhere():
    """p-values read alike in summaries, verdicts and figures: 3 significant digits, an exponent
    below 1e-4, "< 1e-300" (never "p = 0" or "p = < ...") where the test's p underflows."""
    from dynid.analysis.diagnosis.summary_text import fmt_p
    from dynid.analysis.results import p_phrase, p_value_text
    from dynid.reports.figures import format_p, p_equals

    assert p_value_text(0.012345) == "0.0123" and p_value_text(3.2e-7) == "3.2e-07"
    assert p_value_text(0.0) == "< 1e-300" and p_value_text(float("nan")) == "n/a"
    assert p_phrase(0.5) == "p = 0.5" and p_phrase(0.0) == "p < 1e-300"
    assert p_phrase(0.0, "Bonferroni p") == "Bonferroni p < 1e-300"
    assert p_equals(float("nan")) == "p = \u2014" and format_p(0.0) == "< 1e-300"
    assert fmt_p(float("nan")) == "-" and fmt_p(0.25) == "0.25"


def test_a_hidden_spring_not_reported_says_which_rule_it_missed():
    """A tiny p-value beside an amplitude lost in its own σ read as a contradiction ("no spring
    explains it (best joint 2, p = 0)"): the summary now names the rule the best candidate missed."""
    from dynid.analysis.diagnosis.hidden import HiddenEffect

    h = HiddenEffect(joint=2, name="gravity_spring", amplitude=1.10, phase=0.0, sigma=2.38, statistic=900.0,
                     p_value=0.0, deviation_before=10.0, deviation_after=1.0)
    assert h.shortfall() == "p < 1e-300, but its amplitude 1.1 +- 2.4 N m is 0.46 sigma, below 5"
    h.amplitude = 30.0
    assert "explains 90 %" not in h.shortfall() and h.shortfall() == "p < 1e-300"
    h.deviation_after = 8.0
    assert "explains 20 % of the contradiction" in h.shortfall()
    h.p_value = 0.2
    assert h.shortfall() == "p = 0.2, not below 0.01"


@pytest.mark.parametrize("make, key", [(_payload, "tab-payload"), (_drive_gains, "tab-drive-gains")])
def test_payload_and_drive_gain_pages_download_their_tables(make, key, system):
    """The page of `dynid payload --report` (and the full report's section) embeds each table's
    CSV, as its footer says: the values in full precision, in the result's order."""
    import io
    import re
    import urllib.parse

    from dynid.reports.payload_section import payload_html
    r = make(system)
    page = payload_html(r)
    uri = re.search(rf'href="data:text/csv;charset=utf-8,([^"]*)" download="{key}.csv"', page)
    assert uri is not None, "no CSV download for the parameter table"
    csv = pd.read_csv(io.StringIO(urllib.parse.unquote(uri.group(1))), index_col=0)
    column = "gain" if key == "tab-drive-gains" else "value"
    assert np.array_equal(csv[column].to_numpy(), np.asarray(r.chi, float))
    assert np.array_equal(csv["std"].to_numpy(), r.bse.to_numpy())


@pytest.mark.parametrize("make", [_payload, _drive_gains])
def test_dynid_verdict_refuses_a_payload_or_drive_gain_result(make, system):
    """A payload's ten parameters and drive gains have their own rule (`result.verdict()`); the
    robot model's verdict called them "base parameters" and disagreed with it."""
    import dynid
    with pytest.raises(dynid.InputError, match=r"has its own verdict, result.verdict\(\)"):
        dynid.verdict(make(system))


@pytest.mark.parametrize("make", [_diagnosis, _run])
def test_results_holding_their_parameters_answer_as_every_result(make, system):
    """A diagnosis and a run hold their parameters in another result; `params`, `bse`,
    `conf_int()`, `cov_params()` and `r[name]` are that result's (the diagnosis had a parameter
    table but no interval)."""
    r = make(system)
    held = r._held()
    name = list(held.names)[0]
    assert r.params.equals(held.params) and r.bse.equals(held.bse)
    assert r.conf_int().equals(held.conf_int()) and r.cov_params().equals(held.cov_params())
    assert tuple(r[name]) == tuple(held[name])


def test_the_effects_fit_gives_an_interval_for_each_effect_parameter():
    """`run.effects["Ks1"]` and `run.effects.conf_int()`: the stacked WLS with the run's covariance
    (the effects fit had only its own table, so no interval could be asked for)."""
    import dynid
    rec = dynid.simulate("planar2", 6.0, seed=2)
    fit = dynid.run(rec, "planar2", effects="spring:1", write=False).effects
    value, std = fit["Ks1"]
    row = fit.to_frame().loc["Ks1"]
    assert value == row["wls"] and std == row["wls_std"]
    ci = fit.conf_int().loc["Ks1"]
    assert ci["lower"] == pytest.approx(value - 1.959963984540054 * std)
