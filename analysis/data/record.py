"""The `Experiment` record: one recorded trajectory, uniformly sampled, in joint space.

Only the record (its checks, sizes, segments, hash and summary): the loader that
builds it from files is `dynid.analysis.data.experiment`, which re-exports it.
Kept apart so that the column parser (`dynid.analysis.data.columns`) can build an
Experiment without importing the loader that imports it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from dynid.analysis.data import plausibility as plaus
from dynid.analysis.data._format import _fmt_t
from dynid.analysis.data.saturation import saturation_notices
from dynid.analysis.data.timebase import TIME_STEP_TOLERANCE, IrregularTimeSteps, _check_time, _Options, _resample
from dynid.errors import DataError

__all__ = ["Experiment", "SIGNALS", "checked_experiment", "loader_checks", "recording_of", "repeated_recordings", "same_samples", "sample_keys", "shared_run"]

#: Signal names of the column convention, in the order they are stored.
SIGNALS = ("q", "qr", "qd", "qdd", "tau")
#: when a recording's torque was sampled (`meta["torque_timing"]`): the command held over each
#: period (a controller's log), or centred on the samples (an integrating sensor)
TORQUE_TIMINGS = ("held", "centred")


@dataclass(eq=False)
class Experiment:
    """One recorded trajectory, uniformly sampled, in joint space.

    Attributes
    ----------
    t : (N,) time in s, strictly increasing, uniform within the tolerance.
    q, qr, qd, qdd : (N, n) or None, measured / reference positions, velocities,
        accelerations.
    tau : (N, n) joint torques (computed as drive gain × current when the file had
        only `i*`).
    fs : sampling rate in Hz, 1 / median time step.
    source : the file(s) the data came from.
    notices : what the loader ignored, converted, dropped or noticed.
    name : a name for reports (from a TOML `[experiment] name`, else the file stem).
    meta : loader facts, e.g. `reference_shift` (samples), `reference_shift_rms`
        (rad), `start_offset`, `resampled`, `time_from`, `torque_timing` (one of
        `TORQUE_TIMINGS`, when the recording says it).

    Building one checks only shapes, numbers (not complex) and joint counts: an Experiment
    made in memory gets the loader's checks of the data (uniform time, the robot's limits,
    spikes ...) where identify, run, diagnose and validate accept it (`checked_experiment`).
    """

    t: np.ndarray
    q: np.ndarray | None = None
    qr: np.ndarray | None = None
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    tau: np.ndarray | None = None
    fs: float | None = None
    source: str = ""
    notices: list[str] = field(default_factory=list)
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("t",) + SIGNALS:
            value = getattr(self, name)
            if value is not None:
                if np.iscomplexobj(value):      # np.asarray(dtype=float) would drop the imaginary part
                    raise DataError(f"Experiment.{name}: complex values in {name}: dynid needs real numbers. "
                                    f"Store the real values only (e.g. {name}.real, once its imaginary part "
                                    "is known to be zero).")
                try:
                    setattr(self, name, np.asarray(value, dtype=float))
                except (TypeError, ValueError):
                    raise DataError(f"Experiment.{name} must be an array of numbers, got "
                                    f"{type(value).__name__} {str(value)[:40]!r}") from None
        try:
            self.fs = None if self.fs is None else float(self.fs)
        except (TypeError, ValueError):
            raise DataError(f"Experiment.fs must be a sampling rate in Hz, got {self.fs!r}") from None
        self.notices = [] if self.notices is None else self.notices
        self.meta = {} if self.meta is None else self.meta
        if not isinstance(self.notices, (list, tuple)):
            raise DataError(f"Experiment.notices must be a list of strings, got {type(self.notices).__name__}")
        if not isinstance(self.meta, dict):
            raise DataError(f"Experiment.meta must be a dict, got {type(self.meta).__name__}")
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1:
            raise DataError(f"Experiment.t must be 1-D, got shape {t.shape}.")
        if t.size < 2:
            raise DataError(f"An experiment needs at least 2 samples, got {t.size}.")
        self.t = t
        if self.tau is None:
            raise DataError("An experiment needs joint torques (tau); none were given.")
        n = None
        for name in SIGNALS:
            a = getattr(self, name)
            if a is None:
                continue
            a = np.asarray(a, dtype=float)
            if a.ndim == 1:
                a = a[:, None]
            if a.ndim != 2 or a.shape[0] != t.size:
                raise DataError(
                    f"Experiment.{name} has shape {a.shape}; expected ({t.size}, n) "
                    "with one row per time sample."
                )
            if n is None:
                n = a.shape[1]
            elif a.shape[1] != n:
                raise DataError(
                    f"Experiment.{name} has {a.shape[1]} columns but the other signals "
                    f"have {n}: every signal needs one column per joint."
                )
            setattr(self, name, a)
        if self.fs is None:
            step = float(np.median(np.diff(t)))
            if not step > 0:
                raise DataError("Experiment.t must be strictly increasing.")
            self.fs = 1.0 / step
        self.fs = float(self.fs)
        self.notices = list(self.notices)
        self.meta = dict(self.meta)

    # ---- sizes -----------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        """Number of joints n (columns of `tau`)."""
        return int(self.tau.shape[1])

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.size)

    @property
    def duration(self) -> float:
        """Time span `t[-1] - t[0]` in s."""
        return float(self.t[-1] - self.t[0])

    @property
    def signals(self) -> tuple[str, ...]:
        """Names of the signals present, among q, qr, qd, qdd, tau."""
        return tuple(s for s in SIGNALS if getattr(self, s) is not None)

    # ---- operations ------------------------------------------------------------------
    def segment(self, t_start: float | None = None, t_end: float | None = None) -> Experiment:
        """The samples with `t_start <= t < t_end` as a new Experiment.

        `None` means the start / end of the record. The window is half-open, so
        `segment(None, a)` and `segment(a, None)` split the record without overlap
        (e.g. identification and held-out validation data).

        Returns
        -------
        Experiment
            The samples in the window, with the same source, notices and meta.
        """
        lo = -math.inf if t_start is None else float(t_start)
        hi = math.inf if t_end is None else float(t_end)
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise DataError(
                f"segment({t_start!r}, {t_end!r}) of {self.source or 'the experiment'}: "
                "t_start must be smaller than t_end."
            )
        keep = (self.t >= lo) & (self.t < hi)
        idx = np.flatnonzero(keep)
        if idx.size < 2:
            raise DataError(
                f"segment({t_start!r}, {t_end!r}) of {self.source or 'the experiment'} "
                f"holds {idx.size} sample(s); the data span t = {_fmt_t(self.t[0])} … "
                f"{_fmt_t(self.t[-1])} s. Choose a window inside that span with at least "
                "2 samples."
            )
        sl = slice(int(idx[0]), int(idx[-1]) + 1)
        arrays = {s: (None if getattr(self, s) is None else getattr(self, s)[sl].copy())
                  for s in SIGNALS}
        meta = dict(self.meta)
        meta["segment"] = (t_start, t_end)
        return Experiment(
            t=self.t[sl].copy(),
            fs=self.fs,
            source=self.source,
            notices=self.notices
            + [f"segment t ∈ [{'start' if t_start is None else _fmt_t(lo)}, "
               f"{'end' if t_end is None else _fmt_t(hi)}) s: samples {sl.start + 1}.."
               f"{sl.stop} of {self.n_samples} kept"],
            name=self.name,
            meta=meta,
            **arrays,
        )

    def data_hash(self) -> str:
        """SHA-256 (hex) of the arrays t, q, qr, qd, qdd, tau: names, dtypes, shapes and
        little-endian bytes. Deterministic across runs and platforms; independent of
        source, notices and meta.

        Returns
        -------
        str
            64 hexadecimal digits.
        """
        h = hashlib.sha256(b"dynid-experiment-v1\0")
        for name in ("t",) + SIGNALS:
            a = getattr(self, name)
            h.update(name.encode() + b"\0")
            if a is None:
                h.update(b"none\0")
                continue
            a = np.ascontiguousarray(a, dtype=np.dtype(a.dtype).newbyteorder("<"))
            h.update(f"{a.dtype.str}{a.shape}\0".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def to_frame(self):
        """The data as a pandas DataFrame in the column convention (t, q1.., tau1..).

        Returns
        -------
        pandas.DataFrame
            One row per sample; columns `t`, `q1..qn` and the other signals present.
        """
        import pandas as pd  # slow to import, and loading an experiment does not need it

        cols = {"t": self.t}
        for s in SIGNALS:
            a = getattr(self, s)
            if a is not None:
                for j in range(a.shape[1]):
                    cols[f"{s}{j + 1}"] = a[:, j]
        return pd.DataFrame(cols)

    def summary(self) -> str:
        """A short text: source, N, fs, duration, signals and per-joint ranges.

        Returns
        -------
        str
            A few lines of text.
        """
        lines = []
        title = f"Experiment '{self.name}'" if self.name else "Experiment"
        lines.append(f"{title} from {self.source or '(memory)'}")
        lines.append(
            f"  {self.n_joints} joints, {self.n_samples} samples at {self.fs:.6g} Hz "
            f"(step {1e3 / self.fs:.4g} ms), duration {self.duration:.6g} s "
            f"(t = {_fmt_t(self.t[0])} … {_fmt_t(self.t[-1])} s)"
        )
        absent = [s for s in SIGNALS if getattr(self, s) is None]
        lines.append(
            "  signals: " + ", ".join(self.signals)
            + (f" (absent: {', '.join(absent)})" if absent else "")
        )
        qd, qd_note = self.qd, ""
        if qd is None and self.q is not None:
            qd, qd_note = np.gradient(self.q, self.t, axis=0), " (from q)"
        head = f"  {'joint':>5}"
        if self.q is not None:
            head += f"  {'q min … max [rad]':>24}"
        if qd is not None:
            head += f"  {('qd min … max [rad/s]' + qd_note):>30}"
        head += f"  {'tau min … max [N·m]':>26}"
        lines.append(head)
        for j in range(self.n_joints):
            row = f"  {j + 1:>5}"
            if self.q is not None:
                row += f"  {self.q[:, j].min():>11.4g} … {self.q[:, j].max():<10.4g}"
            if qd is not None:
                row += f"  {qd[:, j].min():>14.4g} … {qd[:, j].max():<13.4g}"
            row += f"  {self.tau[:, j].min():>12.4g} … {self.tau[:, j].max():<11.4g}"
            lines.append(row)
        if self.notices:
            lines.append(f"  notices ({len(self.notices)}):")
            lines.extend(f"    - {m}" for m in self.notices)
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (
            f"Experiment(name={self.name!r}, n_joints={self.n_joints}, "
            f"n_samples={self.n_samples}, fs={self.fs:.6g}, signals={self.signals}, "
            f"source={self.source!r})"
        )


def checked_experiment(experiment: Experiment, k: int = 0, robot=None, *, resample: bool = False) -> Experiment:
    """An Experiment built in memory (not loaded from a file), checked as a file would be.

    The loader checks what it reads; an Experiment made from the user's arrays has not been:
    every present signal finite, the robot's joint count, then the loader's own checks
    (`loader_checks`: time uniform, without gaps, at a plausible rate; magnitudes, torques and
    positions against the robot's limits; spikes, jumps and saturation as notices), `t` strictly
    increasing and `fs` the rate of `t` (within 1 %). Errors name the recording (its `source`,
    else its `name`, else "recording k+1"), the signal, the joint and the 1-based sample. A
    recording without a `source` gets that label, so later messages name it too.

    An experiment the loader made (`meta["time_from"]`, which only the loader and these checks
    set) has had those checks, with its description's time tolerance and perhaps resampled:
    it gets only the cheap ones (a few ms on 200,000 samples), and its notices stay as they are;
    its values are checked against `robot`'s limits again (it may have been loaded without one).
    So do the copies made of a checked experiment (`segment`, `holdout_split`).
    `resample`: irregular time steps are put on a uniform grid at the median step, as the
    loader's `resample = true` does, instead of refused.

    Returns
    -------
    Experiment
        `experiment`, or a copy of it with a `source` label, the loader's notices and
        `meta["time_from"]` (resampled, when `resample` and its time steps were irregular).
    """
    label = experiment.source or experiment.name or f"recording {k + 1} (an Experiment in memory)"
    for name in ("t",) + SIGNALS:
        a = getattr(experiment, name)
        if a is None:
            continue
        bad = ~np.isfinite(a)
        if bad.any():
            row, *col = np.argwhere(bad)[0]
            where = f"{name}{col[0] + 1}" if col else name
            raise DataError(f"{label}: {where} is not finite (NaN or inf) at sample {row + 1} (1-based), and "
                            f"{int(bad.sum())} value(s) in all; remove or fill those samples before identifying")
    n = getattr(robot, "n_joints", None)
    if n is not None and experiment.n_joints != n:
        raise DataError(f"{label}: {experiment.n_joints} joint column(s) in tau, but robot "
                        f"'{getattr(robot, 'name', '?')}' has {n} joints; give one column per joint")
    changes = {}
    if "time_from" not in experiment.meta:
        try:
            changes = loader_checks(experiment, label, robot, resample=resample)
        except IrregularTimeSteps as exc:
            raise DataError(f"{exc} In Python: resample=True (dynid.identify, dynid.run) puts an Experiment "
                            "on a uniform grid.") from None
    elif robot is not None:
        # loaded (or checked) perhaps without a robot: its values against this robot's limits, as a
        # path would be (notices aside: the loader's are already in it)
        signals = _signals_of(experiment)
        plaus.check_magnitude(_columns_in_memory(signals, label), robot)
        plaus.check_limits(signals, None, robot, None, label, [])
    t = changes.get("t", experiment.t)
    dt = np.diff(t)
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0])
        raise DataError(f"{label}: t does not increase at sample {row + 2} (1-based): t = "
                        f"{_fmt_t(t[row + 1])} after {_fmt_t(t[row])}; time must be strictly increasing")
    fs_t = 1.0 / float(np.median(dt))
    if "t" not in changes and abs(experiment.fs - fs_t) > TIME_STEP_TOLERANCE * fs_t:
        raise DataError(f"{label}: fs = {experiment.fs:g} Hz, but its time stamps give {fs_t:g} Hz "
                        "(1 / the median step); leave fs out (it is computed from t) or give the rate of t")
    if not experiment.source:
        changes["source"] = label
    return dataclasses.replace(experiment, **changes) if changes else experiment


class _InMemory:
    """A signal of an Experiment in memory as the loader's checks name a file's column: `where`
    (the recording and the signal) and `raw.row(k)` (the 1-based sample)."""

    def __init__(self, where: str):
        self.where = where
        self.raw = self

    @staticmethod
    def row(k) -> str:
        return f"sample {int(k) + 1}"


def _signals_of(experiment: Experiment) -> dict:
    return {s: getattr(experiment, s) for s in SIGNALS if getattr(experiment, s) is not None}


def _columns_in_memory(signals: dict, label: str) -> list:
    """(column, values) of every joint of `signals`, named as `plausibility.check_magnitude` names a
    file's columns."""
    return [(_InMemory(f"{label}: {s}{j + 1}"), a[:, j]) for s, a in signals.items() for j in range(a.shape[1])]


def loader_checks(experiment: Experiment, label: str, robot=None, *, resample: bool = False) -> dict:
    """The checks `load_experiment` makes of a file's signals (`columns._assemble`), made of an
    Experiment's arrays by the loader's own functions, in its order: magnitudes and the robot's
    limits (`plausibility.check_magnitude`, `check_limits`), the time steps (`timebase._check_time`:
    strictly increasing, uniform within `TIME_STEP_TOLERANCE`, no gap; resampled when `resample`)
    and the sampling rate against the joints' speeds (`check_rate`), as `columns._time_and_rate`
    does (not called: the loader's modules import this one), then spikes, one-sample jumps and
    torque saturation, which are notices. Messages name `label`, the signal (`t`, `tau2`) and the
    1-based sample.

    Returns
    -------
    dict
        The fields to replace in `experiment`: its `notices` with the loader's appended and its
        `meta` with `time_from` (the mark of checked data); when resampled, also `t`, the
        signals, `fs` and `meta["resampled"]`.
    """
    signals = _signals_of(experiment)
    plaus.check_magnitude(_columns_in_memory(signals, label), robot)
    time = _InMemory(f"{label}: t")
    rows = np.arange(experiment.n_samples)
    notices: list[str] = []
    meta = dict(experiment.meta)
    plaus.check_limits(signals, None, robot, None, label, notices)
    with plaus.spike_notices(signals, None, None, label) as spikes:
        at = len(notices)          # as the loader: the spike notices before the time checks' ones
        t, checked = experiment.t, signals
        irregular, step = _check_time(t, time, rows, _Options(resample=resample), notices)
        if irregular:              # as `columns._time_and_rate`
            t, checked = _resample(t, dict(signals), notices, time.where)
            meta["resampled"] = True
            step = float(np.median(np.diff(t)))
        plaus.check_rate(t, checked, robot, time.where, notices, step=step)
        saturation_notices(checked["tau"], notices, label)
        found = spikes.result()
        plaus.position_jumps(signals, None, None, label, found, skip=spikes.flagged(), robot=robot)
        notices[at:at] = found
    meta["time_from"] = time.where if "in memory" in label else f"{time.where} (an Experiment in memory)"
    changes = {"notices": list(experiment.notices) + notices, "meta": meta}
    if t is not experiment.t:           # resampled: fs is that of the new grid
        changes.update(checked, t=t, fs=None)
    return changes


def recording_of(item):
    """The Experiment inside a simulated recording (`dynid.simulate`'s result, which carries what
    produced it beside its `experiment`), else `item` itself: every function taking a recording
    takes either."""
    inner = getattr(item, "experiment", None)
    return inner if isinstance(inner, Experiment) and not isinstance(item, Experiment) else item


#: odd multipliers of the row fingerprint (any fixed odd numbers: a row's key is the sum of its
#: columns' bit patterns times these, modulo 2**64)
_ROW_MIX = np.array([0x9E3779B97F4A7C15, 0xBF58476D1CE4E5B9, 0x94D049BB133111EB, 0xD6E8FEB86659FD93,
                     0xA0761D6478BD642F, 0xE7037ED1A0B428DB, 0x8EBC6AF09C88C6E3, 0x589965CC75374CC3],
                    dtype=np.uint64)
#: two recordings whose (q, tau) samples agree bit for bit over this many consecutive samples,
#: at one shift, are one recording given twice (shifted, trimmed or exported again). Independent
#: runs of one excitation share isolated samples when the sensors are coarse (a 12-bit encoder,
#: 0.1 N m torque steps on a 2-joint arm: runs of at most 12), never a run of hundreds.
SHARED_RUN = 100


def sample_keys(e):
    """One 64-bit fingerprint per (q, tau) sample of `e`, in time order."""
    X = np.ascontiguousarray(np.column_stack([e.q, e.tau]), dtype=np.float64) + 0.0   # -0.0 -> 0.0
    bits = X.view(np.uint64)
    mix = np.resize(_ROW_MIX, bits.shape[1]) + np.arange(bits.shape[1], dtype=np.uint64) * np.uint64(2)
    return (bits * mix).sum(axis=1, dtype=np.uint64)


def shared_run(a, b) -> int:
    """The longest run of consecutive samples of `a` that are, bit for bit, consecutive samples
    of `b` at one shift (samples equal to the one before them are left out: a robot holding
    still repeats its samples in any recording). The shifts tried are the three at which most samples of `a` find
    their fingerprint in `b`. `a`, `b`: Experiments or their `sample_keys`."""
    ka = a if isinstance(a, np.ndarray) else sample_keys(a)
    kb = b if isinstance(b, np.ndarray) else sample_keys(b)
    if ka.size == 0 or kb.size == 0:
        return 0
    order = np.argsort(kb, kind="stable")
    pos = np.minimum(np.searchsorted(kb[order], ka), kb.size - 1)
    where = order[pos]                                   # a sample of b with a's key, if any
    found = kb[where] == ka
    if not found.any():
        return 0
    shifts, counts = np.unique(where[found].astype(np.int64) - np.flatnonzero(found), return_counts=True)
    best = 0
    for d in shifts[np.argsort(-counts, kind="stable")[:3]]:
        lo, hi = max(0, -d), min(ka.size, kb.size - d)   # a[i] beside b[i + d]
        if hi - lo <= best:
            continue
        x, y = ka[lo:hi], kb[lo + d:hi + d]
        # a sample repeating the one before (a robot holding still, a coarse sensor) counts for
        # nothing: only the samples that moved make a run, and a repeat does not break one
        moved = np.r_[True, x[1:] != x[:-1]]
        same = (x == y)[moved]
        edges = np.flatnonzero(np.diff(np.r_[0, same.astype(np.int8), 0]))
        if edges.size:
            best = max(best, int((edges[1::2] - edges[::2]).max()))
    return best


def same_samples(a, b) -> bool:
    """True when `a` and `b` are one recording given twice (`shared_run` >= `SHARED_RUN`)."""
    return shared_run(a, b) >= SHARED_RUN


def repeated_recordings(experiments) -> list:
    """The pairs (i, k, run), i < k, of `experiments` that are one recording given twice
    (`same_samples`: `run` consecutive samples in common), each recording's fingerprints computed
    once."""
    keys = [sample_keys(e) for e in experiments]
    out = []
    for k in range(1, len(keys)):
        for i in range(k):
            run = shared_run(keys[i], keys[k])
            if run >= SHARED_RUN:
                out.append((i, k, run))
    return out
