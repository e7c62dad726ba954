"""dynid identify --physical / --mjcf: the JSON block, the report section, the files, bad input."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from dynid.reports.cli import main


@pytest.fixture(scope="module")
def planar2_csv(tmp_path_factory):
    csv = tmp_path_factory.mktemp("sim") / "run.csv"
    assert main(["simulate", "--robot", "planar2", "--duration", "8", "--out", str(csv), "--quiet"]) == 0
    return csv


def test_identify_physical_json_report_urdf_mjcf(planar2_csv, tmp_path):
    mujoco = pytest.importorskip("mujoco")
    js, html, urdf, mjcf = (tmp_path / n for n in ("p.json", "p.html", "p.urdf", "p.xml"))
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--physical", "--bootstrap", "20",
                 "--prior", "apriori", "--prior-weight", "0.01", "--json", str(js), "--report", str(html),
                 "--urdf", str(urdf), "--mjcf", str(mjcf), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    ph = doc["physical"]
    assert ph["consistent"] is True and isinstance(ph["active"], list)
    assert ph["chi2"] >= 0 and 0 <= ph["p_value"] <= 1 and ph["prior_weight"] == 0.01
    # planar2.toml's a-priori values are physical: on its simulated data the constraint costs little
    assert ph["p_value"] > 0.01
    assert doc["urdf_export"]["which"] == "physical" and doc["urdf_export"]["consistent"] is True
    text = html.read_text()
    assert 'id="physical"' in text and "fig-physical-moments" in text
    model = mujoco.MjModel.from_xml_path(str(mjcf))
    assert model.nv == 2 and "frictionloss" in mjcf.read_text()
    assert "<robot" in urdf.read_text()


def test_physical_options_are_refused_without_physical_or_with_another_method(planar2_csv, capsys):
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--prior", "apriori", "--quiet"]) == 2
    assert "--physical" in capsys.readouterr().err
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--method", "projection",
                 "--physical", "--quiet"]) == 2
    assert "--physical" in capsys.readouterr().err


def test_mjcf_shares_the_same_path_checks(planar2_csv, tmp_path, capsys):
    same = tmp_path / "x.out"
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--json", str(same),
                 "--mjcf", str(same), "--quiet"]) == 2
    assert "--mjcf" in capsys.readouterr().err


def test_physical_without_cvxpy_says_how_to_install(planar2_csv, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cvxpy", None)
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--physical", "--quiet"]) == 2
    # the packages themselves: dynid is installed from its source folder, not from an index
    assert 'pip install "cvxpy>=' in capsys.readouterr().err


def test_urdf_without_cvxpy_says_it_used_the_local_search(planar2_csv, tmp_path, monkeypatch, capsys):
    """--urdf runs without the physical extra, and the terminal says how its set was found."""
    monkeypatch.setitem(sys.modules, "cvxpy", None)
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--urdf", str(tmp_path / "p.urdf")]) == 0
    err = capsys.readouterr().err
    assert "URDF: " in err and "local log-Cholesky search was used instead of the SDP" in err
    assert "global search of --urdf" in err and (tmp_path / "p.urdf").exists()


def _pseudo_inertia_min_eig(std, link):
    """Smallest eigenvalue of link's pseudo-inertia [[tr(I)/2 - I, h], [h^T, m]] from the JSON's
    standard parameters (Wensing, Kim & Slotine 2017, eq. (7)), computed here, not by dynid."""
    import numpy as np
    g = {k: std[f"{k}{link}"] for k in ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")}
    inertia = np.array([[g["XX"], g["XY"], g["XZ"]], [g["XY"], g["YY"], g["YZ"]], [g["XZ"], g["YZ"], g["ZZ"]]])
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = [g["MX"], g["MY"], g["MZ"]]
    J[3, 3] = g["M"]
    return np.linalg.eigvalsh(J)[0]


def test_identify_didim_physical_is_pc_didim(planar2_csv, tmp_path):
    """dynid identify --method didim --physical: every Gauss-Newton step a PC-WLS; the JSON's
    block "physical" holds a standard set whose pseudo-inertias are PSD, Fv, Fc >= 0, and base
    parameters that are that set's (P chi); the report has the PC section."""
    js, html = tmp_path / "d.json", tmp_path / "d.html"
    code = main(["identify", str(planar2_csv), "--robot", "planar2", "--method", "didim", "--physical",
                 "--max-iter", "3", "--json", str(js), "--report", str(html), "--quiet"])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["converged"] else 3)
    ph = doc["physical"]
    assert doc["method"] == "DIDIM" and ph["consistent"] is True
    std = {p["name"]: p["value"] for p in ph["standard_parameters"]}
    for link in (1, 2):
        assert _pseudo_inertia_min_eig(std, link) >= -1e-9
        assert std[f"Fv{link}"] >= 0 and std[f"Fc{link}"] >= 0
    # simulated from planar2's physical a-priori model: the constraint costs little, and the PC
    # base parameters stay within 3 sigma of the last step's unconstrained WLS
    assert ph["p_value"] > 0.01
    for p in ph["parameters"]:
        sd = next(q["std"] for q in doc["wls"]["parameters"] if q["name"] == p["name"])
        assert abs(p["value"] - p["wls"]) <= 3 * sd + 1e-12
    assert 'id="physical"' in html.read_text()
    # every value with its unit and %sigma, as every result's records (they had neither)
    assert all(p["unit"] and "rel_std_percent" in p for p in ph["parameters"])
    assert all(p["unit"] for p in ph["standard_parameters"])
    # its errors on the last step's system, as IDIM's PC fit gives them (they were NaN)
    assert 0 < ph["rel_error"] < 0.5 and 0 < ph["wls_rel_error"] < 0.5
    # in Python the fit is `run.physical` too, as docs/formats.md says (it was None for DIDIM)
    import dynid
    run = dynid.run(str(planar2_csv), "planar2", method="didim", physical=True, max_iter=2, write=False)
    assert run.physical is run.result.physical and run.physical.to_frame().shape[0] == len(ph["parameters"])


