"""Joint controller gains identified from a closed-loop recording (reference, position, torque).

DIDIM (Gautier, Janot & Vandanjon 2010, section 3) simulates the robot under its
controller; the paper assumes the gains are known. When the controller's
*structure* is known but not its gains, and the reference ``qr`` is logged, the
gains follow from the control law itself, which is linear in them. Per joint
``j``, at the controller samples (the law of :mod:`dynid.dynamics.simulation`)::

    tau_j = Kp_j e_j + Kd_j (c qdr_j - qd_j) + Ki_j I_j + b_j,   e = qr - q,  I_k = T sum_{i<=k} e_i

with ``c = 1`` when the controller feeds the reference velocity forward and 0
otherwise, and ``b_j`` the unknown initial state of the integral (PID only).
Ordinary least squares on these columns (statsmodels OLS, Newey-West HAC
covariance because the residual of a closed loop is coloured) gives the gains and
their standard deviations. In dynid's normalised form (eq. (30)) they are
``kv = Kd g_ap / (g J_ap)``, ``kp = Kp / Kd``, ``wn = sqrt(kp kv)``,
``zeta = kv / (2 wn)``, ``ki = Ki g_ap / (g J_ap)``, with the robot file's ``J_ap``,
``g_ap`` and drive gain ``g``: only the products are determined, which is all
the simulation uses.

q, qr and tau go through the same zero-phase low-pass (parallel filtering: the
law, linear and time-invariant, holds between the filtered signals exactly).
Encoder noise in q is noise in the regressors e, qd and I, which biases least
squares towards zero gains (errors in variables; on a stiff joint whose velocity
error is small, Kd by tens of %). The bias is removed by corrected least squares
(Fuller 1987, ch. 2): ``(X'X - X_n'X_n) beta = X'y``, with ``X_n'X_n`` the Gram
matrix of the regressors built from white noise of the encoder noise level
(estimated from the band above fs/4, where the motion has nothing, unless
``noise_q`` is given) through the same processing.

Samples where the torque is within 0.1 % of ``tau_max`` (saturation) and the
filter transients at both ends are left out.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.results import ParameterResults
from dynid.errors import DataError, InputError

__all__ = ["GainsResult", "identify_gains"]


@dataclass(eq=False)
class GainsResult(ParameterResults):
    """Identified controller gains per joint (``Kp1, Kd1[, Ki1], ...``), physical units."""

    names: list
    chi: np.ndarray
    cov: np.ndarray
    n_joints: int
    feedforward: bool
    integral: bool
    rel_error: np.ndarray            # per joint ||tau - tau_hat|| / ||tau|| of the control law fit
    n_rows: int
    source: str = ""
    notices: list = field(default_factory=list)

    method = "controller gains (LS on the control law)"

    def gain(self, kind: str) -> np.ndarray:
        """``Kp``, ``Kd`` or ``Ki`` of every joint (zeros for ``Ki`` of a PD)."""
        out = np.zeros(self.n_joints)
        for j in range(self.n_joints):
            name = f"{kind}{j + 1}"
            if name in self.names:
                out[j] = self.chi[self.names.index(name)]
        return out

    def controller(self, robot):
        """The robot's controller with these gains (same rate, J_ap, g_ap, kind)."""
        c = robot.controller
        g = np.array([jt.drive_gain for jt in robot.joints], dtype=float)
        J_ap = np.asarray(c.J_ap, dtype=float)
        g_ap = np.ones(self.n_joints) if c.g_ap is None else np.asarray(c.g_ap, dtype=float)
        Kp, Kd, Ki = self.gain("Kp"), self.gain("Kd"), self.gain("Ki")
        if np.any(Kd <= 0) or np.any(Kp <= 0):
            bad = [f"joint {j + 1}" for j in range(self.n_joints) if Kd[j] <= 0 or Kp[j] <= 0]
            raise DataError(f"{self.source}: the identified gains of {', '.join(bad)} are not positive "
                            "(Kp, Kd): the recording does not follow the controller law assumed "
                            "(check the reference column qr and [controller] kind in the robot file)")
        kv = Kd * g_ap / (g * J_ap)
        kp = Kp / Kd
        wn = np.sqrt(kp * kv)
        zeta = kv / (2.0 * wn)
        ki = Ki * g_ap / (g * J_ap) if self.integral else c.ki
        return dataclasses.replace(c, wn=wn, zeta=zeta, ki=ki)

    def summary(self) -> str:
        lines = [f"Controller gains identified from {self.source} ({self.n_rows} samples; "
                 f"feedforward {'yes' if self.feedforward else 'no'}, integral {'yes' if self.integral else 'no'})",
                 f"  {'gain':<8}{'value':>14}{'std':>12}{'%std':>8}"]
        for n, v, s, r in zip(self.names, self.chi, self.bse, self.rel_std):
            unit = {"Kp": "N m/rad", "Kd": "N m s/rad", "Ki": "N m/(rad s)"}[n[:2]]
            lines.append(f"  {n:<8}{v:>14.6g}{s:>12.3g}{r:>8.2f}  {unit}")
        lines.append("  control-law fit, relative error per joint: "
                     + ", ".join(f"{x:.3%}" for x in self.rel_error))
        lines += [f"  note: {x}" for x in self.notices]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        from dynid.provenance import json_safe
        return json_safe({"method": self.method, "source": self.source, "feedforward": self.feedforward,
                          "integral": self.integral, "n_rows": self.n_rows,
                          "parameters": [{"name": n, "value": v, "std": s, "rel_std_percent": r}
                                         for n, v, s, r in zip(self.names, self.chi, self.bse, self.rel_std)],
                          "control_law_rel_error": self.rel_error, "notices": self.notices})


