"""The HTML report in a real browser (headless Chromium driven by Playwright).

Skipped where Chromium or Playwright is missing, except under CI (CI=true),
where .ci/run installs Chromium and a missing browser is a failure.
"""
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "out"                     # ignored by git; CI keeps it as an artifact folder
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

try:
    from playwright.sync_api import sync_playwright
except ImportError:                    # pragma: no cover
    sync_playwright = None

if not (CHROMIUM and sync_playwright):
    if os.environ.get("CI"):
        pytest.fail("CI must run the browser tests: install Debian's chromium and playwright", pytrace=False)
    pytest.skip("headless Chromium or playwright not available", allow_module_level=True)

ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync"]


def open_page(html_path, screenshot=None):
    """Load a file in Chromium; return what a reviewer would look for."""
    events = {"console_errors": [], "requests": [], "dialogs": [], "page_errors": []}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.on("console", lambda m: m.type == "error" and events["console_errors"].append(m.text))
        page.on("pageerror", lambda e: events["page_errors"].append(str(e)))
        page.on("request", lambda r: events["requests"].append(r.url))
        page.on("dialog", lambda d: (events["dialogs"].append(d.message), d.dismiss()))
        page.goto(html_path.resolve().as_uri())
        page.wait_for_load_state("load")
        events["sections"] = page.eval_on_selector_all(
            "section[id]", "els => els.map(s => ({id: s.id, h2: (s.querySelector('h2')||{}).textContent,"
            " figures: s.querySelectorAll('svg, img').length}))")
        events["nav"] = page.eval_on_selector_all("nav a[href^='#']", "els => els.map(a => a.getAttribute('href'))")
        events["imgs_x"] = page.eval_on_selector_all("img[src='x']", "els => els.length")
        events["body_text"] = page.inner_text("body")
        if screenshot:
            page.screenshot(path=str(screenshot), full_page=True)
        browser.close()
    return events


@pytest.mark.slow
def test_demo_report_in_chromium(tmp_path):
    from dynid.reports.cli import main
    report = tmp_path / "demo.html"
    assert main(["demo", "--duration", "8", "--report", str(report), "--quiet"]) == 0
    OUT.mkdir(exist_ok=True)
    shot = OUT / "demo-report.png"
    ev = open_page(report, screenshot=shot)
    assert ev["console_errors"] == [] and ev["page_errors"] == []
    external = [u for u in ev["requests"] if not u.startswith(("file://", "data:"))]
    assert external == [], external
    assert shot.stat().st_size > 10_000
    ids = [s["id"] for s in ev["sections"]]
    for expected in ("run", "model", "base-parameters", "table2", "essential-path", "torques", "validation",
                     "didim-convergence", "didim-table2", "posterior", "diagnosis", "diagnosis-residuals"):
        assert expected in ids
        assert "#" + expected in ev["nav"]
    for s in ev["sections"]:
        assert s["h2"] and s["h2"].strip(), s
    # every section that shows results has its figure
    figured = {s["id"]: s["figures"] for s in ev["sections"]}
    for sid in ("essential-path", "torques", "validation", "didim-convergence", "didim-torques",
                "posterior", "diagnosis-residuals"):
        assert figured[sid] >= 1, sid


def test_hostile_names_do_not_execute(tmp_path):
    from dynid.analysis.data.synthetic import simulate_experiment
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.robot_file import load_robot
    from dynid.dynamics.trajectories import random_fourier_trajectory
    from dynid.reports.html import render_idim_report, write_report

    text = (ROOT / "dynamics" / "robots" / "planar2.toml").read_text()
    text = text.replace('name = "planar2"', 'name = "<script>alert(1)</script>"')
    text = text.replace('name = "shoulder"', 'name = "\\"><img src=x onerror=alert(1)>"')
    robot_file = tmp_path / "hostile.toml"
    robot_file.write_text(text)
    robot = load_robot(robot_file)
    assert robot.name == "<script>alert(1)</script>"
    bp = base_parameters(robot)
    chi = bp.to_standard(bp.from_standard(robot.standard_vector(
        {k: v for k, v in robot.apriori.items() if k in robot.standard_names})))
    rng = np.random.default_rng(0)
    traj = random_fourier_trajectory(robot, 0.2, 5, rng)
    exp = simulate_experiment(robot, chi, traj, 10.0, rng=rng, q_noise=1e-5, tau_noise=0.05,
                              name='"><img src=x onerror=alert(1)>.csv')
    res = identify_idim(exp, robot, bp=bp)
    report = tmp_path / "hostile.html"
    write_report(report, render_idim_report(res, robot, exp))
    ev = open_page(report)
    assert ev["dialogs"] == []                       # no alert() ran
    assert ev["imgs_x"] == 0                         # the <img> was not created
    assert ev["console_errors"] == [] and ev["page_errors"] == []
    assert "<script>alert(1)</script>" in ev["body_text"]    # shown as text


