"""Do dynid's intervals contain what the next recording finds? (issue 26)

Real data only; each recording (or segment) is identified alone with dynid's default
IDIM processing, once per covariance option (``classic``: eqs. (14)-(15) of Gautier
et al.; ``hac``; ``bootstrap``); the estimates are identical across options, only
σ changes. For the per-joint WLS estimates of every pair of runs, the parameters with
%σ ≤ 10 % in both runs give z = (χa − χb)/√(σa² + σb²): the fraction with |z| ≤ 1.96
(95 % expected), the count of pairs and the median |z| (0.67 expected).

* KUKA LWR4+: recordings 1, 2 and 3 (examples/kuka_lwr4/recording_N.toml), robot kuka_lwr4.
* Staubli TX40: the 9 s log (examples/staubli_tx40/experiment.toml), its decimated
  system built once with the default settings, then cut into three 3 s segments (row
  masks), each fitted alone (WLS, its own σ_j); a parameter a segment cannot identify
  (Fcm6 in the last 3 s) is left out of that segment's pairs.
* Franka Panda: the log (shared data folder, GPL-3.0, converted on the fly to a temporary
  folder) with the example's settings (fc 45 Hz, nd 20, cut-off 4 Hz), cut into halves
  the same way.

Beside the options, ``+segments`` adds to the option's variance the between-segment
variance τ² (DerSimonian-Laird) of three contiguous segments of the same run, each
fitted with the run's weights (what one recording can say about its own model
error), and ``+segments/K`` adds τ²/3 (the variance of the average of three
independent segment biases). The cross-recording random-effects pooling and χ² test
of equal parameters are printed for each data set, and for each LWR4+ recording how
its own three segments agree (the cross-segment check of the verdict, hac σ).

Rows marked ``(candidate)`` are covariances evaluated here and not shipped
(`CANDIDATES`), computed from the classic fit of the same system:

* ``hac_fixed_b``: the Newey-West sandwich with Andrews' bandwidth M and σ times
  cv(M/T)/1.96, cv the fixed-b critical value of Kiefer & Vogelsang (2005, Bartlett);
* ``ewc``: the equal-weighted cosine long-run variance with ν = 0.4 T^(2/3) and the
  t_ν critical value (Lazarus, Lewis, Stock & Watson 2018);
* ``bootstrap_cov``: the shipped bootstrap with the replicates' covariance instead of
  the percentile half-width;
* ``bootstrap_ar1_cov``: the AR(1) block-length rule and the covariance of the
  bootstrap as it was at 0a87b8b (with the samples-with-equations fix).
* ``gp_*``: model discrepancy (Kennedy & O'Hagan 2001,
  dynid.analysis.estimators.discrepancy): the named sampling covariance plus
  Σ_j s_j² A_j K_j A_jᵀ, the covariance of the WLS error b = A δ when the torque the
  model lacks, δ_j, is a Gaussian process over the standardised state (q, qd, qdd of
  every joint; ``joint``: joint j's own three), squared-exponential kernel, 500 random
  Fourier features. s_j², the noise variance and ℓ_j by restricted maximum likelihood of
  the run's own residual of joint j (at most 400 rows, the joint's regressor as fixed
  effects, ℓ on a grid of 0.05-2 median state distances); ``median``: ℓ fixed at the
  median distance. ``ar1``: AR(1)-in-time noise beside the GP in the likelihood;
  ``+model``: the model's own noise part A σ_n² R A' (R the AR(1) correlation) in place
  of a resampling. Because K is over the state, a recording that repeats one trajectory
  does not average the bias down. The variants were fixed in three rounds before each
  was run, none tuned to a figure: (1) reml, joint, median (white noise) with bootstrap,
  hac, classic; (2) after (1) chose short ℓ on the LWR4+ (0.07-0.19 median distances,
  the time correlation of the noise taken for δ): ar1; (3) ar1+model.

A second table judges every row on the classic's pairs (its 31 on the LWR4+) and on
every parameter of every pair (no %σ filter), with the number of the classic's pairs
the row keeps: whether an interval holds the differences where the classic σ calls the
parameters identified, apart from how many it keeps.

The column ``sigma/classic`` is the median σ over the classic σ. The column
``>=90 % of >=16`` says whether a row meets issue 26's must-show on the LWR4+;
``lwr4_bar_met_by`` in the last line lists the rows that do. None does
(2026-12-03): the misses left are recording 3 against the others on Off5, Fc5 and
Ia7 (fixed-b HAC: 5.6σ, 2.9σ, 15σ). Recording 3 repeats one trajectory, its segments
agree within their own noise, so no estimate made from recording 3 alone can see the
bias that separates it from recordings 1 and 2 (Ia7 −0.21 against −1.10 and −1.22);
a σ wide enough to hold those differences identifies too few parameters.

The discrepancy (``gp_*``, 2026-12-03, results/uncertainty.txt) fails the bar on the
count, and is wider than needed elsewhere:

* LWR4+: every variant keeps 7-9 pairs, on MY2R, MY4R and Off1 only (100 % within for
  the +bootstrap/+hac rows, 89 % for +classic/+model: MY4R 1-2 at 2.0-2.4σ), median σ
  2.6-3.7 times the classic (``median``: 11). On the classic's 31 pairs they hold
  74-87 % (bootstrap 61 %), on every parameter of every pair 88-97 % (bootstrap 79 %).
  Off5 and Fc5 are held (gp_ar1+bootstrap: 1-3 at 0.9σ each) but leave the pairs, their
  %σ in recording 3 rising to 24 %; Ia7 is not held even so: 3.2σ (1-3) and 4.7σ (2-3)
  with σ 0.27, 0.20 and 0.066 (24, 17, 31 %). REML chooses a short ℓ (mostly 0.07-0.19
  median state distances) and s/σ_n mostly 0.3-11 on every run: the residual is dominated by error
  that is rough over the state, and a prior on δ cannot know which parameter δ will
  project onto, so A K A' widens every parameter, not only those the recordings
  disagree on. With ℓ fixed at the median distance (``median``) REML puts the whole
  residual in the GP (s/σ_n at the grid's bound, 100): the part of a smooth δ the
  parameters absorb is not identified by the residual, and the σ is unbounded.
* TX40 3 s segments: gp_reml+hac 94 % of 16, gp_reml+classic 94 % of 17, gp_ar1+model
  94 % of 16 meet ">= 90 % of >= 16", with median |z| 0.20-0.27 (0.67 expected: about
  three times wider than the differences need); the +bootstrap rows keep 8 pairs.
* Panda halves: gp_reml+bootstrap 94 % of 16, gp_ar1+classic and gp_ar1+model 94 % of
  16 (bootstrap 65 % of 17), median |z| 1.0-1.15, σ 5.4-5.6 times the classic.
* Independent plant (benchmarks/coverage_independent.py, seeds 9100-9199 held out,
  results/coverage_independent_gp_9100.txt and _gp_model_9100.txt): WLS 95 % coverage
  gp_reml+bootstrap 99.5 % at 2.06 times the classic width, gp_reml+classic 98.6 % at
  1.83, gp_ar1+bootstrap 98.7 % at 1.90, gp_ar1+model 98.4 % at 1.80, gp_ar1+classic
  96.7 % at 1.64 (bootstrap 92.8 % at 1.37, classic 81.4 %); essential set 96.8-99.3 %.
  Only gp_ar1+classic stays in 93-97 %, and it is 89 % of 9 on the LWR4+. The default
is the block bootstrap, the best calibrated here and on the independent plant
(dynid.analysis.estimators.idim.DEFAULT_UNCERTAINTY, whose comment gives the figures);
the JSON's ``lwr4_*`` figures are the default's.

The sensitivity to missing effects (``sensitivity+*``, 2026-12-03, results/uncertainty.txt):
the sampling covariance plus the mean outer product of the estimate's shifts when each
physical effect of the diagnosis' library (asymmetric viscous friction, a spring, drift,
friction drift, Stribeck at two speeds, ripple of orders 1 and 2; `_effect_columns`) is
added on one joint, one at a time. It widens only the parameters an effect would move,
which the discrepancy could not. It fails the bar too: LWR4+ 12 pairs at 75 % (+classic),
11 at 73 % (+hac), 7 at 86 % (+bootstrap). Recording 3's Ia7 barely moves under any effect,
so its σ stays at 0.018 (classic 0.017) and 1-3, 2-3 miss at 7.9σ and 8.7σ (+classic); the
effects widen Off1, Off5 and Fc5 of every recording instead (Off5 of recording 1: 33 %).

With the estimates fixed, the line "any sigma keeps at most N pairs" (``lwr4_any_sigma_max_within``)
counts the differences that the widest interval the %σ filter allows would hold: 44 on the
LWR4+, so the bar is not out of reach by arithmetic. But it takes a σ that is small where the
recordings agree (Off1, MY2R, MY4R, Fc7, ...) and large exactly on recording 3's Ia7, Off5,
Off7, XZ7 and Fc6, and nothing measured within one recording has singled those out: not
its segments (they agree), the residual's time correlation, a discrepancy over the state,
nor the effects above. TX40 segments: +hac 90 % of 21, +bootstrap 100 % of 18; Panda halves 47-69 %.
A σ never below the classic one keeps only pairs of the classic's 31 and can hold at most 21 of
them (``lwr4_classic_pairs_holdable``; the other 10 differ by more than 1.96 √((0.1 a)² + (0.1 b)²):
Ia7, XY7, XZ7 and Off7 of recording 3 against the others, XY7 1-2, and Off5 1-3, by 2 % more).
Such a σ meets the bar only if it exceeds 10 %, in at least one of the two runs, on at least
8 of those 10 pairs, keeps at least 15 of the other 21 and holds at least 15, so at least two
of the 8 the classic σ misses among them (Off1 1-2 and 1-3, Off7 1-2, XZ7 1-2, Fc5 1-2 and
1-3, MY4R 1-2, Off5 2-3: 2.3-6.8 classic σ apart): a shape no σ evaluated here has.

The distance to the rigid bodies (``feasibility+*``, 2026-12-04, results/uncertainty.txt): the
true parameters are those of rigid bodies, so an estimate's error is at least its distance to
them. Each run's WLS minus its PC-WLS projection (`feasibility_shift`, in the classic
covariance's metric) is a bias that one recording shows about itself, without a model of what
is missing; its square is added to the option's variance. It holds what the recordings find,
and identifies too little. LWR4+: 12 pairs at 83 % (+classic), 9 at 100 % (+bootstrap); on the
classic's 31 pairs 94 % and 100 %, on every parameter of every pair 98 % and 100 %. Ia7 is
12-16 classic σ from every rigid body in all three recordings (-1.1, -1.2 and -0.21 where a
rotor inertia is >= 0), so its σ rises to 100 % and its pairs leave the count; Fc5 and Off5
move by 1.4-6.2 σ. Panda halves: 20 at 55 %, 16 at 88 %. TX40 segments: no row (the last 3 s
do not identify Fcm6, and the SDP needs every base parameter).

Run from the repository root (about 2-4 min on a shared 2-core machine):

    python benchmarks/uncertainty.py [--no-panda]

The last line is a JSON object with the headline figures.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OPTIONS = ("classic", "hac", "bootstrap")
N_SEG = 3
#: LWR4+ parameters whose recording-3 estimate no option's interval holds (printed per run)
MISSES = ("Off5", "Fc5", "Ia7")


# ---------------------------------------------------------------- candidates
# Covariances evaluated here and not shipped (none met both bars): each is a function of the
# weighted system (W3, tau, mask, chi, weights, bread_inv = (W~'W~)^-1, groups, state) -> cov,
# with the 95 % critical value folded into an equivalent sigma where its theory has one; state
# (q, qd, qdd) of the samples is used by the discrepancy candidates only.

def _live_parts(mask, groups):
    live = np.asarray(mask, dtype=bool).any(axis=1)
    grp = np.zeros(live.size, dtype=int) if groups is None else np.asarray(groups).reshape(-1)
    return [idx for idx in (np.flatnonzero(live & (grp == k)) for k in np.unique(grp)) if idx.size]


def kiefer_vogelsang_cv(b):
    """97.5 % quantile of the fixed-b t statistic, Bartlett kernel (Kiefer & Vogelsang 2005)."""
    return 1.96 + 2.9694 * b + 0.4160 * b**2 - 0.5324 * b**3


def hac_fixed_b(W3, tau, mask, chi, weights, bread_inv, groups=None, state=None):
    """Newey-West with Andrews' bandwidth M, sigma times cv(M/T)/1.96 (fixed-b, Kiefer-Vogelsang 2005)."""
    from dynid.analysis.estimators import hac
    g, _ = hac.sample_scores(W3, tau, mask, chi, weights)
    parts = _live_parts(mask, groups)
    M = hac.andrews_bandwidth(g[np.concatenate(parts)])
    cov, _ = hac.hac_covariance(W3, tau, mask, chi, weights, bread_inv, groups=groups, bandwidth=M)
    b = M / np.mean([p.size for p in parts])
    return cov * (kiefer_vogelsang_cv(b) / 1.96) ** 2


