"""One BLAS thread for dynid's linear algebra, unless the user chose otherwise.

dynid's dense problems are tall and thin (a few thousand rows by tens of columns: the
QR factorisations of the diagnosis, the least-squares fits, the posterior's log-prob).
A second OpenBLAS thread does not speed these up, and on a busy machine its threads
spin while they wait for a core: measured on the project's 2-core machine beside other
work, a 2111 x 60 pivoted QR took 0.09-0.2 s of CPU with 2 threads and 0.005 s with one,
which made `dynid diagnose` cost 2-10 times `dynid identify` depending on the load.

`single_blas_thread()` limits BLAS to one thread for the work inside it (threadpoolctl,
for numpy's and scipy's OpenBLAS or MKL alike) and restores the previous setting after.
It does nothing when the user set a thread count in the environment (`OPENBLAS_NUM_THREADS`,
`OMP_NUM_THREADS`, `MKL_NUM_THREADS`) or `DYNID_BLAS_THREADS=0`, or when threadpoolctl is
not installed.
"""
from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator

__all__ = ["single_blas_thread", "with_single_blas_thread"]

_USER_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def _wanted() -> bool:
    if os.environ.get("DYNID_BLAS_THREADS", "").strip() == "0":
        return False
    return not any(os.environ.get(v) for v in _USER_VARIABLES)


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the enclosed work with one BLAS thread (see the module docstring).

    Returns
    -------
    A context manager; nesting is allowed (the innermost exit restores its own start).

    Examples
    --------
    >>> import numpy as np
    >>> with single_blas_thread():
    ...     q, r = np.linalg.qr(np.ones((50, 3)))
    """
    if not _wanted():
        yield
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:          # optional at run time: numbers are the same, only slower when busy
        yield
        return
    # threadpoolctl limits the libraries loaded now: load scipy's own OpenBLAS (beside numpy's)
    # first, or a command that imports scipy.linalg later keeps two threads there
    import scipy.linalg  # noqa: F401
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def with_single_blas_thread(func):
    """Decorator: `func` runs inside `single_blas_thread()`.

    Parameters
    ----------
    func : callable

    Returns
    -------
    callable
        `func` wrapped, with the same signature and docstring.
    """
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with single_blas_thread():
            return func(*args, **kwargs)
    return wrapper
