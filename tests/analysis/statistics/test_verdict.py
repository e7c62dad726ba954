"""Held-out error on all samples, the verdict, and one DIDIM step index everywhere."""
from __future__ import annotations

import json
import re
import types
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[3]
TX40 = ROOT / "examples" / "staubli_tx40" / "experiment.toml"


@pytest.fixture(scope="module")
def tx40_run(tmp_path_factory):
    """``dynid identify ... --holdout 3 --json --report`` on the real TX40, run once per session
    (tests/reports/test_browser.py reads the same run)."""
    from shared_runs import tx40_identify_run
    run = tx40_identify_run(tmp_path_factory)
    assert run.returncode == 0, run.stderr
    return json.loads((run.folder / "out.json").read_text()), (run.folder / "out.html").read_text(encoding="utf-8")


def _independent_all_samples_error(doc):
    """The held-out error recomputed from the log and the JSON's parameters, without validate()."""
    from dynid.analysis.data.experiment import load_experiment
    from dynid.analysis.processing.observation import observe
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    robot = load_robot("tx40")
    exp = load_experiment(TX40, robot)
    held = exp.segment(exp.t[-1] - 3.0, None)            # the last 3 s, t >= t[-1] - 3
    assert held.t[0] >= exp.t[-1] - 3.0 and held.t[-1] == exp.t[-1]
    settings = dict(doc["settings"], qd_threshold=0.0)     # same processing, dead zone OFF
    obs = observe(held, robot, base_parameters(robot), settings)
    assert np.asarray(obs.row_mask).all() and obs.W.shape[0] == doc["validation"]["n_samples"]
    col = {n: k for k, n in enumerate(obs.names)}
    names = [p["name"] for p in doc["parameters"]]
    chi = np.array([p["value"] for p in doc["parameters"]])
    tau_hat = obs.W[:, :, [col[n] for n in names]] @ chi
    res = obs.tau - tau_hat
    return (float(np.linalg.norm(res) / np.linalg.norm(obs.tau)),
            np.linalg.norm(res, axis=0) / np.linalg.norm(obs.tau, axis=0))


def test_held_out_error_is_over_all_samples(tx40_run):
    doc, _ = tx40_run
    v = doc["validation"]
    rel, jrel = _independent_all_samples_error(doc)
    assert v["all_samples"]["rel_error"] == pytest.approx(rel, abs=1e-6)
    assert np.allclose(v["all_samples"]["joint_rel_error"], jrel, atol=1e-6)
    assert v["rel_error"] == v["all_samples"]["rel_error"]          # top level = all samples
    mov = v["moving_samples"]
    assert 0 < mov["fraction"] < 1 and mov["excluded_fraction"] == pytest.approx(1 - mov["fraction"])
    assert mov["rel_error"] < v["all_samples"]["rel_error"]       # the dead zone hides the hard rows
    print(f"\nTX40 held-out, all samples: {100 * rel:.2f} % (per joint "
          + ", ".join(f"{100 * x:.1f}" for x in jrel)
          + f" %); moving samples: {100 * mov['rel_error']:.2f} % with {100 * mov['excluded_fraction']:.1f} % excluded")


def test_verdict_flags_exactly_the_parameters_above_threshold(tx40_run):
    doc, html = tx40_run
    vd = doc["verdict"]
    thr = vd["rel_std_threshold_percent"]
    expected = [p["name"] for p in doc["parameters"] if not p["rel_std_percent"] <= thr]
    assert vd["not_identified"] == expected and expected
    assert [p["name"] for p in vd["parameters"] if p["flagged"]] == expected
    joints = vd["validation"]["joints"]
    jrel = doc["validation"]["all_samples"]["joint_rel_error"]
    assert vd["validation"]["flagged_joints"] == [j for j, e in zip(joints, jrel)
                                                   if e > vd["validation"]["joint_error_threshold"]]
    assert vd["validation"]["worst_joint"] == joints[int(np.argmax(jrel))]
    assert vd["validation"]["rel_error"] == doc["validation"]["all_samples"]["rel_error"]
    # the HTML shows the same verdict, first
    m = re.search(r'<section id="verdict"[^>]*data-flagged-parameters="([^"]*)" data-flagged-joints="([^"]*)"', html)
    assert m and m.group(1).split() == expected and m.group(2).split() == vd["validation"]["flagged_joints"]
    assert html.index('id="verdict"') < html.index('<section id="run"')
    print(f"\nTX40 verdict: {vd['status']}; not identified: {', '.join(expected)}; joints: "
          f"{', '.join(vd['validation']['flagged_joints'])}")


