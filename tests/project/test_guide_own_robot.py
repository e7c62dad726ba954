"""docs/guide.md's own-robot recipe ("Your own robot: a URDF, a log, a verdict"), followed as
written: the branched URDF of examples/own_robot, the guide's robot TOML and its two command blocks.

In a file of its own so that, under `pytest -n 2 --dist loadfile`, it and the guide's Python API
blocks (tests/project/test_guide.py), the two longest tests near the end of the run, go to
different workers; the helpers are test_guide.py's.
"""
import json
import os
import subprocess
import sys

import pytest
from test_guide import BIN, ROOT, own_robot_section, sh_blocks, write_own_robot_files


def test_own_robot_recipe_from_a_urdf_to_a_verdict(tmp_path):
    """The guide's own-robot recipe, as written: the URDF it ships (branched, so --base/--tip
    matter), the guide's robot TOML (controller, a-priori rotor inertia and friction), a log, a
    verdict."""
    dynid = BIN / "dynid"
    if not dynid.exists():
        pytest.skip(f"no dynid console script beside {sys.executable}: pip install . first")
    write_own_robot_files(tmp_path)
    (tmp_path / "examples").symlink_to(ROOT / "examples")       # the guide copies the URDF from there
    (tmp_path / "arm.urdf").write_text((ROOT / "examples" / "own_robot" / "arm.urdf").read_text())
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    # the branched URDF alone is refused, and the message offers the tips
    proc = subprocess.run([str(dynid), "robot", "arm.urdf"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and "--tip" in proc.stderr and "link3" in proc.stderr
    blocks = sh_blocks(own_robot_section())
    assert len(blocks) == 2 and "--base base_link --tip link3" in blocks[0]
    for block in blocks:
        proc = subprocess.run(["bash", "-e", "-c", block], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=600)
        assert proc.returncode == 0, f"{block}\nexit {proc.returncode}\n{proc.stderr[-3000:]}"
    params = (tmp_path / "arm3_parameters.txt").read_text()
    # the URDF's rpy="1.5708" is pi/2: Ia2 regroups into ZZ2R (taken literally it did not: 26)
    assert "25 base parameters" in params and "ZZ2R = ZZ2 + Ia2" in params
    assert "taken as the multiple: joint 'j2'" in params
    doc = json.loads((tmp_path / "arm3.json").read_text())
    verdict = doc["verdict"]
    assert verdict["status"] == "identified", verdict["findings"]
    assert verdict["not_identified"] == [] and verdict["apriori"]["flagged"] == []
    # the a-priori friction and rotor inertia were simulated, and come back within 3 sigma
    compared = {c["name"]: c for c in verdict["apriori"]["compared"]}
    for name in ("Fv1", "Fc2", "Fv3", "Ia3"):
        assert compared[name]["n_sigma"] < 3, compared[name]
    assert "<html" in (tmp_path / "arm3.html").read_text()[:200].lower()
