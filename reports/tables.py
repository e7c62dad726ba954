"""Tables for the HTML reports: formatted, template-ready rows and CSV downloads.

A `Table` is what the template renders: column labels, rows of
`Cell` (text already formatted, plus a CSS class), optional column
groups, and the *unformatted* data as a `data:text/csv` URI so that every
table of a report can be downloaded with full precision from the page itself.

Formatting rules (`format_value`): numbers with 4 significant digits,
%σ with 2 decimals below 100 (2 significant digits below 0.1), `inf` → "∞", NaN / missing → "—". All texts stay plain
strings: the template escapes them.
"""
from __future__ import annotations

import math
import numbers
import re
import urllib.parse
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dynid.analysis.results import p_value_text
from dynid.analysis.units import parameter_unit

__all__ = [
    "Cell", "Table", "MISSING", "format_value", "format_number", "format_pct",
    "format_angle", "infer_kind", "frame_rows", "csv_text", "csv_data_uri", "make_table", "with_label_units",
    "table2_frame", "table2_layout", "NOT_ESSENTIAL", "NOT_IN_PAPER",
]

MISSING = "\u2014"          # em dash
INF = "\u221e"
MINUS = "\u2212"
#: Markers of the Table-2 layout.
NOT_ESSENTIAL = "\u2020"    # † in Table 2, not in dynid's essential set
NOT_IN_PAPER = "+"          # in dynid's essential set, not in Table 2

_SLUG = re.compile(r"[^a-z0-9]+")


@dataclass
class Cell:
    """One formatted table cell; `cls` is a CSS class (`num`, `text`, `flag`…)."""

    text: str
    cls: str = ""
    title: str = ""          # tooltip


@dataclass
class Table:
    """A table ready for the template."""

    key: str                             # HTML id (unique within the report)
    caption: str
    columns: list                        # column labels (plain strings, escaped on output)
    rows: list                           # list of lists of Cell
    csv_uri: str = ""                    # data:text/csv;charset=utf-8,...
    csv_name: str = ""                   # file name offered for download
    groups: list = field(default_factory=list)   # [(label, colspan), ...] above the columns
    column_classes: list = field(default_factory=list)  # CSS class per column (th)
    note: str = ""                       # plain text under the table
    cls: str = ""                        # CSS class of the <table>

    @property
    def n_rows(self) -> int:
        return len(self.rows)


# ----------------------------------------------------------------------------- values
def _is_missing(x) -> bool:
    if x is None or x is pd.NA or x is pd.NaT:
        return True
    try:
        return isinstance(x, (float, np.floating)) and math.isnan(float(x))
    except (TypeError, ValueError):
        return False


def _signed(text: str) -> str:
    return MINUS + text[1:] if text.startswith("-") else text


def format_number(x, digits: int = 4) -> str:
    """`x` with `digits` significant digits; ∞ and — for non-finite values."""
    if _is_missing(x):
        return MISSING
    x = float(x)
    if math.isinf(x):
        return INF if x > 0 else MINUS + INF
    if x == 0:
        return "0"
    text = f"{x:.{digits}g}"
    if "e" in text:
        mant, exp = text.split("e")
        text = f"{mant}e{int(exp)}"
    return _signed(text)


def format_pct(x) -> str:
    """A relative standard deviation in %: 2 decimals below 100 (9.97 and 10.02 read apart at the
    10 % threshold), 1 decimal above, 2 significant digits below 0.1 (a %σ of 0.04 is not "0.0"),
    scientific beyond 10⁵."""
    if _is_missing(x):
        return MISSING
    x = float(x)
    if math.isinf(x):
        return INF if x > 0 else MINUS + INF
    if abs(x) >= 1e5:
        return format_number(x, 2)
    if 0 < abs(x) < 0.095:
        return _signed(f"{x:.2g}")
    return _signed(f"{x:.2f}" if abs(x) < 99.995 else f"{x:.1f}")


