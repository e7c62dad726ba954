"""Maximum likelihood with errors in variables (Bona & Curatella 2005, eqs. (13)-(16)).

Both the positions and the torques are measured with white Gaussian noise,
of standard deviations `sigma_q` and `sigma_tau` per joint. Eq. (13)
minimises, over the parameters theta and the unknown true values phi of every
observation, `1/2 sum (x - phi)^T sigma^-2 (x - phi)` subject to the model
`G(theta, phi) = 0` (eq. (14)). Eqs. (15)-(16) eliminate phi to first order
(the "effective variance" of each equation); here phi is kept exact but its
dimension is reduced, which a periodic excitation allows:

* The true positions are a finite Fourier series of the excitation's
  fundamental f0 (eq. (17)): `q_j(t) = c_j0 + sum_k c_jk cos(2 pi k f0 t) +
  d_jk sin(2 pi k f0 t)`, k = 1..K, with velocity and acceleration its
  analytic derivatives (eqs. (18)-(19)). A robot tracking a periodic reference
  in closed loop moves periodically (once the transient is over), so this
  loses nothing but the harmonics above K; K is chosen by BIC on the measured
  q (default) and may include harmonics the reference does not have (friction
  and gravity put some in the tracking error). The unknowns are theta and
  n (2K + 1) coefficients instead of theta and n N positions.
* The true torques are eliminated exactly by the constraint (14):
  `tau_true = G(theta, q, qd, qdd)` is the model's torque along the latent
  trajectory.

So the negative log-likelihood (eq. (13) with the constraint (14) solved) is

    1/2 sum_j ||q_j - B c_j||^2 / sigma_qj^2 + ||tau_j - G_j(theta, Bc, B'c, B''c)||^2 / sigma_tauj^2

plus the log-determinant terms, a nonlinear least-squares problem solved by
`scipy.optimize.least_squares` (trust-region reflective) from the LS start:
theta by OLS of tau on the model's regressor along the LS Fourier fit of q.
Jacobian: exact for the q part (-B / sigma_q) and for theta when the model
gives its regressor; the torque's sensitivity to the latent q, qd, qdd is a
one-sided finite difference per joint and derivative, taking the side with
the smaller magnitude, because the Coulomb term sign(qd) jumps: a difference
across a velocity reversal is a spike, the one on the other side is the true
(zero) slope.

Noise levels. sigma_q is identified by the Fourier fit itself (the residual
of q around its K-harmonic fit, dof N - 2K - 1); sigma_tau, when not given, is
re-estimated from the torque residual and the problem solved again (one
alternation of the concentrated likelihood; the estimate moves little after
that). Given values (e.g. from `dynid.analysis.processing.averaging.average_periods`)
are used as they are.

Covariance. The inverse Fisher information of the Gaussian likelihood, which
for a least-squares likelihood with known sigmas is the inverse Gauss-Newton
Hessian `(J^T J)^-1` of the weighted residual vector; the theta block of the
full inverse (trajectory coefficients included), so the uncertainty of the
latent trajectory is propagated. `tests/analysis/estimators/test_maximum_likelihood.py` checks it
against the spread of estimates over noise seeds. With estimated sigmas, the
uncertainty of sigma is not propagated (a second-order effect for N >> p).

Models. A model is an `EIVModel`: the torque `predict(theta, q, qd,
qdd) -> (N, n)`, optionally its regressor (linear models), and an LS start.
`robot_model` gives the rigid-body base-parameter model of any dynid
robot; `joint_model` the single-joint model
`tau = J qdd + Fv qd + Fc sign(qd) + k sin(q + q_off) + Off` (nonlinear in
q_off); `linear_model` wraps any regressor function.
"""
from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.linalg as sla
from scipy import optimize

from dynid.analysis.estimators.least_squares import identifiable_columns, ols
from dynid.analysis.processing.signals import velocity_dead_zone
from dynid.analysis.results import (
    ParameterResults,
    _fmt,
    deprecated_alias,
    identified_line,
    notices_block,
    parameter_table,
)
from dynid.dynamics.base_parameters import base_parameters, base_regressor
from dynid.errors import ConvergenceError, IdentificationError, InputError
from dynid.provenance import data_hash, json_safe, versions

__all__ = ["EIVModel", "linear_model", "robot_model", "joint_model", "fourier_basis",
           "select_harmonics", "maximum_likelihood", "MLResult"]

_WIDTH = 78


