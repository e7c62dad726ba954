"""The diagnosis' fast paths give the numbers of the direct computations they replace.

Each reference is written here from the definition (interpolate, zero in the dead zone,
decimate; a second observation without the dead zone; permute, bin, transform), not
taken from the code under test. Synthetic planar 2R motion (positions only matter: the
regressor is the robot's), a few seconds at 500 Hz: well under a second in all.
"""
import numpy as np
import pytest

from dynid.analysis.data.experiment import Experiment
from dynid.analysis.diagnosis import structure
from dynid.analysis.diagnosis.effect_observation import observe_effects
from dynid.analysis.diagnosis.rest import REST_MODELS, _all_samples, coulomb_signal
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot_file import load_robot
from dynid.errors import InputError


@pytest.fixture(scope="module")
def planar():
    robot = load_robot("planar2")
    bp = base_parameters(robot)
    fs, rng = 500.0, np.random.default_rng(4)
    t = np.arange(int(4.0 * fs)) / fs
    f = np.array([0.25, 0.4, 0.7])
    a = rng.uniform(0.3, 0.6, (3, 2))
    ph = rng.uniform(0, 2 * np.pi, (3, 2))
    q = np.einsum("kj,tkj->tj", a, np.sin(2 * np.pi * f[:, None] * t[:, None, None] + ph))
    tau = rng.standard_normal(q.shape)
    exp = Experiment(t=t, q=q, qr=q, tau=tau, fs=fs, source="planar2 multisine")
    settings = {"qd_threshold": 0.05, "nd": 5}
    return robot, bp, exp, settings, observe_effects(exp, robot, bp, settings, cache_regressor="auto")


def _shifted_by_definition(eobs, d):
    """W(t - d) by linear interpolation of the full-rate regressor (ends held), zeroed in the
    dead zone, decimated column by column."""
    N, n, k = eobs.W_full.shape
    x = np.arange(N) - d * eobs.fs
    i0 = np.floor(x).astype(int)
    f = (x - i0)[:, None, None]
    W = (1 - f) * eobs.W_full[np.clip(i0, 0, N - 1)] + f * eobs.W_full[np.clip(i0 + 1, 0, N - 1)]
    W = W * (~eobs.dead)[:, :, None]
    return eobs._decimate_2d(W.reshape(N, n * k)).reshape(-1, n, k)


@pytest.mark.parametrize("d", [0.0031, -0.004, 0.0])
def test_shifted_regressor_equals_its_definition(planar, d):
    robot, bp, exp, settings, eobs = planar
    nz = np.any(eobs.W_full != 0, axis=0)
    assert 0 < nz.sum() < nz.size            # identically zero pairs exist: the pairs path runs
    cols = np.arange(len(bp.names))
    ref = _shifted_by_definition(eobs, d)
    got = eobs.shifted_regressor(cols, d)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    assert np.all(got[:, ~nz] == 0.0)
    # a subset of the columns, and without the cached full-rate regressor
    sub = cols[1::2]
    np.testing.assert_allclose(eobs.shifted_regressor(sub, d), ref[:, :, sub], rtol=1e-12,
                               atol=1e-12 * np.abs(ref).max())
    uncached = observe_effects(exp, robot, bp, settings, cache_regressor=False)
    np.testing.assert_allclose(uncached.shifted_regressor(cols, d), ref, rtol=1e-12,
                               atol=1e-12 * np.abs(ref).max())


def test_observation_without_decimation_keeps_every_chunk(planar):
    """The chunks' regressor is built into one reused buffer: without decimation each chunk
    must still be its own rows (here several chunks: the chunk length is lowered)."""
    import dynid.analysis.diagnosis.effect_observation as eo
    robot, bp, exp, settings, _ = planar
    old = eo.CHUNK
    try:
        eo.CHUNK = 500
        e1 = observe_effects(exp, robot, bp, dict(settings, nd=1), cache_regressor="auto")
    finally:
        eo.CHUNK = old
    e2 = observe_effects(exp, robot, bp, dict(settings, nd=1), cache_regressor="auto")
    np.testing.assert_array_equal(e1.obs.W, e2.obs.W)
    np.testing.assert_array_equal(e1.W_full, e2.W_full)


