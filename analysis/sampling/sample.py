"""Sampling the posterior of a linear model, and of an IDIM result's parameters (emcee).

`sample_linear` runs the ensemble sampler on the log-posterior of
dynid.analysis.sampling.linear; `sample_idim` feeds it an IDIM result's
decimated observation, optionally restricted to the physically consistent set.
"""
from __future__ import annotations

import numpy as np

from dynid.analysis.estimators import least_squares as lsq
from dynid.analysis.estimators.physical import PhysicalSupport, pc_wls
from dynid.analysis.sampling.convergence import run_until_converged
from dynid.analysis.sampling.ensemble import (
    criteria_from,
    describe_moves,
    initial_ball,
    make_sampler,
    n_walkers_for,
    rng_from_seed,
)
from dynid.analysis.sampling.linear import LinearPosterior
from dynid.analysis.sampling.noise import DEFAULT_NOISE, check_noise, noise_model, sandwich_model, temper
from dynid.analysis.sampling.result import PosteriorResult
from dynid.analysis.sampling.sufficient import SufficientStats, sufficient_statistics
from dynid.errors import InputError
from dynid.provenance import data_hash
from dynid.ranges import check_range


def sample_linear(W3, tau, names, *, row_mask=None, ls=None, sigma=None, prior=None, seed=0,
                  n_walkers=None, criteria=None, max_steps=None, max_seconds=None, moves="de",
                  init_scale: float = 0.1, method_label: str = "linear model", truth=None,
                  suff_stats: SufficientStats | None = None, progress=None, support=None,
                  start=None, noise: str = DEFAULT_NOISE, robust_cov=None, groups=None,
                  _source: str | None = None) -> PosteriorResult:
    """Posterior of χ (and σ_j) of Y = Wχ + ρ by emcee; see the module docstring.

    Parameters
    ----------
    W3, tau, names, row_mask
        As `dynid.analysis.estimators.least_squares.wls` (decimated system, eq. (9)).
    ls : IdentificationResult, optional
        LS estimate to start from and to report beside the posterior (its
        χ̂, σ and %σ; its `joint_sigma` for the σ_j). Default: WLS of these
        data (with `sigma` as fixed weights when given).
    sigma : (n,) array, optional
        Known noise standard deviations: then only χ is sampled.
    prior : GaussianPrior, optional
        Gaussian prior on (some of) χ; default flat.
    seed : int or numpy.random.Generator
        Seeds the initial ball and emcee's RandomState.
    n_walkers : int, optional
        Default max(32, 2·ndim + 2), even.
    criteria : ConvergenceCriteria or dict, optional
        The convergence rule (≥ 50 τ etc.); `max_steps` and `max_seconds`
        override its limits.
    moves : "de" (default, emcee DEMove), "de-snooker", "stretch" or emcee moves.
    init_scale : float
        Walkers start at the LS estimate + init_scale · N(0, cov_LS) (for
        log σ_j the variance is 1/(2 r_j)); with "sandwich" and σ_j sampled, at the joint
        optimum (χ*, σ*) the curvature is matched at (`SufficientStats.joint_optimum`).
    suff_stats : SufficientStats, optional
        Precomputed statistics (then W3/tau are only used for `ls` if needed).
    progress : callable, optional
        `progress(n_steps, required_steps)` after each batch of the sampler.
    support : callable, optional
        `support(chi)` (K, b) -> bool (K,): the prior is restricted to where it is true
        (log p = −inf elsewhere), e.g. the physically consistent set
        (`dynid.analysis.estimators.physical.PhysicalSupport`).
    start : (b,) array, optional
        Centre of the initial ball instead of the LS estimate (it must be in `support`).
    noise : "sandwich" (default), "neff" or "white"
        The noise model of the likelihood (dynid.analysis.sampling.noise): "sandwich" matches
        the likelihood's curvature to the robust covariance of the LS fit (Ribatet, Cooley &
        Davison 2012), so that correlated rows and model error widen the posterior as they
        widen the fit's robust intervals; with σ_j sampled it is matched at the likelihood's
        joint optimum (χ*, σ*), where the posterior is centred; "neff" tempers each joint's likelihood by the
        effective sample size of its LS residual; "white" is the likelihood of independent
        rows (eq. (16)). The result's settings, summary and JSON name it.
    robust_cov : (b, b) array, optional
        For "sandwich": the robust covariance Σ_R of the estimate `ls`. Default: `ls.cov`
        when `ls` carries a robust ("bootstrap" or "hac") covariance, else the circular
        block bootstrap of the WLS with `ls`'s σ_j (dynid.analysis.estimators.hac, the
        default uncertainty of dynid identify).
    groups : (N,) array, optional
        Recording of each sample, for that bootstrap (no block crosses recordings).
    """
    rng = rng_from_seed(seed)
    if ls is None:
        ls = lsq.wls(W3, tau, names, row_mask=row_mask, joint_sigma=sigma)
    if list(ls.names) != [str(x) for x in names]:
        raise InputError("ls must be a result on the same parameters, in the same order, as names")
    st = suff_stats
    if st is None:
        st = sufficient_statistics(W3, tau, names, row_mask=row_mask, ref=ls.chi)
        st.data_hash = data_hash(np.asarray(W3), np.asarray(tau),
                                    None if row_mask is None else np.asarray(row_mask))
    noise = check_noise(noise)
    # Ribatet's adjustment is matched at the optimum of the likelihood it adjusts: with σ_j sampled,
    # at the joint (χ*, σ*), not at eq. (16)'s σ_j, which the chains leave (on the LWR4+ for σ_j 1.3-2
    # times larger: the posterior was 1.56 times too wide)
    matched = noise == "sandwich" and sigma is None
    js_ls = _joint_sigma_or_residual(st, getattr(ls, "joint_sigma", None), st.active)
    chi_start, js_start = st.joint_optimum(js_ls) if matched else (ls.chi, js_ls)
    if noise == "sandwich":
        js = js_ls if sigma is None else _joint_sigma_or_residual(st, sigma, st.active)
        robust_cov, source = _robust_cov(W3, tau, names, row_mask, ls, js, robust_cov, groups)
        source = _source or source
        if matched:
            st = st.about(chi_start)
        nm = sandwich_model(st, robust_cov, js_start if matched else js, source)
    else:
        nm = noise_model(noise, W3, tau, row_mask, st.ref)
    model = LinearPosterior(temper(st, nm), sigma=sigma, prior=prior)
    d = model.ndim
    b = st.n_params
    nw = n_walkers_for(n_walkers, d)
    centre = np.empty(d)
    centre[:b] = chi_start if start is None else np.asarray(start, dtype=float)
    log_prob = model.log_prob
    if support is not None:
        def log_prob(X, _lp=model.log_prob):
            lp = _lp(X)
            X = np.atleast_2d(X)
            fin = np.isfinite(lp)
            inside = np.zeros(lp.shape, dtype=bool)
            inside[fin] = support(X[fin, :b])
            return np.where(inside, lp, -np.inf)
    cov = np.zeros((d, d))
    cov[:b, :b] = ls.cov
    if sigma is None:
        act = model.active
        centre[b:] = np.log(js_start[act])
        cov[b:, b:] = np.diag(1.0 / (2.0 * model.stats.rows[act]))
    crit = criteria_from(criteria, max_steps=max_steps, max_seconds=max_seconds)
    p0 = initial_ball(log_prob, centre, cov, nw, init_scale, rng)
    sampler = make_sampler(log_prob, nw, d, moves, rng)
    run = run_until_converged(sampler, p0, crit, progress=progress)
    chain = model.to_output(run.kept())
    ls_value = np.full(d, np.nan)
    ls_std = np.full(d, np.nan)
    ls_value[:b] = ls.chi
    ls_std[:b] = ls.bse.to_numpy()
    if sigma is None and getattr(ls, "joint_sigma", None) is not None:
        ls_value[b:] = np.asarray(ls.joint_sigma)[model.active]
    ls_cov = np.full((d, d), np.nan)
    ls_cov[:b, :b] = ls.cov
    noise = ("known σ_j = " + ", ".join(f"{v:.4g}" for v in model.sigma[model.active])) if sigma is not None \
        else "one σ_j per joint, Jeffreys prior p(σ_j) ∝ 1/σ_j, sampled as log σ_j"
    if matched:
        # where the sandwich is matched and the chains start (sample.py: `joint_optimum`)
        nm_dict = dict(nm.to_dict(), joint_optimum={
            "chi": dict(zip(st.names, map(float, st.ref))),
            "sigma": [float(v) for v in js_start],
            "sigma_eq16": [float(v) for v in js_ls],
            "why": "the sampled sigma_j settle at sigma_j^2 = S_j(chi*)/r_j, chi* the WLS of those sigma_j; "
                   "eq. (16)'s sigma_j fit each joint alone"})
    else:
        nm_dict = nm.to_dict()
    settings = {
        "model": method_label,
        "likelihood": _LIKELIHOOD[nm.kind],
        "noise": noise,
        "noise_model": nm_dict,
        "prior_chi": "flat" if prior is None else {"gaussian": prior.to_dict()},
        "linear_parameters": "sampled jointly with the noise parameters (not marginalised)",
        "sampler": "emcee.EnsembleSampler(vectorize=True)",
        "moves": describe_moves(moves),
        "n_walkers": nw,
        "init": (f"{'the joint optimum (chi*, sigma*)' if matched else 'LS estimate'} + {init_scale:g} x "
                 f"N(0, cov_LS); log sigma_j variance 1/(2 r_j)"),
        "seed": seed if isinstance(seed, (int, np.integer)) else "numpy Generator",
        "rows_per_joint": st.rows,
        "n_samples": st.n_samples,
        "sufficient_statistics": ("per joint W'W, W'(Y - W chi_ref), |Y - W chi_ref|^2, r_j; chi_ref = "
                                  + ("chi*, the joint optimum" if matched else "LS")),
        "support": "all of R^b" if support is None else getattr(support, "description", "restricted"),
    }
    return PosteriorResult(
        method="emcee", model=method_label, names=model.names, chain=chain,
        diagnostics=run.diagnostics, ls_value=ls_value, ls_std=ls_std, ls_cov=ls_cov,
        ls_label=getattr(ls, "method", "LS"), settings=settings, truth=truth,
        data_hash=st.data_hash or getattr(ls, "data_hash", None),
        coords=model.coords)


