"""The optimisation problem of eq. (20) (Bona & Curatella 2005): grids, bases, constraints, gradients.

`ExcitationProblem` holds, for one robot, fundamental and number of harmonics, the Fourier
bases on the sampling and constraint grids, the linear limit constraints and the objective
(`log cond` or `-log det` of the scaled base regressor) with its analytic gradient;
`shrink_to_torque` makes a random start keep to the torque limits. The design loop that
uses them, and why they are built so: `dynid.dynamics.excitation`.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.optimize

from dynid.errors import InputError

from .base_parameters import base_regressor
from .dynamic_model import inverse_dynamics
from .excitation_measures import column_scales
from .trajectories import FourierTrajectory

__all__ = ["ExcitationProblem", "shrink_to_torque"]

_H_Q = 1e-6                          # rad (m) step of the position derivative
_H_QD = 1e-6                         # rad/s step of the velocity derivative


class ExcitationProblem:
    """Grids, Fourier bases, linear constraints and the objective of eq. (20)."""

    def __init__(self, robot, bp, f0, N, chi, criterion, scaling, margin, samples_per_harmonic,
                 n_constraint):
        self.robot, self.bp, self.f0, self.N = robot, bp, float(f0), int(N)
        self.n = robot.n_joints
        self.m = 2 * self.N + 1
        self.chi = chi
        self.criterion, self.scaling, self.margin = criterion, scaling, float(margin)
        self.scales = column_scales(robot, bp, "envelope")
        self.opt_scales = column_scales(robot, bp, scaling)
        T = 1.0 / self.f0
        self.G = int(samples_per_harmonic) * self.N
        self.t = np.arange(self.G) * (T / self.G)
        self.B = self._bases(self.t)
        self.Gc = int(n_constraint)
        self.tc = np.arange(self.Gc) * (T / self.Gc)
        self.Bc = self._bases(self.tc)
        q_min, q_max, qd_max, qdd_max, tau_max = robot.limits()
        self.tau_max = tau_max
        self.torque_limited = chi is not None and bool(np.any(np.isfinite(tau_max)))
        self._tkeep = np.isfinite(tau_max)
        # same tightening as the kinematic limits (no guarantee between grid points:
        # the torque is not a trigonometric polynomial of degree N)
        self._tlim = (1.0 - 0.5 * (np.pi * self.N / self.Gc) ** 2) * self.margin * tau_max[self._tkeep]
        # variable scaling: velocity amplitudes by qd_max (or the acceleration/position
        # limits it implies), offsets by the half range
        w = 2.0 * np.pi * self.f0
        half = 0.5 * (q_max - q_min)
        vs = np.fmin(np.fmin(qd_max, qdd_max / (w * self.N)), half * w)
        vs = np.where(np.isfinite(vs) & (vs > 0), vs, 1.0)
        ps = np.where(np.isfinite(half) & (half > 0), half, 1.0)
        self.xs = np.concatenate([np.r_[np.full(2 * self.N, vs[j]), ps[j]] for j in range(self.n)])
        self._linear_constraints(q_min, q_max, qd_max, qdd_max)
        self._values, self._grad_key, self._grad = {}, None, None
        self._tvalues, self._tjac_key, self._tjac = {}, None, None

    # Fourier bases: x_j = [a(N), b(N), q0] -> q_j, qd_j, qdd_j on the grid
    def _bases(self, t):
        w = 2.0 * np.pi * self.f0
        wk = w * np.arange(1, self.N + 1)
        ph = np.multiply.outer(t, wk)
        S, C = np.sin(ph), np.cos(ph)
        one, zero = np.ones((t.size, 1)), np.zeros((t.size, 1))
        return (np.hstack([S / wk, -C / wk, one]), np.hstack([C, S, zero]),
                np.hstack([-S * wk, C * wk, zero]))

    def kinematics(self, x, B=None):
        X = x.reshape(self.n, self.m)
        Bq, Bqd, Bqdd = self.B if B is None else B
        return Bq @ X.T, Bqd @ X.T, Bqdd @ X.T

    def _linear_constraints(self, q_min, q_max, qd_max, qdd_max):
        """A z <= u on the constraint grid (z = x / xs), Bernstein-tightened."""
        guard = 1.0 - 0.5 * (np.pi * self.N / self.Gc) ** 2
        mg = self.margin
        mid = 0.5 * (q_min + q_max)
        half = 0.5 * (q_max - q_min)
        rows, ub = [], []
        Bq, Bqd, Bqdd = self.Bc
        for j in range(self.n):
            sl = slice(j * self.m, (j + 1) * self.m)
            if np.isfinite(half[j]):
                # |q - mid| <= guard mg half on the grid (checked densely afterwards)
                lim = mg * half[j]
                blk = np.zeros((self.Gc, self.n * self.m))
                blk[:, sl] = Bq
                rows += [blk, -blk]
                ub += [np.full(self.Gc, mid[j] + guard * lim), np.full(self.Gc, -(mid[j] - guard * lim))]
            for Bk, lim in ((Bqd, qd_max[j]), (Bqdd, qdd_max[j])):
                if np.isfinite(lim):
                    blk = np.zeros((self.Gc, self.n * self.m))
                    blk[:, sl] = Bk
                    rows += [blk, -blk]
                    ub += [np.full(self.Gc, guard * mg * lim)] * 2
        if rows:
            A = np.vstack(rows) * self.xs           # in normalised variables
            u = np.concatenate(ub)
            # normalise each row so that the tolerances of SLSQP are comparable
            nr = np.abs(u)
            nr = np.where(nr > 0, nr, 1.0)
            self.A, self.u = A / nr[:, None], u / nr
        else:
            self.A, self.u = np.zeros((0, self.n * self.m)), np.zeros(0)

    # --- regressor with partial derivatives
    def _stack(self, q, qd, qdd):
        """All perturbed states: base, q_j +- h, qd_j + d h, qd_j + 2 d h, qdd_j + 1."""
        n = self.n
        Q, QD, QDD = [q], [qd], [qdd]
        d = np.where(qd >= 0, 1.0, -1.0)
        for j in range(n):
            e = np.zeros(n)
            e[j] = 1.0
            Q += [q + _H_Q * e, q - _H_Q * e]
            QD += [qd, qd]
            QDD += [qdd, qdd]
        for j in range(n):
            dq = np.zeros_like(qd)
            dq[:, j] = d[:, j] * _H_QD
            Q += [q, q]
            QD += [qd + dq, qd + 2 * dq]
            QDD += [qdd, qdd]
        for j in range(n):
            e = np.zeros(n)
            e[j] = 1.0
            Q.append(q)
            QD.append(qd)
            QDD.append(qdd + e)
        return np.vstack(Q), np.vstack(QD), np.vstack(QDD), d

    def _partials(self, F, G, d):
        """Split stacked values F ((1 + 5n) G, n, ...) into F0 and dF/dq_j, dF/dqd_j, dF/dqdd_j."""
        n = self.n
        F = F.reshape((1 + 5 * n, G) + F.shape[1:])
        F0 = F[0]
        extra = (None,) * (F.ndim - 2)
        dq = [(F[1 + 2 * j] - F[2 + 2 * j]) / (2.0 * _H_Q) for j in range(n)]
        o = 1 + 2 * n
        dqd = [(F[o + 2 * j + 1] - F[o + 2 * j]) / (d[(slice(None), j) + extra] * _H_QD)
               for j in range(n)]
        o2 = 1 + 4 * n
        dqdd = [F[o2 + j] - F0 for j in range(n)]
        return F0, dq, dqd, dqdd

    def _chain(self, gq, gqd, gqdd, B):
        """Gradient w.r.t. x from per-sample sensitivities g (G, n, ...) to q_j, qd_j, qdd_j."""
        Bq, Bqd, Bqdd = B
        return (np.einsum("sm,js...->...jm", Bq, gq) + np.einsum("sm,js...->...jm", Bqd, gqd)
                + np.einsum("sm,js...->...jm", Bqdd, gqdd))

    # --- objective
    def objective_terms(self, W):
        """(f, H) with f the criterion of the stacked regressor W (G, n, b) and H = df/dW."""
        b = self.bp.n_base
        W2 = W.reshape(-1, b)
        if self.scaling == "columns":
            norms = np.linalg.norm(W2, axis=0)
            norms = np.where(norms > 0, norms, 1.0)
            Ws = W2 / norms
        else:
            Ws = W2 / self.opt_scales
        # eigen-decomposition of the Gram matrix: b x b, much cheaper than the SVD of Ws
        lam, V = np.linalg.eigh(Ws.T @ Ws)
        if lam[0] <= 0 or not np.isfinite(lam).all():
            return math.inf, np.zeros_like(W)
        WV = Ws @ V
        if self.criterion == "cond":
            f = 0.5 * math.log(lam[-1] / lam[0])
            Gm = np.outer(WV[:, -1], V[:, -1]) / lam[-1] - np.outer(WV[:, 0], V[:, 0]) / lam[0]
        else:  # logdet: minimise -log det(Ws^T Ws / G) / b
            f = -float(np.sum(np.log(lam / self.G))) / b
            Gm = -(2.0 / b) * (WV / lam) @ V.T
        if self.scaling == "columns":
            H = (Gm - Ws * np.sum(Ws * Gm, axis=0)) / norms
        else:
            H = Gm / self.opt_scales
        return f, H.reshape(W.shape)

    def _value(self, z):
        """Criterion only (one regressor evaluation): what the line search needs."""
        key = z.tobytes()
        if key in self._values:
            return self._values[key]
        q, qd, qdd = self.kinematics(z * self.xs)
        W = base_regressor(self.robot, self.bp, q, qd, qdd)
        f = self.objective_terms(W)[0]
        if len(self._values) > 64:
            self._values.clear()
        self._values[key] = f
        return f

    def _gradient(self, z):
        key = z.tobytes()
        if key == self._grad_key:
            return self._grad
        x = z * self.xs
        q, qd, qdd = self.kinematics(x)
        Q, QD, QDD, d = self._stack(q, qd, qdd)
        Wst = base_regressor(self.robot, self.bp, Q, QD, QDD)
        W0, dq, dqd, dqdd = self._partials(Wst, self.G, d)
        f, H = self.objective_terms(W0)
        D = np.stack([np.stack(dq), np.stack(dqd), np.stack(dqdd)])     # (3, n, G, n, b)
        g = np.einsum("tjsic,sic->tjs", D, H)                            # (3, n, G)
        grad = self._chain(g[0], g[1], g[2], self.B).ravel() * self.xs
        self._values[key] = f
        self._grad_key, self._grad = key, grad
        return grad

    def fun(self, z):
        return self._value(z)

    def jac(self, z):
        return self._gradient(z)

    # --- torque constraint
    def torque(self, x, B=None):
        q, qd, qdd = self.kinematics(x, self.Bc if B is None else B)
        return inverse_dynamics(self.robot, self.chi, q, qd, qdd)

    def _torque_value(self, z):
        """Normalised torque constraints (>= 0 when within margin tau_max) on the grid."""
        key = z.tobytes()
        if key in self._tvalues:
            return self._tvalues[key]
        tau = self.torque(z * self.xs)
        r = tau[:, self._tkeep] / self._tlim
        c = np.concatenate([(1.0 - r).ravel(), (1.0 + r).ravel()])
        if len(self._tvalues) > 64:
            self._tvalues.clear()
        self._tvalues[key] = c
        return c

    def _torque_jac(self, z):
        key = z.tobytes()
        if key == self._tjac_key:
            return self._tjac
        x = z * self.xs
        q, qd, qdd = self.kinematics(x, self.Bc)
        Q, QD, QDD, d = self._stack(q, qd, qdd)
        tst = inverse_dynamics(self.robot, self.chi, Q, QD, QDD)
        tau, dq, dqd, dqdd = self._partials(tst, self.Gc, d)
        # J[s, i, j, m] = dtau_i(s) / dx_jm
        Bq, Bqd, Bqdd = self.Bc
        J = (np.einsum("sm,jsi->sijm", Bq, np.stack(dq)) + np.einsum("sm,jsi->sijm", Bqd, np.stack(dqd))
             + np.einsum("sm,jsi->sijm", Bqdd, np.stack(dqdd)))
        J = J.reshape(self.Gc, self.n, -1)[:, self._tkeep] * self.xs
        Jr = (J / self._tlim[None, :, None]).reshape(-1, J.shape[-1])
        self._tjac_key, self._tjac = key, np.concatenate([-Jr, Jr])
        return self._tjac

    def constraints(self):
        cons = []
        if self.A.shape[0]:
            A, u = self.A, self.u
            cons.append({"type": "ineq", "fun": lambda z: u - A @ z, "jac": lambda z: -A})
        if self.torque_limited:
            cons.append({"type": "ineq", "fun": self._torque_value, "jac": self._torque_jac})
        return cons

    def max_violation(self, z):
        """Largest normalised constraint violation at z (0 when feasible on the grid)."""
        v = 0.0
        if self.A.shape[0]:
            v = max(v, float(np.max(self.A @ z - self.u)))
        if self.torque_limited:
            v = max(v, float(-np.min(self._torque_value(z))))
        return v

    def optimise(self, z0, max_iter, ftol, tol=1e-7):
        """SLSQP from z0; returns (z, result): the best grid-feasible iterate seen.

        SLSQP may end on an infeasible point (e.g. "Inequality constraints
        incompatible"); the callback keeps the best feasible iterate instead.
        """
        best = {"f": math.inf, "z": z0}

        def consider(z):
            if self.max_violation(z) <= tol:
                f = self.fun(z)
                if f < best["f"]:
                    best["f"], best["z"] = f, np.array(z, copy=True)

        consider(z0)
        res = scipy.optimize.minimize(self.fun, z0, jac=self.jac, method="SLSQP",
                                      constraints=self.constraints(), callback=consider,
                                      options={"maxiter": int(max_iter), "ftol": ftol})
        consider(res.x)
        return best["z"], best["f"], res

    def to_x(self, traj):
        return np.hstack([traj.a, traj.b, traj.q0[:, None]]).ravel()

    def to_traj(self, x):
        X = x.reshape(self.n, self.m)
        N = self.N
        return FourierTrajectory(self.f0, X[:, :N], X[:, N:2 * N], X[:, 2 * N])


def shrink_to_torque(prob, traj, n_grid=2000):
    """Scale a start's oscillation about q0 until |tau| <= margin tau_max (bisection)."""
    if not prob.torque_limited:
        return traj, 1.0
    t = np.arange(n_grid) * (traj.period / n_grid)
    lim = prob.margin * prob.tau_max

    def ok(scale):
        tr = FourierTrajectory(traj.f0, traj.a * scale, traj.b * scale, traj.q0)
        q, qd, qdd = tr.evaluate(t)
        tau = inverse_dynamics(prob.robot, prob.chi, q, qd, qdd)
        return bool(np.all(np.abs(tau) <= lim))

    if ok(1.0):
        return traj, 1.0
    if not ok(0.0):
        raise InputError(f"the gravity torque at the centre of the joint ranges of '{prob.robot.name}' "
                         f"exceeds margin * tau_max: no random start is feasible; raise tau_max or "
                         f"lower margin")
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return FourierTrajectory(traj.f0, traj.a * lo, traj.b * lo, traj.q0), lo
