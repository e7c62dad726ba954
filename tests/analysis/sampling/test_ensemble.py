"""dynid's stepping of the ensemble (dynid.analysis.sampling.ensemble) against emcee's own sampler.

`_Sampler.advance` re-implements emcee's red-blue step for speed; it must draw the same
random numbers in the same order and make the same decisions, so the chain is emcee's
bit for bit, for every move dynid offers (and for emcee moves given by the user).
"""
import emcee
import numpy as np
import pytest

from dynid.analysis.sampling.ensemble import _Sampler, emcee_moves


def _log_prob(X):
    # a correlated Gaussian with one heavy direction, vectorised over walkers; -inf in a slab
    # so that some proposals are refused outright
    A = np.linspace(0.5, 2.0, X.shape[1])
    lp = -0.5 * np.sum((X * A) ** 2, axis=1) - 0.5 * (X[:, 0] - X[:, 1]) ** 2
    return np.where(X[:, 2] > 3.0, -np.inf, lp)


@pytest.mark.parametrize("moves", ["de", "stretch", "de-snooker", "de3"])
def test_advance_is_emcees_chain_bit_for_bit(moves):
    nw, d, steps = 16, 5, 60
    p0 = np.random.default_rng(3).standard_normal((nw, d))
    if moves == "de3":                       # three sub-ensembles: the complement of two halves
        ours_moves, ref_moves = emcee_moves("de"), emcee.moves.DEMove()
        ours_moves.nsplits = ref_moves.nsplits = 3
        nw, p0 = 18, np.random.default_rng(3).standard_normal((18, d))
    else:
        ours_moves = emcee_moves(moves)
        ref_moves = {"de": emcee.moves.DEMove(), "stretch": emcee.moves.StretchMove(),
                     "de-snooker": [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]}[moves]
    seed_state = np.random.RandomState(42).get_state()

    ref = emcee.EnsembleSampler(nw, d, _log_prob, vectorize=True, moves=ref_moves)
    ref.random_state = seed_state
    ref.run_mcmc(p0, steps)
    ref_chain, ref_lp = ref.get_chain(), ref.get_log_prob()

    ours = _Sampler(nw, d, _log_prob, vectorize=True, moves=ours_moves)
    ours.random_state = seed_state
    chain, lps, acc = [], [], np.zeros(nw)
    for st, accepted in ours.advance(p0, steps, check=True):
        chain.append(st.coords.copy())
        lps.append(st.log_prob.copy())
        acc += accepted
    assert np.array_equal(np.array(chain), ref_chain)
    assert np.array_equal(np.array(lps), ref_lp)
    assert np.array_equal(acc, ref.backend.accepted)
    assert 0 < acc.sum() < nw * steps                # some moves refused, some accepted


def test_advance_refuses_a_non_finite_position_as_emcee_does():
    s = _Sampler(8, 2, lambda X: -np.sum(X ** 2, axis=1), vectorize=True, moves=emcee_moves("de"))
    with pytest.raises(ValueError, match="infinite"):
        s._evaluator()(np.array([[0.0, np.inf]]))
    with pytest.raises(ValueError, match="NaN"):
        s._evaluator()(np.array([[np.nan, 0.0]]))