# ----------------------------------------------------------------------- models
@dataclass
class EIVModel:
    """A dynamic model for `maximum_likelihood`.

    `predict(theta, q, qd, qdd)` returns the torques (N, n) for samples (N, n).
    `regressor(q, qd, qdd)` (linear models only) returns W3 (N, n, p) with
    `predict = W3 @ theta`; it makes the theta Jacobian exact and gives the
    LS start. `start(q, qd, qdd, tau)` returns an initial theta for
    nonlinear models (default: OLS on the regressor).
    """

    names: list
    predict: Callable
    regressor: Callable | None = None
    start: Callable | None = None
    description: str = ""

    @property
    def n_params(self):
        return len(self.names)

    def initial(self, q, qd, qdd, tau):
        if self.start is not None:
            return np.asarray(self.start(q, qd, qdd, tau), dtype=float)
        if self.regressor is None:
            raise InputError("a nonlinear model needs theta0= or a start function")
        W = self.regressor(q, qd, qdd)
        if len(identifiable_columns(W)) < W.shape[2]:
            # a joint that never moves leaves columns at zero: lstsq would start from (and the
            # likelihood keep) huge values with tiny sigmas; IDIM's rank check names them
            ols(W, tau, self.names)
            raise IdentificationError(f"the data do not identify every parameter of {self.description}: "
                                      "excite every joint with a richer trajectory")
        A = W.transpose(1, 0, 2).reshape(-1, W.shape[2])
        return np.linalg.lstsq(A, tau.T.reshape(-1), rcond=None)[0]


def linear_model(regressor, names, description="linear in the parameters"):
    """An `EIVModel` from a regressor function `(q, qd, qdd) -> W3 (N, n, p)`."""
    names = list(names)
    return EIVModel(names=names, predict=lambda th, q, qd, qdd: regressor(q, qd, qdd) @ th,
                    regressor=regressor, description=description)


def robot_model(robot, bp=None):
    """The rigid-body model of a dynid robot in its base parameters (eq. (9))."""
    bp = base_parameters(robot) if bp is None else bp
    return linear_model(lambda q, qd, qdd: base_regressor(robot, bp, q, qd, qdd), bp.names,
                        description=f"rigid-body base-parameter model of '{robot.name}'")


def joint_model(joint=1, *, gravity=True, offset=True):
    """Single-joint model of section 3.1: `J qdd + Fv qd + Fc sign(qd) [+ k sin(q + q_off)] [+ Off]`.

    Eqs. (21)-(23) of the paper (gravity as the inverted pendulum of eq. (23)).
    Parameters `J{j} Fv{j} Fc{j} [k{j} qoff{j}] [Off{j}]`. The LS start fits
    `a sin q + b cos q` linearly and converts to `k, q_off`.
    """
    j = int(joint)
    names = [f"J{j}", f"Fv{j}", f"Fc{j}"] + ([f"k{j}", f"qoff{j}"] if gravity else []) + \
            ([f"Off{j}"] if offset else [])

    def predict(th, q, qd, qdd):
        tau = th[0] * qdd + th[1] * qd + th[2] * np.sign(qd)
        i = 3
        if gravity:
            tau = tau + th[3] * np.sin(q + th[4])
            i = 5
        if offset:
            tau = tau + th[i]
        return tau

    def start(q, qd, qdd, tau):
        cols = [qdd[:, 0], qd[:, 0], np.sign(qd[:, 0])]
        if gravity:
            cols += [np.sin(q[:, 0]), np.cos(q[:, 0])]
        if offset:
            cols.append(np.ones(q.shape[0]))
        x = np.linalg.lstsq(np.column_stack(cols), tau[:, 0], rcond=None)[0]
        out = list(x[:3])
        if gravity:
            a, b = x[3], x[4]          # k sin(q + o) = k cos(o) sin q + k sin(o) cos q
            out += [math.hypot(a, b), math.atan2(b, a)]
        if offset:
            out.append(x[-1])
        return np.array(out)

    return EIVModel(names=names, predict=predict, start=start,
                    description="single joint: J qdd + Fv qd + Fc sign(qd)"
                                + (" + k sin(q + q_off)" if gravity else "") + (" + Off" if offset else ""))


# ---------------------------------------------------------------------- Fourier
def fourier_basis(t, f0, n_harmonics):
    """(B, B', B'') of shape (N, 2K+1): columns 1, cos(k w t), sin(k w t) (k = 1..K) and their derivatives."""
    t = np.asarray(t, dtype=float)
    w = 2 * np.pi * f0 * np.arange(1, n_harmonics + 1)
    ph = np.multiply.outer(t, w)
    c, s = np.cos(ph), np.sin(ph)
    N = t.size
    B = np.column_stack([np.ones(N), c, s])
    Bd = np.column_stack([np.zeros(N), -s * w, c * w])
    Bdd = np.column_stack([np.zeros(N), -c * w ** 2, -s * w ** 2])
    return B, Bd, Bdd


