"""The Projection Method's and maximum likelihood's results say which robot and recording they
identified, as IDIM's and DIDIM's do: `robot`, `robot_signature` and `source` in `to_dict()` (the
`--json` of `dynid identify --method projection|ml` had none of them), and a first summary line
naming both. ML built from arrays alone knows neither: null robot and signature, empty source."""
from __future__ import annotations

import json

import bias_scenarios as bs
import pytest

import dynid
from dynid.analysis.estimators.maximum_likelihood import maximum_likelihood, robot_model
from dynid.dynamics.robot import model_signature
from dynid.provenance import dumps_json


@pytest.fixture(scope="module")
def recording():
    return dynid.simulate("planar2", duration=4.0, seed=1, f0=0.5, harmonics=3).experiment


@pytest.mark.parametrize("method, options", [("projection", {}), ("ml", {"f0": 0.5})])
def test_the_result_names_its_robot_and_recording(recording, method, options):
    res = dynid.identify(recording, "planar2", method=method, **options)
    doc = json.loads(dumps_json(res.to_dict()))
    idim = dynid.identify(recording, "planar2").to_dict()
    assert doc["robot"] == idim["robot"] == "planar2"
    assert doc["source"] == idim["source"] == str(recording.source) != ""
    assert doc["robot_signature"] == idim["robot_signature"] == model_signature(res.robot)
    first = res.summary().splitlines()[0]
    assert "'planar2'" in first and str(recording.source) in first, first


def test_ml_from_arrays_knows_no_robot():
    robot, bp, _, _ = bs.pendulum()
    t, q, tau = bs.periodic_motion(fs=200.0)
    res = maximum_likelihood(t, q, tau, robot_model(robot, bp), f0=bs.F0, n_harmonics=5)
    doc = json.loads(dumps_json(res.to_dict()))
    assert doc["robot"] is None and doc["robot_signature"] is None and doc["source"] == ""
    assert res.summary().splitlines()[0].strip().startswith("Maximum likelihood, errors in variables")
