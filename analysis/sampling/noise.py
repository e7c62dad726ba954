"""Noise models of the posterior's likelihood: curvature matched to the robust covariance, effective rows, or white.

`sandwich` (default): the curvature-adjusted likelihood of Ribatet, Cooley &
Davison (2012), the posterior Müller (2013) shows to be the right one for a
misspecified likelihood: the Gaussian likelihood of eq. (16) is evaluated at
χ̂ + C(χ − χ̂), with C chosen so that its curvature in χ at the LS estimate χ̂
(with σ_j at the LS σ_j) is the inverse of the fit's robust covariance Σ_R:

    Cᵀ H C = Σ_R⁻¹,   H = Σ_j G_j / σ_j²,   C = A⁻ᵀ Bᵀ  (H = AAᵀ, Σ_R⁻¹ = BBᵀ, Cholesky),

so with σ_j at their LS values the posterior of χ (flat prior) is N(χ̂, Σ_R)
and a Gaussian prior combines with the robust likelihood. When the sampler also samples
σ_j (`sample_linear` without a given σ), χ̂ and σ_j are the likelihood's joint optimum
(χ*, σ*: σ_j² = S_j(χ*)/r_j, χ* their WLS), where the chains settle: matched at eq. (16)'s
σ_j instead (each joint fitted alone, which absorbs more of the torque the model misses),
the LWR4+ recordings 2 + 3 gave posterior σ 1.34-1.69 times the robust σ and means up to
2.8 σ away; matched at (χ*, σ*), 1.02 times and centred on χ* (which differs from χ̂ by at
most 0.6 σ there, by the weights). Σ_R is the block
bootstrap of the same WLS fit (dynid.analysis.estimators.hac, the default
uncertainty of dynid identify); for the essential parameters it is the
essential fit's robust covariance, the full model's covariance of the same
parameters plus d dᵀ, d the bias of removing the others
(dynid.analysis.estimators.essential). In the sufficient statistics the
adjustment is (G_j, g_j, s_j, r_j) -> (CᵀG_jC, Cᵀg_j, s_j, r_j) about
χ_ref = χ̂: the cost per step is unchanged.

Why (issue 26; independent plant, benchmarks/coverage_posterior.py, development seeds
7000-7009): the essential model's likelihood treats the removed parameters as exactly
zero, so its curvature ignores (1) the bias of removing them (the same WLS on the
noise-free torque differs from the truth by 0.52 of the neff σ, rms, against 0.42 for
the base parameters) and (2) the spread the removal adds to the noise part (rms z of
the estimate about that noise-free fit 1.16 under neff, 0.82 for the base
parameters): neff's essential intervals covered 82.5 % (85.1 % on seeds 5000-5099).
A per-joint scalar such as τ_j cannot repair either: both are directions in parameter
space, which the robust covariance of the fit has. Held out (seeds 7500-7599, closed forms,
results/coverage_posterior_7500.txt): sandwich covers 93.9 % (base, 1.36 times the classic
width) and 93.7 % (essential, 1.91 times), neff 94.5 % and 85.5 %; emcee with sandwich on the
essential parameters, seeds 7500-7548: 94.7 % (2.07 times; σ_j sampled, a little wider than
the closed form at the LS σ_j). Seeds 5000-5099 (neff's held-out set): sandwich 93.8 % and
94.5 %, neff 94.3 % and 85.1 %.

`white`: eq. (16) of Gautier, Janot & Vandanjon (2010) read as a likelihood,
ρ^j ~ N(0, σ_j² I_{r_j}): every decimated row of joint j is new information.
On decimated closed-loop data the residual is correlated in time (filtered
noise, unmodelled torques), so that posterior is too narrow.

`neff`: the likelihood of joint j is tempered by the effective
sample size of its LS residual,

    log L(χ, σ) = Σ_j (1/τ_j) [ −r_j log σ_j − S_j(χ) / (2σ_j²) ],
    τ_j = 1 + 2 Σ_{k<K_j} ρ_j(k)  (≥ 1),   n_eff,j = r_j / τ_j,

with ρ_j the gap-aware autocorrelation of the residual of joint j and K_j the
first lag inside the white-noise band 2/√r_j
(dynid.analysis.statistics.residuals.effective_sample_size, the n_eff the
residual analysis reports). A tempered ("power") likelihood keeps the
Gaussian shape and the LS point estimate and scales the information of each
joint by n_eff,j / r_j: the variance of W^jᵀρ^j is inflated by τ_j when the
regressor columns are smooth over the residual's correlation lags (decimated
data: the motion's bandwidth is far below the decimated rate), which is the
variance the white model forgets. In the sufficient statistics this is
(G_j, g_j, s_j, r_j) / τ_j: the cost per step is unchanged and the σ_j keep
their scale (S_j / r_j is unchanged).

Chosen over AR(p) prewhitening per joint after trying both on the
independent plant (development seeds < 1000): the AR coefficients fitted to
~150 decimated rows per joint (orders by BIC up to 8) gave long-run variance
factors that jumped between 0.2 and 75 from seed to seed, and prewhitening
drops p rows after every gap of the velocity dead zone; the tempering factor
is one robust number per joint and is the same n_eff the residual analysis
shows the user.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from dynid.analysis.sampling.sufficient import SufficientStats, cholesky
from dynid.analysis.statistics.residuals import effective_sample_size
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["NOISE_MODELS", "DEFAULT_NOISE", "NoiseModel", "check_noise", "noise_model", "sandwich_model",
           "temper"]

#: Noise models of the likelihood: "sandwich" (default) curvature matched to the fit's robust
#: covariance, "neff" rows tempered by the effective sample size of the residual, "white"
#: independent rows.
NOISE_MODELS = ("sandwich", "neff", "white")
DEFAULT_NOISE = "sandwich"


def check_noise(noise) -> str:
    """The noise model's name, or an InputError naming the choices."""
    if noise not in NOISE_MODELS:
        raise InputError(f"noise must be one of {', '.join(NOISE_MODELS)}, not {noise!r} (--noise)")
    return noise