def test_didim_physical_takes_the_prior_and_the_bootstrap(planar2_csv, tmp_path):
    """--method didim --physical --prior apriori --prior-weight W --bootstrap N reach the PC fit
    (they were refused before; the API test of the same is in tests/analysis/estimators/test_physical.py)."""
    js = tmp_path / "d.json"
    code = main(["identify", str(planar2_csv), "--robot", "planar2", "--method", "didim", "--physical",
                 "--prior", "apriori", "--prior-weight", "1e6", "--bootstrap", "25", "--max-iter", "1",
                 "--v-s", "0.01", "--json", str(js), "--quiet"])
    assert code in (0, 3)
    ph = json.loads(js.read_text())["physical"]
    assert ph["prior"] == "apriori" and ph["prior_weight"] == 1e6 and ph["n_boot"] == 25
    assert ph["consistent"] is True


def test_identify_physical_essential_set(planar2_csv, tmp_path):
    """--physical --physical-set essential: the block "physical" is over the essential names
    (those of the unconstrained essential model), its standard set consistent."""
    js, urdf = tmp_path / "e.json", tmp_path / "e.urdf"
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--physical", "--physical-set",
                 "essential", "--bootstrap", "0", "--json", str(js), "--urdf", str(urdf), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    ph = doc["physical"]
    assert ph["model"] == "essential" and ph["consistent"] is True
    assert [p["name"] for p in ph["parameters"]] == [p["name"] for p in doc["parameters"]]
    std = {p["name"]: p["value"] for p in ph["standard_parameters"]}
    for link in (1, 2):
        assert _pseudo_inertia_min_eig(std, link) >= -1e-9
    assert "<robot" in urdf.read_text()


KUKA = Path(__file__).resolve().parents[2] / "examples" / "kuka_lwr4"


@pytest.mark.parametrize("spec, words", [
    ("spring:3", "joint 3 outside 1..2"), ("spring:x", "whole number"),
    ("position_ripple:1", "needs an order"), ("position_ripple:1:0", "order must be 1 or more"),
    ("spring:1:2", "only position_ripple takes an order"), ("stribeck:1", "expected name:joint"),
    ("spring:1,spring:all", "given twice"), (",", "names no effect"),
    ("offset:1", "Off1 already in the base model"), ("asymmetric_coulomb:1", "cannot be identified")])
def test_identify_effects_bad_text_is_refused(planar2_csv, capsys, spec, words):
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--effects", spec, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


@pytest.mark.parametrize("extra, words", [
    (["--method", "didim"], "--effects"), (["--urdf", "x.urdf"], "--mjcf PATH writes the rigid body with its springs"),
    (["--physical", "--physical-set", "essential"], "--physical-set"),
    (["--mjcf", "x.xml"], "add --physical")])
def test_identify_effects_refuses_options_it_does_not_combine_with(planar2_csv, capsys, tmp_path, extra, words):
    extra = [str(tmp_path / a) if a.endswith((".urdf", ".xml")) else a for a in extra]
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--effects", "spring:all", *extra,
                 "--quiet"]) == 2
    assert words in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_identify_mjcf_refuses_effects_it_has_no_field_for(planar2_csv, capsys, tmp_path):
    xml = tmp_path / "m.xml"
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--physical", "--effects",
                 "spring:all,position_ripple:2:1", "--mjcf", str(xml), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "MJCF has no field for position_ripple on joint 2" in err and "Traceback" not in err
    assert not xml.exists()