def select_harmonics(t, q, f0, *, max_harmonics=None):
    """K minimising BIC of the Fourier fit of each joint's q; returns (K, per-joint K, table).

    Harmonics enter in order (nested models), so one QR of the largest basis
    gives every candidate's residual.
    """
    N, n = q.shape
    fs = (N - 1) / (t[-1] - t[0])
    k_nyq = int(math.floor((fs / 2) / f0 - 1e-9))
    kmax = min(k_nyq, (N - 2) // 4, 60) if max_harmonics is None else min(int(max_harmonics), k_nyq)
    if kmax < 1:
        raise InputError(f"{N} samples at {fs:g} Hz cannot hold one harmonic of f0 = {f0:g} Hz")
    B, _, _ = fourier_basis(t, f0, kmax)
    order = [0] + [c for k in range(kmax) for c in (1 + k, 1 + kmax + k)]
    Q, _ = np.linalg.qr(B[:, order])
    proj = Q.T @ q
    ss = np.sum(q * q, axis=0)
    rss = ss[None, :] - np.cumsum(proj ** 2, axis=0)      # (2K+1, n)
    ks = np.arange(kmax + 1)
    p = 2 * ks + 1
    r = np.maximum(rss[p - 1], 1e-300 * ss)
    bic = N * np.log(r / N) + p[:, None] * math.log(N)
    per = bic.argmin(axis=0)
    table = pd.DataFrame(bic, index=pd.Index(ks, name="K"), columns=[f"q{j + 1}" for j in range(n)])
    return int(per.max()), [int(x) for x in per], table


# ----------------------------------------------------------------------- result
@dataclass(eq=False, repr=False)
class MLResult(ParameterResults):
    """Maximum-likelihood estimate (eqs. (13)-(16)) with its covariance and the LS start.

    `chi` the estimate (`params` the Series; `theta`, its old name, is deprecated).
    `robot_name`, `source` and `robot_signature` (`dynid.dynamics.robot.model_signature`) say
    which robot and recording were identified: `maximum_likelihood` takes arrays and a model,
    so they are "" unless the caller sets them (`dynid.identify` and the command line do).
    """

    names: list
    chi: np.ndarray
    cov: np.ndarray
    theta_ls: np.ndarray
    sigma_q: np.ndarray
    sigma_tau: np.ndarray
    sigma_tau_given: bool
    n_harmonics: int
    f0: float
    coefficients: np.ndarray      # (n, 2K+1) latent trajectory
    nll: float
    converged: bool
    n_evaluations: int
    n_samples: int
    n_joints: int
    rms_q: np.ndarray
    rms_tau: np.ndarray
    elapsed: float
    model: str = ""
    #: ||tau - tau_model(latent trajectory)|| / ||tau|| on the torque equations kept (the
    #: relative error norm every identification result reports)
    rel_error: float = float("nan")
    settings: dict = field(default_factory=dict)
    notices: list = field(default_factory=list)
    data_hash: str = ""
    stop_reason: str = ""         # the optimiser's message (the verdict's reason when not converged)
    robot_name: str = ""          # the robot identified ("" when built from arrays alone)
    source: str = ""              # the recording identified
    robot_signature: str = ""     # dynamics.robot.model_signature of the robot identified

    method = "ML-EIV"
    theta = deprecated_alias("params (a pandas Series) or chi (the array)", lambda r: r.chi)
    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r.bse.to_numpy())
    rel_sigma = deprecated_alias("rel_std (a pandas Series; .to_numpy() for the array)",
                                 lambda r: r.rel_std.to_numpy())

    def __post_init__(self):
        self.chi = np.asarray(self.chi, dtype=float)
        self.cov = np.asarray(self.cov, dtype=float)

    def trajectory(self, t):
        """Latent (q, qd, qdd) at times t, each (len(t), n).

        Returns
        -------
        q, qd, qdd : numpy.ndarray
            Each (len(t), n): rad, rad/s, rad/s^2.
        """
        B, Bd, Bdd = fourier_basis(t, self.f0, self.n_harmonics)
        C = self.coefficients.T
        return B @ C, Bd @ C, Bdd @ C

    def to_frame(self):
        return pd.DataFrame({"value": self.chi, "std": self.bse.to_numpy(), "rel_std_percent": self.rel_std.to_numpy(),
                             "unit": self._units(), "ls_start": self.theta_ls},
                            index=pd.Index(self.names, name="parameter"))

    def summary(self):
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        # a prismatic joint's position is in m and its force in N
        uq, ut = ("[rad|m]", "[N m|N]") if self._prismatic() else ("[rad]", "[N m]")
        lines = identified_line("Maximum-likelihood", self.robot_name, self.source) + [
                 "Maximum likelihood, errors in variables (Bona & Curatella 2005, eqs. (13)-(16))".center(_WIDTH),
                 rule, f"Model: {self.model}",
                 f"Samples N: {self.n_samples}   joints: {self.n_joints}   parameters: {self.n_params}   "
                 f"latent trajectory: K = {self.n_harmonics} harmonics of f0 = {_fmt(self.f0)} Hz",
                 f"-log L (eq. 13): {_fmt(self.nll)}   converged: {self.converged}   "
                 f"evaluations: {self.n_evaluations}   time: {self.elapsed:.2f} s", thin,
                 f"{'Joint':<8}{'sigma_q ' + uq:>17}{'rms q res. ' + uq:>17}{'sigma_tau ' + ut:>17}"
                 f"{'rms tau res. ' + ut:>19}"]
        for j in range(self.n_joints):
            lines.append(f"{j + 1:<8}{_fmt(self.sigma_q[j]):>17}{_fmt(self.rms_q[j]):>17}"
                         f"{_fmt(self.sigma_tau[j]):>17}{_fmt(self.rms_tau[j]):>19}")
        lines.append(thin)
        lines += parameter_table(self.names, [("ML value", self.chi, "num"), ("sigma", self.bse.to_numpy(), "num"),
                                              ("%sigma", self.rel_std.to_numpy(), "pct"),
                                              ("LS start", self.theta_ls, "num")], prismatic=self._prismatic())
        lines.append(rule)
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self):
        return json_safe({
            "method": "ML-EIV",
            "robot": self.robot_name or None,
            "robot_signature": self.robot_signature or None,
            "source": self.source,
            "model": self.model,
            "settings": self.settings,
            "parameters": self._records(),
            "ls_start": [{"name": n, "value": v} for n, v in zip(self.names, self.theta_ls)],
            "sigma_q": self.sigma_q, "sigma_tau": self.sigma_tau,
            "sigma_tau_given": self.sigma_tau_given,
            "n_harmonics": self.n_harmonics, "f0": self.f0,
            "neg_log_likelihood": self.nll, "converged": self.converged,
            "n_evaluations": self.n_evaluations, "n_samples": self.n_samples,
            "rms_q_residual": self.rms_q, "rms_tau_residual": self.rms_tau,
            "rel_error": self.rel_error, "elapsed_s": self.elapsed,
            "versions": versions(), "data_hash": self.data_hash, "notices": self.notices,
        })



