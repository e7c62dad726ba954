"""A minimal progress bar on stderr (no dependency): shown only on a terminal,
only for work that lasts more than a second, silent with --quiet."""
from __future__ import annotations

import re
import sys
import time

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


class Reporter:
    """Human messages and progress bars on stderr; silent when `quiet`.

    Long pipelines take one: `say("message")` and `with say.progress(label) as bar:
    bar.update(fraction)`. The library's default is a quiet one.
    """

    def __init__(self, quiet=True):
        self.quiet = quiet

    def __call__(self, msg):
        if not self.quiet:
            print(clean_text(msg), file=sys.stderr, flush=True)

    def progress(self, label):
        return Progress(label, quiet=self.quiet)