def _noise_moments(fs, fc, *, N, T):
    """Second moments of unit white noise after dynid's filter and differentiation, per sample.

    For white noise n of unit variance, the filtered position n_f = H n, its derivative
    D H n and its running sum S(n_f) = T sum n_f have, at sample k (k from the start):
    E[n_f^2] = sum h^2, E[(D n_f)^2] = sum (Dh)^2, E[n_f D n_f] = sum h Dh (0 for a
    zero-phase filter), E[S_k n_f,k] = T sum_{m<=k} r(m), E[S_k D n_f,k] = T sum_{m<=k} c(m),
    E[S_k^2] = T^2 ((k+1) r(0) + 2 sum_{m=1..k} (k+1-m) r(m)), with r the autocorrelation of
    h and c the cross-correlation of h and Dh. Exact where the filter is away from the ends.
    """
    from dynid.analysis.processing.signals import derivatives
    L = int(8 * fs / fc) + 8
    impulse = np.zeros((2 * L + 1, 1))
    impulse[L] = 1.0
    h_f, h_d, _ = derivatives(impulse, fs, fc)
    h, dh = h_f[:, 0], h_d[:, 0]
    r = np.correlate(h, h, mode="full")[2 * L:]              # r(m), m = 0 .. 2L
    c_rev = np.correlate(dh, h, mode="full")[2 * L:]          # E[n_f(k - m) Dn_f(k)], m >= 0
    k = np.arange(N)
    m_r = np.zeros(N)
    m_r[:min(N, r.size)] = r[:min(N, r.size)]
    m_c = np.zeros(N)
    m_c[:min(N, c_rev.size)] = c_rev[:min(N, c_rev.size)]
    cum_r = np.cumsum(m_r)                                   # sum_{m<=k} r(m)
    cum_mr = np.cumsum(k * m_r)
    ss = T ** 2 * ((k + 1) * m_r[0] + 2 * ((k + 1) * (cum_r - m_r[0]) - (cum_mr)))
    return {"ee": float(h @ h), "dd": float(dh @ dh), "ed": float(h @ dh),
            "se": T * cum_r, "sd": T * np.cumsum(m_c), "ss": ss}


