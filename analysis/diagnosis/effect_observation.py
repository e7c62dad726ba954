"""The observation system of eq. (9) plus what extra regressor columns are built from.

An unmodelled effect is tested by adding regressor columns to W. Those
columns must be *built at full rate* from the same (q_hat, qd_hat, qdd_hat, t)
as W and go through the *same* processing as W and Y: zeroed in the velocity
dead zone, then low-pass filtered and down-sampled by the same parallel
decimation. Only then does `decimate(W) chi + decimate(C) theta` stand for
`decimate(W chi + C theta)` row by row (the filter is linear).

`observe_effects` repeats `dynid.analysis.processing.observation.observe` step by
step (same settings, filter, edges, dead zone, decimator; its decimated W and
tau are identical, a test checks it) and keeps the full-rate kept samples
(q_hat, qd_hat, qdd_hat, t, tau, dead zone), plus the full-rate standard
regressor columns of the last link's mass and first moments (the `payload`
effect). `EffectObservation.decimate` then pushes any full-rate columns
through the same dead zone and decimation. With `cache_regressor` the
full-rate base regressor is kept too (memory N x n x b x 8 bytes), so the
model torque of any parameter vector is cheap; otherwise it is rebuilt chunk
by chunk when asked for. With `cache_regressor="pairs"` (the default) only its
(joint, column) pairs that are not identically zero are kept (`RegressorPairs`: about half
of them on a 6-joint arm), with the same numbers out of every method: half the memory, and
on a machine where fresh memory is slow to fault in (a VM: some 4 ms per MB measured) that
is time too.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace

import numpy as np

from dynid.analysis.processing.decimation import ParallelDecimator
from dynid.analysis.processing.observation import CHUNK, Observation, dead_zone_notice, decimation_notice, full_rate
from dynid.dynamics.regressor import regressor
from dynid.errors import DataError, InputError

__all__ = ["EffectObservation", "observe_effects", "payload_parameter_names", "CACHE_LIMIT_BYTES"]

#: ``cache_regressor="auto"`` keeps the full-rate base regressor below this size.
CACHE_LIMIT_BYTES = 400e6

#: Rows of the shifted regressor's arithmetic per step (`shifted_regressor`): a block that
#: stays in the cache.
_SUB_BYTES = 1 << 20

#: Bytes of the regressor (and payload) columns per chunk of `observe_effects`.
_OBSERVE_BYTES = 1 << 23

#: Bytes of the shifted regressor pushed to the decimator at a time (`_shift_and_decimate`):
#: measured on a 20 s, 5 kHz TX40 recording (166 pairs), 14 delays took 0.55 s in chunks of
#: 2500 rows against 0.75 s in chunks of 20000 (the observation's `CHUNK`), whose 26 MB the
#: decimator read back from memory.
_SHIFT_BYTES = 1 << 22


def _shift_chunk(width, sub):
    """Rows per chunk of `_shift_and_decimate` for `width` columns: `_SHIFT_BYTES`, at least `sub`."""
    return max(sub, _SHIFT_BYTES // max(1, 8 * width))


#: Values per chunk when the full-rate regressor is rebuilt from its pairs (`regressor_chunks`).
_PAIR_ROWS = 1 << 19

#: The last link's standard parameters the payload effect adds to (mass, first moments).
PAYLOAD_SYMBOLS = ("M", "MX", "MY", "MZ")


def payload_parameter_names(robot):
    """Standard-parameter names of the last link's mass and first moments, e.g. ['M6', 'MX6', ...]."""
    n = robot.n_joints
    return [f"{s}{n}" for s in PAYLOAD_SYMBOLS]