def test_units_and_plausibility_rules():
    from dynid.analysis.statistics.verdict import must_be_nonnegative, parameter_unit
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    assert [parameter_unit(n) for n in ("ZZ1R", "MX2R", "M3", "Ia4", "Fv1", "Fc2", "Off3", "Fvm6", "Fcm6")] == \
        ["kg m\u00b2", "kg m", "kg", "kg m\u00b2", "N m s/rad", "N m", "N m", "N m s/rad", "N m"]
    robot = load_robot("tx40")
    bp = base_parameters(robot)
    k = {n: i for i, n in enumerate(bp.names)}
    assert must_be_nonnegative(bp, robot.standard_names, k["ZZ2R"])        # ZZ2 + Ia2 + c M...
    assert not must_be_nonnegative(bp, robot.standard_names, k["XX2R"])    # XX2 - YY2 - ...
    assert must_be_nonnegative(bp, robot.standard_names, k["Fv1"])


def test_one_normality_computation():
    from dynid.analysis.statistics import noise, validation
    rng = np.random.default_rng(3)
    e = rng.laplace(size=(12_000, 2))
    a = validation.normality(e)
    b = noise.noise_pdf_tests(e).table
    for c in ("excess_kurtosis", "jarque_bera_p", "shapiro_p", "skew"):
        assert np.allclose(a[c].to_numpy(), b[c].to_numpy())
    assert a["shapiro_n"].iloc[0] <= 5000 and a["excess_kurtosis"].iloc[0] == pytest.approx(3.0, abs=0.5)
    # NaN rows (not fitted) are left out, never counted as zeros
    f = e.copy()
    f[::3] = np.nan
    assert validation.normality(f)["n"].iloc[0] == np.isfinite(f[:, 0]).sum()


def _fake_didim(k=4, n=2):
    from dynid.analysis.estimators.didim import DIDIMResult
    rng = np.random.default_rng(0)
    rows = []
    for it in range(1, k + 1):
        row = {"iteration": it, "step_length": 1.0, "rho_norm": 10.0 / it, "rel_change": np.nan if it == 1 else 0.1 / it,
               "output_error": 11.0 / it, "rel_error": 0.01 * it, "max_rel_param_change": 0.1 * it,
               "max_change_sigma": float(it), "substeps": 1}
        for j in range(n):
            row[f"track_rms_{j + 1}"] = 1e-3 * (10 * it + j)
        for j in range(n):
            row[f"kd_scale_{j + 1}"] = 1.0 + 0.1 * it + 0.01 * j
        rows.append(row)
    h = pd.DataFrame(rows)
    res = types.SimpleNamespace(
        history=h, iterations=k, converged=True, stop_reason="test", data_hash="", notices=[],
        q_sim=rng.normal(size=(50, n)), t_dec=np.arange(5.0), transient_samples=0,
        settings={"tol": 1e-3, "max_iter": 15, "initialisation": "x", "update_gains": True, "rate": 1000.0,
                  "feedforward": False, "v_s": 0.01, "saturate": False, "transient": 0.0, "nd": 10,
                  "f_decimation_cutoff": 40.0})
    return res, h, DIDIMResult


def _table_rows(html, key):
    block = html[html.index(f'id="{key}"'):]
    body = block[block.index("<tbody>"):block.index("</tbody>")]
    return [[re.sub(r"<[^>]+>", "", c).strip() for c in re.findall(r"<td[^>]*>(.*?)</td>", tr, re.S)]
            for tr in re.findall(r"<tr>(.*?)</tr>", body, re.S)]


