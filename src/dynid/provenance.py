"""Provenance helpers: package versions, data fingerprints, JSON and atomic writes.

Every result dynid writes should say which code produced it (:func:`versions`),
from which data (:func:`data_hash`), and must never be left half-written on disk
(:func:`atomic_write_text`, :func:`atomic_write_bytes`, :func:`atomic_open`).
:func:`dumps_json` gives deterministic JSON: the same object always gives the
same bytes, non-finite floats become ``null``.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import json
import math
import os
import secrets
from typing import IO, Any, Iterator

import numpy as np

from dynid.errors import InputError

__all__ = [
    "versions",
    "data_hash",
    "json_safe",
    "dumps_json",
    "atomic_open",
    "atomic_write_text",
    "atomic_write_bytes",
]

#: Packages whose versions are recorded with every result, after dynid itself.
DEPENDENCIES = ("numpy", "scipy", "pandas", "statsmodels", "emcee", "matplotlib", "jinja2")


def _version(dist: str, default: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return default


def versions() -> dict[str, str]:
    """Versions of dynid and of its dependencies, in a fixed order.

    dynid's version is ``'0+unknown'`` when it runs from a source tree that is
    not installed; an absent dependency is reported as ``'not installed'``.
    """
    out = {"dynid": _version("dynid", "0+unknown")}
    for dist in DEPENDENCIES:
        out[dist] = _version(dist, "not installed")
    return out


def data_hash(*arrays: Any) -> str:
    """SHA-256 hex digest over the dtypes, shapes and bytes of ``arrays``.

    Arrays are hashed in little-endian byte order so that the digest does not
    depend on the machine; ``None`` is allowed and hashed as an explicit
    "absent" marker, so ``data_hash(a, None)`` differs from ``data_hash(a)``.
    """
    h = hashlib.sha256(b"dynid.data_hash.v1")
    for i, arr in enumerate(arrays):
        if arr is None:
            h.update(b"|none")
            continue
        a = np.asarray(arr)
        if a.dtype.hasobject:
            raise InputError(
                f"data_hash: argument {i} has dtype object, whose bytes are pointers; "
                "convert it to a numeric or string array first."
            )
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        h.update(f"|{a.dtype.str}|{a.shape}|".encode("ascii"))
        # Viewing as bytes avoids copying large regressors just to hash them.
        h.update(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
    return h.hexdigest()


def json_safe(obj: Any, _where: str = "value") -> Any:
    """Convert ``obj`` to plain JSON types; NaN and infinities become ``None``.

    NumPy scalars and arrays become Python numbers and (nested) lists; tuples
    become lists; dict keys become strings; path-like objects become strings.
    Raises :class:`TypeError` naming the offending entry for anything else.
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist(), _where)
    if isinstance(obj, dict):
        return {str(k): json_safe(v, f"{_where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v, f"{_where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(
        f"{_where} has type {type(obj).__name__}, which cannot be written to JSON; "
        "use numbers, strings, booleans, None, lists or dicts."
    )


def dumps_json(obj: Any) -> str:
    """Deterministic JSON text of ``obj`` (via :func:`json_safe`), newline-terminated.

    Keys keep their insertion order, floats use Python's shortest round-trip
    representation and the output is pure ASCII, so equal inputs give
    byte-identical files.
    """
    return json.dumps(json_safe(obj), indent=2, ensure_ascii=True, allow_nan=False) + "\n"


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", *, encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file next to ``path``; on success replace ``path`` by it.

    The temporary file lives in the same directory so that :func:`os.replace`
    is an atomic rename. If the ``with`` body (or the final flush) raises, the
    temporary file is removed and any existing ``path`` is left untouched.
    ``mode`` is ``'w'`` (text, no newline translation) or ``'wb'``.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', not {mode!r}")
    target = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(target))
    tmp = os.path.join(directory, f".{os.path.basename(target)}.{secrets.token_hex(6)}.tmp")
    # os.open with 0o666 lets the umask decide the permissions, as for a plain open().
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        if mode == "wb":
            fh = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding=encoding, newline="")
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (no newline translation)."""
    with atomic_open(path, "w", encoding=encoding) as fh:
        fh.write(text)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
