"""The real KUKA LWR4+ recordings: identification on some, validation on another."""
from pathlib import Path

import pytest

from dynid.analysis.data.experiment import load_experiment
from dynid.analysis.estimators.idim import identify_idim
from dynid.analysis.statistics.validation import validate
from dynid.dynamics.robot_file import load_robot

KUKA = Path(__file__).resolve().parents[2] / "examples" / "kuka_lwr4"


@pytest.fixture(scope="module")
def kuka():
    robot = load_robot("kuka_lwr4")
    return robot, {i: load_experiment(KUKA / f"recording_{i}.toml", robot) for i in (1, 2, 3)}


def test_reference_shift_is_estimated_per_file(kuka):
    _, rec = kuka
    # PROVENANCE.md: 281 for files 1-2 (282.4 fits file 2 best), 142 for file 3
    assert [rec[i].meta["reference_shift"] for i in (1, 2, 3)] == [281, 282, 142]


@pytest.mark.parametrize("train, held_out, bound", [((2, 3), 1, 0.04), ((1,), 2, 0.04)])
def test_held_out_error(kuka, train, held_out, bound):
    robot, rec = kuka
    res = identify_idim([rec[i] for i in train], robot)
    val = validate(res, rec[held_out], robot)
    # measured 2.1 % (2+3 -> 1) and 1.7 % (1 -> 2), see examples/kuka_lwr4/README.md
    assert val.rel_error < bound
    assert len(val.rms) == 7 and (val.rms < 0.5).all()