def test_didim_step_index_is_the_same_everywhere(monkeypatch):
    from dynid.reports import didim_section as D
    from dynid.reports import tables as T
    from dynid.reports.html import render_sections
    res, h, DIDIMResult = _fake_didim()
    seen = {}
    orig = D.convergence_figure

    def spy(history, tol, **kw):
        seen["plot_steps"] = list(np.asarray(history["iteration"], dtype=int))
        seen["plot_rho"] = list(np.asarray(history["rho_norm"], dtype=float))
        return orig(history, tol, **kw)

    monkeypatch.setattr(D, "convergence_figure", spy)
    html = render_sections([D.convergence_section(res)], title="t")
    steps = list(h["iteration"])
    assert seen["plot_steps"] == steps == [1, 2, 3, 4]
    hist = _table_rows(html, "tab-didim-history")
    track = _table_rows(html, "tab-didim-tracking")
    kd = _table_rows(html, "tab-didim-kd-scale")
    for rows in (hist, track, kd):
        assert [int(r[0]) for r in rows] == steps              # one row per step, step 1 first, none empty
        assert all(all(c not in ("", T.MISSING) for c in r[1:]) for r in rows[1:])
    for r, (_, row) in zip(hist, h.iterrows()):
        assert r[2] == T.format_value(row["rho_norm"], "num").text
    for r, (_, row) in zip(track, h.iterrows()):
        assert r[1] == T.format_value(1e3 * row["track_rms_1"], "num").text
    for r, (_, row) in zip(kd, h.iterrows()):
        assert r[2] == T.format_value(row["kd_scale_2"], "num").text
    # the JSON and the terminal summary use the same column
    records = h.to_dict(orient="records")
    assert [int(r["iteration"]) for r in records] == steps
    cols = [c for c in ("iteration", "rho_norm") if c in h]
    text = h[cols].to_string(index=False)
    assert [int(line.split()[0]) for line in text.splitlines()[1:]] == steps


# ML's own fit takes about half a minute on this recording (a full SVD of its Jacobian per
# step): it runs with the slow tests; its identification is in tests/cli/test_cli.py
@pytest.fixture(scope="module")
def planar2_csv(tmp_path_factory):
    """One simulated planar2 recording (the same command for every method), written once."""
    from dynid.reports.cli import main
    csv = tmp_path_factory.mktemp("planar2") / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "10", "--out", str(csv), "--quiet"]) == 0
    return csv


@pytest.mark.parametrize("method", ["didim", "projection", pytest.param("ml", marks=pytest.mark.slow)])
def test_every_method_gives_a_verdict(tmp_path, planar2_csv, method):
    """DIDIM, the Projection Method and ML get the verdict too: JSON, summary and report's first block."""
    from dynid.reports.cli import main
    csv, js, html = planar2_csv, tmp_path / "out.json", tmp_path / "out.html"
    extra = ["--f0", "0.1"] if method == "ml" else []
    code = main(["identify", str(csv), "--robot", "planar2", "--method", method, *extra,
                 "--json", str(js), "--report", str(html), "--quiet"])
    assert code == 0
    doc = json.loads(js.read_text())
    v = doc["verdict"]
    assert v["status"] in ("identified", "identified with reservations", "not identified")
    assert "no validation data" in v["reasons"]                # no held-out data for these methods
    # the flagged parameters are exactly those above the threshold in the JSON's own table
    rel = {p["name"]: p["rel_std_percent"] for p in doc["parameters"]}
    above = sorted(n for n, r in rel.items() if not r <= v["rel_std_threshold_percent"])
    assert sorted(v["not_identified"]) == above
    assert [p["name"] for p in v["parameters"]] == list(rel)
    if method == "didim":                                       # its own residual is judged
        assert v["whiteness"]["test"] == "Ljung-Box" and len(v["whiteness"]["p_value"]) == 2
    else:
        assert v["whiteness"]["test"] is None
    text = html.read_text(encoding="utf-8")
    block = re.search(r'<section id="verdict"[^>]*data-status="([^"]*)"[^>]*data-flagged-parameters="([^"]*)"',
                      text)
    assert block and block.group(1) == v["status"]
    assert sorted(block.group(2).split()) == above
    assert block.start() == text.index("<section")              # the first section of the page


def test_a_check_is_one_function_in_the_list():
    """Adding a check is appending one function: its finding, reason and JSON block appear, the others stay."""
    from dynid.analysis.demo import demo_data
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.statistics.verdict import CHECKS, CheckOutcome, verdict

    robot, bp, _, ident, _ = demo_data(1, 5.0)
    res = identify_idim(ident, robot, bp=bp)
    base = verdict(res)

    def check_planted(x):
        return CheckOutcome(findings=[{"level": "warn", "key": "planted", "text": f"{x.n} joints seen."}],
                            reasons=["planted"], fields={"planted": {"n": x.n}})

    v = verdict(res, checks=[*CHECKS, check_planted])
    assert v.findings[:-1] == base.findings and v.findings[-1]["text"] == "6 joints seen."
    assert v.reasons == base.reasons + ["planted"] and v.status != "identified"
    d, d0 = v.to_dict(), base.to_dict()
    assert d.pop("planted") == {"n": 6} and "planted" not in d0
    d0.pop("findings"), d0.pop("reasons"), d0.pop("status"), d.pop("findings"), d.pop("reasons"), d.pop("status")
    assert d == d0
    # a failing check makes the model "not identified"
    v = verdict(res, checks=[*CHECKS, lambda x: CheckOutcome(fail=True)])
    assert v.status == "not identified" and not v.identified


