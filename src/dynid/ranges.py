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
from dataclasses import dataclass

from dynid.errors import InputError

__all__ = ["RANGES", "check_range", "OptionRange"]


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
    span = f"from {r.low:g} to {r.high:g}{unit}"
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if r.integer and math.isfinite(number) and number != int(number):
        number = math.nan
    if not (math.isfinite(number) and r.low <= number <= r.high):
        kind = "a whole number" if r.integer else "a number"
        raise InputError(f"{where} {value!r} is out of range: give {kind} {span}"
                         + (f" ({r.why})" if r.why and math.isfinite(number) and number > r.high else ""))
    return int(number) if r.integer else number
