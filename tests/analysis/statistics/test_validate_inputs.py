"""validate() and verdict() with a result they cannot validate, or the identification data
itself, raise one clear InputError (they raised AttributeError / KeyError, or said "[ok]")."""
import pytest

import dynid
from dynid.errors import InputError


@pytest.fixture(scope="module")
def split():
    rec = dynid.simulate(dynid.load_robot("planar2"), 6.0, seed=1)
    train, held = dynid.holdout_split(rec.experiment, 2.0)
    return rec.robot, train, held


@pytest.mark.parametrize("method", ["projection", "didim"])
def test_other_methods_are_refused_by_name(split, method):
    robot, train, held = split
    r = dynid.identify(train, robot, method=method)
    for f in (dynid.validate, dynid.verdict):
        with pytest.raises(InputError, match=r"this (ProjectionResult|DIDIMResult) .* cannot be validated"):
            f(r, held)


def test_identification_data_is_not_held_out(split):
    robot, train, held = split
    r = dynid.identify(train, robot)
    with pytest.raises(InputError, match="the held-out recording is the identification data"):
        dynid.verdict(r, train)
    with pytest.raises(InputError, match="Experiment or a file path"):
        dynid.validate(r, {"t": 1})
    run = dynid.run(train, robot)
    assert dynid.validate(run, held).rel_error == pytest.approx(dynid.validate(r, held).rel_error)


def test_the_same_recording_twice_is_refused(split):
    robot, train, _ = split
    with pytest.raises(InputError, match="recording 2 .* holds the same data as recording 1"):
        dynid.identify([train, train], robot)
