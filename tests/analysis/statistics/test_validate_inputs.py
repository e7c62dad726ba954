"""validate() and verdict() with a result they cannot validate, or the identification data
itself, raise one clear InputError (they raised AttributeError / KeyError, or said "[ok]")."""
import numpy as np
import pytest

import dynid
from dynid import Experiment
from dynid.errors import DataError, InputError


@pytest.fixture(scope="module")
def split():
    rec = dynid.simulate(dynid.load_robot("planar2"), 6.0, seed=1)
    train, held = dynid.holdout_split(rec.experiment, 2.0)
    return rec.robot, train, held


@pytest.fixture(scope="module")
def fitted(split):
    """The IDIM result of the identification part (the tests only read it)."""
    robot, train, _ = split
    return dynid.identify(train, robot)


@pytest.mark.parametrize("method", ["projection", "didim"])
def test_other_methods_are_refused_by_name(split, method):
    robot, train, held = split
    r = dynid.identify(train, robot, method=method)
    for f in (dynid.validate, dynid.verdict):
        with pytest.raises(InputError, match=r"this (ProjectionResult|DIDIMResult) .* cannot be validated"):
            f(r, held)


def test_identification_data_is_not_held_out(split, fitted):
    robot, train, held = split
    r = fitted
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


def test_an_experiment_built_in_memory_is_checked(split, fitted):
    """An Experiment made from arrays: a non-finite torque, a joint too many, a wrong fs are named
    with the recording, the signal and the sample (a decimation-stage message named none)."""
    robot, train, held = split
    tau = train.tau.copy()
    tau[200, 1] = np.inf
    with pytest.raises(DataError, match=r"recording 1 \(an Experiment in memory\): tau2 is not finite .* sample 201"):
        dynid.identify(Experiment(t=train.t, q=train.q, tau=tau), robot)
    with pytest.raises(DataError, match=r"3 joint column\(s\) in tau, but robot 'planar2' has 2"):
        dynid.identify(Experiment(t=train.t, q=np.c_[train.q, train.q[:, 0]], tau=np.c_[train.tau, train.tau[:, 0]]),
                       robot)
    r = fitted
    with pytest.raises(DataError, match=r"fs = 10000 Hz, but its time stamps give 1000 Hz"):
        dynid.validate(r, Experiment(t=held.t, q=held.q, tau=held.tau, fs=10000.0))


def test_verdict_names_wrong_arguments(split, fitted):
    robot, train, held = split
    r = fitted
    with pytest.raises(InputError, match="give an identification result"):
        dynid.verdict(None)
    with pytest.raises(InputError, match="held-out data must be an Experiment"):
        dynid.verdict(r, 5)
    with pytest.raises(InputError, match="identifies robot 'planar2', but robot= is 'tx40'"):
        dynid.verdict(r, held, robot="tx40")
    assert dynid.verdict(r, held, robot="planar2").status == dynid.verdict(r, held).status


def test_sample_names_its_inputs(fitted):
    r = fitted
    with pytest.raises(InputError, match="give an IDIM result"):
        dynid.sample(None)
    with pytest.raises(InputError, match="--seed"):
        dynid.sample(r, seed=-1)
    post = dynid.sample(r, walkers=24, max_seconds=1)
    assert post.diagnostics.n_walkers == 24
    # one σ everywhere, to the last digit: bse, the JSON's std and the table's
    assert post.bse.tolist() == [p["std"] for p in post.to_dict()["parameters"]] == post.to_frame()["std"].tolist()
    # neither a posterior nor an essential model alone is an identification to judge
    for part in (post, r.essential):
        with pytest.raises(InputError, match=f"{type(part).__name__} is not an identification the verdict judges"):
            dynid.verdict(part)


def test_conf_int_takes_any_real_alpha(fitted):
    ci = fitted.conf_int(np.float32(0.1))
    assert np.allclose(ci.to_numpy(), fitted.conf_int(0.1).to_numpy(), rtol=1e-6)
    with pytest.raises(InputError, match="alpha must be between 0 and 1"):
        fitted.conf_int(True)


def test_more_api_inputs_are_named(split, fitted):
    robot, train, _ = split
    with pytest.raises(DataError, match=r"Experiment.t must be an array of numbers"):
        Experiment(t="abc", tau=train.tau)
    with pytest.raises(InputError, match="progress must be a function"):
        dynid.identify(train, robot, progress=3)
    with pytest.raises(InputError, match="say must be a function"):
        dynid.run(train, robot, say=5)
    dynid.run(train, robot, say=lambda msg: None)          # a plain function of a message is enough
    with pytest.raises(InputError, match="idim_result must be the IDIM result"):
        dynid.diagnose(train, robot, idim_result="x")
    with pytest.raises(InputError, match=r"predict: the base regressor has shape \(3, 3\)"):
        fitted.predict(np.zeros((3, 3)))


def test_uncertainty_is_refused_where_it_would_be_ignored(split):
    """The Projection Method and ML have their own covariance: `uncertainty=` was silently dropped."""
    robot, train, _ = split
    with pytest.raises(InputError, match=r"uncertainty='classic' .* method 'projection' reports its own"):
        dynid.identify(train, robot, method="projection", uncertainty="classic")


def test_swapped_arguments_and_an_upper_case_method_are_understood(split, fitted):
    robot, train, held = split
    with pytest.raises(InputError, match=r"the order is validate\(result, held_out\)"):
        dynid.validate(held, fitted)
    assert dynid.identify(train, robot, method="IDIM").params.equals(fitted.params)
    assert dynid.identify(train, robot, method="PM").method == "PM"       # the JSON's spelling of projection
    with pytest.raises(InputError, match="got 'Fourier'"):
        dynid.identify(train, robot, method="Fourier")


def test_a_run_has_the_parameter_interface_of_its_identification(split, fitted):
    robot, train, _ = split
    run = dynid.run(train, robot)
    assert run.params.equals(fitted.params) and run.bse.equals(fitted.bse)
    assert run.conf_int(0.1).equals(fitted.conf_int(0.1))


def test_a_run_option_in_the_processing_dict_is_named(split):
    robot, train, _ = split
    with pytest.raises(InputError, match=r"method is an option of the run: pass method="):
        dynid.identify(train, robot, settings={"method": "didim"})