def format_angle(x) -> str:
    """An angle in rad, as a multiple of π/2 or π/4 when it is one (else 4 digits)."""
    if _is_missing(x):
        return MISSING
    x = float(x)
    if x == 0:
        return "0"
    for den in (1, 2, 3, 4, 6):
        k = x * den / math.pi
        if abs(k - round(k)) < 1e-9 and round(k) != 0:
            k = int(round(k))
            num = "\u03c0" if abs(k) == 1 else f"{abs(k)}\u03c0"
            text = num if den == 1 else f"{num}/{den}"
            return (MINUS if k < 0 else "") + text
    return format_number(x)


def infer_kind(series: pd.Series, name: str = "") -> str:
    """Formatting kind of a column: bool, int, pct, p (a p-value), num or text."""
    low = str(name).lower()
    if series.dtype == bool:
        return "bool"
    if pd.api.types.is_integer_dtype(series.dtype):
        return "int"
    if pd.api.types.is_float_dtype(series.dtype):
        if "rel_std" in low or "%" in low or low.endswith("_pct") or "percent" in low:
            return "pct"
        if low in ("p", "p_value", "p-value") or low.endswith(("_p", "_p_value", " p-value")):
            return "p"
        return "num"
    return "text"


def format_value(x, kind: str = "auto") -> Cell:
    """A `Cell` for value `x` of formatting `kind`.

    Kinds: `num` (4 significant digits), `pct` (1 decimal), `p` (a p-value,
    `dynid.analysis.results.p_value_text`), `int`,
    `bool` ("✓" or empty), `angle` (multiples of π), `text`, `code`
    (monospace text), `auto` (from the Python type).
    """
    if kind == "auto":
        if isinstance(x, (bool, np.bool_)):
            kind = "bool"
        elif isinstance(x, numbers.Integral):
            kind = "int"
        elif isinstance(x, numbers.Real):
            kind = "num"
        else:
            kind = "text"
    if kind in ("num", "pct", "angle", "int", "p") and _is_missing(x):
        return Cell(MISSING, "num missing")
    if kind == "num":
        return Cell(format_number(x), "num")
    if kind == "p":
        return Cell(p_value_text(x, MISSING), "num")
    if kind == "pct":
        return Cell(format_pct(x), "num")
    if kind == "angle":
        return Cell(format_angle(x), "num")
    if kind == "int":
        try:
            return Cell(_signed(str(int(x))), "num")
        except (TypeError, ValueError):
            return Cell(str(x), "num")
    if kind == "bool":
        if _is_missing(x):
            return Cell("", "flag")
        return Cell("\u2713" if bool(x) else "", "flag")
    if kind == "code":
        return Cell("" if _is_missing(x) else str(x), "code")
    return Cell("" if _is_missing(x) else str(x), "text")


def frame_rows(df: pd.DataFrame, formats: dict | None = None, *, index: bool = True,
               labels: dict | None = None):
    """`(columns, rows, column_classes)` of `df` formatted for the template.

    `formats` maps column name → kind (see `format_value`); other
    columns get `infer_kind`. `labels` renames columns for display.
    With `index=True` the index comes first (its name as label).
    """
    formats = dict(formats or {})
    labels = dict(labels or {})
    frame = df.reset_index() if index else df
    if index and df.index.name is None and "index" in frame.columns:
        frame = frame.rename(columns={"index": ""})
    kinds = [formats.get(c, infer_kind(frame[c], c)) for c in frame.columns]
    columns = [str(labels.get(c, c)) for c in frame.columns]
    rows = []
    for values in frame.itertuples(index=False, name=None):
        rows.append([format_value(v, k) for v, k in zip(values, kinds)])
    classes = ["num" if k in ("num", "pct", "int", "angle", "p") else
               "flag" if k == "bool" else "text" for k in kinds]
    return columns, rows, classes


# ------------------------------------------------------------------------------ CSV
def csv_text(df: pd.DataFrame, *, index: bool = True) -> str:
    """The CSV of `df`: full precision, `\\n` line ends, deterministic."""
    return df.to_csv(index=index, lineterminator="\n")


