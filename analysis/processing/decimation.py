"""Parallel decimation of eq. (9).

Y_fm and every column of W_fm (eq. (8)) are low-pass filtered with the same
filter and one sample in `nd` is kept, giving eq. (9) (Gautier, Janot &
Vandanjon 2010, section 2; section 5 uses nd = 100 and a cut-off of
0.8 f_m / (2 nd) = 20 Hz at f_m = 5 kHz).  Because the filter is linear and
identical for all columns, decimate(W) @ chi == decimate(W @ chi).

Filter
    Linear-phase FIR (`scipy.signal.firwin`, Kaiser window) designed for
    `ATTENUATION_DB` = 60 dB: its -6 dB point is the cut-off
    (default 0.8 fs / (2 nd)), the transition band is symmetric around it,
    half-width min(fs/(2 nd) - cutoff, cutoff/4), so the stop band starts at
    the decimated Nyquist frequency fs / (2 nd) and the pass band (ripple
    < 0.1 %) ends at 0.75 x cutoff.  Single stage: about 18 nd + 1 taps.
    The FIR is applied centred on each kept sample (zero phase, no delay)
    and only kept samples are computed (polyphase, one BLAS matmul per
    block of nd samples).

Stages
    `nd` may be split into two stages d1 x d2: the first stage only has to
    stop what would alias onto [0, fs/(2 nd)], so it is short.  The split (or
    a single stage) is the one with the fewest multiply-adds per input
    sample, counting stages with fewer than 8 polyphase rows twice (small
    matrix products ran at about half speed when measured, see `_plan`).
    For nd = 100 at 5 kHz this picks 25 x 4 (115 + 75 taps, equivalent to
    one FIR of 1965 taps): measured ~1.5x faster than one 1815-tap stage in
    streaming, about equal in memory.  Pass `factors=(nd,)` to
    `ParallelDecimator` to force a single stage.  The cascade is still a
    symmetric FIR centred on the kept samples; its pass-band ripple is
    < 0.2 % (two stages of 0.1 %).

Memory and speed
    The streaming class keeps, per stage and per pushed array, only the
    last ~(taps + down) input samples; each chunk is read in place (no copy)
    except the few outputs whose window straddles the previous chunk.
    About 0.45 s per million samples of 366 columns (W of 6 x 60 + tau of 6)
    on the development machine, so 18 million samples take ~8 s.

Kept samples and edges
    Kept samples are at multiples of `nd` (0, nd, 2 nd, ...) of the input.
    Those whose filter window would extend past either end of the record are
    dropped (not computed from padding); `dropped_start` / `dropped_end`
    count them so callers can print a notice.  The in-memory function and the
    streaming class share the same code and give the same samples.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from dynid.errors import InputError

#: Stop-band attenuation and pass-band ripple (1e-3) of each FIR stage.
ATTENUATION_DB = 60.0
#: Default cut-off as a fraction of the decimated Nyquist frequency (paper).
CUTOFF_FRACTION = 0.8


def _check_nd(nd) -> int:
    if isinstance(nd, bool) or not isinstance(nd, (int, np.integer)):
        if isinstance(nd, float) and nd.is_integer() and nd >= 1:
            return int(nd)
        raise InputError(f"decimation factor nd must be an integer >= 1, got {nd!r}.")
    if nd < 1:
        raise InputError(
            f"decimation factor nd must be >= 1 (keep one sample in nd), got {nd}."
        )
    return int(nd)


def _kaiser_lowpass(fs: float, f_pass: float, f_stop: float) -> np.ndarray:
    """Odd-length symmetric Kaiser FIR passing [0, f_pass], stopping [f_stop, fs/2]."""
    numtaps, beta = signal.kaiserord(ATTENUATION_DB, (f_stop - f_pass) / (fs / 2.0))
    numtaps |= 1  # odd: the centre tap sits on the kept sample (zero phase)
    return signal.firwin(numtaps, 0.5 * (f_pass + f_stop), window=("kaiser", beta), fs=fs)


def _kaiser_length(fs: float, f_pass: float, f_stop: float) -> int:
    return signal.kaiserord(ATTENUATION_DB, (f_stop - f_pass) / (fs / 2.0))[0] | 1


def _plan(nd: int, fs: float, f_pass: float, f_stop: float, factors=None):
    """Return [(taps, down), ...] implementing the decimation by `nd`.

    Cost model: multiply-adds per input sample, L1/d1 + L2/(d1 d2), where a
    stage with a small polyphase matrix (taps/down < 8 rows) is counted 2x
    slower (measured: small BLAS products run at about half speed).
    """
    if factors is None:
        def cost(d1):
            if d1 == nd:
                return _weighted(_kaiser_length(fs, f_pass, f_stop), nd)
            l1 = _kaiser_length(fs, f_pass, fs / d1 - f_stop)
            l2 = _kaiser_length(fs / d1, f_pass, f_stop)
            return _weighted(l1, d1) + _weighted(l2, nd // d1) / d1

        # d1 == nd is the single stage; ties go to it (simpler, shorter edge).
        candidates = [d for d in range(2, nd + 1) if nd % d == 0] or [nd]
        best = min(candidates, key=lambda d: (cost(d), d != nd))
        factors = (nd,) if best == nd else (best, nd // best)
    factors = tuple(int(d) for d in factors)
    if math.prod(factors) != nd or len(factors) > 2 or (len(factors) == 2 and min(factors) < 2):
        raise InputError(
            f"factors {factors} must be (nd,) or two integers >= 2 whose product is "
            f"nd={nd}."
        )
    if len(factors) == 1:
        return [(_kaiser_lowpass(fs, f_pass, f_stop), nd)]
    d1, d2 = factors
    return [
        (_kaiser_lowpass(fs, f_pass, fs / d1 - f_stop), d1),
        (_kaiser_lowpass(fs / d1, f_pass, f_stop), d2),
    ]


def _weighted(length: int, down: int) -> float:
    rows = -(-length // down)
    return rows * (2.0 if rows < 8 else 1.0)


class DecimationFilter:
    """The FIR cascade and kept-sample grid of a decimation by `nd`.

    `fs` defaults to 1 (then `cutoff` is in cycles per sample); `cutoff`
    defaults to 0.8 fs / (2 nd) and must be below fs / (2 nd).
    """

    def __init__(self, nd, fs=None, cutoff=None, factors=None):
        self.nd = _check_nd(nd)
        self.fs = 1.0 if fs is None else float(fs)
        if not (math.isfinite(self.fs) and self.fs > 0):
            raise InputError(f"sampling frequency fs must be positive, got {fs!r}.")
        nyquist = self.fs / (2 * self.nd)
        self.cutoff = CUTOFF_FRACTION * nyquist if cutoff is None else float(cutoff)
        if not (0.0 < self.cutoff < nyquist):
            raise InputError(
                f"decimation cut-off {self.cutoff:g} Hz must be in (0, fs/(2 nd)) = "
                f"(0, {nyquist:g}) Hz for fs={self.fs:g} Hz, nd={self.nd}; lower the "
                "cut-off or nd."
            )
        half = min(nyquist - self.cutoff, 0.25 * self.cutoff)
        self.f_pass = self.cutoff - half
        self.f_stop = self.cutoff + half
        self.stages = _plan(self.nd, self.fs, self.f_pass, self.f_stop, factors)
        # Kept-sample grid: walk the cascade keeping track of where each
        # stage's local index 0 sits in the input and its step.
        origin, step, half_total = 0, 1, 0
        self._phases = []
        for taps, down in self.stages:
            h = (len(taps) - 1) // 2
            # Outputs of this stage must land on input indices that are
            # multiples of the cumulative factor: local t = phase mod down.
            total_step = step * down
            phase = (-(origin // step)) % down
            first = h + (phase - h) % down
            self._phases.append(phase)
            origin, step = origin + step * first, total_step
            half_total += (total_step // down) * h
        self.first_index = origin
        self.half_length = half_total

    @property
    def n_taps(self) -> int:
        """Length of the equivalent single FIR (odd)."""
        return 2 * self.half_length + 1

    @property
    def min_samples(self) -> int:
        """Fewest input samples that give one decimated sample."""
        return self.first_index + self.half_length + 1

    def n_outputs(self, n_samples: int) -> int:
        """Number of decimated samples kept from `n_samples` input samples."""
        last = n_samples - 1 - self.half_length
        return max(0, (last - self.first_index) // self.nd + 1)

    def too_short(self, n_samples: int) -> InputError:
        """The error of a signal shorter than the filter; it carries `n_samples`, `min_samples`
        and `nd`, for a caller that can say what the shortfall means (a held-out part)."""
        exc = InputError(
            f"the signal has {n_samples} samples but decimating by nd={self.nd} "
            f"(cut-off {self.cutoff:g} Hz at fs={self.fs:g} Hz) needs at least "
            f"{self.min_samples} (FIR of {self.n_taps} taps); use a longer record, "
            "a smaller nd or no decimation."
        )
        exc.n_samples, exc.min_samples, exc.nd = int(n_samples), int(self.min_samples), int(self.nd)
        return exc


class _Stage:
    """One FIR + keep-one-in-`down` stage on a stream, keeping only a tail.

    Several column blocks ("parts", e.g. W and tau) share the index
    bookkeeping but are never concatenated: the bulk of each chunk is read in
    place and only the outputs straddling the previous tail use a small copy.
    """

    def __init__(self, taps: np.ndarray, down: int, phase: int):
        self.down = down
        self.h = (len(taps) - 1) // 2
        rows = -(-len(taps) // down)
        poly = np.zeros(rows * down)
        poly[: len(taps)] = taps
        # poly[p, r] multiplies input sample (start + p*down + r): one matmul
        # per block of ``down`` samples gives every phase at once.
        self.poly = poly.reshape(rows, down)
        self.next = self.h + (phase - self.h) % down  # next output, local index
        self.t0 = 0  # local index of tails[k][0]
        self.tails = None
        self._work = np.empty(0)

    def _scratch(self, size):
        """A reused flat work array of at least `size` values (`_polyphase`'s products): a
        fresh one per push and column block paid its page faults anew (tens of MB on a
        regressor chunk)."""
        if self._work.size < size:
            self._work = np.empty(size)
        return self._work[:size]

    def push(self, parts):
        """Consume the column blocks `parts` (each (n, c_k)); return theirs."""
        n = parts[0].shape[0]
        tails = self.tails or [np.empty((0, p.shape[1])) for p in parts]
        n_tail = tails[0].shape[0]
        down, h, rows = self.down, self.h, self.poly.shape[0]
        start = self.next - h - self.t0  # window start of next output, >= 0
        last = self.t0 + n_tail + n - 1 - h
        count = (last - self.next) // down + 1 if last >= self.next else 0
        # Outputs whose window starts in the tail need [tail; head of chunk].
        n_joined = min(count, max(0, -(-(n_tail - start) // down)))
        head = min(n, start + (n_joined - 1 + rows) * down - n_tail) if n_joined else 0
        outs = []
        for part, tail in zip(parts, tails):
            pieces = []
            if n_joined:
                joined = np.concatenate((tail, part[:head]))
                pieces.append(_polyphase(joined, start, n_joined, self.poly, down, self._scratch))
            if count > n_joined:
                s_in = start + n_joined * down - n_tail
                pieces.append(_polyphase(part, s_in, count - n_joined, self.poly, down, self._scratch))
            outs.append(
                pieces[0] if len(pieces) == 1
                else np.concatenate(pieces) if pieces
                else np.empty((0, part.shape[1]))
            )
        self.next += count * down
        # Samples before the next window are no longer needed (at the very
        # start that can be more than has arrived yet).
        keep = min(self.next - h - self.t0, n_tail + n)
        # Copies: a view would keep the caller's whole chunk alive.
        if keep >= n_tail:
            self.tails = [p[keep - n_tail :].copy() for p in parts]
        else:
            self.tails = [np.concatenate((t[keep:], p)) for t, p in zip(tails, parts)]
        self.t0 += keep
        return outs


def _polyphase(buf: np.ndarray, start: int, count: int, poly: np.ndarray, down: int, scratch=None):
    """`out[i] = sum_j taps[j] * buf[start + i*down + j]` for i < count (`scratch(size)`: a
    flat work array to reuse for the products, else a fresh one)."""
    rows, n_cols = poly.shape[0], buf.shape[1]
    if count == 0:
        return np.empty((0, n_cols))
    n_blocks = count - 1 + rows
    full = min(n_blocks, (buf.shape[0] - start) // down)
    size = n_blocks * rows * n_cols
    z = (np.empty(size) if scratch is None else scratch(size)).reshape(n_blocks, rows, n_cols)
    np.matmul(poly, buf[start : start + full * down].reshape(full, down, n_cols), out=z[:full])
    if full < n_blocks:
        # Last blocks run past the data only where the padded taps are zero.
        pad = np.zeros(((n_blocks - full) * down, n_cols))
        rest = buf[start + full * down :]
        pad[: rest.shape[0]] = rest
        np.matmul(poly, pad.reshape(n_blocks - full, down, n_cols), out=z[full:])
    out = z[:count, 0].copy()
    for p in range(1, rows):
        out += z[p : p + count, p]
    return out


class ParallelDecimator:
    """Streaming parallel decimation (eq. (9)) with bounded memory.

    `push(*chunks)` takes one or several arrays with the same number of
    samples (time on axis 0, any trailing shape, fixed from the first push),
    e.g. a regressor chunk (n, n_joints, n_params) and a torque chunk
    (n, n_joints), and returns the decimated samples it can already finalise
    (an array, or a tuple of arrays if several were pushed).  All arrays go
    through one filter, so their kept indices are identical.  `finish()`
    checks the record and returns what is left (always empty: every output
    is produced as soon as its window is complete).  Concatenating all
    outputs equals `decimate` on the whole record.

    Memory held between pushes: the last ~`n_taps + nd` samples.

    After `finish()`: `indices` (kept input indices), `dropped_start`
    and `dropped_end` (grid samples lost to the filter transients).
    `n_samples_total`, if given, is checked and lets a too-short record be
    reported before any work.  `factors` forces the stage split, e.g.
    `(nd,)` for a single stage or `(10, 10)`; by default it is chosen
    as described in the module docstring.
    """

    def __init__(self, nd, n_samples_total=None, fs=None, cutoff=None, factors=None):
        self.filter = DecimationFilter(nd, fs, cutoff, factors)
        self.nd = self.filter.nd
        self.n_samples_total = None
        if n_samples_total is not None:
            self.n_samples_total = int(n_samples_total)
            if self.filter.n_outputs(self.n_samples_total) == 0:
                raise self.filter.too_short(self.n_samples_total)
        self._stages = [
            _Stage(taps, down, phase)
            for (taps, down), phase in zip(self.filter.stages, self.filter._phases)
        ]
        self._shapes = None
        self.n_in = 0
        self.n_out = 0
        self.finished = False
        self.dropped_start = None
        self.dropped_end = None

    @property
    def indices(self) -> np.ndarray:
        """Input indices of the samples output so far."""
        return self.filter.first_index + self.nd * np.arange(self.n_out)

    def _shaped(self, outs):
        parts = [o.reshape((o.shape[0],) + s) for o, s in zip(outs, self._shapes)]
        return parts[0] if len(parts) == 1 else tuple(parts)

    def push(self, *chunks):
        if self.finished:
            raise InputError("push() after finish(): start a new ParallelDecimator.")
        if not chunks:
            raise InputError("push() needs at least one array.")
        arrays = [np.asarray(c, dtype=float) for c in chunks]
        if any(a.ndim == 0 for a in arrays):
            raise InputError("push() takes arrays with time on axis 0, got a scalar.")
        n = arrays[0].shape[0]
        if any(a.shape[0] != n for a in arrays):
            raise InputError(
                "arrays pushed together must have the same number of samples, got "
                f"{[a.shape[0] for a in arrays]}."
            )
        shapes = [a.shape[1:] for a in arrays]
        if self._shapes is None:
            self._shapes = shapes
        elif shapes != self._shapes:
            raise InputError(
                f"chunk shapes {shapes} differ from the first push {self._shapes}; "
                "push the same columns every time."
            )
        if self.n_samples_total is not None and self.n_in + n > self.n_samples_total:
            raise InputError(
                f"pushed {self.n_in + n} samples, more than n_samples_total="
                f"{self.n_samples_total}."
            )
        flat = [a.reshape(n, math.prod(a.shape[1:])) for a in arrays]
        self.n_in += n
        x = [np.ascontiguousarray(a) for a in flat]
        for stage in self._stages:
            x = stage.push(x)
        # Checking the few outputs is ~10x cheaper than the input; a NaN/inf
        # in any used input sample reaches an output (only samples that no
        # kept window covers, i.e. dropped transients, escape, harmlessly).
        if not all(np.isfinite(o).all() for o in x):
            self._report_non_finite(flat, n)
        self.n_out += x[0].shape[0]
        return self._shaped(x)

    def _report_non_finite(self, flat, n):
        # The bad sample is in this chunk or in the tail of an earlier one.
        bad_rows = [np.nonzero(~np.isfinite(a).all(axis=1))[0] for a in flat]
        bad = [r[0] for r in bad_rows if r.size]
        where = (
            f"sample {self.n_in - n + min(bad)}" if bad
            else f"one of the {self.filter.n_taps} samples before sample {self.n_in - n}"
        )
        raise InputError(
            f"{where} contains NaN or inf; remove or interpolate the missing samples "
            "before decimating."
        )

    def finish(self):
        if self._shapes is None:
            raise InputError("finish() before any push(): nothing to decimate.")
        if self.n_samples_total is not None and self.n_in != self.n_samples_total:
            raise InputError(
                f"received {self.n_in} samples but n_samples_total={self.n_samples_total}."
            )
        if self.n_out == 0:
            raise self.filter.too_short(self.n_in)
        self.finished = True
        first = self.filter.first_index // self.nd
        self.dropped_start = first
        self.dropped_end = (self.n_in - 1) // self.nd - (first + self.n_out - 1)
        return self._shaped([np.empty((0, math.prod(s))) for s in self._shapes])


class Decimated(tuple):
    """`(samples, indices)` of `decimate`, plus edge information.

    Attributes: `samples`, `indices` (into the input samples),
    `dropped_start`, `dropped_end` (kept-grid samples lost to the filter
    transient at each end), `n_taps` (equivalent FIR length).
    """

    def __new__(cls, samples, indices, dropped_start, dropped_end, n_taps):
        self = super().__new__(cls, (samples, indices))
        self.dropped_start = dropped_start
        self.dropped_end = dropped_end
        self.n_taps = n_taps
        return self

    @property
    def samples(self) -> np.ndarray:
        return self[0]

    @property
    def indices(self) -> np.ndarray:
        return self[1]

    @property
    def dropped(self) -> int:
        return self.dropped_start + self.dropped_end


def decimate(x, nd, fs=None, cutoff=None) -> Decimated:
    """Parallel decimation of eq. (9) for an in-memory array.

    `x` has time on axis 0 and any trailing shape ((N,), (N, n),
    (N, n, b), ...); every column is filtered by the same zero-phase FIR
    (module docstring) and one sample in `nd` is kept, at input indices
    that are multiples of `nd`.  `fs` defaults to 1; `cutoff` defaults
    to 0.8 fs / (2 nd).

    Returns `Decimated` `(samples, indices)`; samples has shape
    `(len(indices),) + x.shape[1:]`.  `.dropped_start` / `.dropped_end`
    count the grid samples dropped at each end (filter transient).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        raise InputError("decimate() needs an array with time on axis 0, got a scalar.")
    dec = ParallelDecimator(nd, n_samples_total=x.shape[0], fs=fs, cutoff=cutoff)
    samples = dec.push(x)
    dec.finish()
    return Decimated(samples, dec.indices, dec.dropped_start, dec.dropped_end, dec.filter.n_taps)
