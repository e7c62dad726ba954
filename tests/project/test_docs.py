"""The API reference as a reader sees it: `mkdocs build --strict` of this checkout into a
temporary folder, then the built HTML is read for what renders badly.

* raw Sphinx roles (:func:, :meth:, :class:, :mod: ...) and literal double backticks:
  mkdocstrings' numpy style shows them as text (`.ci/docstrings.py` rewrites them);
* a public function or method without a Returns section (unless it returns None);
* a private name (a leading underscore) or an object documented twice.

mkdocstrings reads the docstrings statically (griffe, nothing imported). dynid's folders
install under one namespace (package-dir mapping), which griffe cannot follow in an
editable install: the test lays out the checkout as `dynid/` with symbolic links and puts
it first on the path. Skipped where mkdocs is not installed (`pip install ".[docs]"`).
"""
from __future__ import annotations

import html as html_lib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|attr|data|obj|exc|ref):`?")
OBJECT = re.compile(r'<div class="doc doc-object doc-(function|class|attribute|module)">')
HEADING = re.compile(r'<h(\d) id="([^"]+)" class="doc doc-heading">\s*<code class="doc-symbol doc-symbol-heading '
                     r'doc-symbol-(\w+)">')


def package_tree(where: Path) -> Path:
    """`where/dynid`: the checkout's src/dynid files and its layer folders, linked."""
    pkg = where / "dynid"
    pkg.mkdir(parents=True)
    for item in (ROOT / "src" / "dynid").iterdir():
        (pkg / item.name).symlink_to(item)
    for layer in ("dynamics", "analysis", "reports", "templates"):
        (pkg / layer).symlink_to(ROOT / layer)
    return where


def build(site: Path, tmp: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(package_tree(tmp / "src")) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(site)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _text(fragment: str) -> str:
    return html_lib.unescape(re.sub(r"<[^>]+>", "", fragment))


def page_problems(page: str, name: str = "page") -> list[str]:
    """What renders badly in one built HTML page (an empty list when nothing does)."""
    problems = []
    # code blocks (signatures, examples) are highlighted token by token: read the text
    text = _text(page)
    for m in ROLE.finditer(text):
        problems.append(f"{name}: raw Sphinx role {text[m.start():m.end() + 40]!r}")
    for m in re.finditer("``", text):
        problems.append(f"{name}: literal double backticks {text[max(0, m.start() - 30):m.end() + 30]!r}")
    starts = [m.start() for m in OBJECT.finditer(page)] + [len(page)]
    seen = {}
    for start, end in zip(starts, starts[1:]):
        block = page[start:end]                 # this object up to the next one (nested ones excluded)
        head = HEADING.search(block)
        if head is None:
            continue
        level, ident, kind = int(head.group(1)), head.group(2), head.group(3)
        if any(part.startswith("_") and not part.startswith("__") for part in ident.split(".")):
            problems.append(f"{name}: private name documented: {ident}")
        if kind in ("function", "method"):
            signature = re.search(r'<div class="doc-signature.*?</code>', block, flags=re.S)
            returns_none = signature is not None and re.search(r"->\s*None$", _text(signature.group(0)).strip())
            if not returns_none and not re.search(r'doc-section-title">(Returns|Yields):', block):
                problems.append(f"{name}: {kind} {ident} has no Returns section")
        if kind in ("function", "class") and ident.count(".") >= 1:
            key = ident.rsplit(".", 1)[-1] if kind == "class" or level <= 2 else ident
            if key in seen:
                problems.append(f"{name}: {key} documented twice ({seen[key]} and {ident})")
            seen.setdefault(key, ident)
    return problems


def site_problems(site: Path) -> list[str]:
    problems, names = [], {}
    for path in sorted(site.rglob("*.html")):
        page = path.read_text(encoding="utf-8")
        rel = str(path.relative_to(site))
        problems += page_problems(page, rel)
        for head in HEADING.finditer(page):
            ident, kind = head.group(2), head.group(3)
            if kind in ("function", "class"):
                short = ident.rsplit(".", 1)[-1]
                if short in names and names[short][0] != rel and kind == names[short][1]:
                    problems.append(f"{short} documented on two pages ({names[short][0]} and {rel})")
                names.setdefault(short, (rel, kind))
    return problems


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pytest.importorskip("mkdocs", reason='the API reference needs pip install ".[docs]"')
    pytest.importorskip("mkdocstrings")
    return built_site(tmp_path_factory)


def built_site(tmp_path_factory) -> Path:
    """The site, built once per session (tests/reports/test_browser.py screenshots a page of it)."""
    from shared_runs import once_in_folder

    def make(folder):
        proc = build(folder / "site", folder)
        return proc.returncode, proc.stderr
    run = once_in_folder(tmp_path_factory, "docs-site", make)
    assert run.returncode == 0, run.stderr[-4000:]
    return run.folder / "site"


def test_api_reference_renders_without_raw_markup_or_missing_returns(site):
    problems = site_problems(site)
    assert not problems, "\n".join(problems[:40]) + f"\n({len(problems)} in all)"


def test_api_reference_documents_the_public_functions(site):
    page = (site / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("load_robot", "load_experiment", "identify", "validate", "sample", "diagnose", "report", "demo"):
        assert f'id="dynid.{name}"' in page, name
    identify = page[page.index('id="dynid.identify"'):page.index('id="dynid.validate"')]
    for section in ("Parameters:", "Returns:", "Raises:", "Examples:"):
        assert f'doc-section-title">{section}' in identify, section
    # the parameter table: one row per parameter, f0 and reference among them with their own text
    assert re.search(r"<code>f0</code>", identify) and re.search(r"<code>reference</code>", identify)


PLANTED = """<div class="doc doc-object doc-function">
<h2 id="dynid.thing" class="doc doc-heading">
<code class="doc-symbol doc-symbol-heading doc-symbol-function"></code> thing</h2>
<div class="doc-signature highlight"><pre><code>thing(x) -&gt; float</code></pre></div>
<div class="doc doc-contents "><p>See {body} for the options.</p>{returns}</div></div>"""


def test_scan_finds_what_it_looks_for():
    """The scan above cannot pass by not looking: each fault, planted alone, is reported."""
    returns = '<p><span class="doc-section-title">Returns:</span></p>'
    assert page_problems(PLANTED.format(body="<code>other</code>", returns=returns)) == []
    assert "raw Sphinx role" in page_problems(PLANTED.format(body=":func:<code>other</code>", returns=returns))[0]
    assert "double backticks" in page_problems(PLANTED.format(body="``other``", returns=returns))[0]
    assert "no Returns" in page_problems(PLANTED.format(body="<code>other</code>", returns=""))[0]
    private = PLANTED.replace("dynid.thing", "dynid._thing").format(body="x", returns=returns)
    assert "private name" in page_problems(private)[0]
    twice = PLANTED.format(body="x", returns=returns) * 2
    assert "documented twice" in page_problems(twice)[0]


if __name__ == "__main__":          # .ci/docs: the scan of a site it has built
    found = site_problems(Path(sys.argv[1]))
    print("\n".join(found) or f"{sys.argv[1]}: no raw markup, every function has Returns")
    sys.exit(1 if found else 0)