def csv_data_uri(df_or_text, *, index: bool = True) -> str:
    """`data:text/csv;charset=utf-8,...` URI of a DataFrame (or of CSV text).

    Everything but unreserved characters is percent-encoded (UTF-8), so the
    URI is safe inside an HTML attribute and decodes with
    `urllib.parse.unquote`.
    """
    text = df_or_text if isinstance(df_or_text, str) else csv_text(df_or_text, index=index)
    return "data:text/csv;charset=utf-8," + urllib.parse.quote(text, safe="", encoding="utf-8")


def slug(text: str) -> str:
    """A lower-case identifier made of `[a-z0-9-]`."""
    s = _SLUG.sub("-", str(text).lower()).strip("-")
    return s or "table"


_LABEL_UNIT = re.compile(r"\[([^\]]+)\]\s*$")


#: a joint quantity's unit, and what it reads on a robot with prismatic joints (their
#: positions, velocities and forces are in m, m/s and N)
_PRISMATIC_UNIT = {"rad": "rad or m", "rad/s": "rad/s or m/s", "N m": "N m or N", "mrad": "mrad or mm"}


def with_label_units(frame: pd.DataFrame, labels: dict | None, prismatic: bool = False) -> pd.DataFrame:
    """`frame` with the unit its displayed label ends with (`"RMS residual [N m]"`) appended to
    the column's CSV name (`rms [N m]`), so that a downloaded table keeps the units the page
    shows. Not "%": a percent column says so in its name (`rel_error_percent`), and some show
    a fraction as a percentage (`rel_error` 0.002 is "0.2 %"). `prismatic`: the table's rows
    include prismatic joints, whose joint units are m, m/s and N (`rms [N m or N]`)."""
    rename = {}
    for col, label in (labels or {}).items():
        m = _LABEL_UNIT.search(str(label))
        if m and col in frame.columns and m.group(1) != "%":
            unit = _PRISMATIC_UNIT.get(m.group(1), m.group(1)) if prismatic else m.group(1)
            rename[col] = f"{col} [{unit}]"
    return frame.rename(columns=rename) if rename else frame


def make_table(df: pd.DataFrame, key: str, caption: str, *, formats: dict | None = None,
               labels: dict | None = None, index: bool = True, note: str = "",
               csv_frame: pd.DataFrame | None = None, csv_index: bool | None = None,
               csv_name: str | None = None, cls: str = "", prismatic: bool = False) -> Table:
    """A `Table` of `df` with its CSV download.

    The CSV holds `csv_frame` (default `df`) unformatted, each column named with the unit its
    label shows (`with_label_units`; `prismatic`: the rows include prismatic joints).
    """
    columns, rows, classes = frame_rows(df, formats, index=index, labels=labels)
    data = with_label_units(df if csv_frame is None else csv_frame, labels, prismatic)
    ci = index if csv_index is None else csv_index
    return Table(key=key, caption=caption, columns=columns, rows=rows,
                 csv_uri=csv_data_uri(data, index=ci),
                 csv_name=csv_name or f"{slug(key)}.csv", column_classes=classes,
                 note=note, cls=cls)


# ----------------------------------------------------------------------- Table 2
def table2_frame(names, chi, rel_sigma, reference=None, base_order=None) -> pd.DataFrame:
    """One row per parameter of dynid's essential set or of the reference table.

    Columns: `value`, `rel_std_percent` (dynid), `paper_value`,
    `paper_rel_std_percent` (NaN when absent), `status`: `both`,
    `not_essential` (in the paper, not in dynid's essential set) or
    `not_in_paper`. Rows follow `base_order` (the base parameters' order),
    then parameters known to neither order.
    """
    ours = {n: (float(c), float(r)) for n, c, r in zip(names, chi, rel_sigma)}
    paper = {} if reference is None else {v.name: v for v in reference.values}
    order = list(base_order) if base_order is not None else list(names)
    wanted = [n for n in order if n in ours or n in paper]
    for n in list(names) + list(paper):
        if n not in wanted:
            wanted.append(n)
    rows = []
    for n in wanted:
        v, r = ours.get(n, (math.nan, math.nan))
        p = paper.get(n)
        if reference is None:
            status = "essential"
        elif n in ours and p is not None:
            status = "both"
        elif p is not None:
            status = "not_essential"
        else:
            status = "not_in_paper"
        rows.append({"parameter": n, "value": v, "rel_std_percent": r,
                     "paper_value": p.value if p is not None else math.nan,
                     "paper_rel_std_percent": p.rel_std_percent if p is not None else math.nan,
                     "status": status})
    frame = pd.DataFrame(rows, columns=["parameter", "value", "rel_std_percent", "paper_value",
                                        "paper_rel_std_percent", "status"])
    frame = frame.set_index("parameter")
    if reference is None:
        frame = frame.drop(columns=["paper_value", "paper_rel_std_percent"])
    return frame


