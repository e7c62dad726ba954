"""Checks shared by the robot readers (TOML and URDF): bounds, names, file reading, numbers.

The limits on what a robot description may say, the reading of a robot file
(a regular file of bounded size) and the checks of names and numbers, each
refusing bad input with one `RobotFileError` naming the file, the field and
what to do. Both `robot_file` and `urdf` import from here, so neither imports
the other for them.
"""
from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynid.errors import RobotFileError

# ----------------------------------------------------------------- bounds
# Limits on what a robot description may say. Each is far beyond any real robot arm
# (the largest industrial arms weigh a few tonnes, reach under 5 m, have under 10
# joints and run their controllers at 1-10 kHz), so they only refuse typing slips and
# unit mix-ups (1e300, a ratio of 1.6e154 that overflowed the regressor, 1e-300 that
# gave NaN base-parameter relations) and inputs that would take minutes and gigabytes
# (a 1000-joint URDF took 6.5 GiB, a 400-joint TOML 3 minutes). Every message says
# the bound and what to do.
MAX_FILE_BYTES = 16 * 2 ** 20     # a robot file; a detailed humanoid URDF is under 1 MiB
MAX_JOINTS = 64                   # moving joints of a robot (a humanoid has ~40)
MAX_URDF_LINKS = 10_000           # links of a URDF, chain or not (a humanoid has ~100)
MAX_LENGTH = 100.0                # m: |d|, |r| of an MDH row, each URDF origin coordinate
MAX_GRAVITY = 100.0               # m/s^2: norm of gravity (10 g; the Earth's is 9.81)
MAX_MASS = 1e5                    # kg: one link's mass (100 t)
MAX_INERTIA = 1e5                 # kg m^2: inertia entries, rotor inertia Ia, controller J_ap
MIN_RATIO, MAX_RATIO = 1e-6, 1e6  # |coupling coefficient|, |its ratio to the motor's|, |drive gain|,
                                  # controller wn (rad/s), zeta, g_ap, ki
MIN_RATE, MAX_RATE = 1.0, 1e6     # Hz: controller rate
MIN_J_AP = 1e-9                   # kg m^2: smallest a-priori joint inertia of the controller
MAX_APRIORI = 1e9                 # |any other a-priori value| (friction, offsets, base parameters)
MAX_NESTING = 32                  # depth of TOML tables/arrays (tx40.toml uses 4)
MAX_ANGLE = 2 * math.pi           # rad: |alpha|, |theta| of an MDH row (one turn; 90 or 180 is degrees)
MAX_TRAVEL = 1e4                  # rad or m: |joint limit| when finite (infinite: no limit)
MAX_SPEED = 1e4                   # rad/s or m/s: qd_max when finite (a fast arm joint: ~10 rad/s)
# rad/s or m/s: the smallest qd_max (0.06 deg/s; a slow heavy joint turns at ~0.5 rad/s): below it
# the loader's speed checks would blame the recording's time column for the robot file's limit
MIN_SPEED = 1e-3
MAX_ACCEL = 1e6                   # rad/s^2 or m/s^2: qdd_max when finite
MAX_EFFORT = 1e7                  # N m or N: tau_max when finite (the largest arms: ~1e5 N m)

# C0 and C1 control characters, DEL, and the bidirectional overrides that reorder text on screen
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_TEXT_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def shown(text):
    """`text` with its control characters escaped, safe to print in a message."""
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), str(text))


def short(value, limit=80):
    """A value's repr, cut short and with control characters escaped, for a message."""
    text = shown(repr(value))
    return text if len(text) <= limit else text[:limit] + "..."


def name_problem(name, where):
    """What is wrong with a name that holds a control character (it would be printed on a
    terminal as is), or None: the one wording of robot files and experiment descriptions."""
    m = _CONTROL.search(name)
    if m is None:
        return None
    return (f"{where} '{shown(name)}' holds the control character {shown(m.group())} (at position "
            f"{m.start() + 1}); names are printed on terminals and in reports: remove it")


def check_name(name, where, path):
    """Refuse a name with control characters."""
    problem = name_problem(name, where)
    if problem:
        raise RobotFileError(f"{path}: {problem}")


def check_text(text, where, path):
    """Free text (descriptions, provenance) may hold tabs and newlines, no other control characters."""
    m = _TEXT_CONTROL.search(text)
    if m:
        raise RobotFileError(f"{path}: {where} holds the control character {shown(m.group())} (at "
                             f"position {m.start() + 1}); it is printed on terminals: remove it")


