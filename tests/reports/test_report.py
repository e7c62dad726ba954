"""Tests of the HTML report framework (dynid.reports.html, dynid.reports.figures, dynid.reports.tables, dynid.reports.paper)."""
from __future__ import annotations

import dataclasses
import io
import math
import re
import urllib.parse
from html import unescape as html_unescape
from pathlib import Path

import jinja2
import numpy as np
import pandas as pd
import pytest
from markupsafe import Markup

from dynid import provenance
from dynid.analysis.data.experiment import Experiment
from dynid.analysis.estimators.idim import identify_idim
from dynid.analysis.statistics.validation import validate
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.regressor import regressor
from dynid.dynamics.robot_file import load_robot
from dynid.reports import figures as F
from dynid.reports import tables as T
from dynid.reports.html import (
    SECTION_IDS,
    Section,
    environment,
    para,
    render_idim_report,
    render_sections,
    write_report,
)
from dynid.reports.paper import DIDIM_TX40_TABLE2, reference_for

EVIL_ROBOT = "<script>alert(1)</script>"
EVIL_JOINT = '"><img src=x onerror=alert(1)>'
EVIL_SOURCE = "runs/<b>bold</b> & 'quoted'.csv"
from conftest import SHARED_DATA

TX40_DATA = (Path(__file__).resolve().parents[2] / "examples" / "staubli_tx40"   # the shipped copy
             if (Path(__file__).resolve().parents[2] / "examples" / "staubli_tx40" / "curr_data.csv").exists()
             else SHARED_DATA / "staubli-tx40-figaroh")

TITLES = {"run": "Run and data", "model": "Model", "base-parameters": "Base parameters",
          "table2": "Essential parameters", "essential-path": "Elimination path",
          "torques": "Measured vs estimated torque", "validation": "Validation"}
SECTIONS_WITH_FIGURES = ("table2", "essential-path", "torques", "validation")


