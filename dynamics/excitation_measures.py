"""How good an excitation trajectory is, and whether it keeps to the robot's limits.

The measures that `dynid.dynamics.excitation.design_excitation` optimises and reports
(Bona & Curatella 2005, eq. (20)): the a-priori parameters behind the torque limits, the
fixed column scales `S` of the base regressor, the condition numbers of `W S^-1`, `W` and
`W` with unit-norm columns, the relative distance to every limit on a dense grid, and the
spectrum of one period. Why these condition numbers and scales: the module docstring of
`dynid.dynamics.excitation`.
"""
from __future__ import annotations

import math

import numpy as np

from dynid.errors import InputError

from .base_parameters import base_parameters, base_regressor
from .dynamic_model import inverse_dynamics

__all__ = ["apriori_parameters", "column_scales", "regressor_conditioning", "limit_margins", "spectrum_check",
           "within_limits", "SCALINGS", "DEFAULT_SAMPLES_PER_HARMONIC", "DEFAULT_N_CHECK"]

SCALINGS = ("envelope", "none", "columns")
DEFAULT_SAMPLES_PER_HARMONIC = 20
DEFAULT_N_CHECK = 20_000
_ENVELOPE_SEED = 19970501           # fixed: S must depend on the robot only
_ENVELOPE_SAMPLES = 4000


def apriori_parameters(robot, bp=None):
    """Standard parameters `chi_st` built from `robot.apriori` (for torque limits).

    Keys of `robot.apriori` may be base-parameter names (`ZZ1R`) or standard
    names. When every key is a standard name, `beta = P chi` maps them to the
    base parameters; otherwise base names are read directly (a standard name that
    is also a base name, such as `Fv1`, counts as both). Parameters without an
    a-priori value are zero. Returns `(chi_st, beta, missing)` with `missing`
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
    """Fixed column scales `S` (b,) of the base regressor (see the module docstring).

    `"envelope"`: RMS of each column over states uniform in the limit box (an
    infinite position range is replaced by [-pi, pi], an infinite velocity or
    acceleration limit by 1); `"none"`: ones. `"columns"` has no fixed scale
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
    """Condition numbers of the base regressor of `trajectory` over one period.

    Returns `{"cond": cond(W S^-1) (envelope scales unless `scales` given),
    "cond_raw": cond(W) in SI units, "cond_unit": cond of W with unit-norm columns,
    "logdet": log det(W_s^T W_s) / b / (samples), "n_samples": ...}`.
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
    """Relative distance of `trajectory` to every limit, per joint, on a dense grid.

    Columns (1 = untouched, 0 = on the limit, negative = violated):
    `q_low = (min q - q_min) / half range`, `q_high = (q_max - max q) / half range`,
    `qd = 1 - max|qd| / qd_max`, `qdd = 1 - max|qdd| / qdd_max` and, with
    `chi_st`, `tau = 1 - max|tau| / tau_max` (NaN where a limit is infinite),
    plus the peak values. The grid is `n_check` points over one period (offset
    by half a step from t = 0).
    """
    import pandas as pd  # slow to import; the dynamics layer needs it only for this table

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
    """FFT of one period of the reference positions: lines only at `k f0`, `k <= N`?

    One whole period sampled at `fs` (default `50 N f0`, at least 64 samples
    per period) puts harmonic `k` exactly in FFT bin `k`. Returns a dict:
    `freqs` (Hz) and `amplitude` (n, bins) of the one-sided amplitude spectrum
    of `q - q0`, `lines` (frequencies of the bins above `rel_tol` times the
    largest line), `off_grid` (largest amplitude outside bins 1..N relative to
    the largest line), `bandwidth` (N f0) and `ok`.
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


def within_limits(margins, tol=0.0):
    """True when no limit margin of `limit_margins` is below `-tol` (NaN: no limit)."""
    cols = [c for c in ("q_low", "q_high", "qd", "qdd", "tau") if c in margins]
    v = margins[cols].to_numpy(dtype=float)
    return bool(np.all(np.where(np.isnan(v), np.inf, v) >= -tol))
