"""Choosing one standard-parameter set for identified base parameters.

Base parameters are combinations of standard ones (`ZZ1R = ZZ1 + Ia1 + YY2
+ ...`): the data fix the combinations, not the standard values. A URDF (or
any simulator) needs standard values, so one set has to be *chosen*. The
choice made here:

    minimise   || R (P chi - beta_hat) ||^2  +  lam * sum_i ((chi_i - chi_ap_i) / s_i)^2
    over physically consistent chi: for every link the pseudo-inertia J_l is positive
    definite, and every actuator inertia Ia_j >= 0

* `beta_hat`: the identified base parameters (an essential model: its
  values, 0 for the parameters it removed); `P`: the regrouping matrix
  (beta = P chi); `R^T R = cov^-1` with `cov` the WLS covariance of all
  base parameters. The first term is then a chi^2: how much the weighted
  squared torque residual of the identification data grows, in units of the
  noise variance. It accounts for correlations: two parameters the data only
  see together may move together at no cost.
* `chi_ap`: the a-priori standard set of the robot file (URDF inertials,
  `<dynamics>` friction; 0 where there is none), `s_i` a scale per
  parameter (its a-priori magnitude, floored per kind). `lam` is tiny
  (1e-8): the second term only picks a point along the directions the data
  cannot see (how `ZZ1R` splits into `ZZ1`, `Ia1`, `YY2`, every mass
  no base parameter fixes, ...).
* A positive-definite `J_l` (Wensing, Kim, Slotine 2017) means mass > 0,
  inertia about the centre of mass positive definite, and the triangle
  inequality: a non-negative mass density can have these ten numbers.

When a consistent set reproduces the identified values (chi^2 ~ 0), that set
is found, and among such sets the one closest to the a-priori values. When
none does -- the identified values are not those of any rigid body, e.g. a
negative `ZZ1R` -- the result is the consistent set closest to them in the
metric above; `reproduces` is False, `chi2` says what it costs and the
notices list the base parameters that moved most, in standard deviations.

Actuator inertias have no URDF field: their scale is tiny, so a rotor inertia
is used only where no link inertia can carry it (`Ia1` goes into `ZZ1`;
`Ia3` of the TX40 or of the KUKA is a base parameter of its own and stays,
written to the URDF's `<dynid:parameters>`).

How (default): the problem is convex -- a quadratic objective, J_l in the
positive-semidefinite cone, linear bounds -- and is solved as an SDP by cvxpy
and Clarabel (`dynid.analysis.estimators.physical`), a global optimum;
the KUKA figures below are those of the local search it replaced. Without the
optional cvxpy (the `physical` extra) or with
`solver="log-cholesky"`: consistency is built into the parametrisation (log-Cholesky, Rucker &
Wensing 2022: `J_l = U U^T` with U upper triangular and an exponentiated
diagonal; `Ia_j = g_j^2`), so the problem is an unconstrained nonlinear
least squares, solved by `scipy.optimize.least_squares` (analytic
Jacobian) from the a-priori set (eigenvalues floored where it is not
consistent). Where the answer lies on the boundary of consistency (a link
that must be as thin as a rod) this parametrisation approaches it slowly:
`max_nfev` bounds the work, and the message says when it stopped there.
Measured on the KUKA recordings 2 + 3: chi^2 1806, 1562, 1431 after 100,
300, 2000 evaluations, relative torque error of the set 2.14 %, 2.08 %,
2.05 % (identified model: 1.66 %) -- the remaining gain is small. An ADMM
on the convex problem (PSD projections) was tried and converged slower.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.optimize

from dynid.analysis.estimators.sdp import build_sdp
from dynid.dynamics.urdf_writer import consistency, inertial_slice, pseudo_inertia
from dynid.errors import InputError
from dynid.provenance import json_safe

# floors of the scales s_i per kind of parameter (SI units): a parameter whose
# a-priori value is 0 may still move by about this much at unit cost
_FLOOR = {"inertia": 1e-3, "first_moment": 1e-2, "mass": 0.1, "Ia": 1e-5, "friction": 1e-2}
_INERTIA = {"XX", "XY", "XZ", "YY", "YZ", "ZZ"}
#: a chi^2 below this (deviations of ~0.01 sigma) counts as reproducing the identified values;
#: the a-priori pull (lam) alone leaves ~1e-6
REPRODUCE_CHI2 = 1e-4
#: how the notices that the set may not be the closest one begin or end (`StandardSet.search_caveats`)
LOCAL_SEARCH_NOTE = "the local log-Cholesky search was used instead of the SDP"
STOPPED_EARLY_NOTE = "the optimisation stopped after"


def _kind(name):
    sym = name.rstrip("0123456789")
    if sym in _INERTIA:
        return "inertia"
    if sym in ("MX", "MY", "MZ"):
        return "first_moment"
    if sym == "M":
        return "mass"
    if sym == "Ia":
        return "Ia"
    return "friction"


@dataclass
class StandardSet:
    """A standard-parameter set chosen for identified base parameters."""

    robot_name: str
    names: list
    chi: np.ndarray                  # chosen standard values
    apriori: np.ndarray              # a-priori standard values it was pulled towards
    beta: np.ndarray                 # base parameters of the chosen set (P chi)
    target: pd.DataFrame             # identified value, sigma, chosen value, deviation in sigma
    base_names: list
    consistent: bool
    reproduces: bool                 # chi2 <= REPRODUCE_CHI2
    links: list                      # per-link checks (dynid.dynamics.urdf_writer.consistency)
    chi2: float                      # ||R (beta - target)||^2, R^T R = cov^-1
    message: str
    notices: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)   # e.g. the prediction check

    def search_caveats(self) -> list:
        """The notices that say the set may not be the closest consistent one: a local search
        replaced the SDP, or the search stopped at its evaluation limit."""
        return [n for n in self.notices if n.endswith(LOCAL_SEARCH_NOTE) or n.startswith(STOPPED_EARLY_NOTE)]

    @property
    def max_deviation_sigma(self) -> float:
        d = np.abs(self.target["deviation_sigma"].to_numpy(dtype=float))
        return float(d.max()) if d.size else 0.0

    def frame(self):
        """One row per standard parameter: a-priori and chosen value."""
        return pd.DataFrame({"apriori": self.apriori, "chosen": self.chi},
                            index=pd.Index(self.names, name="parameter"))

    def base_frame(self):
        """One row per base parameter: chosen value, identified value and sigma where targeted."""
        t = self.target
        return pd.DataFrame({"chosen": self.beta,
                             "identified": [t["identified"].get(n, np.nan) for n in self.base_names],
                             "std": [t["std"].get(n, np.nan) for n in self.base_names],
                             "deviation_sigma": [t["deviation_sigma"].get(n, np.nan)
                                                 for n in self.base_names]},
                            index=pd.Index(self.base_names, name="base parameter"))

    def to_dict(self):
        return json_safe({
            "robot": self.robot_name,
            "choice": ("physically consistent standard set (pseudo-inertia of every link positive "
                       "definite, Ia >= 0) closest to the identified base parameters in the metric of "
                       "their WLS covariance (chi^2 = growth of the weighted squared torque residual); "
                       "among equally close ones, the closest to the a-priori values"),
            "message": self.message,
            "consistent": self.consistent,
            "reproduces_identified": self.reproduces,
            "chi2": self.chi2,
            "max_deviation_sigma": self.max_deviation_sigma,
            "targets": self.target.reset_index().to_dict(orient="records"),
            "standard_parameters": [{"name": n, "value": v, "apriori": a}
                                    for n, v, a in zip(self.names, self.chi, self.apriori)],
            "base_parameters": [{"name": n, "value": v} for n, v in zip(self.base_names, self.beta)],
            "links": self.links,
            "notices": self.notices,
            **self.extra,
        })


def apriori_standard(robot) -> np.ndarray:
    """The robot file's a-priori standard values (0 where it gives none; base names ignored)."""
    prior = getattr(robot, "apriori", {}) or {}
    return np.array([float(prior.get(n, 0.0)) for n in robot.standard_names])


