"""The DE steps' random draws taken in blocks (dynid.analysis.sampling.draws) are numpy's RandomState stream.

emcee draws a DE step's numbers one call at a time; dynid takes the draws of many steps at
once with numpy's own algorithms over the same Mersenne Twister state. They must be the
very numbers the RandomState calls give, in emcee's order, and leave the RandomState
where those calls leave it, also when a run stops inside a block.
"""
import emcee
import numpy as np
import pytest

from dynid.analysis.sampling.draws import DEDraws, StreamState
from dynid.analysis.sampling.ensemble import _pair_columns, _Sampler, emcee_moves


@pytest.mark.parametrize("nw, nsplits, steps", [(64, 2, 40), (18, 3, 25)])
def test_block_draws_are_the_randomstate_calls(nw, nsplits, steps):
    rs = np.random.RandomState(7)
    rs.randn()                                   # a cached second normal to start from
    half = nw // nsplits
    first, second = _pair_columns(nw - half)
    stream = StreamState(rs)
    dr = DEDraws(stream, steps, nw, nsplits, True, first, second)
    labels = np.arange(nw) % nsplits
    for s in range(steps):
        rs.random_sample()                       # emcee's choice among the moves
        inds = labels.copy()
        rs.shuffle(inds)
        order = np.argsort(inds, kind="stable")
        halves = [order[k * half:(k + 1) * half] for k in range(nsplits)]
        for k in range(nsplits):
            other = np.concatenate(halves[:k] + halves[k + 1:])
            pick = rs.randint(0, first.size, size=half)
            assert np.array_equal(dr.order[s, k], halves[k])
            assert np.array_equal(dr.ia[s, k], other[first[pick]])
            assert np.array_equal(dr.ib[s, k], other[second[pick]])
            assert np.array_equal(dr.normals[s, k], rs.randn(half))
            assert np.array_equal(dr.uniforms[s, k], rs.rand(half))
    after = np.random.RandomState(0)
    stream.give(after)
    a, b = rs.get_state(), after.get_state()
    assert np.array_equal(a[1], b[1]) and a[2:] == b[2:]


def _log_prob(X):
    return -0.5 * np.sum((X * np.linspace(0.5, 2.0, X.shape[1])) ** 2, axis=1)


def test_stopping_inside_a_block_leaves_emcees_stream():
    nw, d, steps = 16, 4, 37                     # stop inside the first block of draws
    p0 = np.random.default_rng(3).standard_normal((nw, d))
    seed_state = np.random.RandomState(5).get_state()
    ref = emcee.EnsembleSampler(nw, d, _log_prob, vectorize=True, moves=emcee.moves.DEMove())
    ref.random_state = seed_state
    ref.run_mcmc(p0, steps, store=False)
    ours = _Sampler(nw, d, _log_prob, vectorize=True, moves=emcee_moves("de"))
    ours.random_state = seed_state
    gen = ours.advance(p0, 1000)
    for n, (state, _) in enumerate(gen, start=1):
        last = state
        if n == steps:
            break
    gen.close()
    a, b = ref.random_state, ours.random_state
    assert np.array_equal(a[1], b[1]) and a[2:] == b[2:]
    # and the next steps continue emcee's chain
    ref.run_mcmc(None, 5)
    more = [s.coords.copy() for s, _ in ours.advance(last, 5)]
    assert np.array_equal(more[-1], ref.get_last_sample().coords)


def test_uneven_sub_ensembles_take_the_stepwise_path_with_the_same_chain():
    nw, d, steps = 15, 3, 30                     # 15 walkers: sub-ensembles of 8 and 7
    p0 = np.random.default_rng(4).standard_normal((nw, d))
    seed_state = np.random.RandomState(9).get_state()
    ref = emcee.EnsembleSampler(nw, d, _log_prob, vectorize=True, moves=emcee.moves.DEMove())
    ref.random_state = seed_state
    ref.run_mcmc(p0, steps)
    ours = _Sampler(nw, d, _log_prob, vectorize=True, moves=emcee_moves("de"))
    ours.random_state = seed_state
    chain = [s.coords.copy() for s, _ in ours.advance(p0, steps)]
    assert np.array_equal(np.array(chain), ref.get_chain())
