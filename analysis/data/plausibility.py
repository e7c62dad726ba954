"""Plausibility of loaded data: magnitudes, robot limits, units, spikes.

Checks run by `dynid.analysis.data.columns._assemble` (and, for magnitudes,
right after the cells are parsed). They catch silent nonsense that parses fine:

* `check_magnitude` (robot given): a signal cell with `|value| > MAGNITUDE_LIMIT` (1e12) is
  refused (no torque, position or current in SI units gets there; it is a corrupted
  cell or an overflow), naming the column and the row.
* `check_limits` (robot given): the joint torques against `tau_max`, the
  positions against `q_limits`; wrong units (mN·m, degrees) and single impossible
  samples are errors, milder excess is a notice.
* `spike_notices`: isolated spikes (one sample far from its neighbours' median,
  measured in the column's robust scale) are a notice naming the column and the row.
* `check_rate` (robot given): a sampling rate below `LOW_RATE` with joint
  speeds far below `qd_max` (time in ms), or speeds far above `qd_max`.

Thresholds are generous: the Stäubli TX40, KUKA LWR4+ and Panda recordings and
`dynid simulate` data raise nothing.
"""

from __future__ import annotations

import math

import numpy as np

from dynid.analysis.data.spikes import SPIKE_FACTOR, jumps_of_columns, spikes_of_columns
from dynid.analysis.units import prismatic_joints
from dynid.errors import DataError

#: |value| above which a signal cell is refused.
MAGNITUDE_LIMIT = 1e12
#: 99th percentile of |tau_j| above this × tau_max: a notice (units?).
TAU_NOTICE_FACTOR = 3.0
#: 99th percentile (units) or a single sample (spike) of |tau_j| above this × tau_max: an error.
TAU_ERROR_FACTOR = 20.0
#: every joint's 99th-percentile |tau_j| below this × its tau_max: an error (kN·m?). A moving arm
#: needs a few % of tau_max on some joint; 1000x too small data (kN·m) sit at 1e-4 .. 1e-3.
TAU_SMALL_FACTOR = 2e-3
#: Sampling rates below this (Hz) are implausible for dynamic identification.
LOW_RATE = 10.0
#: ... and an error when every joint's 99th-percentile speed is below this × qd_max.
SLOW_FRACTION = 0.01
#: 99th-percentile |dq/dt| above this × qd_max: a notice.
FAST_FACTOR = 10.0
#: ... and above this × qd_max: an error (no arm moves 100 times faster than its limit: the time
#: column's unit or scale, or the robot file's qd_max, is wrong).
FAST_REFUSE = 100.0
#: A position sample that steps away and back by more than this × the column's mean |step|, and by
#: more than JUMP_MIN (rad, or m), is a glitch: a notice. On the real TX40, LWR4+ and Panda logs the
#: largest such step is 0.1 × the mean step, on dynid's simulated TX40 (4e-5 rad noise) 0.8 ×.
JUMP_FACTOR = 20.0
#: ... the floor: an encoder count flickering on a joint at rest is no glitch
JUMP_MIN = 1e-3
#: the words every glitch notice (spike, jump) carries, by which later steps find them
GLITCH = "a glitch?"

_UNIT = {"q": "rad", "qr": "rad", "qd": "rad/s", "qdd": "rad/s²", "tau": "N·m"}


def _g(x: float) -> str:
    return f"{x:.4g}"


def check_magnitude(items, robot) -> None:
    """DataError for the first cell with |value| > MAGNITUDE_LIMIT in `items` [(col, values)].

    Only with a robot (the data are then meant as a recording of it, in SI units);
    without one the loader reads any finite number."""
    if robot is None:
        return
    for col, v in items:
        big = np.abs(v) > MAGNITUDE_LIMIT
        if big.any():
            k = int(np.flatnonzero(big)[0])
            raise DataError(
                f"{col.where}, {col.raw.row(k)}: {v[k]:.6g} is implausibly large (|value| > "
                f"{MAGNITUDE_LIMIT:g}; {int(big.sum())} such cell(s) in this column): a "
                "corrupted cell or an overflow. Fix or remove that row."
            )


def _joint_value(robot, j: int, attr: str):
    try:
        return getattr(robot.joints[j], attr)
    except (AttributeError, IndexError, TypeError):
        return None


