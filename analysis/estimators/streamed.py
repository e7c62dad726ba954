"""Least squares on a recording too long for memory: its observation system reduced as it streams.

`dynid.analysis.processing.streaming.stream_blocks` filters, builds the base
regressor and decimates the recording block by block; here each decimated chunk is
reduced at once to its per-joint triangles (WᵀW, WᵀY and ‖Y‖² in factored form,
`dynid.analysis.estimators.least_squares.Reduction`), which add up. OLS, WLS and
the essential set are solved on the sum (Gautier, Janot & Vandanjon 2010, eqs. (9)-(13)).
"""
from __future__ import annotations

from dataclasses import dataclass

from dynid.analysis.estimators import least_squares as ls
from dynid.analysis.processing.streaming import stream_blocks

__all__ = ["reduce_stream", "StreamedReduction"]


def reduce_stream(chunks, fs, robot, bp, *, fc_position, nd, f_decimation_cutoff=None,
                  qd_threshold, order=4, block=200_000, progress=None) -> StreamedReduction:
    """The observation system of a chunked recording reduced as it streams, W never held.

    The same decimated rows as
    `dynid.analysis.processing.streaming.observe_stream` (same arguments), but each
    decimated part is reduced at once to its per-joint triangles
    (`dynid.analysis.estimators.least_squares.reduce_system`: WᵀW, WᵀY and ‖Y‖²
    in factored form) and added to the running total, so memory is a few blocks
    of q and tau whatever the recording's length. Rows are selected as there
    (decimated rows that kept at least half their samples). Solve the result
    with `ls.wls_reduced` / `essential_parameters(reduction, None, None, ls.wls)`.
    """
    total = []
    names = list(bp.names)

    def add(part):
        W, tau, kept = part[0], part[1], part[5]
        if W.shape[0] == 0:
            return
        red = ls.reduce_system(W, tau, names, row_mask=kept >= 0.5)
        total[:] = [red if not total else total[0] + red]

    settings, dec, margin, n_in = stream_blocks(add, chunks, fs, robot, bp, fc_position=fc_position, nd=nd,
                                                f_decimation_cutoff=f_decimation_cutoff,
                                                qd_threshold=qd_threshold, order=order, block=block,
                                                progress=progress)
    return StreamedReduction(reduction=total[0], settings=settings, n_raw=n_in,
                             n_decimated=int(len(dec.indices)),
                             notices=[f"streamed {n_in} samples in blocks of {block} (+{margin} overlap), "
                                      f"reduced chunk by chunk"])


@dataclass
class StreamedReduction:
    """What `reduce_stream` returns: the summed `Reduction` and its settings."""

    reduction: object
    settings: dict
    n_raw: int
    n_decimated: int
    notices: list
