"""A prismatic joint's per-joint parameters are in N and m, not N m and rad
(dynid.analysis.units.parameter_unit with the robot's prismatic joints)."""
from pathlib import Path

import pytest

import dynid
from dynid.analysis.units import parameter_unit, prismatic_joints

ROBOT = Path(__file__).resolve().parents[1] / "data" / "prismatic" / "rpr.toml"


def test_units_by_joint_type():
    assert parameter_unit("Fv2", {2}) == "N s/m" and parameter_unit("Fv2") == "N m s/rad"
    assert parameter_unit("Fc-2", {2}) == "N" and parameter_unit("Off2", {2}) == "N"
    assert parameter_unit("Ia2", {2}) == "kg" and parameter_unit("Ia1", {2}) == "kg m\u00b2"
    assert parameter_unit("M2R", {2}) == "kg" and parameter_unit("Kp2", {2}) == "N/m"


@pytest.fixture(scope="module")
def identified():
    robot = dynid.load_robot(ROBOT)
    assert prismatic_joints(robot) == {2}
    rec = dynid.simulate(robot, 6.0, seed=2)
    train, held = dynid.holdout_split(rec.experiment, 2.0)
    return robot, dynid.identify(train, robot), held


def test_identified_parameters_carry_the_joint_units(identified):
    robot, r, held = identified
    assert r["Fv2"].unit == "N s/m" and r["Fc2"].unit == "N" and r["Fv1"].unit == "N m s/rad"
    assert r.wls["Ia2"].unit == "kg"
    table = {line.split()[0]: line.split()[1:3] for line in r.summary().splitlines() if line[:3] in ("Fv1", "Fv2")}
    assert table["Fv2"][:2] == ["N", "s/m"] and table["Fv1"] == ["N", "m"]
    assert any("prismatic" in n for n in r.notices)
    units = {p["name"]: p["unit"] for p in dynid.verdict(r, dynid.validate(r, held)).to_dict()["parameters"]}
    assert units["Fc2"] == "N" and units["Fc1"] == "N m"
    assert dynid.validate(r, held).to_frame()["unit"].tolist() == ["N m", "N", "N m"]   # the held-out RMS


def test_revolute_robot_unchanged():
    assert prismatic_joints(dynid.load_robot("tx40")) == frozenset()


@pytest.mark.parametrize("method", ["idim", "didim", "projection"])
def test_every_export_of_every_method_carries_the_joint_units(identified, method):
    """JSON records and the CSV table (what --csv writes) of each method, and the PC fit's JSON."""
    robot, r, held = identified
    train = dynid.holdout_split(dynid.simulate(robot, 6.0, seed=2).experiment, 2.0)[0]
    res = r if method == "idim" else dynid.identify(train, robot, method=method)
    model = getattr(res, "model", None) or res
    frame = model.to_frame() if method == "didim" else res.to_frame()
    assert frame.loc["Fv2", "unit"] == "N s/m" and frame.loc["Fv1", "unit"] == "N m s/rad"
    units = {p["name"]: p["unit"] for p in res.to_dict()["parameters"]}
    assert units["Fv2"] == "N s/m"


def test_the_physical_fit_json_carries_the_joint_units(identified):
    pytest.importorskip("cvxpy")
    robot, r, held = identified
    pc = dynid.identify(dynid.holdout_split(dynid.simulate(robot, 6.0, seed=2).experiment, 2.0)[0], robot,
                        physical=True)
    units = {p["name"]: p["unit"] for p in pc.to_dict()["parameters"]}
    assert units["Fv2"] == "N s/m" and pc.to_frame().loc["Fv2", "unit"] == "N s/m"


def test_report_csv_downloads_say_the_joint_units(identified):
    """The HTML report's CSV downloads name their units; on a robot with a prismatic joint the
    joint columns read "N m or N" (the page's note says which rows), and the parameter tables
    give each parameter its own unit."""
    import io
    import re
    import urllib.parse

    import pandas as pd

    from dynid.reports.html import render_idim_report
    robot, r, held = identified
    html = render_idim_report(r, robot, None, dynid.validate(r, held))
    csvs = {m.group(1): urllib.parse.unquote(m.group(2).split(",", 1)[1])
            for m in re.finditer(r'<div class="table-block" id="([^"]+)">.*?<a class="csv" href="([^"]+)"',
                                 html, re.S)}
    errors = pd.read_csv(io.StringIO(csvs["tab-torque-errors"]), index_col=0)
    assert "rms [N m or N]" in errors.columns
    joints = pd.read_csv(io.StringIO(csvs["tab-joints"]), index_col=0)
    assert {"q_min [rad or m]", "tau_max [N m or N]"} <= set(joints.columns)
    table2 = pd.read_csv(io.StringIO(csvs["tab-table2"]), index_col=0)
    assert table2.loc["Fv2", "unit"] == "N s/m" and table2.loc["Fv1", "unit"] == "N m s/rad"


def test_didim_report_tables_of_a_robot_with_a_prismatic_joint(identified):
    """The DIDIM section's Table 2 passed `True` where the prismatic joints' numbers go, and
    rendering it on a robot with a prismatic joint raised TypeError."""
    import io
    import re
    import urllib.parse

    import pandas as pd

    from dynid.reports.didim_section import didim_sections
    from dynid.reports.html import render_sections
    robot, r, held = identified
    train = dynid.holdout_split(dynid.simulate(robot, 6.0, seed=2).experiment, 2.0)[0]
    html = render_sections(didim_sections(dynid.identify(train, robot, method="didim")), title="t")
    uri = re.search(r'<div class="table-block" id="tab-didim-table2">.*?<a class="csv" href="([^"]+)"', html, re.S)
    table2 = pd.read_csv(io.StringIO(urllib.parse.unquote(uri.group(1).split(",", 1)[1])), index_col=0)
    assert table2.loc["Fv2", "unit"] == "N s/m" and table2.loc["Fv1", "unit"] == "N m s/rad"
    # the history CSV's tracking errors are in m or rad (the page shows mrad): the header says so
    uri = re.search(r'<div class="table-block" id="tab-didim-history">.*?<a class="csv" href="([^"]+)"', html, re.S)
    history = pd.read_csv(io.StringIO(urllib.parse.unquote(uri.group(1).split(",", 1)[1])), index_col=0)
    assert "track_rms_2 [m or rad]" in history.columns and "rho_norm [N m]" in history.columns
