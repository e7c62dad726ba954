"""Bayesian posterior of the dynamic parameters by ensemble MCMC (emcee), with checks.

The linear model, with the sampled system of Gautier, Janot &
Vandanjon (2010), section 2: Y = W χ + ρ (eq. (9)), the equations of each
joint grouped (eq. (10)), one error standard deviation σ_j per joint as in
the WLS of eq. (16).

Linear models (IDIM base or essential parameters, or any per-joint linear
   model given as W3 (N, n, b), tau (N, n)).

   Likelihood: ρ^j ~ N(0, σ_j² I_{r_j}) independently per joint (noise model "white"),
   by default with its curvature in χ matched to the robust (block-bootstrap) covariance
   of the LS fit (noise model "sandwich": S_j evaluated at χ_ref + C(χ − χ_ref), i.e.
   G_j, g_j → CᵀG_jC, Cᵀg_j; Ribatet, Cooley & Davison 2012), or tempered per joint by
   the effective sample size of its LS residual (noise model "neff": G_j, g_j, s_j, r_j →
   G_j/τ_j, g_j/τ_j, s_j/τ_j, r_j/τ_j); `dynid.analysis.sampling.noise`.
   Priors: Jeffreys p(σ_j) ∝ 1/σ_j on each σ_j; flat on χ, or a Gaussian
   N(μ₀, P₀) on some or all of χ (`GaussianPrior`, e.g. from a-priori
   values or from a previous identification).

   χ and the σ_j are sampled JOINTLY (nothing is marginalised for the linear
   model). The σ_j are sampled as u_j = log σ_j; with the Jeffreys prior the
   Jacobian dσ_j/du_j = σ_j cancels it exactly, so the density in (χ, u) is::

       log p(χ, u | Y) = Σ_j [ −r_j u_j − S_j(χ) e^{−2 u_j} / 2 ] + log p(χ) + const
       S_j(χ) = ‖Y^j − W^j χ‖²  (rows of joint j kept by the row_mask)

   With known σ_j (`sigma=`) only χ is sampled: log p = −Σ_j S_j/(2σ_j²) + log p(χ).

   Cost: S_j is evaluated from sufficient statistics computed ONCE after
   decimation (`sufficient_statistics`): G_j = W^jᵀW^j, and, about a
   reference χ_ref (the LS estimate), g_j = W^jᵀ(Y^j − W^jχ_ref),
   s_j = ‖Y^j − W^jχ_ref‖² and the row count r_j (plus the raw W^jᵀY^j and
   Y^jᵀY^j for the record). With δ = χ − χ_ref,
   S_j(χ) = s_j − 2 δᵀg_j + δᵀG_jδ: exact, cost O(n b²) per evaluation
   whatever the number of samples, and free of the cancellation of
   YᵀY − 2χᵀWᵀY + χᵀWᵀWχ. The log-probability is vectorised over walkers
   (emcee `vectorize=True`): K positions cost one (K, b)·(b, n b) product.

   Analytic results for checking:

   (a) known σ_j, flat or Gaussian prior: χ | Y ~ N(m, Λ⁻¹) with
       Λ = Σ_j G_j/σ_j² + P₀⁻¹ and m = χ_ref + Λ⁻¹ (Σ_j g_j/σ_j² + P₀⁻¹(μ₀ − χ_ref))
       (`known_noise_posterior`).
   (b) a single joint, unknown σ, flat prior on χ, Jeffreys on σ:
       p(χ | Y) ∝ S(χ)^{−r/2}, a multivariate Student t. The marginal of χ_i is
       χ_i = χ̂_i + s √[(WᵀW)⁻¹]_ii · T_ν,  T_ν ~ Student t with ν = r − b,
       χ̂ = (WᵀW)⁻¹WᵀY (OLS), s² = ‖Y − Wχ̂‖² / (r − b) (eq. (13)); and
       σ² | Y ~ ‖Y − Wχ̂‖² / χ²_ν (scaled inverse χ²), i.e. the LS interval
       χ̂_i ± t_ν s √[(WᵀW)⁻¹]_ii is exactly the credible interval
       (`student_t_posterior`).

The nonlinear per-joint gravity model of Bona & Curatella (2005, eq. (23))
that was sampled here too now lives with its tests (tests/support/gravity_posterior.py):
no user-facing command or function reached it.

Outputs: `PosteriorResult` (samples after burn-in and thinning,
summaries, intervals beside the LS values, convergence diagnostics from
`dynid.analysis.sampling.convergence`; `converged=False` with the reason whenever the
rule was not met). Runs are seeded: the same `seed` gives the same chain,
the same `PosteriorResult.to_dict` and the same CSV, byte for byte
on any machine: runs stop on a step budget, never on the clock unless a
`max_seconds` limit is asked for (then the stopping point depends on the machine).

The concepts live in their own modules, re-exported here (the names users
import from dynid.analysis.sampling.posterior): `sufficient` (the per-joint
sufficient statistics), `noise` (the likelihood's noise model), `linear`
(priors, log-posterior, closed forms),
`ensemble` (emcee: moves, walkers, seeding, start, rule), `sample`
(`sample_linear`, `sample_idim`) and `result` (`PosteriorResult`).
"""
from dynid.analysis.sampling.linear import (
    GaussianPrior,
    LinearPosterior,
    StudentTPosterior,
    known_noise_posterior,
    student_t_posterior,
)
from dynid.analysis.sampling.result import MissingDependencyError, PosteriorResult
from dynid.analysis.sampling.sample import sample_idim, sample_linear
from dynid.analysis.sampling.sufficient import SufficientStats, sufficient_statistics

__all__ = [
    "SufficientStats", "sufficient_statistics", "GaussianPrior", "LinearPosterior",
    "known_noise_posterior", "student_t_posterior", "StudentTPosterior",
    "sample_linear", "sample_idim", "PosteriorResult", "MissingDependencyError",
]