def _verdict_in_browser(html_path):
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto(html_path.resolve().as_uri())
        page.wait_for_load_state("load")
        got = page.eval_on_selector(
            "#verdict", "v => ({status: v.dataset.status, params: v.dataset.flaggedParameters,"
            " joints: v.dataset.flaggedJoints, text: v.innerText,"
            " top: v.getBoundingClientRect().top, first: document.querySelector('main section').id})")
        browser.close()
    return got


@pytest.mark.parametrize("which", ["demo", "tx40"])
def test_verdict_block_matches_the_json(tmp_path_factory, which):
    """The runs are shared with tests/cli/test_output_schemas.py (the IDIM-only demo) and
    tests/analysis/statistics/test_verdict.py (identify on the TX40 recording): made once per session."""
    import json

    from shared_runs import DYNID, demo_idim_run, tx40_identify_run
    if which == "demo":
        if not DYNID.exists():
            pytest.skip("no dynid console script beside the interpreter: pip install . first")
        run, stem = demo_idim_run(tmp_path_factory), "demo"
    else:
        run, stem = tx40_identify_run(tmp_path_factory), "out"
    assert run.returncode == 0, run.stderr[-3000:]
    report, js = run.folder / f"{stem}.html", run.folder / f"{stem}.json"
    doc = json.loads(js.read_text())
    vd = doc["verdict"]
    got = _verdict_in_browser(report)
    assert got["first"] == "verdict" and got["top"] < 900             # on the first screen
    assert got["status"] == vd["status"] and vd["status"].upper() in got["text"].upper()
    assert got["params"].split() == vd["not_identified"]
    assert got["joints"].split() == vd["validation"]["flagged_joints"]
    for name in vd["not_identified"]:
        assert name in got["text"]
    assert f"{100 * doc['validation']['all_samples']['rel_error']:.1f} %" in got["text"]


# ------------------------------------------------------------------ screenshots of first screens
def _first_screen(url, path, *, full_page=False):
    """Screenshot of what a reader sees first at `url` (1280 x 900), and the page's text."""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        requests = []
        page.on("request", lambda r: requests.append(r.url))
        page.goto(url)
        page.wait_for_load_state("load")
        page.wait_for_timeout(300)              # the theme's scripts place the page at the anchor
        page.screenshot(path=str(path), full_page=full_page)
        text = page.inner_text("body")
        browser.close()
    assert errors == [] and path.stat().st_size > 10_000
    local = ("file://", "data:", "http://127.0.0.1")
    assert [u for u in requests if not u.startswith(local)] == []     # nothing fetched from elsewhere
    return text


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    """Where the screenshots go (a temporary folder; pytest --basetemp=DIR keeps them to look at)."""
    return tmp_path_factory.mktemp("screenshots")


def test_screenshot_api_page_of_identify(shots, tmp_path_factory):
    pytest.importorskip("mkdocs")
    import sys
    if str(ROOT / "tests" / "project") not in sys.path:     # this file run alone
        sys.path.insert(0, str(ROOT / "tests" / "project"))
    from test_docs import built_site
    site = built_site(tmp_path_factory)          # built once per session, with tests/project/test_docs.py
    # served over HTTP as a reader's server would (the search worker is refused on file://)
    import functools
    import http.server
    import threading
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass
    handler = functools.partial(Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/api/#dynid.identify"
        text = _first_screen(url, shots / "api-identify.png")
    finally:
        server.shutdown()
    assert ":func:" not in text and "``" not in text
    assert "Parameters:" in text and "Returns:" in text


# the whole demo (DIDIM and the diagnosis) for one screenshot: slow; the verdict on the demo
# report's first screen is checked by test_verdict_block_matches_the_json[demo]
@pytest.mark.slow
def test_screenshot_demo_report_first_screen(shots, tmp_path):
    from dynid.reports.cli import main
    report = tmp_path / "demo.html"
    assert main(["demo", "--duration", "8", "--skip", "sample", "--report", str(report), "--quiet"]) == 0
    text = _first_screen(report.resolve().as_uri(), shots / "demo-first-screen.png")
    assert "Full report on tx40" in text and "IDENTIFIED" in text.upper()


def test_screenshot_diagnosis_report_first_screen(shots, tmp_path_factory):
    """The report of `dynid diagnose` on a simulated planar2 recording, run once per session
    (tests/cli/test_output_schemas.py checks the same run's JSON)."""
    from shared_runs import DYNID, planar2_diagnose_run
    if not DYNID.exists():
        pytest.skip("no dynid console script beside the interpreter: pip install . first")
    run = planar2_diagnose_run(tmp_path_factory)
    assert run.returncode == 0, run.stderr[-3000:]
    report = run.folder / "diag.html"
    text = _first_screen(report.resolve().as_uri(), shots / "diagnosis-first-screen.png")
    assert "Residual diagnosis of planar2" in text
    # the structure plots further down, whole, for a look at their axes
    _first_screen(report.resolve().as_uri(), shots / "diagnosis-full.png", full_page=True)
