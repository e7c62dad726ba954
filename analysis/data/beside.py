"""Work beside the caller: a function run on a thread of its own, its value awaited later.

The loader's checks run on one core after pandas' parse, which keeps every core busy; the
CSV scan (file reads and memchr searches, which mostly release the GIL) runs beside them on
the core the parse leaves idle (benchmarks/io.py)."""
from __future__ import annotations

import threading

__all__ = ["Beside"]


class Beside:
    """`fn(*args)` on a daemon thread; `result()` waits for its value (or raises its
    exception in the caller)."""

    def __init__(self, fn, *args, name: str = "dynid-beside"):
        self._value = self._error = None
        self._thread = threading.Thread(target=self._run, args=(fn, args), daemon=True, name=name)
        self._thread.start()

    def _run(self, fn, args):
        try:
            self._value = fn(*args)
        except BaseException as e:  # noqa: BLE001 - handed to the caller of result()
            self._error = e

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value