def _positive(x) -> float | None:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) and x > 0 else None


def _limits(x):
    try:
        lo, hi = (float(v) for v in x)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        return None
    return lo, hi


class _Where:
    """Names a signal's joint column and a row of it in messages."""

    def __init__(self, cols_of, rows, source):
        self.cols_of = cols_of or {}
        self.rows = rows
        self.source = source

    def col(self, s: str, j: int):
        cols = self.cols_of.get(s)
        return cols[j] if cols is not None and j < len(cols) else None

    def name(self, s: str, j: int) -> str:
        c = self.col(s, j)
        own = f"{s}{j + 1}"
        if c is None:
            return f"{self.source}: {own}"
        return c.where if own in c.label else f"{c.where} ({own})"

    def row(self, s: str, j: int, k: int) -> str:
        c = self.col(s, j)
        if c is None or self.rows is None:
            return f"sample {k + 1}"
        return c.raw.row(int(self.rows[k]))


def _check_tau_too_small(tau, robot, w) -> None:
    """Every joint's torque a tiny fraction of its tau_max: torques in kN·m (the mirror of mN·m)."""
    ratios = []
    for j in range(tau.shape[1]):
        tmax = _positive(_joint_value(robot, j, "tau_max"))
        if tmax is None:
            return                  # a joint without tau_max: nothing to compare against
        ratios.append((float(np.percentile(np.abs(tau[:, j]), 99)) / tmax, j, tmax))
    if not ratios or tau.shape[0] < 10:
        return
    top, j, tmax = max(ratios)
    if 0 < top < TAU_SMALL_FACTOR:      # (all zero: a dead channel, reported as such later)
        p99 = top * tmax
        raise DataError(
            f"{w.name('tau', j)}: the largest joint torque, tau{j + 1}, reaches only {_g(p99)} N·m (99th "
            f"percentile), {top:.2g}× the robot's tau_max {_g(tmax)} N·m, and every other joint less: are "
            "the torques in kN·m (or is the drive gain wrong)? Convert the columns to N·m (in an "
            "experiment TOML: [torques] scale = 1000), or correct tau_max in the robot file."
        )


def check_limits(signals: dict, rows, robot, cols_of, source: str, notices: list[str]) -> None:
    """Torques against tau_max and positions against q_limits (see the module doc)."""
    if robot is None:
        return
    w = _Where(cols_of, rows, source)
    tau = signals.get("tau")
    if tau is not None:
        _check_tau_too_small(tau, robot, w)
        for j in range(tau.shape[1]):
            tmax = _positive(_joint_value(robot, j, "tau_max"))
            if tmax is None:
                continue
            a = np.abs(tau[:, j])
            p99 = float(np.percentile(a, 99))
            k = int(np.argmax(a))
            if p99 > TAU_ERROR_FACTOR * tmax:
                raise DataError(
                    f"{w.name('tau', j)}: tau{j + 1} reaches {_g(p99)} N·m (99th percentile of "
                    f"|tau{j + 1}|), {p99 / tmax:.0f}× the robot's tau_max {_g(tmax)} N·m for "
                    f"joint {j + 1}: are the torques in mN·m (or is the drive gain wrong)? "
                    "Convert the column to N·m (in an experiment TOML: [torques] scale = "
                    "0.001), or correct tau_max in the robot file."
                )
            if a[k] > TAU_ERROR_FACTOR * tmax:
                raise DataError(
                    f"{w.name('tau', j)}, {w.row('tau', j, k)}: tau{j + 1} = {tau[k, j]:.6g} "
                    f"N·m, {a[k] / tmax:.0f}× the robot's tau_max {_g(tmax)} N·m, while 99 % of "
                    f"the samples stay below {_g(p99)} N·m: a spike or corrupted value. Fix or "
                    "remove that row."
                )
            if p99 > TAU_NOTICE_FACTOR * tmax:
                notices.append(
                    f"{w.name('tau', j)}: tau{j + 1} reaches {_g(p99)} N·m (99th percentile), "
                    f"{p99 / tmax:.1f}× the robot's tau_max {_g(tmax)} N·m: check the units "
                    "of the torque column (N·m?), the drive gain, or tau_max in the robot file"
                )
    for s in ("q", "qr"):
        x = signals.get(s)
        if x is None:
            continue
        for j in range(x.shape[1]):
            lim = _limits(_joint_value(robot, j, "q_limits"))
            if lim is None:
                continue
            lo, hi = lim
            span = hi - lo
            margin = max(1.0, 0.5 * span)
            obs_lo, obs_hi = (float(v) for v in np.percentile(x[:, j], [0.5, 99.5]))
            if obs_lo >= lo - margin and obs_hi <= hi + margin:
                continue
            rad = np.radians([obs_lo, obs_hi])
            degrees = rad[0] >= lo - margin and rad[1] <= hi + margin
            what = (f"{w.name(s, j)}: {s}{j + 1} spans {_g(obs_lo)} … {_g(obs_hi)} but the "
                    f"robot's q_limits for joint {j + 1} are [{_g(lo)}, {_g(hi)}] rad")
            if degrees:
                fix = ("are the positions in degrees? Convert them to rad (in an experiment "
                       f"TOML: [positions] scale = {math.pi / 180!r})")
            else:
                fix = ("check the units of the position column (rad, m for prismatic joints), "
                       "its zero offset, or q_limits in the robot file")
            if obs_lo < lo - span or obs_hi > hi + span:
                raise DataError(f"{what}: {fix}.")
            notices.append(f"{what}: {fix}")