# ------------------------------------------------------------------ fixtures
def _planar_experiment(robot, seed, duration=8.0, fs=1000.0, source="synthetic.csv"):
    """A noisy recording of the planar 2R arm on a sum of sines (exact inverse dynamics)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration * fs)) / fs
    n = robot.n_joints
    q = np.zeros((t.size, n)); qd = np.zeros_like(q); qdd = np.zeros_like(q)
    for j in range(n):
        for k in range(1, 5):
            a, w, ph = rng.uniform(0.2, 0.5) / k, 2 * np.pi * 0.25 * k * (1 + 0.1 * j), rng.uniform(0, 6.3)
            q[:, j] += a * np.sin(w * t + ph)
            qd[:, j] += a * w * np.cos(w * t + ph)
            qdd[:, j] -= a * w * w * np.sin(w * t + ph)
    chi = robot.standard_vector(dict(robot.apriori))
    tau = regressor(robot, q, qd, qdd) @ chi
    tau += 0.02 * rng.standard_normal(tau.shape)
    q_meas = q + 1e-5 * rng.standard_normal(q.shape)
    return Experiment(t=t, q=q_meas, tau=tau, fs=fs, source=source, name="sines")


@pytest.fixture(scope="module")
def planar():
    robot = load_robot("planar2")
    bp = base_parameters(robot)
    ident = _planar_experiment(robot, 1)
    valid = _planar_experiment(robot, 2, duration=4.0)
    res = identify_idim(ident, robot, bp=bp)
    val = validate(res, valid, robot)
    return robot, ident, res, val


@pytest.fixture(scope="module")
def planar_html(planar):
    robot, ident, res, val = planar
    return render_idim_report(res, robot, ident, val)


@pytest.fixture(scope="module")
def evil():
    """The planar arm under a hostile robot name, joint name and file name."""
    robot = load_robot("planar2")
    robot = dataclasses.replace(
        robot, name=EVIL_ROBOT, description=EVIL_ROBOT,
        joints=[dataclasses.replace(robot.joints[0], name=EVIL_JOINT), robot.joints[1]],
        provenance={EVIL_JOINT: EVIL_ROBOT})
    ident = _planar_experiment(robot, 3, duration=6.0, source=EVIL_SOURCE)
    valid = _planar_experiment(robot, 4, duration=4.0, source=EVIL_SOURCE)
    res = identify_idim(ident, robot)
    val = validate(res, valid, robot)
    return robot, ident, res, val


def _section(html, sid):
    m = re.search(rf'<section id="{re.escape(sid)}">(.*?)</section>', html, re.S)
    assert m, f"section {sid!r} missing"
    return m.group(1)


def _csv_links(html):
    """{table id: decoded CSV text} of every table block."""
    out = {}
    for m in re.finditer(r'<div class="table-block" id="([^"]+)">.*?<a class="csv" href="([^"]+)"',
                         html, re.S):
        uri = m.group(2)
        prefix = "data:text/csv;charset=utf-8,"
        assert uri.startswith(prefix)
        out[m.group(1)] = urllib.parse.unquote(uri[len(prefix):], encoding="utf-8")
    return out


# ------------------------------------------------------------------ the page
def test_one_self_contained_file(planar_html):
    html = planar_html
    assert html.startswith("<!DOCTYPE html>")
    assert html.count("<html") == 1 and html.rstrip().endswith("</html>")
    for bad in ("http://", "https://", 'src="http', "<link", "<script", "@import", "url(http",
                "<iframe", "<object", "<embed"):
        assert bad not in html, bad
    # inline CSS with a print stylesheet; SVGs inline without namespaces or XML prologues
    assert "<style>" in html and "@media print" in html
    assert "<?xml" not in html and "<!DOCTYPE svg" not in html and "<metadata" not in html


def test_every_section_has_id_heading_nav_and_figure(planar_html):
    html = planar_html
    for sid in SECTION_IDS:
        body = _section(html, sid)
        assert re.search(rf"<h2>.*{re.escape(TITLES[sid])}</h2>", body), sid
        assert f'href="#{sid}"' in html.split("<main")[0]  # navigation bar
        if sid in SECTIONS_WITH_FIGURES:
            assert "<svg" in body or "data:image/png;base64" in body, sid
            assert "<figcaption>" in body
    # ids are unique in the whole page (figure-internal SVG ids are prefixed)
    ids = re.findall(r'\bid="([^"]+)"', html)
    assert len(ids) == len(set(ids))
    # every table can be downloaded
    assert html.count('class="table-block"') == html.count('class="csv"')


def test_the_base_section_says_which_sigma_it_shows(planar, planar_html):
    """The IDIM report named the covariance in the verdict only; the essential σ's bias rule nowhere."""
    robot, ident, res, val = planar
    assert f"Uncertainty (\u03c3): {res.uncertainty_text}" in html_unescape(planar_html)
    assert res.uncertainty_text in res.summary()


