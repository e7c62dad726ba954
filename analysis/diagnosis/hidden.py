"""Effects hidden in the parameters: what the base parameters absorbed, found through the
robot file's a-priori values.

An effect whose torque lies (almost) in the span of the base regressor leaves no
residual: the least-squares fit moves the parameters instead. The classic case is
a weight-compensation spring on a shoulder joint, `tau_j = k sin(q_j + phi)`,
shaped like the link's gravity torque: the first moments of that link take it
(measured on the independent plant: a 20 N m spring on TX40 joint 2 moves MX2R
from 2.11 to ~4.1 and the residual stays at the noise floor). The only signature
is in the parameters, which then contradict the a-priori (CAD, or a previous
identification) values.

Test (issue 13, item 5). Let `beta0_i` be the a-priori values of the model's
base parameters that have one (`robot.apriori` through
`dynid.dynamics.excitation.apriori_parameters`), with a prior standard
deviation `s_i = PRIOR_REL |beta0_i|` (the a-priori values are trusted to
`PRIOR_REL` = 10 %; a floor of `PRIOR_ABS` for values near zero). The prior fit
minimises

    J(beta, c) = sum_rows w_j^2 (y - X beta - E c)^2 / tau_j + sum_i ((beta_i - beta0_i) / s_i)^2   (1)

with `w_j = 1 / sigma_j` the joint weights of the WLS fit, `tau_j` the
integrated autocorrelation time of joint j's residual (so the data term counts
effective samples, like the selection's LR), and `E` the decimated columns of a
candidate (none for the reference fit). For a Gaussian linear model with a Gaussian
prior the drop `Delta = J_min(no E) - J_min(E)` is a likelihood-ratio statistic,
`chi2(k)` under "the a-priori values hold and no effect is missing" (k the
candidate's columns). The candidates are the gravity-shaped springs
`E_j = [cos q_j, sin q_j]` on each joint j (k = 2), Bonferroni over the joints.

Gate. The test runs only when the identified parameters contradict the a-priori
values, `|beta_hat_i - beta0_i| > APRIORI_K sqrt(sigma_i^2 + s_i^2)` for some i
(APRIORI_K = 3, as the verdict's a-priori check): without a contradiction there is
nothing hidden to explain.

Rule. A candidate is reported (`hidden`) when its Bonferroni p < alpha, its
amplitude `sqrt(c1^2 + c2^2)` is at least `MIN_AMPLITUDE_SIGMA` (5) of its
standard deviation, it explains most of the contradiction (the a-priori
deviation term of (1) falls by at least half), and the prior fit with it predicts
the held-out (validation) recording as well as the diagnosis' final model, within
`HELDOUT_TOL` (5 %) of its relative error. Why a tolerance and not "lower": an
exactly aliased effect changes the fit's span by nothing, so it cannot lower the
held-out error (measured on the independent plant, 20 N m spring on TX40 joint 2:
0.1586 % before, 0.1601 % after with the prior holding all the a-priori parameters
within 10 %); what it must not do is predict worse. Its before/after errors on
held-out data: the diagnosis' final model (before) and the prior fit with the
effect (after).

Limits. The a-priori values carry the whole burden: a CAD model off by more than
`PRIOR_REL` on a gravity parameter looks like a hidden spring of that shape
(the report names the parameters it contradicts so a user can judge which).
Robots without a-priori values get no test.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from dynid.analysis.estimators.physical import pc_wls
from dynid.analysis.results import p_phrase
from dynid.analysis.statistics.residuals import effective_sample_size
from dynid.dynamics.excitation import apriori_parameters

__all__ = ["hidden_effects", "physical_effects", "HiddenEffect", "PRIOR_REL", "PRIOR_ABS", "APRIORI_K",
           "MIN_AMPLITUDE_SIGMA", "HELDOUT_TOL"]

PRIOR_REL = 0.10
PRIOR_ABS = 1e-3
APRIORI_K = 3.0
MIN_AMPLITUDE_SIGMA = 5.0
HELDOUT_TOL = 0.05


@dataclass
class HiddenEffect:
    joint: int                     # 1-based
    name: str                      # "gravity_spring"
    amplitude: float               # N m, sqrt(c1^2 + c2^2): tau_j = A sin(q_j + phi)
    phase: float                   # rad
    sigma: float                   # N m, of the amplitude
    statistic: float               # Delta of eq. (1)
    p_value: float                 # Bonferroni over the joints
    deviation_before: float        # a-priori term of (1), prior fit without the effect
    deviation_after: float         # with it
    contradicted: list = field(default_factory=list)   # [(name, identified, a-priori, z)]
    errors: dict = field(default_factory=dict)         # {"validation": {"before", "after"}} rel. errors
    reported: bool = False
    route: str = "apriori"         # "apriori" (prior fit, eq. (1)) or "physical" (PC fit, eq. (2))
    alpha: float = 0.01            # the rule it was judged by (`shortfall`)
    min_amplitude_sigma: float = MIN_AMPLITUDE_SIGMA

    @property
    def label(self):
        return f"gravity-shaped spring on joint {self.joint}"

    def to_dict(self):
        return {"joint": self.joint, "name": self.name, "amplitude_nm": self.amplitude,
                "phase_rad": self.phase, "sigma_nm": self.sigma, "statistic": self.statistic,
                "p_value": self.p_value, "apriori_deviation_before": self.deviation_before,
                "apriori_deviation_after": self.deviation_after, "reported": self.reported,
                # the physical route holds the consistent fit's active bounds, with no values to give
                "contradicted": ([] if self.route == "physical" else
                                 [{"name": a, "identified": b, "apriori": c, "z": d}
                                  for a, b, c, d in self.contradicted]),
                "active_bounds": [a for a, *_ in self.contradicted] if self.route == "physical" else [],
                "errors": self.errors, "route": self.route}

    def missed_rule(self) -> str | None:
        """The first of the fit rules (module doc) the candidate misses: "p", "amplitude" or
        "share" (of the contradiction explained), or None (the held-out check is the caller's)."""
        if not self.p_value < self.alpha:
            return "p"
        if not self.amplitude >= self.min_amplitude_sigma * self.sigma:
            return "amplitude"
        if not self.deviation_after <= 0.5 * self.deviation_before:
            return "share"
        return None

    def shortfall(self) -> str:
        """Why a candidate that was not reported falls short of the rule, in words (its p-value
        alone can be tiny while its amplitude is lost in its own σ)."""
        v = self.errors.get("validation") or {}
        missed = self.missed_rule()
        if missed == "p":
            return f"{p_phrase(self.p_value)}, not below {self.alpha:g}"
        ratio = self.amplitude / self.sigma if self.sigma > 0 else math.inf
        if missed == "amplitude":
            return (f"{p_phrase(self.p_value)}, but its amplitude {self.amplitude:.3g} +- {self.sigma:.2g} N m "
                    f"is {ratio:.2g} sigma, below {self.min_amplitude_sigma:g}")
        if missed == "share":
            share = 1.0 - self.deviation_after / self.deviation_before if self.deviation_before > 0 else 0.0
            return (f"{p_phrase(self.p_value)}, but it explains {100 * share:.0f} % of the contradiction "
                    "(half needed)")
        if v:
            return (f"{p_phrase(self.p_value)}, but it predicts the held-out data worse "
                    f"({100 * v['before']:.3g} % -> {100 * v['after']:.3g} %)")
        return p_phrase(self.p_value)

    def sentence(self):
        v = self.errors.get("validation") or {}
        err = (f"; held-out error {100 * v['before']:.3g} % -> {100 * v['after']:.3g} %"
               if v else "")
        if self.route == "physical":
            return (f"joint {self.joint}: a torque {self.amplitude:.3g} sin(q{self.joint} "
                    f"{self.phase:+.3g}) N m (+- {self.sigma:.2g}) shaped like gravity was absorbed "
                    f"by the base parameters, which no rigid body has; with it, the physically "
                    f"consistent fit costs chi2 {self.deviation_before:.3g} -> "
                    f"{self.deviation_after:.3g} ({p_phrase(self.p_value)}){err}")
        names = ", ".join(a for a, *_ in self.contradicted[:3])
        return (f"joint {self.joint}: a torque {self.amplitude:.3g} sin(q{self.joint} "
                f"{self.phase:+.3g}) N m (+- {self.sigma:.2g}) shaped like gravity was absorbed by "
                f"the base parameters ({names} contradict the a-priori values); with it, the "
                f"parameters agree with the a-priori again (deviation {self.deviation_before:.3g} "
                f"-> {self.deviation_after:.3g}, {p_phrase(self.p_value)}){err}")


def _rows(X, Y, mask, scale):
    ri, rj = np.nonzero(mask)
    s = scale[rj]
    return X[ri, rj, :] * s[:, None], Y[ri, rj] * s


def _prior_fit(A, y, P, b0, s, E=None):
    """argmin of eq. (1): (coef, J_data, J_prior, covariance). A, y whitened data rows; P
    indices of the a-priori parameters in the columns of A."""
    p = A.shape[1]
    k = 0 if E is None else E.shape[1]
    Aa = A if E is None else np.hstack([A, E])
    R = np.zeros((P.size, p + k))
    R[np.arange(P.size), P] = 1.0 / s
    M = np.vstack([Aa, R])
    rhs = np.concatenate([y, b0 / s])
    coef, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    r = y - Aa @ coef
    d = (coef[P] - b0) / s
    cov = np.linalg.pinv(M.T @ M)
    return coef, float(r @ r), float(d @ d), cov


def hidden_effects(eobs, X, Y, mask, names, chi, sigma, robot, *, weights, alpha=0.01,
                   validation=None, prior_rel=PRIOR_REL):
    """Gravity-shaped springs the base parameters absorbed: list of `HiddenEffect`
    (the reported ones first; empty when the robot has no a-priori values or the
    parameters do not contradict them).

    `X` (M, n, p), `Y`, `mask`: the decimated design of the final model (base
    parameters `names[:nb]` then effect parameters), `chi`, `sigma` its WLS fit,
    `weights` (n,) `1 / sigma_j`. `validation`: `(Xv, Yv, maskv, eobs_v)` of the
    held-out recording, same columns.
    """
    if robot is None or not getattr(robot, "apriori", None):
        return []
    try:
        _, beta, missing = apriori_parameters(robot, eobs.bp)
    except Exception:        # a-priori values the base set cannot map: no test
        return []
    index = {nm: i for i, nm in enumerate(eobs.bp.names)}
    P = np.array([k for k, nm in enumerate(names) if nm in index and nm not in missing], dtype=int)
    if P.size == 0:
        return []
    b0 = np.array([beta[index[names[k]]] for k in P])
    s = np.maximum(prior_rel * np.abs(b0), PRIOR_ABS)
    chi, sigma = np.asarray(chi, float), np.asarray(sigma, float)
    z = (chi[P] - b0) / np.sqrt(sigma[P] ** 2 + s ** 2)
    contradicted = sorted(((names[k], float(chi[k]), float(b), float(zz))
                           for k, b, zz in zip(P, b0, z) if abs(zz) > APRIORI_K),
                          key=lambda x: -abs(x[3]))
    if not contradicted:
        return []
    n = Y.shape[1]
    A, y, scale = _effective_rows(X, Y, mask, chi, weights)
    coef0, jd0, jp0, _ = _prior_fit(A, y, P, b0, s)
    out = []
    for j in range(n):
        E, _ = _rows(_spring_columns(eobs, j), Y, mask, scale)
        coef, jd, jp, cov = _prior_fit(A, y, P, b0, s, E)
        delta = (jd0 + jp0) - (jd + jp)
        p_raw = float(stats.chi2.sf(max(delta, 0.0), 2))
        c = coef[-2:]
        amp = float(math.hypot(*c))
        g = c / max(amp, 1e-300)
        sd = float(math.sqrt(max(g @ cov[-2:, -2:] @ g, 0.0)))
        h = HiddenEffect(joint=j + 1, name="gravity_spring", amplitude=amp,
                         phase=float(math.atan2(c[0], c[1])), sigma=sd, statistic=float(delta),
                         p_value=float(min(1.0, n * p_raw)), deviation_before=jp0,
                         deviation_after=jp, contradicted=contradicted, alpha=alpha)
        ok = h.missed_rule() is None
        if ok and validation is not None:
            Xv, Yv, mv, ev = validation
            Dv = _spring_columns(ev, j)
            e_before = _rel(Yv, Xv @ chi, mv)
            e_prior = _rel(Yv, Xv @ coef0, mv)
            e_after = _rel(Yv, np.concatenate([Xv, Dv], axis=2) @ coef, mv)
            h.errors = {"validation": {"before": e_before, "prior_without_effect": e_prior,
                                       "after": e_after}}
            ok = e_after <= (1.0 + HELDOUT_TOL) * e_before
        h.reported = bool(ok)
        out.append(h)
    out.sort(key=lambda h: (not h.reported, h.p_value))
    return out


def _effective_rows(X, Y, mask, chi, weights):
    """Whitened rows (eq. (1)) counted in effective samples: each joint's rows are divided by
    the integrated autocorrelation time of its residual `Y - X chi` (the rows of the
    decimated residual are correlated). Returns `(A, y, scale)`."""
    res = np.where(mask, Y - X @ chi, 0.0)
    tau = np.ones(Y.shape[1])
    for j in range(Y.shape[1]):
        u = mask[:, j]
        if u.sum() > 20:
            tau[j] = max(1.0, float(effective_sample_size(res[u, j])[1]))
    scale = np.asarray(weights, float) / np.sqrt(tau)
    A, y = _rows(X, Y, mask, scale)
    return A, y, scale


def _spring_columns(eobs, j):
    """The decimated columns `[cos q_j, sin q_j]` of a gravity-shaped spring on joint j: (M, n, 2)."""
    q = np.asarray(eobs.q, float)[:, j]
    return eobs.decimate(np.stack([np.cos(q), np.sin(q)], axis=1), joint=j)


def _rel(Y, Yh, mask):
    r = np.where(mask, Y - Yh, 0.0)
    return float(np.linalg.norm(r) / np.linalg.norm(np.where(mask, Y, 0.0)))


def physical_effects(eobs, X, Y, mask, n_base, chi, robot, *, weights, alpha=0.01, validation=None,
                     min_amplitude_sigma=MIN_AMPLITUDE_SIGMA):
    """Gravity-shaped springs found through the physical constraints (issue 13 item 5, issue 15
    item 3): list of `HiddenEffect` with `route="physical"` (empty when the data do not
    want a non-physical model).

    `X` (M, n, n_base + k): the decimated design of the *full* base model (all base
    parameters, in `eobs.bp` order) followed by the selected effects' columns; `chi` its WLS
    fit; `weights` (n,) `1 / sigma_j`. `validation`: `(Xv, Yv, maskv, eobs_v)`, same
    columns.

    Rows whitened as in eq. (1) (weights, and the residual's integrated autocorrelation time, so
    the sums count effective samples). Let `SSE(E)` be the weighted squared residual of the
    unconstrained fit with the extra columns E (none, or a candidate `[cos q_j, sin q_j]`),
    and `C(E)` the growth of it that the physical constraints cost: PC-WLS
    (`dynid.analysis.estimators.physical.pc_wls`) of the base parameters with E profiled
    out (their marginal estimate and covariance). Then

        Delta_j = (SSE(0) + C(0)) - (SSE(E_j) + C(E_j))                         (2)

    is the drop of the physically consistent fit's weighted residual when the candidate is
    added: a likelihood-ratio statistic, `chi2(2)` under "a physical model without it
    holds" (conservatively: the constraint part is a chi-bar-squared bound). Gate: PC-WLS of
    the model without a candidate has p < alpha (the chi-bar-squared bound of physical.py): the
    data really want a model no rigid body has. Rule: Bonferroni p of Delta_j < alpha, the
    constraint cost falls by at least half (`C(E_j) <= C(0) / 2`: the candidate explains
    the contradiction), amplitude >= `min_amplitude_sigma` of its (conditional) standard
    deviation, and the PC fit with the candidate predicts the held-out data within
    `HELDOUT_TOL` of the final model.

    The amplitude is that of the PC fit with the candidate: the least spring that makes the base
    parameters those of a rigid body, so a lower bound of the true one when the constraint stays
    active (tests/analysis/diagnosis/test_diagnosis_units.py, planar 2R arm in Pinocchio, masses known to 10 %: a
    10 N m spring is found at 7.9 N m). Measured on the independent TX40 plant, whose robot
    file bounds no mass: a 20 N m spring on joint 2 leaves the fit physical (PC-WLS chi2 13.0
    on 14 active constraints, p = 0.53), so this route does not see it and the a-priori route
    of `hidden_effects` does.
    """
    bp = eobs.bp
    nb = int(n_base)
    chi = np.asarray(chi, float)
    n = Y.shape[1]
    A, y, scale = _effective_rows(X, Y, mask, chi, weights)

    def constrained(Aa):
        coef, *_ = np.linalg.lstsq(Aa, y, rcond=None)
        r = y - Aa @ coef
        # information of the base parameters with the other columns profiled out (Schur
        # complement); a candidate aliased with base parameters leaves a null direction there,
        # which must cost nothing in the PC objective: a tiny ridge makes its variance huge
        # (a pseudo-inverse would make it zero, i.e. fixed at the min-norm split)
        Ab, Ae = Aa[:, :nb], Aa[:, nb:]
        info = Ab.T @ Ab
        if Ae.shape[1]:
            G = Ab.T @ Ae
            info = info - G @ np.linalg.pinv(Ae.T @ Ae) @ G.T
        info = 0.5 * (info + info.T)
        eps = 1e-10 * max(float(np.max(np.diag(info))), 1e-300)
        cov = np.linalg.inv(info + eps * np.eye(nb))
        # the fit alone: whether the unconstrained estimate is physical (a second SDP) is not used
        pc = pc_wls(robot, bp, coef[:nb], 0.5 * (cov + cov.T), n_boot=0, check_wls=False)
        beta = np.asarray(pc.chi, float)
        # the other columns (effects, candidate) given the physical base parameters
        rest, *_ = np.linalg.lstsq(Aa[:, nb:], y - Aa[:, :nb] @ beta, rcond=None) if Aa.shape[1] > nb \
            else (np.zeros(0),)
        return float(r @ r), float(pc.chi2), pc, np.concatenate([beta, rest])

    sse0, c0, pc0, coef0 = constrained(A)
    if not pc0.p_value < alpha:
        return []
    out = []
    for j in range(n):
        E, _ = _rows(_spring_columns(eobs, j), Y, mask, scale)
        Aa = np.hstack([A, E])
        sse, c1, pc1, coef = constrained(Aa)
        delta = (sse0 + c0) - (sse + c1)
        p_raw = float(stats.chi2.sf(max(delta, 0.0), 2))
        c = coef[-2:]
        amp = float(math.hypot(*c))
        g = c / max(amp, 1e-300)
        cov_e = np.linalg.pinv(E.T @ E)
        sd = float(math.sqrt(max(g @ cov_e @ g, 0.0)))
        h = HiddenEffect(joint=j + 1, name="gravity_spring", amplitude=amp,
                         phase=float(math.atan2(c[0], c[1])), sigma=sd, statistic=float(delta),
                         p_value=float(min(1.0, n * p_raw)), deviation_before=c0, deviation_after=c1,
                         contradicted=[(a_, 0.0, 0.0, 0.0) for a_ in pc0.active[:3]], route="physical",
                         alpha=alpha, min_amplitude_sigma=min_amplitude_sigma)
        ok = h.missed_rule() is None
        if ok and validation is not None:
            Xv, Yv, mv, ev = validation
            Dv = _spring_columns(ev, j)
            e_before = _rel(Yv, Xv @ chi, mv)
            e_after = _rel(Yv, np.concatenate([Xv, Dv], axis=2) @ coef, mv)
            h.errors = {"validation": {"before": e_before, "physical_without_effect": _rel(Yv, Xv @ coef0, mv),
                                       "after": e_after}}
            ok = e_after <= (1.0 + HELDOUT_TOL) * e_before
        h.reported = bool(ok)
        out.append(h)
    out.sort(key=lambda h: (not h.reported, h.p_value))
    return out