_LIKELIHOOD = {
    "white": "Gaussian, independent rows, per-joint σ_j (eqs. (9), (10), (16))",
    "neff": "Gaussian, per-joint σ_j (eqs. (9), (10), (16)), each joint's likelihood tempered by its "
            "effective sample size n_eff,j / r_j",
    "sandwich": "Gaussian, per-joint σ_j (eqs. (9), (10), (16)), evaluated at chi_ref + C (chi - chi_ref) "
                "with C' H C the inverse of the fit's robust covariance at sigma_ref (curvature adjustment, "
                "Ribatet, Cooley & Davison 2012); (chi_ref, sigma_ref) the likelihood's joint optimum when "
                "sigma_j are sampled (noise_model.joint_optimum), else the LS estimate and the given sigma_j",
}


def _joint_sigma_or_residual(st, js, active):
    """The per-joint σ `js` (n,) or, when it is missing or not finite on an active joint (an
    OLS result has none), the LS residual's `sqrt(s_j / (r_j - b))` (eq. (16))."""
    js = np.full(st.n_joints, np.nan) if js is None else np.asarray(js, dtype=float).reshape(-1)
    if js.size != st.n_joints or not np.all(np.isfinite(js[active])):
        js = np.sqrt(st.s / np.maximum(st.rows - st.n_params, 1))
    return js


