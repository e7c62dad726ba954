"""The README's first command (the main job), run as written in a fresh virtual
environment. The second command (the tests) is what CI runs as .ci/run.

The fresh-venv run installs dynid and its dependencies: it is marked slow and runs
with DYNID_SLOW_TESTS=1.
"""
import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]



def readme_commands():
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```sh\n(.*?)\n```", text, flags=re.S)[:2]


def test_readme_has_the_two_commands_on_its_first_screen():
    head = "\n".join((ROOT / "README.md").read_text().splitlines()[:25])
    demo, tests = readme_commands()
    assert demo in head and tests in head
    assert "dynid demo" in demo and "pytest" in tests
    assert (ROOT / ".ci" / "run").read_text().strip().endswith(tests.strip())


@pytest.mark.slow
def test_readme_main_command_in_fresh_venv(tmp_path):
    demo, _ = readme_commands()
    venv = tmp_path / "venv"
    report = tmp_path / "dynid-demo.html"
    cmd = demo.replace(".venv", str(venv)).replace("dynid-demo.html", str(report))
    proc = subprocess.run(["bash", "-c", cmd], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    html = report.read_text()
    assert "Full report on tx40" in html and 'id="table2"' in html


def test_installed_distribution_is_the_dynid_namespace_alone(tmp_path):
    """pip install . (not editable, without its dependencies, into a folder of its own): the only
    top-level name is dynid, and `import dynid` works from a folder holding folders named
    analysis/, dynamics/, reports/. The dependencies come from the running environment, behind
    the installed folder on sys.path (a fresh venv with them all takes minutes: the slow
    fresh-venv test above does that)."""
    import sys
    target = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                           "--target", str(target), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    work = tmp_path / "work"
    for name in ("analysis", "dynamics", "reports"):
        (work / name).mkdir(parents=True)
        (work / name / "__init__.py").write_text("raise ImportError('the wrong package')\n")
    script = ("import importlib.metadata as md, dynid\n"
              "files = md.distribution('dynid').files\n"
              "print(sorted({f.parts[0] for f in files if not f.parts[0].endswith('.dist-info')\n"
              "              and f.parts[0] not in ('..', 'bin')}))\n"      # the console script
              "print(dynid.__version__, dynid.load_robot('tx40').n_joints)\n"
              "print(dynid.__file__)\n")
    env = dict(os.environ, PYTHONPATH=str(target))
    out = subprocess.run([sys.executable, "-c", script], cwd=work, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    names, version, where = out.stdout.splitlines()
    assert names == "['dynid']"
    assert version.split()[1] == "6"
    assert Path(where).is_relative_to(target)        # the installed copy, not the checkout


def _table_columns(block):
    """{column heading: [cells]} of the first Markdown table in ``block``."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in block.splitlines() if line.startswith("|") and not line.startswith("|---")]
    heads = rows[0][1:]
    return {h: [r[k + 1] for r in rows[1:]] for k, h in enumerate(heads)}


@pytest.mark.slow
def test_readme_real_data_table_is_what_the_benchmark_computes():
    """Every cell of the README's real-data table comes out of `benchmarks/real_data.py` today."""
    import importlib.util
    import json
    import sys
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "real_data.py")], cwd=ROOT,
                          capture_output=True, text=True, timeout=1200,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])["datasets"]
    spec = importlib.util.spec_from_file_location("real_data", ROOT / "benchmarks" / "real_data.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = _table_columns(text.split(bench.README_BEGIN, 1)[1].split(bench.README_END, 1)[0])
    fresh = _table_columns(bench.readme_block(results))
    compared = 0
    for key, head in bench.README_HEADS.items():
        if not results.get(key, {}).get("available"):
            continue                              # e.g. the Panda log, not shipped
        assert shown[head] == fresh[head], (head, shown[head], fresh[head])
        compared += 1
    assert compared >= 3                          # the TX40 and both LWR4+ splits ship with the project
