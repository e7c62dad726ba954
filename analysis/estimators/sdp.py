"""The SDP of the physically consistent fit: its constraints, objective and active set.

The problem of `dynid.analysis.estimators.physical` (its docstring gives the
method): minimise ||R (P chi - beta_target)||^2 plus a weighted pull toward the a-priori
values, over the standard parameters chi, subject to every link's pseudo-inertia
positive semidefinite (Wensing, Kim & Slotine 2017), Ia, Fv, Fc >= 0 and optional
mass bounds. Built once with cvxpy and re-solved for another target by changing one
parameter (the bootstrap). Both PC-WLS (physical) and the SDP choice of a standard set
(standard_set) use it, so it sits below both.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from dynid.dynamics.urdf_writer import inertial_slice, pseudo_inertia_basis
from dynid.errors import InputError, install_hint

__all__ = ["SDPProblem", "build_sdp", "whitening", "active_constraints", "apriori_pseudo_inertias",
           "require_cvxpy", "J_MARGIN", "ACTIVE_RTOL", "GEOMETRIC_RTOL", "NONNEG_KINDS"]

#: the pseudo-inertia must exceed this multiple of the identity (kg, kg m, kg m^2): a link
#: exactly on the boundary (a rod) is reported active, not flagged inconsistent by rounding
J_MARGIN = 1e-9
#: a constraint counts as active when its slack is below this fraction of its scale
ACTIVE_RTOL = 1e-5
#: prior="geometric" refuses an a-priori pseudo-inertia whose smallest eigenvalue is below this
#: fraction of its largest (singular to rounding: the divergence would be infinite there)
GEOMETRIC_RTOL = 1e-12
#: the standard parameters kept >= 0 (by kind: Ia1, Fv2, Fcm1 ...)
NONNEG_KINDS = ("Ia", "Fv", "Fc")


def require_cvxpy():
    """Import cvxpy (with Clarabel) or say how to install it."""
    try:
        import cvxpy as cp  # optional (the physical extra)
    except ImportError:
        raise InputError('the physically consistent fit (--physical) and the global search of --urdf / '
                         '--mjcf need the optional packages cvxpy and clarabel (without them --urdf uses '
                         f'a local search): {install_hint("physical")}') from None
    if "CLARABEL" not in cp.installed_solvers():
        raise InputError(f'cvxpy is installed without the Clarabel solver: {install_hint("physical")}')
    return cp


def whitening(cov):
    """R with R^T R = cov^-1, tolerant of a nearly singular cov (as standard_set does)."""
    cov = np.asarray(cov, dtype=float)
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.maximum(w, w.max() * 1e-14)
    return (V / np.sqrt(w)).T


@dataclass
class SDPProblem:
    """The compiled SDP, re-solved with another target by changing one parameter (bootstrap)."""

    cp: object
    prob: object
    z: object            # variable: chi / s
    target: object       # parameter: R beta_target
    s: np.ndarray
    names: list
    nonneg: list         # indices of Ia, Fv, Fc parameters
    mass_idx: list
    links: list          # slices of the inertial parameters
    mass_bounds: dict    # index -> (lo, hi)

    def solve(self, t):
        self.target.value = np.asarray(t, dtype=float)
        try:
            with warnings.catch_warnings():
                # "optimal_inaccurate" is reported in the status (and the result's notices)
                warnings.simplefilter("ignore", UserWarning)
                self.prob.solve(solver="CLARABEL")
        except self.cp.error.SolverError as e:
            raise InputError(f"the physically consistent fit failed in the SDP solver: {e}") from None
        if self.prob.status not in ("optimal", "optimal_inaccurate"):
            raise InputError(f"the physically consistent fit has no solution (solver status "
                             f"{self.prob.status}); check the mass bounds of the robot file")
        return self.s * np.asarray(self.z.value, dtype=float)


def apriori_pseudo_inertias(robot, chi_ap):
    """Each link's a-priori pseudo-inertia J0_l (4x4), checked positive definite, as the
    geometric prior needs (its divergence is infinite at a singular J0). One InputError
    names every link that fails."""
    E = pseudo_inertia_basis()
    out, bad = [], []
    for j in range(robot.n_joints):
        J0 = np.tensordot(np.asarray(chi_ap, dtype=float)[inertial_slice(robot, j)], E, axes=1)
        w = np.linalg.eigvalsh(J0)
        # relative test: a rod (a zero principal moment) is as singular at any scale
        if not (np.all(np.isfinite(w)) and w[0] > GEOMETRIC_RTOL * max(abs(w[-1]), np.finfo(float).tiny)):
            bad.append(f"link {j + 1} (XX{j + 1}..M{j + 1}: smallest eigenvalue {w[0]:.3g}"
                       + (", no a-priori inertial values" if not np.any(J0) else "") + ")")
        out.append(J0)
    if bad:
        raise InputError(f"prior='geometric' needs a positive-definite a-priori pseudo-inertia for every "
                         f"link, but robot '{robot.name}' has a singular or non-physical one for "
                         f"{'; '.join(bad)}: give those links a physical a-priori mass, first moment and "
                         "inertia in the robot file's [apriori] values, or use prior='apriori' (Euclidean; "
                         "--prior apriori)")
    return out


def build_sdp(robot, bp, R, chi_ap, s, weight, mass_tolerance, nonneg_kinds=NONNEG_KINDS, zero_kinds=(),
              prior=None):
    """The SDP; `zero_kinds` (e.g. `("Ia",)`) fixes those standard parameters at 0 (a
    model without them, such as no rotor inertia behind a link-side torque sensor).
    `prior="geometric"`: the inertial parameters' a-priori term is the entropic divergence
    of the module doc, the others' stays Euclidean (same `weight`)."""
    cp = require_cvxpy()
    J0 = apriori_pseudo_inertias(robot, chi_ap) if prior == "geometric" else None
    names = list(robot.standard_names)
    n_std = len(names)
    P = bp.matrix
    z = cp.Variable(n_std)
    target = cp.Parameter(R.shape[0])
    A = R @ P * s[None, :]
    E = pseudo_inertia_basis()
    links = [inertial_slice(robot, j) for j in range(robot.n_joints)]
    cons = []
    for sl in links:
        ss = s[sl]
        J = sum(E[k] * ss[k] * z[sl.start + k] for k in range(10))
        cons.append(J - J_MARGIN * np.eye(4) >> 0)
    nonneg = [i for i, nm in enumerate(names) if nm.rstrip("0123456789").rstrip("m") in nonneg_kinds]
    if nonneg:
        cons.append(z[nonneg] >= 0)
    zero = [i for i, nm in enumerate(names) if nm.rstrip("0123456789").rstrip("m") in zero_kinds]
    if zero:
        cons.append(z[zero] == 0)
    mass_idx = [names.index(f"M{j + 1}") for j in range(robot.n_joints)]
    bounds = {}
    if mass_tolerance is not None:
        tol = float(mass_tolerance)
        if not (math.isfinite(tol) and tol >= 0):
            raise InputError(f"mass_tolerance must be a fraction >= 0 (0.1 for +-10 %), got {mass_tolerance!r}")
        for i in mass_idx:
            if chi_ap[i] > 0:
                bounds[i] = ((1 - tol) * chi_ap[i], (1 + tol) * chi_ap[i])
                cons += [z[i] >= bounds[i][0] / s[i], z[i] <= bounds[i][1] / s[i]]
    if J0 is None:
        reg = cp.sum_squares(z - chi_ap / s)
    else:
        # d(J || J0) of M = L0^-1 J L0^-T (J0 = L0 L0^T): det M = det(J0^-1 J), tr M = tr(J0^-1 J),
        # and M is near the identity, better conditioned for the log-det cone than J itself
        inertial = np.zeros(n_std, dtype=bool)
        reg = 0
        for sl, J0_l in zip(links, J0):
            inertial[sl] = True
            Li = np.linalg.inv(np.linalg.cholesky(J0_l))
            B = [Li @ E[k] @ Li.T * s[sl][k] for k in range(10)]
            M = sum(0.5 * (B[k] + B[k].T) * z[sl.start + k] for k in range(10))
            reg = reg - cp.log_det(M) + cp.trace(M) - 4.0
        rest = np.flatnonzero(~inertial)
        if rest.size:
            reg = reg + cp.sum_squares(z[rest] - chi_ap[rest] / s[rest])
    obj = cp.sum_squares(A @ z - target) + weight * reg
    prob = cp.Problem(cp.Minimize(obj), cons)
    return SDPProblem(cp, prob, z, target, s, names, nonneg, mass_idx, links, bounds)


def active_constraints(pb, chi):
    """The active constraints at chi: (labels, number of scalar directions)."""
    E = pseudo_inertia_basis()
    labels, k = [], 0
    for j, sl in enumerate(pb.links):
        J = np.tensordot(chi[sl], E, axes=1)
        w = np.linalg.eigvalsh(J)
        null = int(np.sum(w <= ACTIVE_RTOL * max(w[-1], 1e-12) + 10 * J_MARGIN))
        if null:
            labels.append(f"pseudo-inertia of link {j + 1} singular (nullity {null})")
            k += null * (null + 1) // 2
    for i in pb.nonneg:
        if chi[i] <= ACTIVE_RTOL * pb.s[i]:
            labels.append(f"{pb.names[i]} = 0")
            k += 1
    for i, (lo, hi) in pb.mass_bounds.items():
        if chi[i] <= lo + ACTIVE_RTOL * pb.s[i] or chi[i] >= hi - ACTIVE_RTOL * pb.s[i]:
            labels.append(f"{pb.names[i]} at its bound {lo if chi[i] < 0.5 * (lo + hi) else hi:.4g} kg")
            k += 1
    return labels, k