def read_limited(path, what="robot file"):
    """The bytes of a robot file: a regular file of at most `MAX_FILE_BYTES`, checked before reading."""
    path = Path(path)
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a folder" if stat.S_ISDIR(st.st_mode) else
                    "a named pipe (FIFO)" if stat.S_ISFIFO(st.st_mode) else
                    "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else
                    "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
            raise RobotFileError(f"cannot read {what} '{path}': it is {kind}, not a regular file; "
                                 f"give the path of a .toml or .urdf file")
        if st.st_size > MAX_FILE_BYTES:
            raise RobotFileError(_too_big(path, what))
        # O_NONBLOCK: should the path become a FIFO after the check, opening does not hang
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise RobotFileError(f"cannot read {what} '{path}': it is not a regular file; give "
                                     f"the path of a .toml or .urdf file")
            data = fh.read(MAX_FILE_BYTES + 1)
    except RobotFileError:
        raise
    except OSError as exc:
        raise RobotFileError(f"cannot read {what} '{path}': {exc.strerror}; check the path and that "
                             f"it is a readable file") from None
    except ValueError:      # a path with a NUL byte
        raise RobotFileError(f"cannot read {what} {str(path)!r}: the path is not valid; "
                             f"check the path") from None
    if len(data) > MAX_FILE_BYTES:
        raise RobotFileError(_too_big(path, what))
    return data


def _too_big(path, what):
    return (f"cannot read {what} '{path}': it is larger than {MAX_FILE_BYTES // 2 ** 20} MiB, more "
            f"than any robot description; check that it is the right file")


def number(value, where, path, *, positive=False, nonnegative=False, allow_inf=False, bounds=None,
           unit="", who="", hint=None):
    """A finite float (`allow_inf`: or +-inf); `bounds=(lo, hi)` on `|value|` (lo: nonzero).

    `who` names what the field belongs to (" (joint 'j2')") after the value in
    a message; `hint(v)`, when given, says what to do with a value beyond the
    upper bound (for angles: that they are in radians).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RobotFileError(f"{path}: {where}{who} must be a number, got {short(value)}")
    try:
        v = float(value)
    except OverflowError:   # an integer beyond float range
        raise RobotFileError(f"{path}: {where}{who} must be a finite number, got an integer too large "
                             f"for a float") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise RobotFileError(f"{path}: {where}{who} must be a finite number, got {value!r}")
    if positive and v <= 0:
        raise RobotFileError(f"{path}: {where}{who} must be positive, got {value!r}")
    if nonnegative and v < 0:
        raise RobotFileError(f"{path}: {where} = {v:g}{who} is negative; it must be 0 or positive: "
                             f"fix the sign")
    if bounds is not None and not math.isinf(v):     # an allowed infinity means "no limit"
        lo, hi = bounds
        if lo and abs(v) < lo:
            raise RobotFileError(f"{path}: {where} = {v:g}{who} is {'0' if v == 0 else 'too small'}; its "
                                 f"size must be at least {lo:g}{unit} (at most {hi:g}{unit}): check the "
                                 f"number and its unit")
        if abs(v) > hi:
            raise RobotFileError(f"{path}: {where} = {v:g}{who} is beyond the {hi:.4g}{unit} dynid accepts"
                                 + (f"; {hint(v)}" if hint is not None else
                                    ", far more than a real robot needs; check the number and its unit"))
    return v


@dataclass(frozen=True)
class Number:
    """One numeric field of a robot file: its unit and its finite physical range.

    `bounds=(lo, hi)` on the size (lo = 0: no lower bound); `positive` and
    `nonnegative` on the sign; `allow_inf` for limits that may be unbounded;
    `hint(v)` says what to do with a value beyond `hi`. Calling it checks one value.
    """

    unit: str = ""
    bounds: tuple = None
    positive: bool = False
    nonnegative: bool = False
    allow_inf: bool = False
    hint: Callable = None

    def __call__(self, value, where, path, who=""):
        return number(value, where, path, positive=self.positive, nonnegative=self.nonnegative,
                      allow_inf=self.allow_inf, bounds=self.bounds, unit=self.unit, who=who,
                      hint=self.hint)

    def vector(self, value, n, where, path, names=None):
        """One value per joint (a single number stands for all), each checked; `names`: joint names."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value] * n
        if not isinstance(value, list) or len(value) != n:
            raise RobotFileError(f"{path}: {where} must be a list of {n} numbers (one per joint), "
                                 f"got {short(value)}")
        who = [f" (joint '{shown(nm)}')" for nm in names] if names else [""] * n
        return np.array([self(v, f"{where}[{k + 1}]", path, who[k]) for k, v in enumerate(value)])


def radians_hint(v):
    """What to do with an angle beyond one turn: it is in radians, and a value like 90 is degrees."""
    if abs(v) <= 720:
        return (f"angles are in radians and {v:g} looks like degrees: give {math.radians(v):.6g} "
                f"({v:g} degrees in radians)")
    return "angles are in radians, within one turn: check the number and its unit"


def nesting(doc):
    """Depth of nested tables/arrays of a document, counted without recursion."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        obj, depth = stack.pop()
        deepest = max(deepest, depth)
        if depth > MAX_NESTING:
            return depth
        if isinstance(obj, dict):
            stack.extend((v, depth + 1) for v in obj.values() if isinstance(v, (dict, list)))
        elif isinstance(obj, list):
            stack.extend((v, depth + 1) for v in obj if isinstance(v, (dict, list)))
    return deepest


def no_unknown_keys(tab, allowed, where, path):
    unknown = sorted(set(tab) - set(allowed))
    if unknown:
        raise RobotFileError(f"{path}: {where} has unknown key(s) {', '.join(map(shown, unknown))}; "
                             f"allowed: {', '.join(sorted(allowed))}. Check the spelling.")
