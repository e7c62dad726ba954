"""numpy's large arrays on ordinary memory pages while dynid works, unless the user chose.

dynid allocates many short-lived arrays of tens of MB (regressors, decimation stages,
residuals). With transparent huge pages on `madvise`, numpy asks the kernel for huge pages
for each of them, and a fresh one can stall while the kernel compacts memory: a cost in
system time that grows with the machine's load. Measured on the project's 2-core machine
(benchmarks/diagnosis_speed.py, load 1-2): `dynid diagnose` 11.1 -> 8.9 s CPU, its system
time 2.5-4.2 -> 1.0-1.2 s. Allocation only: the numbers are the same.

`small_pages()` switches numpy's huge-page advice off for the work inside it and restores
it after. It does nothing when the user set `NUMPY_MADVISE_HUGEPAGE`, or when numpy has no
such switch.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

__all__ = ["small_pages"]


@contextlib.contextmanager
def small_pages() -> Iterator[None]:
    """Run the enclosed work with numpy's huge-page advice off (see the module docstring).

    Returns
    -------
    A context manager; nesting is allowed (each exit restores what it found).

    Examples
    --------
    >>> import numpy as np
    >>> with small_pages():
    ...     a = np.zeros(10_000_000)
    """
    try:     # numpy's own switch (private, the one NUMPY_MADVISE_HUGEPAGE sets at import)
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:
        _set_madvise_hugepage = None
    if _set_madvise_hugepage is None or "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        yield
        return
    before = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(before)
