"""A local Dask cluster that Ctrl-C stops with dynid's one-line message alone.

The terminal sends Ctrl-C to every process of its foreground group, the Dask
workers too: a worker still importing printed its KeyboardInterrupt traceback,
a busy one its asyncio traceback, under dynid's message. Here the workers do
not hear it; the program does, and takes the cluster down itself:

* only an ignored signal survives exec (a handler or a blocked mask does not),
  so the workers are forked from a forkserver exec'ed while SIGINT is ignored,
  with the environment Dask gives its workers (one BLAS thread each) already
  set, since the forkserver preloads NumPy;
* a Ctrl-C while the cluster starts is held until it has started (Dask cannot
  close a cluster interrupted while it starts); a second one acts at once;
* an interrupted run tells the nannies not to restart their workers, stops
  the workers (SIGTERM) and closes the cluster with Dask's loggers quiet (each
  broken connection was logged).

This changes process-wide state (Dask's start method, a forkserver that ignores
SIGINT, the SIGINT handler while the cluster starts), so it is for a program
that ends with the run: the command line, not the Python API. Linux only (the
forkserver of macOS would fork after NumPy is loaded; Windows has none).
"""
from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading

__all__ = ["available", "start_local_cluster", "stop_after_interrupt", "restore_logs"]

#: Dask's loggers (and their children), quietened while an interrupted run takes its cluster down
DASK_LOGGERS = ("distributed", "tornado", "asyncio")


def available() -> bool:
    """Whether this process can start workers deaf to Ctrl-C (Linux, main thread, Python's own handler)."""
    return (sys.platform.startswith("linux") and "forkserver" in multiprocessing.get_all_start_methods()
            and threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler)


def start_local_cluster(distributed, **options):
    """A `distributed.LocalCluster(**options)` whose workers ignore Ctrl-C (call when `available()`).

    Raises KeyboardInterrupt, the cluster closed, when Ctrl-C was pressed while it started.
    """
    before = set(getattr(distributed.SpecCluster, "_instances", ()))
    held = []
    try:
        with _ctrl_c_held(held):
            _start_deaf_forkserver()
            cluster = distributed.LocalCluster(**options)
    except KeyboardInterrupt:          # the second Ctrl-C, while the cluster starts
        for half in set(getattr(distributed.SpecCluster, "_instances", ())) - before:
            _close_quietly(half, timeout=2)
            half.shutdown_on_close = False      # Dask's exit handler would wait 10 s, then fail
        raise
    if held:
        _close_quietly(cluster)
        raise KeyboardInterrupt
    return cluster


def _close_quietly(cluster, timeout=None):
    """Stop the workers and close `cluster` with Dask's loggers quiet; errors of the close are
    not the user's (the run is being interrupted)."""
    former = {}
    try:
        stop_after_interrupt(cluster, former)
        with contextlib.suppress(Exception):
            cluster.close(timeout=timeout)
    finally:
        restore_logs(former)


def _start_deaf_forkserver():
    from multiprocessing import forkserver

    import dask
    from distributed.utils import get_mp_context

    # kept for the process: a worker the nanny restarts mid-run comes from the same forkserver
    dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"})
    get_mp_context()                  # Dask's preload list, set before the server starts
    # what the nanny sets before it spawns a worker (as it reads it: the environment wins)
    spawn_env = dask.config.get("distributed.nanny.pre-spawn-environ")
    environ = {k: os.environ.get(k, str(v)) for k, v in spawn_env.items() if v is not None}
    saved = {k: os.environ.get(k) for k in environ}
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        os.environ.update(environ)
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def noted_ctrl_c():
    """Yield a list that gets an entry when Ctrl-C is pressed inside the block; the Ctrl-C
    still raises KeyboardInterrupt as Python's own handler does.

    A KeyboardInterrupt that lands inside a lock's acquire/release in Dask's client code can
    surface as another exception (`RuntimeError: cannot release un-acquired lock`), which
    read as an internal error of dynid; the caller tells the two apart with the list. Only
    where Python's own handler is in place (main thread), else the list stays empty."""
    seen = []
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield seen
        return

    def note(signum, frame):
        seen.append(signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, note)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@contextlib.contextmanager
def _ctrl_c_held(seen: list):
    def hold(signum, frame):
        if seen:
            raise KeyboardInterrupt
        seen.append(signum)

    previous = signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def stop_after_interrupt(cluster, former: dict | None = None):
    """Quieten Dask's loggers, keep the nannies from restarting, stop the workers; returns the
    former log levels (for `restore_logs`). `former`: a dict the levels are recorded in before
    any is changed (so that a caller's `finally` can restore them after a second Ctrl-C)."""
    names = [n for n in list(logging.root.manager.loggerDict) if n.split(".")[0] in DASK_LOGGERS]
    names += list(DASK_LOGGERS)      # Dask's configuration gives some children a level of their own
    former = {} if former is None else former
    former.update({n: logging.getLogger(n).level for n in names})
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL)
    for nanny in list(getattr(cluster, "workers", {}).values()):
        with contextlib.suppress(Exception):
            nanny.close_gracefully()
        pid = getattr(nanny, "pid", None)
        if pid:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGTERM)
    return former


def restore_logs(former) -> None:
    for name, level in (former or {}).items():
        logging.getLogger(name).setLevel(level)
