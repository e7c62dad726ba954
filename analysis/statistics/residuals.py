"""Residual analysis per joint, after any identification.

What a residual `e = Y - W chi_hat` (decimated rows, one column per joint)
says about what the model lacks:

* **vs velocity** (binned means of `e_j` against `qd_j`): the friction
  signature. A model with the right friction leaves a flat line at zero; a
  step at `qd = 0` is a missing Coulomb asymmetry or offset (the two are the
  same thing while the joint moves), a V shape an asymmetric viscous term, a
  bump that dies out with speed a Stribeck effect.
* **vs position** (binned means against `q_j`): springs (a slope), ripple
  (a periodic pattern), gravity errors.
* **vs time** (binned means over the recording): drift (warm-up, temperature).
* **spectrum** (`scipy.signal.welch`): a peak at the motion's frequencies is
  a model error, a flat spectrum white noise.
* **autocorrelation** and **Ljung-Box** (`statsmodels`): is the residual
  white? It is not after filtering and decimation when the model misses
  something, and then every test that counts the samples as independent is
  too optimistic.
* **PDF vs Gaussian**: `dynid.analysis.statistics.validation.normality` (Jarque-Bera,
  Shapiro-Wilk).
* **effective sample size** (`effective_sample_size`), the number of
  independent samples the correlated residual is worth.

Rows outside `mask` (the velocity dead zone, equations not used) are left
out of the bins and of the normality tests; in the autocorrelation they are
gaps (a lag-k product is counted only where both samples are used), in the
spectrum they are zeros (after removing the mean).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import signal
from statsmodels.stats.diagnostic import acorr_ljungbox

from dynid.analysis.statistics.validation import normality
from dynid.provenance import json_safe

__all__ = ["autocorrelation", "effective_sample_size", "binned_means", "ResidualAnalysis",
           "analyze_residuals", "residual_analysis"]


# --------------------------------------------------------------- correlation
def autocorrelation(e, max_lag, mask=None):
    """Autocorrelation ρ_0..ρ_max_lag of each column of `e` (N,) or (N, n), with gaps.

    ρ_k = Σ_i e_i e_(i+k) m_i m_(i+k) / c_k  /  (Σ_i e_i² m_i / c_0), with c_k the
    number of pairs where both samples are used (`mask`) and e the used
    samples minus their mean. Returns (max_lag + 1,) or (max_lag + 1, n);
    lags without any pair give NaN.
    """
    e = np.asarray(e, dtype=float)
    one = e.ndim == 1
    E = e.reshape(e.shape[0], -1)
    N, n = E.shape
    M = np.ones_like(E, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(N, -1)
    M = np.broadcast_to(M, E.shape)
    L = int(min(max_lag, N - 1))
    x = np.where(M, E, 0.0)
    cnt = M.sum(axis=0)
    mean = np.divide(x.sum(axis=0), cnt, out=np.zeros(n), where=cnt > 0)
    x = np.where(M, x - mean, 0.0)
    m = M.astype(float)
    # products over all lags at once by FFT (zero-padded: no wrap-around)
    nfft = 1 << int(math.ceil(math.log2(max(2 * N - 1, 2))))
    fx = np.fft.rfft(x, nfft, axis=0)
    fm = np.fft.rfft(m, nfft, axis=0)
    num = np.fft.irfft(fx * np.conj(fx), nfft, axis=0)[:L + 1]
    pairs = np.rint(np.fft.irfft(fm * np.conj(fm), nfft, axis=0)[:L + 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(pairs > 0, num / np.maximum(pairs, 1), np.nan)
        rho = c / c[0]
    out = np.full((max_lag + 1, n), np.nan)
    out[:L + 1] = rho
    return out[:, 0] if one else out


def effective_sample_size(e, mask=None, max_lag=None):
    """Effective number of independent samples of a serially correlated residual.

    Formula (the integrated autocorrelation time of the residual, as for the
    variance of a mean; Bartlett / Sokal):

        tau_int = 1 + 2 Σ_{k=1}^{K-1} ρ_k,      n_eff = n / tau_int,

    n the number of used samples. Truncation rule: K is the first lag whose
    ρ_K falls inside the white-noise band `|ρ| < 2/sqrt(n)` (or below it),
    searched up to `max_lag` (default min(n/4, 100)); the sum stops before
    it, since beyond that the estimates are noise. `tau_int` is clipped
    below at 1: a negatively correlated residual is not credited with more
    information than independent samples.

    Why it serves for regression tests: the variance of `cᵀe` for a smooth
    regressor column c (its own ρ_c(k) ≈ 1 at these lags) is inflated by
    `1 + 2 Σ ρ_c(k) ρ_e(k) <= tau_int`, so dividing a χ² statistic by
    `tau_int` is conservative.

    Returns `(n_eff, tau_int, K, n)` as arrays over the columns of `e`
    (scalars for a 1-D `e`).

    Not the MCMC effective sample size: that one
    (`dynid.analysis.sampling.convergence.chain_effective_sample_size`)
    uses emcee's walker-averaged τ with Sokal's automatic window (c = 5), the
    right rule for a long, smooth chain autocorrelation; a regression residual
    is short next to its correlation structure and masked, and its ρ_k beyond
    the white-noise band are noise, hence the band truncation here.
    """
    e = np.asarray(e, dtype=float)
    one = e.ndim == 1
    E = e.reshape(e.shape[0], -1)
    N, n_col = E.shape
    M = np.ones_like(E, dtype=bool) if mask is None else np.broadcast_to(
        np.asarray(mask, dtype=bool).reshape(N, -1), E.shape)
    n_used = M.sum(axis=0)
    lag_max = int(max_lag) if max_lag is not None else int(min(100, max(1, N // 4)))
    rho = autocorrelation(E, lag_max, M)
    tau = np.ones(n_col)
    cut = np.zeros(n_col, dtype=int)
    for j in range(n_col):
        if n_used[j] < 4:
            tau[j], cut[j] = np.nan, 0
            continue
        band = 2.0 / math.sqrt(n_used[j])
        r = rho[1:, j]
        inside = np.flatnonzero(~(r >= band))        # NaN counts as inside
        K = int(inside[0]) + 1 if inside.size else lag_max + 1
        cut[j] = K
        tau[j] = max(1.0, 1.0 + 2.0 * float(np.sum(r[:K - 1])))
    n_eff = n_used / tau
    if one:
        return float(n_eff[0]), float(tau[0]), int(cut[0]), int(n_used[0])
    return n_eff, tau, cut, n_used


def binned_means(x, e, bins=15, mask=None):
    """Equal-count bins of `x` (1-D): centre (median), mean of `e`, its standard error, count."""
    x = np.asarray(x, dtype=float)
    e = np.asarray(e, dtype=float)
    use = np.isfinite(x) & np.isfinite(e)
    if mask is not None:
        use &= np.asarray(mask, dtype=bool)
    x, e = x[use], e[use]
    if x.size == 0:
        return pd.DataFrame(columns=["center", "lo", "hi", "mean", "sem", "count"])
    nb = int(max(1, min(bins, x.size // 5)))
    edges = np.unique(np.quantile(x, np.linspace(0, 1, nb + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(0, len(edges) - 2))
    rows = []
    for b in range(max(1, len(edges) - 1)):
        sel = idx == b
        k = int(sel.sum())
        if k == 0:
            continue
        sd = float(e[sel].std(ddof=1)) if k > 1 else float("nan")
        rows.append({"center": float(np.median(x[sel])), "lo": float(x[sel].min()),
                     "hi": float(x[sel].max()), "mean": float(e[sel].mean()),
                     "sem": sd / math.sqrt(k) if k > 1 else float("nan"), "count": k})
    return pd.DataFrame(rows)


# --------------------------------------------------------------- the analysis
@dataclass
class ResidualAnalysis:
    """Per-joint residual diagnostics (see the module docstring)."""

    names: list
    t: np.ndarray
    residual: np.ndarray              # (M, n)
    mask: np.ndarray                  # (M, n)
    velocity: dict                    # joint (1-based) -> DataFrame of binned means vs qd
    position: dict                    # joint -> binned means vs q
    time: dict                        # joint -> binned means vs t
    spectrum: dict                    # joint -> (f [Hz], PSD [(N m)^2/Hz])
    acf: np.ndarray                   # (max_lag + 1, n)
    ljung_box: pd.DataFrame           # per joint: lag, statistic, p-value
    normality: pd.DataFrame           # dynid.analysis.statistics.validation.normality
    n_eff: pd.DataFrame               # per joint: n, tau_int, cut lag, n_eff
    fs: float = float("nan")          # rate of the residual samples, Hz
    notices: list = field(default_factory=list)

    @property
    def rms(self):
        r = np.where(self.mask, self.residual, np.nan)
        return np.sqrt(np.nanmean(r ** 2, axis=0))

    def summary(self):
        lines = ["Residual analysis per joint",
                 "  joint   RMS        Ljung-Box p   tau_int   n_eff / n     JB p"]
        for j in range(self.residual.shape[1]):
            lb = self.ljung_box.iloc[j]
            ne = self.n_eff.iloc[j]
            lines.append(f"  {j + 1:5d}   {self.rms[j]:9.4g}  {lb['p_value']:10.3g}   "
                         f"{ne['tau_int']:7.2f}   {ne['n_eff']:6.1f} / {int(ne['n']):4d}   "
                         f"{self.normality['jarque_bera_p'].iloc[j]:.3g}")
        return "\n".join(lines)

    def to_dict(self):
        return json_safe({
            "rms_per_joint": list(self.rms),
            "ljung_box": self.ljung_box.reset_index().to_dict(orient="records"),
            "n_eff": self.n_eff.reset_index().to_dict(orient="records"),
            "normality": self.normality.reset_index().to_dict(orient="records"),
            "velocity_bins": {str(j): df.to_dict(orient="records") for j, df in self.velocity.items()},
            "position_bins": {str(j): df.to_dict(orient="records") for j, df in self.position.items()},
            "time_bins": {str(j): df.to_dict(orient="records") for j, df in self.time.items()},
            "n_eff_formula": "n_eff = n / (1 + 2 sum_{k<K} rho_k), K = first lag with rho_K < 2/sqrt(n)",
        })


def analyze_residuals(residual, *, t, q, qd, mask=None, fs=None, names=None, bins=15,
                      max_lag=None, lb_lag=None):
    """Residual diagnostics of `residual` (M, n) given the motion at the same samples.

    `t` (M,), `q`/`qd` (M, n) are the (decimated) time, position and
    velocity of the rows; `mask` (M, n) the rows used by the estimator;
    `fs` the rate of the rows (default from `t`). `bins` equal-count
    bins for the binned means; `max_lag` of the autocorrelation (default
    min(M/4, 40)); `lb_lag` of the Ljung-Box test (default min(10, M/5)).
    """
    E = np.asarray(residual, dtype=float)
    M_, n = E.shape
    mask = np.ones((M_, n), dtype=bool) if mask is None else np.broadcast_to(
        np.asarray(mask, dtype=bool), (M_, n)).copy()
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    if fs is None:
        fs = 1.0 / float(np.median(np.diff(t))) if t.size > 1 else 1.0
    names = list(names) if names is not None else [f"joint {j + 1}" for j in range(n)]
    max_lag = int(max_lag) if max_lag is not None else int(max(1, min(40, M_ // 4)))
    lb_lag = int(lb_lag) if lb_lag is not None else int(max(1, min(10, M_ // 5)))
    vel, pos, tim, spec = {}, {}, {}, {}
    lb_rows, ne_rows = [], []
    acf = autocorrelation(E, max_lag, mask)
    n_eff, tau, cut, n_used = effective_sample_size(E, mask, max_lag=max_lag)
    notices = []
    for j in range(n):
        m = mask[:, j]
        e = E[:, j]
        vel[j + 1] = binned_means(qd[:, j], e, bins, m)
        pos[j + 1] = binned_means(q[:, j], e, bins, m)
        tim[j + 1] = binned_means(t, e, bins, m)
        x = np.where(m, e - (e[m].mean() if m.any() else 0.0), 0.0)
        nper = int(min(M_, max(16, M_ // 4)))
        if M_ >= 8:
            f, P = signal.welch(x, fs=fs, nperseg=nper, detrend="constant")
        else:
            f, P = np.zeros(0), np.zeros(0)
        spec[j + 1] = (f, P)
        used = e[m]
        if used.size > lb_lag + 2:
            lb = acorr_ljungbox(used, lags=[lb_lag], return_df=True)
            stat, p = float(lb["lb_stat"].iloc[0]), float(lb["lb_pvalue"].iloc[0])
        else:
            stat, p = float("nan"), float("nan")
        lb_rows.append({"joint": j + 1, "lag": lb_lag, "statistic": stat, "p_value": p})
        ne_rows.append({"joint": j + 1, "n": int(n_used[j]), "tau_int": float(tau[j]),
                        "cut_lag": int(cut[j]), "n_eff": float(n_eff[j])})
    if not mask.all():
        notices.append("rows outside the estimator's mask are left out (gaps in the "
                       "autocorrelation, zeros in the spectrum)")
    masked = np.where(mask, E, np.nan)
    return ResidualAnalysis(
        names=names, t=t, residual=E, mask=mask, velocity=vel, position=pos, time=tim,
        spectrum=spec, acf=acf,
        ljung_box=pd.DataFrame(lb_rows).set_index("joint"),
        normality=normality(masked),
        n_eff=pd.DataFrame(ne_rows).set_index("joint"), fs=float(fs), notices=notices)


def residual_analysis(observation, residual, names=None, **kwargs):
    """`analyze_residuals` on the rows of an `dynid.analysis.processing.observation.Observation`."""
    fs = None
    s = getattr(observation, "settings", None) or {}
    if "fs" in s and "nd" in s:
        fs = float(s["fs"]) / max(1, int(s["nd"]))
    return analyze_residuals(residual, t=observation.t, q=observation.q, qd=observation.qd,
                             mask=observation.row_mask, fs=fs, names=names, **kwargs)
