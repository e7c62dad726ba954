"""Readers: one data file (CSV, Parquet, npz, MAT) → its named raw columns.

Each reader returns a `_RawFile`: the file's arrays by name (CSV cells as text
until a column is used, or float64 columns when the fast CSV path succeeded), plus
the row-numbering convention used in messages. Turning raw columns into signals is
`dynid.analysis.data.columns`' job.
"""

from __future__ import annotations

import csv
import math
import os
import re
import stat
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from dynid.analysis.data._format import _short_list
from dynid.analysis.data.columns import _COLUMN_RE, _CONVENTION
from dynid.errors import DataError

# --------------------------------------------------------------------------------------
# Raw file readers
# --------------------------------------------------------------------------------------

#: Compressed data (npz members, Parquet) may expand at most this many times the file's
#: size: recorded signals compress 1.5 .. 10x; a zip bomb expands 1000x.
MAX_EXPANSION = 50
#: ... unless the expanded data stay below this (small files of constant columns compress well).
EXPANSION_FREE_BYTES = 64 << 20


class _RawFile:
    """The named arrays of one data file, with the file's row-numbering convention."""

    def __init__(self, path: Path, label: str, kind: str):
        self.path = path
        self.label = label
        self.kind = kind  # csv | parquet | npz | mat
        self.arrays: dict[str, np.ndarray] = {}
        self.unreadable: dict[str, str] = {}
        self.line_of_row: list[int] | None = None
        #: CSV read by the fast path: data row k (0-based) is on file line first_line + k.
        self.first_line: int | None = None
        self.notices: list[str] = []
        #: CSV read by the fast path with a thread beside (`_read_csv_fast(beside=True)`),
        #: which takes work from the checks; `_build_beside` closes it.
        self.beside: ThreadPoolExecutor | None = None
        #: Every array is float64 and finite: the fast CSV path checked each as it took it,
        #: so the loader need not pass over them again (`columns._column_values`).
        self.finite = False

    @property
    def tabular(self) -> bool:
        return self.kind in ("csv", "parquet")

    def row(self, k: int) -> str:
        if self.line_of_row is not None:
            return f"data row {k + 1} (file line {self.line_of_row[k]})"
        if self.first_line is not None:
            return f"data row {k + 1} (file line {self.first_line + k})"
        return f"row {k + 1} (1-based sample number)"

    def add(self, name: str, array, where: str) -> None:
        if name in self.arrays or name in self.unreadable:
            raise DataError(
                f"{self.label}: the column name '{name}' appears twice ({where}). "
                "Rename or delete one of them."
            )
        self.arrays[name] = array


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "a special file"


def _refuse_special(path: Path, label: str) -> None:
    """DataError for a FIFO, device, socket (or a symlink to one) before any read.

    Reading /dev/zero or a pipe would never end (or fill the memory); only regular
    files are data files. Stat errors are left to the reader's own messages."""
    try:
        st_ = path.stat()
    except OSError:
        return
    if stat.S_ISDIR(st_.st_mode) or stat.S_ISREG(st_.st_mode):
        return
    what = _file_kind(st_.st_mode)
    if path.is_symlink():
        try:
            what = f"a symbolic link to {os.readlink(path)}, {what}"
        except OSError:
            what = f"a symbolic link to {what}"
    raise DataError(
        f"{label} is {what}, not a regular file. dynid reads experiment data only from "
        "regular files (a pipe or device would be read without end): save the recording to a "
        "file and load that."
    )


def _check_file(path: Path, label: str) -> None:
    """Exists, is a file and is not empty (for formats read by a library)."""
    try:
        st_ = path.stat()
    except FileNotFoundError:
        rel = "" if path.is_absolute() else f" (a relative path is taken relative to {Path.cwd()})"
        raise DataError(f"{label}: file not found. Check the path{rel}.") from None
    except OSError as e:
        raise DataError(f"{label} cannot be read: {e.strerror or e}.") from None
    if path.is_dir():
        raise DataError(f"{label} is a folder, not a file. Give the data file itself.")
    _refuse_special(path, label)
    if st_.st_size == 0:
        raise DataError(f"{label} is empty. Export the recording again.")