def test_all_samples_residuals_equal_a_second_observation_without_dead_zone(planar):
    robot, bp, exp, settings, eobs = planar
    names = list(bp.names)
    cols = np.arange(len(names))
    chi = np.random.default_rng(1).standard_normal(len(names))
    fc = {j: names.index(f"Fc{j + 1}") for j in range(robot.n_joints)}
    got = _all_samples(cols, chi, eobs, fc)
    # by definition: the recording observed again with the dead zone off
    e0 = observe_effects(exp, robot, bp, dict(eobs.settings, qd_threshold=0.0))
    tau = e0.obs.tau
    res0 = tau - e0.obs.W @ chi
    np.testing.assert_allclose(got["tau"], tau, rtol=0, atol=0)
    scale = np.abs(res0).max()
    for m in REST_MODELS:
        ref = res0.copy()
        for j, k in fc.items():
            dead = eobs.dead[:, j]
            d = (e0.decimate(coulomb_signal(eobs.qd[:, j], dead, m), joint=j)
                 - e0.decimate(coulomb_signal(eobs.qd[:, j], dead, "sign(qd)"), joint=j))[:, j, 0]
            ref[:, j] -= chi[k] * d
        np.testing.assert_allclose(got["res"][m], ref, rtol=0, atol=1e-12 * scale)


def _mean_power_by_definition(gi, y, L, n_perm, seed):
    P = np.array([structure._position_power(gi, y[p])
                  for p in structure._block_perms(y.size, L, n_perm, np.random.default_rng(seed))])
    return P.mean(axis=0)


@pytest.mark.parametrize("n, L", [(5003, 40), (4000, 40), (300, 7)])
def test_block_permutation_power_is_the_mean_over_the_permuted_orders(n, L):
    rng = np.random.default_rng(n)
    y = rng.standard_normal(n)
    gi = rng.integers(0, structure.GRID, n)
    ref = _mean_power_by_definition(gi, y, L, 37, seed=2)
    got = structure._perm_power(gi, y, L, 37, np.random.default_rng(2))
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * ref.max())


def test_identification_from_the_effect_observation_is_identify_idims(planar):
    """`dynid diagnose` identifies from the diagnosis' observation (one regressor build): it is
    `observe`'s system field by field, notices included, and IDIM from it is bit-identical."""
    from dynid.analysis.estimators.idim import identify_idim
    from dynid.analysis.processing.observation import observe
    robot, bp, exp, settings, eobs = planar
    o = observe(exp, robot, bp, settings)
    for a in ("W", "tau", "t", "q", "qd", "qdd", "row_mask"):
        assert np.array_equal(getattr(o, a), getattr(eobs.obs, a)), a
    assert (o.names, o.settings, o.notices, o.n_raw) == (
        eobs.obs.names, eobs.obs.settings, eobs.obs.notices, eobs.obs.n_raw)
    ref = identify_idim(exp, robot, settings=settings, bp=bp)
    got = identify_idim(exp, robot, settings=settings, bp=bp, observation=eobs.obs)
    for r, g in ((ref.ols, got.ols), (ref.wls, got.wls), (ref.model, got.model)):
        assert list(r.names) == list(g.names)
        assert np.array_equal(r.chi, g.chi) and np.array_equal(r.bse.to_numpy(), g.bse.to_numpy())
    assert ref.notices == got.notices


