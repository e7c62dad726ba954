"""The HTML reports of the Projection Method and ML label their tables as IDIM's does: the ML table's
headers were the raw field names (`rel_std_percent`, `ls_start`), and the verdict's %σ chart and table
said "essential parameters" where PM and ML judge every base parameter."""
from __future__ import annotations

import bias_scenarios as bs
import pytest

import dynid
from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model
from dynid.reports.projection_section import ml_section
from dynid.reports.render import identification_html


def test_ml_table_headers_are_the_idim_reports():
    robot, bp, _, _ = bs.pendulum()
    t, q, tau = bs.periodic_motion(fs=200.0)
    ml = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0, n_harmonics=5)
    columns = ml_section(ml).tables[0].columns
    assert columns == ["parameter", "ML \u03c7\u0302", "\u03c3", "%\u03c3", "LS start \u03c7\u0302", "unit"]


@pytest.fixture(scope="module")
def recording():
    return dynid.simulate("planar2", duration=4.0, seed=1, f0=0.5, harmonics=3).experiment


def test_the_verdict_of_pm_names_the_base_parameters(recording):
    html = identification_html(dynid.run(recording, "planar2", method="projection"))
    assert "of the base parameters" in html and "Base parameters: value, %\u03c3" in html
    assert "of the essential parameters" not in html and "Essential parameters: value" not in html
