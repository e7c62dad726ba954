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
