"""Joint controller gains identified from a closed-loop recording (reference, position, torque).

DIDIM (Gautier, Janot & Vandanjon 2010, section 3) simulates the robot under its
controller; the paper assumes the gains are known. When the controller's
*structure* is known but not its gains, and the reference `qr` is logged, the
gains follow from the control law itself, which is linear in them. Per joint
`j`, at the controller samples (the law of `dynid.dynamics.simulation`)::

    tau_j = Kp_j e_j + Kd_j (c qdr_j - qd_j) + Ki_j I_j + b_j,   e = qr - q,  I_k = T sum_{i<=k} e_i

with `c = 1` when the controller feeds the reference velocity forward and 0
otherwise, and `b_j` the unknown initial state of the integral (PID only).
The controller's velocity is rarely the central derivative of q: a backward
difference lags it by T/2, a semi-implicit integrator's state by half a step, an
observer by its delay `delta`. `Kd qd(t - delta) = Kd qd - Kd delta qdd`, so a
column `qdd` with coefficient `Ka = Kd delta` absorbs the lag (without it, a lag
of 25 us biased Kp1 by +1 % on the TX40 plant, noise-free).
In dynid's normalised form (eq. (30)) they are
`kv = Kd g_ap / (g J_ap)`, `kp = Kp / Kd`, `wn = sqrt(kp kv)`,
`zeta = kv / (2 wn)`, `ki = Ki g_ap / (g J_ap)`, with the robot file's `J_ap`,
`g_ap` and drive gain `g`: only the products are determined, which is all
the simulation uses.

q, qr and tau go through the same zero-phase low-pass (parallel filtering: the
law, linear and time-invariant, holds between the filtered signals exactly).
Encoder noise in q is noise in the regressors e, qd and I, which biases least
squares towards zero gains (errors in variables; on a stiff joint whose velocity
error is small, Kd by tens of %). The bias is removed by corrected least squares
(Fuller 1987, ch. 2): `(X'X - X_n'X_n) beta = X'y`, with `X_n'X_n` the Gram
matrix of the regressors built from white noise of the encoder noise level
(estimated from the band above fs/4, where the motion has nothing, unless
`noise_q` is given) through the same processing.

Samples where the torque is within 0.1 % of `tau_max` (saturation) and the
filter transients at both ends are left out.

The equation error of that fit is the controller applied to the encoder noise,
`K(s) n`, whose power grows as `(Kd w)^2`: Kd is drawn from the band where the
noise is strongest. The second pass is generalised least squares: the law and its
columns filtered by `F = 1 / K(s)` of the first pass (bilinear, causal; the law,
LTI, still holds), whose error is about `n`, with the noise Gram recomputed through
F. The integral column becomes stationary and the initial state `b` dies out with
F's transient (skipped on a joint with saturated samples, where F would smear the
samples where the law does not hold). On the TX40 plant this took the sigma of Kd1
from 1.3-2 % to 0.3-0.55 %.

The covariance is the sandwich of the corrected estimating equation with a
Newey-West window spanning the filters' memory. Measured over 12 plant seeds its
z-scores have an rms of 0.9-1.6 (Kd worst): the sigma is up to ~1.5x optimistic.
It does not include the error of the estimated noise level (which moves the
correction), of the first-pass gains inside F, nor any departure from the assumed
law (saturation left out, anti-windup, a velocity filter other than a pure lag).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import block_diag
from scipy.signal import bilinear, lfilter

from dynid.analysis.processing.signals import default_settings, derivatives, lowpass_filtfilt
from dynid.analysis.results import ParameterResults, notices_block, parameter_records, parameter_table, percent
from dynid.errors import DataError, InputError
from dynid.provenance import json_safe

__all__ = ["GainsResult", "identify_gains"]


#: a joint whose control-law fit leaves more than this of its torque unexplained has no gains
MAX_LAW_ERROR = 1.0
#: %sigma above which an identified Kp or Kd is not told from 0
MAX_GAIN_REL_STD = 100.0


@dataclass(eq=False, repr=False)
class GainsResult(ParameterResults):
    """Identified controller gains per joint (`Kp1, Kd1[, Ki1], ...`), physical units."""

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
        """`Kp`, `Kd` or `Ki` of every joint (zeros for `Ki` of a PD)."""
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
        lost = self.unidentified()
        if lost:
            raise DataError(f"{self.source}: the controller gains of " + "; ".join(lost) + ": a loop simulated "
                            "with them is another robot's. Saturated samples, or a law other than the robot "
                            "file's [controller] kind, cause this; give the gains in the robot file's "
                            "[controller] and leave out --gains identify (gains='file')")
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

    def unidentified(self) -> list:
        """The joints whose gains this recording does not determine, each with why: the control
        law explains none of its torque (relative error above `MAX_LAW_ERROR`), or Kp or Kd is
        not told from 0 (%sigma above `MAX_GAIN_REL_STD`). Independent plant, held-out seed 15160
        of benchmarks/coverage_didim.py: joint 2, saturated, 1147 % and Kp2 %sigma 8.8e4, gave a
        loop that diverged in 9 ms; on seeds 15200-15219 (DIDIM converged on all) every joint stays
        at or below 44 % and 7.5 %sigma."""
        rel = dict(zip(self.names, self.rel_std.to_numpy()))
        out = []
        for j in range(self.n_joints):
            why = []
            if not self.rel_error[j] <= MAX_LAW_ERROR:
                why.append(f"the control law leaves {percent(self.rel_error[j], 0)} of its torque unexplained")
            gains = [f"{k}{j + 1}" for k in ("Kp", "Kd") if f"{k}{j + 1}" in rel]
            bad = [f"{g} %sigma {rel[g]:.2g}" for g in gains if not rel[g] <= MAX_GAIN_REL_STD]
            if bad:
                why.append(", ".join(bad))
            if why:
                out.append(f"joint {j + 1} are not identified ({'; '.join(why)})")
        return out

    def summary(self) -> str:
        lines = [f"Controller gains identified from {self.source} ({self.n_rows} samples; "
                 f"feedforward {'yes' if self.feedforward else 'no'}, integral {'yes' if self.integral else 'no'})",
                 ]
        lines += parameter_table(self.names, [("value", self.chi, lambda x: f"{x:.6g}"),
                                              ("std", self.bse.to_numpy(), lambda x: f"{x:.3g}"),
                                              ("%std", self.rel_std.to_numpy(), "pct")], label="gain",
                                             prismatic=self._prismatic())
        lines.append("control-law fit, relative error per joint: "
                     + ", ".join(percent(x, 3) for x in self.rel_error))
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return json_safe({"method": self.method, "source": self.source, "feedforward": self.feedforward,
                          "integral": self.integral, "n_rows": self.n_rows,
                          "parameters": parameter_records(self.names, self.chi, self.bse, self.rel_std),
                          "control_law_rel_error": self.rel_error, "notices": self.notices})


def _noise_moments(fs, fc, *, N, T):
    """Second moments of the regressor columns built from unit white encoder noise, per sample.

    White noise n of unit variance enters the columns through stationary filters: e as
    `-H n`, the velocity column as `-D H n`, the acceleration column as `+D^2 H n`
    (H dynid's zero-phase low-pass, D its central difference), and the integral column
    as the running sum `S = -T sum_{i<=k} H n_i`. For two stationary columns with
    impulse responses f_a, f_b, `E[x_a x_b] = sum f_a f_b`; with the integral,
    `E[S_k x_b,k] = T sum_{m<=k} R(m)`, R the cross-correlation of the filter of e and
    f_b, and `E[S_k^2] = T^2 ((k+1) r(0) + 2 sum_{m=1..k} (k+1-m) r(m))`, r the
    autocorrelation of H. Exact where the filter is away from the ends.
    """
    L = int(8 * fs / fc) + 8
    impulse = np.zeros((2 * L + 1, 1))
    impulse[L] = 1.0
    h_f, h_d, h_a = (x[:, 0] for x in derivatives(impulse, fs, fc))
    filt = {"Kp": -h_f, "Kd": -h_d, "ff": np.zeros_like(h_f), "Ka": h_a}
    k = np.arange(N)
    lagged = {}
    for name, f in filt.items():
        R = np.correlate(f, filt["Kp"], mode="full")[2 * L:]  # E[e_noise(k - m) x_noise(k)], m >= 0
        m = np.zeros(N)
        m[:min(N, R.size)] = R[:min(N, R.size)]
        lagged[name] = T * np.cumsum(m)                       # E[S_k x_k] (the sign of e inside R)
    r = np.zeros(N)
    rh = np.correlate(h_f, h_f, mode="full")[2 * L:]
    r[:min(N, rh.size)] = rh[:min(N, rh.size)]
    cum_r = np.cumsum(r)
    ss = T ** 2 * ((k + 1) * r[0] + 2 * ((k + 1) * (cum_r - r[0]) - np.cumsum(k * r)))
    return {"filters": filt, "lagged": lagged, "ss": ss, "integral": -T * np.cumsum(h_f)}


def _whitening_filter(Kp, Kd, Ki, fs):
    """Discrete (bilinear) `F(s) = 1 / K(s)`, K = Kp + Kd s (+ Ki / s): (b, a) for lfilter."""
    if Ki > 0:
        return bilinear([1.0, 0.0], [Kd, Kp, Ki], fs)
    return bilinear([1.0], [Kd, Kp], fs)


def _whitened_gram(mom, cols, n_rows, ba, settle) -> np.ndarray:
    """E[X_n' X_n] of the columns built from unit encoder noise, after the whitening filter."""
    base = dict(mom["filters"], Ki=mom["integral"])
    f = {}
    for c in cols:
        if c in base:
            x = np.concatenate([base[c], np.full(settle, base[c][-1])])
            f[c] = lfilter(*ba, x)
    return np.array([[float(f[a] @ f[b]) * n_rows if a in f and b in f else 0.0 for b in cols]
                     for a in cols])


def _noise_gram(mom, cols, rows) -> np.ndarray:
    """E[X_n' X_n] over `rows` for the columns `cols` built from unit encoder noise."""
    # ff and b hold no noise (the reference is exact; b is the integral's initial state)
    n_rows = float(np.count_nonzero(rows))
    filt = mom["filters"]

    def entry(a, b):
        if a == "Ki" and b == "Ki":
            return float(mom["ss"][rows].sum())
        if "Ki" in (a, b):
            other = b if a == "Ki" else a
            return float(mom["lagged"][other][rows].sum()) if other in filt else 0.0
        if a in filt and b in filt:
            return float(filt[a] @ filt[b]) * n_rows
        return 0.0
    return np.array([[entry(a, b) for b in cols] for a in cols])


def _newey_west(psi, lags) -> np.ndarray:
    """Newey-West long-run covariance `sum_|l|<=L w_l sum_k psi_k+l psi_k'`, Bartlett weights.

    The lagged sums come from one FFT cross-correlation of the columns (the window spans
    the filters' memory, hundreds to thousands of samples).
    """
    N = psi.shape[0]
    lags = int(min(lags, N - 1))
    P = np.fft.rfft(psi, n=2 * N, axis=0)
    C = np.fft.irfft(P[:, :, None] * np.conj(P[:, None, :]), n=2 * N, axis=0)   # C[l] = sum psi_k+l psi_k'
    w = 1.0 - np.arange(1, lags + 1) / (lags + 1.0)
    pos = np.tensordot(w, C[1:lags + 1], axes=(0, 0))
    return C[0] + pos + pos.T


def _hac_lags(n_rows: int) -> int:
    # Newey & West's rule of thumb 4 (N/100)^(2/9)
    return max(1, int(math.floor(4.0 * (n_rows / 100.0) ** (2.0 / 9.0))))


def position_noise_level(q, fs) -> np.ndarray:
    """Per-joint standard deviation of white noise on `q`, from its content above fs/4.

    The estimator (power above fs/4 after dynid's zero-phase low-pass) is
    calibrated on unit white noise, so it is unbiased for white noise.
    """
    q = np.asarray(q, dtype=float)
    f1 = 0.25 * fs
    cut = max(20, q.shape[0] // 100)
    high = (q - lowpass_filtfilt(q, fs, f1))[cut:-cut]
    w = np.random.default_rng(0).normal(size=(q.shape[0], 1))
    unit = (w - lowpass_filtfilt(w, fs, f1))[cut:-cut]
    return np.sqrt(np.mean(high ** 2, axis=0) / np.mean(unit ** 2))


def _check_noise_q(noise_q, n):
    """The encoder noise given (rad, per joint), or None to estimate it."""
    if noise_q is None or (isinstance(noise_q, str) and noise_q == "auto"):
        return None
    if isinstance(noise_q, (str, bool)):
        raise InputError(f"noise_q must be 'auto', 0 or the encoder noise in rad, not {noise_q!r}")
    sigma_q = np.broadcast_to(np.asarray(noise_q, dtype=float), (n,))
    if not np.all(np.isfinite(sigma_q)) or np.any(sigma_q < 0):
        raise InputError(f"noise_q must be finite and >= 0 (rad), got {noise_q!r}")
    return sigma_q


@dataclass
class _GainsFit:
    """The filtered signals of one recording and what every per-joint fit of the control law shares."""

    e: np.ndarray                # qr - q, filtered
    qd: np.ndarray
    qdd: np.ndarray
    qdr: np.ndarray
    tau_f: np.ndarray            # torque, filtered
    T: float                     # controller period (s)
    keep: np.ndarray             # rows away from the filter transients at both ends
    sat: np.ndarray              # saturated samples (per joint)
    sigma_q: np.ndarray          # encoder noise (rad, per joint)
    moments: object              # _noise_moments of the processing
    edge: int
    hac_lags: int
    integral: bool
    velocity_lag: bool
    source: str

    def columns(self, j, mode):
        """The regressors of joint j's control law; mode "free", True (fed forward) or False."""
        N = self.e.shape[0]
        cols = {"Kp": self.e[:, j]}
        if self.velocity_lag:
            # the controller's velocity lags the central derivative of q by some delta (a
            # backward difference T/2, a semi-implicit integrator's h/2, an observer):
            # Kd qd(t - delta) = Kd qd - Kd delta qdd, linear in Ka = Kd delta
            cols["Ka"] = self.qdd[:, j]
        if mode == "free":             # feedforward coefficient fitted on its own, to decide
            cols["Kd"], cols["ff"] = -self.qd[:, j], self.qdr[:, j]
        else:
            cols["Kd"] = (self.qdr[:, j] - self.qd[:, j]) if mode else -self.qd[:, j]
        if self.integral:
            cols["Ki"] = np.cumsum(self.e[:, j]) * self.T
            cols["b"] = np.ones(N)
        return cols

    def fit(self, j, mode, wf=None):
        """Corrected least squares of joint j's law (`wf`: the whitening filter and its settling)."""
        rows = self.keep & ~self.sat[:, j]
        if rows.sum() < 50:
            raise DataError(f"{self.source}: joint {j + 1} has only {int(rows.sum())} unsaturated "
                            "samples away from the ends; the gains cannot be identified")
        cols = self.columns(j, mode)
        if wf is None:
            X = np.column_stack(list(cols.values()))[rows]
            y = self.tau_f[rows, j]
            # the same columns built from the noise alone (its part of e, -qd and I; none in qr)
            G = self.sigma_q[j] ** 2 * _noise_gram(self.moments, list(cols), rows)
        else:
            # Generalised least squares: the equation error is the controller applied to the
            # encoder noise, K(s) n, whose power grows as (Kd w)^2; the law filtered by
            # F = 1 / K(s) of the first estimate still holds exactly (LTI) and its error is
            # about n, white below fc. The integral column becomes stationary and the
            # integral's initial state b dies out with F's transient.
            ba, settle = wf
            cols.pop("b", None)
            Xf = lfilter(*ba, np.column_stack(list(cols.values())), axis=0)
            yf = lfilter(*ba, self.tau_f[:, j])
            rows = rows.copy()
            rows[:self.edge + settle] = False
            X, y = Xf[rows], yf[rows]
            G = self.sigma_q[j] ** 2 * _whitened_gram(self.moments, list(cols), float(rows.sum()), ba, settle)
        A = np.linalg.inv(X.T @ X - G)
        beta = A @ (X.T @ y)
        # Sandwich covariance of the corrected estimating equation X'(y - X beta) + G beta = 0:
        # its terms x_k u_k (centred: their mean is -G beta / N) are correlated over the
        # filter's memory, so the Newey-West window spans it (a window of a few samples, the
        # usual rule, made the reported sigma of Kp and Kd 3-10x too small).
        u = y - X @ beta
        psi = X * u[:, None]
        psi -= psi.mean(axis=0)
        cov = A @ _newey_west(psi, self.hac_lags + (0 if wf is None else 2 * wf[1])) @ A
        return list(cols), beta, cov, float(np.linalg.norm(y - X @ beta) / np.linalg.norm(y))


def _prepare(experiment, robot, fc, sigma_q, integral, velocity_lag):
    """Parallel filtering, the rows kept and the noise moments: the shared part of every fit."""
    fs, T = float(experiment.fs), 1.0 / float(experiment.fs)
    # Parallel filtering: q, qr and tau through the same zero-phase low-pass. The law is linear
    # and time-invariant, so it holds between the filtered signals exactly, while the encoder
    # noise above fc leaves the regressors (noise in a regressor biases its gain towards zero)
    # and no loop dynamics are lost from one side only.
    q_f, qd, qdd = derivatives(experiment.q, fs, fc)
    qr_f, qdr, _ = derivatives(experiment.qr, fs, fc)
    tau_f = lowpass_filtfilt(experiment.tau, fs, fc)
    tau = experiment.tau
    if sigma_q is None:
        sigma_q = position_noise_level(experiment.q, fs)
    moments = _noise_moments(fs, fc, N=experiment.q.shape[0], T=T)
    N = tau.shape[0]
    edge = max(10, int(4 * fs / fc))
    keep = np.zeros(N, bool)
    keep[edge:N - edge] = True
    tau_max = np.array([jt.tau_max if jt.tau_max else np.inf for jt in robot.joints], dtype=float)
    return _GainsFit(e=qr_f - q_f, qd=qd, qdd=qdd, qdr=qdr, tau_f=tau_f, T=T, keep=keep,
                     sat=np.abs(tau) >= 0.999 * tau_max, sigma_q=sigma_q, moments=moments, edge=edge,
                     hac_lags=max(_hac_lags(N), 2 * edge), integral=bool(integral),
                     velocity_lag=velocity_lag, source=experiment.source)


def _feedforward_vote(problem, n):
    """Fed forward when the reference velocity's coefficient is nearer Kd than 0 on most joints."""
    votes = []
    for j in range(n):
        cols, beta, _, _ = problem.fit(j, "free")
        kd, ff = beta[cols.index("Kd")], beta[cols.index("ff")]
        votes.append(abs(ff - kd) < abs(ff))
    return sum(votes) > n / 2


def _fit_joint(problem, j, use_ff, whiten, fs):
    """Joint j's first pass, then the whitened pass when it applies; (cols, beta, cov, r, whitened)."""
    cols, beta, cov, r = problem.fit(j, bool(use_ff))
    gains = {c: beta[cols.index(c)] for c in ("Kp", "Kd", "Ki") if c in cols}
    if not (whiten and not problem.sat[:, j].any() and gains["Kp"] > 0 and gains["Kd"] > 0
            and gains.get("Ki", 0) >= 0):
        return cols, beta, cov, r, not whiten
    # settle: ten time constants of F's slowest pole
    ba = _whitening_filter(gains["Kp"], gains["Kd"], gains.get("Ki", 0.0), fs)
    slowest = np.max(np.abs(np.roots(ba[1])))
    settle = int(10 / max(1e-12, -math.log(min(slowest, 1 - 1e-12)))) + 1
    if settle >= problem.e.shape[0] // 4:
        return cols, beta, cov, r, False
    # r stays the first pass's: the relative error of the law on the torque itself
    cols, beta, cov, _ = problem.fit(j, bool(use_ff), (ba, settle))
    return cols, beta, cov, r, True


def identify_gains(experiment, robot, *, feedforward="auto", integral="auto", fc=None,
                   noise_q="auto", velocity_lag=True,
                   whiten=True) -> GainsResult:
    """Gains Kp, Kd (, Ki) of every joint from `experiment` (needs `qr`); see the module docstring.

    Parameters
    ----------
    experiment : Experiment
        A closed-loop recording with the reference `qr`.
    robot : Robot
        With a [controller] table.
    feedforward : True, False or "auto"
        "auto": both columns fitted; the reference velocity is fed forward when
        its coefficient is closer to Kd than to 0.
    integral : True, False or "auto"
        "auto": the robot file's controller kind, pid or pd.
    fc : float, optional
        Cut-off (Hz) of the parallel zero-phase filter (default: dynid's
        position filter for these data).
    noise_q : "auto", None, 0 or float or array
        Encoder noise (rad, scalar or per joint); "auto" or None: estimated;
        0: plain least squares.
    velocity_lag : bool
        Fit the lag of the controller's velocity (column qdd).
    whiten : bool
        Second, generalised least-squares pass through 1 / K(s).

    Returns
    -------
    GainsResult

    Raises
    ------
    InputError
        No [controller] table, or a bad `noise_q`.
    DataError
        No reference column, or too few unsaturated samples on a joint.
    """
    if robot.controller is None:
        raise InputError(f"robot '{robot.name}' ({robot.source}) has no [controller] table: the gains "
                         "are identified for a known controller structure; add one")
    if experiment.qr is None:
        raise DataError(f"{experiment.source}: no reference column (qr1..qr{robot.n_joints}): the controller "
                        "gains cannot be identified without the reference the controller tracked; DIDIM "
                        "then depends on the gains assumed in the robot file")
    sigma_q = _check_noise_q(noise_q, robot.n_joints)
    n, fs = robot.n_joints, float(experiment.fs)
    if integral == "auto":
        integral = robot.controller.kind == "pid"
    fc = default_settings(fs, experiment.q)["fc_position"] if fc is None else float(fc)
    problem = _prepare(experiment, robot, fc, sigma_q, integral, velocity_lag)
    notices = []
    if problem.sat.any():
        notices.append(f"{int(problem.sat.any(axis=1).sum())} saturated samples left out")
    use_ff = _feedforward_vote(problem, n) if feedforward == "auto" else feedforward
    out_names, out_vals, blocks, rel, lag, plain = [], [], [], [], [], []
    for j in range(n):
        cols, beta, cov, r, whitened = _fit_joint(problem, j, use_ff, whiten, fs)
        if whiten and not whitened:
            plain.append(j + 1)
        if "Ka" in cols:
            lag.append(beta[cols.index("Ka")] / beta[cols.index("Kd")])
        idx = [k for k, c in enumerate(cols) if c in ("Kp", "Kd", "Ki")]
        out_names += [f"{cols[k]}{j + 1}" for k in idx]
        out_vals += [beta[k] for k in idx]
        blocks.append(cov[np.ix_(idx, idx)])
        rel.append(r)
    if plain:
        notices.append("not whitened (saturated samples, gains not positive or a transient too long): joint "
                       + ", ".join(map(str, plain)))
    notices.append("sigma: the sandwich of the fit, not including the error of the estimated encoder "
                   "noise level nor of the first-pass gains in the whitening (on a simulated plant the "
                   "errors were 0.9-1.6 sigma rms)")
    if lag:
        notices.append("velocity lag of the controller against the central derivative of q (us): "
                       + ", ".join(f"{1e6 * x:.1f}" for x in lag))
    return GainsResult(names=out_names, chi=np.array(out_vals), cov=block_diag(*blocks), n_joints=n,
                       feedforward=bool(use_ff), integral=bool(integral), rel_error=np.array(rel),
                       n_rows=int(problem.keep.sum()), source=str(experiment.source), notices=notices)