def table2_layout(names, chi, rel_sigma, reference=None, base_order=None, *,
                  key="table2", caption="Essential parameters in the layout of Table 2",
                  ours_label="dynid", prismatic=frozenset()) -> Table:
    """Two side-by-side blocks of Parameter | unit | χ̂ | %σ (| paper χ̂ | paper %σ), like Table 2.

    The CSV download has one row per parameter with its SI `unit` (`prismatic`: the 1-based
    numbers of the prismatic joints, whose parameters are in N and m).

    With a `reference` (`dynid.reports.paper.ReferenceTable`) the paper's
    value and %σ stand beside dynid's; a parameter of the paper missing from
    dynid's essential set is marked † (and dynid's cells are "—"), one of
    dynid's essential set absent from the paper is marked +.
    """
    frame = table2_frame(names, chi, rel_sigma, reference, base_order)
    with_paper = reference is not None
    n = len(frame)
    half = (n + 1) // 2
    blocks = [frame.iloc[:half], frame.iloc[half:]]

    def cells(name, row):
        mark, title, cls = "", "", "text param"
        if with_paper and row["status"] == "not_essential":
            mark, title, cls = f" {NOT_ESSENTIAL}", "in Table 2, not in dynid's essential set", cls + " marked"
        elif with_paper and row["status"] == "not_in_paper":
            mark, title, cls = f" {NOT_IN_PAPER}", "in dynid's essential set, not in Table 2", cls + " marked"
        out = [Cell(f"{name}{mark}", cls, title), Cell(parameter_unit(str(name), prismatic), "text unit"),
               format_value(row["value"], "num"), format_value(row["rel_std_percent"], "pct")]
        if with_paper:
            pv = format_value(row["paper_value"], "num")
            pr = format_value(row["paper_rel_std_percent"], "pct")
            pv.cls += " paper"
            pr.cls += " paper"
            out += [pv, pr]
        return out

    width = 6 if with_paper else 4
    rows = []
    for i in range(half):
        row = []
        for b, block in enumerate(blocks):
            if i < len(block):
                c = cells(block.index[i], block.iloc[i])
            else:
                c = [Cell("", "empty") for _ in range(width)]
            if b == 1:
                c[0].cls += " block-start"
            row += c
        rows.append(row)
    one = ["Parameter", "unit", "\u03c7\u0302", "%\u03c3"]
    if with_paper:
        one += ["\u03c7\u0302 paper", "%\u03c3 paper"]
    classes = ["text", "text", "num", "num"] + (["num paper", "num paper"] if with_paper else [])
    columns = one + one
    column_classes = classes + ["text block-start"] + classes[1:]
    groups = []
    if with_paper:
        g = [("", 2), (ours_label, 2), ("paper", 2)]
        groups = g + g
    note = ""
    if with_paper:
        n_missing = int((frame["status"] == "not_essential").sum())
        n_extra = int((frame["status"] == "not_in_paper").sum())
        note = (f"{NOT_ESSENTIAL} in Table 2 but not in dynid's essential set ({n_missing}); "
                f"{NOT_IN_PAPER} in dynid's essential set but not in Table 2 ({n_extra}). "
                f"Paper: {reference.citation}, {reference.title}.")
    csv = frame.copy()
    csv.insert(1, "unit", [parameter_unit(str(n), prismatic) for n in frame.index])
    return Table(key=key, caption=caption, columns=columns, rows=rows,
                 csv_uri=csv_data_uri(csv), csv_name=f"{slug(key)}.csv", groups=groups,
                 column_classes=column_classes, note=note, cls="table2")