def _read_bytes(path: Path, label: str) -> bytes:
    _refuse_special(path, label)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        rel = "" if path.is_absolute() else f" (a relative path is taken relative to {Path.cwd()})"
        raise DataError(f"{label}: file not found. Check the path{rel}.") from None
    except IsADirectoryError:
        raise DataError(f"{label} is a folder, not a file. Give the data file itself.") from None
    except PermissionError:
        raise DataError(f"{label} cannot be read: permission denied.") from None
    except OSError as e:
        raise DataError(f"{label} cannot be read: {e.strerror or e}.") from None
    if not data.strip():
        what = ("Write the experiment description (docs/formats.md, \"Experiment description (TOML)\")"
                if str(label).lower().endswith(".toml") else "Export the recording again")
        raise DataError(f"{label} is empty. {what}.")
    return data


def _read_csv(path: Path, label: str, beside: bool = False) -> _RawFile:
    """A CSV file: the fast pandas path when the file is regular, else the precise one.

    `beside`: a file read by the fast path gets a thread for the checks to share, and the
    caller builds its result with `_build_beside`."""
    _refuse_special(path, label)
    raw = _read_csv_fast(path, label, beside=beside)
    if raw is not None:
        return raw
    return _read_csv_precise(path, label)


def _build_beside(raw: _RawFile, build):
    """`build(raw)`, after which the thread beside it (`_read_csv_fast(beside=True)`) takes
    no more work: it ends with its tasks, also when the build fails."""
    try:
        return build(raw)
    finally:
        _stop_beside(raw)


def _stop_beside(raw: _RawFile) -> None:
    """No more work for `raw.beside`: its thread ends with what it was given."""
    if raw.beside is not None:
        raw.beside.shutdown(wait=False)


#: Bytes read at a time by the fast CSV path's scan of the file: one buffer, refilled, small
#: enough for its seven searches to stay in the cache (a fresh 4 MB object per read cost
#: a third of the scan in page faults: benchmarks/io.py).
_SCAN_CHUNK = 1 << 18
#: Spellings pandas' float parser reads as booleans (1.0 / 0.0), in any case (TrUe too);
#: Python's float() does not.
_BOOL_WORDS = (b"rue", b"alse")


def _header_line(f) -> str | None:
    """The first line of the open binary file `f` as text, or None when the fast path cannot
    take it: no line end, blank, quoted, a NUL, a CR inside it, not UTF-8."""
    first = f.readline(1 << 20)
    if not first.endswith(b"\n") or b'"' in first or b"\0" in first:
        return None
    line = first[:-1]
    if line.endswith(b"\r"):
        line = line[:-1]
    if not line.strip() or b"\r" in line:
        return None
    try:
        return line.decode("utf-8-sig")
    except UnicodeDecodeError:
        return None


def _scan_csv(path: Path, words_only: bool = False) -> str | None:
    """Check a CSV (in chunks, at memchr speed) for what pandas would read differently
    from `_read_csv_precise`; the header line, or None.

    Refused: a first line that is blank or quoted, quotes, NUL bytes, a CR that does not
    end a line, and boolean words (pandas reads "True" as 1.0). `words_only`: the boolean
    words alone (pandas 3 refuses the rest in a float column by itself)."""
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed by the with below
    except OSError:
        return None
    with f:
        header = _header_line(f)
        if header is None:
            return None
        last = b""
        cr_open = False
        buf = bytearray(_SCAN_CHUNK)
        while True:
            n = f.readinto(buf)
            if not n:
                break
            chunk = buf if n == _SCAN_CHUNK else bytes(memoryview(buf)[:n])
            if not words_only:
                if b'"' in chunk or b"\0" in chunk:
                    return None
                if cr_open and not chunk.startswith(b"\n"):
                    return None
                if b"\r" in chunk:
                    cr_open = chunk.endswith(b"\r")
                    if chunk.count(b"\r") != chunk.count(b"\r\n") + cr_open:
                        return None
                else:
                    cr_open = False
            if any(c in chunk or c in last for c in (b"u", b"U", b"l", b"L")):
                joined = (last + chunk).lower()
                if any(w in joined for w in _BOOL_WORDS):
                    return None
            last = bytes(chunk[-4:])
    if cr_open:
        return None
    return header


