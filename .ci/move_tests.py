#!/usr/bin/env python3
"""Move test files from tests/ into the folders that mirror the packages (issue 25 item 7).

    python .ci/move_tests.py             # git mv what is still at tests/, fix paths and imports
    python .ci/move_tests.py --dry-run   # say what would move, change nothing
    python .ci/move_tests.py --skip analysis/diagnosis/hidden.py ...   # leave these files' text alone

Idempotent: a file already in its folder is left where it is, and every rewrite below matches
only the old form, so a second run changes nothing. Run it again after merging branches that
added test files at tests/: their rows in TABLE move them; a test file at tests/ without a row
is listed (add its row, then run again).

What it does, in order:

1. `git mv tests/NAME.py tests/FOLDER/NAME.py` for each row of TABLE whose file is still at
   tests/ (history follows the file);
2. in each file it moved, the paths that counted from tests/: `Path(__file__).resolve().parents[k]`
   gains the depth of FOLDER, `Path(__file__).parent` becomes the tests/ folder;
3. in tests/ and benchmarks/: `from tests import X` / `from tests.X import` name X where it now
   lives (`tests.support.X`, `tests.dynamics.test_urdf`), and the benchmarks' `ROOT / "tests"`
   on sys.path becomes `ROOT / "tests" / "support"` (the helper modules' folder);
4. in every tracked text file but README.md and CHANGELOG.md (the integrator's) and --skip:
   the references `tests/NAME.py` become `tests/FOLDER/NAME.py`.

tests/conftest.py stays at tests/ (the fixtures every folder shares; it puts tests/support on
sys.path, so `import oracles` works from every folder) and tests/data/ stays where it is.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"

# the helper modules (not tests): tests/support/, a package (tests.support.X)
SUPPORT = ["bias_scenarios", "diagnosis_cases", "gravity_posterior", "independent_plant", "oracles",
           "payload_plant", "physical_truth", "simulated_fleet"]

# test file -> folder under tests/ (the package it tests; cli: the command line; integration:
# end to end on real data or through exports; project: the repository's own promises)
TABLE = {
    **{name: "support" for name in SUPPORT},
    # dynamics
    "test_base_parameters": "dynamics",
    "test_excitation": "dynamics",
    "test_independent_plant": "dynamics",
    "test_regressor": "dynamics",
    "test_robot_file": "dynamics",
    "test_simulation": "dynamics",
    "test_trajectories": "dynamics",
    "test_urdf": "dynamics",
    "test_urdf_export": "dynamics",
    # analysis
    "test_interface": "analysis",
    "test_experiment": "analysis/data",
    "test_split": "analysis/data",
    "test_averaging": "analysis/processing",
    "test_decimation": "analysis/processing",
    "test_signals": "analysis/processing",
    "test_streaming": "analysis/processing",
    "test_asymmetric_friction": "analysis/estimators",
    "test_chunked_reduction": "analysis/estimators",
    "test_didim": "analysis/estimators",
    "test_didim_gains": "analysis/estimators",
    "test_essential": "analysis/estimators",
    "test_gravity_tilt": "analysis/estimators",
    "test_idim": "analysis/estimators",
    "test_least_squares": "analysis/estimators",
    "test_maximum_likelihood": "analysis/estimators",
    "test_payload": "analysis/estimators",
    "test_physical": "analysis/estimators",
    "test_physical_prior": "analysis/estimators",
    "test_projection": "analysis/estimators",
    "test_uncertainty": "analysis/estimators",
    "test_noise": "analysis/statistics",
    "test_verdict": "analysis/statistics",
    "test_results_family": "analysis",
    "test_bayes": "analysis/sampling",
    "test_sample_physical": "analysis/sampling",
    "test_diagnosis": "analysis/diagnosis",
    "test_diagnosis_independent": "analysis/diagnosis",
    "test_diagnosis_units": "analysis/diagnosis",
    "test_physical_effects": "analysis/diagnosis",
    "test_decoupled": "analysis/decoupled",
    "test_fleet": "analysis/fleet",
    # reports and the base layer
    "test_browser": "reports",
    "test_report": "reports",
    "test_progress": "base",
    "test_threads": "base",
    # the command line
    "test_cli": "cli",
    "test_cli_api": "cli",
    "test_cli_chain": "cli",
    "test_cli_physical": "cli",
    "test_hostile": "cli",
    "test_output_schemas": "cli",
    # end to end
    "test_comparison": "integration",
    "test_examples": "integration",
    "test_kuka": "integration",
    "test_panda": "integration",
    "test_payload_export": "integration",
    "test_replay": "integration",
    "test_robustness": "integration",
    # the repository's promises: layers, docs, guide, README
    "test_architecture": "project",
    "test_docs": "project",
    "test_guide": "project",
    "test_readme": "project",
}

NOT_MOVED = {"conftest"}
TEXT_SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".cfg", ".txt", ".html", ".j2", ".sh", ""}
NEVER_EDIT = {Path("README.md"), Path("CHANGELOG.md")}   # the integrator's


def _depth(folder: str) -> int:
    return len(Path(folder).parts)


def _fix_own_paths(text: str, d: int) -> str:
    """Paths a moved file computed from its own place at tests/."""
    text = re.sub(r"Path\(__file__\)\.resolve\(\)\.parents\[(\d+)\]",
                  lambda m: f"Path(__file__).resolve().parents[{int(m.group(1)) + d}]", text)
    # Path(__file__).parent was tests/: d folders up from the new place
    return re.sub(r"Path\(__file__\)(?:\.resolve\(\))?\.parent\b(?!s)",
                  f"Path(__file__).resolve().parents[{d}]", text)


def _module_path(name: str) -> str:
    return "tests." + TABLE[name].replace("/", ".") + "." + name


def _fix_imports(text: str, benchmark: bool) -> str:
    names = "|".join(sorted(TABLE, key=len, reverse=True))
    # from tests import X[, Y]  (only helper modules are imported this way)
    def from_tests(m):
        mods = [s.strip() for s in m.group(2).split(",")]
        folders = {TABLE.get(s.split(" as ")[0].strip()) for s in mods}
        if len(folders) != 1 or None in folders:
            return m.group(0)
        return f"{m.group(1)}from tests.{folders.pop().replace('/', '.')} import {m.group(2)}"
    text = re.sub(rf"^(\s*)from tests import ((?:{names})\b[^\n(]*)$", from_tests, text, flags=re.M)
    # from tests.X import ...
    text = re.sub(rf"\bfrom tests\.({names}) import\b", lambda m: f"from {_module_path(m.group(1))} import", text)
    if benchmark:
        # the helper modules' folder on sys.path (bare `import oracles` etc.)
        text = re.sub(r'(ROOT|parents\[1\]) / "tests"(?!\s*/)', r'\1 / "tests" / "support"', text)
    return text


def _fix_references(text: str) -> str:
    names = "|".join(sorted(TABLE, key=len, reverse=True))
    return re.sub(rf"(?<![\w/.])tests/({names})\.py\b", lambda m: f"tests/{TABLE[m.group(1)]}/{m.group(1)}.py", text)


def _tracked() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [ROOT / p for p in out.split("\0") if p]


def _rewrite(path: Path, fn, dry: bool, changed: list):
    try:
        old = path.read_text()
    except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
        return
    new = fn(old)
    if new != old:
        changed.append(path.relative_to(ROOT))
        if not dry:
            path.write_text(new)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dry-run", action="store_true")
    ap.add_argument("--skip", nargs="*", default=[], help="paths (from the repository root) whose text is left alone")
    args = ap.parse_args(argv)
    skip = {str(Path(s)) for s in args.skip}
    dry = args.dry_run

    moved, changed = [], []
    for name, folder in TABLE.items():
        src = TESTS / f"{name}.py"
        dst = TESTS / folder / f"{name}.py"
        if not src.exists() or dst.exists():
            continue
        print(f"git mv {src.relative_to(ROOT)} {dst.relative_to(ROOT)}")
        if not dry:
            dst.parent.mkdir(parents=True, exist_ok=True)
            subprocess.run(["git", "mv", str(src), str(dst)], cwd=ROOT, check=True)
            depth = _depth(folder)
            _rewrite(dst, lambda t, d=depth: _fix_own_paths(t, d), dry, changed)
        moved.append(name)

    init = TESTS / "support" / "__init__.py"
    if not init.exists():
        print(f"create {init.relative_to(ROOT)}")
        if not dry:
            init.parent.mkdir(parents=True, exist_ok=True)
            init.write_text('"""Test-only helpers shared by every test folder and by benchmarks/: independent plants,\n'
                            'oracles, simulated data (not part of the dynid package)."""\n')
            subprocess.run(["git", "add", str(init)], cwd=ROOT, check=True)

    tracked = _tracked()
    for path in tracked:
        rel = path.relative_to(ROOT)
        if str(rel) in skip or not path.is_file():
            continue
        if rel.parts[0] in ("tests", "benchmarks") and path.suffix == ".py":
            _rewrite(path, lambda t, b=rel.parts[0] == "benchmarks": _fix_imports(t, b), dry, changed)
        if (rel not in NEVER_EDIT and path.suffix in TEXT_SUFFIXES and "egg-info" not in str(rel)
                and rel != Path(".ci/move_tests.py")):
            _rewrite(path, _fix_references, dry, changed)

    left = sorted(p.name for p in TESTS.glob("*.py") if p.stem not in NOT_MOVED and p.stem not in TABLE)
    for p in sorted(set(changed)):
        print(f"rewrote {p}")
    if left:
        print("no row in TABLE (left at tests/): " + ", ".join(left), file=sys.stderr)
    print(f"{len(moved)} moved, {len(set(changed))} files rewritten" + (" (dry run)" if dry else ""))
    return 1 if left else 0


if __name__ == "__main__":
    sys.exit(main())
