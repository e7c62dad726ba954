"""The compiled row masks give NumPy's values to the last bit, on a real regressor chunk."""
import numpy as np
import pytest

from dynid.analysis.processing.row_masks import centred_rows, zero_dead_rows
from dynid.dynamics.base_parameters import base_parameters, base_regressor
from dynid.dynamics.robot_file import load_robot


@pytest.fixture(scope="module")
def chunk():
    robot = load_robot("tx40")
    rng = np.random.default_rng(18000)
    m = 501
    q, qd, qdd = (rng.normal(0, s, (m + 1, robot.n_joints)) for s in (1.0, 0.5, 3.0))
    qd[::7, 2] = 0.0                      # exact zeros: sign(qd) = 0 columns
    W = base_regressor(robot, base_parameters(robot), q, qd, qdd)
    dead = rng.random((m, robot.n_joints)) < 0.3
    return W, dead


def test_zero_dead_rows_is_numpys_product(chunk):
    W, dead = chunk
    expected = W[:-1] * (~dead)[:, :, None]
    got = zero_dead_rows(W[:-1].copy(), ~dead)
    assert np.array_equal(got, expected)
    assert np.array_equal(np.signbit(got), np.signbit(expected))       # -0.0 where NumPy has it


@pytest.mark.parametrize("masked", [True, False])
def test_centred_rows_are_numpys_mean_then_mask(chunk, masked):
    W, dead = chunk
    expected = 0.5 * (W[1:] + W[:-1])
    keep = None
    if masked:
        keep = (~dead).astype(float)
        expected *= keep[:, :, None]
    work = W.copy()
    got = centred_rows(work, keep)
    assert got.shape == expected.shape and np.shares_memory(got, work)
    assert np.array_equal(got, expected)
    assert np.array_equal(np.signbit(got), np.signbit(expected))


def test_a_wrong_keep_shape_is_refused(chunk):
    W, dead = chunk
    with pytest.raises(ValueError, match="keep has shape"):
        centred_rows(W.copy(), ~dead[:-1])
    with pytest.raises(ValueError, match="C-contiguous"):
        zero_dead_rows(W[:, :, ::2], ~dead)
