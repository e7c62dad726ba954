"""Run `dynid ARGS` in a process of its own without paying the interpreter's imports each time.

A fresh `python -c "...main(sys.argv[1:])"` spends about a second (several on a loaded 2-core
machine) importing numpy, scipy, pandas, statsmodels and dynid's analysis stack before it reads
its first argument; the hostile-input suite starts ~150 of them. Here one server process (per
test worker) imports those modules once, then forks a child per run. The child is what a fresh
process would be from `main(argv)` on:

- its own session (process group: a timeout kills it and everything it started), the
  address-space limit (if one is given) set before it runs anything, stdin on /dev/null, its own working
  folder and exactly the environment the caller gives;
- stdout and stderr fresh text streams on new files (what the caller reads afterwards);
- the command line runs at the top level of the interpreter and the child leaves as the
  interpreter does: an uncaught exception prints its traceback and exits 1, SystemExit
  gives its code, atexit handlers and non-daemon threads are waited for, and a failing flush
  of stdout at exit gives 120, as in a fresh `python -c`. The teardown of a normal exit
  (freeing every object) is skipped, because it costs most of a short run. What a fresh
  process would do there is therefore missing: `__del__` methods and finalizers of objects
  still alive, the flush of files left open (other than stdout and stderr), the removal of
  a temporary file left to its finalizer, and the errors any of them prints. dynid closes its
  files and removes its temporaries itself (`atomic_open`, atexit); a test that checks stderr
  for tracebacks does not see one printed during teardown.

What a forked child cannot be: a process whose environment differs from the server's where the
interpreter reads it at start-up, or whose fd 1 is closed at start-up (sys.stdout is None), or a
check of start-up itself. `ForkedCli.run` returns None for any environment other than the one the
server was started with (but for PYTEST_CURRENT_TEST); callers then start a fresh interpreter (as they do for a closed stdout,
a file-size limit or a stdout of their own). DYNID_TEST_FRESH_PROCESSES=1 turns the server off.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: what the commands import on their first use; importing more would only cost the server time
PRELOAD = ("dynid.reports.cli", "dynid.analysis.run", "dynid.reports.pipeline",
           "dynid.analysis.data.synthetic", "dynid.dynamics.excitation", "dynid.reports.fleet_run",
           "dynid.reports.fleet_report")

#: `memory_limit` for children with the caller's own address-space limit
NO_LIMIT = -1

_SERVER = r'''
import json, os, resource, sys
for _name in sys.argv[1].split(","):
    __import__(_name)
_LIMIT, _CODE = int(sys.argv[2]), sys.argv[3]
_requests = os.fdopen(os.dup(0), "r")
_answers = os.fdopen(os.dup(1), "w")
_null = os.open(os.devnull, os.O_RDWR)
os.dup2(_null, 0)
os.dup2(_null, 1)


def _serve():
    for line in _requests:
        req = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _requests.close()
            _answers.close()
            os.setsid()
            if _LIMIT >= 0:
                resource.setrlimit(resource.RLIMIT_AS, (_LIMIT, _LIMIT))
            os.chdir(req["cwd"])
            os.environ.clear()
            os.environ.update(req["env"])
            for fd, path, flags in ((0, os.devnull, os.O_RDONLY),
                                    (1, req["out"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                                    (2, req["err"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
                opened = os.open(path, flags, 0o600)
                os.dup2(opened, fd)
                os.close(opened)
            os.close(_null)
            enc = sys.stdout.encoding
            sys.stdin = sys.__stdin__ = open(0, "r", encoding=enc, closefd=False)
            sys.stdout = sys.__stdout__ = open(1, "w", encoding=enc, closefd=False)
            sys.stderr = sys.__stderr__ = open(2, "w", encoding=enc, errors="backslashreplace",
                                               closefd=False, buffering=1)
            sys.argv = [req["argv0"], *req["args"]]
            return True
        _answers.write(f"{pid}\n")
        _answers.flush()
        _, status = os.waitpid(pid, 0)
        _answers.write(f"{os.waitstatus_to_exitcode(status)}\n")
        _answers.flush()
    return False


if _serve():
    del _serve, _requests, _answers, _null, _LIMIT, _name, json, resource
    import atexit as _atexit
    import threading as _threading
    try:
        exec(compile(_CODE, "<string>", "exec"))
        _status = 0
    except SystemExit as _exc:
        if _exc.code is not None and not isinstance(_exc.code, int):
            raise                      # printed and exit 1: the interpreter's own path below
        _status = _exc.code or 0
    # What the interpreter does when it leaves (Py_FinalizeEx), up to its teardown: wait for
    # the non-daemon threads, run the atexit handlers, flush stdout and stderr. The teardown
    # itself (freeing every object) writes to every page the child shares with the server,
    # and copying them costs ~0.7 s per run on a 2-core machine, about 20 times the
    # command's own time on bad input. Anything unusual (an uncaught exception, a failing
    # flush, which exits 120) takes the interpreter's own exit instead.
    _threading._shutdown()
    _atexit._run_exitfuncs()
    try:
        for _stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
            if _stream is not None and not _stream.closed:
                _stream.flush()
    except BaseException:
        sys.exit(_status)
    os._exit(_status & 0xFF if -2 ** 63 <= _status < 2 ** 63 else 255)
'''


def _startup(env):
    """The environment but pytest's name of the running test, which changes from test to test
    and which the interpreter does not read (the child gets the caller's, as given)."""
    return {k: v for k, v in env.items() if k != "PYTEST_CURRENT_TEST"}


class ForkedCli:
    """One server process; `run` sends it a command line and waits for the child's exit."""

    def __init__(self, code: str, env: dict, memory_limit: int):
        self.env = dict(env)
        self.folder = Path(tempfile.mkdtemp(prefix="dynid-forked-cli-"))
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _SERVER, ",".join(PRELOAD), str(memory_limit), code],
            env=self.env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            cwd=self.folder)

    def _line(self, timeout):
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            return None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the forked-CLI server ended (exit {self.proc.poll()})")
        return int(line)

    def run(self, args, cwd, env, timeout, argv0="-c"):
        """(returncode or None when timed out, stdout bytes, stderr bytes, elapsed s), or None
        when `env` is not the server's (the caller starts a fresh interpreter). `argv0`: the
        child's sys.argv[0] ("-c" as for `python -c`, or the console script's path)."""
        if _startup(env) != _startup(self.env) or self.proc.poll() is not None:
            return None
        out, err = self.folder / "stdout", self.folder / "stderr"
        t0 = time.monotonic()
        self.proc.stdin.write(json.dumps({"args": [str(a) for a in args], "cwd": str(cwd), "env": env,
                                          "out": str(out), "err": str(err), "argv0": argv0}) + "\n")
        self.proc.stdin.flush()
        pid = self._line(60)
        if pid is None:
            raise RuntimeError("the forked-CLI server did not start a child within 60 s")
        code = self._line(max(timeout - (time.monotonic() - t0), 0.0))
        timed_out = code is None
        if timed_out:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._line(None)
        elapsed = time.monotonic() - t0
        return (None if timed_out else code), out.read_bytes(), err.read_bytes(), elapsed

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for name in ("stdout", "stderr"):
            (self.folder / name).unlink(missing_ok=True)
        self.folder.rmdir()


def enabled() -> bool:
    return not os.environ.get("DYNID_TEST_FRESH_PROCESSES") and hasattr(os, "fork")