def _scan_or_none(path: Path, words_only: bool = False) -> str | None:
    """`_scan_csv`, with a read that fails on the way (an I/O error) taken as a refusal: the
    precise reader then reads the file again and says what is wrong with it."""
    try:
        return _scan_csv(path, words_only)
    except (OSError, MemoryError):
        return None


def _read_csv_fast(path: Path, label: str, beside: bool = False) -> _RawFile | None:
    """The whole CSV parsed by pandas' C reader into float64 columns (text for columns
    outside the dynid convention, exactly as the precise path keeps them), or None
    when anything is unusual and `_read_csv_precise` must read (and judge) it.

    The values are bit-identical to Python's `float()` of each cell (pandas ≥ 3 parses
    floats exactly; pandas 2 does with `float_precision="round_trip"`). Cells the
    precise path would reject or read differently (text, empty cells, NaN, quotes, NUL
    bytes, '_' digit separators, Unicode digits) make pandas fail, and the precise path
    then names the file, column, data row and file line. pandas 3 refuses all of them in
    a float column by itself, save boolean words: it converts a column in blocks of rows
    (`_pandas_block_rows`) and casts a block of boolean words alone ("True", "fAlSe") to
    1.0 and 0.0, so a block holding only 0 and 1 sends the file to the scan for those words
    (`_scan_csv(words_only=True)`, rare); pandas 2 and text columns need the whole scan
    first. A CR alone ends a line for pandas as for the precise path.

    `beside`: the returned file has a thread (`raw.beside`) for the checks to share (they
    run on one core once pandas' parse, which keeps every core busy, is done;
    benchmarks/io.py); build the result with `_build_beside`."""
    try:
        import pandas as pd
    except ImportError:
        return None
    try:
        if path.stat().st_size == 0:
            return None
    except OSError:
        return None
    pandas3 = int(pd.__version__.split(".")[0]) >= 3
    if pandas3:
        try:
            with open(path, "rb") as f:
                header_text = _header_line(f)
        except OSError:
            return None
    else:
        header_text = _scan_or_none(path)
    if header_text is None:
        return None
    names = next(csv.reader([header_text]))
    stripped = [c.strip() for c in names]
    if (any(c == "" for c in stripped) or len(set(stripped)) != len(stripped)
            or len(set(names)) != len(names) or len(names) < 2
            or all(_is_number(h) for h in stripped)):
        return None
    # pandas >= 3 parses floats exactly, on its threads: faster than Arrow on one thread
    # (benchmarks/io.py); pandas 2 needs its slower round-trip parser, so Arrow goes first
    raw = None if pandas3 else _read_csv_arrow(path, label, names, stripped)
    if raw is not None:
        return raw
    kw = {} if pandas3 else {"float_precision": "round_trip"}

    def parse(dtypes):
        with warnings.catch_warnings():
            # "Length of header or names does not match length of data": a long first row
            warnings.simplefilter("error")
            # No blank lines are skipped: a blank or short row gives '' in a float column,
            # which fails; so data row k is on file line k + 2.
            return pd.read_csv(path, sep=",", header=0, dtype=dtypes, na_filter=False,
                               engine="c", encoding="utf-8", quoting=csv.QUOTE_NONE,
                               skip_blank_lines=False, index_col=False, **kw)

    # Every column as numbers first (a TOML may name any column); if that fails, the
    # columns outside the convention as text, as the precise path keeps them.
    dtypes = dict.fromkeys(names, float)
    scanned = not pandas3
    try:
        df = parse(dtypes)
    except Exception:  # noqa: BLE001 - any parse failure: the precise path explains it
        dtypes = {raw: (float if _COLUMN_RE.match(name) else object)
                  for raw, name in zip(names, stripped, strict=True)}
        # quotes in a text column: pandas keeps them, the precise path reads them as CSV
        if object not in dtypes.values() or (not scanned and _scan_or_none(path) is None):
            return None
        scanned = True
        try:
            df = parse(dtypes)
        except Exception:  # noqa: BLE001
            return None
        # a short row or a blank line shows only in the columns read as text
        if _count_commas(path) != (len(names) - 1) * (len(df) + 1):
            return None
    if list(df.columns) != names or len(df) < 1:
        return None
    raw = _RawFile(path, label, "csv")
    raw.first_line = 2
    block = _pandas_block_rows(len(names))
    ones_and_zeros = False
    for c, name in enumerate(stripped):
        col = df.iloc[:, c]
        if dtypes[names[c]] is float:
            a = col.to_numpy(dtype=float)
            # NaN and inf: the precise path names the cell (as the loader would, one pass later)
            if a.dtype != np.float64 or not _all_finite(a):
                return None
            ones_and_zeros = ones_and_zeros or (not scanned and _a_block_of_ones_and_zeros(a, block))
        else:
            a = col.to_numpy(dtype=object)
        raw.arrays[name] = a
    if ones_and_zeros and not scanned and _scan_or_none(path, words_only=True) is None:
        return None
    raw.finite = object not in dtypes.values()
    if beside:
        raw.beside = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dynid-csv-beside")
    return raw


