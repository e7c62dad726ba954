"""Optimal excitation: Fourier coefficients that minimise cond(W) (Bona & Curatella 2005).

Eq. (20) of Bona & Curatella 2005 (after Presse & Gautier 1993 and Swevers et
al. 1997): choose, for every joint ``i``, the ``2 N + 1`` parameters
``delta_i = [a_i(1..N), b_i(1..N), q_i0]`` of the finite Fourier series of
eqs. (17)-(19) (:class:`dynamics.trajectories.FourierTrajectory`) so that the
base regressor ``W`` stacked over one period is as well conditioned as the
limits allow::

    delta = argmin cond(W(q(t), qd(t), qdd(t)))
    s.t.  |q - q_mid| <= margin (q_max - q_min) / 2,  |qd| <= margin qd_max,
          |qdd| <= margin qdd_max,  |tau(q, qd, qdd; chi)| <= margin tau_max

The fundamental ``f0`` and the number of harmonics ``N`` are *given*: they fix
the period (``1 / f0``, a whole number of periods avoids leakage and allows
period averaging, section 2.3) and the bandwidth ``N f0`` (kept below the first
resonance, section 3.3: 0.1 Hz and 5 harmonics on the COMAU Smart-3 S2).

Which condition number
----------------------
``cond(W)`` in SI units (``cond_raw``) depends on the units of the parameters
(kg m^2 vs g mm^2 changes it by orders of magnitude) and is dominated by the
ratio of the largest to the smallest column norm. dynid therefore reports and,
by default, minimises the condition number of ``W S^-1`` where ``S`` is a
*fixed* diagonal of column scales (``scaling="envelope"``): the RMS of each
base-regressor column over random states drawn uniformly inside the robot's
limit box (``q`` in its range, ``|qd| <= qd_max``, ``|qdd| <= qdd_max``; a fixed
seed, so ``S`` depends on the robot only). That is the regressor in units where
every parameter contributes O(1) torque at full-range motion: the number is
independent of the parameters' units, and still rewards a trajectory that
excites a weak column more (unlike the column-normalised ``cond_unit``, where
every column of ``W`` is scaled to unit norm *for that trajectory*, a pure
collinearity measure, also reported). ``scaling="none"`` reproduces the paper's
``kappa(Phi)`` in SI units, ``"columns"`` optimises ``cond_unit``. A-priori
magnitudes were not used as scales: most base parameters (36 of the TX40's 60)
have no a-priori value. With ``criterion="logdet"`` (D-optimality, Swevers
1997) ``-log det(W_s^T W_s) / b`` is minimised instead; it does not depend on the
column scales (they add a constant) and the three condition numbers are still
reported.

``W`` is sampled on ``samples_per_harmonic`` (default 20) points per period of
the highest harmonic, uniformly over one period (``20 N`` samples; 100 for
``N = 5``). Every condition number reported is computed on that grid.

Constraints and their check
---------------------------
Positions, velocities and accelerations are linear in ``delta``: the limits
are imposed as linear inequalities on ``n_constraint`` points per period
(default ``max(200, 40 N)``), tightened by Bernstein's bound
``(pi N / m)^2 / 2`` so that they hold at every time, not only on the grid.
Torques are computed with a-priori parameters (``chi``; default the robot's
``[apriori]`` values mapped to base parameters, unknown ones zero, see
:func:`apriori_parameters`) by the compiled inverse dynamics and imposed on
the same grid. The result is then checked against the *actual* limits on a
dense grid (``n_check``, default 20 000 points per period, torque included):
:attr:`ExcitationResult.margins`. A candidate that fails the check is
discarded.

Optimiser
---------
SLSQP (scipy) on variables normalised by the velocity limits and the joint
half-ranges, from ``n_starts`` random feasible starts
(:func:`dynamics.trajectories.random_fourier_trajectory` with the same
``margin``; a start whose torque is out of bounds is shrunk towards ``q0``);
the best feasible result is kept. Gradients are analytic in the Fourier basis
(chain rule through ``q, qd, qdd``) with the partial derivatives of the regressor
with respect to ``q_j``, ``qd_j``, ``qdd_j`` taken by finite differences of the
compiled regressor, all samples at once (``5 n + 1`` regressor evaluations of the
grid per gradient instead of ``n (2 N + 1)``); the objective is the log of the
condition number. The velocity difference is one-sided away from zero, so the
Coulomb ``sign(qd)`` column never jumps inside a difference.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from .base_parameters import base_parameters, base_regressor
from .dynamic_model import inverse_dynamics
from .errors import InputError
from .trajectories import FourierTrajectory, random_fourier_trajectory

__all__ = ["ExcitationResult", "design_excitation", "apriori_parameters", "column_scales",
           "regressor_conditioning", "limit_margins", "spectrum_check", "SCALINGS", "CRITERIA"]

SCALINGS = ("envelope", "none", "columns")
CRITERIA = ("cond", "logdet")
DEFAULT_SAMPLES_PER_HARMONIC = 20
DEFAULT_N_CHECK = 20_000
_ENVELOPE_SEED = 19970501           # fixed: S must depend on the robot only
_ENVELOPE_SAMPLES = 4000
_H_Q = 1e-6                          # rad (m) step of the position derivative
_H_QD = 1e-6                         # rad/s step of the velocity derivative


# ----------------------------------------------------------------------------- helpers
def apriori_parameters(robot, bp=None):
    """Standard parameters ``chi_st`` built from ``robot.apriori`` (for torque limits).

    Keys of ``robot.apriori`` may be base-parameter names (``ZZ1R``) or standard
    names. When every key is a standard name, ``beta = P chi`` maps them to the
    base parameters; otherwise base names are read directly (a standard name that
    is also a base name, such as ``Fv1``, counts as both). Parameters without an
    a-priori value are zero. Returns ``(chi_st, beta, missing)`` with ``missing``
    the base parameters that had no value.
    """
    bp = base_parameters(robot) if bp is None else bp
    values = dict(robot.apriori or {})
    std = set(robot.standard_names)
    if values and set(values) <= std:
        beta = bp.from_standard(robot.standard_vector(values))
        missing = []
        for k, name in enumerate(bp.names):
            involved = [bp.standard_names[bp.independent[k]]] + [
                bp.standard_names[d] for c, d in zip(bp.K[k], bp.dependent) if c != 0.0]
            if not any(nm in values for nm in involved):
                missing.append(name)
    else:
        unknown = sorted(set(values) - set(bp.names) - std)
        if unknown:
            raise InputError(f"a-priori values of '{robot.name}' name unknown parameters: "
                             f"{', '.join(unknown)}; use base names ({', '.join(bp.names[:4])}, ...) "
                             "or standard names")
        beta = np.array([float(values.get(nm, 0.0)) for nm in bp.names])
        missing = [nm for nm in bp.names if nm not in values]
    return bp.to_standard(beta), beta, missing


def column_scales(robot, bp, scaling="envelope"):
    """Fixed column scales ``S`` (b,) of the base regressor (see the module docstring).

    ``"envelope"``: RMS of each column over states uniform in the limit box (an
    infinite position range is replaced by [-pi, pi], an infinite velocity or
    acceleration limit by 1); ``"none"``: ones. ``"columns"`` has no fixed scale
    (the columns are normalised per trajectory): ones are returned.
    """
    if scaling not in SCALINGS:
        raise InputError(f"scaling must be one of {', '.join(SCALINGS)}, got {scaling!r}")
    if scaling != "envelope":
        return np.ones(bp.n_base)
    q_min, q_max, qd_max, qdd_max, _ = robot.limits()
    finite = np.isfinite(q_min) & np.isfinite(q_max)
    lo = np.where(finite, q_min, -np.pi)
    hi = np.where(finite, q_max, np.pi)
    vd = np.where(np.isfinite(qd_max), qd_max, 1.0)
    va = np.where(np.isfinite(qdd_max), qdd_max, 1.0)
    rng = np.random.default_rng(_ENVELOPE_SEED)
    m, n = _ENVELOPE_SAMPLES, robot.n_joints
    q = rng.uniform(lo, hi, (m, n))
    qd = rng.uniform(-vd, vd, (m, n))
    qdd = rng.uniform(-va, va, (m, n))
    W = base_regressor(robot, bp, q, qd, qdd)
    rms = np.sqrt(np.mean(W ** 2, axis=(0, 1)) * n)   # RMS per sample (all joints' rows)
    return np.where(rms > 0, rms, 1.0)


def _cond(s):
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def regressor_conditioning(robot, bp, trajectory, *, samples_per_harmonic=DEFAULT_SAMPLES_PER_HARMONIC,
                           scales=None):
    """Condition numbers of the base regressor of ``trajectory`` over one period.

    Returns ``{"cond": cond(W S^-1) (envelope scales unless ``scales`` given),
    "cond_raw": cond(W) in SI units, "cond_unit": cond of W with unit-norm columns,
    "logdet": log det(W_s^T W_s) / b / (samples), "n_samples": ...}``.
    """
    scales = column_scales(robot, bp) if scales is None else np.asarray(scales, dtype=float)
    G = int(samples_per_harmonic) * trajectory.harmonics
    t = np.arange(G) * (trajectory.period / G)
    q, qd, qdd = trajectory.evaluate(t)
    W = base_regressor(robot, bp, q, qd, qdd).reshape(-1, bp.n_base)
    s_raw = np.linalg.svd(W, compute_uv=False)
    Ws = W / scales
    s = np.linalg.svd(Ws, compute_uv=False)
    norms = np.linalg.norm(W, axis=0)
    s_unit = np.linalg.svd(W / np.where(norms > 0, norms, 1.0), compute_uv=False)
    with np.errstate(divide="ignore"):
        logdet = float(2.0 * np.sum(np.log(s / math.sqrt(G))) / bp.n_base)
    return {"cond": _cond(s), "cond_raw": _cond(s_raw), "cond_unit": _cond(s_unit),
            "logdet": logdet, "n_samples": G}


def limit_margins(robot, trajectory, chi_st=None, *, n_check=DEFAULT_N_CHECK, bp=None):
    """Relative distance of ``trajectory`` to every limit, per joint, on a dense grid.

    Columns (1 = untouched, 0 = on the limit, negative = violated):
    ``q_low = (min q - q_min) / half range``, ``q_high = (q_max - max q) / half range``,
    ``qd = 1 - max|qd| / qd_max``, ``qdd = 1 - max|qdd| / qdd_max`` and, with
    ``chi_st``, ``tau = 1 - max|tau| / tau_max`` (NaN where a limit is infinite),
    plus the peak values. The grid is ``n_check`` points over one period (offset
    by half a step from t = 0).
    """
    import pandas as pd

    q_min, q_max, qd_max, qdd_max, tau_max = robot.limits()
    t = (np.arange(n_check) + 0.5) * (trajectory.period / n_check)
    q, qd, qdd = trajectory.evaluate(t)
    half = 0.5 * (q_max - q_min)
    with np.errstate(invalid="ignore", divide="ignore"):
        rows = {
            "q_low": np.where(np.isfinite(q_min), (q.min(0) - q_min) / half, np.nan),
            "q_high": np.where(np.isfinite(q_max), (q_max - q.max(0)) / half, np.nan),
            "qd": np.where(np.isfinite(qd_max), 1.0 - np.abs(qd).max(0) / qd_max, np.nan),
            "qdd": np.where(np.isfinite(qdd_max), 1.0 - np.abs(qdd).max(0) / qdd_max, np.nan),
        }
        peaks = {"q_min_reached": q.min(0), "q_max_reached": q.max(0),
                 "qd_peak": np.abs(qd).max(0), "qdd_peak": np.abs(qdd).max(0)}
        if chi_st is not None:
            tau = inverse_dynamics(robot, chi_st, q, qd, qdd)
            rows["tau"] = np.where(np.isfinite(tau_max), 1.0 - np.abs(tau).max(0) / tau_max, np.nan)
            peaks["tau_peak"] = np.abs(tau).max(0)
    df = pd.DataFrame({**rows, **peaks}, index=pd.Index(robot.joint_names, name="joint"))
    return df


def spectrum_check(trajectory, fs=None, *, rel_tol=1e-9):
    """FFT of one period of the reference positions: lines only at ``k f0``, ``k <= N``?

    One whole period sampled at ``fs`` (default ``50 N f0``, at least 64 samples
    per period) puts harmonic ``k`` exactly in FFT bin ``k``. Returns a dict:
    ``freqs`` (Hz) and ``amplitude`` (n, bins) of the one-sided amplitude spectrum
    of ``q - q0``, ``lines`` (frequencies of the bins above ``rel_tol`` times the
    largest line), ``off_grid`` (largest amplitude outside bins 1..N relative to
    the largest line), ``bandwidth`` (N f0) and ``ok``.
    """
    N = trajectory.harmonics
    if fs is None:
        m = max(64, 50 * N)
    else:
        m = int(round(float(fs) * trajectory.period))
        if abs(m - float(fs) * trajectory.period) > 1e-6 * m:
            raise InputError(f"fs = {fs} Hz does not give a whole number of samples per period "
                             f"({float(fs) * trajectory.period:g}); choose fs = k f0")
    t = np.arange(m) * (trajectory.period / m)
    q, _, _ = trajectory.evaluate(t)
    X = np.fft.rfft(q - q.mean(0), axis=0) / m
    amp = 2.0 * np.abs(X).T                                  # (n, bins)
    freqs = np.arange(amp.shape[1]) * trajectory.f0
    peak = float(amp.max()) if amp.size else 0.0
    mask = np.zeros(amp.shape[1], bool)
    mask[1:N + 1] = True
    off = float(amp[:, ~mask].max() / peak) if peak > 0 and (~mask).any() else 0.0
    lines = freqs[(amp.max(0) > rel_tol * peak)] if peak > 0 else np.array([])
    return {"freqs": freqs, "amplitude": amp, "lines": lines, "off_grid": off,
            "bandwidth": N * trajectory.f0, "max_line": float(lines.max()) if lines.size else 0.0,
            "ok": bool(off <= rel_tol and (lines.size == 0 or lines.max() <= N * trajectory.f0 * (1 + 1e-9)))}


# ----------------------------------------------------------------------------- problem
class _Problem:
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
        # variable scaling: velocity amplitudes by qd_max (or the acceleration/position
        # limits it implies), offsets by the half range
        w = 2.0 * np.pi * self.f0
        half = 0.5 * (q_max - q_min)
        vs = np.fmin(np.fmin(qd_max, qdd_max / (w * self.N)), half * w)
        vs = np.where(np.isfinite(vs) & (vs > 0), vs, 1.0)
        ps = np.where(np.isfinite(half) & (half > 0), half, 1.0)
        self.xs = np.concatenate([np.r_[np.full(2 * self.N, vs[j]), ps[j]] for j in range(self.n)])
        self._linear_constraints(q_min, q_max, qd_max, qdd_max)
        self._cache_key = None

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
                # |q - mid| <= mg half: the oscillating part bounded with the guard
                lim = mg * half[j]
                blk = np.zeros((self.Gc, self.n * self.m))
                blk[:, sl] = Bq
                # q = q0 + p(t); require (q - mid) <= lim - (1-guard) * amplitude bound:
                # conservatively tighten the whole bound by the guard factor
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