def scales(robot, apriori) -> np.ndarray:
    """s_i: a-priori magnitude floored per kind; actuator inertias get the tiny floor only."""
    return np.array([_FLOOR["Ia"] if _kind(n) == "Ia" else max(abs(a), _FLOOR[_kind(n)])
                     for n, a in zip(robot.standard_names, apriori)])


# ------------------------------------------------------------------ log-Cholesky
_REV = np.arange(3, -1, -1)
_TRIU = np.triu_indices(4)
_DIAG = [k for k, (i, j) in enumerate(zip(*_TRIU)) if i == j]


def _theta_from_J(J):
    """Log-Cholesky coordinates (10) of a positive-definite pseudo-inertia J = U U^T."""
    L = np.linalg.cholesky(J[np.ix_(_REV, _REV)])
    U = L[np.ix_(_REV, _REV)]                    # upper triangular, J = U U^T
    th = U[_TRIU].copy()
    th[_DIAG] = np.log(th[_DIAG])
    return th


def _values_and_jacobian(th):
    """Ten standard values XX..M of U U^T and their derivatives (10 x 10) w.r.t. th."""
    U = np.zeros((4, 4))
    u = th.copy()
    u[_DIAG] = np.exp(u[_DIAG])
    U[_TRIU] = u
    vals = _J_to_values(U @ U.T)
    jac = np.empty((10, 10))
    for k, (i, j) in enumerate(zip(*_TRIU)):
        dU = np.zeros((4, 4))
        dU[i, j] = u[k] if i == j else 1.0        # d exp(t)/dt = exp(t) on the diagonal
        dJ = dU @ U.T
        jac[:, k] = _J_to_values(dJ + dJ.T)
    return vals, jac