def ewc(W3, tau, mask, chi, weights, bread_inv, groups=None, state=None):
    """Equal-weighted cosine long-run variance, nu = 0.4 T^(2/3) cosines, t_nu critical value.

    Lazarus, Lewis, Stock & Watson (2018), "HAR inference: recommendations for practice".
    """
    from scipy import stats

    from dynid.analysis.estimators import hac
    g, _ = hac.sample_scores(W3, tau, mask, chi, weights)
    S = np.zeros((g.shape[1], g.shape[1]))
    nu = 0
    for idx in _live_parts(mask, groups):
        T = idx.size
        k = max(1, int(0.4 * T ** (2.0 / 3.0)))
        C = np.sqrt(2.0 / T) * np.cos(np.pi * np.outer(np.arange(1, k + 1), np.arange(T) + 0.5) / T)
        L = C @ g[idx]
        S += T * (L.T @ L) / k       # long-run variance of the sum over the recording
        nu += k
    r = int(np.count_nonzero(mask))
    cov = bread_inv @ S @ bread_inv * (r / max(r - g.shape[1], 1))
    return 0.5 * (cov + cov.T) * (stats.t.ppf(0.975, nu) / 1.96) ** 2


def _boot(block, spread):
    def f(W3, tau, mask, chi, weights, bread_inv, groups=None, state=None):
        from dynid.analysis.estimators import hac
        return hac.bootstrap_covariance(W3, tau, mask, chi, weights, groups=groups, block=block,
                                        spread=spread)[0]
    return f


