"""Send a signal to a running command once its stderr says it got under way."""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time


def signal_when(proc: subprocess.Popen, marker: str, send, *, settle: float = 0.0,
                timeout: float = 120.0) -> tuple[str, float]:
    """Call `send()` once a stderr line of `proc` holds `marker` (after `settle` s more), wait for
    the exit (the process group is killed after 60 s). Returns (stderr text, seconds to exit).

    `proc` runs in a session of its own (`start_new_session=True`) with `stderr=PIPE`."""
    lines, seen = [], threading.Event()

    def read():
        for raw in proc.stderr:
            lines.append(raw.decode("utf-8", "replace"))
            if marker in lines[-1]:
                seen.set()
        seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    assert seen.wait(timeout), "the run never got under way"
    time.sleep(settle)
    t0 = time.monotonic()
    send()
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    reader.join(timeout=10)
    return "".join(lines), time.monotonic() - t0
