"""A system reduced chunk by chunk (ls.Reduction) gives the in-memory numbers: OLS, WLS, essential set."""
import numpy as np
import pytest

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import essential_parameters
from dynid.errors import InputError


def _system(seed=1, N=2500, n=3, b=9):
    """Random W3 with joint 1 blind to the last columns, two parameters truly zero, unequal noise."""
    rng = np.random.default_rng(seed)
    W3 = rng.normal(size=(N, n, b)) * rng.uniform(0.1, 10, size=b)       # columns of very different scale
    W3[:, 0, 6:] = 0.0
    chi = rng.normal(size=b)
    chi[[2, 7]] = 0.0
    tau = W3 @ chi + rng.normal(size=(N, n)) * np.array([0.05, 0.5, 2.0])
    mask = rng.random((N, n)) > 0.1
    return W3, tau, mask, [f"P{i}" for i in range(b)]


def _reduce(W3, tau, mask, names, edges):
    total = None
    for a, z in zip(edges[:-1], edges[1:]):
        red = ls.reduce_system(W3[a:z], tau[a:z], names, row_mask=mask[a:z])
        total = red if total is None else total + red
    return total


def _rel(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)) / np.maximum(np.abs(np.asarray(b)), 1e-300)))


EDGES = [0, 1, 40, 700, 701, 1900, 2500]      # uneven chunks, one of a single sample


def test_ols_of_the_chunk_sums_is_the_closed_form_least_squares():
    W3, tau, mask, names = _system()
    red = _reduce(W3, tau, mask, names, EDGES)
    r = ls.ols_reduced(red)
    # closed form, outside the QR machinery: numpy's lstsq on the stacked included rows
    A = np.concatenate([W3[mask[:, j], j, :] for j in range(3)])
    y = np.concatenate([tau[mask[:, j], j] for j in range(3)])
    chi, ss, *_ = np.linalg.lstsq(A, y, rcond=None)
    s2 = float(ss[0]) / (A.shape[0] - A.shape[1])
    assert _rel(r.chi[[0, 1, 3, 4, 5, 6, 8]], chi[[0, 1, 3, 4, 5, 6, 8]]) < 1e-10
    assert _rel(r.cov, s2 * np.linalg.inv(A.T @ A)) < 1e-8          # inv(AᵀA) itself has cond² rounding
    assert r.n_rows == A.shape[0] and r.n_samples == 2500
    assert abs(r.rel_error / (np.sqrt(float(ss[0]) / (y @ y))) - 1) < 1e-10


def test_wls_and_essential_set_of_the_chunk_sums_equal_the_in_memory_path():
    W3, tau, mask, names = _system()
    red = _reduce(W3, tau, mask, names, EDGES)
    whole = ls.wls(W3, tau, names, row_mask=mask)
    chunked = ls.wls_reduced(red)
    assert _rel(chunked.chi, whole.chi) < 1e-10 and _rel(chunked.bse.to_numpy(), whole.bse.to_numpy()) < 1e-10
    assert _rel(chunked.joint_sigma, whole.joint_sigma) < 1e-10
    assert _rel(chunked.rms, whole.rms) < 1e-10 and _rel(chunked.rel_error, whole.rel_error) < 1e-10
    assert chunked.residual.shape == (0, 3)                  # the samples are not held
    e_whole = essential_parameters(W3, tau, names, ls.wls, row_mask=mask)
    e_chunk = essential_parameters(red, None, None, ls.wls)
    assert e_whole.removed and e_chunk.removed == e_whole.removed       # the zero parameters go, in order
    assert e_chunk.essential == e_whole.essential
    assert _rel(e_chunk.result.chi, e_whole.result.chi) < 1e-10
    assert _rel(e_chunk.result.bse.to_numpy(), e_whole.result.bse.to_numpy()) < 1e-10
    np.testing.assert_allclose(e_chunk.path["rel_error"], e_whole.path["rel_error"], rtol=1e-10)


def test_reductions_refuse_mixed_models_and_sample_options():
    W3, tau, mask, names = _system(N=50)
    a = ls.reduce_system(W3, tau, names)
    with pytest.raises(InputError, match="different parameter lists"):
        a + ls.reduce_system(W3, tau, [f"Q{i}" for i in range(9)])
    with pytest.raises(InputError, match="row_mask and joints apply when a chunk is reduced"):
        essential_parameters(a, None, None, ls.wls, row_mask=mask)
