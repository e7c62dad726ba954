"""The emcee ensemble sampler as dynid runs it: moves, walkers, seeding, start and convergence rule.

Shared by every posterior: `rng_from_seed` makes runs reproducible,
`initial_ball` places the walkers where the posterior is positive,
`make_sampler` seeds emcee's RandomState from the run's Generator and
`criteria_from` copies the caller's convergence rule before applying overrides.
"""
from __future__ import annotations

import dataclasses

import emcee
import numpy as np

from dynid.analysis.sampling.convergence import ConvergenceCriteria
from dynid.errors import IdentificationError, InputError


def emcee_moves(moves):
    if moves is None or moves == "de":
        return emcee.moves.DEMove()
    if moves == "stretch":
        return emcee.moves.StretchMove()
    if moves == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
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
    raise IdentificationError("could not place the initial walkers where the posterior is positive; "
                              "check the LS starting point and the prior bounds")


def make_sampler(log_prob, n_walkers, d, moves, rng):
    sampler = emcee.EnsembleSampler(n_walkers, d, log_prob, vectorize=True, moves=emcee_moves(moves))
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


