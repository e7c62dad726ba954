"""The Projection Method for closed-loop identification (Bona & Curatella 2005, eqs. (10)-(12)).

Forssell & Ljung's two-stage method, as section 2.2 of the paper applies it:

1. **Sensitivity** (eq. (10)). Per joint, the torque (or control signal) u is
   fitted by least squares with a non-causal FIR filter of the reference r,
   `u(t) = c + sum_{k=-M1}^{M2} s_k r(t-k)`; the fit gives the estimated
   torque `u_hat = S_hat r` (eq. (11)), the part of u that the reference
   explains. Noise fed back through the controller is independent of r, so it
   stays in `u_tilde = u - u_hat`. A constant c is fitted too: gravity's mean
   and torque offsets are not a linear response to r, and without c the DC gain
   of the filter would have to absorb them.
2. **Open-loop identification with u_hat** (eq. (12)). The parameters are
   identified by IDIM least squares with u_hat in place of the measured torque.

Which regressor in stage 2, and why. The paper's eq. (12) is a forward model
`y = G u_hat` identified by an open-loop method; dynid's open-loop method is
the inverse model (IDIM), `u = W(q, qd, qdd) chi`. Regressing u_hat on W
built from the *measured* q is biased: W then holds the noise-driven part of
the motion (the controller's reaction to the noise moves the robot), which
u_hat, being a function of r alone, lacks; the estimate is attenuated like an
errors-in-variables fit. Building W from the *reference* is noise-free but
wrong by the tracking error, a bias that does not shrink with more data
(measured: 600 standard errors on the 1-DOF test case). So stage 2 projects
the regressor with the same filter space as the torque: each column of W^j is
replaced by its LS projection `W_hat^j = P_j W^j` on the lagged reference
of joint j, and `u_hat^j = P_j u^j = W_hat^j chi + P_j e^j` is solved by OLS
(`dynid.analysis.estimators.least_squares.ols`). This is two-stage least squares with the
lagged reference as instruments: `chi_hat = (W^T P W)^-1 W^T P u`, consistent
whenever the noise e is independent of r, whatever its colour and whether or
not the controller feeds it back. The paper's own implementation (FFT lines of
the excitation only, section 3.4) is the special case of a periodic r, whose
lag space is exactly the span of the excited harmonics.

Rows where a joint is nearly still (Coulomb friction's sign unreliable) are
zeroed in W and u *before* both are projected, as IDIM zeroes them before
decimation: the projection spreads every row over the whole recording, so a
sign error near a velocity reversal would otherwise reach every row.

Choice of M1, M2. Candidates form the nested family `(M1, M2) = (0, 0),
(1, 0), (1, 1), (2, 1), ...` (columns ordered c, r(t), r(t+1), r(t-1),
r(t+2), ...), so one column-pivot-free QR of the largest lag matrix gives the
residual sum of squares of every candidate (the squared tail of Q^T u). The
chosen order minimises BIC `N log(RSS/N) + p log N` (or AIC, `2 p`) on the
rows common to all candidates, with p the numerical rank of the candidate's
lag matrix (a periodic r with H harmonics has rank <= 2H + 1 whatever the
number of lags, so wider windows cost nothing once the harmonics are spanned).
Residual noise is coloured (the H2 e term of eq. (10)), so BIC tends to pick
slightly large windows; that costs variance, not bias. Asymmetric windows can
be given explicitly (`m1=`, `m2=`).

Paper's diagnostic. Eq. (11) asks M1, M2 "to avoid correlation between u_hat
and u_tilde". Their lag-0 correlation is zero by construction of LS (the paper
reports 2.9e-14); the result also gives the largest normalised
cross-correlation over lags |l| <= `xcorr_lags`, which is what a too-short
window leaves behind.

Standard deviations. The stage-2 OLS residual is P e, far smaller than e, so
the OLS covariance of eq. (14) would be badly optimistic. The covariance is
the IV sandwich `(W_hat^T W_hat)^-1 S (W_hat^T W_hat)^-1` with `S` the
Newey-West (Bartlett) long-run covariance of the scores `W_hat_t^T e_t`,
`e = u - W chi_hat` the structural residual: the noise here is coloured by
construction. Its bandwidth is twice the lag at which the residual's
autocorrelation first falls below 2/sqrt(N), capped at N/10.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.linalg as sla
from statsmodels.stats.sandwich_covariance import S_hac_simple, weights_bartlett

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.processing.observation import observe, resolve_settings
from dynid.analysis.processing.signals import default_position_cutoff
from dynid.analysis.results import (
    ParameterResults,
    deprecated_alias,
    identified_line,
    notices_block,
    parameter_table,
    percent,
)
from dynid.dynamics.base_parameters import base_parameters
from dynid.dynamics.robot import model_signature
from dynid.errors import InputError
from dynid.provenance import data_hash, json_safe, versions

__all__ = ["lag_matrix", "fit_fir", "select_fir_order", "FIRFit", "OrderSelection",
           "ProjectionResult", "projection_method", "identify_projection", "RANK_RTOL"]

#: Relative tolerance on |R_ii| / ||column i|| below which a lag column adds no
#: new direction (periodic references make most lag columns dependent).
RANK_RTOL = 1e-9
_WIDTH = 78


# ----------------------------------------------------------------------- inputs
def _array(name, x, ndim_ok, shape_doc):
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a numeric array of shape {shape_doc}") from None
    if a.ndim not in ndim_ok:
        raise InputError(f"{name} has shape {a.shape} but must have shape {shape_doc}")
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise InputError(f"{name} holds non-finite values (NaN or inf), first at index "
                         f"{tuple(int(i) for i in bad)}; fill or drop those samples first")
    return a


def _check_orders(m1, m2):
    for name, m in (("m1", m1), ("m2", m2)):
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 0:
            raise InputError(f"{name} must be a non-negative integer number of samples, got {m!r}")
    return int(m1), int(m2)


def lag_matrix(r, m1, m2, *, intercept=True):
    """Rows and columns of the FIR regression of eq. (10).

    `r`: (N,) or (N, m) references. Returns `(rows, R)`: `rows` the
    sample indices t = M2 .. N-1-M1 where every lag exists, `R` of shape
    (len(rows), [1 +] m (M1 + M2 + 1)) with columns `[1,] r(t+M1), ...,
    r(t), ..., r(t-M2)` (reference by reference).
    """
    m1, m2 = _check_orders(m1, m2)
    r = _array("r", r, (1, 2), "(N,) or (N, m)")
    r2 = r[:, None] if r.ndim == 1 else r
    N = r2.shape[0]
    n_rows = N - m1 - m2
    if n_rows < 1:
        raise InputError(f"the reference has {N} samples, too few for an FIR filter with "
                         f"M1 = {m1}, M2 = {m2}; record longer or lower M1, M2")
    rows = np.arange(m2, N - m1)
    cols = [np.ones(n_rows)] if intercept else []
    for i in range(r2.shape[1]):
        cols += [r2[rows - k, i] for k in range(-m1, m2 + 1)]
    return rows, np.column_stack(cols)


def _nested_lags(m_max):
    """Lags in the order of the nested candidate family: 0, -1, +1, -2, +2, ..."""
    out = [0]
    for k in range(1, m_max + 1):
        out += [-k, k]
    return out


def _orders_of(n_lags):
    """(M1, M2) of the candidate made of the first `n_lags` lags of `_nested_lags`."""
    m1 = n_lags // 2
    m2 = (n_lags - 1) // 2
    return m1, m2


@dataclass
class OrderSelection:
    """BIC/AIC over the nested FIR orders (see the module doc)."""

    criterion: str
    m1: int
    m2: int
    table: pd.DataFrame       # one row per candidate: m1, m2, rank, rss, aic, bic
    n_rows: int

    def to_dict(self):
        return json_safe({"criterion": self.criterion, "m1": self.m1, "m2": self.m2,
                          "n_rows": self.n_rows, "candidates": self.table.to_dict("records")})


def select_fir_order(r, u, *, max_lag=None, criterion="bic", rank_rtol=RANK_RTOL):
    """Choose (M1, M2) of eq. (10) for one joint by BIC (or AIC) over the nested family.

    `r`: (N,) reference (or (N, m) several references, all lagged alike),
    `u`: (N,) torque. `max_lag` (default `min(50, N // 20)`) bounds M1 and M2.
    All candidates are compared on the same rows (those of the widest window).
    """
    u = _array("u", u, (1,), "(N,)")
    r = _array("r", r, (1, 2), "(N,) or (N, m)")
    if r.shape[0] != u.shape[0]:
        raise InputError(f"r has {r.shape[0]} samples but u has {u.shape[0]}; they must be sampled together")
    if criterion not in ("bic", "aic"):
        raise InputError(f"criterion must be 'bic' or 'aic', got {criterion!r}")
    N = u.shape[0]
    if max_lag is None:
        max_lag = max(1, min(50, N // 20))
    if isinstance(max_lag, bool) or not isinstance(max_lag, (int, np.integer)) or max_lag < 0:
        raise InputError(f"max_lag must be a non-negative integer, got {max_lag!r}")
    max_lag = int(max_lag)
    r2 = r[:, None] if r.ndim == 1 else r
    m = r2.shape[1]
    lags = _nested_lags(max_lag)
    n_rows = N - 2 * max_lag
    n_cols = 1 + m * len(lags)
    if n_rows < 2 * n_cols:
        raise InputError(f"{N} samples are too few to choose an FIR order up to max_lag = {max_lag} "
                         f"({n_cols} coefficients need at least {2 * n_cols + 2 * max_lag} samples); "
                         "record longer or lower max_lag")
    rows = np.arange(max_lag, N - max_lag)
    cols = [np.ones(n_rows)] + [r2[rows - k, i] for k in lags for i in range(m)]
    R = np.column_stack(cols)
    norms = np.linalg.norm(R, axis=0)
    norms[norms == 0] = 1.0
    # Unpivoted QR keeps the nested order, so every prefix is a candidate model.
    Q, Rr = np.linalg.qr(R / norms)
    y = u[rows]
    proj = Q.T @ y
    independent = np.abs(np.diag(Rr)) > rank_rtol
    records = []
    ss = float(y @ y)
    tail = ss - np.cumsum(proj ** 2)
    for n_lags in range(1, len(lags) + 1):
        p_cols = 1 + m * n_lags
        rank = int(independent[:p_cols].sum())
        rss = max(float(tail[p_cols - 1]), ss * 1e-300)
        m1, m2 = _orders_of(n_lags)
        base = n_rows * math.log(rss / n_rows)
        records.append({"m1": m1, "m2": m2, "rank": rank, "rss": rss,
                        "aic": base + 2 * rank, "bic": base + rank * math.log(n_rows)})
    table = pd.DataFrame(records)
    best = int(table[criterion].to_numpy().argmin())
    return OrderSelection(criterion=criterion, m1=int(table.m1[best]), m2=int(table.m2[best]),
                          table=table, n_rows=n_rows)


@dataclass
class FIRFit:
    """Stage 1 for one joint: the FIR sensitivity of eq. (10) and u_hat of eq. (11)."""

    m1: int
    m2: int
    taps: np.ndarray          # s_k, k = -M1..M2 (per reference: (m, M1+M2+1))
    intercept: float
    rows: np.ndarray          # samples where u_hat is defined
    u_hat: np.ndarray         # (len(rows),) eq. (11)
    u_tilde: np.ndarray       # u - u_hat on those rows
    rank: int
    basis: np.ndarray = field(repr=False)   # orthonormal basis of the lag space (len(rows), rank)
    corr: float = math.nan    # corr(u_hat, u_tilde), lag 0
    max_xcorr: float = math.nan
    max_xcorr_lag: int = 0

    def project(self, x):
        """LS projection of x (len(rows), ...) on the lag space: P x."""
        B = self.basis
        return np.tensordot(B, np.tensordot(B.T, x, axes=(1, 0)), axes=(1, 0))


def _orthonormal_basis(R, rank_rtol):
    norms = np.linalg.norm(R, axis=0)
    norms[norms == 0] = 1.0
    Q, Rr, _ = sla.qr(R / norms, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(Rr))
    rank = int(np.count_nonzero(d > rank_rtol * d[0])) if d.size else 0
    return Q[:, :rank], rank


def _xcorr(a, b, max_lag):
    """Largest |normalised cross-correlation| of a and b over lags |l| <= max_lag."""
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    if den == 0:
        return 0.0, 0.0, 0
    c0 = float(a @ b) / den
    best, lag = abs(c0), 0
    n = a.size
    for l in range(1, min(max_lag, n - 1) + 1):
        for s in (l, -l):
            v = float(a[s:] @ b[:n - s]) if s > 0 else float(a[:n + s] @ b[-s:])
            if abs(v) / den > best:
                best, lag = abs(v) / den, s
    return c0, best, lag


def fit_fir(r, u, m1, m2, *, rows=None, rank_rtol=RANK_RTOL, xcorr_lags=None):
    """Stage 1 of the Projection Method for one joint: eqs. (10)-(11).

    `r`: (N,) reference (or (N, m) several); `u`: (N,) torque. `rows`
    restricts the fit to a subset of the valid rows (default: all of them,
    t = M2..N-1-M1). The coefficients s_k are the minimum-norm LS solution
    (the lag matrix of a periodic reference is rank-deficient; u_hat is unique
    all the same).
    """
    u = _array("u", u, (1,), "(N,)")
    m1, m2 = _check_orders(m1, m2)
    r = _array("r", r, (1, 2), "(N,) or (N, m)")
    if r.shape[0] != u.shape[0]:
        raise InputError(f"r has {r.shape[0]} samples but u has {u.shape[0]}; they must be sampled together")
    all_rows, R = lag_matrix(r, m1, m2)
    if rows is not None:
        sel = np.asarray(rows) - m2
        if sel.min() < 0 or sel.max() >= all_rows.size:
            raise InputError(f"rows must lie in {m2}..{u.size - 1 - m1} for M1 = {m1}, M2 = {m2}")
        R, all_rows = R[sel], all_rows[sel]
    if all_rows.size < 2 * R.shape[1]:
        raise InputError(f"{u.size} samples are too few for an FIR filter with M1 = {m1}, M2 = {m2} "
                         f"({R.shape[1]} coefficients on {all_rows.size} usable rows); record longer "
                         "or lower M1, M2")
    y = u[all_rows]
    coef, *_ = np.linalg.lstsq(R, y, rcond=None)
    B, rank = _orthonormal_basis(R, rank_rtol)
    u_hat = B @ (B.T @ y)
    u_tilde = y - u_hat
    L = xcorr_lags if xcorr_lags is not None else max(m1, m2, 10)
    c0, cmax, lag = _xcorr(u_hat, u_tilde, int(L))
    m = 1 if r.ndim == 1 else r.shape[1]
    taps = coef[1:].reshape(m, m1 + m2 + 1)
    return FIRFit(m1=m1, m2=m2, taps=taps[0] if r.ndim == 1 else taps, intercept=float(coef[0]),
                  rows=all_rows, u_hat=u_hat, u_tilde=u_tilde, rank=rank, basis=B, corr=c0,
                  max_xcorr=cmax, max_xcorr_lag=lag)


# ----------------------------------------------------------------------- result
@dataclass(eq=False, repr=False)
class ProjectionResult(ParameterResults):
    """Parameters identified by the Projection Method, with stage 1's diagnostics.

    `chi`, `cov` (IV sandwich, see the module doc), `bse`, `rel_std`
    (%σ = 100 σ/|χ̂|, eq. (15) of Gautier et al.); `m1`, `m2` per joint;
    `corr` (lag-0 corr(û, ũ), eq. (11)) and `max_xcorr` per joint;
    `stage2` the OLS of û on the projected regressor (its own covariance is
    not the one to use); `ls` plain OLS of u on the unprojected W, for
    comparison (None if not computed). `robot_name`, `source` and
    `robot_signature` (`dynid.dynamics.robot.model_signature`) say which robot and
    recording `identify_projection` identified ("" when built from arrays).
    """

    names: list
    chi: np.ndarray
    cov: np.ndarray
    m1: list
    m2: list
    corr: np.ndarray
    max_xcorr: np.ndarray
    max_xcorr_lag: np.ndarray
    fir_rank: list
    n_samples: int
    n_rows: int
    rel_error: float               # ||u - W chi|| / ||u|| (structural residual)
    rel_error_projected: float     # ||u_hat - W_hat chi|| / ||u_hat||
    hac_lags: int
    stage2: object = None
    ls: object = None
    selection: list = field(default_factory=list)
    u_hat: np.ndarray = None       # (n_rows, n) eq. (11) on the common rows
    u_tilde: np.ndarray = None
    rows: np.ndarray = None
    settings: dict = field(default_factory=dict)
    notices: list = field(default_factory=list)
    data_hash: str = ""
    robot_name: str = ""           # the robot identified ("" when built from arrays)
    source: str = ""               # the recording identified
    robot_signature: str = ""      # dynamics.robot.model_signature of the robot identified

    sigma = deprecated_alias("bse (a pandas Series; .to_numpy() for the array)", lambda r: r.bse.to_numpy())
    rel_sigma = deprecated_alias("rel_std (a pandas Series; .to_numpy() for the array)",
                                 lambda r: r.rel_std.to_numpy())

    def __post_init__(self):
        self.chi = np.asarray(self.chi, dtype=float)
        self.cov = np.asarray(self.cov, dtype=float)

    method = "PM"

    def to_frame(self):
        df = pd.DataFrame({"value": self.chi, "std": self.bse.to_numpy(), "rel_std_percent": self.rel_std.to_numpy(),
                           "unit": self._units()}, index=pd.Index(self.names, name="parameter"))
        if self.ls is not None:
            df["ls_value"] = self.ls.chi
            df["ls_rel_std_percent"] = self.ls.rel_std.to_numpy()
        return df

    def joint_table(self):
        """Per joint: M1, M2, rank of the lag space, corr(û, ũ), max cross-correlation.

        Returns
        -------
        pandas.DataFrame
            One row per joint.
        """
        n = len(self.m1)
        return pd.DataFrame({"M1": self.m1, "M2": self.m2, "fir_rank": self.fir_rank,
                             "corr_uhat_utilde": self.corr, "max_xcorr": self.max_xcorr,
                             "max_xcorr_lag": self.max_xcorr_lag},
                            index=pd.Index([f"joint {j + 1}" for j in range(n)], name="joint"))

    def summary(self):
        rule, thin = "=" * _WIDTH, "-" * _WIDTH
        lines = identified_line("Projection Method", self.robot_name, self.source) + [
                 "Projection Method (Bona & Curatella 2005, eqs. (10)-(12))".center(_WIDTH), rule,
                 f"Samples N: {self.n_samples}   torque equations used (all joints): {self.n_rows}   "
                 f"parameters: {self.n_params}",
                 f"Rel. error |u - W chi|/|u|: {percent(self.rel_error)}   "
                 f"projected |u^ - W^ chi|/|u^|: {percent(self.rel_error_projected)}",
                 f"Covariance: IV sandwich, Newey-West with {self.hac_lags} lags", thin,
                 f"{'Joint':<8}{'M1':>5}{'M2':>5}{'rank':>6}{'corr(u^,u~)':>16}{'max |xcorr|':>14}{'at lag':>8}"]
        for j in range(len(self.m1)):
            lines.append(f"{j + 1:<8}{self.m1[j]:>5}{self.m2[j]:>5}{self.fir_rank[j]:>6}"
                         f"{self.corr[j]:>16.2e}{self.max_xcorr[j]:>14.3g}{int(self.max_xcorr_lag[j]):>8}")
        lines.append(thin)
        columns = [("PM value", self.chi, "num"), ("sigma", self.bse.to_numpy(), "num"),
                   ("%sigma", self.rel_std.to_numpy(), "pct")]
        if self.ls is not None:
            columns += [("LS value", self.ls.chi, "num"), ("LS %sigma", self.ls.rel_std.to_numpy(), "pct")]
        lines += parameter_table(self.names, columns, prismatic=self._prismatic())
        lines.append(rule)
        lines += notices_block(self.notices)
        return "\n".join(lines)

    def to_dict(self):
        params = self._records()
        out = {
            "method": "PM",
            "robot": self.robot_name or None,
            "robot_signature": self.robot_signature or None,
            "source": self.source,
            "settings": self.settings,
            "parameters": params,
            "fir": [{"joint": j + 1, "m1": self.m1[j], "m2": self.m2[j], "rank": self.fir_rank[j],
                     "corr_uhat_utilde": self.corr[j], "max_xcorr": self.max_xcorr[j],
                     "max_xcorr_lag": int(self.max_xcorr_lag[j])} for j in range(len(self.m1))],
            "order_selection": [s.to_dict() if s is not None else None for s in self.selection],
            "rel_error": self.rel_error,
            "rel_error_projected": self.rel_error_projected,
            "hac_lags": self.hac_lags,
            "n_samples": self.n_samples,
            "n_rows": self.n_rows,
            "ls": None if self.ls is None else self.ls.to_dict(),
            "versions": versions(),
            "data_hash": self.data_hash,
            "notices": self.notices,
        }
        return json_safe(out)


# ------------------------------------------------------------------ covariance
def _hac_lags(e, n_rows):
    """Twice the lag where the pooled residual autocorrelation first drops below 2/sqrt(N)."""
    x = e - e.mean(axis=0)
    den = float(np.sum(x * x))
    if den == 0:
        return 0
    cap = max(1, n_rows // 10)
    thr = 2.0 / math.sqrt(n_rows)
    for l in range(1, cap + 1):
        if float(np.sum(x[l:] * x[:-l])) / den < thr:
            return min(cap, 2 * l)
    return cap


def _iv_covariance(What, e, L):
    """(Ŵ^T Ŵ)^-1 S (Ŵ^T Ŵ)^-1, S the Bartlett long-run covariance of g_t = Σ_j Ŵ_tj^T e_tj."""
    g = np.einsum("tjb,tj->tb", What, e)
    # S = Σ_{|l|<=L} (1 - |l|/(L+1)) Σ_t g_t g_{t-l}^T, not divided by the row count
    S = S_hac_simple(g, nlags=int(L), weights_func=weights_bartlett)
    A = np.einsum("tjb,tjc->bc", What, What)
    Ainv = np.linalg.pinv(A, rcond=1e-13)
    return Ainv @ S @ Ainv


# ------------------------------------------------------------------------- API
def _mask(row_mask, N, n):
    if row_mask is None:
        return np.ones((N, n), dtype=bool)
    m = np.asarray(row_mask)
    if m.dtype != bool:
        raise InputError(f"row_mask must be a boolean array (True = use the row), got dtype {m.dtype}")
    if m.shape == (N,):
        return np.repeat(m[:, None], n, axis=1)
    if m.shape != (N, n):
        raise InputError(f"row_mask has shape {m.shape}; it must be ({N},) or ({N}, {n})")
    return m.copy()


def _per_joint(value, n, name):
    if value is None:
        return [None] * n
    v = list(np.broadcast_to(np.asarray(value, dtype=object), (n,)))
    for x in v:
        _check_orders(x, 0) if name == "m1" else _check_orders(0, x)
    return [int(x) for x in v]


def projection_method(W3, tau, r, names, *, m1=None, m2=None, criterion="bic", max_lag=None,
                      references="own", row_mask=None, compare_ls=True, xcorr_lags=None,
                      rank_rtol=RANK_RTOL, settings=None) -> ProjectionResult:
    """Identify chi by the Projection Method, eqs. (10)-(12), from arrays.

    Parameters
    ----------
    W3 : (N, n, b) regressor built from the measured (filtered) positions.
    tau : (N, n) measured torques or control signals u.
    r : (N, n) reference positions qr, sampled with tau.
    names : b parameter names (`ZZ1R`, `Fv1`, ...).
    m1, m2 : FIR window of eq. (10), in samples: one value or one per joint;
        `None` chooses it by `criterion` ('bic' or 'aic') up to `max_lag`.
    references : 'own' (joint j's u is filtered from r_j only, as in the
        paper) or 'all' (from every joint's reference: the multivariable
        sensitivity, for coupled joints).
    row_mask : bool (N,) or (N, n); False rows (e.g. the velocity dead zone)
        are zeroed in W and tau before the projection.
    compare_ls : also run plain OLS of tau on W (same rows), kept as `.ls`.

    Returns a `ProjectionResult`. Raises InputError on bad shapes,
    non-finite values or too few samples for the FIR order.
    """
    W3 = _array("W3", W3, (3,), "(N samples, n joints, b parameters)")
    tau = _array("tau", tau, (2,), "(N samples, n joints)")
    r = _array("r", r, (1, 2), "(N samples, n joints)")
    if r.ndim == 1:
        r = r[:, None]
    N, n, b = W3.shape
    if tau.shape != (N, n):
        raise InputError(f"tau has shape {tau.shape} but W3 has shape {W3.shape}; tau must be ({N}, {n})")
    if r.shape != (N, n):
        raise InputError(f"r has shape {r.shape}; it must be ({N}, {n}): one reference per joint, "
                         "sampled with tau")
    if references not in ("own", "all"):
        raise InputError(f"references must be 'own' or 'all', got {references!r}")
    names = list(names)
    if len(names) != b:
        raise InputError(f"{len(names)} names for {b} columns of W3")
    mask = _mask(row_mask, N, n)
    Wm = W3 * mask[:, :, None]
    um = tau * mask
    m1s, m2s = _per_joint(m1, n, "m1"), _per_joint(m2, n, "m2")
    selections = []
    for j in range(n):
        rj = r[:, j] if references == "own" else r
        if m1s[j] is None or m2s[j] is None:
            sel = select_fir_order(rj, um[:, j], max_lag=max_lag, criterion=criterion,
                                   rank_rtol=rank_rtol)
            selections.append(sel)
            m1s[j] = sel.m1 if m1s[j] is None else m1s[j]
            m2s[j] = sel.m2 if m2s[j] is None else m2s[j]
        else:
            selections.append(None)
    # common rows, so the per-joint projections stack into one system
    lo, hi = max(m2s), N - max(m1s)
    if hi - lo < 2 * b:
        raise InputError(f"{N} samples leave {max(hi - lo, 0)} rows after the FIR windows "
                         f"(M1 up to {max(m1s)}, M2 up to {max(m2s)}): too few for {b} parameters")
    rows = np.arange(lo, hi)
    fits, What, uhat = [], np.empty((rows.size, n, b)), np.empty((rows.size, n))
    for j in range(n):
        rj = r[:, j] if references == "own" else r
        fit = fit_fir(rj, um[:, j], m1s[j], m2s[j], rows=rows, rank_rtol=rank_rtol,
                      xcorr_lags=xcorr_lags)
        fits.append(fit)
        uhat[:, j] = fit.u_hat
        What[:, j, :] = fit.project(Wm[rows, j, :])
    user = dict(settings or {})
    stage2 = ls.ols(What, uhat, names, settings=user)
    chi = stage2.chi
    e = um[rows] - Wm[rows] @ chi
    L = _hac_lags(e, rows.size)
    cov = _iv_covariance(What, e, L)
    used = mask[rows]
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = float(np.linalg.norm(e[used]) / np.linalg.norm(um[rows][used]))
        rel_p = float(np.linalg.norm((uhat - What @ chi)[used]) / np.linalg.norm(uhat[used]))
    ls_res = ls.ols(Wm[rows], um[rows], names, row_mask=used, settings=user) if compare_ls else None
    notices = []
    for j, f in enumerate(fits):
        if f.max_xcorr > 0.1:
            notices.append(f"joint {j + 1}: u_hat and u_tilde correlate up to {f.max_xcorr:.2f} "
                           f"(lag {f.max_xcorr_lag}); the FIR window M1 = {f.m1}, M2 = {f.m2} may be "
                           "too short")
    cfg = {**user, "projection": {"criterion": criterion, "max_lag": max_lag, "references": references,
                                  "m1": m1s, "m2": m2s, "row_mask": row_mask is not None,
                                  "stage2": "OLS of u_hat on the projected regressor (2SLS, "
                                            "lagged reference as instruments)",
                                  "covariance": f"IV sandwich, Newey-West Bartlett, {L} lags"}}
    return ProjectionResult(
        names=names, chi=chi, cov=cov, m1=m1s, m2=m2s,
        corr=np.array([f.corr for f in fits]), max_xcorr=np.array([f.max_xcorr for f in fits]),
        max_xcorr_lag=np.array([f.max_xcorr_lag for f in fits]),
        fir_rank=[f.rank for f in fits], n_samples=N, n_rows=int(used.sum()), rel_error=rel,
        rel_error_projected=rel_p, hac_lags=L, stage2=stage2, ls=ls_res, selection=selections,
        u_hat=uhat, u_tilde=um[rows] - uhat, rows=rows, settings=cfg, notices=notices,
        data_hash=data_hash(W3, tau, r))


def identify_projection(experiment, robot, *, bp=None, settings=None, **kwargs) -> ProjectionResult:
    """The Projection Method on a recording (needs `t`, `q`, `qr`, `tau`).

    The regressor is built as IDIM builds it (`dynid.analysis.processing.observation.observe`:
    zero-phase filtered q, central differences, velocity dead zone) but without
    decimation, because the FIR of eq. (10) runs on the recorded samples; the
    rows of the dead zone are masked. Other keyword arguments go to
    `projection_method`.
    """

    if getattr(experiment, "qr", None) is None:
        raise InputError(f"{experiment.source}: the Projection Method needs the reference positions "
                         "(columns qr1..qrn) as well as q and tau")
    bp = base_parameters(robot) if bp is None else bp
    over = dict(settings or {})
    over["nd"] = 1
    if over.get("fc_position") is None and experiment.q is not None:
        # without decimation default_settings raises the q filter to 10 x a 0.4 fs "decimation cut-off"
        # (0.2 fs): W then carries the acceleration noise up to there, which the instruments (the lagged
        # reference, inside the motion's band) do not see, but the HAC sandwich does (sigma 15-27 x the
        # real scatter, rel_error ~100 %); keep the filter at 10 x the motion's bandwidth
        bandwidth = resolve_settings(experiment, over)["bandwidth"]       # estimated or given, checked
        over["fc_position"] = default_position_cutoff(bandwidth, experiment.fs)
    obs = observe(experiment, robot, bp, over)
    idx = np.searchsorted(experiment.t, obs.t)
    r = experiment.qr[idx]
    res = projection_method(obs.W, obs.tau, r, bp.names, row_mask=obs.row_mask,
                            settings={"processing": obs.settings}, **kwargs)
    res.notices = obs.notices + res.notices
    res.robot_name, res.source, res.robot_signature = robot.name, str(experiment.source), model_signature(robot)
    return res