# ------------------------------------------------------------------- problem
def _check(t, q, tau):
    def arr(name, x, nd):
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a numeric array") from None
        if nd == 2 and a.ndim == 1:
            a = a[:, None]
        if a.ndim != nd:
            raise InputError(f"{name} has shape {a.shape}; expected {'(N,)' if nd == 1 else '(N, n)'}")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name} holds non-finite values (NaN or inf); drop or fill those samples")
        return a
    t, q, tau = arr("t", t, 1), arr("q", q, 2), arr("tau", tau, 2)
    if q.shape[0] != t.size or tau.shape != q.shape:
        raise InputError(f"t {t.shape}, q {q.shape} and tau {tau.shape} must have the same number of "
                         "samples N, and q and tau the same number of joints")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise InputError("t must be strictly increasing")
    return t, q, tau


def _sig(x, n, name):
    v = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(v) & (v > 0)):
        raise InputError(f"{name} must be positive and finite (one value or one per joint), got {x!r}")
    return v


class _Problem:
    """Weighted residual vector and Jacobian of the eq. (13) likelihood in x = [theta, c]."""

    def __init__(self, model, t, q, tau, f0, K, sq, st, keep):
        self.model, self.q, self.tau = model, q, tau
        self.w = keep.astype(float)          # torque equations used (velocity dead zone excluded)
        self.B, self.Bd, self.Bdd = fourier_basis(t, f0, K)
        self.N, self.n = q.shape
        self.p = model.n_params
        self.m = 2 * K + 1
        self.sq, self.st = sq, st

    def split(self, x):
        return x[:self.p], x[self.p:].reshape(self.n, self.m)

    def kin(self, C):
        return self.B @ C.T, self.Bd @ C.T, self.Bdd @ C.T

    def residual(self, x):
        th, C = self.split(x)
        q, qd, qdd = self.kin(C)
        rq = (self.q - q) / self.sq
        rt = self.w * (self.tau - self.model.predict(th, q, qd, qdd)) / self.st
        return np.concatenate([rq.T.ravel(), rt.T.ravel()])

    def jacobian(self, x):
        th, C = self.split(x)
        q, qd, qdd = self.kin(C)
        N, n, p, m = self.N, self.n, self.p, self.m
        J = np.zeros((2 * n * N, p + n * m))
        for j in range(n):                               # q part: -B / sigma_q
            J[j * N:(j + 1) * N, p + j * m:p + (j + 1) * m] = -self.B / self.sq[j]
        base = self.model.predict(th, q, qd, qdd)
        Jt = np.empty((N, n, p + n * m))
        if self.model.regressor is not None:
            Jt[:, :, :p] = self.model.regressor(q, qd, qdd)
        else:
            for k in range(p):
                h = 1e-7 * max(1.0, abs(th[k]))
                e = th.copy()
                e[k] += h
                Jt[:, :, k] = (self.model.predict(e, q, qd, qdd) - base) / h
        args = (q, qd, qdd)
        for l in range(n):
            acc = np.zeros((N, n, m))
            for i, Bx in enumerate((self.B, self.Bd, self.Bdd)):
                x0 = args[i]
                h = 1e-6 * max(1.0, float(np.abs(x0[:, l]).max()))
                d = []
                for sgn in (1.0, -1.0):
                    xs = x0.copy()
                    xs[:, l] += sgn * h
                    a = list(args)
                    a[i] = xs
                    d.append(sgn * (self.model.predict(th, *a) - base) / h)
                # the smaller one-sided slope: a step across a sign(qd) jump is a spike
                g = np.where(np.abs(d[0]) <= np.abs(d[1]), d[0], d[1])     # (N, n)
                acc += g[:, :, None] * Bx[:, None, :]
            Jt[:, :, p + l * m:p + (l + 1) * m] = acc
        # torque residual = (tau - G) / sigma_tau: derivative -dG/dx / sigma_tau
        for j in range(n):
            J[n * N + j * N:n * N + (j + 1) * N] = -Jt[:, j, :] * (self.w[:, j, None] / self.st[j])
        return J