def test_a_negative_inertia_within_its_uncertainty_is_not_impossible():
    """ZZ4R = -0.00066 ± 0.00043 (a zero within 1.53 σ) made DIDIM's verdict "not identified"; it is
    now named as zero within its uncertainty, and a negative beyond 1.96 σ still fails."""
    import types

    from dynid.analysis.statistics.verdict import check_plausibility
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    robot = load_robot("tx40")
    bp = base_parameters(robot)

    def run(value, std):
        p = {"name": "ZZ4R", "value": value, "std": std, "unit": "kg m\u00b2"}
        return check_plausibility(types.SimpleNamespace(base=bp, robot=robot, params=[p]))
    near = run(-0.00066, 0.00043)
    assert not near.fail and near.findings[0]["level"] == "info" and "1.5 σ" in near.findings[0]["text"]
    far = run(-0.0066, 0.00043)
    assert far.fail and far.fields["implausible"][0]["name"] == "ZZ4R"


def test_a_method_that_did_not_converge_is_not_identified():
    """A DIDIM run that stopped before its criterion printed "[ok]" lines and "identified" above
    its own "DID NOT CONVERGE": the verdict now says so first, and fails."""
    import types

    from dynid.analysis.statistics.verdict import CHECKS, check_convergence
    assert CHECKS[0] is check_convergence
    stopped = types.SimpleNamespace(result=types.SimpleNamespace(
        converged=False, method="DIDIM", stop_reason="max_iter = 2 steps without meeting the criterion."))
    out = check_convergence(stopped)
    assert out.fail and out.findings[0]["level"] == "bad"
    assert "DIDIM did NOT converge (max_iter = 2 steps without meeting the criterion)" in out.findings[0]["text"]
    for ok in (types.SimpleNamespace(converged=True, method="DIDIM"), types.SimpleNamespace(method="IDIM")):
        out = check_convergence(types.SimpleNamespace(result=ok))
        assert not out.fail and not out.findings and not out.reasons


def test_joint_labels_count_from_one_beside_the_robot_files_names():
    """The LWR4+ URDF names its joints from 0: the verdict said "lwr_5_joint 30.2 %" for the
    validation table's joint 6. Labels are j1..jn, with the file's name beside when it differs."""
    import types

    from dynid.analysis.statistics.verdict import _joint_names
    lwr = types.SimpleNamespace(joint_names=[f"lwr_{k}_joint" for k in range(7)])
    assert _joint_names(lwr, 7)[5] == "j6 (lwr_5_joint)"
    assert _joint_names(types.SimpleNamespace(joint_names=["j1", "Joint_2"]), 3) == ["j1", "j2", "j3"]
    assert _joint_names(None, 2) == ["j1", "j2"]


def test_a_maximum_likelihood_that_did_not_converge_gets_its_own_advice():
    """ML has no step limit the user can raise (`--max-iter` is DIDIM's): the advice is its own, and
    the optimiser's message (a notice) is the reason."""
    import types

    from dynid.analysis.statistics.verdict import check_convergence
    ml = types.SimpleNamespace(converged=False, method="ML-EIV",
                               notices=["least_squares stopped without convergence: The maximum number of "
                                        "function evaluations is exceeded."])
    text = check_convergence(types.SimpleNamespace(result=ml)).findings[0]["text"]
    assert "(The maximum number of function evaluations is exceeded)" in text
    assert "--max-iter" not in text and "--f0" in text


def test_whiteness_line_names_the_joints_the_diagnosis_flags(monkeypatch):
    """The verdict said "the diagnosis found no missing effect" while the same diagnosis flagged
    joints 6 and 7 as holding torque the model lacks (LWR4+ recording 2 against 3)."""
    from types import SimpleNamespace as NS

    import pandas as pd

    from dynid.analysis.statistics import verdict as V
    monkeypatch.setattr(V, "_sigma_option", lambda x: "bootstrap")
    lb = pd.DataFrame({"lag": [10, 10], "statistic": [50.0, 60.0], "p_value": [1e-6, 1e-7]})

    def text(selected, unexplained):
        x = NS(names=["j1", "j2"], n=2, alpha=0.05, residuals=NS(ljung_box=lb),
               diagnosis=NS(selected=selected, unexplained=unexplained))
        return V._whiteness(x)
    flagged = text([], [NS(joint=6), NS(joint=7)])
    assert "found no missing effect" not in flagged["text"] and "flag joints 6, 7" in flagged["text"]
    assert flagged["diagnosis_flagged_joints"] == [6, 7]
    assert "found no missing effect" in text([], [])["text"]