def _robust_label(ls):
    """The robust covariance option `ls` carries ("bootstrap", "hac") or None."""
    unc = ((getattr(ls, "settings", None) or {}).get("least_squares") or {}).get("uncertainty") or {}
    kind = unc.get("uncertainty") if isinstance(unc, dict) else None
    return kind if kind in ("bootstrap", "hac") else None


def _robust_cov(W3, tau, names, row_mask, ls, joint_sigma, robust_cov, groups):
    """(Σ_R, where it came from) for the sandwich noise model (see `sample_linear`)."""
    if robust_cov is not None:
        return np.asarray(robust_cov, dtype=float), "robust covariance given"
    kind = _robust_label(ls)
    if kind is not None:
        return np.asarray(ls.cov, dtype=float), f"the fit's {kind} covariance"
    if W3 is None or tau is None:
        raise InputError("the sandwich noise model needs the samples (W3, tau) or robust_cov")
    boot = lsq.wls(W3, tau, names, row_mask=row_mask, joint_sigma=joint_sigma, uncertainty="bootstrap",
                   groups=groups)
    return boot.cov, f"the {_robust_label(boot) or 'bootstrap'} covariance of the WLS fit"


def idim_robust_cov(idim_result, which: str = "essential"):
    """(Σ_R, where it came from): the robust covariance of an IDIM result's base or essential estimate.

    The result's own covariance when it was identified with a robust uncertainty
    ("bootstrap", the default of dynid identify, or "hac"); otherwise the same
    computation: the circular block bootstrap of the full WLS (its σ_j and
    recordings), and for the essential parameters the full model's covariance of
    them plus d dᵀ, d the essential minus the full estimate
    (dynid.analysis.estimators.essential, the removal bias).
    """
    ls = idim_result.essential.result if which == "essential" else idim_result.wls
    kind = _robust_label(ls)
    if kind is not None:
        return np.asarray(ls.cov, dtype=float), f"the IDIM {which} fit's {kind} covariance"
    obs = idim_result.observation
    full = idim_result.wls
    boot = lsq.wls(obs.W, obs.tau, full.names, row_mask=obs.row_mask, joint_sigma=full.joint_sigma,
                   uncertainty="bootstrap", groups=getattr(idim_result, "groups", None))
    kind = _robust_label(boot) or "bootstrap"
    if which != "essential":
        return boot.cov, f"the IDIM base fit's {kind} covariance"
    cols = [full.names.index(n) for n in ls.names]
    d = ls.chi - boot.chi[cols]
    return (boot.cov[np.ix_(cols, cols)] + np.outer(d, d),
            f"the full WLS's {kind} covariance of these parameters + d d', d the bias of removing the others")