@dataclass(frozen=True, eq=False)
class RegressorPairs:
    """The full-rate base regressor (N, n, b) without its identically zero (joint, column) pairs.

    `flat` (P,): the kept pairs' indices into the flattened (n * b) pairs, sorted (joint by
    joint); `data` (N, P): their values; `shape`: (n, b). Every pair left out is exactly zero
    in this recording. `nonzero` (n, b): the pairs not identically zero (a subset of `flat`).
    """

    flat: np.ndarray
    data: np.ndarray
    shape: tuple
    nonzero: np.ndarray

    def fill(self, rows, out):
        """Rows `rows` (a slice) of the regressor, into `out` (len, n * b): its left-out pairs
        must be zero already (they are never written)."""
        out[:, self.flat] = self.data[rows]
        return out

    def subset(self, idx):
        """The pairs of the base columns `idx` (in that order), as a new `RegressorPairs`."""
        n, b = self.shape
        idx = np.asarray(idx, dtype=int)
        k = idx.size
        new_of_old = np.full(b, -1)
        new_of_old[idx] = np.arange(k)
        joint, col = self.flat // b, self.flat % b
        new = new_of_old[col]
        take = np.flatnonzero(new >= 0)
        flat = joint[take] * k + new[take]
        order = np.argsort(flat, kind="stable")
        return RegressorPairs(flat=flat[order], data=np.ascontiguousarray(self.data[:, take[order]]),
                              shape=(n, k), nonzero=self.nonzero[:, idx])


#: Random motions the structurally nonzero pairs of the regressor are found at (`_structural_pairs`).
_PROBE_STATES = 8


def _structural_pairs(robot, columns):
    """(n * len(columns),) bool: the regressor's (joint, column) pairs that are nonzero at some
    random motion (the others are zero by the robot's structure: a joint's row has no columns
    of the links before it, nor the other joints' drive terms)."""
    n = robot.n_joints
    q, qd, qdd = np.random.default_rng(7).uniform(-2.0, 2.0, (3, _PROBE_STATES, n))
    W = regressor(robot, q, qd, qdd, columns=np.asarray(columns, dtype=int))
    return np.any(W != 0, axis=0).ravel()


