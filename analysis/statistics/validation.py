"""Validation: predict the torques of another recording and judge the residual.

The identified model predicts τ̂ = W χ̂ on data it was not fitted to (a second
recording or a held-out time segment), processed with the *same* filter and
decimation settings. Reported: the relative error norm ‖τ − τ̂‖ / ‖τ‖ over
all joints, per-joint RMS and relative error, and whether each joint's
residual looks Gaussian (Jarque-Bera from statsmodels, Shapiro-Wilk from
scipy), the noise-PDF check of both papers.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats
from statsmodels.stats.stattools import jarque_bera

from dynid.analysis.processing.observation import observe
from dynid.analysis.results import Exportable


def normality(residual):
    """Per-joint noise-PDF checks of a residual (N, n): mean, std, skew, kurtosis, tests."""
    rows = []
    for j in range(residual.shape[1]):
        e = residual[:, j]
        e = e[np.isfinite(e)]
        jb, jb_p, skew, kurt = jarque_bera(e)
        sw = stats.shapiro(e[:5000]) if e.size >= 3 else (np.nan, np.nan)
        rows.append({"joint": j + 1, "mean": float(e.mean()), "std": float(e.std(ddof=1)),
                     "skew": float(skew), "kurtosis": float(kurt),
                     "jarque_bera": float(jb), "jarque_bera_p": float(jb_p),
                     "shapiro": float(sw[0]), "shapiro_p": float(sw[1])})
    return pd.DataFrame(rows).set_index("joint")


@dataclass
class ValidationResult(Exportable):
    """Prediction of a recording by an identified model."""

    source: str
    t: np.ndarray
    tau: np.ndarray
    tau_hat: np.ndarray
    rel_error: float
    rms: np.ndarray
    joint_rel_error: np.ndarray
    noise: pd.DataFrame
    notices: list = field(default_factory=list)

    @property
    def residual(self):
        return self.tau - self.tau_hat

    def summary(self):
        lines = [f"Validation on {self.source}: {len(self.t)} decimated samples",
                 f"  relative error ||tau - tau_hat|| / ||tau|| = {self.rel_error:.4f}",
                 "  joint   RMS [N m]   rel. error   Jarque-Bera p"]
        for j in range(self.tau.shape[1]):
            lines.append(f"  {j + 1:5d}   {self.rms[j]:9.4g}   {self.joint_rel_error[j]:10.4f}   "
                         f"{self.noise['jarque_bera_p'].iloc[j]:.3g}")
        return "\n".join(lines)

    def to_dict(self):
        from dynid.provenance import json_safe
        return json_safe({"source": self.source, "n_samples": int(len(self.t)),
                          "rel_error": self.rel_error, "rms_per_joint": list(self.rms),
                          "joint_rel_error": list(self.joint_rel_error),
                          "noise": self.noise.reset_index().to_dict(orient="records"),
                          "notices": self.notices})


def prediction_errors(tau, tau_hat):
    """Relative error norm, per-joint RMS and per-joint relative error."""
    res = tau - tau_hat
    rel = float(np.linalg.norm(res) / np.linalg.norm(tau))
    rms = np.sqrt(np.mean(res ** 2, axis=0))
    jrel = np.linalg.norm(res, axis=0) / np.linalg.norm(tau, axis=0)
    return rel, rms, jrel


def validate(idim_result, experiment, robot=None):
    """Predict ``experiment`` with the essential model of ``idim_result``.

    ``experiment`` may be a path; ``robot`` defaults to the one identified.
    """
    if robot is None:
        robot = getattr(idim_result, "robot", None)
        if robot is None:
            from dynid.errors import InputError
            raise InputError("validate: this result does not carry its robot; pass robot=")
    if isinstance(experiment, (str, bytes)) or hasattr(experiment, "__fspath__"):
        from dynid.analysis.data.experiment import load_experiment
        experiment = load_experiment(experiment, robot)
    obs = observe(experiment, robot, idim_result.base, idim_result.settings)
    tau_hat = idim_result.predict(obs.W)
    rel, rms, jrel = prediction_errors(obs.tau, tau_hat)
    return ValidationResult(source=str(experiment.source), t=obs.t, tau=obs.tau, tau_hat=tau_hat,
                            rel_error=rel, rms=rms, joint_rel_error=jrel,
                            noise=normality(obs.tau - tau_hat), notices=obs.notices)
