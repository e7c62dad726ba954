"""docs/guide.md, followed as a new user would: every ```sh block runs, in order, in an
empty folder with the repository's examples/ beside it, with the dynid of the venv the
tests run in; exit codes and the outputs the guide promises are checked.

The ```python blocks of the "Python API" section run in order, in one interpreter.
The code under test is the installed dynid of that venv.
"""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "guide.md"
BIN = Path(sys.executable).parent

# files each block promises (by the order of the blocks in the guide)
PROMISED = {
    "dynid simulate --robot tx40": ["run.csv"],
    "dynid excite": ["traj.csv", "ex.json"],
    "dynid robot tx40": ["tx40_parameters.txt", "kuka.json"],
    "dynid robot arm.urdf": ["arm3_parameters.txt"],
    "dynid simulate --robot arm3.toml": ["arm3_log.csv", "arm3.html", "arm3.json"],
    "dynid identify run.csv": ["id.html", "id.json", "essential.csv"],
    "--holdout 3 --report tx40.html": ["tx40.html", "tx40.json"],
    "--method didim": ["didim.html", "didim.json"],
    "dynid sample": ["post.json"],
    "dynid diagnose": ["diag.html", "diag.json"],
    "--urdf kuka_identified.urdf": ["kuka_identified.urdf", "kuka_urdf.json"],
    "--physical --bootstrap 20": ["tx40_pc.urdf", "tx40_pc.xml", "tx40_pc.json"],
    "--effects spring:all": ["kuka_effects.json"],
    "--gravity-tilt": ["kuka_tilt.json"],
}


def sh_blocks(text=None):
    return re.findall(r"```sh\n(.*?)\n```", GUIDE.read_text() if text is None else text, flags=re.S)


# The own-robot recipe starts from the user's URDF (examples/own_robot/arm.urdf, which the
# guide copies): a 3-joint arm with a camera on a moving mount beside joint 2, so the tree
# branches and --base/--tip must pick the chain; the robot TOML is the guide's ```toml block.
OWN_ROBOT = "### Your own robot"


def own_robot_section():
    text = GUIDE.read_text()
    start = text.index(OWN_ROBOT)
    return text[start:text.index("\n## ", start)]


def write_own_robot_files(folder):
    """The robot TOML as the guide gives it (the guide's first block copies the URDF)."""
    toml_blocks = re.findall(r"```toml\n(.*?)\n```", own_robot_section(), flags=re.S)
    assert len(toml_blocks) == 1
    (folder / "arm3.toml").write_text(toml_blocks[0] + "\n")


def test_guide_has_the_promised_blocks():
    blocks = sh_blocks()
    assert len(blocks) == len(PROMISED)
    for marker in PROMISED:
        assert sum(marker in b for b in blocks) == 1, marker


@pytest.mark.slow
def test_every_command_block_runs(tmp_path):
    dynid = BIN / "dynid"
    if not dynid.exists():
        pytest.skip(f"no dynid console script beside {sys.executable}: pip install . first")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    write_own_robot_files(tmp_path)
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    for block in sh_blocks():
        proc = subprocess.run(["bash", "-e", "-c", block], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, f"{block}\nexit {proc.returncode}\n{proc.stderr[-3000:]}"
        marker = next(m for m in PROMISED if m in block)
        for name in PROMISED[marker]:
            path = tmp_path / name
            assert path.exists() and path.stat().st_size > 0, f"{block}\ndid not write {name}"
        if marker == "--urdf kuka_identified.urdf":
            export = json.loads((tmp_path / "kuka_urdf.json").read_text())["urdf_export"]
            assert export["consistent"] is True
            assert "<robot" in (tmp_path / "kuka_identified.urdf").read_text()
        if marker == "--gravity-tilt":
            doc = json.loads((tmp_path / "kuka_tilt.json").read_text())
            assert doc["gravity_tilt"]["theta_rad"] == pytest.approx([20.0e-3, 6.0e-3], abs=0.1e-3)
            assert doc["physical"]["validation"]["gap_points"] == pytest.approx(0.085, abs=0.002)
        if marker == "--effects spring:all":
            ph = json.loads((tmp_path / "kuka_effects.json").read_text())["physical"]
            assert ph["consistent"] is True and ph["validation"]["gap_points"] < 0.2
            assert [p["name"] for p in ph["effects"]["parameters"]] == [f"Ks{j}" for j in range(1, 8)]
    html = (tmp_path / "tx40.html").read_text()
    assert 'id="validation"' in html
    assert "parameter" in (tmp_path / "essential.csv").read_text().splitlines()[0]


def python_blocks():
    return re.findall(r"```python\n(.*?)\n```", GUIDE.read_text(), flags=re.S)


def test_python_api_blocks_run_in_order(tmp_path):
    blocks = python_blocks()
    assert len(blocks) == 4 and "dynid.identify(" in blocks[1] and "dynid.report(" in blocks[2]
    assert "dynid.verdict(r, v)" in blocks[2] and "dynid.run(" in blocks[3]
    assert all(len(b.strip().splitlines()) <= 8 for b in blocks)       # a handful of lines each
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    script = "\n\n".join(blocks)
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ZZ1R =" in proc.stdout and "lower" in proc.stdout and "Validation on" in proc.stdout
    assert proc.stdout.count("Verdict:") >= 2       # dynid.verdict(...) and the run's verdict, printed
    html = (tmp_path / "tx40_report.html").read_text()
    assert 'id="validation"' in html and 'id="diagnosis"' in html