def _all_finite(a: np.ndarray) -> bool:
    """Whether every value of the float array `a` is finite. Its sum is, when they all are and
    it does not overflow: one pass without a temporary (the elementwise test runs only then)."""
    with np.errstate(over="ignore", invalid="ignore"):
        total = a.sum()
    return bool(np.isfinite(total)) or bool(np.isfinite(a).all())


def _pandas_block_rows(width: int) -> int:
    """The rows pandas' C reader converts at a time for a file of `width` columns (its
    low-memory blocks: the largest power of two below 2**20 / width, pandas/_libs/parsers.pyx;
    tests/analysis/data/test_experiment.py checks it on the installed pandas)."""
    heuristic = (1 << 20) // max(int(width), 1)
    rows = 1
    while rows * 2 < heuristic:
        rows *= 2
    return rows


def _a_block_of_ones_and_zeros(a: np.ndarray, block: int) -> bool:
    """Whether a block of `block` rows of `a` (the last one shorter) holds only 0.0 and 1.0:
    what pandas makes of a block of boolean words. The first value of each block decides
    which blocks to look at."""
    firsts = a[::block]
    for k in np.flatnonzero((firsts == 0.0) | (firsts == 1.0)):
        part = a[k * block:(k + 1) * block]
        if np.all((part == 0.0) | (part == 1.0)):
            return True
    return False


#: With pandas < 3, try Arrow's CSV reader before pandas' (benchmarks/io.py turns it off to time
#: the pandas route).
_USE_ARROW = True


def _read_csv_arrow(path: Path, label: str, names: list[str], stripped: list[str]) -> _RawFile | None:
    """Every column as float64 by Arrow's CSV reader (on one thread about 1.5x as fast as
    pandas 2's exact round-trip parse; pandas 3 is faster still), or None, and the pandas route decides.

    Arrow's float parser rounds correctly, so each value is the bits of Python's `float()`
    of its cell. Nothing is accepted that pandas' float parse rejects: no null spellings,
    no booleans, no quotes (the scan refused them), no blank lines; a NaN cell (Arrow reads
    "nan", pandas does not) sends the file on to pandas, as does any failure. Optional:
    without pyarrow the pandas route reads every file."""
    if not _USE_ARROW:
        return None
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:
        return None
    try:
        table = pacsv.read_csv(
            path,
            # one thread: on a loaded 2-core machine Arrow's thread pool is slower than one
            # thread (measured: 0.34 s against 0.52 s median for 51 MB at load 16)
            read_options=pacsv.ReadOptions(encoding="utf8", use_threads=False),
            parse_options=pacsv.ParseOptions(delimiter=",", quote_char=False, double_quote=False,
                                             escape_char=False, newlines_in_values=False,
                                             ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(names, pa.float64()), null_values=[], true_values=[],
                false_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False),
        )
    except Exception:  # noqa: BLE001 - any failure: pandas (then the precise path) judges the file
        return None
    if table.column_names != names or table.num_rows < 1:
        return None
    raw = _RawFile(path, label, "csv")
    raw.first_line = 2
    for c, name in enumerate(stripped):
        a = table.column(c).to_numpy()
        if a.dtype != np.float64 or np.isnan(a).any():
            return None
        raw.arrays[name] = a
    return raw