def position_jumps(signals: dict, rows, cols_of, source: str, notices: list, skip=frozenset(),
                   robot=None) -> None:
    """A notice per position column (q, qr) with a one-sample jump out and back: both steps
    larger than `JUMP_FACTOR` times the column's mean |step| (and than `JUMP_MIN`) and of
    opposite signs (an encoder glitch or wrap-around). The spike test misses a jump of a few
    rad, which is small beside the spread of the positions; in the regressor it is a burst of
    thousands of rad/s, which can zero a whole joint through the velocity dead zone (1 % of
    the peak |qd|) or bias every parameter. `skip`: the (signal, column) pairs whose spike is
    already named (`SpikeNotices.flagged`); `robot` (optional) tells the prismatic joints, in m."""
    w = _Where(cols_of, rows, source)
    prismatic = [bool(getattr(jt, "prismatic", False)) for jt in getattr(robot, "joints", None) or []]
    for s in ("q", "qr"):
        x = signals.get(s)
        if x is None or x.shape[0] < 3:
            continue
        first, count, mean, step = jumps_of_columns(x, JUMP_FACTOR, JUMP_MIN)
        for j in np.flatnonzero(count > 0):
            if (s, int(j)) in skip:
                continue
            k = int(first[j])
            unit = "m" if j < len(prismatic) and prismatic[j] else "rad"
            notices.append(
                f"{w.name(s, j)}, {w.row(s, j, k)}: {s}{j + 1} jumps by {_g(float(step[j]))} {unit} in one "
                f"sample and back (more than {_g(JUMP_FACTOR)}x its mean step of {_g(float(mean[j]))} {unit})"
                f"{f'; {int(count[j])} such samples in all' if count[j] > 1 else ''}: {GLITCH} Fix or remove "
                "that row (it is a burst of speed and acceleration in the regressor)")


def _first_spikes(x: np.ndarray) -> list[tuple[int, int, int, float, float]]:
    """(column, row of its first spike, its number of spikes, its robust scale, the first
    spike's value) for each column of x (n, k) with isolated spikes."""
    out = []
    for j, (idx, scale) in enumerate(spikes_of_columns(x)):
        if idx.size:
            k = int(idx[0])
            out.append((j, k, int(idx.size), scale, float(x[k, j])))
    return out


