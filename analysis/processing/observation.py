"""From a recording to the decimated observation system Y = W chi + rho (eqs. (8)-(9)).

Filter q (zero-phase Butterworth), differentiate it (central differences),
drop the filter transients at both ends, build the base regressor chunk by
chunk, and low-pass and down-sample Y and every column of W *in parallel*
with the same filter. The full-rate W never exists as a whole: each chunk is
built, pushed through the decimator and dropped.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from dynid.analysis.processing.decimation import ParallelDecimator
from dynid.analysis.processing.row_masks import zero_dead_rows
from dynid.analysis.processing.signals import (
    AUTO_DEAD_ZONE,
    dead_zone_thresholds,
    default_settings,
    derivatives,
    low_velocity_mask,
    velocity_dead_zone,
)
from dynid.dynamics.base_parameters import base_regressor
from dynid.dynamics.regressor import regressor
from dynid.errors import DataError, InputError, did_you_mean

CHUNK = 20_000
#: A decimated row made mostly of zeroed (dead-zone) samples carries little information and a
#: distorted noise level: rows whose window kept less than this fraction are dropped.
KEPT_FRACTION_MIN = 0.5
#: Regressor values per chunk of `observed_residual` (4 MB).
_MODEL_ROWS = 1 << 19

# the settings users may override, with their meaning
SETTINGS_HELP = {
    "fc_position": "cut-off of the zero-phase Butterworth filter of q, Hz",
    "order": "order of that Butterworth filter",
    "nd": "decimation factor n_d (1 = no decimation)",
    "f_decimation_cutoff": "cut-off of the decimation low-pass, Hz (paper: 0.8 fs / (2 nd))",
    "edge": "samples dropped at each end for the filter transients",
    "bandwidth": "motion bandwidth, Hz (estimated from q if not given)",
    "qd_threshold": ("drop rows where |qd_j| is below this, rad/s, one value or one per joint "
                     "(Coulomb friction's sign is unreliable there); 'auto' = "
                     f"{AUTO_DEAD_ZONE:g} x max |qd_j|; 0 = keep all"),
}


@dataclass
class Observation:
    """The decimated identification system of eq. (9), with what it was made from."""

    W: np.ndarray            # (M, n, b) base regressor, decimated
    tau: np.ndarray          # (M, n) torques, decimated
    t: np.ndarray            # (M,) time of each decimated sample
    q: np.ndarray            # (M, n) filtered positions at those samples
    qd: np.ndarray           # (M, n) velocities at those samples
    qdd: np.ndarray          # (M, n) accelerations
    row_mask: np.ndarray     # (M, n) rows used for estimation
    names: list
    settings: dict
    notices: list = field(default_factory=list)
    n_raw: int = 0           # samples of the recording

    @property
    def n_samples(self):
        return self.W.shape[0]


def resolve_settings(experiment, overrides=None):
    """The processing settings for this recording: data-derived defaults, then overrides."""
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(SETTINGS_HELP))
    if unknown:
        raise InputError(f"unknown processing setting(s) {', '.join(unknown)}"
                         f"{did_you_mean(unknown[0], SETTINGS_HELP)}; known: "
                         + ", ".join(f"{k} ({v})" for k, v in SETTINGS_HELP.items()))
    qd_threshold = overrides.pop("qd_threshold", "auto")
    order = int(overrides.pop("order", 4))
    try:
        proposed = default_settings(experiment.fs, experiment.q, order=order,
                                    **{k: v for k, v in overrides.items() if v is not None})
    except InputError as e:      # the signal functions know arrays, not the recording
        raise DataError(f"{experiment.source}: {e}") from None
    proposed["order"] = order
    proposed["qd_threshold"] = qd_threshold
    proposed["fs"] = float(experiment.fs)
    return proposed


def observe(experiment, robot, bp, settings=None, *, progress=None, reference=False):
    """Build the decimated observation system of eq. (9) from a recording.

    `settings` are overrides of `resolve_settings` (or its full output).
    `reference=True` uses the reference `qr` instead of `q` (analytic
    trajectories, or DIDIM-like checks).
    """
    q_meas = experiment.qr if reference else experiment.q
    if q_meas is None:
        col = "qr" if reference else "q"
        raise DataError(f"{experiment.source}: the regressor is built from measured joint positions "
                        f"({col}1..{col}n) and the file has none (IDIM, the diagnosis and the Projection "
                        f"Method need them). Use DIDIM (needs qr and tau) or add the position columns.")
    fr = full_rate(experiment, robot, q_meas, settings)
    s, fs, N, dead = fr.settings, fr.fs, fr.n_raw, fr.dead
    qf, qd, qdd, tau, t = fr.q, fr.qd, fr.qdd, fr.tau, fr.t
    notices = [fr.edge_notice]
    nd = int(s["nd"])
    n_kept = qf.shape[0]
    if dead is not None:
        notices.append(dead_zone_notice(s, dead))
    if nd <= 1:
        W = base_regressor(robot, bp, qf, qd, qdd)
        Wd, taud, qd_d, qf_d, qdd_d, td = W, tau, qd, qf, qdd, t
        mask = dead is None or ~dead
        mask = np.broadcast_to(mask, taud.shape).copy()
        if dead is not None:
            Wd, taud = Wd * mask[:, :, None], taud * mask
    else:
        dec = ParallelDecimator(nd, n_samples_total=n_kept, fs=fs, cutoff=s["f_decimation_cutoff"])
        parts = []
        # one regressor buffer for every chunk: the decimator keeps no view of what it is
        # pushed, and a fresh chunk-sized W (58 MB for the TX40) paid its page faults anew
        buf = np.empty((min(CHUNK, n_kept), qf.shape[1], bp.n_base))
        for start in range(0, n_kept, CHUNK):
            sl = slice(start, min(n_kept, start + CHUNK))
            parts.append(push_chunk(dec, robot, bp, qf[sl], qd[sl], qdd[sl], tau[sl],
                                    None if dead is None else dead[sl],
                                    out=buf[:sl.stop - sl.start]))
            if progress is not None:
                progress(sl.stop / n_kept)
        dec.finish()
        Wd, taud, qf_d, qd_d, qdd_d, kept_frac = (np.concatenate([p[k] for p in parts], axis=0)
                                                  for k in range(6))
        idx = dec.indices
        td = t[idx]
        notices.append(decimation_notice(s, n_kept, dec))
        mask = kept_frac >= KEPT_FRACTION_MIN
    return Observation(W=Wd, tau=taud, t=td, q=qf_d, qd=qd_d, qdd=qdd_d, row_mask=mask,
                       names=list(bp.names), settings=s, notices=notices, n_raw=N)


# the dead-zone functions of dynid.analysis.processing.signals, re-exported for users
__all__ = ["Observation", "observe", "observed_residual", "resolve_settings", "low_velocity_mask", "velocity_dead_zone",
           "SETTINGS_HELP", "AUTO_DEAD_ZONE"]


def observed_residual(experiment, robot, bp, settings, cols, chi):
    """(decimated `tau - W[:, :, cols] chi` (M, n), row mask (M, n)) of `experiment` processed as
    `observe` does with `settings` (filter, dead zone, decimation), from the full-rate model
    torque: the decimation is linear, so this is the decimated W times chi up to rounding
    (1e-13 relative), without decimating all b columns of W. `cols` index the base
    parameters of `bp`, `chi` their values."""
    fr = full_rate(experiment, robot, experiment.q, settings)
    nd = int(fr.settings["nd"])
    keep = None if fr.dead is None else ~fr.dead
    columns = np.asarray(bp.independent)[cols]
    N = fr.q.shape[0]
    if nd <= 1:
        mask = np.ones(fr.tau.shape, dtype=bool) if keep is None else keep
        W = regressor(robot, fr.q, fr.qd, fr.qdd, columns=columns)
        return fr.tau * mask - (W * mask[:, :, None]) @ chi, mask
    dec = ParallelDecimator(nd, n_samples_total=N, fs=fr.fs, cutoff=fr.settings["f_decimation_cutoff"])
    # one regressor buffer of a few MB: each row's model torque is the same whatever the
    # chunk, and a buffer of CHUNK rows (58 MB for 60 columns of 6 joints) per draw cost more
    # in page faults than its products
    rows = max(1, min(CHUNK, N, _MODEL_ROWS // max(1, fr.q.shape[1] * columns.size)))
    buf = np.empty((rows, fr.q.shape[1], columns.size))
    parts = []
    for start in range(0, N, rows):
        sl = slice(start, min(N, start + rows))
        model = regressor(robot, fr.q[sl], fr.qd[sl], fr.qdd[sl], columns=columns,
                          out=buf[:sl.stop - sl.start]) @ chi
        tau = fr.tau[sl]
        if keep is not None:                 # zeroed on both sides in the dead zone, as observe
            model *= keep[sl]
            tau = tau * keep[sl]
        kept = np.ones(tau.shape) if keep is None else keep[sl].astype(float)
        parts.append(dec.push(tau, model, kept))
    dec.finish()
    taud, modeld, kept_frac = (np.concatenate([p[k] for p in parts], axis=0) for k in range(3))
    return taud - modeld, kept_frac >= KEPT_FRACTION_MIN


def dead_zone_notice(s, dead) -> str:
    """The notice of the velocity dead zone `dead` (N, n) with the thresholds of settings `s`."""
    return ("velocity dead zone (Coulomb friction's sign is unreliable there): rows with "
            + ", ".join(f"|qd{j + 1}| < {v:.3g}" for j, v in enumerate(s["qd_threshold"]))
            + " rad/s are zeroed in W and Y before decimation; excluded per joint (full-rate rows): "
            + ", ".join(f"{100 * f:.1f} %" for f in dead.mean(axis=0)))


def decimation_notice(s, n_kept, dec) -> str:
    """The notice of the parallel decimation `dec` (a finished ParallelDecimator) of `n_kept` rows."""
    return (f"parallel decimation by nd = {int(s['nd'])} (low-pass {s['f_decimation_cutoff']:.3g} Hz): "
            f"{n_kept} -> {len(dec.indices)} samples, {dec.dropped_start} + {dec.dropped_end} "
            f"dropped for the decimation filter's transients")


def push_chunk(dec, robot, bp, qf, qd, qdd, tau, dead, out=None):
    """Build the base regressor of one chunk and push it with tau through the decimator.

    `out`: a (len(qf), n, n_base) buffer for the chunk's regressor, free again once this
    returns (the decimator copies what it keeps)."""
    W = base_regressor(robot, bp, qf, qd, qdd, out=out)
    if dead is not None:
        # zeroing both sides keeps Y = W chi exact row by row, so the parallel
        # decimation stays consistent while the samples where the friction
        # model is wrong drop out entirely
        keep_rows = ~dead
        zero_dead_rows(W, keep_rows)      # W is this chunk's own: in place, no second copy
        tau = tau * keep_rows
    kept = np.ones(tau.shape) if dead is None else (~dead).astype(float)
    return dec.push(W, tau, qf, qd, qdd, kept)


class FullRate(NamedTuple):
    """The full-rate signals every observation is built from (see `full_rate`)."""

    settings: dict           # resolved settings, qd_threshold as numbers
    fs: float
    n_raw: int               # samples of the recording
    keep: slice              # the samples kept (the filter's edges dropped)
    t: np.ndarray            # (N', ) times of the kept samples
    q: np.ndarray            # (N', n) filtered positions
    qd: np.ndarray           # (N', n) velocities
    qdd: np.ndarray          # (N', n) accelerations
    tau: np.ndarray          # (N', n) torques
    dead: np.ndarray | None  # (N', n) velocity dead zone, None if qd_threshold is 0
    edge_notice: str


def full_rate(experiment, robot, q_meas, settings=None) -> FullRate:
    """Filter and differentiate `q_meas`, drop the filter's edges, find the dead zone.

    The steps `observe`, `dynid.analysis.diagnosis.effect_observation.observe_effects`
    share before the regressor: settings resolved as `resolve_settings`
    (or given in full), zero-phase filter and central differences
    (`derivatives`), `edge` samples dropped at each end, the velocity
    dead zone widened by fs / fc_position samples.
    """
    if robot.n_joints != q_meas.shape[1]:
        raise DataError(f"{experiment.source}: robot '{robot.name}' has {robot.n_joints} joints "
                        f"but the data have {q_meas.shape[1]}")
    s = settings if (settings and "fs" in settings) else resolve_settings(experiment, settings)
    fs = experiment.fs
    N = q_meas.shape[0]
    edge = int(s["edge"])
    # before the filter, whose own check of the length does not know the file
    if N - 2 * edge < 10:
        raise DataError(f"{experiment.source}: {N} samples are too few for the position filter at "
                        f"{s['fc_position']:.4g} Hz (it needs {edge} samples at each end): record longer")
    der = derivatives(q_meas, fs, s["fc_position"], s["order"])
    keep = slice(edge, N - edge)
    qd = der.qd[keep]
    s, dead = _dead_zone(s, qd, robot, guard=int(np.ceil(fs / s["fc_position"])), source=experiment.source)
    return FullRate(settings=s, fs=fs, n_raw=N, keep=keep, t=experiment.t[keep], q=der.q[keep], qd=qd,
                    qdd=der.qdd[keep], tau=np.asarray(experiment.tau, dtype=float)[keep], dead=dead,
                    edge_notice=f"dropped {edge} samples ({edge / fs:.3g} s) at each end: transients "
                                f"of the {s['fc_position']:g} Hz position filter")


#: rad/s: a recording whose every joint stays below this peak speed does not move
STILL_SPEED = 1e-6


def _dead_zone(s, qd, robot, guard=0, whole=True, source=""):
    """Full-rate samples (N, n) inside the velocity dead zone, or None; settings with numbers.

    The settings' `qd_threshold` resolved by
    `dynid.analysis.processing.signals.dead_zone_thresholds` and applied, with the
    robot's couplings and widened by `guard` samples on each side, by
    `dynid.analysis.processing.signals.velocity_dead_zone` (measured: +0.7 % on Ia5 of
    the simulated TX40 without the widening). None when every threshold is 0.
    """
    thr = dead_zone_thresholds(qd, s.get("qd_threshold"))
    if not np.any(thr > 0):
        return dict(s, qd_threshold=[0.0] * qd.shape[1]), None
    dead = velocity_dead_zone(qd, thr, guard=guard, couplings=robot.couplings)
    # on a whole recording, no equation left is the user's threshold; a chunk of a streamed
    # recording may well be all at rest
    if whole and dead.size and dead.all():
        peak = np.abs(np.asarray(qd, dtype=float)).max(axis=0)
        where = f"{source}: " if source else ""
        if np.all(peak < STILL_SPEED):
            raise DataError(f"{where}no joint moves (peak |qd| " + ", ".join(f"{v:.3g}" for v in peak)
                            + " rad/s): the recording holds no motion to identify or validate on; record "
                            "the excitation trajectory")
        raise DataError(
            f"{where}the velocity dead zone (--qd-threshold, qd_threshold: "
            + ", ".join(f"{v:.3g}" for v in thr) + " rad/s) is above every joint speed (peak "
            + ", ".join(f"|qd{j + 1}| = {v:.3g}" for j, v in enumerate(peak))
            + " rad/s), so every sample is dropped and no equation is left. Lower "
            "--qd-threshold below the joint speeds, or leave it at 'auto'.")
    return dict(s, qd_threshold=[float(v) for v in thr]), dead


def concatenate(observations):
    """One observation system from several recordings (rows stacked, same settings)."""
    obs = list(observations)
    if len(obs) == 1:
        return obs[0]
    first = obs[0]
    cat = lambda attr: np.concatenate([getattr(o, attr) for o in obs], axis=0)
    notices = [f"identification recording {k + 1} of {len(obs)} (in the order given): {n}"
               for k, o in enumerate(obs) for n in o.notices]
    return Observation(W=cat("W"), tau=cat("tau"), t=cat("t"), q=cat("q"), qd=cat("qd"),
                       qdd=cat("qdd"), row_mask=cat("row_mask"), names=first.names,
                       settings=first.settings, notices=notices, n_raw=sum(o.n_raw for o in obs))
