"""The streamed observation equals the in-memory one (up to the filter-transient tolerance)."""
import numpy as np
import pytest
from conftest import TX40_EXAMPLE

from dynid.analysis.data.experiment import load_experiment
from dynid.analysis.processing.observation import observe
from dynid.analysis.processing.streaming import observe_stream
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.errors import DataError

TX40_EXPERIMENT = TX40_EXAMPLE / "experiment.toml"


@pytest.fixture(scope="module")
def tx40():
    robot = load_robot("tx40")
    return robot, base_parameters(robot), load_experiment(TX40_EXPERIMENT, robot)


def test_streamed_equals_in_memory_on_real_tx40(tx40):
    robot, bp, exp = tx40
    obs = observe(exp, robot, bp)
    s = obs.settings

    def chunks():
        rng = np.random.default_rng(3)
        k = 0
        while k < exp.n_samples:
            m = int(rng.integers(500, 7000))
            yield exp.q[k:k + m], exp.tau[k:k + m]
            k += m

    st = observe_stream(chunks(), exp.fs, robot, bp, fc_position=s["fc_position"], nd=s["nd"],
                        f_decimation_cutoff=s["f_decimation_cutoff"], qd_threshold=s["qd_threshold"],
                        block=8000)
    assert st.W.shape == obs.W.shape
    np.testing.assert_allclose(st.t, obs.t)
    scale = np.abs(obs.W).max(axis=(0, 1))
    assert np.max(np.abs(st.W - obs.W) / scale) < 1e-4
    np.testing.assert_array_equal(st.row_mask, obs.row_mask)
    assert np.max(np.abs(st.tau - obs.tau)) < 1e-9 * np.abs(obs.tau).max()


def test_stream_needs_numeric_dead_zone(tx40):
    robot, bp, exp = tx40
    with pytest.raises(DataError, match="numeric qd_threshold"):
        observe_stream(iter([]), exp.fs, robot, bp, fc_position=100.0, nd=100, qd_threshold="auto")