class SpikeNotices:
    """The notices of `spike_notices`, the last signal's perhaps still being found on another
    thread: `result()` waits for them; leaving a ``with`` block on an exception cancels that
    check if it has not started."""

    def __init__(self, where: _Where, found: list, pending=None):
        self._where = where
        self._found = found              # [(signal, _first_spikes of it)]
        self._pending = pending          # (signal, Future of its _first_spikes) or None

    def result(self) -> list[str]:
        found = list(self._found)
        if self._pending is not None:
            found.append((self._pending[0], self._pending[1].result()))
            self._found, self._pending = found, None
        w = self._where
        return [
            f"{w.name(s, j)}, {w.row(s, j, k)}: isolated spike in {s}{j + 1}: "
            f"{value:.6g} {_UNIT[s]}, more than {SPIKE_FACTOR:g}× the column's robust "
            f"scale ({_g(scale)}, from its median absolute deviation) away from its "
            f"neighbours{f' ({count} such samples in all)' if count > 1 else ''}: {GLITCH} "
            "Fix or remove that row (outliers bias the fit)"
            for s, columns in found for j, k, count, scale, value in columns
        ]

    def flagged(self) -> set:
        """The (signal, column) pairs with a spike notice (after `result()`)."""
        return {(s, j) for s, columns in self._found for j, *_ in columns}

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and self._pending is not None:
            self._pending[1].cancel()


def spike_notices(signals: dict, rows, cols_of, source: str, beside=None) -> SpikeNotices:
    """A notice per column (q, qr, tau) with isolated spikes, naming the first row.

    `beside`: an executor whose thread will be free while the caller goes on (the CSV loader's
    scan thread); the last signal's check is queued there, and `result()` waits for it. Only
    the values the notices need are kept, not the signals (resampling frees them)."""
    w = _Where(cols_of, rows, source)
    present = [s for s in ("q", "qr", "tau") if signals.get(s) is not None]
    pending = None
    if beside is not None and present:
        last = present.pop()
        pending = (last, beside.submit(_first_spikes, signals[last]))
    return SpikeNotices(w, [(s, _first_spikes(signals[s])) for s in present], pending)


#: a logged velocity whose least-squares slope against dq/dt lies outside these bounds, or whose
#: correlation with it is below LOGGED_QD_CORR, is named (unit, sign or joint order of the logger)
LOGGED_QD_SLOPE = (0.8, 1.25)
LOGGED_QD_CORR = 0.9
#: rad/s (or m/s): RMS of a joint's dq/dt below which it stands still (0.6 deg/s)
STILL_SPEED = 0.01


def logged_derivative_notices(t, signals: dict, cols_of, source: str) -> list[str]:
    """What the logged velocities and accelerations are for: nothing in the fit (dynid derives
    them from the positions), so a notice says so, and names a logged velocity that is not
    dq/dt (another unit, the opposite sign, another joint's), which would otherwise go unseen
    (`velocity_mismatches`)."""
    q, qd, qdd = signals.get("q"), signals.get("qd"), signals.get("qdd")
    if qd is None and qdd is None:
        return []
    logged = " and ".join(n for n, a in (("velocities qd", qd), ("accelerations qdd", qdd)) if a is not None)
    out = [f"{source}: the logged {logged} are not used: dynid derives them from the low-pass-filtered "
           "positions"]
    bad = [] if qd is None or q is None else velocity_mismatches(t, q, qd)
    if bad:
        w = _Where(cols_of, None, source)
        out.append(f"{source}: the logged velocities are not the positions' derivative: "
                   + "; ".join(f"{w.name('qd', j)} is {slope:.3g} × dq{j + 1}/dt (correlation {corr:.2f})"
                               for j, slope, corr in bad)
                   + ": check their unit (rad/s), sign and joint order; dynid does not use them")
    return out