def test_csv_downloads_decode_to_the_tables(planar, planar_html):
    robot, ident, res, val = planar
    csvs = _csv_links(planar_html)
    assert {"tab-settings", "tab-versions", "tab-dh", "tab-joints", "tab-base", "tab-table2",
            "tab-essential-path", "tab-torque-errors", "tab-validation-errors",
            "tab-normality"} <= set(csvs)
    base = pd.read_csv(io.StringIO(csvs["tab-base"]), index_col=0)
    expected = res.parameter_table()
    assert list(base.index) == list(expected.index)
    assert list(base["relation"]) == list(expected["relation"])
    for col in ("ols", "ols_rel_std", "wls", "wls_rel_std"):     # %sigma named as percent in the CSV
        np.testing.assert_allclose(base[col + ("_percent" if col.endswith("_rel_std") else "")], expected[col],
                                   rtol=1e-15)
    assert list(base["essential"]) == list(expected["essential"])
    path = pd.read_csv(io.StringIO(csvs["tab-essential-path"]))
    assert list(path["removed"]) == list(res.essential.path["removed"])
    np.testing.assert_allclose(path["rel_error"], res.essential.path["rel_error"], rtol=1e-15)
    t2 = pd.read_csv(io.StringIO(csvs["tab-table2"]), index_col=0)
    assert sorted(t2.index) == sorted(res.model.names)   # planar2: no published reference
    np.testing.assert_allclose(t2.loc[res.model.names, "value"], res.model.chi, rtol=1e-15)
    noise = pd.read_csv(io.StringIO(csvs["tab-normality"]), index_col=0)
    np.testing.assert_allclose(noise["jarque_bera_p"], val.noise["jarque_bera_p"], rtol=1e-15)
    errs = pd.read_csv(io.StringIO(csvs["tab-validation-errors"]), index_col=0)
    np.testing.assert_allclose(errs["rms [N m]"], val.rms, rtol=1e-15)
    # every downloaded value keeps its unit: a unit column beside parameters, else in the header
    assert base.loc["ZZ1R", "unit"] == t2.loc["ZZ1R", "unit"] == "kg m\u00b2"
    assert t2.loc["Fv1", "unit"] == "N m s/rad"
    dh = pd.read_csv(io.StringIO(csvs["tab-dh"]), index_col=0)
    assert {"alpha [rad]", "d [m]", "theta [rad]", "r [m]"} <= set(dh.columns)
    assert {"mean [N m]", "std [N m]"} <= set(noise.columns)


def test_user_strings_are_escaped(evil):
    robot, ident, res, val = evil
    html = render_idim_report(res, robot, ident, val, title=f"report {EVIL_ROBOT}")
    assert "<script" not in html
    assert "<img src=x" not in html and "<img" not in html.replace("<img alt=", "")
    assert "<b>bold</b>" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "&lt;img src=x onerror=alert(1)&gt;" in html
    assert "&lt;b&gt;bold&lt;/b&gt;" in html
    # the CSV download of the joint table carries the name unescaped (it is data, percent-encoded)
    joints = pd.read_csv(io.StringIO(_csv_links(html)["tab-joints"]), index_col=0)
    assert joints["joint"].iloc[0] == EVIL_JOINT


def test_same_input_gives_byte_identical_output(planar, planar_html):
    robot, ident, res, val = planar
    again = render_idim_report(res, robot, ident, val)
    assert again == planar_html