_GP_CACHE: dict = {}


def _sampling(kind, W3, tau, mask, chi, weights, bread_inv, groups, info=None):
    from dynid.analysis.estimators import hac
    if kind == "model":   # the GP model's own noise part: AR(1) per joint, its REML variance and coefficient
        from dynid.analysis.estimators.discrepancy import noise_covariance
        return noise_covariance(W3, mask, weights, bread_inv, info["noise2"], info["phi"])
    if kind == "classic":
        r = int(np.count_nonzero(mask))
        rho = np.where(mask, tau - W3 @ chi, 0.0) * np.asarray(weights)[None, :]
        return bread_inv * float(np.sum(rho**2)) / max(r - W3.shape[2], 1)
    if kind == "hac":
        return hac.hac_covariance(W3, tau, mask, chi, weights, bread_inv, groups=groups)[0]
    return hac.bootstrap_covariance(W3, tau, mask, chi, weights, groups=groups)[0]


def _gp(sampling, per_joint_state=False, lengthscale="reml", noise="white"):
    """Sampling covariance plus the Kennedy-O'Hagan discrepancy A K A' (dynid.analysis.estimators.discrepancy)."""
    def f(W3, tau, mask, chi, weights, bread_inv, groups=None, state=None):
        from dynid.analysis.estimators.discrepancy import discrepancy_from_fit
        if state is None:
            raise ValueError("the discrepancy candidates need the state (q, qd, qdd) of the samples")
        key = (W3.shape, chi.tobytes(), np.asarray(mask).tobytes(), per_joint_state, lengthscale, noise)
        if key not in _GP_CACHE:
            if len(_GP_CACHE) > 8:
                _GP_CACHE.clear()   # the variants of one fit share it
            _GP_CACHE[key] = discrepancy_from_fit(W3, tau, mask, chi, weights, bread_inv, state,
                                                  per_joint_state=per_joint_state, lengthscale=lengthscale,
                                                  noise=noise)
        dcov, info = _GP_CACHE[key]
        GP_INFO.append({"variant": ("joint state" if per_joint_state else "whole state", lengthscale, noise), **info})
        return _sampling(sampling, W3, tau, mask, chi, weights, bread_inv, groups, info) + dcov
    return f


