"""Messages and progress of the command line and of the pipeline (`dynid.report`, `dynid.demo`).

Progress goes through `dynid.progress`: a bar on a terminal, elsewhere `logging` records (logger
`dynid.progress`) or, with no logging configured, lines on stderr, for work that lasts more than a second; nothing with --quiet
or after `dynid.progress.silence()`. `Progress` is the bar itself, kept for callers that
draw one directly."""
from __future__ import annotations

import re
import sys
import time

from dynid.progress import task

#: control characters a terminal may act on (escape sequences, bell, carriage return...);
#: tab and newline are kept
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def clean_text(text) -> str:
    """`text` with every control character but tab and newline shown escaped (`\\x1b`).

    Names read from files (robot names, column names) reach messages; printed raw, an
    escape sequence in one could retitle or clear the user's terminal.
    """
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text))


class Progress:
    def __init__(self, label, quiet=False, stream=None, delay=1.0):
        self.label = clean_text(label)
        self.stream = stream or sys.stderr
        self.enabled = not quiet and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.monotonic()
        self.delay = delay
        self.shown = False

    def update(self, fraction):
        if not self.enabled or time.monotonic() - self.start < self.delay:
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        filled = int(30 * fraction)
        self.stream.write(f"\r{self.label}: [{'#' * filled}{'.' * (30 - filled)}] {100 * fraction:5.1f}%")
        self.stream.flush()
        self.shown = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
        return False


_LIBRARY_DEFAULT = object()


class _TaskProgress:
    """`with reporter.progress(label) as bar: bar.update(fraction)` over `dynid.progress.task`."""

    def __init__(self, label):
        self._context = task(clean_text(label))
        self._call = None

    def update(self, fraction, total=None):
        self._call(fraction, total)

    __call__ = update

    def __enter__(self):
        self._call = self._context.__enter__()
        return self

    def __exit__(self, *exc):
        return self._context.__exit__(*exc)


class Reporter:
    """Human messages and progress bars on stderr.

    Long pipelines take one: `say("message")` and `with say.progress(label) as bar:
    bar.update(fraction)`. `Reporter(quiet=True)` (the command line's --quiet) shows
    nothing; `Reporter(quiet=False)` shows both. The library's default, `Reporter()`,
    prints no messages but reports progress through `dynid.progress` (a bar on a
    terminal, progress lines or logging records elsewhere; `dynid.progress.silence()` turns it off), so a
    minutes-long `dynid.report(...)` in Python is not silent.
    """

    def __init__(self, quiet=_LIBRARY_DEFAULT):
        self.library = quiet is _LIBRARY_DEFAULT
        self.quiet = True if self.library else bool(quiet)

    def __call__(self, msg):
        if not self.quiet:
            print(clean_text(msg), file=sys.stderr, flush=True)

    def progress(self, label):
        if self.quiet and not self.library:
            return Progress(label, quiet=True)
        return _TaskProgress(label)