#: ML's 'auto' velocity dead zone: this fraction of each joint's peak latent
#: speed, passed explicitly to the shared
#: :func:`dynid.analysis.processing.signals.velocity_dead_zone` instead of its 1 %
#: default (``AUTO_DEAD_ZONE``, IDIM's). Larger because the latent velocity is
#: not dilated around reversals and a closed-loop joint lingers near zero speed
#: while it reverses (first measured: Fc biased by -20 % at 1 %, < 1 % at 5 %
#: on the 1-DOF test case; re-measured with the default reversal guard, 12 seeds
#: of tests/analysis/estimators/test_maximum_likelihood.py's case: mean Fc error -8.3 % at 1 %,
#: -7.8 % at 5 %, spread 9 %). Kept at 5 % so ML's estimates do not change.
ML_DEAD_ZONE_FRACTION = 0.05


def _reversal_guard(t, qd, guard):
    """False within `guard` s of a sign change of each joint's qd."""
    keep = np.ones(qd.shape, dtype=bool)
    if guard <= 0:
        return keep
    for j in range(qd.shape[1]):
        k = np.flatnonzero(np.signbit(qd[1:, j]) != np.signbit(qd[:-1, j]))
        if k.size == 0:
            continue
        tc = 0.5 * (t[k] + t[k + 1])
        idx = np.searchsorted(tc, t)
        near = np.full(t.size, np.inf)
        near = np.minimum(near, np.abs(t - tc[np.clip(idx, 0, tc.size - 1)]))
        near = np.minimum(near, np.abs(t - tc[np.clip(idx - 1, 0, tc.size - 1)]))
        keep[:, j] = near > guard
    return keep


def _fisher_cov(J, p):
    """theta block of (J^T J)^-1 via the SVD of J (no squared condition number)."""
    _, s, Vt = sla.svd(J, full_matrices=False, check_finite=False)
    keep = s > s[0] * 1e-12
    V = Vt[keep].T / s[keep]
    full_theta = V[:p]
    return full_theta @ full_theta.T


