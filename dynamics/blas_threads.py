"""Fewer OpenBLAS threads for a stretch of many small BLAS calls (the excitation design)."""
from __future__ import annotations

import contextlib
import ctypes

__all__ = ["limit_blas_threads"]

_BLAS_API = (("openblas_get_num_threads", "openblas_set_num_threads"),
             ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
             ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
             ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"))


@contextlib.contextmanager
def limit_blas_threads(n):
    """Limit the OpenBLAS libraries loaded in this process to `n` threads, then restore.

    The optimisation makes thousands of small BLAS calls (60 x 60 Gram
    matrices, SLSQP's least-squares steps); a multithreaded OpenBLAS spends
    more time synchronising than computing on them, worst on a busy machine
    (15x slower measured on 2 loaded cores). Finds the OpenBLAS copies of numpy
    and scipy through `/proc/self/maps` (Linux) and calls their
    `*_set_num_threads`; a no-op where that is not possible (other systems:
    set `OPENBLAS_NUM_THREADS=1` in the environment instead). `n=None`: no
    change.
    """
    restore = []
    if n is not None:
        try:
            with open("/proc/self/maps") as fh:
                paths = {ln.split()[-1] for ln in fh if "openblas" in ln.lower() and "/" in ln}
            for path in sorted(paths):
                try:
                    lib = ctypes.CDLL(path)
                except OSError:
                    continue
                for get, set_ in _BLAS_API:
                    if hasattr(lib, get) and hasattr(lib, set_):
                        getter, setter = getattr(lib, get), getattr(lib, set_)
                        getter.restype = ctypes.c_int
                        old = int(getter())
                        setter(ctypes.c_int(int(n)))
                        restore.append((setter, old))
                        break
        except OSError:
            pass
    try:
        yield len(restore)
    finally:
        for setter, old in restore:
            setter(ctypes.c_int(old))