def _J_to_values(J):
    S = J[:3, :3]
    I_o = np.trace(S) * np.eye(3) - S
    return np.array([I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2],
                     J[0, 3], J[1, 3], J[2, 3], J[3, 3]])


def _make_consistent(values, s_link):
    """The nearest-ish consistent J to a link's a-priori values (eigenvalues floored)."""
    J = pseudo_inertia(values)
    w, V = np.linalg.eigh(J)
    floor = 1e-3 * max(float(np.max(s_link)), 1e-6)
    if w[0] > floor:
        return J
    return (V * np.maximum(w, floor)) @ V.T


def choose_standard_set(robot, bp, target, cov, *, target_names=None, apriori=None, lam=1e-8,
                        max_nfev=400, solver="sdp") -> StandardSet:
    """A physically consistent standard set for identified base parameters (see the module doc).

    `target` (b,): the identified base-parameter vector to reproduce, in the
    order of `bp.names` (an essential model: its values, 0 elsewhere).
    `cov` (b, b): the covariance the distance is measured with -- the WLS
    covariance of all base parameters, so that ||R (beta - target)||^2 (R^T R
    = cov^-1) is how much the weighted squared torque residual of the
    identification data grows, in units of its noise variance (a chi^2).
    `target_names`: the parameters listed in the result's table (default all).
    `solver`: `"sdp"` (default) solves the convex problem above exactly, a
    global optimum (`dynid.analysis.estimators.physical`, cvxpy + Clarabel,
    with J_l positive semidefinite plus a 1e-9 margin and Fv, Fc >= 0 as well);
    without cvxpy, or with `"log-cholesky"`, the local search of the module doc.
    """
    names = list(robot.standard_names)
    chi_ap = apriori_standard(robot) if apriori is None else np.asarray(apriori, dtype=float)
    s = scales(robot, chi_ap)
    P = bp.matrix
    b = np.asarray(target, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if b.shape != (bp.n_base,) or cov.shape != (bp.n_base, bp.n_base):
        raise ValueError(f"target must have {bp.n_base} values and cov shape ({bp.n_base}, {bp.n_base})")
    # R^T R = cov^-1, by an eigen-decomposition that tolerates a nearly singular cov
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.maximum(w, w.max() * 1e-14)
    R = (V / np.sqrt(w)).T
    RP = R @ P
    n = robot.n_joints
    link_sl = [inertial_slice(robot, j) for j in range(n)]
    ia = [names.index(f"Ia{j + 1}") for j in range(n)]
    # A rotor inertia that only appears regrouped with its link's ZZ (same column of P) is put
    # into ZZ: URDF has no rotor field, and a reader of the file must still see the inertia.
    zz = [names.index(f"ZZ{j + 1}") for j in range(n)]
    ia_free = np.array([0.0 if np.allclose(P[:, ia[j]], P[:, zz[j]]) else 1.0 for j in range(n)])
    inertial_idx = np.concatenate([np.arange(sl.start, sl.stop) for sl in link_sl])
    free = np.array(sorted(set(range(len(names))) - set(inertial_idx) - set(ia)), dtype=int)
    n_x = 11 * n + len(free)
    sq_lam = np.sqrt(lam)

    def chi_and_jac(x):
        chi = np.empty(len(names))
        D = np.zeros((len(names), n_x))
        for j, sl in enumerate(link_sl):
            chi[sl], D[sl, 10 * j:10 * j + 10] = _values_and_jacobian(x[10 * j:10 * j + 10])
        g = x[10 * n:11 * n] * ia_free
        chi[ia] = g * g
        D[ia, 10 * n + np.arange(n)] = 2 * g * ia_free
        chi[free] = x[11 * n:]
        D[free, 11 * n + np.arange(len(free))] = 1.0
        return chi, D

    def residual(x):
        chi, _ = chi_and_jac(x)
        return np.concatenate([R @ (P @ chi - b), sq_lam * (chi - chi_ap) / s])

    def jacobian(x):
        _, D = chi_and_jac(x)
        return np.vstack([RP @ D, (sq_lam / s)[:, None] * D])

    x0 = np.concatenate([np.concatenate([_theta_from_J(_make_consistent(chi_ap[sl], s[sl]))
                                         for sl in link_sl]),
                         (np.sqrt(np.maximum(chi_ap[ia], 0.0)) + 1e-3) * ia_free,
                         chi_ap[free]])
    notices = []
    sol = None
    if solver == "sdp":
        try:
            pb = build_sdp(robot, bp, R, chi_ap, s, lam, None)
        except InputError as e:
            notices.append(f"{e}; {LOCAL_SEARCH_NOTE}")
            solver = "log-cholesky"
        else:
            chi = pb.solve(R @ b)
            message = f"SDP (cvxpy + Clarabel): {pb.prob.status}, a global optimum"
    elif solver != "log-cholesky":
        raise ValueError(f"solver must be 'sdp' or 'log-cholesky', got {solver!r}")
    if solver == "log-cholesky":
        sol = scipy.optimize.least_squares(residual, x0, jac=jacobian, method="trf", xtol=1e-15,
                                           ftol=1e-15, gtol=1e-12, max_nfev=max_nfev)
        chi = chi_and_jac(sol.x)[0]
        message = f"least_squares: {sol.message} ({sol.nfev} evaluations)"
    beta = P @ chi
    chi2 = float(np.sum((R @ (beta - b)) ** 2))
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        dev = (beta - b) / sig
    listed = list(bp.names) if target_names is None else list(target_names)
    idx = [bp.names.index(nm) for nm in listed]
    table = pd.DataFrame({"identified": b[idx], "std": sig[idx], "chosen": beta[idx],
                          "deviation_sigma": dev[idx]}, index=pd.Index(listed, name="base parameter"))
    links = consistency(robot, chi)
    consistent = all(l["consistent"] for l in links) and bool(np.all(chi[ia] >= 0))
    reproduces = bool(chi2 <= REPRODUCE_CHI2)
    if np.any(ia_free == 0):
        notices.append("rotor inertias regrouped with their link's ZZ ("
                       + ", ".join(f"Ia{j + 1}" for j in range(n) if ia_free[j] == 0)
                       + ") are written into the link's izz: URDF has no rotor inertia")
    if not reproduces and sol is not None and sol.status == 0:
        notices.append(f"{STOPPED_EARLY_NOTE} {sol.nfev} evaluations (max_nfev) at chi^2 = "
                       f"{chi2:.4g}; a consistent set closer to the identified values may exist")
    elif not reproduces:
        worst = table.reindex(table["deviation_sigma"].abs().sort_values(ascending=False).index)
        lst = ", ".join(f"{k} {r.identified:.4g} -> {r.chosen:.4g} ({r.deviation_sigma:+.1f} sigma)"
                        for k, r in worst.head(6).iterrows())
        notices.append(f"no physically consistent standard set reproduces the identified values "
                       f"(the closest one costs chi^2 = {chi2:.4g}, i.e. that much more weighted "
                       f"squared torque residual in units of the noise variance); it moves " + lst)
    return StandardSet(robot_name=robot.name, names=names, chi=chi, apriori=chi_ap, beta=beta,
                       target=table, base_names=list(bp.names), consistent=consistent,
                       reproduces=reproduces, links=links, chi2=chi2,
                       message=message, notices=notices)