def test_identify_mjcf_writes_the_springs(planar2_csv, tmp_path):
    """--physical --effects spring:all --mjcf: the PC standard set of the effects model and its
    springs as joint stiffness (springref 0), listed in the JSON and the report."""
    mujoco = pytest.importorskip("mujoco")
    js, html, xml = tmp_path / "s.json", tmp_path / "s.html", tmp_path / "s.xml"
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--physical", "--bootstrap", "0",
                 "--effects", "spring:all", "--mjcf", str(xml), "--json", str(js), "--report", str(html),
                 "--quiet"]) == 0
    doc = json.loads(js.read_text())
    pc = {p["name"]: p["pc"] for p in doc["effects"]["parameters"]}
    exp = doc["urdf_export"]
    assert exp["which"] == "physical" and exp["mjcf_springs"] == pc
    assert any("joint stiffness" in n for n in exp["notices"])
    assert exp["prediction"]["rel_error_chosen_set_with_springs"] == doc["effects"]["rel_error_pc"]
    # the rigid body written is the PC fit of the effects model, not a separate consistent set
    std = {p["name"]: p["value"] for p in doc["physical"]["standard_parameters"]}
    model = mujoco.MjModel.from_xml_path(str(xml))
    np.testing.assert_array_equal(model.jnt_stiffness, [pc["Ks1"], pc["Ks2"]])
    np.testing.assert_array_equal(model.qpos_spring, 0.0)
    np.testing.assert_allclose(model.body_mass[1:], [std["M1"], std["M2"]], rtol=1e-12)
    assert "The MJCF holds the linear springs" in html.read_text()


def test_identify_effects_without_physical_fits_the_unconstrained_model(planar2_csv, tmp_path):
    """--effects alone: the unconstrained WLS with the springs' columns; the simulated planar2 has
    no spring, so each Ks is within 4 sigma of 0; no PC values and no "physical" block."""
    js = tmp_path / "e.json"
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--effects", "spring:all",
                 "--holdout", "2", "--json", str(js), "--quiet"]) == 0
    doc = json.loads(js.read_text())
    assert "physical" not in doc
    eff = doc["effects"]
    assert eff["spec"] == "spring:all" and [p["name"] for p in eff["parameters"]] == ["Ks1", "Ks2"]
    for p in eff["parameters"]:
        assert p["effect"] == "spring" and "pc" not in p and p["wls_std"] > 0
        assert abs(p["wls"]) <= 4 * p["wls_std"]
    v = eff["validation"]
    assert v["samples"] == "all" and 0 < v["rel_error_wls"] < 0.2 and "rel_error_pc" not in v


def _kuka_json(tmp_path, *extra):
    js = tmp_path / "k.json"
    assert main(["identify", str(KUKA / "recording_1.toml"), "--robot", "kuka_lwr4", "--validation",
                 str(KUKA / "recording_2.toml"), "--physical", "--bootstrap", "0", *extra,
                 "--json", str(js), "--quiet"]) == 0
    return json.loads(js.read_text())


def test_lwr4_springs_from_the_cli_close_the_held_out_gap(tmp_path):
    """FloBaRoID's split 1 -> 2 with a spring on every joint: the JSON's "physical" block carries
    the effects (values, sigma), every link is consistent and PC is within the issue's 0.2 points
    of the unconstrained fit of the same model (measured +0.030; examples/kuka_lwr4/README.md)."""
    doc = _kuka_json(tmp_path, "--effects", "spring:all")
    ph, eff = doc["physical"], doc["effects"]
    assert ph["effects"] == eff and ph["consistent"] is True
    assert [p["name"] for p in eff["parameters"]] == [f"Ks{j}" for j in range(1, 8)]
    assert all(p["wls_std"] > 0 and p["pc_std"] > 0 for p in eff["parameters"])
    v = eff["validation"]
    assert ph["validation"] == v and v["n_samples"] > 100
    assert abs(v["gap_points"] - 100 * (v["rel_error_pc"] - v["rel_error_wls"])) < 1e-9
    assert v["gap_points"] < 0.2
    # the base parameters of the same PC fit: Ia3, which the rigid-body-only fit wants negative
    assert {p["name"] for p in ph["parameters"]} >= {"ZZ1R", "Ia3"}


def test_lwr4_cli_physical_without_effects_has_the_gap(tmp_path):
    """The same split without effects: PC costs more than 0.2 points held out (+0.358 measured),
    which is what the springs remove."""
    doc = _kuka_json(tmp_path)
    v = doc["physical"]["validation"]
    assert "effects" not in doc and doc["physical"]["consistent"] is True
    assert v["gap_points"] > 0.2