def sample_idim(idim_result, *, which: str = "essential", physical: bool = False, robot=None,
                **kwargs) -> PosteriorResult:
    """Posterior of the essential (default) or base parameters of an `IDIMResult`.

    Uses its decimated observation (W, tau, row_mask) and its WLS estimate
    as the starting point and LS reference. Other arguments: `sample_linear`.

    `physical=True` (base parameters only): the posterior's support is the physically
    consistent set (`PhysicalSupport`: some
    standard set with PSD pseudo-inertias and Ia, Fv, Fc >= 0 gives these base parameters),
    i.e. the flat prior restricted to it; the walkers start around the PC-WLS estimate.
    `robot` defaults to the result's. `walkers` is accepted for `n_walkers` (the command line's
    and `Settings`' name).
    """
    if getattr(idim_result, "observation", None) is None or getattr(idim_result, "essential", None) is None:
        raise InputError(f"sample: give an IDIM result (dynid.identify(..., method='idim')), not "
                         f"{type(idim_result).__name__}")
    if "walkers" in kwargs:
        if "n_walkers" in kwargs:
            raise InputError("sample: give walkers or n_walkers, not both")
        kwargs["n_walkers"] = kwargs.pop("walkers")
    if not isinstance(kwargs.get("seed"), np.random.Generator):
        kwargs["seed"] = check_range("seed", kwargs.get("seed", 0))
    if kwargs.get("n_walkers") is not None:
        kwargs["n_walkers"] = check_range("walkers", kwargs["n_walkers"])
    obs = idim_result.observation
    if which == "essential":
        ls = idim_result.essential.result
    elif which == "base":
        ls = idim_result.wls
    else:
        raise InputError(f"which must be 'essential' or 'base', not {which!r}")
    cols = idim_result.columns(ls.names)
    W = obs.W[:, :, cols]
    truth = None
    if idim_result.truth:
        truth = {k: v for k, v in idim_result.truth.items() if k in ls.names}
    kwargs.setdefault("method_label", f"IDIM {which} parameters of {idim_result.robot_name}"
                      + (", physically consistent support" if physical else ""))
    if physical:
        if which != "base":
            raise InputError("the physically consistent posterior is over the base parameters: "
                             "use which='base' (--which base)")
        robot = robot if robot is not None else getattr(idim_result, "robot", None)
        if robot is None:
            raise InputError("physical=True needs the robot of the identification")
        pc = pc_wls(robot, idim_result.base, ls.chi, ls.cov, n_boot=0)
        support = PhysicalSupport(robot, idim_result.base, ls.names, reference=pc.standard)
        support.description = ("physically consistent set: some standard set with every link's "
                               "pseudo-inertia PSD and Ia, Fv, Fc >= 0 gives these base parameters "
                               "(feasibility SDP per point, cvxpy + Clarabel)")
        kwargs["support"] = support
        kwargs["start"] = pc.chi
    if check_noise(kwargs.get("noise", DEFAULT_NOISE)) == "sandwich" and kwargs.get("robust_cov") is None:
        kwargs["robust_cov"], kwargs["_source"] = idim_robust_cov(idim_result, which)
    res = sample_linear(W, obs.tau, ls.names, row_mask=obs.row_mask, ls=ls, truth=truth, **kwargs)
    res.data_hash = idim_result.data_hash or res.data_hash
    return res


