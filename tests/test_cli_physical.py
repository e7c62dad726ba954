"""dynid identify --physical / --mjcf: the JSON block, the report section, the files, bad input."""
import json
import sys

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
    assert 'pip install "dynid[physical]"' in capsys.readouterr().err


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


def test_didim_physical_refuses_the_prior(planar2_csv, capsys):
    assert main(["identify", str(planar2_csv), "--robot", "planar2", "--method", "didim", "--physical",
                 "--prior", "apriori", "--quiet"]) == 2
    assert "PC-DIDIM" in capsys.readouterr().err


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