def _count_commas(path: Path) -> int | None:
    try:
        with open(path, "rb") as f:
            return sum(chunk.count(b",") for chunk in iter(lambda: f.read(_SCAN_CHUNK), b""))
    except OSError:
        return None



def _read_csv_precise(path: Path, label: str) -> _RawFile:
    """Python's csv module and one text cell per value; every malformed-input message
    (file, line, data row, column) comes from here. Slow and memory-hungry (a Python
    string per cell), so used only when `_read_csv_fast` declines the file."""
    text = _csv_text(_read_bytes(path, label), label)
    raw = _RawFile(path, label, "csv")
    header, header_line, rows, line_of_row, blank = _csv_rows(text, label)
    _check_csv_header(header, header_line, label)
    _blank_line_notice(raw, blank, line_of_row, label)
    if not rows:
        raise DataError(
            f"{label} has a header line but no data rows. Export the recording again."
        )
    _check_csv_widths(rows, header, line_of_row, label)
    raw.line_of_row = line_of_row
    _add_csv_columns(raw, header, header_line, list(zip(*rows, strict=True)), label)
    return raw


def _csv_text(data: bytes, label: str) -> str:
    """The file's text: no NUL bytes, UTF-8 (a BOM dropped)."""
    if b"\0" in data:
        raise DataError(
            f"{label} is not a text file (it contains NUL bytes). Export the data as a "
            "comma-separated text file, or use the matching extension (.parquet, .npz, .mat)."
        )
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise DataError(
            f"{label}: line {line} is not valid UTF-8 text (byte {e.start}). "
            "Save the file as UTF-8 CSV."
        ) from None


#: a line of a CSV text with its end (CRLF, CR or LF), or the last line without one
_LINES = re.compile(r"[^\r\n]*(?:\r\n|\r|\n)|[^\r\n]+$")


def _csv_rows(text: str, label: str):
    """(header, its line, data rows, the line of each row, blank lines after the header)."""
    # lines with their ends (CRLF, CR or LF): a quoted field spanning lines keeps its line break
    # (and is then no number), where lines without them glued "1<LF>2" into 12
    reader = csv.reader(_LINES.findall(text))
    header: list[str] | None = None
    header_line = 0
    rows: list[list[str]] = []
    line_of_row: list[int] = []
    blank: list[int] = []
    while True:
        ln = reader.line_num + 1  # first line of the next row (quoted fields may span lines)
        try:
            row = next(reader)
        except StopIteration:
            break
        except csv.Error as e:
            raise DataError(
                f"{label}, file line {ln}: cannot be parsed as CSV ({e}). Fix that line "
                "(check the quotes)."
            ) from None
        if not row or (len(row) == 1 and not row[0].strip()):
            if header is not None:
                blank.append(ln)
            continue
        if header is None:
            header, header_line = [c.strip() for c in row], ln
            continue
        rows.append(row)
        line_of_row.append(ln)
    if header is None:
        raise DataError(f"{label} is empty. Export the recording again.")
    while header and header[-1] == "":
        header.pop()
    return header, header_line, rows, line_of_row, blank


def _check_csv_header(header: list[str], header_line: int, label: str) -> None:
    """The first line names columns, separated by commas."""
    if header and header[0].lstrip()[:1] in ("{", "["):
        raise DataError(f"{label}: the file starts with {header[0].strip()[:20]!r}: it looks like JSON, not a "
                        "comma-separated table. Give the recording's CSV (t, q1..qn, tau1..taun).")
    if not header:
        raise DataError(
            f"{label}, file line {header_line}: the header line has no column names. "
            "The first line must name the columns (t, q1..qn, tau1..taun; "
            f"{_CONVENTION})."
        )
    if len(header) == 1 and any(s in header[0] for s in (";", "\t", "|")):
        sep = next(s for s in (";", "\t", "|") if s in header[0])
        raise DataError(
            f"{label}, file line {header_line}: the columns seem to be separated by "
            f"{sep!r}; dynid reads comma-separated files. Export with ',' as the column "
            "separator and '.' as the decimal point."
        )
    if all(_is_number(h) for h in header if h):
        raise DataError(
            f"{label}, file line {header_line}: the first line holds numbers, not column "
            "names. Add a header line naming the columns (t, q1..qn, tau1..taun; "
            f"{_CONVENTION}), or describe the file in an experiment TOML."
        )