def test_write_report_is_atomic(tmp_path, monkeypatch, planar_html):
    target = tmp_path / "report.html"
    write_report(target, planar_html)
    assert target.read_text(encoding="utf-8") == planar_html

    def boom(src, dst):
        raise OSError("disk full")

    new = tmp_path / "new.html"
    monkeypatch.setattr(provenance.os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_report(new, planar_html)
    with pytest.raises(OSError):
        write_report(target, "<p>half</p>")
    monkeypatch.undo()
    assert not new.exists()
    assert target.read_text(encoding="utf-8") == planar_html    # old file untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]  # no temporary left


def test_a_robot_without_a_published_table_has_no_table2_section(planar_html):
    """planar2 has no published reference: its essential parameters are not put in the layout
    of the papers' Table 2, and the report does not apologise for a missing reference."""
    t2 = _section(planar_html, "table2")
    assert "Table 2" not in t2 and "No published reference" not in t2
    assert "Table 2" not in planar_html


def test_report_title_says_what_the_report_is(planar, planar_html, monkeypatch):
    robot, ident, res, val = planar
    from dynid.reports import html as html_module
    from dynid.reports.html import REPORT_TITLES, report_kind

    def title(html):
        return re.search(r"<h1>(.*?)</h1>", html, flags=re.S).group(1)
    assert title(planar_html) == "Identification of planar2"
    # the title does not depend on the IDIM sections: render them (and their figures) once
    sections = html_module.idim_sections(res, robot, ident, val)
    monkeypatch.setattr(html_module, "idim_sections", lambda *args, **kwargs: list(sections))
    diag = [Section("diagnosis", "Residual diagnosis", para("x")), Section("diagnosis-errors", "E", para("y"))]
    post = [Section("posterior", "Posterior (emcee)", para("z"))]
    assert report_kind(diag) == "diagnosis" and report_kind(post) == "posterior"
    assert report_kind(diag + post) == "full"
    assert title(render_idim_report(res, robot, ident, val, extra_sections=diag)) == "Residual diagnosis of planar2"
    assert title(render_idim_report(res, robot, ident, val, extra_sections=post)).startswith("Posterior")
    assert title(render_idim_report(res, robot, ident, val, extra_sections=post, kind="full")) == \
        REPORT_TITLES["full"].format(robot="planar2")
    assert "IDIM identification of" not in render_idim_report(res, robot, ident, val, extra_sections=diag + post)


def test_extra_sections_plug_in(planar):
    robot, ident, res, val = planar
    extra = [Section("diagnosis", "Diagnosis <draft>", "<b>plain text is escaped</b>"),
             Section("posterior", "Posterior", para("value ", Markup("<em>trusted</em>")))]
    html = render_idim_report(res, robot, None, None, extra_sections=extra, title="T")
    assert "validation" not in re.findall(r'<section id="([^"]+)"', html)
    ids = re.findall(r'<section id="([^"]+)"', html)
    assert ids == ["verdict"] + [s for s in SECTION_IDS if s != "validation"] + ["diagnosis", "posterior"]
    assert "&lt;b&gt;plain text is escaped&lt;/b&gt;" in html
    assert "Diagnosis &lt;draft&gt;" in html
    assert "<p>value <em>trusted</em></p>" in html
    with pytest.raises(ValueError, match="twice|two report sections"):
        render_idim_report(res, robot, extra_sections=[Section("model", "again")])
    with pytest.raises(ValueError, match="must match"):
        render_sections([Section("Bad Id", "x")], title="t")


def test_templates_are_package_data_found_through_the_import_system():
    env = environment()
    assert isinstance(env.loader, jinja2.PackageLoader)
    assert env.loader.package_name == "dynid.templates"
    assert env.autoescape is True
    assert "report.html.j2" in env.list_templates()
    src = Path(env.get_template("report.html.j2").filename).read_text(encoding="utf-8")
    assert "|safe" not in src.replace(" ", "")


# ------------------------------------------------------------------ TX40 and the paper
def test_paper_table2_data():
    t = DIDIM_TX40_TABLE2
    assert len(t) == 24
    assert t.names[:3] == ["ZZ1R", "Fv1", "Fc1"] and t.names[-2:] == ["Fvm6", "Fcm6"]
    assert t.get("ZZ1R").value == 1.30 and t.get("ZZ1R").rel_std_percent == 0.65
    assert t.get("Ia5").value == 0.053 and t.get("Ia5").rel_std_percent == 12.0
    assert t.get("Fcm6").value == 1.6 and t.get("Fcm6").rel_std_percent == 4.4
    assert "Gautier" in t.citation and "hal-00536953" in t.citation
    assert reference_for("TX-40") is t and reference_for("planar2") is None
    # the bundled TX40's a-priori values are the same table
    assert load_robot("tx40").apriori == pytest.approx(t.value_map())


@pytest.mark.skipif(not TX40_DATA.is_dir(), reason="real TX40 data not available")
def test_real_tx40_report(tmp_path):
    from dynid.analysis.data.experiment import load_experiment
    desc = tmp_path / "tx40.toml"
    desc.write_text(f"""[experiment]
name = "Staubli TX40 excitation (FIGAROH)"
sampling_rate = 5000.0
[positions]
file = "{TX40_DATA / 'pos_read_data.csv'}"
columns = ["Joint_1","Joint_2","Joint_3","Joint_4","Joint_5","Joint_6"]
side = "motor"
[torques]
file = "{TX40_DATA / 'curr_data.csv'}"
columns = ["Joint_1","Joint_2","Joint_3","Joint_4","Joint_5","Joint_6"]
side = "motor"
[transmission]
gear_ratios = [32, 32, 45, -48, 45, 32]
couplings = [{{motor = 6, joint = 5, ratio = 32}}]
position_offsets = [0.0, -1.5707963267948966, 1.5707963267948966, 0.0, 0.0, 3.141592653589793]
""", encoding="utf-8")
    robot = load_robot("tx40")
    e = load_experiment(desc, robot)
    res = identify_idim(e.segment(None, 6.0), robot)
    val = validate(res, e.segment(6.0, None), robot)
    html = render_idim_report(res, robot, e.segment(None, 6.0), val)
    t2 = _section(html, "table2")
    assert "paper" in t2 and "1.3" in t2 and "8.71" in t2          # the paper's values
    assert "Essential parameters (Table 2)" in t2                   # a published table: its layout, named
    csv = pd.read_csv(io.StringIO(_csv_links(html)["tab-table2"]), index_col=0)
    assert set(DIDIM_TX40_TABLE2.names) <= set(csv.index)
    assert set(res.model.names) <= set(csv.index)
    both = csv[csv["status"] == "both"]
    np.testing.assert_allclose(both["paper_rel_std_percent"],
                               [DIDIM_TX40_TABLE2.get(n).rel_std_percent for n in both.index])
    extra = csv[csv["status"] == "not_in_paper"].index
    assert all(f"{n} {T.NOT_IN_PAPER}" in t2 for n in extra)
    for sid in SECTION_IDS:
        _section(html, sid)
    assert len(html.encode("utf-8")) < 1_500_000


# ------------------------------------------------------------------ tables
def test_number_formatting():
    assert T.format_number(1.248251) == "1.248"
    assert T.format_number(-0.4679731) == "\u22120.468"
    assert T.format_number(12345.6) == "1.235e4"
    assert T.format_number(0) == "0"
    assert T.format_number(math.inf) == "\u221e"
    assert T.format_number(-math.inf) == "\u2212\u221e"
    assert T.format_number(math.nan) == "\u2014" and T.format_number(None) == "\u2014"
    assert T.format_pct(0.6512) == "0.65" and T.format_pct(34.219) == "34.22" and T.format_pct(152.36) == "152.4"
    assert T.format_pct(0.0384) == "0.038" and T.format_pct(0.0) == "0.00"     # not "0.0" for 0.038
    assert (T.format_pct(9.97), T.format_pct(10.02)) == ("9.97", "10.02")     # apart at the 10 % threshold
    assert T.format_pct(math.inf) == "\u221e" and T.format_pct(math.nan) == "\u2014"
    assert T.format_angle(-math.pi / 2) == "\u2212\u03c0/2" and T.format_angle(0.3) == "0.3"
    assert T.format_value(True, "bool").text == "\u2713"
    assert T.format_value(7).text == "7" and T.format_value("x<y").text == "x<y"


def test_csv_data_uri_roundtrip():
    df = pd.DataFrame({"name": ["a,b", "é \"q\"", "<x>&"], "v": [1.0, math.inf, math.nan]},
                      index=pd.Index([1, 2, 3], name="j"))
    uri = T.csv_data_uri(df)
    assert uri.startswith("data:text/csv;charset=utf-8,")
    assert re.fullmatch(r"[A-Za-z0-9%._~:;=,/\-]+", uri)  # safe inside an attribute
    back = pd.read_csv(io.StringIO(urllib.parse.unquote(uri.split(",", 1)[1])), index_col=0)
    assert list(back["name"]) == list(df["name"])
    assert back["v"].iloc[0] == 1.0 and np.isinf(back["v"].iloc[1]) and np.isnan(back["v"].iloc[2])


def test_table2_layout_markers():
    names, chi, rs = ["ZZ1R", "Fv1", "MX3"], [1.25, 8.0, 0.04], [0.6, 0.7, 21.7]
    table = T.table2_layout(names, chi, rs, DIDIM_TX40_TABLE2,
                            base_order=["ZZ1R", "Fv1", "Fc1", "MX3"])
    assert len(table.columns) == 12 and len(table.groups) == 6     # Parameter | unit | ours | paper, twice
    assert table.columns[:2] == ["Parameter", "unit"] and table.rows[0][1].text == "kg m\u00b2"   # ZZ1R
    texts = [c.text for row in table.rows for c in row]
    assert "MX3 +" in texts                       # dynid extra
    assert f"Fc1 {T.NOT_ESSENTIAL}" in texts       # in Table 2, not essential in dynid
    assert len(table.rows) == math.ceil((3 + 22) / 2)
    frame = T.table2_frame(names, chi, rs, DIDIM_TX40_TABLE2, ["ZZ1R", "Fv1", "Fc1", "MX3"])
    assert frame.loc["ZZ1R", "status"] == "both" and frame.loc["ZZ1R", "paper_value"] == 1.30
    assert frame.loc["MX3", "status"] == "not_in_paper" and math.isnan(frame.loc["MX3", "paper_value"])
    assert frame.loc["Fc1", "status"] == "not_essential" and math.isnan(frame.loc["Fc1", "value"])
    assert list(frame.index[:4]) == ["ZZ1R", "Fv1", "Fc1", "MX3"]


# ------------------------------------------------------------------ figures
def test_dense_torque_plot_is_decimated_png_and_deterministic():
    t = np.arange(30_000) / 1000.0
    y = np.sin(np.outer(t, [1, 2, 3]))
    a = F.torque_figure(t, y, 0.9 * y, ["a", "b", "c"], key="fig-dense")
    b = F.torque_figure(t, y, 0.9 * y, ["a", "b", "c"], key="fig-dense")
    assert a.kind == "png" and a.markup.startswith('<img alt="') and "data:image/png;base64," in a.markup
    assert "every 6th of 30000 samples" in a.caption
    assert a.markup == b.markup
    small = F.torque_figure(t[:500], y[:500], y[:500], ["a", "b", "c"], key="fig-small")
    assert small.kind == "svg" and small.markup.startswith("<svg")
    assert small.n_bytes < 150_000


def test_excluded_spans_reach_halfway_to_the_kept_neighbours():
    t = np.array([0.0, 1.0, 2.0, 4.0, 5.0, 6.0])
    excluded = np.array([True, False, True, True, False, True])
    assert F._excluded_spans(t, excluded) == [(0.0, 0.5), (1.5, 4.5), (5.5, 6.0)]
    assert F._excluded_spans(t, np.zeros(6, bool)) == []
    assert F._excluded_spans(t, np.ones(6, bool)) == [(0.0, 6.0)]


def test_svg_is_inline_ready_and_stable():
    path = pd.DataFrame({"step": [1, 2], "removed": ["a", "b"], "rel_std_removed": [500.0, 80.0],
                         "max_rel_std_remaining": [80.0, 10.0], "rel_error": [0.05, 0.051],
                         "n_remaining": [3, 2]})
    f1 = F.essential_path_figure(path, base_rel_error=0.0499, base_max_rel_std=500.0,
                                 error_limit=0.0509, key="fig-a")
    f2 = F.essential_path_figure(path, base_rel_error=0.0499, base_max_rel_std=500.0,
                                 error_limit=0.0509, key="fig-a")
    assert f1.markup == f2.markup
    svg = str(f1.markup)
    assert svg.startswith("<svg") and "xmlns" not in svg and "http" not in svg and "<!--" not in svg
    assert all(i.startswith("fig-a-") for i in re.findall(r'\bid="([^"]+)"', svg))
    bars = F.rel_std_bar_figure(["ZZ1R", "XX3R"], [0.6, 10.5], DIDIM_TX40_TABLE2.rel_std_map(),
                                key="fig-b")
    assert bars.kind == "svg" and "paper" in bars.caption
    pdf = F.residual_pdf_figure(np.random.default_rng(0).standard_normal((300, 2)), ["j1", "$x$"],
                                [0.5, 1e-9], key="fig-c")
    assert "JB p = 0.5" in str(pdf.markup) and "$x$" in str(pdf.markup)


def test_no_excluded_sample_is_drawn_at_zero(planar, monkeypatch):
    """Rows of the velocity dead zone (zeroed in W and Y for the fit) are gaps in every plot."""
    import matplotlib.axes
    robot, ident, res, val = planar
    obs = res.observation
    excluded = ~np.broadcast_to(np.asarray(obs.row_mask, dtype=bool), obs.tau.shape)
    assert excluded.any(), "the planar data must have dead-zone rows for this test to mean anything"
    # what the fit sees there: rows (partly) zeroed before decimation, not measurements
    drawn = []
    plot = matplotlib.axes.Axes.plot

    def spy(self, *args, **kwargs):
        lines = plot(self, *args, **kwargs)
        for ln in lines:
            drawn.append(np.asarray(ln.get_ydata(), dtype=float))
        return lines

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", spy)
    render_idim_report(res, robot, ident, val)
    assert drawn
    zeros = sum(int(np.sum(y == 0.0)) for y in drawn)
    assert zeros == 0, f"{zeros} plotted samples are exactly zero (excluded rows drawn as measurements)"
    # the held-out figures show every sample: nothing there is NaN
    assert np.all(np.isfinite(val.tau)) and np.all(np.isfinite(val.tau_hat))


def _labels_overlap(axis, renderer, pad=2.0) -> bool:
    """Whether the drawn major tick labels of `axis` run into each other (the oracle: measured
    on the drawn labels, not from the label widths the layout engine estimates)."""
    lo, hi = sorted(axis.get_view_interval())
    span = (hi - lo) * 1e-9
    labels = [t for loc, t in zip(axis.get_majorticklocs(), axis.get_ticklabels())
              if lo - span <= loc <= hi + span]      # ticks outside the view are not drawn
    boxes = [t.get_window_extent(renderer) for t in labels if t.get_visible() and t.get_text()]
    boxes.sort(key=lambda b: b.x0)
    return any(b.x0 < a.x1 + pad for a, b in zip(boxes, boxes[1:]))


def test_tick_labels_of_narrow_panels_do_not_overlap():
    """One panel per joint, a few centimetres wide (the diagnosis' structure plots), with long tick
    labels: they overlap as matplotlib draws them; render_figure thins them, or slants them."""
    import matplotlib
    with matplotlib.rc_context(F.STYLE):
        fig = F.Figure(figsize=(3.0, 2.2), layout="constrained")
        axes = fig.subplots(1, 3)
        for ax in axes:
            x = np.linspace(1.2e-5, 4.67e-4, 50)        # long labels: -0.00025 0.00000 ...
            ax.plot(x, np.sin(1e4 * x))
    F.FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    fig.draw_without_rendering()
    assert any(_labels_overlap(ax.xaxis, renderer) for ax in axes)   # the fault, as drawn
    F.render_figure(fig, "fig-narrow", "narrow panels")
    F.FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    fig.draw_without_rendering()
    for ax in axes:
        slanted = all(t.get_rotation() > 0 for t in ax.xaxis.get_ticklabels())
        assert slanted or not _labels_overlap(ax.xaxis, renderer)
        assert len([t for t in ax.xaxis.get_ticklabels() if t.get_text()]) >= 2