def maximum_likelihood(t, q, tau, model, *, f0, n_harmonics=None, sigma_q=None, sigma_tau=None,
                       theta0=None, qd_threshold="auto", reversal_guard="auto", max_nfev=200, refine_sigma_tau=True,
                       settings=None, progress=None) -> MLResult:
    """Maximum-likelihood estimate of the model parameters with noise on q and tau (eqs. (13)-(16)).

    Parameters
    ----------
    t : (N,) sample times, s.  q : (N, n) measured positions, rad.  tau : (N, n) torques, N m.
    model : `EIVModel` (`robot_model`, `joint_model`, `linear_model`).
    f0 : fundamental frequency of the periodic excitation, Hz.
    n_harmonics : K of the latent trajectory; None = BIC on q (`select_harmonics`).
    sigma_q, sigma_tau : noise standard deviations (one or per joint); None = estimated
        (sigma_q from the Fourier fit of q, sigma_tau from the torque residual).
    theta0 : start; default the model's LS start along the Fourier-fitted q.
    qd_threshold : torque equations where the Fourier-fitted |qd_j| is below this
        (rad/s; one value or per joint) are left out, as IDIM's velocity dead zone:
        sign(qd) is the wrong model while a joint reverses or sticks. 'auto' =
        `ML_DEAD_ZONE_FRACTION` (5 %) x max |qd_j|; 0 keeps all. Fixed from the start, so
        the objective stays smooth.
    reversal_guard : torque equations within this time (s) of a velocity
        reversal of the latent trajectory are left out too. At a reversal the
        Coulomb torque jumps by 2 Fc, the true acceleration jumps to match it
        and the torque stays continuous; a K-harmonic series smooths that jump
        over about 1/(2 K f0), so there the model predicts a torque step the
        data do not have (measured: Fc biased by -12 to -19 % without the
        guard). 'auto' = 1/(4 K f0); 0 disables it.
    progress : callable, optional
        Called with the fraction of the optimiser's evaluation budget spent (max_nfev per
        pass; the optimiser usually stops before it, and the last call is 1.0).

    Returns `MLResult`. Raises InputError on bad input, ConvergenceError
    when the optimiser fails.
    """
    t0 = time.perf_counter()
    t, q, tau = _check(t, q, tau)
    N, n = q.shape
    f0 = _check_f0(f0, t)
    notices = []
    K = _harmonics(t, q, f0, n_harmonics, notices)
    m = 2 * K + 1
    p = model.n_params
    if N <= m + p:
        raise InputError(f"{N} samples are too few for {p} parameters and {m} Fourier coefficients per joint")
    _check_size(N, n, p, K, n_harmonics is None)
    B, Bd, Bdd, C0 = _fourier_start(t, q, f0, K)
    _check_periodic(q, B @ C0, f0, K, notices, harmonics_given=n_harmonics is not None)
    sq = _sigma_q(q, B, C0, sigma_q, m)
    qf, qdf, qddf = B @ C0, Bd @ C0, Bdd @ C0
    keep = _kept_equations(t, qdf, qd_threshold, reversal_guard, K, f0, p)
    rows = keep.all(axis=1)
    th0 = model.initial(qf[rows], qdf[rows], qddf[rows], tau[rows]) if theta0 is None else np.asarray(theta0, dtype=float)
    if th0.shape != (p,) or not np.all(np.isfinite(th0)):
        raise InputError(f"theta0 must be {p} finite numbers ({', '.join(model.names)})")
    th_ls = th0.copy()
    r_tau = keep * (tau - model.predict(th0, qf, qdf, qddf))
    dof_tau = np.maximum(keep.sum(axis=0) - p, 1)
    given = sigma_tau is not None
    st = _sig(sigma_tau, n, "sigma_tau") if given else np.sqrt(np.sum(r_tau ** 2, axis=0) / dof_tau)
    if not np.all(st > 0):
        raise InputError("the torque residual is exactly zero: sigma_tau cannot be estimated; pass sigma_tau")
    x = np.concatenate([th0, C0.T.ravel()])
    passes = 1 if (given or not refine_sigma_tau) else 2
    sol, prob, st, n_eval = _optimise(model, t, q, tau, f0, K, sq, st, keep, x, passes, max_nfev, dof_tau,
                                      progress)
    if sol.status <= 0:
        notices.append(f"least_squares stopped without convergence: {sol.message}")
    x = sol.x
    th, C = prob.split(x)
    ql, qdl, qddl = prob.kin(C)
    J = prob.jacobian(x)
    cov = _fisher_cov(J, p)
    rq = q - ql
    rt = keep * (tau - model.predict(th, ql, qdl, qddl))
    n_tau = keep.sum(axis=0)
    nll = float(0.5 * np.sum((rq / sq) ** 2) + 0.5 * np.sum((rt / st) ** 2)
                + N * np.sum(np.log(sq)) + np.sum(n_tau * np.log(st))
                + 0.5 * (N * n + n_tau.sum()) * math.log(2 * math.pi))
    if not keep.all():
        notices.append("velocity dead zone: torque equations left out per joint: "
                       + ", ".join(f"{100 * (1 - f):.1f} %" for f in keep.mean(axis=0)))
    cfg = {**(settings or {}), "maximum_likelihood": {
        "latent": f"Fourier series, K = {K} harmonics of f0 = {f0:g} Hz",
        "optimizer": "scipy.optimize.least_squares (trf), x_scale='jac'",
        "covariance": "theta block of (J^T J)^-1 (Fisher information, known sigmas)",
        "qd_threshold": qd_threshold if isinstance(qd_threshold, str) else np.broadcast_to(
            np.asarray(qd_threshold, dtype=float), (n,)).tolist(),
        "sigma_q": "given" if sigma_q is not None else "Fourier-fit residual",
        "sigma_tau": "given" if given else "torque residual (one concentrated-likelihood pass)"}}
    return MLResult(names=list(model.names), chi=th, cov=cov, theta_ls=th_ls, sigma_q=sq, sigma_tau=st,
                    sigma_tau_given=given, n_harmonics=K, f0=f0, coefficients=C, nll=nll,
                    converged=bool(sol.status > 0), n_evaluations=n_eval, n_samples=N, n_joints=n,
                    rms_q=np.sqrt(np.mean(rq ** 2, axis=0)), rms_tau=np.sqrt(np.sum(rt ** 2, axis=0) / n_tau),
                    elapsed=time.perf_counter() - t0, model=model.description,
                    rel_error=float(np.linalg.norm(rt) / np.linalg.norm(keep * tau)), settings=cfg,
                    notices=notices, data_hash=data_hash(t, q, tau), stop_reason=str(sol.message))


def _check_f0(f0, t):
    try:
        f0 = float(f0)
    except (TypeError, ValueError):
        raise InputError(f"f0 must be a frequency in Hz, got {f0!r}") from None
    if not (np.isfinite(f0) and f0 > 0):
        raise InputError(f"f0 must be a positive frequency in Hz, got {f0!r}")
    if t.size < 8:
        raise InputError(f"{t.size} samples are too few for the likelihood of eq. (13)")
    return f0


#: the largest Jacobian (2 n N rows x p + n (2K + 1) columns, dense) the optimiser is given: its
#: SVD at every step costs rows x columns^2. 5e7 entries (400 MB): a 5 kHz, 4 s TX40 log with 10
#: harmonics (4.5e7) took a minute and a half; with 60 (BIC's cap, 1.9e8) it had not ended after
#: 15 minutes and 10 GB.
ML_MAX_JACOBIAN = 5e7


