"""Provenance helpers: package versions, data fingerprints and deterministic JSON.

Every result dynid writes should say which code produced it (`versions`)
and from which data (`data_hash`); `dynid.outputs` writes it.
`dumps_json` gives deterministic JSON: the same object always gives the
same bytes, non-finite floats become `null`.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import math
import os
from typing import Any

import numpy as np

from dynid.errors import InputError

__all__ = [
    "versions",
    "data_hash",
    "json_safe",
    "dumps_json",
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

    dynid's version is `'0+unknown'` when it runs from a source tree that is
    not installed; an absent dependency is reported as `'not installed'`.
    """
    out = {"dynid": _version("dynid", "0+unknown")}
    for dist in DEPENDENCIES:
        out[dist] = _version(dist, "not installed")
    return out


def data_hash(*arrays: Any) -> str:
    """SHA-256 hex digest over the dtypes, shapes and bytes of `arrays`.

    Arrays are hashed in little-endian byte order so that the digest does not
    depend on the machine; `None` is allowed and hashed as an explicit
    "absent" marker, so `data_hash(a, None)` differs from `data_hash(a)`.
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
    """Convert `obj` to plain JSON types; NaN and infinities become `None`.

    NumPy scalars and arrays become Python numbers and (nested) lists; tuples
    become lists; dict keys become strings; path-like objects become strings.
    Raises `TypeError` naming the offending entry for anything else.
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
    """Deterministic JSON text of `obj` (via `json_safe`), newline-terminated.

    Keys keep their insertion order, floats use Python's shortest round-trip
    representation and the output is pure ASCII, so equal inputs give
    byte-identical files.
    """
    return json.dumps(json_safe(obj), indent=2, ensure_ascii=True, allow_nan=False) + "\n"
