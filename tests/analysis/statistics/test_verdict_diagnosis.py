"""The verdict's diagnosis line (issue 27): findings named with their size, effects cut by
max_effects with their gain and how to include them; the status does not change."""
from types import SimpleNamespace

import pytest


@pytest.fixture(scope="module")
def demo_result():
    """IDIM of a 10 s simulated planar2 recording (0.5 s)."""
    import numpy as np

    from dynid.analysis.data.synthetic import apriori_parameters, simulate_experiment
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.dynamics.base_parameters import base_parameters
    from dynid.dynamics.excitation import random_fourier_trajectory
    from dynid.dynamics.robot_file import load_robot
    robot = load_robot("planar2")
    rng = np.random.default_rng(2)
    exp = simulate_experiment(robot, apriori_parameters(robot, base_parameters(robot)),
                              random_fourier_trajectory(robot, 0.1, 8, rng), 10.0, rng=rng,
                              q_noise=1e-6, tau_noise=0.05)
    return identify_idim(exp, robot)


def _diagnosis(findings=(), cut=()):
    return SimpleNamespace(selected=[], findings=list(findings), cut=list(cut),
                           settings={"max_effects": 3})


def _drift():
    from dynid.analysis.diagnosis.findings import Finding
    return Finding(name="drift", joint=2, label="drift (joint 2, friction level)",
                   size="viscous coefficient -0.859 N m s/rad (52 % of Fv2)", change=0.03,
                   rel_change=0.01, cv_gain=0.069, statistic=51.0, p_value=1.8e-9,
                   why="a change during this recording cannot predict another recording")


def _cut(label, gain):
    return SimpleNamespace(label=label, name=label.split()[0], joint=int(label.split("joint ")[1][0]),
                           cv_gain=gain, statistic=30.0, p_value=1e-6)


def test_findings_and_cut_effects_in_one_verdict_line(demo_result):
    from dynid.analysis.statistics.verdict import verdict
    base = verdict(demo_result, diagnosis=_diagnosis())
    assert not [f for f in base.findings if f["key"] == "diagnosis"]     # nothing to say: no line
    v = verdict(demo_result, diagnosis=_diagnosis(
        [_drift()], [_cut("coupling (joint 2, from qd1)", 0.0564), _cut("load_friction (joint 1)", 0.0625)]))
    lines = [f for f in v.findings if f["key"] == "diagnosis"]
    assert len(lines) == 1 and lines[0]["level"] == "info"
    text = lines[0]["text"]
    assert "drift (joint 2, friction level): viscous coefficient -0.859 N m s/rad (52 % of Fv2)" in text
    assert "CV gain 6.9 %" in text and "did not add" in text
    assert "Cut by max_effects = 3" in text and "coupling (joint 2, from qd1), CV gain 5.6 %" in text
    assert "load_friction (joint 1), CV gain 6.2 %" in text and "--max-effects 5" in text
    assert v.status == base.status and v.reasons == base.reasons     # information only
    d = v.to_dict()
    assert d["diagnosis_findings"][0]["joint"] == 2 and d["diagnosis_findings"][0]["cv_gain"] == 0.069
    assert [c["joint"] for c in d["diagnosis_cut"]] == [2, 1]
    assert d["diagnosis_include_cut_with"] == "--max-effects 5"


def test_cut_alone_and_no_diagnosis(demo_result):
    from dynid.analysis.statistics.verdict import verdict
    v = verdict(demo_result, diagnosis=_diagnosis(cut=[_cut("stribeck (joint 1, v_s = 0.9 rad/s)", 0.067)]))
    text = next(f["text"] for f in v.findings if f["key"] == "diagnosis")
    assert text.startswith("Cut by max_effects = 3") and "did not add" not in text
    assert not [f for f in verdict(demo_result).findings if f["key"] == "diagnosis"]