def _check_size(N, n, p, K, chosen):
    """Refuse, before any work, a likelihood whose Jacobian would not fit `ML_MAX_JACOBIAN`."""
    rows, cols = 2 * n * N, p + n * (2 * K + 1)
    if rows * cols <= ML_MAX_JACOBIAN:
        return
    fit = max(1, int((ML_MAX_JACOBIAN / rows - p) / n - 1) // 2)
    raise InputError(
        f"maximum likelihood with {K} harmonics{' (chosen by BIC on q)' if chosen else ''} on {N} samples x {n} "
        f"joints needs a {rows:,} x {cols:,} Jacobian ({rows * cols * 8 / 1e9:.1f} GB, refactored at every step): "
        f"too large. Fit fewer harmonics (--ml-harmonics, ml_harmonics= in Python; {fit} fit these samples), "
        "or resample the recording to a lower rate or cut it to whole periods (a TOML experiment file), or "
        "use IDIM")


def _harmonics(t, q, f0, n_harmonics, notices):
    """K of the latent trajectory: given, or chosen by BIC on q (said in `notices`)."""
    if n_harmonics is None:
        K, per_joint, _ = select_harmonics(t, q, f0)
        K = max(K, 1)
        notices.append(f"latent trajectory: K = {K} harmonics (BIC on q; per joint {per_joint})")
        return K
    K = int(n_harmonics)
    if K < 1 or K != n_harmonics:
        raise InputError(f"n_harmonics must be a positive integer, got {n_harmonics!r}")
    return K


#: share of a joint's motion (RMS about its mean) the Fourier series of f0 may leave
#: unexplained: above NOT_PERIODIC_NOTICE a notice, above NOT_PERIODIC_ERROR an error
NOT_PERIODIC_NOTICE, NOT_PERIODIC_ERROR = 0.05, 0.25
#: the latent trajectory's misfit of q, in units of q's noise, above which the fit is said biased
NOT_PERIODIC_NOISE = 10.0
#: a joint whose motion (RMS about its mean, rad or m) is below this is not judged: near the
#: noise level, no Fourier series explains it, and it says nothing about f0
STILL_JOINT_RMS = 1e-3


def _check_periodic(q, q_fit, f0, K, notices, harmonics_given=False):
    """The latent trajectory (eq. (17)) must describe q: with the wrong f0, too few harmonics or a
    motion that is not periodic most of it is left out, and the fit that follows is meaningless."""
    spread = np.sqrt(np.mean((q - q.mean(axis=0)) ** 2, axis=0))
    moving = spread >= STILL_JOINT_RMS
    if not moving.any():
        raise InputError(f"no joint moves by more than {STILL_JOINT_RMS:g} rad (RMS about its mean): the "
                         "recording does not excite the robot, so there is nothing to identify; record the "
                         "excitation trajectory")
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.sqrt(np.mean((q - q_fit) ** 2, axis=0)) / spread
    share = np.where(moving & np.isfinite(share), share, 0.0)
    j = int(np.argmax(share))
    text = (f"{K} harmonics of f0 = {f0:g} Hz leave {100 * share[j]:.3g} % of joint {j + 1}'s motion "
            "unexplained (RMS about its mean)")
    fix = ("give more harmonics (--ml-harmonics; ml_harmonics= in Python), or the fundamental frequency of "
           "the excitation (--f0: 1 / the period of the reference)" if harmonics_given else
           "give the fundamental frequency of the excitation (--f0: 1 / the period of the reference)")
    if share[j] > NOT_PERIODIC_ERROR:
        raise InputError(f"{text}: the latent trajectory of maximum likelihood (eq. (17)) does not describe "
                         f"the recording. {fix[0].upper() + fix[1:]}; for data that are not periodic use "
                         "IDIM or DIDIM")
    if share[j] > NOT_PERIODIC_NOTICE:
        notices.append(f"{text}: the latent trajectory (eq. (17)) misses part of the motion, which biases the "
                       f"estimates; {fix}")
        return
    # a small share can still be far above the noise (a start-up transient, a drift): the likelihood
    # then reads the misfit as position noise, and the estimates are biased (Fv1 7 sigma off)
    noise = np.std(np.diff(q, n=2, axis=0), axis=0) / math.sqrt(6.0)     # white noise: var(d2 q) = 6 s^2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.sqrt(np.mean((q - q_fit) ** 2, axis=0)) / noise
    ratio = np.where(moving & np.isfinite(ratio), ratio, 0.0)
    j = int(np.argmax(ratio))
    if ratio[j] > NOT_PERIODIC_NOISE:
        notices.append(f"the latent trajectory ({K} harmonics of f0 = {f0:g} Hz) leaves {ratio[j]:.3g} times the "
                       f"noise of joint {j + 1}'s q (from its second differences): the motion is not periodic "
                       "at the noise level (a start-up transient, a drift), and maximum likelihood reads the "
                       "misfit as position noise, which biases its estimates; cut the recording to whole "
                       "periods of the steady motion (a TOML experiment file), or use IDIM or DIDIM")


def _fourier_start(t, q, f0, K):
    """The Fourier basis and its derivatives, and the least-squares coefficients of q (the start)."""
    m = 2 * K + 1
    B, Bd, Bdd = fourier_basis(t, f0, K)
    C0, res, rank, _ = np.linalg.lstsq(B, q, rcond=None)
    if rank < m:
        raise InputError(f"the recording cannot separate {K} harmonics of f0 = {f0:g} Hz (rank {rank} < {m}); "
                         "record at least one full period, or fit fewer harmonics (--ml-harmonics on the "
                         "command line, ml_harmonics= in Python)")
    return B, Bd, Bdd, C0


def _sigma_q(q, B, C0, sigma_q, m):
    """sigma_q given, or from the residual of the Fourier fit of q."""
    N, n = q.shape
    if sigma_q is not None:
        return _sig(sigma_q, n, "sigma_q")
    resid_q = q - B @ C0
    sq = np.sqrt(np.sum(resid_q ** 2, axis=0) / (N - m))
    if not np.all(sq > 0):
        raise InputError("q is exactly a Fourier series of f0 (no position noise to estimate sigma_q from: "
                         "a simulation without noise?); add the measurement noise, or call "
                         "dynid.analysis.estimators.maximum_likelihood.maximum_likelihood(..., sigma_q=...) "
                         "with the encoders' noise level")
    return sq


def _kept_equations(t, qdf, qd_threshold, reversal_guard, K, f0, p):
    """Torque equations outside the velocity dead zone and away from velocity reversals."""
    keep = ~velocity_dead_zone(qdf, qd_threshold, fraction=ML_DEAD_ZONE_FRACTION)
    auto = reversal_guard == "auto"
    if auto:
        reversal_guard = 1.0 / (4.0 * K * f0)
    keep &= _reversal_guard(t, qdf, float(reversal_guard))
    if np.any(keep.sum(axis=0) < 2 * p):
        # say what removed the equations: the dead zone, the guard around reversals, or a short record
        j = int(np.argmin(keep.sum(axis=0)))
        in_dead = int((~velocity_dead_zone(qdf, qd_threshold, fraction=ML_DEAD_ZONE_FRACTION))[:, j].sum())
        raise InputError(f"maximum likelihood keeps {int(keep[:, j].sum())} of {keep.shape[0]} torque equations "
                         f"of joint {j + 1} (the velocity dead zone leaves {in_dead}, the guard around velocity "
                         f"reversals takes the rest) but needs at least {2 * p}: give a longer recording "
                         f"(more periods of the excitation), or use IDIM (--method idim, method='idim')")
    both = int(keep.all(axis=1).sum())
    if both < 2 * p:
        # the start (and the sample set) needs samples where every joint's equation is kept
        raise InputError(f"maximum likelihood keeps {both} of {keep.shape[0]} samples with every joint's torque "
                         f"equation (no joint within {float(reversal_guard):.3g} s of a velocity reversal"
                         + (f", 1 / (4 K f0) with K = {K} harmonics" if auto else "")
                         + f", nor in its dead zone) but needs at least {2 * p}: "
                         + ("fit more harmonics (--ml-harmonics, ml_harmonics=: the guard shrinks as 1/K), "
                            if auto else "a shorter reversal_guard, ")
                         + "a longer recording, or IDIM (--method idim, method='idim')")
    return keep


def _reporting(residual, progress, it, passes, max_nfev):
    """`residual`, reporting at each call the share of the passes' evaluation budget spent."""
    calls = itertools.count(1)

    def counted(x):
        progress(min(1.0, (it + next(calls) / max_nfev) / passes))
        return residual(x)
    return counted


def _optimise(model, t, q, tau, f0, K, sq, st, keep, x, passes, max_nfev, dof_tau, progress=None):
    """Minimise eq. (13); between passes sigma_tau is re-estimated from the torque residual.

    Returns the last solution, its problem, sigma_tau and the number of evaluations.
    """
    n_eval = 0
    for it in range(passes):
        prob = _Problem(model, t, q, tau, f0, K, sq, st, keep)
        residual = prob.residual if progress is None else _reporting(prob.residual, progress, it, passes, max_nfev)
        sol = optimize.least_squares(residual, x, jac=prob.jacobian, method="trf",
                                     x_scale="jac", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10)
        n_eval += sol.nfev
        if not np.all(np.isfinite(sol.x)):
            raise ConvergenceError("maximum likelihood: the optimiser returned non-finite parameters")
        x = sol.x
        if it + 1 < passes:
            th, C = prob.split(x)
            ql, qdl, qddl = prob.kin(C)
            rt = keep * (tau - model.predict(th, ql, qdl, qddl))
            st = np.sqrt(np.sum(rt ** 2, axis=0) / dof_tau)
    if progress is not None:
        progress(1.0)
    return sol, prob, st, n_eval
