"""How far a torque prediction is from the measured torques: the figures of every held-out check.

The relative error norm ||tau - tau_hat|| / ||tau||, the per-joint RMS [N m] and the
per-joint relative errors, over all samples or over a mask of them. Used by the held-out
validation (dynid.analysis.statistics.validation) and by the physically consistent fits;
it sits in processing, below both, so that neither imports the other.
"""
from __future__ import annotations

import numpy as np

__all__ = ["prediction_errors"]


def prediction_errors(tau, tau_hat, mask=None):
    """Relative error norm, per-joint RMS and per-joint relative error (over `mask` if given)."""
    tau = np.asarray(tau, dtype=float)
    res = tau - tau_hat
    if mask is not None:
        m = np.broadcast_to(np.asarray(mask, dtype=bool), tau.shape)
        res = np.where(m, res, 0.0)
        tau = np.where(m, tau, 0.0)
        cnt = np.maximum(m.sum(axis=0), 1)
        rms = np.sqrt(np.sum(res ** 2, axis=0) / cnt)
    else:
        rms = np.sqrt(np.mean(res ** 2, axis=0))
    rel = float(np.linalg.norm(res) / np.linalg.norm(tau))
    jrel = np.linalg.norm(res, axis=0) / np.linalg.norm(tau, axis=0)
    return rel, rms, jrel
