"""The finite physical range of every numeric option, in one table.

Each option is checked where the library consumes it (so the command line and
Python refuse alike, before any work), with one message naming both spellings
(`--nd` on the command line, `nd=` in Python), the value and the range. The
ranges are wide: they refuse what cannot be meant (a decimation by 1e10, a
Coulomb smoothing of 1e-300 rad/s, a prior weighed 1e300 times the data), not
unusual choices.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from dynid.errors import InputError

__all__ = ["RANGES", "check_range", "check_joints", "OptionRange"]


@dataclass(frozen=True)
class OptionRange:
    """The accepted values of one option: `low` .. `high` (inclusive), whole numbers if `integer`."""

    cli: str            # the command-line flag
    python: str         # the keyword argument
    low: float
    high: float
    unit: str = ""
    integer: bool = False
    why: str = ""       # what the upper end protects (time, memory, a solver)
    open_low: bool = False      # `low` itself refused (a cut-off of 0 Hz, a level of 0)
    open_high: bool = False


RANGES = {
    "nd": OptionRange("--nd", "nd", 1, 10_000, integer=True,
                      why="a decimation beyond 10 000 leaves no samples of any recording and its filter "
                          "alone takes gigabytes"),
    "n_boot": OptionRange("--bootstrap", "n_boot", 0, 100_000, "refits", integer=True,
                          why="each refit is an SDP solve; 100 000 already takes hours"),
    "v_s": OptionRange("--v-s", "settings['v_s']", 1e-3, 10.0, "rad/s",
                       why="a narrower smoothing makes the simulated friction stiff: the simulation's "
                           "steps shrink without end"),
    "prior_weight": OptionRange("--prior-weight", "prior_weight", 0.0, 1e15,
                                why="beyond 1e15 the data vanish below double precision beside the "
                                    "a-priori term and the SDP solver fails"),
    # the other numeric options of an identification run (dynid.analysis.run.Settings)
    "holdout": OptionRange("--holdout", "holdout", 0.0, 1e7, "s", open_low=True),
    "fc": OptionRange("--fc", "fc", 0.0, 1e6, "Hz", open_low=True),
    "decimation_cutoff": OptionRange("--decimation-cutoff", "decimation_cutoff", 0.0, 1e6, "Hz", open_low=True),
    "max_error_growth": OptionRange("--max-error-growth", "max_error_growth", 0.0, 100.0,
                                    "(a fraction: 0.02 = 2 %)"),
    "f0": OptionRange("--f0", "f0", 0.0, 1e4, "Hz", open_low=True),
    "ml_harmonics": OptionRange("--ml-harmonics", "ml_harmonics", 1, 1000, integer=True,
                                why="each harmonic adds parameters to every joint's latent trajectory"),
    "max_iter": OptionRange("--max-iter", "max_iter", 1, 10_000, "steps", integer=True,
                            why="each step is a closed-loop simulation"),
    "mass_tolerance": OptionRange("--mass-tolerance", "mass_tolerance", 0.0, 1e3, "(a fraction of each mass)"),
    "seed": OptionRange("--seed", "seed", 0, 10**18, integer=True),
    "max_seconds": OptionRange("--max-seconds", "max_seconds", 0.0, 1e7, "s", open_low=True),
    "duration": OptionRange("--duration", "duration", 0.0, 1e6, "s", open_low=True),
    "max_effects": OptionRange("--max-effects", "max_effects", 1, 100, integer=True),
    "alpha": OptionRange("--alpha", "alpha", 0.0, 1.0, open_low=True, open_high=True),
    "walkers": OptionRange("--walkers", "walkers", 1, 100_000, integer=True,
                           why="every walker keeps its own chain in memory"),
    "n_starts": OptionRange("--starts", "n_starts", 1, 10_000, "starts", integer=True,
                            why="each start is an optimisation of its own"),
    "workers": OptionRange("--workers", "workers", 1, 1024, "processes", integer=True,
                           why="each local worker is a process of its own"),
    "max_steps": OptionRange("--max-steps", "max_steps", 1, 100_000_000, integer=True,
                             why="the chains are kept in memory"),
    # Python only (dynid.identify_payload): no flag, so the message names the function
    "rank_rtol": OptionRange("identify_payload", "rank_rtol", 0.0, 1.0, open_low=True, open_high=True),
    "max_rel_halfwidth": OptionRange("identify_payload", "max_rel_halfwidth", 0.0, 1e6, open_low=True),
}


def check_range(name: str, value, *, cli: str | None = None, python: str | None = None):
    """`value` if it is within `RANGES[name]`, else an InputError naming the option.

    Returns an int for an integer option, a float otherwise.

    Examples
    --------
    >>> check_range("nd", 10)
    10
    """
    r = RANGES[name]
    where = f"{cli or r.cli} ({python or r.python}=)"
    unit = f" {r.unit}" if r.unit else ""
    span = (f"{'greater than' if r.open_low else 'from'} {r.low:g} "
            f"{'and below' if r.open_high else 'and at most' if r.open_low else 'to'} {r.high:g}{unit}")
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if r.integer and math.isfinite(number) and number != int(number):
        number = math.nan
    inside = (math.isfinite(number) and (r.low < number if r.open_low else r.low <= number)
              and (number < r.high if r.open_high else number <= r.high))
    if not inside:
        kind = "a whole number" if r.integer else "a number"
        raise InputError(f"{where} {value!r} is out of range: give {kind} {span}"
                         + (f" ({r.why})" if r.why and math.isfinite(number) and number > r.high else ""))
    # a whole number given as 3.0 stays an int; a float option keeps its value (a numpy float stays one)
    if r.integer:   # an integer keeps every digit (a seed above 2**53 would move through float)
        return int(value) if isinstance(value, numbers.Integral) else int(number)
    return value if isinstance(value, float) else number


def check_joints(joints, n: int, *, option: str = "joints", robot: str = "") -> list:
    """`joints` as a list of distinct 1-based joint numbers in 1..n (None or "all": all `n`), else an
    InputError naming the option: a joint 0 would silently index the last joint from the end.

    Examples
    --------
    >>> check_joints([3, 1], 6)
    [3, 1]
    """
    if joints is None or (isinstance(joints, str) and joints.strip().lower() == "all"):
        return list(range(1, n + 1))
    of = f" of robot '{robot}'" if robot else ""
    items = [joints] if isinstance(joints, (numbers.Number, str)) else joints
    try:
        items = list(items)
        # a boolean is no joint number (True would be joint 1), numpy's neither
        out = [int(j) for j in items if not isinstance(j, (bool, np.bool_)) and float(j) == int(j)]
        ok = len(out) == len(items)
    except (TypeError, ValueError, OverflowError):
        out, ok = [], False
    if not ok or not out or any(not 1 <= j <= n for j in out) or len(set(out)) != len(out):
        raise InputError(f"{option} must list distinct joint numbers 1..{n}{of} (1-based), got {joints!r}")
    return out
