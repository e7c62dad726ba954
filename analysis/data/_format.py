"""Number, time and list formatting shared by the experiment loader's messages."""

from __future__ import annotations

#: Longest list written out in full in a message (the rest is counted).
_MAX_LIST = 8


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _fmt_t(x: float) -> str:
    """A time value: all digits down to 0.1 ms for large (epoch) stamps."""
    return f"{x:.4f}" if abs(x) >= 1e4 else f"{x:.6g}"



def _short_list(items, limit: int = _MAX_LIST) -> str:
    items = list(items)
    s = ", ".join(str(x) for x in items[:limit])
    if len(items) > limit:
        s += f", … ({len(items) - limit} more)"
    return s

