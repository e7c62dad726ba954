"""The sampler's stop depends on the chain and its step budget, not on the clock (unless asked).

A machine slowed down a million times (the clock jumps 1e6 s at every reading) must give the
same posterior as a normal one under the default settings; with an explicit `max_seconds`
the run stops on time and says so.
"""

import numpy as np

from dynid.analysis.run import Settings
from dynid.analysis.sampling import convergence
from dynid.analysis.sampling import posterior as bayes


def _problem():
    rng = np.random.default_rng(4)
    W = rng.standard_normal((300, 2, 3))
    y = W @ np.array([1.0, 2.0, 3.0]) + 0.1 * rng.standard_normal((300, 2))
    return W, y, ["a", "b", "c"]


class _SlowClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        self.t += 1e6
        return self.t


def test_a_slow_machine_gives_the_same_posterior(monkeypatch):
    W, y, names = _problem()
    fast = bayes.sample_linear(W, y, names, seed=5, n_walkers=16)
    monkeypatch.setattr(convergence.time, "perf_counter", _SlowClock())
    slow = bayes.sample_linear(W, y, names, seed=5, n_walkers=16)
    assert fast.converged and slow.converged
    assert slow.diagnostics.limit is None
    np.testing.assert_array_equal(fast.chain, slow.chain)
    assert fast.to_dict()["parameters"] == slow.to_dict()["parameters"]


def test_an_explicit_time_limit_stops_the_run_and_says_so(monkeypatch):
    W, y, names = _problem()
    monkeypatch.setattr(convergence.time, "perf_counter", _SlowClock())
    res = bayes.sample_linear(W, y, names, seed=5, n_walkers=16, max_seconds=10.0)
    assert res.diagnostics.limit == "time" and "time limit max_seconds = 10 s" in res.reason


def test_no_wall_clock_limit_by_default():
    assert convergence.ConvergenceCriteria().max_seconds is None
    assert Settings().max_seconds is None
