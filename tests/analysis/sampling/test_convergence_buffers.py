"""The convergence checks on buffers kept between the checks of a run (dynid.analysis.sampling.convergence.Workspace).

A run checks chains of different lengths on the same buffers; nothing of an earlier,
longer chain may leak into a later estimate, and the estimates must be those of fresh
arrays bit for bit (the stopping decisions and the reported τ history depend on them).
"""
import emcee
import numpy as np

from dynid.analysis.sampling.convergence import Workspace, integrated_time, split_rhat


def _ar_chain(T, W, d, seed):
    rng = np.random.default_rng(seed)
    x = np.zeros((T, W, d))
    for t in range(1, T):
        x[t] = 0.8 * x[t - 1] + rng.standard_normal((W, d))
    return x


def test_reused_buffers_give_fresh_results_bit_for_bit():
    ws = Workspace()
    for T, W, d, seed in [(700, 8, 5, 1), (300, 8, 5, 2), (1100, 6, 3, 3), (90, 8, 5, 4), (700, 8, 5, 1)]:
        x = _ar_chain(T, W, d, seed)
        assert np.array_equal(integrated_time(x, work=ws), integrated_time(x))
        assert np.array_equal(split_rhat(x, work=ws), split_rhat(x))
        post = x[T // 3:]                       # a view, as the post-burn-in chain is
        assert np.array_equal(integrated_time(post, work=ws), integrated_time(np.array(post)))
    np.testing.assert_allclose(integrated_time(x, work=ws), emcee.autocorr.integrated_time(x, tol=0), rtol=1e-9)


def test_split_rhat_is_the_textbook_formula_in_any_layout():
    x = _ar_chain(401, 6, 3, 7) * [1.0, 10.0, 0.1]
    x[:, 0, 2] += 0.5                           # one walker off: R-hat > 1 for that parameter
    n = 200
    halves = np.concatenate([x[:n], x[-n:]], axis=1)
    m = halves.shape[1]
    B = n / (m - 1) * ((halves.mean(0) - halves.mean(0).mean(0)) ** 2).sum(0)
    Wv = halves.var(0, ddof=1).mean(0)
    want = np.sqrt(((n - 1) / n * Wv + B / n) / Wv)
    np.testing.assert_allclose(split_rhat(x), want, rtol=1e-12)
    np.testing.assert_allclose(split_rhat(np.asfortranarray(x)), want, rtol=1e-12)
    assert split_rhat(x)[2] > 1.05 > split_rhat(x)[0]


def test_a_parameter_that_never_moves_has_no_autocorrelation_time():
    x = _ar_chain(200, 4, 2, 9)
    x[:, :, 1] = 0.1                            # constant (the mean of 0.1s is not exactly 0.1)
    tau = integrated_time(x, work=Workspace())
    assert np.isfinite(tau[0]) and np.isnan(tau[1])


def test_integrated_time_is_nan_for_a_constant_or_nan_parameter_only():
    x = _ar_chain(300, 6, 5, 12)
    x[:, :, 1] = 0.1                 # constant, and its mean is not exactly 0.1 in floating point
    x[5, 0, 2] = np.nan
    x[[0, -1], :, 4] = 0.3           # varies, but not among the first and last draws
    tau = integrated_time(x)
    assert np.isfinite(tau[[0, 3, 4]]).all() and np.isnan(tau[[1, 2]]).all()