def test_the_verdict_says_which_model_it_judges_beside_the_physical_and_effects_fits():
    """With --physical and --effects the verdict still judges the unconstrained rigid body, and one
    line says so and quotes the other fits' own errors (real TX40, last 3 s held out)."""
    pytest.importorskip("cvxpy")
    import dynid
    from dynid.analysis.statistics.verdict import verdict

    # 20 bootstrap refits of the PC fit, not 100: nothing here reads the refits (the PC estimate, its
    # chi2 and p do not depend on them), and from 20 up its sigma and intervals take the same form
    r = dynid.run(TX40, "tx40", holdout=3, effects="spring:all", physical=True, bootstrap=20)
    lines = [f for f in r.verdict.findings if f["key"] == "other_fits"]
    assert len(lines) == 1 and lines[0]["level"] == "info"
    text = lines[0]["text"]
    assert text.startswith("The verdict judges the unconstrained rigid-body model (its essential parameters)")
    assert f"{100 * r.validation.rel_error:.2f} % held out" in text
    assert f"{100 * r.effects.validation['rel_error_wls']:.2f} %" in text
    assert f"{100 * r.effects.validation['rel_error_pc']:.2f} %" in text
    assert r.physical.verdict_line() in text
    block = r.verdict.to_dict()["other_fits"]
    assert block["effects"]["held_out_rel_error_wls"] == r.effects.validation["rel_error_wls"]
    assert block["physical"]["p_value"] == r.physical.p_value
    plain = verdict(r.result, r.validation, robot=r.robot)
    assert all(f["key"] != "other_fits" for f in plain.findings) and "other_fits" not in plain.to_dict()
    assert plain.status == r.verdict.status
    # the report's PC section says its WLS is the fit with the effects, and gives units
    from dynid.reports.html import render_sections
    from dynid.reports.render import idim_extra_sections
    html = render_sections(idim_extra_sections(r), title="x")
    assert "The unconstrained WLS here is that of the rigid body with the effects spring:all" in html
    assert "Base parameters: unconstrained WLS and PC-WLS (both with the effects spring:all)" in html
    assert "kg m\u00b2" in html.split('id="tab-physical-parameters"')[1].split("</table>")[0]
    frame = r.verdict.to_frame()        # the CSV's columns, as every result's parameter table
    assert frame.index.name == "parameter" and list(frame.columns[:4]) == ["value", "std", "rel_std_percent", "unit"]


def test_the_harmonics_bic_chose_are_no_warning_but_a_misfit_is():
    """ML's notice of the harmonic count BIC chose ("latent trajectory: K = 48 harmonics ...") made
    every ML verdict with automatic harmonics say "the motion is not periodic"; only the misfit
    notices of maximum_likelihood._check_periodic do."""
    import types

    from dynid.analysis.statistics.verdict import check_data_quality
    reason = "the motion is not periodic at maximum likelihood's f0"

    def reasons(*notices):
        x = types.SimpleNamespace(result=types.SimpleNamespace(notices=list(notices)), validation=None,
                                  cond_threshold=1e3)
        return check_data_quality(x).reasons
    import inspect

    from dynid.analysis.estimators import maximum_likelihood as ml
    # the phrases below are the module's own (a rewording there must show here)
    misfit = inspect.getsource(ml._check_periodic)
    assert "misses part of the motion" in misfit and "the motion is not periodic" in misfit
    assert 'f"latent trajectory: K = {K} harmonics (BIC' in inspect.getsource(ml._harmonics)
    info = "latent trajectory: K = 48 harmonics (BIC on q; per joint [48, 44])"
    assert reason not in reasons(info)
    assert reason in reasons(info, "5 harmonics of f0 = 0.5 Hz leave 12 % of joint 2's motion unexplained (RMS "
                             "about its mean): the latent trajectory (eq. (17)) misses part of the motion, which "
                             "biases the estimates; give more harmonics")
    assert reason in reasons("the latent trajectory (5 harmonics of f0 = 0.5 Hz) leaves 110 times the noise of "
                             "joint 1's q (from its second differences): the motion is not periodic at the noise "
                             "level (a start-up transient, a drift), and maximum likelihood reads ...")