def _effect_columns(q, qd, s):
    """Columns of the physical effects a model may lack on one joint (the diagnosis' library,
    dynid.analysis.diagnosis.effects, as functions of the decimated state): asymmetric viscous
    friction, a spring, a drift and a friction drift over the run, Stribeck friction at two
    speeds and position ripple of orders 1 and 2."""
    vmax = max(float(np.percentile(np.abs(qd), 95)), 1e-12)
    out = [[np.abs(qd)], [q], [s], [s * qd, s * np.sign(qd)]]
    out += [[np.sign(qd) * np.exp(-(qd / (f * vmax)) ** 2)] for f in (0.05, 0.2)]
    out += [[np.cos(k * q), np.sin(k * q)] for k in (1, 2)]
    return out


def _sensitivity(sampling):
    """Sampling covariance plus the spread of the estimate over the missing effects: the WLS
    refitted with each effect of `_effect_columns` added on one joint (one at a time, every
    joint), and the mean of the shifts' outer products (each effect equally likely to be
    the one missing, Draper 1995's model uncertainty with the base model's estimate kept)."""
    def f(W3, tau, mask, chi, weights, bread_inv, groups=None, state=None):
        if state is None:
            raise ValueError("the sensitivity candidates need the state (q, qd, qdd) of the samples")
        q, qd, _ = state
        m = np.asarray(mask, dtype=bool)
        w = np.asarray(weights, dtype=float)
        M, n, p = W3.shape
        A = (W3 * w[None, :, None])[m]
        y = (tau * w[None, :])[m]
        chi0 = np.linalg.lstsq(A, y, rcond=None)[0]
        live = np.flatnonzero(m.any(axis=1))
        s = np.zeros(M)
        s[live] = (live - live[0]) / max(live[-1] - live[0], 1)
        shifts = []
        for j in range(n):
            if not m[:, j].any():
                continue
            for cols in _effect_columns(q[:, j], qd[:, j], s):
                C3 = np.zeros((M, n, len(cols)))
                C3[:, j, :] = np.column_stack(cols)
                x = np.linalg.lstsq(np.hstack([A, (C3 * w[None, :, None])[m]]), y, rcond=None)[0]
                shifts.append(x[:p] - chi0)
        S = np.asarray(shifts)
        return _sampling(sampling, W3, tau, mask, chi, weights, bread_inv, groups) + S.T @ S / len(S)
    return f



#: the rows added to a sampling option by `feasibility_shift` (issue 26, 2026-12-04)
FEASIBILITY = ("classic", "bootstrap")


def feasibility_shift(robot, bp, chi, cov):
    """The WLS estimate `chi` minus its physically consistent projection (PC-WLS,
    dynid.analysis.estimators.physical.pc_wls, in the metric of the classic covariance
    `cov`, no bootstrap), or None when the SDP fails.

    The true parameters are those of rigid bodies, so the estimate's error is at least its
    distance to the set of such parameters: the shift is a lower bound on the bias that one
    recording shows about itself. ``feasibility+<option>`` adds its square to the option's
    variance (a bias term beside the sampling one)."""
    from dynid.analysis.estimators.physical import pc_wls
    try:
        return np.asarray(chi, dtype=float) - np.asarray(pc_wls(robot, bp, chi, cov, n_boot=0).chi, dtype=float)
    except Exception as exc:  # noqa: BLE001 - a failed SDP leaves the row out
        print(f"  feasibility: PC-WLS failed ({str(exc).splitlines()[0]})")
        return None


#: hyperparameters of every discrepancy fit, for the printout
GP_INFO: list = []

#: name -> covariance function, beside the shipped OPTIONS
CANDIDATES = {
    "hac_fixed_b": hac_fixed_b,
    "ewc": ewc,
    "bootstrap_cov": _boot("politis-white", "cov"),          # the shipped bootstrap with np.cov
    "bootstrap_ar1_cov": _boot("ar1", "cov"),                # the block rule and spread of 0a87b8b
    # Kennedy-O'Hagan discrepancy, variants fixed before any LWR4+ figure was seen (2026-12-03)
    "gp_reml+bootstrap": _gp("bootstrap"),                   # whole state, l/s2/noise by REML
    "gp_reml+hac": _gp("hac"),
    "gp_reml+classic": _gp("classic"),
    "gp_joint_reml+bootstrap": _gp("bootstrap", per_joint_state=True),   # joint j's own (q, qd, qdd)
    "gp_median+bootstrap": _gp("bootstrap", lengthscale="median"),       # l = median distance, s2 by REML
    # second round, after the first on the LWR4+ (l chosen short: the GP took the noise's
    # correlation in time): AR(1)-in-time noise beside the GP in the likelihood, as the brief proposed
    "gp_ar1+bootstrap": _gp("bootstrap", noise="ar1"),
    "gp_ar1+classic": _gp("classic", noise="ar1"),
    "gp_joint_ar1+bootstrap": _gp("bootstrap", per_joint_state=True, noise="ar1"),
    # third: the model's own total A (noise2 R + s2 K) A', its AR(1) noise in place of a resampling
    "gp_ar1+model": _gp("model", noise="ar1"),
    # fourth (2026-12-03, after the discrepancy): the estimate's sensitivity to the effects the
    # diagnosis looks for, which widens only the parameters an effect would move
    "sensitivity+classic": _sensitivity("classic"),
    "sensitivity+hac": _sensitivity("hac"),
    "sensitivity+bootstrap": _sensitivity("bootstrap"),
}