def _blank_line_notice(raw: _RawFile, blank: list[int], line_of_row: list[int], label: str) -> None:
    # blank lines at the very end are normal; others are reported
    if blank and line_of_row:
        inner = [b for b in blank if b < line_of_row[-1]]
        if inner:
            raw.notices.append(
                f"{label}: skipped {len(inner)} blank line(s) among the data (file line(s) "
                f"{_short_list(inner)})"
            )


def _check_csv_widths(rows: list[list[str]], header: list[str], line_of_row: list[int], label: str) -> None:
    """Every row as wide as the header (empty trailing cells dropped); a title or comment line
    above the header is named as such."""
    h = len(header)
    if header and header[0].lstrip().startswith("#") and rows \
            and not any(_is_number(c) for c in rows[0] if c.strip()):
        raise DataError(
            f"{label}: the first line, {','.join(header)[:60]!r}, is a comment: the line after it names "
            f"{len(rows[0])} columns. Delete the line(s) above the header, so that the file starts "
            "with the column names."
        )
    if h == 1 and rows and len([c for c in rows[0] if c.strip()]) > 1 \
            and not any(_is_number(c) for c in rows[0] if c.strip()):
        what = "a comment" if header[0].lstrip().startswith("#") else "not the header"
        raise DataError(
            f"{label}: the first line, {header[0][:60]!r}, is {what}: the line after it names "
            f"{len(rows[0])} columns. Delete the line(s) above the header, so that the file starts "
            "with the column names."
        )
    for k, row in enumerate(rows):
        if len(row) > h:
            if all(not c.strip() for c in row[h:]):
                del row[h:]
            else:
                raise DataError(
                    f"{label}, {_csv_row(line_of_row, k)}: {len(row)} values but the "
                    f"header names {h} columns. Remove the extra values, or name the "
                    "extra columns in the header."
                )
        if len(row) < h:
            raise DataError(
                f"{label}, {_csv_row(line_of_row, k)}: {len(row)} value(s) but the header "
                f"names {h} columns: the row is truncated (column '{header[len(row)]}' and "
                "after are missing). Complete or delete that line."
            )


def _add_csv_columns(raw: _RawFile, header: list[str], header_line: int, columns, label: str) -> None:
    first_pos: dict[str, int] = {}
    for c, name in enumerate(header):
        if name == "":
            raw.notices.append(f"{label}: column {c + 1} has no name in the header; ignored")
            continue
        if name in first_pos:
            raise DataError(
                f"{label}, file line {header_line}: the column name '{name}' appears twice "
                f"(columns {first_pos[name] + 1} and {c + 1} of the header). Rename or "
                "delete one of them."
            )
        first_pos[name] = c
        raw.arrays[name] = np.array(columns[c], dtype=object)


def _csv_row(line_of_row: list[int], k: int) -> str:
    return f"data row {k + 1} (file line {line_of_row[k]})"


def _is_number(s: str) -> bool:
    try:
        float(s)
    except (ValueError, TypeError):
        return False
    return True


