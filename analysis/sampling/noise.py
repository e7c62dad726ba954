"""Noise models of the posterior's likelihood: independent rows, or rows worth their effective number.

`white`: eq. (16) of Gautier, Janot & Vandanjon (2010) read as a likelihood,
ρ^j ~ N(0, σ_j² I_{r_j}): every decimated row of joint j is new information.
On decimated closed-loop data the residual is correlated in time (filtered
noise, unmodelled torques), so that posterior is too narrow.

`neff` (default): the likelihood of joint j is tempered by the effective
sample size of its LS residual,

    log L(χ, σ) = Σ_j (1/τ_j) [ −r_j log σ_j − S_j(χ) / (2σ_j²) ],
    τ_j = 1 + 2 Σ_{k<K_j} ρ_j(k)  (≥ 1),   n_eff,j = r_j / τ_j,

with ρ_j the gap-aware autocorrelation of the residual of joint j and K_j the
first lag inside the white-noise band 2/√r_j
(dynid.analysis.statistics.residuals.effective_sample_size, the n_eff the
residual analysis reports). A tempered ("power") likelihood keeps the
Gaussian shape and the LS point estimate and scales the information of each
joint by n_eff,j / r_j: the variance of W^jᵀρ^j is inflated by τ_j when the
regressor columns are smooth over the residual's correlation lags (decimated
data: the motion's bandwidth is far below the decimated rate), which is the
variance the white model forgets. In the sufficient statistics this is
(G_j, g_j, s_j, r_j) / τ_j: the cost per step is unchanged and the σ_j keep
their scale (S_j / r_j is unchanged).

Chosen over AR(p) prewhitening per joint after trying both on the
independent plant (development seeds < 1000): the AR coefficients fitted to
~150 decimated rows per joint (orders by BIC up to 8) gave long-run variance
factors that jumped between 0.2 and 75 from seed to seed, and prewhitening
drops p rows after every gap of the velocity dead zone; the tempering factor
is one robust number per joint and is the same n_eff the residual analysis
shows the user.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dynid.analysis.sampling.sufficient import SufficientStats
from dynid.analysis.statistics.residuals import effective_sample_size
from dynid.errors import InputError
from dynid.provenance import json_safe

__all__ = ["NOISE_MODELS", "NoiseModel", "check_noise", "noise_model", "temper"]

#: Noise models of the likelihood: "neff" (default) rows tempered by the effective sample size
#: of the residual, "white" independent rows.
NOISE_MODELS = ("neff", "white")


def check_noise(noise) -> str:
    """The noise model's name, or an InputError naming the choices."""
    if noise not in NOISE_MODELS:
        raise InputError(f"noise must be one of {', '.join(NOISE_MODELS)}, not {noise!r} (--noise)")
    return noise


@dataclass(eq=False)
class NoiseModel:
    """The noise model a posterior used.

    Attributes
    ----------
    kind : "neff" or "white".
    tau_int : (n,)
        Integrated autocorrelation time of each joint's LS residual, in rows (1 for white).
    rows : (n,) int
        Rows of each joint.
    cut_lag : (n,) int
        First lag inside the white-noise band (the sum stops before it; 0 for white).
    """

    kind: str
    tau_int: np.ndarray
    rows: np.ndarray
    cut_lag: np.ndarray

    @property
    def n_eff(self) -> np.ndarray:
        """Effective rows r_j / τ_j of each joint."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.rows / self.tau_int

    def describe(self) -> str:
        if self.kind == "white":
            return "white: independent Gaussian rows, one sigma_j per joint (eqs. (9), (10), (16))"
        taus = ", ".join(f"{t:.2f}" for t in self.tau_int)
        return ("neff: Gaussian rows, each joint's likelihood tempered by 1/tau_j, the integrated "
                "autocorrelation time of its LS residual (n_eff = r_j / tau_j; tau_j = " + taus + ")")

    def to_dict(self) -> dict:
        return json_safe({"kind": self.kind, "description": self.describe(), "tau_int": self.tau_int,
                          "n_eff": self.n_eff, "rows": self.rows, "cut_lag": self.cut_lag})


def noise_model(kind: str, W3, tau, mask, chi) -> NoiseModel:
    """The noise model `kind` of the system (W3 (N, n, b), tau (N, n), mask) about the LS `chi`.

    Returns
    -------
    NoiseModel
        For "neff", τ_j from `effective_sample_size` of the residual tau − W3 χ (rows in `mask`).
    """
    check_noise(kind)
    W3 = np.asarray(W3, dtype=float)
    N, n, _ = W3.shape
    m = np.ones((N, n), bool) if mask is None else np.broadcast_to(
        np.asarray(mask, bool).reshape(N, -1), (N, n))
    rows = m.sum(axis=0).astype(int)
    if kind == "white":
        return NoiseModel("white", np.ones(n), rows, np.zeros(n, int))
    with np.errstate(invalid="ignore", over="ignore"):
        e = np.where(m, np.asarray(tau, float) - np.einsum(
            "tjb,b->tj", np.where(m[:, :, None], W3, 0.0), np.asarray(chi, float)), 0.0)
    _, tau_int, cut, _ = effective_sample_size(e, m)
    tau_int = np.where(np.isfinite(tau_int), tau_int, 1.0)     # joints with < 4 rows: as white
    return NoiseModel("neff", np.asarray(tau_int, float), rows, np.asarray(cut, int))


def temper(stats: SufficientStats, model: NoiseModel) -> SufficientStats:
    """The sufficient statistics of the tempered likelihood: (G_j, g_j, s_j, r_j) / τ_j."""
    if model.kind == "white":
        return stats
    w = 1.0 / np.asarray(model.tau_int, dtype=float)
    return dataclasses.replace(stats, G=stats.G * w[:, None, None], g=stats.g * w[:, None],
                               s=stats.s * w, rows=stats.rows * w)