def candidate_sigmas(r, W3, tau, mask, groups=None, state=None, only=None):
    """{candidate: (cov, sigma)} of a classic WLS result `r` of the system (W3, tau, mask).

    `state` (q, qd, qdd) of the samples, for the discrepancy candidates (left out without it);
    `only`: the candidates to compute (default all).
    """
    m = np.asarray(mask, dtype=bool)
    if m.ndim == 1:
        m = np.broadcast_to(m[:, None], tau.shape)
    rows = m.sum(axis=0)
    w = np.where(rows > 0, 1.0 / np.where(np.isfinite(r.joint_sigma), r.joint_sigma, 1.0), 0.0)
    bread = r.cov / r.sigma_rho ** 2
    out = {}
    for name, f in CANDIDATES.items():
        if (state is None and name.startswith(("gp_", "sensitivity"))) or (only is not None and name not in only):
            continue
        cov = f(W3, tau, m, r.chi, w, bread, groups, state=state)
        out[name] = (cov, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    return out


def _segment_tau2(res):
    """Between-segment variance τ² (DL) of the run's WLS, from N_SEG contiguous segments."""
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.agreement import random_effects, segments
    obs = res.observation
    chis, sig = [], []
    for m in segments(obs.n_samples, obs.row_mask, N_SEG):
        r = ls.wls(obs.W, obs.tau, list(res.base.names), row_mask=m, joint_sigma=res.wls.joint_sigma)
        chis.append(r.chi)
        sig.append(r.bse.to_numpy())
    return random_effects(chis, sig)["tau"] ** 2


def segment_fits(obs, names, k, opt):
    """WLS of each of k contiguous segments of one observation system, with option ``opt``.

    A segment that cannot identify a parameter (e.g. the TX40's Fcm6 in its last 3 s)
    leaves it out: NaN, never compared; so are, in that segment, the parameters that take its
    torque there (Off5 and Off6 for Fcm6: ``identifiable_and_aliased``, as ``dynid identify``'s
    segment agreement).
    """
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.agreement import segments
    out = []
    for m in segments(obs.n_samples, obs.row_mask, k):
        cols, aliased = ls.identifiable_and_aliased(obs.W, m)
        r = ls.wls(obs.W[:, :, cols], obs.tau, [names[c] for c in cols], row_mask=m, uncertainty=opt)
        chi, sig = np.full(len(names), np.nan), np.full(len(names), np.nan)
        chi[cols], sig[cols] = r.chi, r.bse.to_numpy()
        chi[aliased], sig[aliased] = np.nan, np.nan
        cov = np.full((len(names), len(names)), np.nan)
        cov[np.ix_(cols, cols)] = r.cov
        cov[aliased, :], cov[:, aliased] = np.nan, np.nan
        out.append((chi, sig, cov))
    return out


def _agree(chis, sig, names):
    """pairwise_agreement with the %sigma filter, and beside it ("all") over every parameter."""
    from dynid.analysis.estimators.agreement import pairwise_agreement
    out = pairwise_agreement(chis, sig, names=names)
    out["all"] = pairwise_agreement(chis, sig, names=names, rel_max=np.inf)
    return out


def _width(sig, ref):
    """Median sigma / classic sigma over the runs' parameters."""
    r = np.concatenate([np.asarray(a) / np.asarray(b) for a, b in zip(sig, ref)])
    return float(np.nanmedian(r))


def segment_candidates(obs, names, k):
    """{candidate: [sigma of each of the k segments]} (NaN where a segment leaves a parameter out)."""
    from dynid.analysis.estimators import least_squares as ls
    from dynid.analysis.estimators.agreement import segments
    out = {c: [] for c in CANDIDATES}
    for m in segments(obs.n_samples, obs.row_mask, k):
        cols = ls.identifiable_columns(obs.W, m)
        r = ls.wls(obs.W[:, :, cols], obs.tau, [names[c] for c in cols], row_mask=m)
        for cand, (_, sig) in candidate_sigmas(r, obs.W[:, :, cols], obs.tau, m,
                                               state=(obs.q, obs.qd, obs.qdd)).items():
            full = np.full(len(names), np.nan)
            full[cols] = sig
            out[cand].append(full)
    return out


def runs_of(dataset, panda_dir=None):
    """(robot, [(label, Experiment)], settings) of a data set."""
    from dynid.analysis.data.experiment import load_experiment
    from dynid.dynamics.robot_file import load_robot
    if dataset == "lwr4":
        robot = load_robot("kuka_lwr4")
        return robot, [(f"recording {k}", load_experiment(ROOT / f"examples/kuka_lwr4/recording_{k}.toml", robot))
                       for k in (1, 2, 3)], None
    if dataset == "tx40":
        robot = load_robot("tx40")
        return robot, [("9 s log", load_experiment(ROOT / "examples/staubli_tx40/experiment.toml", robot))], None
    if dataset == "panda":
        sys.path.insert(0, str(ROOT / "examples/franka_panda"))
        import run as panda_run
        robot = load_robot("panda")
        toml = panda_run.prepare(panda_dir, tempfile.mkdtemp(prefix="dynid_panda_"))
        return robot, [("21 s log", load_experiment(toml, robot))], dict(panda_run.SETTINGS)
    raise ValueError(dataset)


def evaluate_segments(dataset, panda_dir=None):
    """One recording, its observation system built once, its k segments fitted alone."""
    from dynid.analysis.estimators.agreement import agreement, agreement_verdict
    from dynid.analysis.estimators.idim import identify_idim
    robot, runs, settings = runs_of(dataset, panda_dir)
    exp = runs[0][1]
    res = identify_idim(exp, robot, settings=settings)
    names = list(res.base.names)
    k = 3 if dataset == "tx40" else 2
    rows, fits = {}, {}
    for opt in OPTIONS:
        fits[opt] = segment_fits(res.observation, names, k, opt)
        rows[opt] = _agree([f[0] for f in fits[opt]], [f[1] for f in fits[opt]], names)
        rows[opt]["width"] = _width([f[1] for f in fits[opt]], [f[1] for f in fits["classic"]])
    for cand, sig in segment_candidates(res.observation, names, k).items():
        rows[cand] = _agree([f[0] for f in fits["classic"]], sig, names)
        rows[cand]["width"] = _width(sig, [f[1] for f in fits["classic"]])
    shifts = []
    for chi, _, cov in fits["classic"]:
        ok = np.isfinite(chi)
        shifts.append(feasibility_shift(robot, res.base, chi, cov) if ok.all() else None)
    if all(d is not None for d in shifts):      # a segment without every parameter: no SDP, no row
        for opt in FEASIBILITY:
            sig = [np.sqrt(f[1] ** 2 + d ** 2) for f, d in zip(fits[opt], shifts)]
            rows[f"feasibility+{opt}"] = _agree([f[0] for f in fits["classic"]], sig, names)
            rows[f"feasibility+{opt}"]["width"] = _width(sig, [f[1] for f in fits["classic"]])
    both = np.all([np.isfinite(f[0]) for f in fits["classic"]], axis=0)
    cl = fits["classic"]
    agr = agreement([f[0][both] for f in cl], [f[1][both] for f in cl], [f[2][np.ix_(both, both)] for f in cl],
                    [n for n, b in zip(names, both) if b], kind="segments")
    labels = [f"segment {j + 1} of {k}" for j in range(k)]
    return rows, agr, agreement_verdict(agr), labels


def evaluate(dataset, panda_dir=None):
    from dynid.analysis.estimators.agreement import agreement, agreement_verdict, pairwise_agreement
    from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY, identify_idim
    if dataset != "lwr4":
        return evaluate_segments(dataset, panda_dir)
    robot, runs, settings = runs_of(dataset, panda_dir)
    fits = {opt: [] for opt in OPTIONS}
    cand_sig = {c: [] for c in CANDIDATES}
    tau2 = []
    names = None
    within = []
    for label, exp in runs:
        for opt in OPTIONS:
            r = identify_idim(exp, robot, settings=settings, uncertainty=opt)
            fits[opt].append(r)
            names = list(r.base.names)
        ref = fits["classic"][-1]
        obs = ref.observation
        for cand, (_, sig) in candidate_sigmas(ref.wls, obs.W, obs.tau, obs.row_mask,
                                               state=(obs.q, obs.qd, obs.qdd)).items():
            cand_sig[cand].append(sig)
        a = fits["hac"][-1].agreement
        if a is not None:   # what this recording alone says about its own model error
            within.append(f"  {dataset} {label}: its {a.k} segments (hac sigma) {100 * a.within_95:.0f} % of "
                          f"{a.pairs} pairs within, median |z| {a.median_abs_z:.2f}, chi2 p = "
                          f"{a.p_value:.2g}")
        for opt in OPTIONS[1:]:
            assert np.array_equal(fits[opt][-1].wls.chi, ref.wls.chi), "the option changed the estimate"
        try:
            tau2.append(_segment_tau2(ref))
        except Exception as exc:   # a segment that does not identify every parameter
            print(f"  {dataset} {label}: segments skipped ({str(exc).splitlines()[0]})")
            tau2.append(None)
    rows = {}
    for opt in OPTIONS:
        chis = [r.wls.chi for r in fits[opt]]
        sig = [r.wls.bse.to_numpy() for r in fits[opt]]
        rows[opt] = _agree(chis, sig, names)
        rows[opt]["width"] = _width(sig, [r.wls.bse.to_numpy() for r in fits["classic"]])
        if all(t is not None for t in tau2):
            rows[f"{opt}+segments"] = pairwise_agreement(
                chis, [np.sqrt(s**2 + t) for s, t in zip(sig, tau2)], names=names)
            rows[f"{opt}+segments/K"] = pairwise_agreement(
                chis, [np.sqrt(s**2 + t / N_SEG) for s, t in zip(sig, tau2)], names=names)
    for cand, sig in cand_sig.items():
        rows[cand] = _agree([r.wls.chi for r in fits["classic"]], sig, names)
        rows[cand]["width"] = _width(sig, [r.wls.bse.to_numpy() for r in fits["classic"]])
    shifts = [feasibility_shift(robot, r.base, r.wls.chi, r.wls.cov) for r in fits["classic"]]
    if all(d is not None for d in shifts):
        for opt in FEASIBILITY:
            sig = [np.sqrt(r.wls.bse.to_numpy() ** 2 + d ** 2) for r, d in zip(fits[opt], shifts)]
            rows[f"feasibility+{opt}"] = _agree([r.wls.chi for r in fits["classic"]], sig, names)
            rows[f"feasibility+{opt}"]["width"] = _width(sig, [r.wls.bse.to_numpy() for r in fits["classic"]])
        FEASIBILITY_SHIFTS[dataset] = (names, [r.wls.chi for r in fits["classic"]],
                                       [r.wls.bse.to_numpy() for r in fits["classic"]], shifts)
    cl = fits["classic"]
    agr = agreement([r.wls.chi for r in cl], [r.wls.bse.to_numpy() for r in cl], [r.wls.cov for r in cl], names,
                    kind="recordings" if dataset == "lwr4" else "segments")
    print("\n".join(within))
    ANY_SIGMA[dataset] = any_sigma_bound([r.wls.chi for r in cl])
    n_cl, n_held, not_held = holdable_classic_pairs([r.wls.chi for r in cl], [r.wls.bse.to_numpy() for r in cl],
                                                    names)
    HOLDABLE[dataset] = n_held
    print(f"  {dataset}: a sigma never below the classic can hold at most {n_held} of the classic's {n_cl} pairs "
          f"(%sigma <= 10 %)" + (f"; not {', '.join(not_held)}" if not_held else ""))
    print(f"  {dataset}: with these estimates, any sigma keeps at most {ANY_SIGMA[dataset]} pairs within "
          f"+-1.96 combined sigma at %sigma <= 10 % (|a - b| <= 1.96 sqrt((0.1 a)^2 + (0.1 b)^2))")
    # the parameters whose recording-3 estimate no option holds (issue 26): value +- sigma (%sigma) per run
    sigs = {opt: [r.wls.bse.to_numpy() for r in fits[opt]] for opt in ("classic", DEFAULT_UNCERTAINTY)}
    sigs.update({c: v for c, v in cand_sig.items()
                 if (c.startswith("gp_") and c.endswith("+bootstrap")) or c == "sensitivity+classic"})
    for name in MISSES:
        k = names.index(name)
        for opt, sg in sigs.items():
            zs = [f"{a + 1}-{b + 1} z {(cl[a].wls.chi[k] - cl[b].wls.chi[k]) / np.hypot(sg[a][k], sg[b][k]):+.2f}"
                  for a, b in ((0, 1), (0, 2), (1, 2))]
            print(f"  {name} {opt}: " + ", ".join(
                f"{r.wls.chi[k]:+.3g} +- {s[k]:.2g} ({100 * s[k] / abs(r.wls.chi[k]):.0f} %)" for r, s in zip(cl, sg))
                + "; " + ", ".join(zs))
    if dataset in FEASIBILITY_SHIFTS:
        _, chis_f, sig_f, shifts = FEASIBILITY_SHIFTS[dataset]
        for name in MISSES:
            k = names.index(name)
            print(f"  {name} distance to the rigid bodies (WLS - PC-WLS): " + ", ".join(
                f"{c[k]:+.3g} - PC = {d[k]:+.2g} ({abs(d[k]) / s[k]:.1f} classic sigma)"
                for c, s, d in zip(chis_f, sig_f, shifts)))
    return rows, agr, agreement_verdict(agr), [label for label, _ in runs]


#: dataset -> `any_sigma_bound` of its runs' estimates
ANY_SIGMA: dict = {}
#: dataset -> `holdable_classic_pairs` count of its runs
HOLDABLE: dict = {}
#: dataset -> (names, estimates, classic sigmas, feasibility shifts) of its runs
FEASIBILITY_SHIFTS: dict = {}


def any_sigma_bound(chis) -> int:
    """The most (pair, parameter) differences any sigma can hold within +-1.96 combined sigma
    with %sigma <= 10 % in both runs: |a - b| <= 1.96 sqrt((0.1 a)^2 + (0.1 b)^2), the widest
    interval the filter allows. The estimates are fixed (the options change only sigma)."""
    chis = [np.asarray(c, dtype=float) for c in chis]
    n = 0
    for i in range(len(chis)):
        for k in range(i + 1, len(chis)):
            a, b = chis[i], chis[k]
            n += int(np.count_nonzero(np.abs(a - b) <= 1.96 * np.hypot(0.1 * a, 0.1 * b)))
    return n


def holdable_classic_pairs(chis, sigmas, names):
    """Of the pairs with classic %σ <= 10 % in both runs, those a σ never below the classic one
    could hold within ±1.96 combined σ and keep (%σ <= 10 %, so at most 0.1 |χ|):
    (number of pairs, number holdable, the names of the others as "a-b NAME")."""
    chis = [np.asarray(c, dtype=float) for c in chis]
    sigmas = [np.asarray(v, dtype=float) for v in sigmas]
    with np.errstate(divide="ignore", invalid="ignore"):      # the filter of pairwise_agreement
        rel = [100 * s / np.abs(c) for s, c in zip(sigmas, chis)]
    n, held, not_held = 0, 0, []
    for i in range(len(chis)):
        for k in range(i + 1, len(chis)):
            a, b = chis[i], chis[k]
            kept = (rel[i] <= 10) & (rel[k] <= 10)
            ok = np.abs(a - b) <= 1.96 * np.hypot(0.1 * a, 0.1 * b)
            n += int(kept.sum())
            held += int((kept & ok).sum())
            not_held += [f"{i + 1}-{k + 1} {names[j]}" for j in np.flatnonzero(kept & ~ok)]
    return n, held, not_held


def meets_bar(r) -> bool:
    """Issue 26's must-show: >= 90 % within +-1.96 combined sigma with >= 16 pairs."""
    return r["pairs"] >= 16 and r["within_95"] >= 0.9


def main(argv=None):
    sys.path.insert(0, str(ROOT))
    from dynid.analysis.estimators.idim import DEFAULT_UNCERTAINTY
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-panda", action="store_true")
    ap.add_argument("--sets", default="lwr4,tx40,panda", help="comma-separated data sets (lwr4, tx40, panda)")
    ap.add_argument("--panda-data", default=None, help="Gaz et al.'s folder (default: the shared data folder)")
    a = ap.parse_args(argv)
    t0 = time.time()
    wanted = [x.strip() for x in a.sets.split(",") if x.strip()]
    sets = [x for x in ("lwr4", "tx40") if x in wanted]
    panda_dir = a.panda_data
    if not a.no_panda and "panda" in wanted:
        if panda_dir is None:
            for p in [ROOT, *ROOT.parents]:
                if (p / "shared/data/franka-panda-gaz").is_dir():
                    panda_dir = p / "shared/data/franka-panda-gaz"
                    break
        if panda_dir is not None:
            sets.append("panda")
        else:
            print("Panda: data folder not found (pass --panda-data): skipped")
    out = {"default_uncertainty": DEFAULT_UNCERTAINTY}
    for ds in sets:
        GP_INFO.clear()
        rows, agr, verdict, labels = evaluate(ds, panda_dir)
        seen = set()
        for g in GP_INFO:
            key = (g["variant"], tuple(g["s2"]))
            if key in seen:
                continue
            seen.add(key)
            print(f"  discrepancy {', '.join(g['variant'])}: l/median distance "
                  + " ".join(f"{v:.2f}" for v in g["lengthscale_rel"]) + "; noise AR(1) "
                  + " ".join(f"{v:.2f}" for v in g["phi"]) + "; s/noise "
                  + " ".join(f"{np.sqrt(a / b):.2f}" for a, b in zip(g["s2"], g["noise2"]))
                  + (f"; at a grid bound on joints {[j + 1 for j, b in enumerate(g['at_bound']) if b]}"
                     if any(g["at_bound"]) else ""))
        print(f"\n{ds}: {', '.join(labels)} each alone; per-joint WLS, pairs with %sigma <= 10 % in both runs")
        print(f"  {'sigma':<30}{'pairs':>6}{'within 95 %':>13}{'median |z|':>12}{'beyond 5':>10}"
              f"{'sigma/classic':>15}{'  >=90 % of >=16':>17}")
        for opt, r in rows.items():
            tag = " (default)" if opt == DEFAULT_UNCERTAINTY else ""
            tag += " (candidate)" if opt in CANDIDATES or opt.startswith("feasibility+") else ""
            width = f"{r['width']:.2f}" if "width" in r else "-"
            print(f"  {opt + tag:<30}{r['pairs']:>6}{100 * r['within_95']:>12.0f}%{r['median_abs_z']:>12.2f}"
                  f"{100 * r['beyond_5']:>9.0f}%{width:>15}{'yes' if meets_bar(r) else 'no':>17}")
        # the same sigmas judged on the classic's pairs, and on every parameter (no %sigma filter):
        # whether the intervals hold the differences where the classic sigma calls them identified
        ref = {(z["a"], z["b"], z["name"]) for z in rows["classic"]["z"]}
        print(f"  {'sigma':<30}{'on the classic pairs':>22}{'median |z|':>12}{'all parameters':>16}{'median |z|':>12}"
              f"{'  classic pairs with %sigma <= 10 % in both':>44}")
        for opt, r in rows.items():
            if "all" not in r:
                continue
            on = [abs(z["z"]) for z in r["all"]["z"] if (z["a"], z["b"], z["name"]) in ref]
            al = r["all"]
            kept = len({(z["a"], z["b"], z["name"]) for z in r["z"]} & ref)
            on_txt = f"{100 * np.mean(np.array(on) <= 1.96):.0f}% of {len(on)}"
            all_txt = f"{100 * al['within_95']:.0f}% of {al['pairs']}"
            print(f"  {opt:<30}{on_txt:>22}{np.median(on):>12.2f}{all_txt:>16}{al['median_abs_z']:>12.2f}{kept:>44}")
        for opt, r in rows.items():
            if opt.startswith("gp_") or opt == DEFAULT_UNCERTAINTY:
                miss = [f"{z['a'] + 1}-{z['b'] + 1} {z['name']} {z['z']:+.1f}"
                        for z in r["z"] if abs(z["z"]) > 1.96]
                ins = sorted({z["name"] for z in r["z"]})
                print(f"  {opt}: pairs on {', '.join(ins)}; beyond 1.96: {', '.join(miss) or 'none'}")
        if ds == "lwr4":
            out["lwr4_bar_met_by"] = [opt for opt, r in rows.items() if meets_bar(r)]
            out["lwr4_any_sigma_max_within"] = ANY_SIGMA.get("lwr4")
            out["lwr4_classic_pairs_holdable"] = HOLDABLE.get("lwr4")
        print(f"  verdict (classic): {verdict}")
        pooled = [(n, p, s, t) for n, p, s, t in zip(agr.names, agr.pooled, agr.pooled_std,
                                                    agr.between_std) if t > 0]
        print(f"  random effects (DerSimonian-Laird): between-run spread > 0 for {len(pooled)} of "
              f"{len(agr.names)} parameters; chi2 {agr.chi2:.4g} on {agr.dof:.1f} dof, p = {agr.p_value:.2g}")
        d = rows[DEFAULT_UNCERTAINTY]
        out[f"{ds}_pairs"] = d["pairs"]
        out[f"{ds}_pairs_within_95"] = d["within_95"]
        out[f"{ds}_median_abs_z"] = d["median_abs_z"]
        for opt, r in rows.items():
            out[f"{ds}_{opt}"] = [r["pairs"], round(r["within_95"], 3), round(r["median_abs_z"], 3)]
        out[f"{ds}_chi2_p_value"] = agr.p_value
    out["seconds"] = round(time.time() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