def velocity_mismatches(t, q, qd) -> list:
    """(joint, slope, correlation) of each moving joint whose logged velocity is not dq/dt: the
    least-squares slope of qd on dq/dt outside `LOGGED_QD_SLOPE`, or their correlation below
    `LOGGED_QD_CORR`. Compared on ~100 Hz block means (quantisation and noise average out); a
    joint whose dq/dt has an RMS below `STILL_SPEED` stands still and is not compared (its
    encoder noise is no velocity to compare with)."""
    if t.size < 40 or not t[-1] > t[0]:
        return []
    k = max(1, int(round((t.size - 1) / float(t[-1] - t[0]) / 100.0)))
    m = (t.size // k) * k
    if m // k < 20:
        return []
    n = q.shape[1]
    g = np.gradient(q[:m].reshape(-1, k, n).mean(axis=1), t[:m].reshape(-1, k).mean(axis=1), axis=0)
    v = qd[:m].reshape(-1, k, n).mean(axis=1)
    out = []
    for j in range(n):
        gj, vj = g[:, j], v[:, j]
        if not (np.all(np.isfinite(vj)) and np.sqrt(np.mean(gj ** 2)) >= STILL_SPEED):
            continue
        slope = float(np.dot(vj, gj) / np.dot(gj, gj))
        corr = float(np.corrcoef(vj, gj)[0, 1]) if np.std(vj) > 0 else 0.0
        if not (LOGGED_QD_SLOPE[0] <= slope <= LOGGED_QD_SLOPE[1]) or not corr >= LOGGED_QD_CORR:
            out.append((j, slope, corr))
    return out


def _refuse_too_fast(robot, known, speed, qd_max, time_where) -> None:
    """A DataError when most joints with a qd_max move more than FAST_REFUSE times it: a time
    column's unit or scale slip speeds up every joint alike, where one fast joint is a glitch,
    a motor-side encoder or a placeholder limit (the notice of `check_rate`)."""
    fast = [j for j in known if speed[j] > FAST_REFUSE * qd_max[j]]
    if 2 * len(fast) <= len(known):
        return
    prismatic = prismatic_joints(robot)

    def unit(j):
        return "m/s" if j + 1 in prismatic else "rad/s"

    raise DataError(
        f"{time_where}: with this time column " + ", ".join(
            f"joint {j + 1} moves at {_g(speed[j])} {unit(j)} ({speed[j] / qd_max[j]:.0f}× its qd_max "
            f"{_g(qd_max[j])} {unit(j)})" for j in fast)
        + " (99th percentiles), which no arm does: check the time column's unit and scale (s; in an "
          "experiment TOML [time] scale or sampling_rate), the positions' unit (rad, or m; motor-side "
          "encoders: side = \"motor\" and gear_ratios in the TOML), and the robot file's qd_max")


def check_rate(t: np.ndarray, signals: dict, robot, time_where: str, notices: list[str],
               step: float | None = None) -> None:
    """A time column in ms (rate below LOW_RATE, joints far slower than qd_max) and
    joint speeds far above qd_max. `step`: the median time step of t, when the caller has it."""
    if robot is None or t.size < 3:
        return
    q = signals.get("q")
    if q is None:
        q = signals.get("qr")
    if q is None:
        return
    step = float(np.median(np.diff(t))) if step is None else float(step)
    if not step > 0:
        return
    fs = 1.0 / step
    with np.errstate(all="ignore"):
        qd = np.gradient(q, t, axis=0)
    speed = np.percentile(np.abs(qd), 99, axis=0)
    qd_max = [_positive(_joint_value(robot, j, "qd_max")) for j in range(q.shape[1])]
    known = [j for j, v in enumerate(qd_max) if v is not None]
    dur = float(t[-1] - t[0])
    if fs < LOW_RATE:
        head = (f"{time_where}: t steps by {_g(step)} (median) and spans {_g(dur)} s, a "
                f"sampling rate of {_g(fs)} Hz")
        if known and all(speed[j] < SLOW_FRACTION * qd_max[j] for j in known):
            j = max(known, key=lambda i: speed[i] / qd_max[i])
            # the unit that makes the joints' speeds plausible (a third of qd_max): ms, µs or ns
            ratio = speed[j] / qd_max[j]
            scale, unit = min(((1e-3, "ms"), (1e-6, "\u00b5s"), (1e-9, "ns")),
                              key=lambda su: abs(math.log10(max(ratio / su[0], 1e-300) / 0.3)))
            raise DataError(
                f"{head}; at that rate the fastest joint (joint {j + 1}) moves at "
                f"{_g(speed[j])} rad/s, {100 * speed[j] / qd_max[j]:.2g} % of its qd_max "
                f"{_g(qd_max[j])} rad/s: is t in {unit}? Convert the time column to s (in an "
                f"experiment TOML: [time] scale = {scale:g})."
            )
        notices.append(f"{head}, low for dynamic identification: is t in s (not ms)?")
    _refuse_too_fast(robot, known, speed, qd_max, time_where)
    for j in known:
        if speed[j] > FAST_FACTOR * qd_max[j]:
            notices.append(
                f"{time_where}: with this time column joint {j + 1} moves at {_g(speed[j])} "
                f"rad/s (99th percentile), {speed[j] / qd_max[j]:.0f}× its qd_max "
                f"{_g(qd_max[j])} rad/s: check the units of t (s) and of the positions (rad)"
            )
