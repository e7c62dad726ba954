"""The observation system of eq. (9) from a recording too long for memory.

A 1-hour recording at 5 kHz of a 6-joint robot is 18 million samples; its
full-rate base regressor would take 52 GB. Here the recording arrives in
chunks (any iterable of `(q, tau)` pairs); the zero-phase position filter
runs on overlapping blocks, each padded on both sides by `margin` samples
(the filter's transient, where its impulse response has decayed below 1e-5
of its peak: see `dynid.analysis.processing.signals.transient_samples`), so each block's
centre equals the whole-record filtfilt to that tolerance. The centre then
goes through the same regressor -> dead zone -> parallel decimation as
`dynid.analysis.processing.observation.observe`. Memory: a few blocks of q and tau plus
one regressor chunk, plus the decimated system (n_d times smaller than the
recording); `dynid.analysis.estimators.streamed.reduce_stream` does not keep even
that: it feeds `stream_blocks` a sink that reduces each decimated chunk to its
per-joint triangles and adds them up.
"""
from __future__ import annotations

import numpy as np

from dynid.analysis.processing.decimation import ParallelDecimator
from dynid.analysis.processing.observation import CHUNK, Observation, _dead_zone, push_chunk
from dynid.analysis.processing.signals import derivatives, transient_samples
from dynid.errors import DataError


def observe_stream(chunks, fs, robot, bp, *, fc_position, nd, f_decimation_cutoff=None,
                   qd_threshold, order=4, block=200_000, progress=None):
    """Decimated (W, tau) of a chunked recording; settings must be explicit.

    `qd_threshold` must be numbers (per joint or one): 'auto' would need the
    whole record's peak speed before the first block is processed.
    """
    parts = []
    settings, dec, margin, n_in = stream_blocks(parts.append, chunks, fs, robot, bp, fc_position=fc_position,
                                                 nd=nd, f_decimation_cutoff=f_decimation_cutoff,
                                                 qd_threshold=qd_threshold, order=order, block=block,
                                                 progress=progress)
    Wd, taud, qf_d, qd_d, qdd_d, kept = (np.concatenate([p[k] for p in parts], axis=0) for k in range(6))
    t = (margin + dec.indices) / fs
    return Observation(W=Wd, tau=taud, t=t, q=qf_d, qd=qd_d, qdd=qdd_d, row_mask=kept >= 0.5,
                       names=list(bp.names), settings=settings,
                       notices=[f"streamed {n_in} samples in blocks of {block} (+{margin} overlap)"],
                       n_raw=n_in)


def stream_blocks(sink, chunks, fs, robot, bp, *, fc_position, nd, f_decimation_cutoff, qd_threshold,
                  order, block, progress):
    """Push every block through filter, regressor, dead zone and decimator; `sink` each part.

    Each part is the decimated `(W, tau, q, qd, qdd, kept)` of one regressor chunk
    (`kept`: the fraction of its samples outside the dead zone). Arguments as
    `observe_stream`. Returns (settings, decimator, margin, samples read).
    """
    if isinstance(qd_threshold, str):
        raise DataError("observe_stream needs numeric qd_threshold values (rad/s); 'auto' needs the "
                        "whole recording first. Estimate it on a first segment.")
    margin = transient_samples(fs, fc_position, order) + 2
    guard = int(np.ceil(fs / fc_position))
    f_cut = 0.8 * fs / (2 * nd) if f_decimation_cutoff is None else f_decimation_cutoff
    settings = {"fc_position": fc_position, "nd": nd, "f_decimation_cutoff": f_cut,
                "edge": margin, "order": order, "qd_threshold": qd_threshold, "fs": fs}
    dec = ParallelDecimator(nd, fs=fs, cutoff=f_cut)
    buf_q, buf_tau = [], []
    n_buf = 0
    n_in = 0

    def process(q, tau):
        # q, tau hold [left margin | centre | right margin] (no left margin at the start)
        der = derivatives(q, fs, fc_position, order)
        lo = margin
        hi = len(q) - margin
        s, dead = _dead_zone(settings, der.qd, robot, guard=guard, whole=False)
        for start in range(lo, hi, CHUNK):
            sl = slice(start, min(hi, start + CHUNK))
            sink(push_chunk(dec, robot, bp, der.q[sl], der.qd[sl], der.qdd[sl], tau[sl],
                            None if dead is None else dead[sl]))

    for q_c, tau_c in chunks:
        q_c = np.asarray(q_c, dtype=float)
        tau_c = np.asarray(tau_c, dtype=float)
        buf_q.append(q_c)
        buf_tau.append(tau_c)
        n_buf += len(q_c)
        n_in += len(q_c)
        while n_buf >= block + 2 * margin:
            q = np.concatenate(buf_q)
            tau = np.concatenate(buf_tau)
            process(q[:block + 2 * margin], tau[:block + 2 * margin])
            # keep the last 2*margin samples: the next block's left margin and overlap
            keep = block
            buf_q, buf_tau = [q[keep:]], [tau[keep:]]
            n_buf = len(buf_q[0])
        if progress is not None:
            progress(n_in)
    if n_buf > 2 * margin + 10:
        q = np.concatenate(buf_q)
        tau = np.concatenate(buf_tau)
        process(q, tau)
    dec.finish()
    return settings, dec, margin, n_in
