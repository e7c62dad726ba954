"""The emcee ensemble sampler as dynid runs it: moves, walkers, seeding, start and convergence rule.

Shared by every posterior: `rng_from_seed` makes runs reproducible,
`initial_ball` places the walkers where the posterior is positive,
`make_sampler` seeds emcee's RandomState from the run's Generator and
`criteria_from` copies the caller's convergence rule before applying overrides.
`_Sampler.advance` steps emcee's moves without emcee's per-step bookkeeping; with dynid's
default DEMove it takes the random draws of a block of steps at once from the same
RandomState stream and runs each sub-ensemble's proposal and acceptance compiled
(dynid.analysis.sampling.draws): the chain is emcee's bit for bit (tests/analysis/sampling).
"""
from __future__ import annotations

import dataclasses
import functools
import math

import emcee
import numpy as np
from emcee.ensemble import walkers_independent
from emcee.model import Model
from emcee.state import State

from dynid.analysis.sampling import draws
from dynid.analysis.sampling.convergence import ConvergenceCriteria
from dynid.errors import IdentificationError, InputError


class _VectorAccept:
    """emcee's red-blue `propose` with the acceptance of a half-ensemble drawn and decided at
    once: one uniform per walker, in walker order, as emcee's loop draws them one by one (the
    same RandomState stream, the same decisions), without a Python step per walker."""

    def propose(self, model, state):
        nwalkers, ndim = state.coords.shape
        if nwalkers < 2 * ndim and not self.live_dangerously:
            raise RuntimeError("It is unadvisable to use a red-blue move with fewer walkers than "
                               "twice the number of dimensions.")
        self.setup(state.coords)
        accepted = np.zeros(nwalkers, dtype=bool)
        all_inds = np.arange(nwalkers)
        inds = all_inds % self.nsplits
        if self.randomize_split:
            model.random.shuffle(inds)
        for split in range(self.nsplits):
            S1 = inds == split
            sets = [state.coords[inds == j] for j in range(self.nsplits)]
            q, factors = self.get_proposal(sets[split], sets[:split] + sets[split + 1:], model.random)
            new_log_probs, new_blobs = model.compute_log_prob_fn(q)
            idx = all_inds[S1]
            lnpdiff = factors + new_log_probs - state.log_prob[idx]
            accepted[idx] = lnpdiff > np.log(model.random.rand(idx.size))
            state = self.update(state, State(q, log_prob=new_log_probs, blobs=new_blobs), accepted, S1)
        return state, accepted


class _DEMove(_VectorAccept, emcee.moves.DEMove):
    """emcee's DEMove with the same draws (RandomState.choice over the pairs is randint over
    their count) in fewer array operations: it runs twice per step."""

    def get_proposal(self, s, c, random):
        c = c[0] if len(c) == 1 else np.concatenate(c, axis=0)
        ns = s.shape[0]
        pairs = _nondiagonal_pairs(c.shape[0])
        pick = pairs[random.randint(0, pairs.shape[0], size=ns)]
        gamma = self.g0 * (1 + self.sigma * random.randn(ns, 1))
        return s + gamma * (c[pick[:, 1]] - c[pick[:, 0]]), np.zeros(ns)

    def proposal(self, coords, idx, other, random):
        """`get_proposal(coords[idx], [coords[other]], random)` from the walkers' indices (the
        same draws and positions) without copying the two halves; its factors are zero,
        returned as None."""
        first, second = _pair_columns(other.size)
        pick = random.randint(0, first.size, size=idx.size)
        gamma = self.g0 * (1 + self.sigma * random.randn(idx.size, 1))
        return coords[idx] + gamma * (coords[other[second[pick]]] - coords[other[first[pick]]]), None


@functools.lru_cache(maxsize=4)
def _nondiagonal_pairs(n):
    """The pairs (i, j), i != j, in the order of emcee.moves.de (its draws index them)."""
    rows, cols = np.tril_indices(n, -1)
    return np.column_stack([np.concatenate([rows, cols]), np.concatenate([cols, rows])])


@functools.lru_cache(maxsize=4)
def _pair_columns(n):
    """The two columns of `_nondiagonal_pairs(n)`, each contiguous."""
    pairs = _nondiagonal_pairs(n)
    return np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])


class _DESnookerMove(_VectorAccept, emcee.moves.DESnookerMove):
    pass


class _StretchMove(_VectorAccept, emcee.moves.StretchMove):
    pass


