"""Progress of long steps (DIDIM iterations, sampling, diagnosis scoring, fleet runs), in the
command line and in Python alike.

The estimators take a `progress` callable (`progress(fraction)` or `progress(done, total)`);
`task(label)` makes one:

    from dynid.progress import task
    with task("DIDIM") as progress:
        result = identify_didim(..., progress=progress)

* on a terminal (stderr is a TTY): a tqdm bar when tqdm is installed, else a one-line bar;
* elsewhere (a notebook, a batch job, CI): `logging` records on the logger `dynid.progress`
  at INFO when the application's logging shows them, else lines `dynid progress: ...` on
  stderr; at most one per `log_every` seconds and at the end, so a long run says it is
  alive without filling a log;
* silent after `silence()` (or `enable(False)`), under the environment variable
  `DYNID_PROGRESS=0`, or for work shorter than `delay` seconds.

Without a `progress` argument the estimators report nothing; the public functions
(`dynid.report`, `demo`, `diagnose`, `sample`, ...) make one with `task`.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator

__all__ = ["task", "enable", "silence", "enabled", "LOGGER"]

LOGGER = logging.getLogger("dynid.progress")

_ENABLED: bool | None = None      # None: from the environment (DYNID_PROGRESS)


def enable(on: bool = True) -> None:
    """Turn progress reporting on or off for the whole process.

    Returns
    -------
    None
    """
    global _ENABLED
    _ENABLED = bool(on)


def silence() -> None:
    """No progress bars and no progress log records (same as `enable(False)`).

    Returns
    -------
    None
    """
    enable(False)


def enabled() -> bool:
    """Whether progress is reported: `enable`'s last word, else `DYNID_PROGRESS` (default on).

    Returns
    -------
    bool
    """
    if _ENABLED is not None:
        return _ENABLED
    return os.environ.get("DYNID_PROGRESS", "1").strip().lower() not in ("0", "false", "no", "off")


class _Bar:
    """What `task` yields: call it with a fraction, or with (done, total)."""

    def __init__(self, label, stream, delay, log_every, terminal):
        self.label, self.stream, self.delay, self.log_every = label, stream, delay, log_every
        self.terminal = terminal
        self.start = time.monotonic()
        self.last_log = -float("inf")
        self.fraction = 0.0
        self.tqdm = None
        self.drawn = False

    def __call__(self, done, total=None) -> None:
        fraction = float(done) / float(total) if total else float(done)
        self.fraction = min(max(fraction, 0.0), 1.0)
        now = time.monotonic()
        if now - self.start < self.delay:
            return
        if self.terminal:
            self._draw()
        elif now - self.last_log >= self.log_every:
            self.last_log = now
            self._log("%s: %.0f %% (%.0f s)", self.label, 100 * self.fraction, now - self.start)

    def _draw(self) -> None:
        try:
            from tqdm import tqdm
        except ImportError:
            tqdm = None
        if tqdm is not None:
            if self.tqdm is None:
                self.tqdm = tqdm(total=1000, desc=self.label, file=self.stream, leave=False,
                                 bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")
            self.tqdm.n = int(1000 * self.fraction)
            self.tqdm.refresh()
        else:
            filled = int(30 * self.fraction)
            self.stream.write(f"\r{self.label}: [{'#' * filled}{'.' * (30 - filled)}] {100 * self.fraction:5.1f}%")
            self.stream.flush()
        self.drawn = True

    def close(self, failed: bool) -> None:
        elapsed = time.monotonic() - self.start
        if self.tqdm is not None:
            self.tqdm.close()
        elif self.drawn:
            self.stream.write("\n")
            self.stream.flush()
        if not self.terminal and elapsed >= self.delay:
            self._log("%s: %s after %.0f s", self.label, "stopped" if failed else "done", elapsed)

    def _log(self, fmt, *args) -> None:
        """A record of `LOGGER` when the application's logging shows its INFO records; else one line on
        the stream (a notebook or a script that set up nothing, or logging at WARNING, would otherwise see
        nothing for minutes)."""
        if (LOGGER.hasHandlers() and LOGGER.isEnabledFor(logging.INFO)) or self.stream is None:
            LOGGER.info(fmt, *args)
            return
        try:
            self.stream.write("dynid progress: " + fmt % args + "\n")
            self.stream.flush()
        except (OSError, ValueError, AttributeError):     # a closed or odd stream: progress is not worth an error
            pass


def _noop(done, total=None) -> None:
    return None


@contextlib.contextmanager
def task(label: str, *, delay: float = 1.0, log_every: float = 10.0, stream=None) -> Iterator[Callable]:
    """A progress callable for one long step, closed (bar removed, end logged) on exit.

    Parameters
    ----------
    label : str
        What is running ("DIDIM", "posterior", "diagnosis", "fleet").
    delay : float
        Seconds before anything is shown: short work stays silent.
    log_every : float
        Off a terminal, seconds between two log records.
    stream : file, optional
        Where the bar goes (default stderr); a bar is drawn only if it is a terminal.

    Returns
    -------
    contextlib.AbstractContextManager
        Yields `progress(done, total=None)`: `done` a fraction in [0, 1], or a count
        out of `total`. A no-op when progress is silenced.
    """
    if not enabled():
        yield _noop
        return
    stream = sys.stderr if stream is None else stream
    try:
        terminal = bool(getattr(stream, "isatty", None) and stream.isatty())
    except (ValueError, OSError):        # a closed stream: no bar (and `_log` writes nothing to it)
        terminal = False
    bar = _Bar(label, stream, delay, log_every, terminal)
    failed = True
    try:
        yield bar
        failed = False
    finally:
        bar.close(failed)
