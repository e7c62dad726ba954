"""The experiment description (`.toml`): schema, checks and loading.

Reference: docs/formats.md, section "Experiment description (TOML)". In short:

For logs that are not in dynid's column format. Paths are relative to the TOML file.
All sections and keys are checked; an unknown key is an error (typos do not pass).

`[experiment]` (these keys may also be written at the top of the file)
    `name`            str, optional.
    `file`            default data file for every section below. With no signal
                        section at all, this file is read in dynid's column format and
                        the options below apply to it.
    `sampling_rate`   Hz; required when there is no time column ([time] / `t`),
                        t = start_time + k / sampling_rate. With a time column it is
                        checked against the median step (1 %).
    `start_time`      s, default 0, used with `sampling_rate`.
    `start_offset`    samples to skip at the start (default 0).
    `resample`        bool (default false): linear interpolation of every signal onto
                        a uniform grid at the median time step, for irregular time
                        stamps. Done last, after `start_offset` and the reference shift.
    `time_tolerance`  allowed relative deviation of a time step from the median
                        (default 0.01).
    `gear_ratios`     n numbers, optional: the gear ratio N_j of each joint's motor
                        (q_motor = N_j q_j), a fact about the robot, not a conversion:
                        signals are not converted by it. Kept in `meta["gear_ratios"]`
                        for the diagnosis, which names a spectral line at a harmonic
                        of the motor turn with it. Motor-side data give them already
                        ([transmission] gear_ratios, also kept there); both given and
                        different is an error.

`[time]`: `file`, `column` (or `key`) naming a 1-D column/array in s,
`scale` (e.g. 0.001 for ms).

Signal sections `[positions]` (q), `[reference]` (qr), `[velocities]` (qd),
`[accelerations]` (qdd), `[torques]` (tau), `[currents]` (i → tau), keys:
    `file`            data file (.csv, .parquet, .npz, .mat); default [experiment].file.
    `columns`         list of n column names (CSV/Parquet), or of n 1-D arrays
                        (npz/mat), one per joint in joint order; or
    `key`             one 2-D array of shape (N, n) in an npz/mat file.
    `side`            "joint" (default) or "motor": motor-side signals are converted
                        through [transmission]: q = R⁻¹·q_m + position_offsets,
                        qd = R⁻¹·qd_m, qdd = R⁻¹·qdd_m, tau = Rᵀ·tau_m.
    `scale`           number or list of n numbers multiplying the signal (default 1),
                        applied before the transmission.
    `drive_gains`     ([torques], [currents]) list of n gains, signal → (motor)
                        torque, applied before the transmission. Default for
                        [currents]: `robot.drive_gains`; for [torques]: 1.
    `identify_gains`  ([currents] only) true (every joint), false (default) or a list of
                        1-based joints whose drive gain is not trusted: the gains that
                        `dynid.identify_drive_gains` (`dynid payload --gains`) identifies.
                        Kept in `meta["identify_gains"]` (1-based joints), the gains
                        applied in `meta["drive_gains"]`.
    `shift`           ([reference] only) 0 (default), an integer L, or "estimate":
                        pair measured q[i + L] with reference[i]. "estimate" picks the L
                        that minimises the mean square of q[i + L] − reference[i] over all
                        joints and overlapping samples, searching min_shift ≤ L ≤
                        max_shift (see below). For L > 0 the first L measured samples and the last L
                        reference samples have no partner and are dropped (for L < 0,
                        the reverse). L is recorded in the notices and in
                        `meta["reference_shift"]`. The shift is applied to the raw
                        samples (after `start_offset`, before resampling).
    `min_shift`, `max_shift`  ([reference] only) search range in samples,
                        defaults 0 and N // 4 (N after start_offset). L ≥ 0 by default
                        because the measurement follows the command. Keep the range below
                        one period of a periodic excitation: a shift by ± one period fits
                        as well (the KUKA trajectories repeat every ~1257 / ~2513 samples).

`[transmission]`  (only needed for `side = "motor"`; see `dynid.analysis.data.transmission`)
    `gear_ratios`     n numbers, the diagonal of R (q_motor = R · q_joint).
    `couplings`       list of {motor = m, joint = j, ratio = r} (1-based): R[m, j] += r.
    `position_offsets` n numbers (rad) added to q (and a motor-side qr) after R⁻¹.

Examples (the Stäubli TX40 and KUKA LWR4+ recordings): docs/formats.md, same section.

Arrays or columns of a data file that no section uses are listed in a notice.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dynid.analysis.data import plausibility as _plaus
from dynid.analysis.data import transmission as _tr
from dynid.analysis.data._format import _fmt, _short_list
from dynid.analysis.data.columns import (
    _assemble,
    _check_finite,
    _Col,
    _drive_gains,
    _from_columns,
    _release,
    _robot_joints,
    _time_values,
    _to_float,
    stack_columns,
)
from dynid.analysis.data.readers import _RawFile, _read_bytes, _read_data_file
from dynid.analysis.data.record import TORQUE_TIMINGS
from dynid.analysis.data.timebase import TIME_STEP_TOLERANCE, _Options
from dynid.dynamics.robot_checks import name_problem
from dynid.errors import DataError

if TYPE_CHECKING:
    from dynid.analysis.data.experiment import Experiment

# --------------------------------------------------------------------------------------
# TOML experiment descriptions
# --------------------------------------------------------------------------------------

_SECTIONS = {"positions": "q", "reference": "qr", "velocities": "qd",
             "accelerations": "qdd", "torques": "tau", "currents": "i"}
_SECTION_KEYS = {"file", "key", "columns", "side", "scale"}
_EXTRA_KEYS = {"torques": {"drive_gains"}, "currents": {"drive_gains", "identify_gains"},
               "reference": {"shift", "max_shift", "min_shift"}}
_TIME_KEYS = {"file", "key", "column", "scale"}
_TRANSMISSION_KEYS = {"gear_ratios", "couplings", "position_offsets"}
#: Largest accepted ``sampling_rate`` (Hz): far above any robot controller's rate.
MAX_SAMPLING_RATE = 1e6
#: Largest accepted ``time_tolerance``: a step 25 % off the median is no longer uniform
#: sampling (steps 1.5x the median are gaps); irregular logs take ``resample = true``.
MAX_TIME_TOLERANCE = 0.25
#: Largest experiment TOML read (bytes): it names files and columns, the data live elsewhere.
MAX_TOML_BYTES = 1 << 20


@dataclass(frozen=True)
class _Field:
    """One key of a TOML table: its type, default and range (the range's message names the fix)."""

    kind: str                           # "string" | "number" | "integer" | "bool"
    default: object = None
    positive: bool = False
    minimum: int | None = None
    maximum: float | None = None
    too_large: str = ""                 # message when above maximum; {v} is the value


#: The [experiment] table (also allowed at the top level), in the order it is checked.
_EXPERIMENT_FIELDS = {
    "name": _Field("string", ""),
    "sampling_rate": _Field(
        "number", positive=True, maximum=MAX_SAMPLING_RATE,
        too_large=f"sampling_rate = {{v:g}} Hz is out of range: give the rate in Hz, at most "
                  f"{MAX_SAMPLING_RATE:g} (robot controllers log at 100 Hz … 10 kHz)."),
    "start_time": _Field("number", 0.0),
    "start_offset": _Field("integer", 0, minimum=0),
    "time_tolerance": _Field(
        "number", TIME_STEP_TOLERANCE, positive=True, maximum=MAX_TIME_TOLERANCE,
        too_large=f"time_tolerance = {{v:g}} is out of range: it is the allowed relative deviation "
                  f"of a time step from the median, at most {MAX_TIME_TOLERANCE:g} (default "
                  f"{TIME_STEP_TOLERANCE:g}); for irregular time stamps set resample = true instead."),
    "resample": _Field("bool", False),
    "file": _Field("string"),
    "torque_timing": _Field("string", ""),
}
#: keys of [experiment] that are lists, read once the number of joints is known
_EXPERIMENT_LISTS = {"gear_ratios"}
_EXPERIMENT_KEYS = set(_EXPERIMENT_FIELDS) | _EXPERIMENT_LISTS


class _Toml:
    """Typed access to a parsed TOML with messages naming file, section and key."""

    def __init__(self, label: str):
        self.label = label

    def err(self, section: str | None, msg: str) -> DataError:
        where = f"{self.label}, [{section}]" if section else self.label
        return DataError(f"{where}: {msg}")

    def check_keys(self, section: str, table: dict, allowed: set[str]) -> None:
        if not isinstance(table, dict):
            raise self.err(None, f"'{section}' must be a table [{section}], got {table!r}.")
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.err(
                section,
                f"unknown key(s) {', '.join(repr(u) for u in unknown)}. Allowed: "
                f"{', '.join(sorted(allowed))} (see docs/formats.md, section "
                "'Experiment description (TOML)').",
            )

    def field(self, section: str, table: dict, key: str, f: _Field):
        """The value of `key` checked against its field description `f`."""
        if f.kind == "string":
            return self.string(section, table, key, f.default)
        if f.kind == "integer":
            return self.integer(section, table, key, f.default, minimum=f.minimum)
        if f.kind == "bool":
            v = table.get(key, f.default)
            if not isinstance(v, bool):
                raise self.err(section, f"{key} must be true or false, got {v!r}.")
            return v
        v = self.number(section, table, key, f.default, positive=f.positive)
        if v is not None and f.maximum is not None and v > f.maximum:
            raise self.err(section, f.too_large.format(v=v))
        return v

    def string(self, section, table, key, default=None):
        v = table.get(key, default)
        if v is not None and not isinstance(v, str):
            raise self.err(section, f"{key} must be a string, got {v!r}.")
        return v

    def number(self, section, table, key, default=None, positive=False):
        v = table.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(section, f"{key} must be a finite number, got {v!r}.")
        if positive and not v > 0:
            raise self.err(section, f"{key} must be positive, got {v!r}.")
        return float(v)

    def integer(self, section, table, key, default=None, minimum=None):
        v = table.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(section, f"{key} must be a whole number, got {v!r}.")
        if minimum is not None and v < minimum:
            raise self.err(section, f"{key} must be ≥ {minimum}, got {v}.")
        return v

    def numbers(self, section, table, key, n=None):
        v = table.get(key)
        if v is None:
            return None
        if not isinstance(v, list) or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in v
        ):
            raise self.err(section, f"{key} must be a list of numbers, got {v!r}.")
        if n is not None and len(v) != n:
            raise self.err(
                section, f"{key} has {len(v)} entries but there are {n} joints; give one per joint."
            )
        return np.asarray(v, dtype=float)


