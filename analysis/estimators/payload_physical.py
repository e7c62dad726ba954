"""The physically consistent payload: one SDP nearest the free estimate (issue 28).

minimise ||R (x - chi)||^2 (R^T R = cov^-1, the free estimate's covariance) subject to the
payload's pseudo-inertia positive semidefinite (Wensing, Kim & Slotine 2017), mass > 0 and,
optionally, the centre of mass inside a box (m lo <= h <= m hi, linear). Solved by Clarabel
through cvxpy, as the physical fits of dynid.analysis.estimators.physical; the minimum is a
chi^2 distance (large: the data want a payload no body can be).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynid.analysis.estimators.sdp import J_MARGIN, require_cvxpy
from dynid.analysis.estimators.sdp import whitening as _whitening
from dynid.analysis.results import ParameterResults, parameter_table
from dynid.dynamics.robot import INERTIAL
from dynid.dynamics.urdf_writer import pseudo_inertia_basis
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["PAYLOAD_NAMES", "PhysicalPayload", "physical_payload"]

PAYLOAD_NAMES = tuple(f"{s}L" for s in INERTIAL)


@dataclass(eq=False, repr=False)
class PhysicalPayload(ParameterResults):
    """The physically consistent payload: the SDP of `physical_payload`.

    `chi` the constrained estimate, `cov` the free estimate's (the constrained one's
    uncertainty is no larger where no constraint is active), `delta` the growth of the
    weighted squared residual in units of the free estimate's covariance (a chi^2 value:
    large means the data want a non-physical payload), `active` the constraints that bind.
    """

    method = "payload-physical"
    names: list
    chi: np.ndarray
    cov: np.ndarray
    delta: float
    active: list
    com_box: tuple | None
    status: str

    def summary(self):
        lines = [f"physically consistent payload (SDP, Clarabel: {self.status}); chi^2 distance to the "
                 f"free estimate {self.delta:.3g}; active: {', '.join(self.active) or 'none'}"]
        lines += parameter_table(self.names, [("value", self.chi, lambda x: f"{x:.6g}"),
                                              ("sigma", self.bse.to_numpy(), lambda x: f"{x:.3g}")])
        lines.append("sigma: the free estimate's (no larger where no constraint is active)")
        return "\n".join(lines)

    def to_dict(self):
        return json_safe({"method": self.method, "names": self.names, "values": self.chi,
                          "parameters": self._records(),
                          "delta_chi2": self.delta, "active": self.active,
                          "com_box": None if self.com_box is None else [list(b) for b in self.com_box],
                          "status": self.status})


def physical_payload(chi, cov, *, com_box=None):
    """The physically consistent payload nearest the free estimate: one SDP (Clarabel).

    minimise `||R (x - chi)||^2` (`R^T R = cov^-1`) subject to the payload's
    pseudo-inertia positive semidefinite (Wensing, Kim & Slotine 2017), mass > 0 and,
    with `com_box`, `lo <= c <= hi` written linearly as `m lo <= h <= m hi`.

    Parameters
    ----------
    chi : (10,) free estimate; cov : (10, 10) its covariance.
    com_box : ((3,), (3,)), optional
        Lower and upper corners of a box holding the centre of mass, payload frame, m.

    Returns
    -------
    PhysicalPayload

    Raises
    ------
    InputError
        cvxpy/Clarabel missing, a malformed box, or no solution.
    """
    cp = require_cvxpy()
    chi = np.asarray(chi, dtype=float)
    box = None
    if com_box is not None:
        try:
            lo, hi = (np.asarray(b, dtype=float).reshape(3) for b in com_box)
        except (TypeError, ValueError):
            raise InputError(f"com_box must be two corners [[x, y, z], [x, y, z]] in m, got {com_box!r}") from None
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise InputError(f"com_box: the lower corner {lo} must be below the upper {hi} (m)")
        box = (lo, hi)
    s = np.maximum(np.abs(chi), np.sqrt(np.maximum(np.diag(cov), 0.0)))
    s = np.where(s > 0, s, 1.0)
    Rw = _whitening(cov) * s[None, :]
    z = cp.Variable(10)
    E = pseudo_inertia_basis()
    J = sum(E[k] * s[k] * z[k] for k in range(10))
    cons = [J - J_MARGIN * np.eye(4) >> 0]
    if box is not None:
        cons += [cp.multiply(s[6:9], z[6:9]) >= s[9] * z[9] * lo,
                 cp.multiply(s[6:9], z[6:9]) <= s[9] * z[9] * hi]
    target = Rw @ (chi / s)
    prob = cp.Problem(cp.Minimize(cp.sum_squares(Rw @ z - target)), cons)
    try:
        prob.solve(solver="CLARABEL")
    except cp.error.SolverError as e:
        raise InputError(f"the physically consistent payload fit failed in the SDP solver: {e}") from None
    if prob.status not in ("optimal", "optimal_inaccurate"):
        raise InputError(f"the physically consistent payload fit has no solution (status {prob.status}); "
                         "check the centre-of-mass box")
    x = s * np.asarray(z.value, dtype=float)
    Rc = _whitening(cov)
    delta = float(np.sum((Rc @ (x - chi)) ** 2))
    active = []
    Jx = np.tensordot(x, E, axes=1)
    if np.linalg.eigvalsh(Jx)[0] < 1e-6 * max(1.0, abs(x[9])):
        active.append("pseudo-inertia (a payload on the edge of physical: a rod, a plate or a point mass)")
    if box is not None:
        c = x[6:9] / x[9]
        for k, ax in enumerate("xyz"):
            if abs(c[k] - box[0][k]) < 1e-6 or abs(c[k] - box[1][k]) < 1e-6:
                active.append(f"centre-of-mass box along {ax}")
    return PhysicalPayload(names=list(PAYLOAD_NAMES), chi=x, cov=np.asarray(cov, dtype=float), delta=delta,
                           active=active, com_box=None if box is None else (tuple(box[0]), tuple(box[1])),
                           status=prob.status)