@dataclass
class EffectObservation:
    """A recording prepared for effect columns: the decimated system and its full-rate sources.

    `obs` is the decimated observation system exactly as `observe`
    builds it. The full-rate arrays cover the kept samples (the recording
    without the position filter's edges): `t` (N,), `q`, `qd`, `qdd`
    (N, n), `tau` (N, n), `dead` (N, n) the velocity dead zone (None if
    off), `payload` (N, n, 4) the standard-regressor columns of the last
    link's M, MX, MY, MZ. `keep` is the slice of the recording they come from.
    The full-rate base regressor, when kept: `W_full` (N, n, b), or `pairs` (its pairs that
    are not identically zero, `RegressorPairs`; `W_full` is then None).
    """

    obs: Observation
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    dead: np.ndarray | None
    payload: np.ndarray
    keep: slice
    fs: float
    settings: dict
    robot: object = None
    bp: object = None
    source: str = ""
    W_full: np.ndarray | None = None
    notices: list = field(default_factory=list)
    pairs: RegressorPairs | None = None

    # ------------------------------------------------------------- sizes
    @property
    def n_full(self) -> int:
        return self.t.shape[0]

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    @property
    def t_start(self) -> float:
        """Time of the recording's first sample (before the dropped edge), s."""
        return float(self.t[0] - self.keep.start / self.fs)

    @property
    def duration(self) -> float:
        """Duration of the whole recording, s (its samples / fs)."""
        return float(self.obs.n_raw / self.fs)

    # ------------------------------------------------------------- decimation
    def _decimator(self):
        """A fresh `ParallelDecimator` of this recording: a copy of one designed once per
        observation (the filter design, a Kaiser FIR per candidate split of nd, cost more than
        decimating a few columns, and the diagnosis asks for some 60)."""
        template = self.__dict__.get("_decimator_template")
        if template is None:
            s = self.settings
            template = ParallelDecimator(int(s["nd"]), n_samples_total=self.n_full, fs=self.fs,
                                         cutoff=s["f_decimation_cutoff"])
            self.__dict__["_decimator_template"] = template
        return copy.deepcopy(template)

    def decimate(self, columns, joint=None):
        """Decimated version of full-rate columns, with the dead zone and decimation of W.

        `columns` is (N, n, k) (a column per joint row), or (N, k) together
        with `joint` (0-based): columns that act on that joint only (zero on
        the others). Returns (M, n, k) aligned with `obs.W`.
        """
        C = np.asarray(columns, dtype=float)
        if C.shape[0] != self.n_full:
            raise DataError(f"effect columns have {C.shape[0]} samples, the kept recording {self.n_full}")
        if joint is not None:
            C = C.reshape(self.n_full, -1)
            if self.dead is not None:
                C = C * (~self.dead[:, joint])[:, None]
            D = self._decimate_2d(C)
            out = np.zeros((D.shape[0], self.n_joints, D.shape[1]))
            out[:, joint, :] = D
            return out
        if C.ndim == 2:
            C = C[:, :, None]
        if self.dead is not None:
            C = C * (~self.dead)[:, :, None]
        k = C.shape[2]
        D = self._decimate_2d(C.reshape(self.n_full, -1))
        return D.reshape(D.shape[0], self.n_joints, k)

    def _decimate_2d(self, C):
        if int(self.settings["nd"]) <= 1:
            return np.array(C, dtype=float)
        dec = self._decimator()
        parts = [dec.push(C[start:start + CHUNK]) for start in range(0, self.n_full, CHUNK)]
        dec.finish()
        return np.concatenate(parts, axis=0)

    def decimate_joint_blocks(self, blocks):
        """Decimate many single-joint column blocks at once.

        `blocks` is a list of `(columns (N, k), joint (0-based))`, the columns
        possibly given as a callable that builds them: they are then built one
        joint at a time (a joint's blocks are all the memory held). The blocks of
        one joint are stacked and decimated in one pass. Returns a list of
        (M, n, k) arrays in the order given.
        """
        out = [None] * len(blocks)
        by_joint = {}
        for i, (_C, j) in enumerate(blocks):
            by_joint.setdefault(j, []).append(i)
        flat = np.empty(0)
        for j, idx in by_joint.items():
            mats = [np.asarray(blocks[i][0]() if callable(blocks[i][0]) else blocks[i][0],
                               dtype=float).reshape(self.n_full, -1) for i in idx]
            widths = [m.shape[1] for m in mats]
            # stacked (and zeroed in the dead zone) into one buffer reused joint after joint:
            # a fresh stack and a masked copy of it per joint cost more in page faults than
            # the products (the same values: each column times the joint's 0/1 mask)
            if flat.size < self.n_full * sum(widths):
                flat = np.empty(self.n_full * sum(widths))
            C = flat[:self.n_full * sum(widths)].reshape(self.n_full, sum(widths))
            keep = None if self.dead is None else (~self.dead[:, j])[:, None]
            pos = 0
            for m, w in zip(mats, widths):
                if keep is None:
                    C[:, pos:pos + w] = m
                else:
                    np.multiply(m, keep, out=C[:, pos:pos + w])
                pos += w
            del mats
            D = self._decimate_2d(C)
            pos = 0
            for i, w in zip(idx, widths):
                block = np.zeros((D.shape[0], self.n_joints, w))
                block[:, j, :] = D[:, pos:pos + w]
                out[i] = block
                pos += w
        return out

    # ------------------------------------------------------------- model torque
    def regressor_chunks(self):
        """Yield `(slice, W_base chunk (n_chunk, n, b))` over the kept samples, full rate."""
        if self.W_full is not None:
            for start in range(0, self.n_full, CHUNK):
                sl = slice(start, min(self.n_full, start + CHUNK))
                yield sl, self.W_full[sl]
            return
        if self.pairs is not None:
            # one zeroed buffer of a few MB (its left-out pairs stay zero), refilled per chunk:
            # each row's product is the same whatever the chunk
            n, b = self.pairs.shape
            rows = max(1, min(self.n_full, _PAIR_ROWS // max(1, n * b)))
            buf = np.zeros((rows, n * b))
            for start in range(0, self.n_full, rows):
                sl = slice(start, min(self.n_full, start + rows))
                yield sl, self.pairs.fill(sl, buf[:sl.stop - start]).reshape(-1, n, b)
            return
        if self.robot is None or self.bp is None:
            raise DataError("this EffectObservation keeps neither the robot nor the full-rate regressor")
        for start in range(0, self.n_full, CHUNK):
            sl = slice(start, min(self.n_full, start + CHUNK))
            W = regressor(self.robot, self.q[sl], self.qd[sl], self.qdd[sl],
                          columns=self.bp.independent)
            yield sl, W

    def model_torque(self, columns, chi, *, exclude=None):
        """Full-rate torque (N, n) of the model `W_base[:, :, columns] @ chi`.

        `exclude`: a boolean (len(columns),) of parameters left out (e.g. the
        friction terms, for the torque the transmission carries).
        """
        return self.model_torques(columns, [(chi, exclude)])[0]

    def model_torques(self, columns, models):
        """`model_torque(columns, chi, exclude=exclude)` of each `(chi, exclude)` in `models`,
        in one pass over the full-rate regressor (the same numbers as one call each)."""
        b = self.W_full.shape[2] if self.W_full is not None else (
            self.pairs.shape[1] if self.pairs is not None else -1)
        specs = []
        for chi, exclude in models:
            cols = np.asarray(columns, dtype=int)
            chi = np.asarray(chi, dtype=float)
            if exclude is not None:
                keep = ~np.asarray(exclude, dtype=bool)
                cols, chi = cols[keep], chi[keep]
            # all columns in order: the chunk itself, not a gathered copy of it (the same product)
            specs.append((None if b >= 0 and np.array_equal(cols, np.arange(b)) else cols, chi))
        taus = [np.empty((self.n_full, self.n_joints)) for _ in specs]
        for sl, W in self.regressor_chunks():
            for tau, (cols, chi) in zip(taus, specs):
                tau[sl] = (W if cols is None else W[:, :, cols]) @ chi
        return taus

    def shifted_regressor(self, columns, d):
        """Decimated base-regressor columns of the motion shifted by `d` s: W(t - d).

        The full-rate columns are shifted by linear interpolation (ends
        held), zeroed in the (unshifted) velocity dead zone like the torque,
        and decimated, chunk by chunk. `d > 0`: the torque samples are late
        against the positions. Returns (M, n, len(columns)).
        """
        cols = np.asarray(columns, dtype=int)
        N, n, k = self.n_full, self.n_joints, cols.size
        x = float(d) * self.fs
        si = int(np.floor(x))
        frac = x - si
        full = self.W_full is not None and k == self.W_full.shape[2] and np.array_equal(
            cols, np.arange(k))

        def source(a, b):
            """Rows clip(a..b-1, 0, N-1) of the regressor: a view inside the recording (no
            gather copy per delay), the ends held by a clipped index only at its edges."""
            if self.W_full is not None:
                rows = _held_rows(self.W_full, a, b)
                return rows if full else rows[:, :, cols]
            lo, hi = min(max(a, 0), N - 1), max(min(b, N), 1)
            W = regressor(self.robot, self.q[lo:hi], self.qd[lo:hi], self.qdd[lo:hi],
                          columns=np.asarray(self.bp.independent)[cols])
            return W[np.clip(np.arange(a, b), lo, hi - 1) - lo]

        if self.W_full is not None or self.pairs is not None:
            # only the (joint, column) pairs that are not identically zero (a joint's row
            # has no columns of the links before it, nor the other joints' drive terms:
            # about half of them on a 6-joint arm); the others stay exact zeros
            sel = np.flatnonzero(self._nonzero_pairs()[:, cols].ravel())
            if sel.size < n * k or self.pairs is not None:
                return self._shifted_pairs(cols, sel, si, frac)
        nd = int(self.settings["nd"])
        dec = self._decimator() if nd > 1 else None
        keep = None if self.dead is None else (~self.dead)[:, :, None].astype(float)
        # (without the cached regressor, `source` builds the rows: one call per chunk)
        sub = max(1, _SUB_BYTES // max(1, 8 * n * k)) if self.W_full is not None else CHUNK
        D = _shift_and_decimate(source, N, (n, k), si, frac,
                                None if keep is None else lambda out, src, a, b: np.multiply(src, keep[a:b], out=out),
                                dec, sub, chunk=_shift_chunk(n * k, sub) if self.W_full is not None else CHUNK)
        return D.reshape(D.shape[0], n, k)

    def _nonzero_pairs(self):
        """(n, b) bool: the full-rate regressor's (joint, column) pairs not identically zero
        (computed once per observation; `with_base` makes a new one)."""
        nz = self.__dict__.get("_nonzero")
        if nz is None and self.pairs is not None:
            nz = self.pairs.nonzero
        if nz is None:
            nz = np.zeros(self.W_full.shape[1:], dtype=bool)
            for start in range(0, self.n_full, CHUNK):
                nz |= np.any(self.W_full[start:start + CHUNK] != 0, axis=0)
            self.__dict__["_nonzero"] = nz
        return nz

    def _pair_keep(self, joint):
        """(N, len(joint)) bool: outside the velocity dead zone of each pair's joint (kept for
        the next delays, whose pairs are the same)."""
        cached = self.__dict__.get("_pair_keep_cache")
        if cached is None or not np.array_equal(cached[0], joint):
            cached = (joint, np.ascontiguousarray((~np.asarray(self.dead, dtype=bool))[:, joint]))
            self.__dict__["_pair_keep_cache"] = cached
        return cached[1]

    def _shifted_pairs(self, cols, sel, si, frac):
        """`shifted_regressor` of the flat (joint, column) pairs `sel` of (n, len(cols)) only,
        the others zero: the same operations on each pair, in the same order."""
        N, n, k = self.n_full, self.n_joints, cols.size
        b_all = self.W_full.shape[2] if self.W_full is not None else self.pairs.shape[1]
        joint = sel // k
        flat = joint * b_all + cols[sel % k]          # pairs in the flattened (n * b) rows
        if self.W_full is None:
            # the kept pairs are the nonzero ones or more: read in place when they are these
            stored = self.pairs.flat
            if np.array_equal(stored, flat):
                Wp, pick = self.pairs.data, slice(None)
            else:
                Wp, pick = self.pairs.data, np.searchsorted(stored, flat)
        else:
            # the pairs gathered once into a contiguous copy, kept for the next
            # delays (the delay grid shifts the same columns 14 times per step), unless that
            # copy would pass half the regressor cache's limit: then gathered block by block
            W2 = self.W_full.reshape(N, n * b_all)
            cached = self.__dict__.get("_pairs")
            if (cached is None or not np.array_equal(cached[0], flat)) and N * flat.size * 8 <= CACHE_LIMIT_BYTES / 2:
                Wp = np.empty((N, flat.size))
                for start in range(0, N, CHUNK):
                    Wp[start:start + CHUNK] = W2[start:start + CHUNK][:, flat]
                cached = (flat, Wp)
                self.__dict__["_pairs"] = cached
            if cached is not None and np.array_equal(cached[0], flat):
                Wp, pick = cached[1], slice(None)
            else:
                Wp, pick = W2, flat

        def source(a, b):
            return _held_rows(Wp, a, b)[:, pick]

        keep = None if self.dead is None else self._pair_keep(joint)

        def zero_dead(out, src, a, b):
            # times the pair's joint's 0/1 (a bool, cast to 1.0 or 0.0: the same products as
            # a float mask) in one contiguous pass; per joint, a run of a few columns per row
            # cost three times as much
            np.multiply(src, keep[a:b], out=out)

        nd = int(self.settings["nd"])
        dec = self._decimator() if nd > 1 else None
        m = sel.size
        sub = max(1, _SUB_BYTES // max(1, 8 * m))
        D = _shift_and_decimate(source, N, (m,), si, frac, None if keep is None else zero_dead,
                                dec, sub, buffers=self.__dict__.setdefault("_shift_buffers", {}),
                                chunk=_shift_chunk(m, sub))
        out = np.zeros((D.shape[0], n * k))
        out[:, sel] = D
        return out.reshape(D.shape[0], n, k)

    # ------------------------------------------------------------- variants
    def with_base(self, bp_sub):
        """The same data for a base-parameter set that is a subset of this one's.

        E.g. `dynid.analysis.diagnosis.selection.without_parameters(bp, ("Off",))`: a model
        without torque offsets. W (decimated and cached full-rate) keeps the
        columns of `bp_sub` only.
        """
        pos = {int(c): k for k, c in enumerate(np.asarray(self.bp.independent))}
        try:
            idx = [pos[int(c)] for c in np.asarray(bp_sub.independent)]
        except KeyError:
            raise DataError("with_base: the new base parameters are not a subset of this "
                            "observation's") from None
        obs = replace(self.obs, W=self.obs.W[:, :, idx], names=list(bp_sub.names))
        W_full = None if self.W_full is None else self.W_full[:, :, idx]
        pairs = None if self.pairs is None else self.pairs.subset(idx)
        return replace(self, obs=obs, bp=bp_sub, W_full=W_full, pairs=pairs)

    def with_torque(self, tau_recording):
        """The same motion with another recorded torque (N_raw, n) (e.g. an injected effect).

        Only the torque is decimated again (with the same dead zone and filter);
        the regressor, full-rate signals and cache are shared, not copied.
        """
        tau_recording = np.asarray(tau_recording, dtype=float)
        tau = tau_recording[self.keep]
        if tau.shape != self.q.shape:
            raise DataError(f"torque of shape {tau_recording.shape} does not match the recording "
                            f"({self.keep.stop - self.keep.start} kept samples of {self.n_joints} joints)")
        taud = self.decimate(tau[:, :, None])[:, :, 0]
        obs = replace(self.obs, tau=taud)
        return replace(self, obs=obs, tau=tau)


def observe_effects(experiment, robot, bp, settings=None, *, cache_regressor="pairs",
                    progress=None) -> EffectObservation:
    """`dynid.analysis.processing.observation.observe`, keeping what effect columns are built from.

    Same steps and settings as `observe` (its decimated W, tau, q, qd, qdd,
    t and row mask are reproduced exactly); `settings` are overrides or a
    resolved settings dict (e.g. an identification's, for validation data).
    `cache_regressor`: "pairs" (default: keep the full-rate base regressor's (joint, column)
    pairs that are not identically zero, `EffectObservation.pairs`, when the whole regressor
    would take less than `CACHE_LIMIT_BYTES`: the same numbers in half the memory), "auto"
    (the whole regressor, `EffectObservation.W_full`, under the same limit), True or False.
    """
    q_meas = experiment.q
    if q_meas is None:
        raise DataError(f"{experiment.source}: the residual diagnosis needs measured joint positions "
                        "(q1..qn)")
    fr = full_rate(experiment, robot, q_meas, settings)
    s, fs, N, dead, keep = fr.settings, fr.fs, fr.n_raw, fr.dead, fr.keep
    qf, qd, qdd, tau, t = fr.q, fr.qd, fr.qdd, fr.tau, fr.t
    notices = [fr.edge_notice]
    nd = int(s["nd"])
    n_kept = qf.shape[0]
    if dead is not None:
        # observe's notices: its observation system is this one's `obs`
        notices.append(dead_zone_notice(s, dead))
    b = len(bp.independent)
    std_names = robot.standard_names
    pay_idx = [std_names.index(nm) for nm in payload_parameter_names(robot)]
    columns = np.concatenate([np.asarray(bp.independent, dtype=int), np.asarray(pay_idx, dtype=int)])
    n = robot.n_joints
    if not (isinstance(cache_regressor, bool) or cache_regressor in ("auto", "pairs")):
        raise InputError(f"cache_regressor must be True, False, 'auto' or 'pairs', got {cache_regressor!r}")
    as_pairs = cache_regressor == "pairs"
    if cache_regressor in ("auto", "pairs"):
        cache_regressor = n_kept * n * b * 8 <= CACHE_LIMIT_BYTES
    as_pairs = as_pairs and bool(cache_regressor)
    store = {"W_full": np.empty((n_kept, n, b)) if cache_regressor and not as_pairs else None}
    payload = np.empty((n_kept, n, len(pay_idx)))
    keep_rows = None if dead is None else ~dead

    # chunks of a few MB: the decimator then reads them from the cache (measured on a 20 s,
    # 5 kHz TX40 recording: 0.4 s in chunks of 2500 rows against 0.6-1.4 s in chunks of
    # 20000); the outputs do not depend on the chunk
    chunk = min(CHUNK, max(1, _OBSERVE_BYTES // (8 * n * columns.size)))
    chunk_buf = np.empty((min(n_kept, chunk), n, columns.size))
    if as_pairs:
        structural = _structural_pairs(robot, bp.independent)
        kept_pairs = np.flatnonzero(structural)
        width = columns.size
        # the kept pairs' places in a chunk of the buffer (its rows hold the payload columns too)
        in_buf = (kept_pairs // b) * width + kept_pairs % b
        store.update(data=np.empty((n_kept, kept_pairs.size)), nonzero=np.zeros(n * b, dtype=bool))

    def chunk_regressor(sl):
        # into one reused buffer (its parts are copied out below, or masked into another)
        Wc = regressor(robot, qf[sl], qd[sl], qdd[sl], columns=columns,
                       out=chunk_buf[:sl.stop - sl.start])
        payload[sl] = Wc[:, :, b:]
        Wb = Wc[:, :, :b]
        if store["W_full"] is not None:
            store["W_full"][sl] = Wb
        elif as_pairs and "data" in store:
            nz = np.any(Wb != 0, axis=0).ravel()
            if np.any(nz & ~structural):
                _pairs_to_full(store, kept_pairs, sl.start, (n_kept, n, b))   # never seen: kept in full
                store["W_full"][sl] = Wb
            else:
                store["nonzero"] |= nz
                np.take(Wc.reshape(Wc.shape[0], -1), in_buf, axis=1, out=store["data"][sl], mode="clip")
        return Wb

    if nd <= 1:
        W = np.concatenate([chunk_regressor(slice(a, min(n_kept, a + chunk))).copy()   # the buffer is reused
                            for a in range(0, n_kept, chunk)], axis=0)
        mask = np.ones(tau.shape, dtype=bool) if dead is None else keep_rows.copy()
        Wd, taud = W * mask[:, :, None], tau * mask
        obs = Observation(W=Wd, tau=taud, t=t, q=qf, qd=qd, qdd=qdd, row_mask=mask,
                          names=list(bp.names), settings=s, notices=list(notices), n_raw=N)
    else:
        dec = ParallelDecimator(nd, n_samples_total=n_kept, fs=fs, cutoff=s["f_decimation_cutoff"])
        parts = []
        # one buffer for the masked chunks (the decimator copies what it keeps): a fresh
        # array per chunk costs more in page faults than the product
        buf = None if keep_rows is None else np.empty((min(n_kept, chunk), n, b))
        for start in range(0, n_kept, chunk):
            sl = slice(start, min(n_kept, start + chunk))
            W = chunk_regressor(sl)
            tc = tau[sl]
            if keep_rows is not None:
                # as dynid.analysis.processing.observation.push_chunk: zero both sides in the dead zone
                W = np.multiply(W, keep_rows[sl][:, :, None], out=buf[:sl.stop - sl.start])
                tc = tc * keep_rows[sl]
            kept = np.ones(tc.shape) if dead is None else keep_rows[sl].astype(float)
            parts.append(dec.push(W, tc, qf[sl], qd[sl], qdd[sl], kept))
            if progress is not None:
                progress(sl.stop / n_kept)
        dec.finish()
        Wd, taud, qf_d, qd_d, qdd_d, kept_frac = (np.concatenate([p[k] for p in parts], axis=0)
                                                  for k in range(6))
        td = t[dec.indices]
        notices.append(decimation_notice(s, n_kept, dec))
        obs = Observation(W=Wd, tau=taud, t=td, q=qf_d, qd=qd_d, qdd=qdd_d,
                          row_mask=kept_frac >= 0.5, names=list(bp.names), settings=s,
                          notices=list(notices), n_raw=N)
    pairs = None
    if as_pairs and "data" in store:
        pairs = RegressorPairs(flat=kept_pairs, data=store["data"], shape=(n, b),
                               nonzero=store["nonzero"].reshape(n, b))
    return EffectObservation(obs=obs, t=t, q=qf, qd=qd, qdd=qdd, tau=tau, dead=dead,
                             payload=payload, keep=keep, fs=float(fs), settings=s, robot=robot,
                             bp=bp, source=str(experiment.source), W_full=store["W_full"],
                             notices=notices, pairs=pairs)


def _pairs_to_full(store, kept_pairs, rows, shape):
    """Switch `observe_effects`' store from pairs to the full regressor, its first `rows` rows
    from the pairs (a pair the structural probe missed is nonzero in this recording)."""
    N, n, b = shape
    W_full = np.zeros(shape)
    W_full.reshape(N, n * b)[:rows, kept_pairs] = store["data"][:rows]
    store["W_full"] = W_full
    del store["data"], store["nonzero"]


def _held_rows(A, a, b):
    """Rows a..b-1 of `A` with the ends held (indices clipped to its rows): a view of `A` when
    they lie inside it, a gathered copy only at its edges."""
    if a >= 0 and b <= A.shape[0]:
        return A[a:b]
    return A[np.clip(np.arange(a, b), 0, A.shape[0] - 1)]


def _shift_and_decimate(source, N, tail, si, frac, keep, dec, sub, buffers=None, chunk=CHUNK):
    """Rows `source(a - si, b - si)` delayed by a further `frac` sample (linear interpolation
    between neighbours), zeroed in the velocity dead zone by `keep(out, src, a, b)` where given
    (`out = src * keep` of rows a..b-1, `src` may be `out`), decimated by `dec` (None: kept at
    full rate): (M, prod(tail)).

    Two chunk buffers serve the whole pass: a fresh 50 MB array per chunk and delay costs
    more in page faults than in arithmetic (the decimator copies what it keeps). The
    arithmetic runs on sub-blocks of `sub` rows that stay in the cache: one pass over memory,
    not four, with the same operations in the same order, so the same numbers. `buffers`: a
    dict that keeps the two buffers for the next call (the delay grid shifts the same columns
    14 times per step: one allocation, not 14). `chunk`: rows pushed to the decimator at a
    time (`_shift_chunk`: a few MB, which the decimator then reads from the cache; the
    outputs do not depend on it).
    """
    buffers = {} if buffers is None else buffers
    key = (min(N, chunk), *tail)
    buf = buffers.get(key)
    if buf is None:
        buf = buffers[key] = np.empty(key)
    tmp = None
    if frac:
        tmp = buffers.get(("tmp", sub, *tail))
        if tmp is None:
            tmp = buffers[("tmp", sub, *tail)] = np.empty((min(N, sub), *tail))
    parts = []
    for start in range(0, N, chunk):
        stop = min(N, start + chunk)
        C = buf[:stop - start]
        for a in range(start, stop, sub):
            b = min(stop, a + sub)
            Cs = C[a - start:b - start]
            if frac:
                np.multiply(source(a - si, b - si), 1.0 - frac, out=Cs)
                Cs += np.multiply(source(a - si - 1, b - si - 1), frac, out=tmp[:b - a])
                if keep is not None:
                    keep(Cs, Cs, a, b)
            elif keep is not None:
                keep(Cs, source(a - si, b - si), a, b)
            else:
                Cs[...] = source(a - si, b - si)   # may be a view of the cached regressor: never scaled in place
        C = C.reshape(stop - start, -1)
        parts.append(dec.push(C) if dec is not None else C.copy())   # C is the reused buffer
    if dec is not None:
        dec.finish()
    return np.concatenate(parts, axis=0)