def _read_parquet(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        import pandas as pd
    except ImportError:
        raise DataError(
            f"{label}: reading Parquet needs pandas and pyarrow: pip install pandas pyarrow"
        ) from None
    _check_parquet_size(path, label)
    try:
        names, n_rows = _parquet_layout(path)
        raw = _RawFile(path, label, "parquet")
        # one column at a time: the peak is the arrays kept plus one column, not the
        # Arrow table, the DataFrame and the arrays at once (issue 31: 10x the file)
        for c, name in enumerate(names):
            series = pd.read_parquet(path, columns=[name]).iloc[:, 0]
            _add_parquet_column(raw, label, c, name, series, pd)
            del series
            _release_arrow_memory()
    except ImportError:
        raise DataError(
            f"{label}: reading Parquet files needs pyarrow. Install it with "
            "`pip install pyarrow`, or export the data as CSV."
        ) from None
    except DataError:
        raise
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file
        raise DataError(
            f"{label} is not a readable Parquet file ({type(e).__name__}: "
            f"{str(e).splitlines()[0] if str(e) else ''}). Export it again."
        ) from None
    if n_rows == 0:
        raise DataError(f"{label} has columns but no rows. Export the recording again.")
    return raw


def _release_arrow_memory() -> None:
    # Arrow's allocator (mimalloc, jemalloc) keeps freed buffers for reuse: hand them back,
    # or each column read leaves its decoded copy in the process's memory
    try:
        import pyarrow as pa
        pa.default_memory_pool().release_unused()
    except (ImportError, AttributeError):
        pass


def _parquet_layout(path: Path):
    """(column names in order, less the pandas index columns as pandas.read_parquet; rows)."""
    import pyarrow.parquet as pq
    pf = pq.ParquetFile(path)
    schema = pf.schema_arrow
    meta = schema.pandas_metadata or {}
    index = {c for c in meta.get("index_columns", []) if isinstance(c, str)}
    return [n for n in schema.names if n not in index], pf.metadata.num_rows


def _add_parquet_column(raw: _RawFile, label: str, c: int, name, s, pd) -> None:
    sname = str(name).strip()
    if sname == "":
        raw.notices.append(f"{label}: column {c + 1} has no name; ignored")
        return
    if sname in raw.arrays:
        raise DataError(
            f"{label}: the column name '{sname}' appears twice. Rename or delete one "
            "of them."
        )
    if isinstance(s.dtype, pd.DatetimeTZDtype):
        s = s.dt.tz_convert(None)
    kind = s.dtype.kind if isinstance(s.dtype, np.dtype) else None
    if kind in ("M", "m"):
        raw.arrays[sname] = s.to_numpy()
    elif pd.api.types.is_numeric_dtype(s.dtype) and not pd.api.types.is_bool_dtype(s.dtype):
        try:
            # a copy of numpy's own: the Arrow buffer under the Series is freed now, not held
            # (and counted) until the whole recording is assembled
            raw.arrays[sname] = np.array(s.to_numpy(dtype=float, na_value=np.nan), dtype=float, copy=True)
        except (TypeError, ValueError):
            raw.arrays[sname] = s.to_numpy(dtype=object)
    else:
        raw.arrays[sname] = s.to_numpy(dtype=object)


def _check_parquet_size(path: Path, label: str) -> None:
    """Before loading: the row groups' uncompressed size (from the footer) against the file's."""
    try:
        import pyarrow.parquet as pq
        meta = pq.ParquetFile(path).metadata
        expanded = sum(meta.row_group(k).total_byte_size for k in range(meta.num_row_groups))
    except Exception:  # noqa: BLE001 - the reader reports a bad file
        return
    _check_expansion(label, expanded, path.stat().st_size, "its columns")


def _read_npz(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
    except OSError as e:
        raise DataError(f"{label} cannot be read: {e.strerror or e}.") from None
    if magic.startswith(b"\x93NUMPY"):
        raise DataError(
            f"{label} holds a single array, not an .npz archive of named arrays. Save it "
            "with numpy.savez(path, t=..., q=..., tau=...)."
        )
    if not magic.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        text = " (it looks like a text file, e.g. a CSV: give it the .csv extension)" if (
            magic and all(32 <= b < 127 or b in (9, 10, 13) for b in magic)) else ""
        raise DataError(
            f"{label} is not an npz archive: it does not start with the zip signature of "
            f"files written by numpy.savez{text}. Save the data with "
            "numpy.savez(path, t=..., q=..., tau=...)."
        )
    _check_npz_sizes(path, label)
    try:
        f = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001
        raise DataError(
            f"{label} is not a readable .npz archive ({_safe_reason(e)}). Save it with "
            "numpy.savez(path, t=..., q=..., tau=...)."
        ) from None
    if not hasattr(f, "files"):
        raise DataError(
            f"{label} holds a single array, not an .npz archive of named arrays. Save it "
            "with numpy.savez(path, t=..., q=..., tau=...)."
        )
    raw = _RawFile(path, label, "npz")
    with f:
        for key in f.files:
            try:
                a = f[key]
            except Exception as e:  # noqa: BLE001 - object arrays, corrupt members
                raw.unreadable[key] = _safe_reason(e)
                continue
            raw.arrays[key] = np.asarray(a)
    if not raw.arrays and not raw.unreadable:
        raise DataError(f"{label} holds no arrays. Save the data with numpy.savez.")
    return raw


def _check_expansion(label: str, expanded: int, size: int, what: str) -> None:
    if expanded > EXPANSION_FREE_BYTES and expanded > MAX_EXPANSION * max(size, 1):
        raise DataError(
            f"{label}: {what} expand to {expanded / 2**20:.0f} MiB from a {size / 2**20:.2g} MiB file, "
            f"more than the {MAX_EXPANSION}x that recorded signals compress to (a zip bomb or a corrupted "
            "file); it was not loaded. Save the recording uncompressed (numpy.savez) if it is genuine."
        )


def _check_npz_sizes(path: Path, label: str) -> None:
    """Before loading: each member's declared array size against its stored size, and the
    archive's expanded size against its file size (np.load allocates what a header declares)."""
    import zipfile
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError):
        return                      # np.load reports the broken archive
    size = path.stat().st_size
    with zf:
        infos = zf.infolist()
        _check_expansion(label, sum(i.file_size for i in infos), size, "its arrays")
        for info in infos:
            if not info.filename.endswith(".npy"):
                continue
            try:
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                                   (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                    if read_header is None:
                        continue
                    shape, _, dtype = read_header(fh)
            except Exception:  # noqa: BLE001 - np.load reports a bad member
                continue
            declared = dtype.itemsize * math.prod(shape) if dtype.itemsize else 0
            if declared > info.file_size:
                raise DataError(
                    f"{label}: array '{info.filename[:-4]}' declares shape {shape} ({declared / 2**20:.0f} MiB) "
                    f"but holds {info.file_size / 2**20:.2g} MiB: a corrupted or forged archive; it was not "
                    "loaded. Save the data again with numpy.savez."
                )


def _read_mat(path: Path, label: str) -> _RawFile:
    _check_file(path, label)
    try:
        import scipy.io
    except ImportError:
        raise DataError(f"{label}: reading .mat files needs scipy: pip install scipy") from None
    try:
        d = scipy.io.loadmat(path, squeeze_me=True)
    except NotImplementedError:
        raise DataError(
            f"{label} is a MATLAB v7.3 (HDF5) file, which scipy cannot read. Save it "
            "from MATLAB with save(..., '-v7'), or export CSV."
        ) from None
    except Exception as e:  # noqa: BLE001
        raise DataError(
            f"{label} is not a readable MATLAB .mat file ({type(e).__name__}: "
            f"{str(e).splitlines()[0] if str(e) else ''}). Save it with save(..., '-v7')."
        ) from None
    raw = _RawFile(path, label, "mat")
    for key, a in d.items():
        if key.startswith("__"):
            continue
        raw.arrays[key] = np.asarray(a)
    if not raw.arrays:
        raise DataError(f"{label} holds no variables.")
    return raw


def _safe_reason(e: Exception) -> str:
    """An exception as a short reason, never suggesting unpickling (numpy's messages
    mention allow_pickle; loading pickles runs arbitrary code)."""
    first = str(e).splitlines()[0] if str(e) else ""
    if "pickle" in first.lower():
        return "it holds Python objects (pickled data), which dynid does not load"
    return f"{type(e).__name__}: {first}"


_READERS = {".csv": _read_csv, ".parquet": _read_parquet, ".npz": _read_npz, ".mat": _read_mat}


def _read_data_file(path: Path, label: str, beside: bool = False) -> _RawFile:
    """The raw columns of one data file. `beside` (CSV): see `_read_csv`; build the
    result with `_build_beside`."""
    ext = path.suffix.lower()
    if ext not in _READERS:
        raise DataError(
            f"{label}: unknown data file extension '{path.suffix}'. Supported: "
            ".csv, .parquet, .npz, .mat (and .toml experiment descriptions). If it is a "
            "comma-separated table, rename it to .csv."
        )
    if ext == ".csv":
        return _read_csv(path, label, beside=beside)
    return _READERS[ext](path, label)

