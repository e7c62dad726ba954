"""Physically consistent weighted least squares (PC-WLS): an SDP over the standard parameters.

The unconstrained WLS of `dynid.analysis.estimators.least_squares`
(Gautier, Janot & Vandanjon 2010, eq. (16)) fits the base parameters
`beta` freely; nothing keeps them those of a rigid body. PC-WLS minimises
the *same* weighted residual over the standard parameters `chi`
(`beta = P chi`, `dynid.dynamics.base_parameters`), subject to

* every link's pseudo-inertia `J_l(chi)` positive semidefinite (Wensing,
  Kim & Slotine 2017, "Linear matrix inequalities for physically consistent
  inertial parameter identification", IEEE RA-L 3(1)): mass >= 0, centre of
  mass where a non-negative density can put it, triangle inequalities;
* actuator inertia `Ia >= 0`, viscous `Fv >= 0` and Coulomb `Fc >= 0`
  friction (also those of a coupled motor);
* optionally each mass within a fraction of its a-priori value
  (`mass_tolerance`).

Why the objective is written in base-parameter space. With the per-joint
weights 1/sigma_j of the WLS kept fixed, the weighted squared residual of
any beta is `||W~ beta - Y~||^2 = ||W~ beta_wls - Y~||^2 + ||R (beta -
beta_wls)||^2` with `R^T R = W~^T W~` (Pythagoras on the range of W~). So

    minimise   ||R_c (P chi - beta_wls)||^2  +  w * sum_i ((chi_i - chi_ap_i) / s_i)^2
    subject to the constraints above,               R_c^T R_c = cov_wls^-1,

has the PC-WLS solution, and its first term (call it Delta) is the growth of
the weighted squared residual in units of the WLS error variance
sigma_rho^2 (eq. (13)): a chi^2 statistic. `chi_ap` are the robot file's
a-priori values and `s_i` per-parameter scales (as in
`dynid.analysis.estimators.standard_set`). The second term is the
Euclidean regularisation toward the a-priori values (`prior="apriori"`); `w`
is reported. With `prior=None` it is only a tie-break (`w = 1e-8`): the data
see the base parameters only, and among the standard sets with the same fit the
one closest to the a-priori values is returned.

The geometric prior (`prior="geometric"`; Lee, Wensing & Park 2020, "Geometric
robot dynamic identification: a convex programming approach", IEEE T-RO 36(2),
the entropic divergence; the authors' reference code, `ID_Entropic.m`
of Geometric-Robot-DynID, minimises the same -log det J + tr(J0^-1 J)). For the
ten inertial parameters of link l the Euclidean term is replaced by the Bregman
divergence of -log det on the pseudo-inertias (twice the Kullback-Leibler
divergence of zero-mean Gaussians of covariances J_l and J0_l),

    d(J_l || J0_l) = -log det(J0_l^-1 J_l) + tr(J0_l^-1 J_l) - 4,

with `J0_l` the a-priori link's pseudo-inertia (it must be positive definite:
a robot file without a-priori inertials is refused). d is convex in J_l, zero
only at J_l = J0_l, and invariant under a rigid change of the link's frame
(J -> T J T^T, T a homogeneous transform, applied to J and J0), which no
per-parameter Euclidean distance is: the pull no longer depends on where the
link frame sits or on the scales s_i. Near J0 it is `||J0^-1/2 dJ J0^-1/2||_F^2 / 2`,
a relative change like the scaled Euclidean term, so the same weight `w`
means about the same strength. The parameters that have no pseudo-inertia (Ia,
Fv, Fc, Off, motor couplings) keep the Euclidean term with the same `w`.
The SDP gains one log-det (exponential and PSD cones, Clarabel) per link. This
is the paper's entropic divergence, not its constant-pullback distance (the
quadratic form of the affine-invariant metric at J0).

The test "the data want a non-physical model". Under the hypothesis that
the true parameters are physically consistent, Delta is a chi-bar-squared
variable (a mixture of chi^2_0 .. chi^2_k over the k active constraint
directions; Shapiro 1985, Kodde & Palm 1986), and P(chi-bar^2 > c) <=
P(chi^2_k > c). The reported `p_value` is that bound with k the number of
active scalar constraints (`r (r + 1) / 2` for a pseudo-inertia of nullity
r, 1 per bound), so it is conservative: a small p-value means the data
really want a non-physical model (a modelling error worth diagnosing), a
large one that the constraint costs nothing worth noticing.

Uncertainty: a parametric bootstrap of the constrained fit (`n_boot`
draws). The PC fit depends on the data only through `beta_wls`, whose
distribution under Gaussian errors is N(beta, cov_wls); so draws beta* ~
N(P chi_pc, cov_wls), centred on the constrained fit, are exactly the WLS
estimates of data simulated from the fitted physical model, and each is
re-fitted under the constraints. The intervals (`conf_int`) are the hull of
the bootstrap percentile interval and the estimate plus or minus z sigma_wls, cut at the
physical bound of a base parameter that is a lone Ia, Fv or Fc (>= 0):

    [min(q_lo, max(beta_pc - z sigma_wls, lb)),  max(q_hi, beta_pc + z sigma_wls)].

Why not the percentiles alone: the bootstrap spread is smaller than the WLS
one only where a constraint cuts it, and that is the spread of the estimator
*if the truth is on the constraint*; a truth just inside it (the usual case
for a thin link) is not covered at the nominal rate (Andrews 2000), and with
few refits the 2.5/97.5 % quantiles are themselves noisy (the interval
between the k-th smallest and largest of n draws holds a new draw with
probability (n + 1 - 2k) / (n + 1): 91 % for n = 50). The constraint removes
only non-physical values; it makes the data no more informative elsewhere,
so the interval keeps the unconstrained half-width on each side and is
one-sided only where the physical bound itself cuts it (the truth is
physical, so the cut never removes it: the coverage is at least that of the
WLS interval). The standard errors (`bse`, %sigma) are the half-width of the
wider side of that 95 % interval (before the cut) over 1.96, with the correlations
of the refits (`interval_covariance`): `beta_pc +- 1.96 sigma` contains
`conf_int`. The refits' own spread (`boot_std`) is not reported as sigma: normal
intervals on it under-covered. Measured on 50 + 50 simulated Panda seeds near the
constraints in `benchmarks/physical_seeds.py --coverage`; see the CHANGELOG.

Solved with cvxpy and the Clarabel interior-point solver (optional extra
`dynid[physical]`). The problem is convex, so the solution is a global
optimum, unlike the log-Cholesky local search of
`dynid.analysis.estimators.standard_set.choose_standard_set`.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.estimators.essential import with_selection_bias
from dynid.analysis.estimators.sdp import (
    NONNEG_KINDS,
    active_constraints,
    apriori_pseudo_inertias,
    build_sdp,
    require_cvxpy,
    whitening,
)
from dynid.analysis.estimators.standard_set import REPRODUCE_CHI2, StandardSet, apriori_standard, scales
from dynid.analysis.processing.observation import observe
from dynid.analysis.processing.prediction import prediction_errors
from dynid.analysis.results import (
    ParameterResults,
    _check_alpha,
    deprecated_alias,
    notices_block,
    parameter_table,
    percent,
)
from dynid.analysis.units import parameter_unit
from dynid.dynamics.urdf_writer import consistency, inertial_slice, pseudo_inertia_basis
from dynid.errors import InputError
from dynid.provenance import json_safe, versions
from dynid.ranges import check_range

__all__ = ["PhysicalResult", "PhysicalSupport", "pc_wls", "identify_physical", "require_cvxpy", "TIE_BREAK",
           "apriori_pseudo_inertias"]

#: weight of the a-priori term when no prior is asked for: it only picks one standard set
#: among those with the same base parameters
TIE_BREAK = 1e-8
#: the normal 97.5 % quantile: the level at which the reported sigma matches the interval
_Z95 = 1.959963984540054

#: the a-priori terms of pc_wls(prior=...): None = tie-break only
PRIORS = (None, "apriori", "geometric")


@dataclass(eq=False, repr=False)
class PhysicalResult(ParameterResults):
    """A physically consistent WLS estimate (the `ParameterResults` interface).

    `names`/`params`/`bse`/`cov`: all base parameters, `beta = P chi`;
    `conf_int`: the hull of the bootstrap percentiles and the WLS half-width, cut at
    the physical bound (module doc); `bse` (and %sigma) the half-width of the wider side of
    that 95 % interval over 1.96, so `params +- 1.96 bse` contains it
    (`interval_covariance`); `boot_std`: the spread of the bootstrap refits.
    `standard`: the standard set (what a URDF or MJCF holds).
    """

    method = "PC-WLS"

    robot_name: str
    names: list
    chi: np.ndarray                  # base parameters of the PC solution
    cov: np.ndarray                  # interval_covariance: +-1.96 sigma holds the 95 % conf_int
    standard_names: list
    standard: np.ndarray             # the standard set
    apriori: np.ndarray
    wls_chi: np.ndarray              # the unconstrained WLS estimate it is compared with
    wls_cov: np.ndarray              # the WLS covariance of the intervals (`uncertainty`)
    chi2: float                      # growth of the weighted squared residual / sigma_rho^2
    dof: int                         # active scalar constraints (k of the chi-bar^2 bound)
    p_value: float
    active: list
    links: list                      # per-link consistency checks of the standard set
    prior: str | None
    prior_weight: float
    mass_tolerance: float | None
    n_boot: int
    boot: np.ndarray | None = None   # (n_boot, b) bootstrap refits of the base parameters
    # the refits' covariance: the estimator's sampling covariance if the truth sat on the
    # active constraints (None without a bootstrap); not the reported one (interval_covariance)
    boot_cov: np.ndarray | None = None
    # physical lower bound of each base parameter used by conf_int: 0 for a lone Ia, Fv, Fc
    lower_bound: np.ndarray | None = None
    solve_seconds: float = math.nan
    wls_consistent: bool | None = None   # was the unconstrained estimate physical?
    rel_error: float = math.nan          # ||Y - W beta|| / ||Y|| on the identification data
    wls_rel_error: float = math.nan
    notices: list = field(default_factory=list)
    data_hash: str = ""
    idim: object = None              # the IDIMResult it came from, when it did
    # which unconstrained model was constrained: "base" (all base parameters) or "essential";
    # columns: the base-regressor columns of ``names`` (None: all, in order)
    model: str = "base"
    columns: np.ndarray | None = None
    # held-out errors of this fit and of the unconstrained one (held_out_block), when validated
    validation: dict | None = None
    # the covariance option of the intervals (dynid.analysis.estimators.least_squares.UNCERTAINTY)
    uncertainty: str = "classic"

    @property
    def consistent(self) -> bool:
        return all(lk["consistent"] for lk in self.links) and all(
            self.standard[i] >= -1e-12 for i, nm in enumerate(self.standard_names)
            if nm.rstrip("0123456789").rstrip("m") in NONNEG_KINDS)

    @property
    def base(self):
        """The base parameters (of the IDIM result it came from): what validate() needs."""
        return getattr(self.idim, "base", None)

    @property
    def settings(self):
        return getattr(self.idim, "settings", {})

    @property
    def robot(self):
        return getattr(self.idim, "robot", None)

    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r.bse.to_numpy())

    @property
    def boot_std(self):
        """The standard deviation of the bootstrap refits (None without a bootstrap): the
        estimator's spread if the truth sat on the active constraints; smaller than `bse`
        there (see `interval_covariance`)."""
        return None if self.boot_cov is None else np.sqrt(np.maximum(np.diag(self.boot_cov), 0.0))

    def conf_int(self, alpha: float = 0.05) -> pd.DataFrame:
        """(1 - alpha) intervals: hull of the bootstrap percentiles and `chi +- z sigma_wls`,
        cut at the physical lower bound (module doc); without a bootstrap the WLS half-width
        alone, with fewer than 20 refits `z` times the larger of it and the refits' spread (as
        `bse`), cut the same way.

        Returns
        -------
        pandas.DataFrame
            One row per parameter, columns `lower` and `upper`.
        """
        _check_alpha(alpha)
        sd = np.sqrt(np.maximum(np.diag(self.wls_cov), 0.0))
        if self.boot is not None and 2 <= len(self.boot) < 20:     # as `bse` (interval_covariance)
            sd = np.maximum(sd, np.std(self.boot, axis=0, ddof=1))
        half = self._interval_quantile(alpha) * sd
        lb = np.full(len(self.chi), -np.inf) if self.lower_bound is None else self.lower_bound
        lo, hi = np.maximum(self.chi - half, lb), self.chi + half
        if self.boot is not None and len(self.boot) >= 20:
            q_lo, q_hi = np.quantile(self.boot, [alpha / 2, 1 - alpha / 2], axis=0)
            lo, hi = np.minimum(lo, q_lo), np.maximum(hi, q_hi)
        return pd.DataFrame({"lower": lo, "upper": hi}, index=self._index())

    def standard_frame(self) -> pd.DataFrame:
        return pd.DataFrame({"apriori": self.apriori, "value": self.standard},
                            index=pd.Index(self.standard_names, name="parameter"))

    def comparison(self) -> pd.DataFrame:
        """Per base parameter: WLS value and sigma, PC value and sigma (interval_covariance), shift in WLS sigma.

        Returns
        -------
        pandas.DataFrame
            One row per base parameter.
        """
        s_wls = np.sqrt(np.maximum(np.diag(self.wls_cov), 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            return pd.DataFrame({"wls": self.wls_chi, "wls_std": s_wls,
                                 "wls_rel_std_percent": 100 * s_wls / np.abs(self.wls_chi),
                                 "pc": self.chi, "pc_std": self.bse.to_numpy(),
                                 "shift_sigma": (self.chi - self.wls_chi) / s_wls},
                                index=self._index())

    def to_standard_set(self):
        """The PC standard set as a `StandardSet`
        (what the URDF export writes), its targets the unconstrained WLS values.

        Returns
        -------
        StandardSet
            The standard parameters of every link, physically consistent.
        """
        sig = np.sqrt(np.maximum(np.diag(self.wls_cov), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            dev = (self.chi - self.wls_chi) / sig
        table = pd.DataFrame({"identified": self.wls_chi, "std": sig, "chosen": self.chi,
                              "deviation_sigma": dev}, index=pd.Index(self.names, name="base parameter"))
        notices = [] if self.chi2 <= REPRODUCE_CHI2 else [
            f"PC-WLS: {self.verdict_line()}; active: {', '.join(self.active) or 'none'}"]
        beta, base_names = self.chi, list(self.names)
        if self.columns is not None and self.idim is not None:
            # the essential fit: the set's own base parameters, all of them (what a URDF of it holds)
            beta, base_names = self.idim.base.from_standard(self.standard), list(self.idim.base.names)
        return StandardSet(robot_name=self.robot_name, names=list(self.standard_names), chi=self.standard,
                           apriori=self.apriori, beta=beta, target=table, base_names=base_names,
                           consistent=self.consistent, reproduces=bool(self.chi2 <= REPRODUCE_CHI2),
                           links=self.links, chi2=self.chi2,
                           message="PC-WLS (SDP, cvxpy + Clarabel): the physically consistent fit itself",
                           notices=notices)

    def predict(self, W_base):
        """Torques (N, n) from a base regressor (N, n, b) (its essential columns for the
        PC fit of the essential set).

        Returns
        -------
        numpy.ndarray
            (N, n) joint torques [N m].
        """
        W = np.asarray(W_base)
        return (W if self.columns is None else W[..., self.columns]) @ self.chi

    def held_out_block(self, experiment, robot) -> dict:
        """Held-out relative error ||tau - tau_hat|| / ||tau|| and per-joint RMS [N m] of this fit and
        of the unconstrained WLS it constrains, on all decimated samples of `experiment` (no dead
        zone, as `dynid.analysis.statistics.validation.validate`), with the gap in points.

        Returns
        -------
        dict
            JSON-safe: relative errors and per-joint RMS [N m] of both fits.
        """
        if self.idim is None:
            raise InputError("held_out_block: this PC fit does not carry the IDIM result it came from")
        full = observe(experiment, robot, self.idim.base, dict(self.settings, qd_threshold=0.0))
        W = full.W if self.columns is None else full.W[..., self.columns]
        e_wls, rms_wls, _ = prediction_errors(full.tau, W @ self.wls_chi)
        e_pc, rms_pc, _ = prediction_errors(full.tau, W @ self.chi)
        return {"samples": "all", "n_samples": int(full.tau.shape[0]), "rel_error_wls": e_wls,
                "rms_wls": [float(x) for x in rms_wls], "rel_error_pc": e_pc,
                "rms_pc": [float(x) for x in rms_pc], "gap_points": 100.0 * (e_pc - e_wls)}

    def physical_block(self) -> dict:
        """The JSON block `"physical"` of `dynid identify --physical`.

        Returns
        -------
        dict
            JSON-safe.
        """
        return json_safe({
            "model": self.model,
            "consistent": self.consistent, "active": self.active, "chi2": self.chi2, "dof": self.dof,
            "p_value": self.p_value, "unconstrained_consistent": self.wls_consistent,
            "prior": self.prior, "prior_weight": self.prior_weight, "mass_tolerance": self.mass_tolerance,
            "rel_error": self.rel_error, "wls_rel_error": self.wls_rel_error,
            "n_boot": self.n_boot, "uncertainty": self.uncertainty,
            "solve_seconds": self.solve_seconds, "validation": self.validation,
            "test": ("chi2 = growth of the weighted squared residual over the unconstrained WLS, in "
                     "units of its error variance; p_value = P(chi2_dof > chi2), an upper bound of the "
                     "chi-bar-squared p-value with dof = active scalar constraints"),
            # the records of every result (unit, %sigma), with the unconstrained value beside each
            "parameters": [{**r, "wls": w} for r, w in zip(self._records(), self.wls_chi)],
            "standard_parameters": [{"name": n, "value": v, "apriori": a, "unit": parameter_unit(n, self._prismatic())}
                                    for n, v, a in zip(self.standard_names, self.standard, self.apriori)],
            "links": self.links,
            "notices": self.notices,
        })

    def to_dict(self) -> dict:
        return json_safe({"method": self.method, "robot": self.robot_name,
                          "parameters": self._records(),
                          "physical": self.physical_block(), "data_hash": self.data_hash,
                          "versions": versions()})

    def verdict_line(self) -> str:
        if not self.active or self.chi2 < 1e-6:
            return "the constraints cost nothing: the unconstrained fit is (or is as good as) physical"
        if self.p_value < 0.01:
            return (f"the data want a non-physical model (chi2 = {self.chi2:.4g} on {self.dof} active "
                    f"constraint directions, p <= {self.p_value:.3g}): a modelling error worth diagnosing")
        return (f"the constraints cost little (chi2 = {self.chi2:.4g}, p <= {self.p_value:.3g}): "
                f"compatible with a physical model")

    def summary(self) -> str:
        lines = [f"Physically consistent WLS (PC-WLS, SDP) of robot '{self.robot_name}'"
                 + (", essential parameters" if self.model == "essential" else ""),
                 f"  every link consistent: {'yes' if self.consistent else 'NO'}; unconstrained WLS "
                 f"physical: {'yes' if self.wls_consistent else 'no'}",
                 f"  active constraints: {', '.join(self.active) or 'none'}",
                 f"  chi2 = {self.chi2:.4g} (dof {self.dof}), p <= {self.p_value:.3g}: {self.verdict_line()}",
                 f"  relative error ||Y - W beta|| / ||Y||: PC {percent(self.rel_error)}, "
                 f"WLS {percent(self.wls_rel_error)}",
                 *([f"  held-out relative error (all samples): PC {percent(self.validation['rel_error_pc'])}, WLS "
                    f"{percent(self.validation['rel_error_wls'])} (PC - WLS "
                    f"{self.validation['gap_points']:+.3f} points)"]
                   if self.validation else []),
                 f"  a-priori term: {self.prior or 'tie-break only'}, weight {self.prior_weight:g}; "
                 f"sigma: wider side of the 95 % interval / 1.96 ({self.n_boot} bootstrap refits)"]
        c = self.comparison()
        lines += parameter_table(self.names, [("PC", c["pc"], "num"), ("sigma", c["pc_std"], "num"),
                                              ("%sigma", self.rel_std.to_numpy(), "pct"), ("WLS", c["wls"], "num"),
                                              ("shift [sigma]", c["shift_sigma"], lambda x: f"{x:.2f}")],
                                 prismatic=self._prismatic())
        lines += notices_block(self.notices)
        return "\n".join(lines)


def pc_wls(robot, bp, beta_wls, cov_wls, *, prior=None, prior_weight=1.0, mass_tolerance=None,
           n_boot=100, seed=0, apriori=None, interval_cov=None, uncertainty="classic",
           check_wls=True) -> PhysicalResult:
    """PC-WLS from an unconstrained WLS estimate `beta_wls` (b,) and its covariance (b, b).

    `prior`: None (a-priori values only break ties), `"apriori"` (add
    `prior_weight * sum(((chi - chi_ap) / s)^2)`, Euclidean, to the chi^2) or
    `"geometric"` (add `prior_weight` times the entropic divergence of each link's
    pseudo-inertia from its a-priori one, Lee, Wensing & Park 2020, and the Euclidean term
    of the other parameters; module doc). `apriori`: standard values to use instead of
    the robot file's.
    `mass_tolerance`: keep each link mass within this fraction of its
    a-priori value (default: the robot file's `[apriori] mass_tolerance`, else none). `n_boot`: parametric-bootstrap refits for the
    uncertainty (0: the WLS covariance is reported, with a notice).
    `interval_cov`: the covariance of `beta_wls` the bootstrap draws from and whose half-width
    the intervals keep (a HAC or block-bootstrap one, named by `uncertainty`); default
    `cov_wls`. The fit's metric stays `cov_wls` (eq. (14)'s), so the estimate does not depend
    on it: only `bse`, `conf_int` and the refits do, and they agree with each other. On the
    independent TX40 plant with AR(1) noise and a ripple (benchmarks/coverage_independent.py,
    held-out seeds 4000-4099) the 95 % intervals cover 88.0 % drawn from the classic
    covariance and 95.8 % from the block bootstrap's (1.38 times the classic WLS width).
    `check_wls`: also test whether some rigid body has the unconstrained estimate (a second
    SDP, `wls_consistent`); False skips it (`wls_consistent` None, the fit itself unchanged),
    for callers that use only the fit (the residual diagnosis' physical test).
    """
    if prior not in PRIORS:
        raise InputError(f"prior must be one of None, 'apriori' (Euclidean) or 'geometric' (Lee, Wensing & "
                         f"Park 2020), got {prior!r}")
    try:
        w = TIE_BREAK if prior is None else float(prior_weight)
    except (TypeError, ValueError):
        w = math.nan
    if not (math.isfinite(w) and w >= 0):
        raise InputError(f"prior_weight must be a number >= 0, got {prior_weight!r}")
    check_range("prior_weight", prior_weight)
    n_boot = check_range("n_boot", n_boot)
    beta_wls = np.asarray(beta_wls, dtype=float)
    cov_wls = np.asarray(cov_wls, dtype=float)
    interval_cov = cov_wls if interval_cov is None else np.asarray(interval_cov, dtype=float)
    if (beta_wls.shape != (bp.n_base,) or cov_wls.shape != (bp.n_base, bp.n_base)
            or interval_cov.shape != cov_wls.shape):
        raise InputError(f"pc_wls: {bp.n_base} base parameters expected, got an estimate of shape "
                         f"{beta_wls.shape} and covariances of shape {cov_wls.shape} and {interval_cov.shape}")
    chi_ap = apriori_standard(robot) if apriori is None else np.asarray(apriori, dtype=float)
    s = scales(robot, chi_ap)
    R = whitening(cov_wls)
    if mass_tolerance is None:
        mass_tolerance = getattr(robot, "mass_tolerance", None)      # [apriori] mass_tolerance
    pb = build_sdp(robot, bp, R, chi_ap, s, w, mass_tolerance, prior=prior)
    t0 = time.perf_counter()
    chi = pb.solve(R @ beta_wls)
    seconds = time.perf_counter() - t0
    status = pb.prob.status
    beta = bp.matrix @ chi
    chi2 = float(np.sum((R @ (beta - beta_wls)) ** 2))
    active, k = active_constraints(pb, chi)
    p = 1.0 if k == 0 else float(stats.chi2.sf(chi2, min(k, bp.n_base)))
    notices = []
    if status != "optimal":
        notices.append(f"the SDP solver ended with status {status}: the solution is feasible to the "
                       "solver's tolerance but its last digits may be off")
    boot = None
    if n_boot:
        rng = np.random.default_rng(seed)
        # a square root by eigen-decomposition: a Cholesky factor can fail on the nearly
        # singular covariance of a badly excited parameter
        w_c, V_c = np.linalg.eigh(0.5 * (interval_cov + interval_cov.T))
        L = V_c * np.sqrt(np.maximum(w_c, 0.0))
        draws = beta + rng.standard_normal((int(n_boot), bp.n_base)) @ L.T
        refits, failed = [], 0
        for d in draws:
            try:
                refits.append(bp.matrix @ pb.solve(R @ d))
            except InputError:
                failed += 1
        if failed:
            # an interior-point failure on one draw (numerical, seen once in 2,500 refits of
            # PC-DIDIM's last step) must not discard the fit; the count is reported
            notices.append(f"{failed} of {int(n_boot)} bootstrap refits failed in the SDP solver and "
                           "are left out of the intervals")
        boot = np.array(refits) if refits else None
    else:
        notices.append("no bootstrap (n_boot = 0): the reported sigma and intervals are the "
                       "unconstrained WLS ones (cut at the physical bounds)")
    boot_cov = None if boot is None or len(boot) < 2 else np.cov(boot, rowvar=False).reshape(cov_wls.shape)
    cov = interval_covariance(beta, interval_cov, boot, boot_cov)
    if uncertainty != "classic":
        notices.append(f"sigma and intervals: the bootstrap draws from the {uncertainty} covariance of the "
                       "WLS estimate (its metric stays the classic eq. (14), so the estimate does not move)")
    wls_std = _wls_standard_consistent(robot, bp, beta_wls) if check_wls else None
    if wls_std is False:
        notices.append("the unconstrained WLS base parameters are those of no rigid body "
                       "(no consistent standard set reproduces them)")
    return PhysicalResult(robot_name=robot.name, names=list(bp.names), chi=beta, cov=cov,
                          standard_names=pb.names, standard=chi, apriori=chi_ap, wls_chi=beta_wls,
                          wls_cov=interval_cov, chi2=chi2, dof=k, p_value=p, active=active,
                          links=consistency(robot, chi), prior=prior, prior_weight=w,
                          mass_tolerance=mass_tolerance, n_boot=int(n_boot), boot=boot, boot_cov=boot_cov,
                          lower_bound=_lower_bounds(bp.names),
                          solve_seconds=seconds, wls_consistent=wls_std, notices=notices,
                          uncertainty=uncertainty)


def interval_covariance(beta, cov_wls, boot=None, boot_cov=None):
    """The reported covariance of a PC fit: standard deviations that make `beta +- 1.96 sigma`
    contain the 95 % interval of `PhysicalResult.conf_int` (before its cut at a bound),

        sigma_i = max(sigma_wls_i, (q97.5_i - beta_i) / 1.96, (beta_i - q2.5_i) / 1.96),

    with the correlations of the bootstrap refits `boot` (K, b; `boot_cov` their covariance,
    computed when not given) (those of `cov_wls`
    without a bootstrap or with fewer than 20 refits, where `sigma_i` is the larger of
    `sigma_wls_i` and the refits' spread).

    Why not the bootstrap spread itself: it is the spread of the estimator *if the truth is
    on the constraint*, smaller than the WLS one wherever a constraint cuts it, and normal
    intervals built on it under-covered (91.7-92.4 % on the simulated seeds of
    `benchmarks/physical_seeds.py --coverage`, nominal 95 %). %sigma (eq. (15)) read as
    +-1.96 sigma must be an interval that covers; the bootstrap's spread stays available as
    `PhysicalResult.boot_std`.
    """
    sd_wls = np.sqrt(np.maximum(np.diag(cov_wls), 0.0))
    if boot is not None and len(boot) >= 20:
        z = _Z95
        q_lo, q_hi = np.quantile(boot, [0.025, 0.975], axis=0)
        sd = np.maximum.reduce([sd_wls, (q_hi - beta) / z, (beta - q_lo) / z])
        corr_of = np.cov(boot, rowvar=False).reshape(len(beta), len(beta)) if boot_cov is None else boot_cov
    else:
        sd = sd_wls if boot is None or len(boot) < 2 else np.maximum(sd_wls, np.std(boot, axis=0, ddof=1))
        corr_of = np.asarray(cov_wls, dtype=float)
    d = np.sqrt(np.maximum(np.diag(corr_of), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        C = corr_of / np.outer(d, d)
    # a parameter the refits never moved (pinned at a bound in every draw) has no correlation
    C = np.where(np.isfinite(C), C, 0.0)
    np.fill_diagonal(C, 1.0)
    return C * np.outer(sd, sd)


def _lower_bounds(names):
    """0 for a base parameter that is a lone Ia, Fv or Fc (nothing regrouped into it, so the
    constraint bounds it directly), -inf for the others (whose physical range the intervals
    do not use)."""
    return np.array([0.0 if n.rstrip("0123456789").rstrip("m") in NONNEG_KINDS else -np.inf for n in names])


def _wls_standard_consistent(robot, bp, beta_wls):
    """Whether some consistent standard set reproduces beta_wls exactly (a feasibility SDP)."""
    cp = require_cvxpy()
    n_std = robot.n_standard
    chi = cp.Variable(n_std)
    E = pseudo_inertia_basis()
    cons = [bp.matrix @ chi == beta_wls]
    for j in range(robot.n_joints):
        sl = inertial_slice(robot, j)
        cons.append(sum(E[k] * chi[sl.start + k] for k in range(10)) >> 0)
    nonneg = [i for i, nm in enumerate(robot.standard_names) if nm.rstrip("0123456789").rstrip("m") in NONNEG_KINDS]
    if nonneg:
        cons.append(chi[nonneg] >= 0)
    prob = cp.Problem(cp.Minimize(0), cons)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)     # the status says it
            prob.solve(solver="CLARABEL")
    except cp.error.SolverError:
        return None
    if prob.status in ("infeasible", "infeasible_inaccurate"):
        return False
    return True if prob.status in ("optimal", "optimal_inaccurate") else None


class _Rows:
    """The base parameters `names` of `bp` alone (the essential set): rows of P."""

    def __init__(self, bp, names):
        self.names = list(names)
        self.rows = np.array([bp.names.index(n) for n in self.names], dtype=int)
        self.matrix = bp.matrix[self.rows]
        self.n_base = len(self.names)


def identify_physical(result, robot, *, prior=None, prior_weight=1.0, mass_tolerance=None,
                      n_boot=100, seed=0, which="base", uncertainty=None) -> PhysicalResult:
    """PC-WLS of an IDIM result: its WLS of all base parameters (`which="base"`) or its
    essential WLS (`which="essential"`), constrained.

    The base regressor, the decimation and the per-joint weights 1/sigma_j are
    those of `result` (`dynid.analysis.estimators.idim.identify_idim`).

    The essential set: the same SDP with the essential WLS estimate and covariance as the
    target and `beta_e = P_e chi` (the essential rows of P). The parameters the essential
    model dropped are not in its torques, so they are free in the SDP: the standard set
    gives them whatever values consistency needs (reported in `standard`; a URDF of that
    set predicts them too, a small difference by the essential rule's construction).

    `uncertainty` (one of dynid.analysis.estimators.least_squares.UNCERTAINTY; default: the
    IDIM result's own): the covariance the bootstrap draws from and the intervals keep. The
    fit's metric is the classic covariance of eq. (14) whatever it is, so the PC estimate does
    not depend on it (a result identified with a robust option is refitted with the classic
    one for the metric, the same estimate).
    """
    wls = getattr(result, "wls", None)
    if wls is None or getattr(result, "base", None) is None:
        raise InputError("the physically consistent fit starts from an IDIM result (its WLS of all base "
                         f"parameters); got {type(result).__name__}")
    if which not in ("base", "essential"):
        raise InputError(f"which must be 'base' or 'essential', got {which!r}")
    columns = None
    bp = result.base
    if which == "essential":
        ess = getattr(getattr(result, "essential", None), "result", None)
        if ess is None:
            raise InputError("this IDIM result has no essential parameters; use which='base'")
        bp = _Rows(result.base, ess.names)
        columns = bp.rows
        wls = ess
    own = getattr(result, "uncertainty", "classic") or "classic"
    uncertainty = own if uncertainty is None else ls.check_uncertainty(uncertainty)
    metric, interval = wls.cov, wls.cov
    if own != "classic" or uncertainty != own:
        metric, interval = _covariances(result, which, uncertainty, wls)
    res = pc_wls(robot, bp, wls.chi, metric, prior=prior, prior_weight=prior_weight,
                 mass_tolerance=mass_tolerance, n_boot=n_boot, seed=seed, interval_cov=interval,
                 uncertainty=uncertainty)
    res.model, res.columns = which, columns
    obs = getattr(result, "observation", None)
    if obs is not None:
        mask = np.asarray(obs.row_mask, dtype=bool)
        if mask.ndim == 1:
            mask = np.broadcast_to(mask[:, None], obs.tau.shape)
        y = np.where(mask, obs.tau, 0.0)
        res.rel_error = float(np.linalg.norm(np.where(mask, obs.tau - res.predict(obs.W), 0.0)) /
                              np.linalg.norm(y))
        res.wls_rel_error = float(wls.rel_error)
    res.idim = result
    res.data_hash = getattr(result, "data_hash", "") or ""
    return res


def _covariances(result, which, uncertainty, wls):
    """(classic, `uncertainty`) covariances of the WLS estimate `wls` of an IDIM result.

    Refitted on the result's decimated system with its weights (the same estimate, checked):
    the classic one is PC-WLS's metric, the other one its intervals'.
    """
    obs = getattr(result, "observation", None)
    if obs is None:
        raise InputError(f"uncertainty={uncertainty!r} for PC-WLS needs the IDIM result's samples "
                         "(its observation system); this result has none: use its own covariance")
    kw = {"row_mask": obs.row_mask, "joint_sigma": result.wls.joint_sigma,
          "groups": getattr(result, "groups", None)}
    names = list(result.base.names)
    cols = np.arange(len(names)) if which == "base" else np.array([names.index(n) for n in wls.names])
    out = []
    for opt in ("classic", uncertainty):
        if which == "base":
            r = ls.wls(obs.W, obs.tau, names, uncertainty=opt, **kw)
        else:   # the essential set's robust rule: the full model's covariance plus the removal bias
            r = ls.wls(obs.W[:, :, cols], obs.tau, list(wls.names), uncertainty=opt, **kw)
            if opt != "classic":
                full = ls.wls(obs.W, obs.tau, names, uncertainty=opt, **kw)
                r = with_selection_bias(r, full, cols)
        if not np.allclose(r.chi, wls.chi, rtol=1e-9, atol=1e-12):
            raise InputError("PC-WLS: the IDIM result's WLS estimate is not reproduced by its own system "
                             "(was it edited?); identify again")
        out.append(r.cov)
    return out[0], out[1]


class PhysicalSupport:
    """Indicator of the physically consistent set in base-parameter space (the posterior's support).

    `beta` (base parameters, or a subset `names` of them with the others zero, as an
    essential model) is physical when some standard set `chi` has `P chi = beta`, every
    link's pseudo-inertia PSD and Ia, Fv, Fc >= 0 (the constraints of PC-WLS, without the
    margin or the mass bounds): a feasibility SDP, compiled once and re-solved per point.
    Cheap tests first: a base parameter that is a lone Ia, Fv or Fc (its own column, nothing
    regrouped into it) must be >= 0 (necessary); and with `reference` (a consistent standard
    set, e.g. the PC-WLS one) the standard set keeping its regrouped parameters and taking the
    independent ones from `beta` is checked by eigenvalues (sufficient when it passes). The
    SDP decides only the points between the two.
    """

    def __init__(self, robot, bp, names=None, reference=None):
        cp = require_cvxpy()
        self.cp = cp
        names = list(bp.names) if names is None else [str(n) for n in names]
        unknown = [n for n in names if n not in bp.names]
        if unknown:
            raise InputError(f"physical support: {', '.join(unknown)} are not base parameters of "
                             f"'{robot.name}'")
        self.idx = np.array([bp.names.index(n) for n in names], dtype=int)
        self.n_base = bp.n_base
        chi = cp.Variable(robot.n_standard)
        self.beta = cp.Parameter(bp.n_base)
        E = pseudo_inertia_basis()
        cons = [bp.matrix @ chi == self.beta]
        for j in range(robot.n_joints):
            sl = inertial_slice(robot, j)
            cons.append(sum(E[k] * chi[sl.start + k] for k in range(10)) >> 0)
        std = list(robot.standard_names)
        nonneg = [i for i, nm in enumerate(std) if nm.rstrip("0123456789").rstrip("m") in NONNEG_KINDS]
        if nonneg:
            cons.append(chi[nonneg] >= 0)
        self.prob = cp.Problem(cp.Minimize(0), cons)
        self.lone = [k for k, n in enumerate(names) if n.rstrip("0123456789").rstrip("m") in NONNEG_KINDS]
        self.n_solves = 0
        self.bp = bp
        self.links = [inertial_slice(robot, j) for j in range(robot.n_joints)]
        self.nonneg_std = np.array(nonneg, dtype=int)
        self.reference = None if reference is None else np.asarray(reference, dtype=float)

    def _one(self, beta_full):
        self.beta.value = beta_full
        self.n_solves += 1
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                self.prob.solve(solver="CLARABEL")
        except self.cp.error.SolverError:
            return False
        return self.prob.status in ("optimal", "optimal_inaccurate")

    def __call__(self, B) -> np.ndarray:
        """Boolean (K,): which rows of B (K, len(names)) are physically consistent."""
        B = np.atleast_2d(np.asarray(B, dtype=float))
        ok = np.all(np.isfinite(B), axis=1)
        if self.lone:
            ok &= np.all(B[:, self.lone] >= 0, axis=1)
        full = np.zeros((B.shape[0], self.n_base))
        full[:, self.idx] = B
        todo = np.flatnonzero(ok)
        if self.reference is not None and todo.size:
            dep = self.reference[self.bp.dependent]
            chi = np.tile(self.reference, (todo.size, 1))
            chi[:, self.bp.independent] = full[todo] - dep @ self.bp.K.T
            E = pseudo_inertia_basis()
            good = np.all(chi[:, self.nonneg_std] >= 0, axis=1) if self.nonneg_std.size else \
                np.ones(todo.size, dtype=bool)
            for sl in self.links:
                J = np.einsum("kp,pab->kab", chi[:, sl], E)
                good &= np.linalg.eigvalsh(J)[:, 0] >= 0
            todo = todo[~good]
        for k in todo:
            ok[k] = self._one(full[k])
        return ok