def _parse_toml(path: Path, label: str) -> dict:
    _refuse_large(path, label)
    data = _read_bytes(path, label)
    try:
        return tomllib.loads(data.decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise DataError(f"{label} is not UTF-8 text. Save it as UTF-8.") from None
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{label} is not valid TOML: {e}. Fix the syntax there.") from None
    except RecursionError:
        raise DataError(
            f"{label}: arrays or tables are nested too deeply to read. An experiment TOML "
            "needs no nesting beyond lists of numbers or names; fix the file."
        ) from None


def _split_tables(doc: dict, tk: _Toml) -> tuple[dict, dict]:
    """(the [experiment] keys, merged with the top-level ones; the tables), unknown names refused."""
    top = {k: v for k, v in doc.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in doc.items() if isinstance(v, dict)}
    allowed_tables = {"experiment", "time", "transmission"} | set(_SECTIONS)
    unknown = sorted(set(tables) - allowed_tables)
    if unknown:
        raise tk.err(
            None,
            f"unknown section(s) {', '.join(f'[{u}]' for u in unknown)}. Allowed: "
            f"{', '.join(f'[{a}]' for a in sorted(allowed_tables))}.",
        )
    unknown = sorted(set(top) - _EXPERIMENT_KEYS)
    if unknown:
        raise tk.err(
            None,
            f"unknown top-level key(s) {', '.join(repr(u) for u in unknown)}. Allowed: "
            f"{', '.join(sorted(_EXPERIMENT_KEYS))} (or put them under [experiment]).",
        )
    exp = dict(tables.get("experiment", {}))
    tk.check_keys("experiment", exp, _EXPERIMENT_KEYS)
    both = sorted(set(top) & set(exp))
    if both:
        raise tk.err(
            None, f"{', '.join(both)} given both at the top and in [experiment]; keep one."
        )
    exp.update(top)
    return exp, tables


def _experiment_options(exp: dict, tk: _Toml, path: Path, label: str) -> tuple[_Options, str | None]:
    """The [experiment] options (declarative: _EXPERIMENT_FIELDS) and the default data file."""
    v = {key: tk.field("experiment", exp, key, f) for key, f in _EXPERIMENT_FIELDS.items()}
    problem = name_problem(v["name"], "name")
    if problem:
        raise tk.err("experiment", problem + ".")
    opts = _Options(name=v["name"] or path.stem, sampling_rate=v["sampling_rate"],
                    start_time=v["start_time"], start_offset=v["start_offset"], resample=v["resample"],
                    time_tolerance=v["time_tolerance"], where=f"{label}, [experiment]")
    return opts, v["file"]


def _load_toml(path: Path, label: str, robot, n_joints) -> Experiment:
    """An Experiment from an experiment description (see the module's docstring)."""
    return _Description(path, label, robot, n_joints).load()


class _Description:
    """One experiment TOML being loaded: its data files, the sections read, the notices."""

    def __init__(self, path: Path, label: str, robot, n_joints):
        self.path, self.label, self.robot, self.n_joints = path, label, robot, n_joints
        self.tk = _Toml(label)
        self.notices: list[str] = []
        self.raws: dict[str, _RawFile] = {}
        self.used_names: dict[str, set[str]] = {}
        self.default_file: str | None = None

    # --- the steps, in order
    def load(self) -> Experiment:
        tk, label = self.tk, self.label
        exp, tables = _split_tables(_parse_toml(self.path, label), tk)
        opts, self.default_file = _experiment_options(exp, tk, self.path, label)
        meta: dict = {"description": label}
        timing = tk.field("experiment", exp, "torque_timing", _EXPERIMENT_FIELDS["torque_timing"])
        if timing and timing not in TORQUE_TIMINGS:
            raise tk.err("experiment", f"torque_timing = {timing!r}: give 'held' (the command held over each "
                                       "period, a controller's log) or 'centred' (centred on the samples, an "
                                       "integrating sensor); DIDIM models it")
        if timing:
            meta["torque_timing"] = timing
        sections = {s: tables[s] for s in _SECTIONS if s in tables}
        if not sections and "time" not in tables:
            experiment = self._column_format(tables, opts, meta)
            gear = _gear_ratios(exp, None, tk, experiment.n_joints)
            if gear is not None:
                experiment.meta["gear_ratios"] = gear
            return experiment
        time_col, t = self._time(tables, opts)
        _check_required(sections, tk)
        values, sides, section_cols = self._signals(sections)
        n = self._joint_count(values, section_cols)
        self._check_lengths(values, section_cols, time_col, t)
        for s, table in sections.items():
            self._scale(s, table, values, n)
            if s in ("torques", "currents"):
                self._gains(s, table, values, n, meta)
        if "currents" in sections:
            _gains_to_identify(sections["currents"], sides["currents"], tables, tk, n, meta)
        self._transmission(tables, sections, sides, values, n)
        gear = _gear_ratios(exp, tables.get("transmission") if any(
            v == "motor" for v in sides.values()) else None, tk, n)
        if gear is not None:
            meta["gear_ratios"] = gear
        self._unused_notice()
        _release(self.raws.values(), [time_col] + [c for cols in section_cols.values() for c in cols])
        signals = {_SECTIONS[s]: v for s, v in values.items()}
        if "i" in signals:
            signals["tau"] = signals.pop("i")
        shift, min_shift, max_shift = _reference_shift(sections, tk)
        cols_of = {("tau" if _SECTIONS[s] == "i" else _SECTIONS[s]):
                   (None if sides[s] == "motor" else section_cols[s]) for s in sections}
        return _assemble(
            t=t, time_col=time_col, signals=signals, opts=opts, notices=self.notices,
            source=f"{label} (data: {', '.join(self.raws)})", meta=meta, shift=shift,
            max_shift=max_shift, min_shift=min_shift, shift_where=f"{label}, [reference]",
            robot=self.robot, cols_of=cols_of,
        )

    def _column_format(self, tables, opts, meta) -> Experiment:
        """No signal section: [experiment] file is in dynid's column format."""
        tk = self.tk
        if self.default_file is None:
            raise tk.err(
                None,
                "describes no data. Give [experiment] file = \"...\" (a file in dynid's "
                "column format) or [positions] / [torques] sections.",
            )
        if "transmission" in tables:
            raise tk.err(
                "transmission",
                "applies to [positions] / [torques] sections with side = \"motor\"; this "
                "file has none.",
            )
        p, plabel = self._resolve(self.default_file)
        if p.suffix.lower() == ".toml":
            raise tk.err("experiment", "file must be a data file, not another TOML.")
        raw = _read_referenced(p, plabel, f"{self.label}, [experiment]")
        return _from_columns(raw, self.robot, self.n_joints, opts, f"{self.label} (data: {plabel})",
                             self.notices, meta)

    def _time(self, tables, opts):
        """(the time column, its values in s) from [time], or (None, None) with a sampling_rate."""
        if "time" not in tables:
            if opts.sampling_rate is None:
                raise self.tk.err(
                    None,
                    "no time: with signal sections the time column is not found by its name; give a "
                    "[time] section naming it (e.g. [time] column = \"t\") or [experiment] sampling_rate = "
                    "... (Hz).",
                )
            return None, None
        tt = tables["time"]
        self.tk.check_keys("time", tt, _TIME_KEYS)
        time_col = self._select_single("time", tt)
        t, note = _time_values(time_col)
        if note:
            self.notices.append(note)
        _check_finite([(time_col, t)])
        tscale = self.tk.number("time", tt, "scale", 1.0, positive=True)
        if tscale != 1.0:
            t = t * tscale
            self.notices.append(f"time scaled by {_fmt(tscale)} ([time] scale)")
        return time_col, t

    def _signals(self, sections):
        """(values (N, n) per section, side per section, the columns of each section)."""
        values: dict[str, np.ndarray] = {}
        sides: dict[str, str] = {}
        section_cols: dict[str, list[_Col]] = {}
        for s, table in sections.items():
            self.tk.check_keys(s, table, _SECTION_KEYS | _EXTRA_KEYS.get(s, set()))
            cols = self._select(s, table)
            items = [(c, _to_float(c)) for c in cols]
            _check_finite(items)
            _plaus.check_magnitude(items, self.robot)
            values[s] = stack_columns([v for _, v in items])
            section_cols[s] = cols
            side = self.tk.string(s, table, "side", "joint")
            if side not in ("joint", "motor"):
                raise self.tk.err(s, f"side must be \"joint\" or \"motor\", got {side!r}.")
            sides[s] = side
        _check_distinct_columns(section_cols, self.tk)
        return values, sides, section_cols

    def _joint_count(self, values, section_cols) -> int:
        ns = {s: v.shape[1] for s, v in values.items()}
        if len(set(ns.values())) > 1:
            raise self.tk.err(
                None,
                "the sections disagree on the number of joints: "
                + ", ".join(f"[{s}] has {k}" for s, k in ns.items())
                + ". Give one column per joint in every section.",
            )
        n = next(iter(ns.values()))
        expected, who = _robot_joints(self.robot, self.n_joints)
        if expected is not None and n != expected:
            s0 = next(iter(values))
            raise DataError(
                f"{who} but {self.label} gives {n} columns in [{s0}] ({section_cols[s0][0].raw.label}). "
                "Load the data with the robot it was recorded on, or fix the column lists."
            )
        return n

    def _check_lengths(self, values, section_cols, time_col, t) -> None:
        lens = {s: v.shape[0] for s, v in values.items()}
        if time_col is not None:
            lens["time"] = t.size
        if len(set(lens.values())) > 1:
            raise self.tk.err(
                None,
                "the sections have different numbers of samples: "
                + ", ".join(
                    f"[{s}] {k} ({(time_col if s == 'time' else section_cols[s][0]).raw.label})"
                    for s, k in lens.items()
                )
                + ". Every signal needs one value per sample.",
            )
        if next(iter(lens.values())) < 2:
            raise self.tk.err(None, "the data have fewer than 2 samples.")

    def _scale(self, s, table, values, n) -> None:
        sc = table.get("scale")
        if sc is None:
            return
        sc = self.tk.numbers(s, table, "scale", n) if isinstance(sc, list) else self.tk.number(s, table, "scale")
        zero = np.flatnonzero(np.atleast_1d(sc) == 0)
        if zero.size:
            which = "scale" if np.isscalar(sc) else f"scale[{int(zero[0])}] (joint {int(zero[0]) + 1})"
            raise self.tk.err(
                s,
                f"{which} = 0 would make every value of the signal 0. Give the factor "
                "that converts the file's values to SI units (1 if they are already), "
                "or remove scale.",
            )
        values[s] = values[s] * sc
        self.notices.append(f"[{s}] scaled by "
                            + (_fmt(sc) if np.isscalar(sc) else "[" + ", ".join(_fmt(x) for x in sc) + "]"))

    def _gains(self, s, table, values, n, meta) -> None:
        g = self.tk.numbers(s, table, "drive_gains", n)
        if g is not None and np.any(g == 0):
            j = int(np.flatnonzero(g == 0)[0])
            raise self.tk.err(
                s,
                f"drive_gains[{j}] = 0 (joint {j + 1}) would make that joint's torque 0 "
                "throughout. Give the gain that converts the signal to N·m (the motor's "
                "torque constant × gear ratio for a current), or 1 if the column already "
                "holds torques.",
            )
        if g is None and s == "currents":
            g, origin = _drive_gains(self.robot, n, self.label)
            self.notices.append(
                f"[currents]: torque = drive gain × current, g = "
                f"[{', '.join(_fmt(x) for x in g)}] ({origin})"
            )
        elif g is not None:
            self.notices.append(
                f"[{s}]: drive gains [{', '.join(_fmt(x) for x in g)}] applied "
                "(signal → torque)"
            )
        if g is not None:
            values[s] = values[s] * g
            meta["drive_gains"] = [float(x) for x in g]

    def _transmission(self, tables, sections, sides, values, n) -> None:
        motor = [s for s in sections if sides[s] == "motor"]
        R = offsets = None
        if "transmission" in tables:
            R, offsets = _reduction(tables["transmission"], self.tk, n)
            if not motor:
                self.notices.append(
                    f"{self.label}: [transmission] given but no section has side = \"motor\"; unused"
                )
        if motor and R is None:
            raise self.tk.err(
                motor[0],
                "side = \"motor\" needs a [transmission] section (gear_ratios, couplings, "
                "position_offsets) to convert to the joint side.",
            )
        for s in motor:
            values[s], how = _to_joint_side(s, values[s], R, offsets)
            self.notices.append(f"[{s}]: motor side converted to joint side, {how}")

    def _unused_notice(self) -> None:
        for plabel, raw in self.raws.items():
            unused = [k for k in raw.arrays if k not in self.used_names[plabel]]
            unused += [k for k in raw.unreadable]
            if unused:
                self.notices.append(
                    f"{plabel}: not used by {self.label}: {_short_list([repr(u) for u in unused])}"
                )

    # --- data files and their columns
    def _resolve(self, f: str) -> tuple[Path, str]:
        p = Path(f)
        if not p.is_absolute():
            p = self.path.parent / p
        return p, str(p)

    def _raw_for(self, section: str, table: dict) -> _RawFile:
        f = self.tk.string(section, table, "file", self.default_file)
        if f is None:
            raise self.tk.err(section, "no data file: give file = \"...\" here or in [experiment].")
        p, plabel = self._resolve(f)
        if plabel not in self.raws:
            self.raws[plabel] = _read_referenced(p, plabel, f"{self.label}, [{section}]")
            self.used_names[plabel] = set()
            self.notices.extend(self.raws[plabel].notices)
        return self.raws[plabel]

    def _lookup(self, raw: _RawFile, name: str, section: str, one_d: bool) -> _Col:
        col = _lookup(raw, name, section, self.tk, _available, one_d=one_d)
        self.used_names[raw.label].add(name)
        return col

    def _select_single(self, section: str, table: dict) -> _Col:
        """The one column [time] names (column = ... or key = ...)."""
        raw = self._raw_for(section, table)
        key, key2 = table.get("key"), table.get("column")
        if key is not None and key2 is not None:
            raise self.tk.err(section, "give either key or column, not both.")
        key = key if key is not None else key2
        if key is None:
            raise self.tk.err(section, "name the time column: column = \"...\" (or key = \"...\").")
        if not isinstance(key, str):
            raise self.tk.err(section, f"column must be a string, got {key!r}.")
        return self._lookup(raw, key, section, one_d=True)

    def _select(self, section: str, table: dict) -> list[_Col]:
        """The joint columns of a signal section: columns = [...] or key = a 2-D array."""
        raw = self._raw_for(section, table)
        key, cols = table.get("key"), table.get("columns")
        if (key is None) == (cols is None):
            raise self.tk.err(
                section,
                "give exactly one of columns = [\"...\", ...] (one column per joint) "
                "or key = \"...\" (a 2-D array of shape (N, n) in an npz/mat file).",
            )
        if cols is not None:
            if not isinstance(cols, list) or not cols or not all(isinstance(c, str) for c in cols):
                raise self.tk.err(section, f"columns must be a non-empty list of names, got {cols!r}.")
            dup = sorted({c for c in cols if cols.count(c) > 1})
            if dup:
                raise self.tk.err(section, f"columns lists {', '.join(map(repr, dup))} twice.")
            return [self._lookup(raw, c, section, one_d=True) for c in cols]
        if not isinstance(key, str):
            raise self.tk.err(section, f"key must be a string, got {key!r}.")
        if raw.tabular:
            raise self.tk.err(
                section,
                f"key = {key!r}: {raw.label} is a table; name its columns with "
                "columns = [\"...\", ...], one per joint.",
            )
        a = self._lookup(raw, key, section, one_d=False).data
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2:
            raise self.tk.err(
                section,
                f"array '{key}' of {raw.label} has shape {a.shape}; expected (N, n), one row "
                "per sample and one column per joint.",
            )
        return [_Col(raw, key, j, a[:, j]) for j in range(a.shape[1])]


def _available(raw: _RawFile) -> str:
    return _short_list([f"'{x}'" for x in raw.arrays], 15)


def _check_distinct_columns(section_cols: dict, tk: _Toml) -> None:
    """One column feeds one signal of one joint: a column named twice (in two sections, or
    twice in one) is a slip of the description, which the fit would take for data."""
    seen = {}
    keys = {s: [(c.raw.label, c.name, c.j) for c in cols] for s, cols in section_cols.items()}
    # the measured positions as the reference, joint by joint: what DIDIM does without [reference]
    same_reference = "reference" in keys and keys["reference"] == keys.get("positions")
    for s, cols in section_cols.items():
        if s == "reference" and same_reference:
            continue
        for j, (c, key) in enumerate(zip(cols, keys[s])):
            if key in seen:
                s0, j0 = seen[key]
                raise tk.err(s, f"joint {j + 1} reads {c.label} of {c.raw.label}, which [{s0}] already reads for "
                                f"joint {j0 + 1}: give each signal and joint its own column.")
            seen[key] = (s, j)


def _check_required(sections: dict, tk: _Toml) -> None:
    if "torques" not in sections and "currents" not in sections:
        raise tk.err(None, "no [torques] (or [currents]) section: torques are required.")
    if "torques" in sections and "currents" in sections:
        raise tk.err(None, "give either [torques] or [currents], not both.")
    if "positions" not in sections and "reference" not in sections:
        raise tk.err(None, "no [positions] (or [reference]) section: positions are required.")


def _gains_to_identify(table: dict, side: str, tables: dict, tk: _Toml, n: int, meta: dict) -> None:
    """`identify_gains` of [currents] (true, false or 1-based joints) into `meta["identify_gains"]`."""
    v = table.get("identify_gains", False)
    if isinstance(v, bool):
        joints = list(range(1, n + 1)) if v else []
    elif isinstance(v, list) and v and all(isinstance(x, int) and not isinstance(x, bool) for x in v):
        joints = list(v)
        bad = [j for j in joints if not 1 <= j <= n]
        if bad or len(set(joints)) != len(joints):
            raise tk.err("currents", f"identify_gains = {v!r}: list distinct joints 1..{n} (1-based) whose "
                                     "drive gain is to be identified, or write true for all of them.")
    else:
        raise tk.err("currents", f"identify_gains must be true, false or a list of 1-based joints, got {v!r}.")
    if joints and side == "motor" and (tables.get("transmission") or {}).get("couplings"):
        raise tk.err("currents", "identify_gains with side = \"motor\" and [transmission] couplings: a "
                                 "coupled motor's gain is not one joint's torque scale. Convert the currents "
                                 "to joint side first, or identify the gains of uncoupled joints only with "
                                 "side = \"joint\".")
    if joints:
        meta["identify_gains"] = joints


def _gear_ratios(exp: dict, transmission: dict | None, tk: _Toml, n: int) -> list[float] | None:
    """The joints' gear ratios for `meta["gear_ratios"]`: `[experiment] gear_ratios`, or those
    of a [transmission] that converts motor-side signals; None when neither gives them."""
    given = tk.numbers("experiment", exp, "gear_ratios", n)
    if given is not None and np.any(given == 0):
        j = int(np.flatnonzero(given == 0)[0])
        raise tk.err("experiment", f"gear_ratios[{j}] = 0 (joint {j + 1}): a gear ratio is the motor's "
                                   "turns per joint turn, never 0. Give it, or leave gear_ratios out.")
    used = None if transmission is None else tk.numbers("transmission", transmission, "gear_ratios", n)
    if given is not None and used is not None and not np.allclose(given, used):
        raise tk.err("experiment", f"gear_ratios {[_fmt(x) for x in given]} differ from [transmission] "
                                   f"gear_ratios {[_fmt(x) for x in used]}, which convert the motor-side "
                                   "signals; remove the [experiment] key (the [transmission] ones are kept).")
    ratios = given if given is not None else used
    return None if ratios is None else [float(x) for x in ratios]


def _reduction(tr: dict, tk: _Toml, n: int):
    """(R, position offsets or None) of a [transmission] table."""
    tk.check_keys("transmission", tr, _TRANSMISSION_KEYS)
    if "gear_ratios" not in tr:
        raise tk.err("transmission", "gear_ratios is required (one per joint).")
    ratios = tk.numbers("transmission", tr, "gear_ratios", n)
    couplings = tr.get("couplings", [])
    if not isinstance(couplings, list):
        raise tk.err("transmission", f"couplings must be a list, got {couplings!r}.")
    try:
        R = _tr.reduction_matrix(list(ratios), couplings)
    except DataError as e:
        raise tk.err("transmission", str(e)) from None
    return R, tk.numbers("transmission", tr, "position_offsets", n)


def _to_joint_side(s: str, values, R, offsets):
    """(the joint-side signal, how it was converted) of a motor-side section."""
    if s in ("positions", "reference"):
        how = "q = R⁻¹·q_motor" + (" + position_offsets" if offsets is not None else "")
        return _tr.joint_from_motor_positions(values, R, offsets), how
    if s in ("velocities", "accelerations"):
        return _tr.joint_from_motor_velocities(values, R), "R⁻¹·(motor signal)"
    return _tr.joint_from_motor_torques(values, R), "tau = Rᵀ·tau_motor"


def _reference_shift(sections: dict, tk: _Toml):
    """(shift or None, min_shift, max_shift) of the [reference] section."""
    if "reference" not in sections:
        return None, None, None
    rt = sections["reference"]
    shift = rt.get("shift", 0)
    if not (shift == "estimate" or (isinstance(shift, int) and not isinstance(shift, bool))):
        raise tk.err(
            "reference",
            f"shift must be a whole number of samples or \"estimate\", got {shift!r}.",
        )
    max_shift = tk.integer("reference", rt, "max_shift", None)
    min_shift = tk.integer("reference", rt, "min_shift", None)
    if min_shift is not None and max_shift is not None and min_shift > max_shift:
        raise tk.err("reference", f"min_shift = {min_shift} exceeds max_shift = {max_shift}.")
    if shift != "estimate" and (min_shift is not None or max_shift is not None):
        given = " and ".join(k for k, v in (("min_shift", min_shift), ("max_shift", max_shift)) if v is not None)
        shown = f"shift = {shift}" if "shift" in rt else "no shift (0)"
        raise tk.err("reference", f"{given} bound(s) the search of shift = \"estimate\", and {shown} is "
                                  f"given: remove {given}, or set shift = \"estimate\".")
    return (None if shift == 0 else shift), min_shift, max_shift


def _refuse_large(path: Path, label: str) -> None:
    """Refuse an experiment TOML over MAX_TOML_BYTES before reading it (parsing takes ~2x its size)."""
    try:
        size = path.stat().st_size
    except OSError:
        return                      # the reader says what is wrong
    if size > MAX_TOML_BYTES:
        raise DataError(
            f"{label} is {size / 2**20:.1f} MiB, more than the {MAX_TOML_BYTES // 2**20} MiB an experiment "
            "TOML may have: it names data files and columns, the samples belong in the data file "
            "(.csv, .parquet, .npz, .mat) it refers to."
        )


def _read_referenced(p: Path, plabel: str, where: str) -> _RawFile:
    """Read a data file named in a TOML; errors also say where the name came from."""
    try:
        return _read_data_file(p, plabel)
    except DataError as e:
        hint = (" Paths in an experiment TOML are relative to the TOML file's folder."
                if "not found" in str(e) else "")
        raise DataError(f"{where} names a data file that cannot be used: {e}{hint}") from None


def _lookup(raw: _RawFile, name: str, section: str, tk: _Toml, available, one_d: bool) -> _Col:
    if name in raw.unreadable:
        raise tk.err(
            section,
            f"array '{name}' of {raw.label} cannot be read ({raw.unreadable[name]}). Store "
            "it as a plain numeric array.",
        )
    if name not in raw.arrays:
        raise tk.err(
            section,
            f"{raw.label} has no {'column' if raw.tabular else 'array'} '{name}'. "
            f"Available: {available(raw)}.",
        )
    a = raw.arrays[name]
    if one_d:
        if a.ndim == 2 and 1 in a.shape:
            a = a.reshape(-1)
        if a.ndim != 1:
            raise tk.err(
                section,
                f"'{name}' of {raw.label} has shape {a.shape}; a single column of shape "
                "(N,) is needed here (use key = ... for a 2-D array).",
            )
    return _Col(raw, name, None, a)