class _Sampler(emcee.EnsembleSampler):
    """emcee's sampler for a vectorised log-probability that returns one float per walker and
    no blobs: the values are taken as one array (emcee converts them one by one)."""

    def compute_log_prob(self, coords):
        if np.any(np.isinf(coords)):
            raise ValueError("At least one parameter value was infinite")
        if np.any(np.isnan(coords)):
            raise ValueError("At least one parameter value was NaN")
        lp = np.asarray(self.log_prob_fn(coords))
        if lp.shape != (coords.shape[0],) or lp.dtype.kind not in "fi":
            return super().compute_log_prob(coords)      # blobs or another shape: emcee's way
        return np.array(lp, dtype=np.float64), None

    def _evaluator(self):
        """`compute_log_prob(q)[0]` with the fewest calls on the common path: one finiteness
        test of the positions, the user's function called directly (not through emcee's
        wrapper), its float64 array used as it is (the step copies what it keeps)."""
        wrapper, compute = self.log_prob_fn, self.compute_log_prob
        fn = wrapper.f if not (wrapper.args or wrapper.kwargs) else wrapper

        def evaluate(q):
            if not math.isfinite(q.sum()):
                # an inf or NaN position (or a sum that overflows): emcee's checks and error
                return compute(q)[0]
            lp = fn(q)
            if type(lp) is np.ndarray and lp.dtype == np.float64 and lp.shape == (q.shape[0],):
                return lp
            return compute(q)[0]
        return evaluate

    def advance(self, state, iterations: int, check: bool = False):
        """Yield (state, accepted) after each of `iterations` steps from `state` (a State or an
        (n_walkers, d) array): emcee's `sample(store=False)` step for step (the same move choice,
        proposals and acceptance from the same RandomState, hence the same chain) without its
        per-step bookkeeping (a copy of the 624-word random state at every step, a progress
        bar, the backend); `accepted` (n_walkers,) bool is the step's acceptance.
        `check`: emcee's test that the initial walkers are linearly independent."""
        state = State(state, copy=True)
        if check and not walkers_independent(state.coords):
            raise ValueError("Initial state has a large condition number. Make sure that your walkers "
                             "are linearly independent for the best performance")
        if state.log_prob is None:
            state.log_prob, state.blobs = self.compute_log_prob(state.coords)
            if np.any(np.isnan(state.log_prob)):
                raise ValueError("The initial log_prob was NaN")
        if len(self._moves) == 1 and isinstance(self._moves[0], _VectorAccept):
            yield from self._red_blue_steps(state, int(iterations), self._moves[0])
            return
        model = Model(self.log_prob_fn, self.compute_log_prob, map, self._random)
        for _ in range(int(iterations)):
            move = self._random.choice(self._moves, p=self._weights)   # kept: it draws from the stream
            state, accepted = move.propose(model, state)
            yield state, accepted

    def _red_blue_steps(self, state, iterations, move):
        """One red-blue move, step after step, on the state's arrays in place: the draws of
        emcee's loop in its order (the move's choice, the split's shuffle, each half's
        proposal and uniforms), without a State object and an update per half-step. The
        halves are index arrays (emcee's complement: the other halves in split order); a move
        with `proposal` (de) draws from them without copying the halves."""
        rnd = self._random
        coords, lp = state.coords, state.log_prob
        nwalkers, ndim = coords.shape
        if nwalkers < 2 * ndim and not move.live_dangerously:
            raise RuntimeError("It is unadvisable to use a red-blue move with fewer walkers than "
                               "twice the number of dimensions.")
        nsplits = move.nsplits
        split_of = np.arange(nwalkers) % nsplits
        # each half's walkers in walker order: one stable sort of the shuffled labels
        ends = np.cumsum(np.bincount(split_of, minlength=nsplits)).tolist()
        cuts = [slice(a, b) for a, b in zip([0] + ends[:-1], ends)]
        evaluate = self._evaluator()
        if (type(move) is _DEMove and nwalkers % nsplits == 0 and coords.dtype == np.float64
                and coords.flags.c_contiguous and lp.dtype == np.float64 and lp.flags.c_contiguous
                and rnd.get_state()[0] == "MT19937"):
            yield from self._de_steps(state, iterations, move, evaluate)
            return
        proposal = getattr(move, "proposal", None)
        for _ in range(iterations):
            rnd.random_sample()            # emcee's choice among the moves: one uniform
            move.setup(coords)
            accepted = np.zeros(nwalkers, dtype=bool)
            inds = split_of.copy()
            if move.randomize_split:
                rnd.shuffle(inds)
            order = np.argsort(inds, kind="stable")
            halves = [order[c] for c in cuts]
            for split in range(nsplits):
                idx = halves[split]
                others = halves[:split] + halves[split + 1:]
                if proposal is not None:
                    q, factors = proposal(coords, idx, others[0] if nsplits == 2 else np.concatenate(others),
                                          rnd)
                else:
                    q, factors = move.get_proposal(coords[idx], [coords[o] for o in others], rnd)
                new_lp = evaluate(q)
                # emcee accepts if factors + new_lp - lp > log(u): zero factors, the same decisions
                diff = new_lp - lp[idx] if factors is None else factors + new_lp - lp[idx]
                acc = diff > np.log(rnd.rand(idx.size))
                accepted[idx] = acc
                moved = idx[acc]
                coords[moved] = q[acc]
                lp[moved] = new_lp[acc]
            yield state, accepted

    def _de_steps(self, state, iterations, move, evaluate, block=256):
        """`_red_blue_steps` for dynid's DEMove with equal sub-ensembles: the random draws of
        up to `block` steps taken at once (dynid.analysis.sampling.draws, the same stream), the
        proposal and the acceptance of a sub-ensemble in one compiled pass each. The
        RandomState is left where emcee's would be after the steps yielded, also when the
        caller stops early."""
        rnd = self._random
        coords, lp = state.coords, state.log_prob
        nwalkers = coords.shape[0]
        nsplits = move.nsplits
        first, second = _pair_columns(nwalkers - nwalkers // nsplits)
        stream = draws.StreamState(rnd)
        half = nwalkers // nsplits
        q_shape, lp_shape = (half, coords.shape[1]), (half,)
        done = 0
        while done < iterations:
            m = min(block, iterations - done)
            start = stream.copy()
            move.setup(coords)
            dr = draws.DEDraws(stream, m, nwalkers, nsplits, move.randomize_split, first, second)
            stream.give(rnd)
            # the step sizes and log-uniforms as emcee computes them, elementwise on the block
            gamma = move.g0 * (1 + move.sigma * dr.normals)
            log_u = np.log(dr.uniforms)
            taken = 0
            accepted = np.zeros((m, nwalkers), dtype=bool)     # row s: step s's acceptance
            try:
                for s in range(m):
                    for split in range(nsplits):
                        q = np.empty(q_shape)
                        draws.propose(coords, dr.order, dr.ia, dr.ib, gamma, s, split, q)
                        new_lp = evaluate(q)
                        if type(new_lp) is not np.ndarray or new_lp.dtype != np.float64:
                            new_lp = np.ascontiguousarray(new_lp, dtype=np.float64)
                        if new_lp.shape != lp_shape:     # the compiled test reads new_lp[k] unchecked
                            raise ValueError(f"the log-probability returned shape {new_lp.shape} for "
                                             f"{lp_shape[0]} walkers")
                        draws.accept(coords, lp, dr.order, s, split, q, new_lp, log_u, accepted[s])
                    taken = s + 1
                    yield state, accepted[s]
            finally:
                if taken < m:
                    # stopped inside the block: the stream as after the steps taken
                    stream = start
                    if taken:
                        draws.DEDraws(stream, taken, nwalkers, nsplits, move.randomize_split, first, second)
                    stream.give(rnd)
            done += m


def emcee_moves(moves):
    if moves is None or moves == "de":
        return _DEMove()
    if moves == "stretch":
        return _StretchMove()
    if moves == "de-snooker":
        return [(_DEMove(), 0.8), (_DESnookerMove(), 0.2)]
    if isinstance(moves, str):
        raise InputError(f"moves must be 'de', 'de-snooker', 'stretch' or emcee move object(s), not {moves!r}")
    return moves


def describe_moves(moves) -> str:
    return moves if isinstance(moves, str) else ("de" if moves is None else repr(moves))


def n_walkers_for(n_walkers, d):
    if n_walkers is None:
        n_walkers = max(32, 2 * d + 2)
        n_walkers += n_walkers % 2
    n_walkers = int(n_walkers)
    if n_walkers < 2 * d:
        raise InputError(f"n_walkers = {n_walkers} is fewer than twice the {d} sampled dimensions; "
                         f"use at least {2 * d + 2}")
    return n_walkers


def rng_from_seed(seed):
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        raise InputError("seed must be an int (or a numpy Generator): runs are reproducible by design")
    return np.random.default_rng(seed)


def initial_ball(log_prob, centre, cov, n_walkers, init_scale, rng):
    """Walkers centre + init_scale · N(0, cov), each with a finite log-probability."""
    d = centre.size
    cov = 0.5 * (cov + cov.T)
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, 1e-300)
    L = V * np.sqrt(w)
    p0 = centre + init_scale * rng.standard_normal((n_walkers, d)) @ L.T
    for _ in range(100):
        bad = ~np.isfinite(log_prob(p0))
        if not bad.any():
            return p0
        p0[bad] = centre + init_scale * rng.standard_normal((int(bad.sum()), d)) @ L.T
    raise IdentificationError("could not place the initial walkers where the posterior is positive: around "
                              "the least-squares estimate, within its covariance, the density cannot be "
                              "evaluated (a recording too short or too poorly excited for its parameters, "
                              "which the identification's %σ shows; or a prior that excludes the estimate). "
                              "Record longer or richer motion, or check the prior bounds")


def make_sampler(log_prob, n_walkers, d, moves, rng):
    sampler = _Sampler(n_walkers, d, log_prob, vectorize=True, moves=emcee_moves(moves))
    # emcee 3.1 draws from a numpy RandomState; seed it from the run's Generator
    sampler.random_state = np.random.RandomState(int(rng.integers(0, 2**32 - 1))).get_state()
    return sampler


def criteria_from(criteria, **overrides):
    if criteria is None:
        criteria = ConvergenceCriteria()
    elif isinstance(criteria, dict):
        criteria = ConvergenceCriteria(**criteria)
    elif isinstance(criteria, ConvergenceCriteria):
        criteria = dataclasses.replace(criteria)       # never modify the caller's object
    else:
        raise InputError(f"criteria must be a ConvergenceCriteria or a dict, not {type(criteria).__name__}")
    for k, v in overrides.items():
        if v is not None:
            setattr(criteria, k, v)
    criteria.__post_init__()
    return criteria


