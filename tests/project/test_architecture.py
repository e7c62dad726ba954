"""The layers of docs/architecture.md hold: import-linter's contracts of pyproject.toml.

dynid.fleet (facade) <- reports <- analysis <- dynamics <- outputs | provenance <- errors, the
analysis sub-layers, and no import cycle between sibling modules. grimp reads every import
statement, those inside functions too.
"""
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytest.importorskip("importlinter")

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = ROOT / "pyproject.toml"

_LINT = ("import sys\n"
         "from importlinter.cli import lint_imports\n"
         "sys.exit(lint_imports(config_filename=sys.argv[1], no_cache=True, no_logo=True))\n")


def _mirror(dest: Path) -> Path:
    """The installed layout of the source tree (package-dir: dynamics/ -> dynid/dynamics/ ...)
    under ``dest``: what an editable install maps by an import hook, which grimp cannot follow."""
    package_dir = tomllib.loads(PYPROJECT.read_text())["tool"]["setuptools"]["package-dir"]
    for package, folder in sorted(package_dir.items()):
        shutil.copytree(ROOT / folder, dest.joinpath(*package.split(".")), dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return dest


def _lint(tmp_path: Path, tree: Path | None):
    """lint-imports in a fresh interpreter (grimp finds dynid by import: this process has it
    loaded already), on ``tree`` (a folder holding dynid/) or on the installed package."""
    env = dict(os.environ, COLUMNS="200")     # one line per import in the report, as matched below
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    return subprocess.run([sys.executable, "-c", _LINT, str(PYPROJECT)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)


def _installed_tree_is_whole() -> bool:
    import dynid
    return (Path(dynid.__path__[0]) / "dynamics" / "__init__.py").is_file()


def test_the_import_contracts_hold(tmp_path):
    # A regular install (CI: pip install ".[test]") holds the whole dynid tree: lint it. An
    # editable one (development) maps the folders by an import hook: lint their mirror.
    tree = None if _installed_tree_is_whole() else _mirror(tmp_path / "tree")
    run = _lint(tmp_path, tree)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "BROKEN" not in run.stdout


def test_an_upward_import_inside_a_function_breaks_the_layers(tmp_path):
    tree = _mirror(tmp_path / "tree")
    regressor = tree / "dynid" / "dynamics" / "regressor.py"
    regressor.write_text(regressor.read_text() + "\n\ndef _planted():\n    from dynid.reports import cli\n"
                         "    return cli\n")
    run = _lint(tmp_path, tree)
    assert run.returncode != 0
    assert "dynid.dynamics is not allowed to import dynid.reports" in run.stdout
    assert "dynid.dynamics.regressor -> dynid.reports.cli" in run.stdout