def _noise_gram(mom, cols, rows) -> np.ndarray:
    """E[X_n' X_n] over ``rows`` for the columns ``cols`` built from unit encoder noise."""
    # the noise enters e = qr - q as -n_f, -qd as -D n_f, I as -S(n_f); ff, b and c hold none
    n_rows = float(np.count_nonzero(rows))
    entry = {("Kp", "Kp"): mom["ee"] * n_rows, ("Kd", "Kd"): mom["dd"] * n_rows,
             ("Kp", "Kd"): mom["ed"] * n_rows,
             ("Ki", "Ki"): float(mom["ss"][rows].sum()), ("Kp", "Ki"): float(mom["se"][rows].sum()),
             ("Kd", "Ki"): float(mom["sd"][rows].sum())}
    G = np.zeros((len(cols), len(cols)))
    for a, ca in enumerate(cols):
        for b, cb in enumerate(cols):
            G[a, b] = entry.get((ca, cb), entry.get((cb, ca), 0.0))
    return G


def _hac_lags(n_rows: int) -> int:
    # Newey & West's rule of thumb 4 (N/100)^(2/9)
    return max(1, int(math.floor(4.0 * (n_rows / 100.0) ** (2.0 / 9.0))))


def position_noise_level(q, fs) -> np.ndarray:
    """Per-joint standard deviation of white noise on ``q``, from its content above fs/4.

    The estimator (power above fs/4 after dynid's zero-phase low-pass) is
    calibrated on unit white noise, so it is unbiased for white noise.
    """
    from dynid.analysis.processing.signals import lowpass_filtfilt
    q = np.asarray(q, dtype=float)
    f1 = 0.25 * fs
    cut = max(20, q.shape[0] // 100)
    high = (q - lowpass_filtfilt(q, fs, f1))[cut:-cut]
    w = np.random.default_rng(0).normal(size=(q.shape[0], 1))
    unit = (w - lowpass_filtfilt(w, fs, f1))[cut:-cut]
    return np.sqrt(np.mean(high ** 2, axis=0) / np.mean(unit ** 2))


def identify_gains(experiment, robot, *, feedforward="auto", integral="auto", fc=None,
                   noise_q="auto") -> GainsResult:
    """Gains ``Kp, Kd (, Ki)`` of every joint from ``experiment`` (needs ``qr``); see the module doc.

    ``feedforward``: True, False or ``"auto"`` (both columns fitted; the reference
    velocity is fed forward when its coefficient is closer to Kd than to 0).
    ``integral``: True, False or ``"auto"`` (the robot file's controller kind, pid or pd).
    ``fc``: cut-off (Hz) of the parallel zero-phase filter (default: dynid's
    position filter for these data). ``noise_q``: encoder noise (rad, scalar or per
    joint), ``"auto"`` or None (estimated) or 0 (plain least squares).
    """
    import statsmodels.api as sm

    from dynid.analysis.processing.signals import default_settings, derivatives, lowpass_filtfilt
    if robot.controller is None:
        raise InputError(f"robot '{robot.name}' ({robot.source}) has no [controller] table: the gains "
                         "are identified for a known controller structure; add one")
    if experiment.qr is None:
        raise DataError(f"{experiment.source}: no reference column (qr1..qr{robot.n_joints}): the controller "
                        "gains cannot be identified without the reference the controller tracked; DIDIM "
                        "then depends on the gains assumed in the robot file")
    n, fs, T = robot.n_joints, float(experiment.fs), 1.0 / float(experiment.fs)
    if integral == "auto":
        integral = robot.controller.kind == "pid"
    fc = default_settings(fs, experiment.q)["fc_position"] if fc is None else float(fc)
    # Parallel filtering: q, qr and tau through the same zero-phase low-pass. The law is linear
    # and time-invariant, so it holds between the filtered signals exactly, while the encoder
    # noise above fc leaves the regressors (noise in a regressor biases its gain towards zero)
    # and no loop dynamics are lost from one side only.
    q_f, qd, _ = derivatives(experiment.q, fs, fc)
    qr_f, qdr, _ = derivatives(experiment.qr, fs, fc)
    tau_f = lowpass_filtfilt(experiment.tau, fs, fc)
    e = qr_f - q_f
    tau = experiment.tau
    if noise_q is None or (isinstance(noise_q, str) and noise_q == "auto"):
        sigma_q = position_noise_level(experiment.q, fs)
    else:
        if isinstance(noise_q, (str, bool)):
            raise InputError(f"noise_q must be 'auto', 0 or the encoder noise in rad, not {noise_q!r}")
        sigma_q = np.broadcast_to(np.asarray(noise_q, dtype=float), (robot.n_joints,))
        if not np.all(np.isfinite(sigma_q)) or np.any(sigma_q < 0):
            raise InputError(f"noise_q must be finite and >= 0 (rad), got {noise_q!r}")
    moments = _noise_moments(fs, fc, N=experiment.q.shape[0], T=T)
    N = tau.shape[0]
    edge = max(10, int(4 * fs / fc))
    keep = np.zeros(N, bool)
    keep[edge:N - edge] = True
    tau_max = np.array([jt.tau_max if jt.tau_max else np.inf for jt in robot.joints], dtype=float)
    notices = []
    sat = np.abs(tau) >= 0.999 * tau_max
    if sat.any():
        notices.append(f"{int(sat.any(axis=1).sum())} saturated samples left out")
    def fit(j, mode):
        rows = keep & ~sat[:, j]
        if rows.sum() < 50:
            raise DataError(f"{experiment.source}: joint {j + 1} has only {int(rows.sum())} unsaturated "
                            "samples away from the ends; the gains cannot be identified")
        cols = {"Kp": e[:, j]}
        if mode == "free":             # feedforward coefficient fitted on its own, to decide
            cols["Kd"], cols["ff"] = -qd[:, j], qdr[:, j]
        else:
            cols["Kd"] = (qdr[:, j] - qd[:, j]) if mode else -qd[:, j]
        if integral:
            cols["Ki"] = np.cumsum(e[:, j]) * T
            cols["b"] = np.ones(N)
        X = np.column_stack(list(cols.values()))[rows]
        y = tau_f[rows, j]
        # the same columns built from the noise alone (its part of e, -qd and I; none in qr)
        G = sigma_q[j] ** 2 * _noise_gram(moments, list(cols), rows)
        res = sm.OLS(y, X).fit(cov_type="HAC", cov_kwds={"maxlags": _hac_lags(int(rows.sum()))})
        beta = np.linalg.solve(X.T @ X - G, X.T @ y)
        # covariance: the HAC sandwich of the LS fit, with the corrected bread
        A = np.linalg.inv(X.T @ X - G)
        B = np.linalg.inv(X.T @ X)
        cov = A @ (np.linalg.inv(B) @ np.asarray(res.cov_params()) @ np.linalg.inv(B)) @ A
        return list(cols), beta, cov, float(np.linalg.norm(y - X @ beta) / np.linalg.norm(y))

    use_ff = feedforward
    if feedforward == "auto":
        # fed forward when the reference velocity's coefficient is nearer Kd than 0 on most joints
        votes = []
        for j in range(n):
            cols, beta, _, _ = fit(j, "free")
            kd, ff = beta[cols.index("Kd")], beta[cols.index("ff")]
            votes.append(abs(ff - kd) < abs(ff))
        use_ff = sum(votes) > n / 2
    out_names, out_vals, blocks, rel = [], [], [], []
    for j in range(n):
        cols, beta, cov, r = fit(j, bool(use_ff))
        idx = [k for k, c in enumerate(cols) if c in ("Kp", "Kd", "Ki")]
        out_names += [f"{cols[k]}{j + 1}" for k in idx]
        out_vals += [beta[k] for k in idx]
        blocks.append(cov[np.ix_(idx, idx)])
        rel.append(r)
    from scipy.linalg import block_diag
    return GainsResult(names=out_names, chi=np.array(out_vals), cov=block_diag(*blocks), n_joints=n,
                       feedforward=bool(use_ff), integral=bool(integral), rel_error=np.array(rel),
                       n_rows=int(keep.sum()), source=str(experiment.source), notices=notices)