@dataclass(eq=False)
class NoiseModel:
    """The noise model a posterior used.

    Attributes
    ----------
    kind : "sandwich", "neff" or "white".
    tau_int : (n,)
        Integrated autocorrelation time of each joint's LS residual, in rows (1 for white
        and sandwich: their rows are not tempered).
    rows : (n,) int
        Rows of each joint.
    cut_lag : (n,) int
        First lag inside the white-noise band (the sum stops before it; 0 for white and sandwich).
    transform : (b, b), optional
        The sandwich's C (the likelihood is evaluated at χ_ref + C(χ − χ_ref)).
    width : (b,), optional
        The sandwich's σ_R,i over the white likelihood's σ_i (√ of the diagonals).
    source : str
        Where Σ_R came from.
    """

    kind: str
    tau_int: np.ndarray
    rows: np.ndarray
    cut_lag: np.ndarray
    transform: np.ndarray | None = None
    width: np.ndarray | None = None
    source: str = ""

    @property
    def n_eff(self) -> np.ndarray:
        """Effective rows r_j / τ_j of each joint."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.rows / self.tau_int

    def describe(self) -> str:
        if self.kind == "white":
            return "white: independent Gaussian rows, one sigma_j per joint (eqs. (9), (10), (16))"
        if self.kind == "sandwich":
            return ("sandwich: Gaussian rows (eq. (16)) with the curvature in chi matched to the fit's robust "
                    f"covariance (Ribatet, Cooley & Davison 2012; {self.source}); median width "
                    f"{np.median(self.width):.2f} times the white likelihood's")
        taus = ", ".join(f"{t:.2f}" for t in self.tau_int)
        return ("neff: Gaussian rows, each joint's likelihood tempered by 1/tau_j, the integrated "
                "autocorrelation time of its LS residual (n_eff = r_j / tau_j; tau_j = " + taus + ")")

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "description": self.describe(), "tau_int": self.tau_int,
               "n_eff": self.n_eff, "rows": self.rows, "cut_lag": self.cut_lag}
        if self.kind == "sandwich":
            out.update(width_vs_white=self.width, source=self.source)
        return json_safe(out)


def noise_model(kind: str, W3, tau, mask, chi) -> NoiseModel:
    """The noise model `kind` of the system (W3 (N, n, b), tau (N, n), mask) about the LS `chi`.

    Returns
    -------
    NoiseModel
        For "neff", τ_j from `effective_sample_size` of the residual tau − W3 χ (rows in `mask`).
    """
    check_noise(kind)
    if kind == "sandwich":
        raise InputError("the sandwich noise model needs the fit's robust covariance: use sandwich_model")
    W3 = np.asarray(W3, dtype=float)
    N, n, _ = W3.shape
    m = np.ones((N, n), bool) if mask is None else np.broadcast_to(
        np.asarray(mask, bool).reshape(N, -1), (N, n))
    rows = m.sum(axis=0).astype(int)
    if kind == "white":
        return NoiseModel("white", np.ones(n), rows, np.zeros(n, int))
    with np.errstate(invalid="ignore", over="ignore"):
        e = np.where(m, np.asarray(tau, float) - np.einsum(
            "tjb,b->tj", np.where(m[:, :, None], W3, 0.0), np.asarray(chi, float)), 0.0)
    _, tau_int, cut, _ = effective_sample_size(e, m)
    tau_int = np.where(np.isfinite(tau_int), tau_int, 1.0)     # joints with < 4 rows: as white
    return NoiseModel("neff", np.asarray(tau_int, float), rows, np.asarray(cut, int))


def sandwich_model(stats: SufficientStats, robust_cov, joint_sigma, source: str = "") -> NoiseModel:
    """The sandwich noise model of `stats` (about their χ_ref): C with Cᵀ H C = Σ_R⁻¹.

    Parameters
    ----------
    stats : SufficientStats
        About the estimate the curvature is matched at: the LS estimate χ̂, or the likelihood's
        joint optimum χ* when the sampler samples σ_j (`SufficientStats.joint_optimum`).
    robust_cov : (b, b)
        Σ_R, the robust covariance of that estimate.
    joint_sigma : (n,)
        The σ_j at which the curvature H = Σ_j G_j / σ_j² is matched (eq. (16)'s, or σ* with χ*).
    source : str
        Where Σ_R came from (for the settings and the summary).

    Returns
    -------
    NoiseModel
        kind "sandwich" with `transform` C and `width` √(diag Σ_R / diag H⁻¹).

    Raises
    ------
    IdentificationError
        H or Σ_R is not positive definite.
    """
    b = stats.n_params
    R = np.asarray(robust_cov, dtype=float)
    if R.shape != (b, b) or not np.all(np.isfinite(R)):
        raise InputError(f"robust_cov must be a finite ({b}, {b}) matrix, got shape {R.shape}")
    sig = np.asarray(joint_sigma, dtype=float)
    act = stats.active
    w = np.zeros(stats.n_joints)
    w[act] = 1.0 / sig[act] ** 2
    H = np.einsum("j,jbc->bc", w, stats.G)
    A = cholesky(0.5 * (H + H.T), stats.names, "The likelihood's curvature Σ G_j/σ_j²")[0]
    P = np.linalg.inv(0.5 * (R + R.T))
    Bc = cholesky(0.5 * (P + P.T), stats.names, "The inverse of the robust covariance")[0]
    A, Bc = np.tril(A), np.tril(Bc)
    C = sla.solve_triangular(A.T, Bc.T, lower=False)
    Hinv = sla.cho_solve((A, True), np.eye(b))
    width = np.sqrt(np.diag(R) / np.diag(Hinv))
    rows = stats.rows.astype(int)
    return NoiseModel("sandwich", np.ones(stats.n_joints), rows, np.zeros(stats.n_joints, int),
                      transform=C, width=width, source=source)


def temper(stats: SufficientStats, model: NoiseModel) -> SufficientStats:
    """The sufficient statistics of the model's likelihood.

    neff: (G_j, g_j, s_j, r_j) / τ_j; sandwich: (CᵀG_jC, Cᵀg_j, s_j, r_j); white: unchanged.
    """
    if model.kind == "white":
        return stats
    if model.kind == "sandwich":
        C = model.transform
        return dataclasses.replace(stats, G=np.einsum("bi,jbc,cl->jil", C, stats.G, C),
                                   g=stats.g @ C)
    w = 1.0 / np.asarray(model.tau_int, dtype=float)
    return dataclasses.replace(stats, G=stats.G * w[:, None, None], g=stats.g * w[:, None],
                               s=stats.s * w, rows=stats.rows * w)