@pytest.mark.parametrize("nd", [5, 1])
def test_position_noise_residual_is_observes_residual(planar, nd):
    """The position-noise floor's residual from the full-rate model torque is the residual of
    `observe`'s decimated system (the decimation is linear), row mask included."""
    from dynid.analysis.processing.observation import observe, observed_residual
    robot, bp, exp, settings, _ = planar
    o = observe(exp, robot, bp, dict(settings, nd=nd))
    cols = np.arange(0, len(bp.names), 2)
    chi = np.random.default_rng(1).normal(size=cols.size)
    r, mask = observed_residual(exp, robot, bp, o.settings, cols, chi)
    ref = o.tau - o.W[:, :, cols] @ chi
    assert np.array_equal(mask, o.row_mask)
    np.testing.assert_allclose(r, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_small_pages_inside_the_diagnosis_and_restored_after(monkeypatch):
    """dynid's commands turn numpy's huge-page advice off for their work only, unless the user
    chose (NUMPY_MADVISE_HUGEPAGE)."""
    mm = pytest.importorskip("numpy._core.multiarray")
    from dynid.pages import small_pages as _small_pages
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    start = mm._set_madvise_hugepage(True)
    try:
        with _small_pages():
            assert mm._set_madvise_hugepage(False) is False
        assert mm._set_madvise_hugepage(True) is True
        monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")
        with _small_pages():
            assert mm._set_madvise_hugepage(True) is True
    finally:
        mm._set_madvise_hugepage(start)


def test_pc_wls_without_the_consistency_check_is_the_same_fit():
    # the diagnosis' physical test asks pc_wls for the fit alone (check_wls=False): the same
    # estimate, chi2, p and active constraints as the full call, only wls_consistent left out
    pytest.importorskip("cvxpy")
    import bias_scenarios as bs

    from dynid.analysis.estimators.physical import pc_wls
    robot, bp, _, beta = bs.pendulum()
    b = beta.copy()
    b[bp.names.index("ZZ1R")] = -0.05          # no rigid body: a constraint is active
    cov = np.diag((np.abs(beta) * 0.01 + 1e-3) ** 2)
    full = pc_wls(robot, bp, b, cov, n_boot=0)
    fit = pc_wls(robot, bp, b, cov, n_boot=0, check_wls=False)
    assert full.wls_consistent is False and fit.wls_consistent is None
    assert np.array_equal(fit.chi, full.chi) and np.array_equal(fit.standard, full.standard)
    assert (fit.chi2, fit.p_value, fit.dof, fit.active) == (full.chi2, full.p_value, full.dof, full.active)
    assert fit.p_value < 1e-3


def test_regressor_kept_as_pairs_gives_the_same_numbers(planar):
    """`cache_regressor="pairs"` keeps only the regressor's pairs that are not identically
    zero: every method gives the numbers of the full regressor, bit for bit."""
    from dynid.analysis.diagnosis.problem import without_parameters
    robot, bp, exp, settings, full = planar
    pairs = observe_effects(exp, robot, bp, settings, cache_regressor="pairs")
    assert pairs.W_full is None and pairs.pairs.data.shape[1] < full.W_full[0].size
    n, b = pairs.pairs.shape
    rebuilt = np.zeros((pairs.n_full, n * b))
    pairs.pairs.fill(slice(None), rebuilt)
    assert np.array_equal(rebuilt.reshape(full.W_full.shape), full.W_full)
    for a in ("W", "tau", "row_mask"):
        assert np.array_equal(getattr(pairs.obs, a), getattr(full.obs, a)), a
    assert np.array_equal(pairs._nonzero_pairs(), np.any(full.W_full != 0, axis=0))
    cols = np.arange(b)
    rng = np.random.default_rng(3)
    chi = rng.standard_normal(b)
    for c in (cols, cols[1::2]):
        assert np.array_equal(pairs.model_torque(c, chi[:c.size]), full.model_torque(c, chi[:c.size]))
        for d in (0.0031, -0.004, 0.0):
            assert np.array_equal(pairs.shifted_regressor(c, d), full.shifted_regressor(c, d))
    sub = without_parameters(bp, ("Off",))
    p2, f2 = pairs.with_base(sub), full.with_base(sub)
    c2 = np.arange(len(sub.names))
    assert np.array_equal(p2.shifted_regressor(c2, 0.0031), f2.shifted_regressor(c2, 0.0031))


def test_regressor_pairs_fall_back_to_the_full_regressor(planar, monkeypatch):
    """A pair the structural probe calls zero but the recording does not: the full regressor
    is kept instead, the same as without pairs."""
    import dynid.analysis.diagnosis.effect_observation as eo
    robot, bp, exp, settings, full = planar
    nz = np.any(full.W_full != 0, axis=0).ravel()
    missed = nz.copy()
    missed[np.flatnonzero(nz)[-1]] = False
    monkeypatch.setattr(eo, "_structural_pairs", lambda robot, columns: missed)
    got = observe_effects(exp, robot, bp, settings, cache_regressor="pairs")
    assert got.pairs is None
    np.testing.assert_array_equal(got.W_full, full.W_full)


def test_model_torques_in_one_pass_are_model_torque_each(planar):
    robot, bp, exp, settings, eobs = planar
    cols = np.arange(len(bp.names))
    rng = np.random.default_rng(5)
    chi = rng.standard_normal(cols.size)
    ex = rng.random(cols.size) < 0.4
    for e in (eobs, observe_effects(exp, robot, bp, settings, cache_regressor="pairs")):
        a, b = e.model_torques(cols, [(chi, None), (chi, ex)])
        assert np.array_equal(a, e.model_torque(cols, chi))
        assert np.array_equal(b, e.model_torque(cols, chi, exclude=ex))


def test_line_confirmation_not_needed_draws_the_same_permutations():
    """With the full-data p at 1 the confirmation is not computed, but the generator is left
    where the computation leaves it: the tests after it draw the same permutations."""
    rng0 = np.random.default_rng(8)
    n = 3001
    e = rng0.standard_normal(n)
    gi = rng0.integers(0, structure.GRID, n)
    sel = np.zeros(structure.GRID + 1, dtype=bool)
    sel[10:200] = True
    r1, r2 = np.random.default_rng(3), np.random.default_rng(3)
    structure._line_confirmation(gi, e, sel, 40, 11, r1)
    assert structure._line_confirmation(gi, e, sel, 40, 11, r2, needed=False) == 1.0
    assert r1.integers(0, 2 ** 62) == r2.integers(0, 2 ** 62)


def test_an_unknown_cache_regressor_is_refused(planar):
    robot, bp, exp, settings, _ = planar
    with pytest.raises(InputError, match="cache_regressor.*'pair'"):
        observe_effects(exp, robot, bp, settings, cache_regressor="pair")
