"""URDF chain selection from the command line: --base/--tip, and the refusal of branched trees."""
from dynid.reports.cli import main

TREE = """<robot name="two_arms">
 <link name="world"/><link name="torso"/>
 <joint name="fix" type="fixed"><parent link="world"/><child link="torso"/></joint>
 {links}
</robot>"""
LINK = ('<link name="{n}"><inertial><mass value="1"/>'
        '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>')
JOINT = ('<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><axis xyz="0 0 1"/>'
         '<origin xyz="0 {y} 0.1"/><limit lower="-1" upper="1" velocity="1" effort="10"/></joint>')


def two_arm_urdf(tmp_path):
    parts = []
    for side, y in (("left", 0.2), ("right", -0.2)):
        parent = "torso"
        for k in (1, 2):
            parts.append(LINK.format(n=f"{side}_{k}"))
            parts.append(JOINT.format(n=f"{side}_j{k}", p=parent, c=f"{side}_{k}", y=y if k == 1 else 0))
            parent = f"{side}_{k}"
    path = tmp_path / "two_arms.urdf"
    path.write_text(TREE.format(links="\n ".join(parts)))
    return path


def test_branched_urdf_is_refused_with_the_cli_fix(tmp_path, capsys):
    assert main(["robot", str(two_arm_urdf(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert "--tip" in err and "left_j1" in err and "right_j1" in err and "Traceback" not in err


def test_tip_selects_one_arm(tmp_path, capsys):
    path = two_arm_urdf(tmp_path)
    assert main(["robot", str(path), "--tip", "left_2"]) == 0
    out = capsys.readouterr().out
    assert "2 joints" in out and "left_j1, left_j2" in out and "right" not in out.split("standard")[0]
    assert main(["robot", str(path), "--base", "left_1", "--tip", "left_2"]) == 0
    assert "1 joints" in capsys.readouterr().out


def test_unknown_tip_is_bad_input(tmp_path, capsys):
    assert main(["robot", str(two_arm_urdf(tmp_path)), "--tip", "nowhere"]) == 2
    assert "nowhere" in capsys.readouterr().err
