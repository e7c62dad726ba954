"""dynid.progress: a bar on a terminal, logging records elsewhere, a switch to silence both."""
import io
import logging

import pytest

from dynid import progress as P


class _TTY(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture(autouse=True)
def _default_switch(monkeypatch):
    monkeypatch.delenv("DYNID_PROGRESS", raising=False)
    P._ENABLED = None
    yield
    P._ENABLED = None


def test_off_a_terminal_progress_goes_to_logging(caplog):
    caplog.set_level(logging.INFO, logger="dynid.progress")
    out = io.StringIO()
    with P.task("DIDIM", delay=0.0, log_every=0.0, stream=out) as progress:
        progress(0.5)
        progress(3, 4)
    assert out.getvalue() == ""                       # no bar in a log file
    texts = [r.getMessage() for r in caplog.records]
    assert "DIDIM: 50 %" in texts[0] and "DIDIM: 75 %" in texts[1] and "DIDIM: done" in texts[-1]


def test_on_a_terminal_a_bar_is_drawn_and_nothing_logged(caplog):
    caplog.set_level(logging.INFO, logger="dynid.progress")
    tty = _TTY()
    with P.task("posterior", delay=0.0, stream=tty) as progress:
        for k in range(5):
            progress(k, 4)
    assert "posterior" in tty.getvalue() and not caplog.records


def test_silenced_by_the_switch_or_the_environment(caplog, monkeypatch):
    caplog.set_level(logging.INFO, logger="dynid.progress")
    tty = _TTY()
    P.silence()
    with P.task("diagnosis", delay=0.0, stream=tty) as progress:
        progress(0.5)
    P.enable()
    monkeypatch.setenv("DYNID_PROGRESS", "0")
    P._ENABLED = None
    assert not P.enabled()
    with P.task("fleet", delay=0.0, log_every=0.0, stream=io.StringIO()) as progress:
        progress(1, 2)
    assert tty.getvalue() == "" and not caplog.records


def test_short_work_stays_silent(caplog):
    caplog.set_level(logging.INFO, logger="dynid.progress")
    with P.task("quick", delay=60.0, log_every=0.0, stream=io.StringIO()) as progress:
        progress(1.0)
    assert not caplog.records


def test_the_pipelines_default_reporter_logs_progress_and_quiet_silences_it(caplog, monkeypatch):
    """`dynid.report(...)` in Python (its default Reporter) says it is alive; --quiet does not."""
    from dynid.reports.progress import Reporter
    caplog.set_level(logging.INFO, logger="dynid.progress")
    clock = iter(range(0, 1000, 5))                       # five seconds between calls
    monkeypatch.setattr(P.time, "monotonic", lambda: float(next(clock)))
    with Reporter().progress("diagnosis") as bar:
        bar.update(0.5)
    assert any("diagnosis: 50 %" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with Reporter(quiet=True).progress("diagnosis") as bar:
        bar.update(0.5)
    assert not caplog.records


def test_with_no_logging_configured_progress_lines_go_to_stderr(monkeypatch):
    """A notebook or script that configured no logging: `logging` would drop INFO records (only
    WARNING reaches Python's last-resort handler), so the lines go to the stream instead."""
    monkeypatch.setattr(P.LOGGER, "propagate", False)
    monkeypatch.setattr(P.LOGGER, "handlers", [])
    out = io.StringIO()
    with P.task("diagnosis", delay=0.0, log_every=0.0, stream=out) as progress:
        progress(0.5)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("dynid progress: diagnosis: 50 %") and "done after" in lines[-1]


def test_logging_at_warning_does_not_swallow_progress(monkeypatch):
    """`logging.basicConfig()` (WARNING) gives the root a handler but drops INFO: lines go to the stream."""
    handler = logging.StreamHandler(io.StringIO())
    monkeypatch.setattr(P.LOGGER, "propagate", False)
    monkeypatch.setattr(P.LOGGER, "handlers", [handler])
    monkeypatch.setattr(P.LOGGER, "level", logging.WARNING)
    out = io.StringIO()
    with P.task("DIDIM", delay=0.0, log_every=0.0, stream=out) as progress:
        progress(0.25)
    assert out.getvalue().startswith("dynid progress: DIDIM: 25 %") and handler.stream.getvalue() == ""


def test_a_closed_stream_is_no_error():
    out = io.StringIO()
    out.close()
    with P.task("fleet", delay=0.0, log_every=0.0, stream=out) as progress:
        progress(0.5)
