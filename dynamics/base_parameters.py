"""Base parameters: the minimal set the dynamics can be computed from (eq. (4)).

Numerical method of Gautier (1991): stack the standard regressor IDM_st over
random samples and take its QR decomposition without pivoting. A column whose
`|R_ii|` is negligible next to the column's own norm is a linear
combination of the columns before it; its parameter is *regrouped* into
those earlier parameters. With the standard order (link 1 to n, and
`XX ... M Ia Fv Fc Off` within a link) this keeps the parameters the
literature keeps: `ZZ1R = ZZ1 + Ia1 + YY2 + ...`, `MX2R = MX2 + d3 M3 + ...`.

With `W_st = [W_1 W_2] P` (independent columns first) and `W_2 = W_1 K`:
`W_st chi_st = W_1 (chi_1 + K chi_2) = W_1 beta`. The relation is exact;
`K` is cleaned of rounding noise and checked on fresh samples.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .regressor import regressor

_SEED = 20100419           # fixed: the base set must not change from run to run
_TOL = 1e-8                # |R_ii| / ||column i|| below this: dependent


@dataclass
class BaseParameters:
    """Which standard parameters are base, how the others regroup into them."""

    robot_name: str
    standard_names: list
    independent: np.ndarray       # indices (into the standard vector) of base columns
    dependent: np.ndarray         # indices of regrouped or unidentifiable parameters
    K: np.ndarray                 # (b, n_dependent): beta = chi[independent] + K chi[dependent]
    names: list                   # base-parameter names, 'R' suffix where regrouped
    prismatic: tuple = ()         # 1-based numbers of the prismatic joints (their units: N, m)

    @property
    def n_base(self) -> int:
        return len(self.independent)

    @property
    def n_standard(self) -> int:
        return len(self.standard_names)

    @property
    def matrix(self) -> np.ndarray:
        """(b, Ns) matrix P with beta = P chi_st."""
        P = np.zeros((self.n_base, self.n_standard))
        P[np.arange(self.n_base), self.independent] = 1.0
        P[:, self.dependent] = self.K
        return P

    @property
    def unidentifiable(self) -> list:
        """Standard parameters with no effect on the dynamics at all."""
        return [self.standard_names[d] for k, d in enumerate(self.dependent)
                if not np.any(self.K[:, k])]

    def from_standard(self, chi_st) -> np.ndarray:
        """beta = P chi_st (exact)."""
        return self.matrix @ np.asarray(chi_st, dtype=float)

    def to_standard(self, beta, method="zero") -> np.ndarray:
        """One standard-parameter set with the same dynamics as `beta`.

        `method="zero"` sets every regrouped parameter to zero (chi_1 = beta),
        the classic choice; `"least_norm"` returns the minimum-norm chi_st with
        `P chi_st = beta`. Both give exactly the same torques; neither is the
        physical robot, which the data cannot single out.
        """
        beta = np.asarray(beta, dtype=float)
        if method == "zero":
            chi = np.zeros(self.n_standard)
            chi[self.independent] = beta
            return chi
        if method == "least_norm":
            return np.linalg.lstsq(self.matrix, beta, rcond=None)[0]
        raise ValueError(f"method must be 'zero' or 'least_norm', got {method!r}")

    def relation(self, k) -> str:
        """Readable regrouping relation of base parameter k, e.g. 'ZZ1R = ZZ1 + Ia1 + YY2'."""
        terms = [self.standard_names[self.independent[k]]]
        for c, d in zip(self.K[k], self.dependent):
            if c == 0.0:
                continue
            name = self.standard_names[d]
            mag = abs(c)
            term = name if np.isclose(mag, 1.0, rtol=0, atol=1e-12) else f"{mag:.6g}*{name}"
            terms.append(("- " if c < 0 else "+ ") + term)
        return f"{self.names[k]} = " + " ".join(terms)

    @property
    def relations(self) -> list:
        return [self.relation(k) for k in range(self.n_base)]

    def table(self):
        """List of dicts {name, relation} in base order."""
        return [{"name": n, "relation": r} for n, r in zip(self.names, self.relations)]


def random_samples(robot, n_samples, rng):
    """Generic configurations, velocities and accelerations for structural rank tests."""
    n = robot.n_joints
    q = rng.uniform(-np.pi, np.pi, (n_samples, n))
    qd = rng.normal(0.0, 2.0, (n_samples, n))
    qdd = rng.normal(0.0, 5.0, (n_samples, n))
    return q, qd, qdd


def base_parameters(robot, n_samples=None, seed=_SEED) -> BaseParameters:
    """Compute the base parameters of `robot` (Gautier 1991, numerical QR)."""
    ns = robot.n_standard
    n = robot.n_joints
    if n_samples is None:
        n_samples = max(60, 3 * ns // n + 20)
    rng = np.random.default_rng(seed)
    q, qd, qdd = random_samples(robot, n_samples, rng)
    W = regressor(robot, q, qd, qdd).reshape(-1, ns)
    norms = np.linalg.norm(W, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    Ws = W / scale
    R = scipy.linalg.qr(Ws, mode="r", check_finite=False)[0]
    diag = np.abs(np.diag(R))
    zero_col = norms <= 1e-12 * max(norms.max(), 1.0)
    independent = np.flatnonzero((diag > _TOL) & ~zero_col)
    dependent = np.flatnonzero(~((diag > _TOL) & ~zero_col))
    W1 = W[:, independent]
    K = np.linalg.lstsq(W1, W[:, dependent], rcond=None)[0] if len(dependent) else np.zeros((len(independent), 0))
    K = _clean(K)
    resid = W[:, dependent] - W1 @ K
    if len(dependent) and np.linalg.norm(resid) > 1e-8 * max(np.linalg.norm(W), 1.0):
        raise RuntimeError(f"base parameters of '{robot.name}': regrouping is not exact "
                           f"(residual {np.linalg.norm(resid):.3g}); please report this robot")
    names = []
    std = robot.standard_names
    for k, i in enumerate(independent):
        names.append(std[i] + ("R" if np.any(K[k]) else ""))
    return BaseParameters(robot_name=robot.name, standard_names=list(std),
                          independent=independent, dependent=dependent, K=K, names=names,
                          prismatic=tuple(i + 1 for i, jt in enumerate(robot.joints) if jt.prismatic))


def _clean(K):
    """Remove rounding noise: tiny entries to 0, near-integers and short decimals snapped."""
    K = np.where(np.abs(K) < 1e-10, 0.0, K)
    for digits in (12,):
        rounded = np.round(K, digits)
        K = np.where(np.abs(K - rounded) < 1e-11, rounded, K)
    return K


def base_regressor(robot, bp: BaseParameters, q, qd, qdd, **kwargs):
    """W_base = IDM(q, qd, qdd) of eq. (4): the independent columns of IDM_st."""
    return regressor(robot, q, qd, qdd, columns=bp.independent, **kwargs)
