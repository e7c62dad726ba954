"""Hostile input to the ``dynid`` command line: the to-do list of a 374-probe run.

Every case is generated here in ``tmp_path``. For each one the suite checks, as far
as it applies: no Python traceback on stderr; exit code 2 for bad input (1 means
"internal error, a bug"); a message naming the file, column or option at fault (and
no Python-API advice such as ``allow_pickle`` or ``default_settings(...)``); input
files byte-identical afterwards; old outputs either untouched or fully replaced; no
stray temporary files left in the output folder.

Groups (test names start with the group's prefix):

1. ``test_g1_*`` an output path equal to an input path (directly, via a symlink,
   two outputs on one path) is refused before any computation.
2. ``test_g2_*`` special output files: a FIFO and a private null device stay what
   they are, a symlink is kept, a full disk is reported, an output's mode is kept,
   a 250-character name works or is refused before the computation. (The machine's
   own /dev/null and /dev/full are never used as outputs: the current code renames
   a temporary file over the target and would replace them. Private device nodes
   made with ``os.mknod`` in ``tmp_path`` stand in for them.)
3. ``test_g3_*`` all-or-none writing of several outputs, in-process with
   ``os.replace`` patched (a failing rename, a SIGTERM between renames) and stale
   temporary files of a killed run.
4. ``test_g4_*`` silent nonsense in data and options (units, spikes, booleans,
   NaN noise, a file given twice or as its own validation): a notice on stderr
   naming the column and what looks wrong, or exit 2.
5. ``test_g5_*`` impossible robot files (TOML and URDF): exit 2, clear message.
6. ``test_g6_*`` unbounded memory and hangs (/dev/zero, FIFOs, huge durations,
   rates, harmonics, 1000 joints): fail fast, under a 4 GiB address-space limit and
   a subprocess timeout, naming the option or file and the size.
7. ``test_g7_*`` bad input reported today as an internal error (exit 1).
8. ``test_g8_*`` messages that point the wrong way.
9. ``test_g9_*`` terminal escape sequences in names.

Issue 31 (the fleet and the newer options):

10. ``test_g10_*`` data loss: a fleet output onto its catalogue, a recording or a robot
    file (directly, through a symlink, a hard link or ``..``), from the CLI and Python;
    ``--json ""``, ``--json x.json/``, a closed stdout; the all-or-none commit with a
    second writer in another PID namespace (``unshare``; skipped where unavailable).
11. ``test_g11_*`` silently wrong values: fleet duplicates (symlink, byte-identical copy),
    monitoring options and temperatures out of range, failed recordings that must fail
    the run, torques in kN·m, ``time_tolerance = 1e9``.
12. ``test_g12_*`` hangs and memory: FIFO and /dev/zero catalogue entries, an oversized
    TOML, an npz zip bomb and a forged npz shape, resampling across a huge gap, ``--nd``,
    ``--v-s`` and ``--bootstrap`` far out of range.
13. ``test_g13_*`` internal errors: ``--prior-weight 1e300``, ``--v-s 1e-300``, a
    scheduler that is not an address, an unwritable or read-only store.
14. ``test_g14_*`` advice the user can follow from the command line (a motionless recording,
    maximum likelihood, rank deficiency, too many harmonics), several data files after
    ``--robot``, and the Parquet readers docs/formats.md gives for the fleet store, run as written.

Also in groups 11-13: robot files in degrees and a negative PID ``ki`` through the CLI, excite
limits of 1e300, ``--starts`` and ``--workers`` out of range, a fleet with one failed recording,
an unknown ``--parameters`` name, the orchestrator's ranges in Python (``dynid.run``,
``dynid.identify``), a long compiled simulation stopped by SIGTERM/SIGINT, and ``simulate``
saying what it leaves out (friction, rotor inertia).

``pytest -m "not slow"`` leaves out the cases over 20 s. The CLI is run in one place, :func:`run_dynid` (subprocess), and imported in one
place, :func:`dynid_main` (in-process, group 3 and NUL-byte paths): when the package
moves to ``dynid.reports.cli`` only ``DYNID_MODULE`` changes.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import resource
import select
import shutil
import signal
import stat
import subprocess
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from signalled import signal_when

ROOT = Path(__file__).resolve().parents[2]

# The 'slow' mark (cases over 20 s; deselect with -m "not slow") is not registered in
# pyproject.toml yet; silence pytest's unknown-mark warning for this module only.
warnings.filterwarnings("ignore", r"Unknown pytest\.mark\.slow", pytest.PytestUnknownMarkWarning)

# ---- the one place that knows where the CLI lives ------------------------------------------
DYNID_MODULE = "dynid.reports.cli"
DYNID_CODE = f"import sys; from {DYNID_MODULE} import main; sys.exit(main(sys.argv[1:]))"

MEMORY_LIMIT = 4 << 30          # RLIMIT_AS of every subprocess: a runaway cannot take the machine down
PLANAR2 = ROOT / "dynamics" / "robots" / "planar2.toml"


@dataclass
class Run:
    args: tuple
    rc: int | None
    out: str
    err: str
    elapsed: float
    timed_out: bool
    timeout: float
    changed_inputs: list = field(default_factory=list)
    new_temp_files: list = field(default_factory=list)

    def __str__(self):
        state = f"TIMED OUT after {self.timeout:g} s" if self.timed_out else f"exit {self.rc}"
        return (f"dynid {' '.join(map(str, self.args))}: {state} in {self.elapsed:.1f} s\n"
                f"--- stderr ---\n{self.err[-3000:]}\n--- stdout ---\n{self.out[-1500:]}")


OUTPUT_FLAGS = {"--json", "--report", "--csv", "--out", "--urdf", "--mjcf"}
#: dynid's temporary files beside the target (dynid.outputs): a writer's lease lock
#: ".dynid-<host>-<pid>-<16 hex>.lock" (".new" before it is published), its temporary files
#: "<same>-<n>.tmp" and hard-linked backups "<same>-<n>.bak"; the older layouts
#: ".dynid-<pid>-<12 hex>.tmp|bak" and ".<target>.<12 hex>.tmp" are matched too
DYNID_TEMP = re.compile(r"^\.dynid-[A-Za-z0-9.-]*-\d+-[0-9a-f]{16}(-\d+\.(tmp|bak)|\.lock|\.new)$"
                        r"|^\.dynid-\d+-[0-9a-f]{12}\.(tmp|bak)$|^\..+\.[0-9a-f]{12}\.tmp$")


def _dead_pid():
    """A process id no process has (above the kernel's pid_max)."""
    try:
        return int(Path("/proc/sys/kernel/pid_max").read_text()) + 1
    except (OSError, ValueError):
        return (1 << 22) + 1


class _Watch:
    """What a run must not do: change an input file, leave a temporary file behind.

    Inputs: every argument that names an existing regular file and is not only the
    value of an output option. Folders watched: the working directory and the folder
    of every output option."""

    def __init__(self, args, cwd):
        args = [str(a) for a in args]
        cwd = Path(cwd)
        out_idx = {i + 1 for i, a in enumerate(args[:-1]) if a in OUTPUT_FLAGS}
        self.inputs = {}
        for i, a in enumerate(args):
            if i in out_idx or "\0" in a:
                continue
            p = cwd / a
            try:
                if p.is_file():              # follows symlinks; FIFOs and devices are skipped
                    self.inputs[p] = p.read_bytes()
            except (OSError, ValueError):
                pass
        self.folders = {cwd} | {(cwd / args[i]).parent for i in out_idx
                                if i < len(args) and args[i] != "-" and "\0" not in args[i]}
        self.temps = self._temps()

    def _temps(self):
        found = set()
        for d in self.folders:
            if d.is_dir():
                found |= {d / n for n in os.listdir(d) if DYNID_TEMP.match(n)}
        return found

    def report(self, run):
        for p, data in self.inputs.items():
            try:
                same = p.is_file() and p.read_bytes() == data
            except OSError:
                same = False
            if not same:
                run.changed_inputs.append(str(p))
        run.new_temp_files = sorted(str(p) for p in self._temps() - self.temps)
        return run


def run_dynid(*args, cwd, env=None, timeout=60, stdout=subprocess.PIPE, close_stdout=False,
              file_size_limit=None):
    """Run ``dynid ARGS`` in a subprocess with a 4 GiB address-space limit.

    ``stdout``: a file descriptor / file to write stdout to instead of a pipe;
    ``close_stdout``: start dynid with fd 1 closed (``>&-``);
    ``file_size_limit``: RLIMIT_FSIZE in bytes (a disk that fills up), SIGXFSZ ignored.
    A run that exceeds ``timeout`` is killed (its own process group) and reported
    as timed out instead of raising. The returned Run also lists the input files the
    run changed and the temporary files it left (see :class:`_Watch`).

    With stdout a pipe, no file-size limit and the worker's environment (most runs), the
    process is forked from a server that has imported dynid once (tests/support/forked_cli.py:
    a fresh interpreter spends a second or more on imports before it reads its arguments);
    any other run, or every run with DYNID_TEST_FRESH_PROCESSES=1, starts a fresh interpreter.
    """
    cmd = [sys.executable, "-c", DYNID_CODE, *map(str, args)]
    full_env = dict(os.environ)
    full_env["PYTHONPATH"] = str(ROOT) + (os.pathsep + full_env["PYTHONPATH"]
                                          if full_env.get("PYTHONPATH") else "")
    full_env.setdefault("OPENBLAS_NUM_THREADS", "1")
    full_env.setdefault("OMP_NUM_THREADS", "1")
    if env:
        full_env.update(env)

    def preexec():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        if file_size_limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))
        if close_stdout:
            os.close(1)

    watch = _Watch(args, cwd)
    dec = lambda b: (b or b"").decode("utf-8", "replace")  # noqa: E731
    if stdout is subprocess.PIPE and not close_stdout and file_size_limit is None:
        forked = _forked_cli(full_env)
        answer = forked.run(args, cwd, full_env, timeout) if forked else None
        if answer is not None:
            rc, out, err, elapsed = answer
            return watch.report(Run(args, rc, dec(out), dec(err), elapsed, rc is None, timeout))
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=cwd, env=full_env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL if close_stdout else stdout,
                            stderr=subprocess.PIPE, preexec_fn=preexec, start_new_session=True)
    timed_out = False
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        timed_out = True
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
    elapsed = time.monotonic() - t0
    return watch.report(Run(args, None if timed_out else proc.returncode, dec(out), dec(err),
                            elapsed, timed_out, timeout))


_FORKED = []


def _forked_cli(env):
    """This worker's forked-CLI server (tests/support/forked_cli.py), started on first use with
    the environment of a default run; None where fork is unavailable or turned off."""
    import forked_cli
    if not forked_cli.enabled():
        return None
    if not _FORKED:
        _FORKED.append(forked_cli.ForkedCli(DYNID_CODE, env, MEMORY_LIMIT))
    return _FORKED[0]


@pytest.fixture(scope="module", autouse=True)
def _close_forked_cli():
    yield
    while _FORKED:
        _FORKED.pop().close()


def dynid_main():
    """The CLI's ``main(argv) -> exit code``, imported in-process (the one import)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    import importlib
    return importlib.import_module(DYNID_MODULE).main


def run_in_process(capsys, *args):
    """``main(args)`` in this process; returns a Run (stdout / stderr captured).

    Paths in ``args`` should be absolute. Restores the SIGTERM handler main() installs."""
    watch = _Watch(args, Path.cwd())
    old = signal.getsignal(signal.SIGTERM)
    t0 = time.monotonic()
    try:
        try:
            rc = dynid_main()([str(a) for a in args])
        except SystemExit as exc:         # argparse
            rc = exc.code
        except BaseException as exc:      # noqa: BLE001 - a leak out of main() is a failure
            rc = f"main() raised {type(exc).__name__}: {exc}"
    finally:
        signal.signal(signal.SIGTERM, old)
    cap = capsys.readouterr()
    return watch.report(Run(args, rc, cap.out, cap.err, time.monotonic() - t0, False, 0))


# ---- checks ---------------------------------------------------------------------------------
#: Python-API advice a CLI user cannot follow.
FORBIDDEN_ADVICE = ("allow_pickle", "pickle.load", "ols(", "wls(", "default_settings",
                    "settings=", "identify_idim(", "load_experiment(")


def _has(text, alternatives):
    """Whether ``text`` matches one of the regexes ``alternatives`` (a str is one regex)."""
    if isinstance(alternatives, str):
        alternatives = (alternatives,)
    return any(re.search(a, text, re.IGNORECASE) for a in alternatives)


def assert_clean(run):
    assert not run.timed_out, f"no answer within {run.timeout:g} s (hang or unbounded work)\n{run}"
    assert "Traceback (most recent call last)" not in run.err, f"traceback on stderr\n{run}"
    assert "internal error" not in run.err, f"reported as an internal error (a bug)\n{run}"
    assert not run.changed_inputs, f"input files changed: {run.changed_inputs}\n{run}"
    assert not run.new_temp_files, f"temporary files left: {run.new_temp_files}\n{run}"
    for bad in FORBIDDEN_ADVICE:
        assert bad not in run.err, f"the message gives Python-API advice ({bad!r})\n{run}"


def assert_input_error(run, *names):
    """Exit 2, no traceback, and the message matches each of ``names`` (regex or tuple of)."""
    assert_clean(run)
    assert run.rc == 2, f"expected exit 2 (bad input)\n{run}"
    for alternatives in names:
        assert _has(run.err, alternatives), f"the message does not name {alternatives!r}\n{run}"


def assert_notice_or_error(run, what, why):
    """Exit 2 naming ``what``, or success with a notice on stderr naming ``what`` and ``why``."""
    assert_clean(run)
    if run.rc == 2:
        assert _has(run.err, what), f"the error does not name {what!r}\n{run}"
        return
    assert run.rc == 0, f"expected exit 0 with a notice, or exit 2\n{run}"
    assert _has(run.err, what) and _has(run.err, why), (
        f"accepted silently: no notice on stderr naming {what!r} and saying {why!r}\n{run}")


def fingerprint(*paths):
    """Bytes hash and file type of each path (symlinks: the link and its target)."""
    out = {}
    for p in map(Path, paths):
        st = os.lstat(p)
        entry = {"type": stat.S_IFMT(st.st_mode), "mode": stat.S_IMODE(st.st_mode)}
        if stat.S_ISLNK(st.st_mode):
            entry["link"] = os.readlink(p)
        if Path(p).is_file():
            entry["sha256"] = hashlib.sha256(Path(p).read_bytes()).hexdigest()
        out[str(p)] = entry
    return out


def temp_files(folder):
    return sorted(p.name for p in Path(folder).iterdir() if DYNID_TEMP.match(p.name))


def assert_no_temp(folder, run=None):
    left = temp_files(folder)
    assert not left, f"temporary files left in {folder}: {left}\n{run or ''}"


# ---- data and robot files --------------------------------------------------------------------
@pytest.fixture(scope="session")
def recording(tmp_path_factory):
    """A 2 s closed-loop recording of planar2 (t, q1, q2, qr1, qr2, tau1, tau2)."""
    d = tmp_path_factory.mktemp("recording")
    run = run_dynid("simulate", "--robot", "planar2", "--duration", "2", "--out", "rec.csv",
                    "--quiet", cwd=d, timeout=120)
    assert run.rc == 0, str(run)
    return d / "rec.csv"


@pytest.fixture
def frame(recording):
    return pd.read_csv(recording)


@pytest.fixture
def data(tmp_path, recording):
    """``in.csv``: a copy of the recording in this test's folder."""
    p = tmp_path / "in.csv"
    shutil.copyfile(recording, p)
    return p


def write_csv(path, df):
    df.to_csv(path, index=False, float_format="%.10g")
    return path


def planar2_toml(folder, *edits, append="", name="my.toml"):
    """A copy of planar2.toml with ``(old, new)`` text replacements and text appended."""
    text = PLANAR2.read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = Path(folder) / name
    p.write_text(text + append, encoding="utf-8")
    return p


_LINK = """  <link name="{name}">
    <inertial><origin xyz="0.5 0 0"/><mass value="{mass}"/>
      <inertia ixx="{ixx}" ixy="{ixy}" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>
  </link>
"""


def urdf_chain(n=2, *, mass=None, inertia=None, joint_extra=None, limit=None, extra="",
               duplicate_link=False, name="arm"):
    """A serial chain base -> link_1 -> ... -> link_n of revolute joints j1..jn about z.

    ``mass`` / ``inertia`` / ``joint_extra`` / ``limit``: dicts {k: value} overriding link k's
    mass, inertia (ixx, ixy, iyy, izz), adding XML inside joint jk, replacing its limit attributes.
    """
    mass, inertia, joint_extra, limit = mass or {}, inertia or {}, joint_extra or {}, limit or {}
    parts = [f'<?xml version="1.0"?>\n<robot name="{name}">\n  <link name="base"/>\n']
    for k in range(1, n + 1):
        ine = dict(ixx=0.01, ixy=0.0, iyy=0.1, izz=0.1)
        ine.update(inertia.get(k, {}))
        parts.append(_LINK.format(name=f"link_{k}", mass=mass.get(k, 1.0), **ine))
        if duplicate_link and k == 1:
            parts.append(_LINK.format(name="link_1", mass=3.0, ixx=0.2, ixy=0.0, iyy=0.2, izz=0.2))
        lim = limit.get(k, 'lower="-3" upper="3" effort="100" velocity="5"')
        parts.append(f'  <joint name="j{k}" type="revolute">\n'
                     f'    <parent link="{"base" if k == 1 else f"link_{k - 1}"}"/>'
                     f'<child link="link_{k}"/>\n'
                     f'    <origin xyz="{0 if k == 1 else 1} 0 0"/><axis xyz="0 0 1"/>\n'
                     f'    <limit {lim}/>\n{joint_extra.get(k, "")}  </joint>\n')
    parts.append(extra + "</robot>\n")
    return "".join(parts)


def identify_args(data, *more):
    return ("identify", data, "--robot", "planar2", *more)


# =============================================================================================
# 1. An output path equal to an input path
# =============================================================================================
def test_g1_identify_csv_onto_its_input(tmp_path, data):
    before = fingerprint(data)
    run = run_dynid(*identify_args("in.csv", "--csv", "in.csv"), cwd=tmp_path)
    assert_input_error(run, "in.csv", "--csv")
    assert "loaded" not in run.err, f"refused only after loading the data\n{run}"
    assert fingerprint(data) == before, "the input recording was overwritten"
    assert_no_temp(tmp_path, run)


def test_g1_simulate_onto_its_robot_file(tmp_path):
    robot = planar2_toml(tmp_path)
    before = fingerprint(robot)
    run = run_dynid("simulate", "--robot", "my.toml", "--duration", "2", "--out", "my.toml",
                    cwd=tmp_path)
    assert_input_error(run, "my.toml", "--out")
    assert "wrote" not in run.err
    assert fingerprint(robot) == before, "the robot file was overwritten by the recording"
    assert_no_temp(tmp_path, run)


def test_g1_output_through_a_symlink_to_the_input(tmp_path, data):
    (tmp_path / "link.json").symlink_to("in.csv")
    before = fingerprint(data, tmp_path / "link.json")
    run = run_dynid(*identify_args("in.csv", "--json", "link.json"), cwd=tmp_path)
    assert_input_error(run, ("link.json", "in.csv"), "--json")
    assert "loaded" not in run.err, f"refused only after loading the data\n{run}"
    assert fingerprint(data, tmp_path / "link.json") == before
    assert_no_temp(tmp_path, run)


def test_g1_output_onto_the_validation_file(tmp_path, data, frame):
    other = frame.copy()
    other["tau1"] *= 1.01                   # another recording (a copy is refused as validation)
    other.to_csv(tmp_path / "valid.csv", index=False)
    before = fingerprint(data, tmp_path / "valid.csv")
    run = run_dynid(*identify_args("in.csv", "--validation", "valid.csv", "--report", "valid.csv"),
                    cwd=tmp_path)
    assert_input_error(run, "valid.csv", "--report")
    assert "loaded" not in run.err
    assert fingerprint(data, tmp_path / "valid.csv") == before
    assert_no_temp(tmp_path, run)


def test_g1_two_outputs_on_one_path(tmp_path, data):
    before = fingerprint(data)
    run = run_dynid(*identify_args("in.csv", "--json", "same.out", "--report", "same.out"),
                    cwd=tmp_path)
    assert_input_error(run, "same.out", "--json", "--report")
    assert "loaded" not in run.err, f"refused only after loading the data\n{run}"
    assert not (tmp_path / "same.out").exists(), "one output silently overwrote the other"
    assert fingerprint(data) == before
    assert_no_temp(tmp_path, run)


# =============================================================================================
# 2. Special output files
# =============================================================================================
class FifoReader:
    """Reads a FIFO without blocking anyone (O_NONBLOCK), until EOF after data or stop()."""

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        self.data = b""
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        chunks, seen, deadline = [], False, time.monotonic() + 120
        try:
            while time.monotonic() < deadline:
                ready, _, _ = select.select([self.fd], [], [], 0.1)
                if ready:
                    b = os.read(self.fd, 1 << 16)
                    if b:
                        chunks.append(b)
                        seen = True
                        continue
                    if seen:
                        break            # EOF after the writer closed
                if self._stop.is_set():
                    break
                time.sleep(0.02)         # no writer yet (EOF without data)
        finally:
            self.data = b"".join(chunks)
            os.close(self.fd)

    def stop(self):
        time.sleep(0.3)
        self._stop.set()
        self.thread.join(10)
        return self.data


def test_g2_json_into_a_fifo_stays_a_fifo(tmp_path):
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    reader = FifoReader(fifo)
    run = run_dynid("robot", "planar2", "--json", "out.json", "--quiet", cwd=tmp_path, timeout=30)
    got = reader.stop()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode), f"the FIFO was replaced by a regular file\n{run}"
    assert_clean(run)
    if run.rc == 0:
        assert json.loads(got)["robot"] == "planar2", "the reader did not receive the JSON"
    else:
        assert_input_error(run, "out.json")
    assert_no_temp(tmp_path, run)


def _mknod(path, major, minor):
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(major, minor))
    except (PermissionError, OSError) as exc:
        pytest.skip(f"cannot create a private device node here ({exc})")


def test_g2_json_into_a_null_device_stays_a_device(tmp_path):
    null = tmp_path / "null"
    _mknod(null, 1, 3)                  # a private /dev/null
    run = run_dynid("robot", "planar2", "--json", "null", "--quiet", cwd=tmp_path, timeout=30)
    assert stat.S_ISCHR(os.lstat(null).st_mode), f"the device was replaced by a regular file\n{run}"
    assert_clean(run)
    assert run.rc in (0, 2), str(run)
    assert_no_temp(tmp_path, run)


def test_g2_json_into_a_full_device_reports_a_full_disk(tmp_path):
    full = tmp_path / "full"
    _mknod(full, 1, 7)                  # a private /dev/full: every write fails with ENOSPC
    run = run_dynid("robot", "planar2", "--json", "full", "--quiet", cwd=tmp_path, timeout=30)
    assert stat.S_ISCHR(os.lstat(full).st_mode), f"the device was replaced by a regular file\n{run}"
    assert_input_error(run, "full", ("space", "full"))
    assert_no_temp(tmp_path, run)


def test_g2_disk_full_midway_keeps_old_outputs(tmp_path, data):
    out = tmp_path / "out"
    out.mkdir()
    olds = {"r.json": "OLD json\n", "r.html": "OLD html\n"}
    for name, text in olds.items():
        (out / name).write_text(text)
    before = fingerprint(data)
    run = run_dynid(*identify_args("in.csv", "--json", "out/r.json", "--report", "out/r.html"),
                    cwd=tmp_path, file_size_limit=60_000)
    assert_input_error(run, ("r.html", "r.json"), ("space", "full", "large", "cannot write"))
    assert {n: (out / n).read_text() for n in olds} == olds, "old outputs were changed"
    assert fingerprint(data) == before
    assert_no_temp(out, run)


def test_g2_json_through_a_symlink_keeps_the_link(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "target.json").write_text("OLD\n")
    link = tmp_path / "out.json"
    link.symlink_to(real / "target.json")
    run = run_dynid("robot", "planar2", "--json", "out.json", "--quiet", cwd=tmp_path, timeout=30)
    assert_clean(run)
    assert link.is_symlink(), f"the symlink was replaced by a regular file\n{run}"
    if run.rc == 0:
        assert json.loads((real / "target.json").read_text())["robot"] == "planar2"
    else:
        assert_input_error(run, "out.json", "link")
        assert (real / "target.json").read_text() == "OLD\n"
    assert_no_temp(tmp_path, run)
    assert_no_temp(real, run)


def test_g2_overwrite_keeps_the_mode_of_the_old_output(tmp_path):
    js = tmp_path / "out.json"
    js.write_text("OLD\n")
    os.chmod(js, 0o600)
    run = run_dynid("robot", "planar2", "--json", "out.json", "--quiet", cwd=tmp_path, timeout=30)
    assert_clean(run)
    assert run.rc == 0, str(run)
    assert js.read_text() != "OLD\n"
    assert stat.S_IMODE(os.stat(js).st_mode) == 0o600, (
        f"mode {oct(stat.S_IMODE(os.stat(js).st_mode))} after the overwrite, was 0o600")


def test_g2_name_of_250_characters_works_or_is_refused_first(tmp_path, data):
    name = "r" * 245 + ".json"
    assert len(name) == 250
    run = run_dynid(*identify_args("in.csv", "--json", name), cwd=tmp_path)
    assert_clean(run)
    if run.rc == 0:
        assert json.loads((tmp_path / name).read_text())
    else:
        assert_input_error(run, ("--json", "r{40}"), ("long", "name"))
        assert "loaded" not in run.err, (
            f"refused only after the computation ({run.elapsed:.1f} s)\n{run}")
    assert_no_temp(tmp_path, run)


# =============================================================================================
# 3. All-or-none (in-process: os.replace patched)
# =============================================================================================
OLD_OUTPUTS = {"r.json": "OLD json\n", "r.html": "OLD html\n", "r.csv": "OLD csv\n"}


def _three_outputs(tmp_path, data):
    out = tmp_path / "out"
    out.mkdir()
    for name, text in OLD_OUTPUTS.items():
        (out / name).write_text(text)
    args = identify_args(str(data), "--json", str(out / "r.json"), "--report", str(out / "r.html"),
                         "--csv", str(out / "r.csv"), "--quiet")
    return out, args


def _patch_replace(monkeypatch, out, on_second):
    """os.replace (and os.rename) calling ``on_second()`` at the second rename into ``out``."""
    calls = []

    def patched(real):
        def rename(src, dst, *a, **k):
            if Path(os.fspath(dst)).parent == out:
                calls.append(Path(os.fspath(dst)).name)
                if len(calls) == 2:
                    on_second()
            return real(src, dst, *a, **k)
        return rename

    monkeypatch.setattr(os, "replace", patched(os.replace))
    monkeypatch.setattr(os, "rename", patched(os.rename))
    return calls


def _assert_all_or_none(out, run):
    new = [n for n, old in OLD_OUTPUTS.items() if (out / n).read_text() != old]
    if new and len(new) < len(OLD_OUTPUTS):
        # mixed: acceptable only if the message says exactly which files were written
        unnamed = [n for n in new if n not in run.err]
        assert not unnamed and _has(run.err, ("written", "wrote", "replaced")), (
            f"mixed outputs: {new} are new, the others old, and the message does not say "
            f"which were written\n{run}")
        assert not _has(run.err, r"no partial output"), f"claims no partial output, but {new} were written\n{run}"
    assert_no_temp(out, run)


def test_g3_second_rename_fails(tmp_path, data, monkeypatch, capsys):
    out, args = _three_outputs(tmp_path, data)

    def fail():
        raise OSError(errno.EIO, "Input/output error (injected)")

    calls = _patch_replace(monkeypatch, out, fail)
    run = run_in_process(capsys, *args)
    assert len(calls) >= 2, f"expected at least two renames, saw {calls}\n{run}"
    assert run.rc == 2, str(run)
    assert "Traceback" not in run.err
    _assert_all_or_none(out, run)


def test_g3_sigterm_between_renames(tmp_path, data, monkeypatch, capsys):
    out, args = _three_outputs(tmp_path, data)
    calls = _patch_replace(monkeypatch, out, lambda: signal.raise_signal(signal.SIGTERM))
    run = run_in_process(capsys, *args)
    assert len(calls) >= 2, f"expected at least two renames, saw {calls}\n{run}"
    assert run.rc in (0, 130), str(run)
    _assert_all_or_none(out, run)


def test_g3_interrupt_while_staging_leaves_no_temporary_file(tmp_path, monkeypatch):
    """Ctrl-C inside the write of a temporary file: the old output stays and the temporary file
    goes (it was not yet staged, and its lease is released on the way out: no later run could
    prove it abandoned)."""
    from dynid.outputs import write_all
    old = tmp_path / "e.json"
    old.write_text("OLD")

    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_all([(str(old), "NEW")])
    assert old.read_text() == "OLD"
    assert not [n for n in temp_files(tmp_path) if n.endswith(".tmp")], temp_files(tmp_path)


_LEASE_HOLDER = """
import os, sys, time
from dynid.outputs import staged_path
with staged_path(sys.argv[1]) as tmp:
    open(tmp, "w").write('{"half": ')
    print("staged", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def _hold_lease(target, seconds):
    """A process writing `target` through dynid.outputs, paused mid-write (its lease held)."""
    proc = subprocess.Popen([sys.executable, "-c", _LEASE_HOLDER, str(target), str(seconds)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "staged"
    return proc


def test_g3_stale_temp_files_of_a_killed_run_are_cleaned(tmp_path):
    killed = _hold_lease(tmp_path / "old.json", 60)
    killed.kill()                       # SIGKILL mid-write: its lease lock is released by the kernel
    killed.wait()
    stale = temp_files(tmp_path)
    assert any(n.endswith(".tmp") for n in stale) and any(n.endswith(".lock") for n in stale), stale
    live = _hold_lease(tmp_path / "other.json", 60)        # a running writer's files stay
    try:
        live_files = set(temp_files(tmp_path)) - set(stale)
        keep = [tmp_path / "notes.tmp", tmp_path / ".other.tmp",                # not dynid's naming
                tmp_path / f".dynid-{_dead_pid()}-00112233aabb.tmp"]          # no lease: not provably stale
        for p in keep:
            p.write_text("mine")
        run = run_dynid("robot", "planar2", "--json", "out.json", "--quiet", cwd=tmp_path, timeout=30)
        assert run.rc == 0, str(run)
        assert all(p.exists() for p in keep), "removed files that are not provably stale dynid files"
        assert live_files and live_files <= set(temp_files(tmp_path)), "removed a running writer's files"
        left = [n for n in stale if (tmp_path / n).exists()]
        assert not left, f"temporary files of a killed run are still there: {left}"
    finally:
        live.kill()
        live.wait()


# =============================================================================================
# 4. Silent nonsense
# =============================================================================================
def test_g4_torques_in_mNm(tmp_path, frame):
    frame[["tau1", "tau2"]] *= 1000.0
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"tau[12]?\b", (r"tau_max", r"mN", r"\bunits?\b", r"1000"))


def test_g4_positions_in_degrees(tmp_path, frame):
    cols = ["q1", "q2", "qr1", "qr2"]
    frame[cols] = np.degrees(frame[cols])
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"\bqr?[12]\b", (r"q_limits", r"degree", r"\bdeg\b", r"\bunits?\b"))


def test_g4_time_in_ms(tmp_path, frame):
    frame["t"] *= 1000.0
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, (r"'t'", r"\btime\b", r"column t\b"),
                           (r"\bms\b", r"milli", r"\bunits?\b", r"qd_max"))


def test_g4_one_torque_spike(tmp_path, frame):
    frame.loc[777, "tau1"] = 1e6
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"tau1\b", (r"tau_max", r"spike", r"outlier", r"\brow\b"))


def test_g4_boolean_parquet_column(tmp_path, frame):
    pytest.importorskip("pyarrow")
    frame["q2"] = frame["q2"] > 0
    frame.to_parquet(tmp_path / "in.parquet", index=False)
    run = run_dynid(*identify_args("in.parquet", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"\bq2\b", (r"bool", r"true", r"false"))


def test_g4_boolean_npz_column(tmp_path, frame):
    arrays = {c: frame[c].to_numpy() for c in frame.columns}
    arrays["q2"] = arrays["q2"] > 0
    np.savez(tmp_path / "in.npz", **arrays)
    run = run_dynid(*identify_args("in.npz", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"\bq2\b", (r"bool", r"true", r"false"))


@pytest.mark.parametrize("value", ["nan", "inf", "-1"])
def test_g4_simulate_noise_q(tmp_path, value):
    run = run_dynid("simulate", "--robot", "planar2", "--duration", "2", "--noise-q", value,
                    "--out", "x.csv", cwd=tmp_path)
    assert_notice_or_error(run, r"--noise-q", (r"finite", r"negative", r"positive", r"\bnan\b",
                                               r"\binf\b"))
    if run.rc == 2:
        assert not (tmp_path / "x.csv").exists()


def test_g4_same_file_twice(tmp_path, data):
    before = fingerprint(data)
    run = run_dynid("identify", "in.csv", "in.csv", "--robot", "planar2", "--json", "o.json",
                    cwd=tmp_path)
    assert_notice_or_error(run, r"in\.csv", (r"twice", r"same", r"duplicate", r"more than once"))
    assert fingerprint(data) == before


def test_g4_file_as_its_own_validation(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--validation", "in.csv", "--json", "o.json"),
                    cwd=tmp_path)
    assert_notice_or_error(run, (r"--validation", r"in\.csv"),
                           (r"same", r"itself", r"identical", r"also the"))


def test_g4_copy_as_validation_or_twice(tmp_path, data):
    """A copy of the recording under another name is the same recording (the bytes compared)."""
    shutil.copyfile(data, tmp_path / "copy.csv")
    run = run_dynid(*identify_args("in.csv", "--validation", "copy.csv", "--json", "o.json"), cwd=tmp_path)
    assert_input_error(run, r"--validation copy\.csv", r"a copy of the data file in\.csv")
    run = run_dynid("identify", "in.csv", "copy.csv", "--robot", "planar2", cwd=tmp_path)
    assert_input_error(run, r"copy\.csv", r"given twice")
    assert not (tmp_path / "o.json").exists()


def test_g4_output_on_a_file_an_experiment_section_reads(tmp_path, data):
    """An experiment TOML whose [time], [positions], [torques] name their files: --csv on that file
    is refused before any work, and the recording is kept."""
    (tmp_path / "exp.toml").write_text('[time]\nfile = "in.csv"\ncolumn = "t"\n'
                                       '[positions]\nfile = "in.csv"\ncolumns = ["q1", "q2"]\n'
                                       '[torques]\nfile = "in.csv"\ncolumns = ["tau1", "tau2"]\n')
    before = fingerprint(data)
    run = run_dynid("identify", "exp.toml", "--robot", "planar2", "--csv", "in.csv", cwd=tmp_path)
    assert_input_error(run, r"--csv in\.csv", r"exp\.toml reads")
    assert fingerprint(data) == before


def test_g4_payload_outputs_and_inputs(tmp_path, data):
    """payload: --json on its --model file, and --unloaded equal to --loaded, are refused."""
    (tmp_path / "model.json").write_text("{}")
    run = run_dynid("payload", "--robot", "planar2", "--loaded", "in.csv", "--model", "model.json",
                    "--json", "model.json", cwd=tmp_path)
    assert_input_error(run, r"--json model\.json", r"--model file")
    assert (tmp_path / "model.json").read_text() == "{}"
    run = run_dynid("payload", "--robot", "planar2", "--loaded", "in.csv", "--unloaded", "in.csv",
                    "--json", "p.json", cwd=tmp_path)
    assert_input_error(run, r"--unloaded in\.csv", r"same file as the data file")


# =============================================================================================
# 5. Impossible robot files
# =============================================================================================
TOML_CASES = {
    "apriori_negative_mass": ([("M2 = 2.0", "M2 = -2.0")], "", (r"\bM2\b",)),
    "apriori_unknown_name": ([("Fc2 = 0.5 }", "Fc2 = 0.5, RUBBISH = 1.0 }")], "", (r"RUBBISH",)),
    "reversed_q_limits": ([("q_limits = [-2.8, 2.8]", "q_limits = [2.8, -2.8]")], "", (r"q_limits",)),
    "coupling_1e154": ([], "\n[[couplings]]\nmotor = 2\njoints = [1, 2]\ncoefficients = [1e154, 1.0]\n",
                       (r"coupling",)),
    "coupling_1e-300": ([], "\n[[couplings]]\nmotor = 2\njoints = [1, 2]\ncoefficients = [1.0, 1e-300]\n",
                        (r"coupling",)),
    "d_1e200": ([("d = 1.0", "d = 1e200")], "", (r"joints\[2\]|elbow",)),
    "gravity_1e300": ([("gravity = [0.0, -9.81, 0.0]", "gravity = [0.0, -1e300, 0.0]")], "",
                      (r"gravity",)),
}


@pytest.mark.parametrize("case", list(TOML_CASES))
def test_g5_impossible_toml_robot(tmp_path, case):
    edits, append, names = TOML_CASES[case]
    robot = planar2_toml(tmp_path, *edits, append=append)
    before = fingerprint(robot)
    run = run_dynid("robot", "my.toml", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"my\.toml", *names)
    assert fingerprint(robot) == before


URDF_CASES = {
    "negative_mass": (dict(mass={2: -1.0}), (r"link_2", r"mass")),
    "inertia_not_positive_definite": (dict(inertia={2: dict(ixx=0.1, ixy=0.5, iyy=0.1, izz=0.1)}),
                                      (r"link_2", r"inertia")),
    "duplicate_link_names": (dict(duplicate_link=True), (r"link_1", (r"duplicate", r"twice"))),
    "mimic": (dict(joint_extra={2: '    <mimic joint="j1" multiplier="2"/>\n'}), (r"mimic",)),
    "lower_above_upper": (dict(limit={2: 'lower="1" upper="-1" effort="100" velocity="5"'}),
                          (r"\bj2\b", (r"lower", r"upper"))),
}


@pytest.mark.parametrize("case", list(URDF_CASES))
def test_g5_impossible_urdf_robot(tmp_path, case):
    kwargs, names = URDF_CASES[case]
    p = tmp_path / "arm.urdf"
    p.write_text(urdf_chain(2, **kwargs))
    run = run_dynid("robot", "arm.urdf", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"arm\.urdf", *names)


# =============================================================================================
# 6. Unbounded memory and hangs: fail fast, naming the option / file and the size
# =============================================================================================
def assert_fails_fast(run, *names, limit=30):
    assert_input_error(run, *names)
    assert run.elapsed < limit, f"took {run.elapsed:.1f} s to refuse\n{run}"
    assert re.search(r"\d", run.err), f"the message gives no size\n{run}"


@pytest.mark.slow          # reads /dev/zero up to the 4 GiB limit today: ~20 s
def test_g6_data_file_is_dev_zero(tmp_path):
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    run = run_dynid(*identify_args("zero.csv"), cwd=tmp_path, timeout=30)
    assert_input_error(run, r"zero\.csv")


def test_g6_robot_file_is_dev_zero(tmp_path):
    (tmp_path / "zero.toml").symlink_to("/dev/zero")
    run = run_dynid("robot", "zero.toml", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"zero\.toml")


def test_g6_fc_1e_minus_9(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--fc", "1e-9"), cwd=tmp_path, timeout=30)
    assert_fails_fast(run, r"--fc")


def test_g6_simulate_duration_1e9(tmp_path):
    run = run_dynid("simulate", "--robot", "planar2", "--duration", "1e9", "--out", "x.csv",
                    cwd=tmp_path, timeout=30)
    assert_fails_fast(run, r"--duration")
    assert not (tmp_path / "x.csv").exists()


def test_g6_controller_rate_1e9(tmp_path):
    planar2_toml(tmp_path, ("rate = 1000.0", "rate = 1e9"))
    run = run_dynid("simulate", "--robot", "my.toml", "--duration", "2", "--out", "x.csv",
                    cwd=tmp_path, timeout=30)
    assert_fails_fast(run, r"rate")


def test_g6_excite_harmonics_1e8(tmp_path):
    run = run_dynid("excite", "--robot", "planar2", "--f0", "0.1", "--harmonics", "100000000",
                    "--out", "e.csv", cwd=tmp_path, timeout=30)
    assert_fails_fast(run, r"--harmonics")


def test_g6_demo_duration_1e6(tmp_path):
    run = run_dynid("demo", "--duration", "1e6", "--report", "d.html", cwd=tmp_path, timeout=30)
    assert_fails_fast(run, r"--duration")
    assert not (tmp_path / "d.html").exists()


def test_g6_fifo_as_robot_file(tmp_path):
    os.mkfifo(tmp_path / "fifo.toml")
    run = run_dynid("robot", "fifo.toml", cwd=tmp_path, timeout=60)   # a hang is forever; 10 s failed on a loaded CI machine
    assert_input_error(run, r"fifo\.toml")


def test_g6_fifo_as_data_file(tmp_path):
    os.mkfifo(tmp_path / "fifo.csv")
    run = run_dynid(*identify_args("fifo.csv"), cwd=tmp_path, timeout=60)   # a hang is forever; 10 s failed on a loaded CI machine
    assert_input_error(run, r"fifo\.csv")


def test_g6_urdf_with_1000_joints(tmp_path):
    (tmp_path / "big.urdf").write_text(urdf_chain(1000, name="big"))
    run = run_dynid("robot", "big.urdf", "--quiet", cwd=tmp_path, timeout=30)
    assert_clean(run)
    if run.rc != 0:        # working quickly is fine too; otherwise a clear, fast refusal
        assert_fails_fast(run, r"big\.urdf")


# =============================================================================================
# 7. Bad input that is an internal error (exit 1) today
# =============================================================================================
def test_g7_negative_seed_simulate(tmp_path):
    run = run_dynid("simulate", "--robot", "planar2", "--duration", "2", "--seed", "-1",
                    "--out", "x.csv", cwd=tmp_path)
    assert_input_error(run, r"--seed")


def test_g7_negative_seed_excite(tmp_path):
    run = run_dynid("excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--starts", "1",
                    "--seed", "-1", "--out", "e.csv", cwd=tmp_path)
    assert_input_error(run, r"--seed")


def test_g7_negative_seed_sample(tmp_path, data):
    run = run_dynid("sample", "in.csv", "--robot", "planar2", "--seed", "-1", "--max-seconds", "5",
                    "--json", "p.json", cwd=tmp_path)
    assert_input_error(run, r"--seed")
    assert "loaded" not in run.err, f"--seed checked only after the identification\n{run}"


def test_g7_negative_seed_demo(tmp_path):
    run = run_dynid("demo", "--seed", "-1", "--duration", "2", "--skip", "didim,sample,diagnose",
                    "--report", "d.html", cwd=tmp_path)
    assert_input_error(run, r"--seed")


@pytest.mark.parametrize("value", ["nan", "inf", "1e-9"])
def test_g7_simulate_duration(tmp_path, value):
    run = run_dynid("simulate", "--robot", "planar2", "--duration", value, "--out", "x.csv",
                    cwd=tmp_path, timeout=30)
    assert_input_error(run, r"--duration")


@pytest.mark.parametrize("value", ["nan", "inf", "1e-9"])
def test_g7_demo_duration(tmp_path, value):
    run = run_dynid("demo", "--duration", value, "--report", "d.html", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"--duration")


def test_g7_controller_rate_1e_minus_6(tmp_path):
    planar2_toml(tmp_path, ("rate = 1000.0", "rate = 1e-6"))
    run = run_dynid("simulate", "--robot", "my.toml", "--duration", "2", "--out", "x.csv",
                    cwd=tmp_path, timeout=30)
    assert_input_error(run, r"rate")


def test_g7_qd_threshold_three_values_for_two_joints(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--qd-threshold", "1,2,3"), cwd=tmp_path)
    assert_input_error(run, r"--qd-threshold")


def test_g7_experiment_sampling_rate_1e308(tmp_path, frame):
    write_csv(tmp_path / "not.csv", frame.drop(columns=["t"]))
    (tmp_path / "exp.toml").write_text('[experiment]\nfile = "not.csv"\nsampling_rate = 1e308\n')
    run = run_dynid(*identify_args("exp.toml"), cwd=tmp_path)
    assert_input_error(run, r"sampling_rate")


def test_g7_nul_byte_in_data_file_name(tmp_path, data, capsys):
    run = run_in_process(capsys, *identify_args(str(tmp_path / "in\0.csv")))
    assert_input_error(run, r"in.{0,6}\.csv")


def test_g7_nul_byte_in_robot_file_name(tmp_path, capsys):
    run = run_in_process(capsys, "robot", str(tmp_path / "my\0.toml"))
    assert_input_error(run, r"my.{0,6}\.toml")


def test_g7_nul_byte_in_output_name(tmp_path, capsys):
    run = run_in_process(capsys, "robot", "planar2", "--json", str(tmp_path / "o\0.json"))
    assert_input_error(run, r"--json")
    assert_no_temp(tmp_path, run)


def test_g7_nul_byte_in_experiment_toml_file_key(tmp_path, data):
    (tmp_path / "exp.toml").write_text('[experiment]\nfile = "in\\u0000.csv"\n')
    run = run_dynid(*identify_args("exp.toml"), cwd=tmp_path)
    assert_input_error(run, r"exp\.toml")


def test_g7_nul_byte_in_robot_toml_urdf_key(tmp_path):
    (tmp_path / "my.toml").write_text('name = "x"\nurdf = "arm\\u0000.urdf"\n')
    run = run_dynid("robot", "my.toml", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"my\.toml", r"urdf")


def test_g7_robot_toml_nested_500_deep(tmp_path):
    (tmp_path / "my.toml").write_text('name = "x"\ngravity = ' + "[" * 500 + "]" * 500 + "\n")
    run = run_dynid("robot", "my.toml", cwd=tmp_path, timeout=30)
    assert_input_error(run, r"my\.toml")


def test_g7_experiment_toml_nested_500_deep(tmp_path, data):
    (tmp_path / "exp.toml").write_text('file = "in.csv"\nsampling_rate = ' + "[" * 500 + "]" * 500 + "\n")
    run = run_dynid(*identify_args("exp.toml"), cwd=tmp_path)
    assert_input_error(run, r"exp\.toml")


def test_g7_urdf_fixed_side_branch_of_3000_links(tmp_path):
    branch = []
    for k in range(1, 3001):
        branch.append(f'  <link name="f{k}"/>\n  <joint name="fj{k}" type="fixed">'
                      f'<parent link="{"link_1" if k == 1 else f"f{k - 1}"}"/><child link="f{k}"/>'
                      f'</joint>\n')
    (tmp_path / "arm.urdf").write_text(urdf_chain(2, extra="".join(branch)))
    run = run_dynid("robot", "arm.urdf", "--quiet", cwd=tmp_path, timeout=30)
    assert_clean(run)
    if run.rc != 0:        # a deep fixed branch is legal URDF: reading it is fine too
        assert_input_error(run, r"arm\.urdf")


def test_g7_json_to_stdout_closed_before_start(tmp_path):
    run = run_dynid("robot", "planar2", "--json", "-", cwd=tmp_path, timeout=30, close_stdout=True)
    assert_input_error(run, (r"stdout", r"standard output"))


def test_g7_json_to_stdout_pipe_closed_before_write(tmp_path):
    r, w = os.pipe()
    os.close(r)                         # nobody will ever read: the write gets EPIPE
    try:
        run = run_dynid("robot", "planar2", "--json", "-", cwd=tmp_path, timeout=30, stdout=w)
    finally:
        os.close(w)
    assert_input_error(run, (r"stdout", r"standard output", r"pipe"))


# =============================================================================================
# 8. Messages that point the wrong way
# =============================================================================================
def test_g8_torque_1e308_in_one_row(tmp_path, frame):
    frame.loc[500, "tau1"] = 1e308
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"tau1\b", (r"\brow\b", r"tau_max", r"large", r"1e\+?308"))
    if run.rc == 2:
        assert _has(run.err, (r"\brow\b", r"line")), f"the message does not give the row\n{run}"


def test_g8_all_zero_torque(tmp_path, frame):
    frame[["tau1", "tau2"]] = 0.0
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_notice_or_error(run, r"tau[12]?\b", (r"zero", r"all 0", r"constant"))
    if run.rc == 2:
        assert _has(run.err, (r"zero", r"all 0", r"constant")), f"does not say the torques are zero\n{run}"


def test_g8_drive_gain_zero_in_experiment_toml(tmp_path, frame):
    frame = frame.rename(columns={"tau1": "i1", "tau2": "i2"})
    write_csv(tmp_path / "cur.csv", frame)
    (tmp_path / "exp.toml").write_text(
        '[experiment]\nfile = "cur.csv"\n[time]\ncolumn = "t"\n'
        '[positions]\ncolumns = ["q1", "q2"]\n'
        '[currents]\ncolumns = ["i1", "i2"]\ndrive_gains = [0.0, 1.0]\n')
    run = run_dynid(*identify_args("exp.toml"), cwd=tmp_path)
    assert_input_error(run, r"exp\.toml", r"drive_gains")


def test_g8_drive_gain_zero_in_robot_toml(tmp_path, frame):
    frame = frame.rename(columns={"tau1": "i1", "tau2": "i2"})
    write_csv(tmp_path / "cur.csv", frame)
    planar2_toml(tmp_path, ("tau_max = 200.0", "tau_max = 200.0\ndrive_gain = 0.0"))
    run = run_dynid("identify", "cur.csv", "--robot", "my.toml", cwd=tmp_path)
    assert_input_error(run, r"my\.toml", r"drive_gain")


def test_g8_zero_position_scale_in_experiment_toml(tmp_path, data):
    (tmp_path / "exp.toml").write_text(
        '[experiment]\nfile = "in.csv"\n[time]\ncolumn = "t"\n'
        '[positions]\ncolumns = ["q1", "q2"]\nscale = 0\n'
        '[torques]\ncolumns = ["tau1", "tau2"]\n')
    run = run_dynid(*identify_args("exp.toml"), cwd=tmp_path)
    assert_input_error(run, r"exp\.toml", r"scale")


def test_g8_csv_renamed_npz(tmp_path, data):
    shutil.copyfile(data, tmp_path / "run.npz")
    run = run_dynid(*identify_args("run.npz"), cwd=tmp_path)
    assert_input_error(run, r"run\.npz")
    assert "pickle" not in run.err, f"suggests unpickling a file of unknown origin\n{run}"
    assert _has(run.err, (r"\bCSV\b", r"text", r"\.csv")), f"does not say it looks like a CSV\n{run}"


def test_g8_qd_threshold_above_every_speed(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--qd-threshold", "1e9"), cwd=tmp_path)
    assert_input_error(run, r"--qd-threshold")


# =============================================================================================
# 9. Terminal escape injection
# =============================================================================================
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f\x80-\x9f]")


def test_g9_escape_sequences_in_the_robot_name(tmp_path):
    planar2_toml(tmp_path, ('name = "planar2"', r'name = "\u001b]0;TITLE\u0007\u001b[2J"'))
    run = run_dynid("robot", "my.toml", cwd=tmp_path, timeout=30)
    assert_clean(run)
    assert run.rc in (0, 2), str(run)
    for stream, text in (("stdout", run.out), ("stderr", run.err)):
        bad = sorted(set(CONTROL.findall(text)))
        assert not bad, f"control characters {bad!r} printed on {stream}\n{run!r}"


def test_g9_escape_sequences_in_a_column_name(tmp_path, frame):
    frame["\x1b]0;TITLE\x07\x1b[2J"] = 1.0
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_clean(run)
    assert run.rc in (0, 2), str(run)
    for stream, text in (("stdout", run.out), ("stderr", run.err)):
        bad = sorted(set(CONTROL.findall(text)))
        assert not bad, f"control characters {bad!r} printed on {stream}\n{run!r}"


# =============================================================================================
# 10. Issue 31: the fleet and the newer options (groups g10 data loss ... g14 messages)
# =============================================================================================
_VICTIM = """
import os, sys, time
import dynid.outputs as outputs
folder, ready, go = sys.argv[1:4]
real_replace = os.replace
calls = []
def paused_replace(src, dst):
    calls.append(dst)
    if len(calls) == 2:             # the first output renamed, the second not yet: the backups matter now
        open(ready, "w").close()
        t0 = time.time()
        while not os.path.exists(go) and time.time() - t0 < 30:
            time.sleep(0.02)
    return real_replace(src, dst)
os.replace = paused_replace
try:
    outputs.write_all([(os.path.join(folder, "a.json"), "new json"), (os.path.join(folder, "a.csv"), "new csv")])
except Exception as exc:
    print(f"victim: {exc}", file=sys.stderr)
    sys.exit(3)
"""

_CLEANER = """
import os, sys
import dynid.outputs as outputs
outputs.write_all([(os.path.join(sys.argv[1], "c.txt"), "another run")])
"""


def _unshare_available():
    if shutil.which("unshare") is None:
        return False
    try:
        return subprocess.run(["unshare", "--pid", "--fork", "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def test_g10_commit_survives_a_writer_in_another_pid_namespace(tmp_path):
    """Two dynid processes in two PID namespaces write into one folder (two containers on a
    shared volume): the second must not take the first's backups for a dead process's."""
    if not _unshare_available():
        pytest.skip("unshare --pid is not available (needs root or user namespaces)")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.json").write_text("old json")
    (out / "a.csv").write_text("old csv")
    ready, go = tmp_path / "ready", tmp_path / "go"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    # sh stays pid 1 of the victim's namespace, Python is pid 2: a pid that the cleaner's own
    # namespace (where it is pid 1, alone) does not have
    victim = subprocess.Popen(["unshare", "--pid", "--fork", "sh", "-c", '"$0" -c "$1" "$2" "$3" "$4"; exit $?',
                               sys.executable, _VICTIM, str(out), str(ready), str(go)],
                              env=env, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not ready.exists():
            assert victim.poll() is None, f"the writer ended early: {victim.stderr.read()}"
            assert time.time() - t0 < 60, "the writer never reached its second rename"
            time.sleep(0.02)
        cleaner = subprocess.run(["unshare", "--pid", "--fork", sys.executable, "-c", _CLEANER, str(out)],
                                 env=env, capture_output=True, text=True, timeout=60)
        assert cleaner.returncode == 0, cleaner.stderr
    finally:
        go.touch()
        _, err = victim.communicate(timeout=60)
    contents = ((out / "a.json").read_text(), (out / "a.csv").read_text())
    assert contents in (("new json", "new csv"), ("old json", "old csv")), (
        f"all-or-none broken by the other process: a.json={contents[0]!r}, a.csv={contents[1]!r}; {err}")
    assert victim.returncode == 0 and contents == ("new json", "new csv"), (
        f"the writer failed (exit {victim.returncode}): {err}")
    assert (out / "c.txt").read_text() == "another run"
    assert_no_temp(out)


# ---- g10: data loss in the fleet ------------------------------------------------------------
def fleet_catalogue(folder, recording, n=2, robot="planar2", extra_rows="", temperature=None):
    """`cat.csv` listing `n` recordings: `recording` less its last k rows (distinct files, not copies)."""
    folder = Path(folder)
    lines = ["robot_id,timestamp,path,robot" + (",temperature" if temperature is not None else "")]
    for k in range(n):
        rec = folder / f"rec{k}.csv"
        rec.write_text("".join(recording.read_text().splitlines(keepends=True)[:-(k + 1)]))
        lines.append(f"R1,2026-03-0{k + 1}T08:00:00Z,{rec.name},{robot}"
                     + (f",{temperature}" if temperature is not None else ""))
    cat = folder / "cat.csv"
    cat.write_text("\n".join(lines) + "\n" + extra_rows)
    return cat


def fleet_inputs(folder):
    """Fingerprints of every file of the fleet's folder (the catalogue, recordings, robot files)."""
    return fingerprint(*[p for p in sorted(Path(folder).iterdir()) if p.is_file() and not DYNID_TEMP.match(p.name)])


def assert_fleet_refused(run, before, folder, *names):
    assert_input_error(run, *names)
    assert fleet_inputs(folder) == before, f"an input changed\n{run}"
    assert not (Path(folder) / "store").exists(), f"the store was created before the refusal\n{run}"


@pytest.mark.parametrize("option", ["--json", "--report"])
def test_g10_fleet_output_onto_its_catalogue(tmp_path, recording, option):
    fleet_catalogue(tmp_path, recording)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", option, "cat.csv", cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, "cat.csv", "catalogue")


@pytest.mark.parametrize("how", ["symlink", "hardlink", "dotdot"])
def test_g10_fleet_output_onto_a_recording_or_robot_file(tmp_path, recording, how):
    robot = planar2_toml(tmp_path, name="arm.toml")
    fleet_catalogue(tmp_path, recording, robot=robot.name)
    (tmp_path / "sub").mkdir()
    if how == "symlink":
        os.symlink(tmp_path / "rec1.csv", tmp_path / "sub" / "out.json")
        args, names = ("--json", "sub/out.json"), ("rec1.csv", "recording")
    elif how == "hardlink":
        os.link(robot, tmp_path / "sub" / "out.html")
        args, names = ("--report", "sub/out.html"), ("arm.toml", "robot file")
    else:
        args, names = ("--json", "sub/../rec0.csv"), ("rec0.csv", "recording")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", *args, cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, *names)


def test_g10_python_fleet_run_refuses_too(tmp_path, recording):
    import dynid.fleet
    from dynid.errors import InputError
    cat = fleet_catalogue(tmp_path, recording)
    before = fleet_inputs(tmp_path)
    with pytest.raises(InputError, match="rec0.csv.*recording"):
        dynid.fleet.run(cat, tmp_path / "store", report=tmp_path / "rec0.csv")
    assert fleet_inputs(tmp_path) == before and not (tmp_path / "store").exists()


@pytest.mark.parametrize("value,why", [("", "empty"), ("x.json/", "folder")])
def test_g10_json_name_that_writes_nothing_or_elsewhere(tmp_path, data, value, why):
    run = run_dynid(*identify_args("in.csv", "--json", value), cwd=tmp_path)
    assert_input_error(run, "--json", why)
    assert not (tmp_path / "x.json").exists(), f"wrote x.json for --json x.json/\n{run}"


def test_g10_json_to_closed_stdout_is_refused(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--json", "-"), cwd=tmp_path, close_stdout=True)
    assert_input_error(run, "--json", "stdout")


# ---- g11: silently wrong fleet values -------------------------------------------------------
def test_g11_fleet_same_recording_through_a_symlink(tmp_path, recording):
    os.symlink("rec0.csv", tmp_path / "alias.csv")
    fleet_catalogue(tmp_path, recording, extra_rows="R1,2026-03-09T08:00:00Z,alias.csv,planar2\n")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, "cat.csv", "row 3", "alias.csv|rec0.csv", "once")


def test_g11_fleet_byte_identical_copy_of_a_recording(tmp_path, recording):
    fleet_catalogue(tmp_path, recording, extra_rows="R2,2026-03-09T08:00:00Z,copy.csv,planar2\n")
    shutil.copyfile(tmp_path / "rec1.csv", tmp_path / "copy.csv")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, "copy.csv", "rec1.csv", "same bytes")


@pytest.mark.parametrize("option,value", [("--false-alarm-rate", "0"), ("--false-alarm-rate", "nan"),
                                          ("--baseline", "0"), ("--baseline", "1000000000")])
def test_g11_fleet_monitoring_option_out_of_range(tmp_path, recording, option, value):
    fleet_catalogue(tmp_path, recording)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", option, value, cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, option)


@pytest.mark.parametrize("value", ["inf", "1e308", "-300"])
def test_g11_fleet_temperature_out_of_range(tmp_path, recording, value):
    fleet_catalogue(tmp_path, recording, temperature=value)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", cwd=tmp_path, timeout=60)
    assert_fleet_refused(run, before, tmp_path, "cat.csv", "column temperature, row 1", "Celsius")


def test_g11_fleet_failed_recordings_fail_the_run(tmp_path, recording):
    """Every recording broken: exit 2, counted as failed (not identified), no TypeError from the monitor."""
    fleet_catalogue(tmp_path, recording, robot="panda")          # 7 joints: the 2-joint data cannot fit
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--workers", "1", "--json", "f.json",
                    "--report", "f.html", cwd=tmp_path, timeout=180)
    assert_input_error(run, "2 of 2 recordings could not be identified")
    assert "0 identified" in run.out and "not monitored" in run.out, run     # the summary: stdout
    after = fleet_inputs(tmp_path)
    assert {p: after.get(p) for p in before} == before, "an input changed"
    doc = json.loads((tmp_path / "f.json").read_text())
    assert doc["n_failed"] == 2 and doc["n_identified"] == 0
    assert "Recordings that failed" in (tmp_path / "f.html").read_text()


def test_g11_torques_in_kNm(tmp_path, frame):
    frame[["tau1", "tau2"]] /= 1000.0
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    assert_input_error(run, "in.csv", r"tau[12]", "kN·m")
    assert not (tmp_path / "o.json").exists()


def _toml_of_npz(folder, name="rec.npz", **options):
    lines = ["[experiment]", f'file = "{name}"'] + [f"{k} = {v}" for k, v in options.items()]
    lines += ["[time]", 'key = "t"', "[positions]", 'key = "q"', "[torques]", 'key = "tau"']
    p = Path(folder) / "exp.toml"
    p.write_text("\n".join(lines) + "\n")
    return p


def _npz_from(frame, path, t=None):
    np.savez(path, t=frame["t"].to_numpy() if t is None else t, q=frame[["q1", "q2"]].to_numpy(),
             tau=frame[["tau1", "tau2"]].to_numpy())


def test_g11_time_tolerance_1e9_is_refused(tmp_path, frame):
    t = frame["t"].to_numpy().copy()
    t[len(t) // 2:] += 0.1                                   # a 100 ms gap
    _npz_from(frame, tmp_path / "rec.npz", t)
    _toml_of_npz(tmp_path, time_tolerance="1e9")
    run = run_dynid(*identify_args("exp.toml", "--json", "o.json"), cwd=tmp_path)
    assert_input_error(run, "exp.toml", "time_tolerance", "0.25")
    assert not (tmp_path / "o.json").exists()


# ---- g12: hangs and unbounded memory --------------------------------------------------------
@pytest.mark.parametrize("kind", ["fifo", "dev_zero"])
def test_g12_fleet_recording_that_is_not_a_regular_file(tmp_path, recording, kind):
    cat = fleet_catalogue(tmp_path, recording, n=1)
    if kind == "fifo":
        os.mkfifo(tmp_path / "special.csv")
        target = "special.csv"
    else:
        target = "/dev/zero"
    cat.write_text(cat.read_text() + f"R1,2026-03-05T08:00:00Z,{target},planar2\n")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", cwd=tmp_path, timeout=30)
    assert_fleet_refused(run, before, tmp_path, "cat.csv", "row 2", target, "not a regular file")


def test_g12_experiment_toml_over_the_size_cap(tmp_path, data):
    p = tmp_path / "exp.toml"
    with open(p, "w") as fh:
        fh.write('[experiment]\nfile = "in.csv"\nname = "')
        fh.write("x" * (2 << 20))
        fh.write('"\n')
    run = run_dynid(*identify_args("exp.toml", "--json", "o.json"), cwd=tmp_path, timeout=30)
    assert_input_error(run, "exp.toml", "MiB")
    assert not (tmp_path / "o.json").exists()


def test_g12_npz_zip_bomb_is_refused_before_loading(tmp_path):
    import zipfile
    n = 10_000_000                                            # 80 MB of zeros per member, ~80 kB compressed
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        for name, shape in (("t", (n,)), ("q", (n // 2, 2)), ("tau", (n // 2, 2))):
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": shape})
                block = bytes(1 << 20)
                for _ in range(8 * n // len(block)):
                    fh.write(block)
    run = run_dynid(*identify_args("bomb.npz", "--json", "o.json"), cwd=tmp_path, timeout=60)
    assert_input_error(run, "bomb.npz", "zip bomb|expand")
    assert not (tmp_path / "o.json").exists()


def test_g12_npz_with_a_forged_shape_is_refused(tmp_path):
    import io
    import zipfile
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.zeros(10))
    forged = buf.getvalue().replace(b"(10,)", b"(10000000000,)")
    with zipfile.ZipFile(tmp_path / "forged.npz", "w") as zf:
        for name in ("t", "q", "tau"):
            zf.writestr(f"{name}.npy", forged)
    run = run_dynid(*identify_args("forged.npz", "--json", "o.json"), cwd=tmp_path, timeout=60)
    assert_input_error(run, "forged.npz", "declares shape")


def test_g12_resampling_across_a_huge_gap_is_refused(tmp_path, frame):
    t = frame["t"].to_numpy().copy()
    t[len(t) // 2:] += 1e5                                   # a day-long gap: 1e8 grid points at 1 ms
    t[3] += 0.3 * (t[4] - t[3])                              # irregular, so that it resamples
    _npz_from(frame, tmp_path / "rec.npz", t)
    _toml_of_npz(tmp_path, resample="true")
    run = run_dynid(*identify_args("exp.toml", "--json", "o.json"), cwd=tmp_path, timeout=60)
    assert_input_error(run, "rec.npz", "gap", "Split the recording")
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("args,option", [
    (("--nd", "10000000000"), "--nd"), (("--nd", "100000000"), "--nd"),
    (("--method", "didim", "--v-s", "1e-9"), "--v-s"),
    (("--physical", "--bootstrap", "1000000000"), "--bootstrap")])
def test_g12_option_far_out_of_range_is_refused_fast(tmp_path, data, args, option):
    run = run_dynid(*identify_args("in.csv", *args, "--json", "o.json"), cwd=tmp_path, timeout=60)
    assert_input_error(run, option, "out of range")
    assert run.elapsed < 30, f"took {run.elapsed:.0f} s to refuse\n{run}"
    assert not (tmp_path / "o.json").exists()


# ---- g13: tracebacks and internal errors ----------------------------------------------------
@pytest.mark.parametrize("args,option", [
    (("--physical", "--prior", "apriori", "--prior-weight", "1e300"), "--prior-weight"),
    (("--method", "didim", "--v-s", "1e-300"), "--v-s")])
def test_g13_extreme_option_is_an_input_error_not_a_crash(tmp_path, data, args, option):
    run = run_dynid(*identify_args("in.csv", *args, "--json", "o.json"), cwd=tmp_path, timeout=120)
    assert_input_error(run, option)
    assert not (tmp_path / "o.json").exists()


def test_g13_python_api_refuses_the_same_ranges():
    from dynid.errors import InputError
    from dynid.ranges import check_range
    for name, bad in (("nd", 10**10), ("n_boot", 10**9), ("v_s", 1e-300), ("prior_weight", 1e300),
                      ("v_s", float("nan")), ("nd", 2.5)):
        with pytest.raises(InputError, match="out of range"):
            check_range(name, bad)


def test_g13_fleet_scheduler_that_is_not_an_address(tmp_path, recording):
    fleet_catalogue(tmp_path, recording, n=1)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--scheduler", "not a url", cwd=tmp_path, timeout=60)
    assert_input_error(run, "--scheduler", "not a url")
    assert fleet_inputs(tmp_path) == before


def test_g13_fleet_store_under_a_file(tmp_path, recording):
    fleet_catalogue(tmp_path, recording, n=1)
    (tmp_path / "afile").write_text("x")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "afile/store", cwd=tmp_path, timeout=60)
    assert_input_error(run, "--out", "afile/store", "cannot be written")
    assert fleet_inputs(tmp_path) == before


def test_g13_fleet_store_on_a_read_only_file_system(tmp_path, recording):
    """A read-only mount (root, a private mount namespace): one message, no Dask traceback."""
    if not _unshare_available() or subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode:
        pytest.skip("unshare -m is not available")
    fleet_catalogue(tmp_path, recording, n=1)
    (tmp_path / "ro").mkdir()
    before = fleet_inputs(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = 'mount --bind -o ro ro ro && exec "$0" -c "$1" fleet cat.csv --out ro/store'
    res = subprocess.run(["unshare", "-m", "sh", "-c", cmd, sys.executable, DYNID_CODE], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "ro/store" in res.stderr and "Read-only" in res.stderr, res.stderr
    assert fleet_inputs(tmp_path) == before


# ---- g14: advice the user can follow from where they are -----------------------------------
def test_g14_motionless_recording_gives_command_line_advice(tmp_path, frame):
    frame[["q1", "q2"]] = 0.1                     # no motion: the bandwidth cannot be estimated
    frame = frame.drop(columns=["qr1", "qr2"])
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path)
    if run.rc == 2 and "bandwidth" in run.err:
        assert_input_error(run, "bandwidth", "command line")
    else:                                        # refused earlier (no motion at all): still clean
        assert_input_error(run, "in.csv|q1|motion|move")
    assert not (tmp_path / "o.json").exists()


def test_g10_fleet_json_to_closed_stdout_is_refused_first(tmp_path, recording):
    fleet_catalogue(tmp_path, recording, n=1)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--json", "-", cwd=tmp_path, close_stdout=True,
                    timeout=60)
    assert_fleet_refused(run, before, tmp_path, "--json", "stdout")


def test_g11_python_fleet_options_refused_before_work(tmp_path, recording):
    import dynid.fleet
    from dynid.errors import InputError
    cat = fleet_catalogue(tmp_path, recording)
    before = fleet_inputs(tmp_path)
    for kwargs, name in (({"false_alarm_rate": 0}, "false_alarm_rate"), ({"n_baseline": 0}, "n_baseline"),
                         ({"n_baseline": 10**9}, "n_baseline"), ({"parameters": "Fv"}, "parameters")):
        with pytest.raises(InputError, match=name):
            dynid.fleet.run(cat, tmp_path / "store", **kwargs)
    assert fleet_inputs(tmp_path) == before and not (tmp_path / "store").exists()


def test_g10_check_outputs_sees_hard_links_and_dotdot(tmp_path):
    from dynid.errors import InputError
    from dynid.outputs import check_outputs
    src = tmp_path / "in.csv"
    src.write_text("t\n0\n")
    (tmp_path / "d").mkdir()
    os.link(src, tmp_path / "d" / "hard.json")
    for out in (tmp_path / "d" / "hard.json", tmp_path / "d" / ".." / "in.csv"):
        with pytest.raises(InputError, match="in.csv"):
            check_outputs([("--json", out)], [("the data file", src)])
    with pytest.raises(InputError, match="same file"):
        check_outputs([("--json", tmp_path / "a.json"), ("--report", tmp_path / "d" / ".." / "a.json")])
    check_outputs([("--json", tmp_path / "new.json")], [("the data file", src)])     # a fresh name passes
    assert src.read_text() == "t\n0\n"


# =============================================================================================
# Issue 31, the rest: several data files after --robot, interruption of compiled loops, the
# orchestrator's ranges in Python, advice (ML, rank deficiency), the documented store reader,
# robot files and fleet options through the command line
# =============================================================================================
def _serial_fleet_store(folder, recording):
    """A fleet results store of 2 recordings, each identified in this process (no Dask)."""
    from dynid.analysis.fleet.engine import plan
    from dynid.analysis.fleet.store import ResultStore
    from dynid.analysis.fleet.task import identify_recording
    cat = fleet_catalogue(folder, recording)
    store = ResultStore(Path(folder) / "store")
    specs, _ = plan(str(cat), store)
    for spec in specs:
        store.write(identify_recording(spec))
    return store


def _documented_store_readers():
    """The reader lines of docs/formats.md's "Fleet store" section, as written there."""
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    section = text[text.index("## Fleet store"):]
    section = section[:section.index("\n## ", 5)] if "\n## " in section[5:] else section
    return sorted(set(re.findall(r"`([a-z_.]+\(STORE[^`]*\)[^`]*)`", section)))


def test_g14_documented_store_readers_work(tmp_path, recording):
    """The docs said `pandas.read_parquet(STORE)` works; it failed with ArrowTypeError (the folder
    names repeat columns the files hold). Every reader line the docs give is run as written."""
    pytest.importorskip("pyarrow")
    import pyarrow.dataset  # noqa: F401  (the namespace the documented line names)

    import dynid
    import dynid.fleet
    store = _serial_fleet_store(tmp_path, recording)
    expected = store.read()
    lines = _documented_store_readers()
    assert any(line.startswith("pandas.read_parquet(") for line in lines), lines
    names = {"pandas": pd, "pyarrow": sys.modules["pyarrow"], "dynid": dynid, "STORE": str(store.root)}
    for line in lines:
        got = eval(line, names)                                 # noqa: S307 - the docs' own line
        got = got.to_pandas() if hasattr(got, "to_pandas") else got
        assert len(got) == len(expected) and set(expected.columns) <= set(got.columns), line
        assert sorted(got["robot_id"].astype(str)) == sorted(expected["robot_id"].astype(str)), line


def test_g14_several_data_files_after_the_robot_option(tmp_path, recording):
    """`dynid identify a.csv --robot planar2 b.csv` was "unrecognized arguments": both are identified."""
    lines = recording.read_text().splitlines(keepends=True)
    half = len(lines) // 2
    (tmp_path / "a.csv").write_text("".join(lines[:half]))
    (tmp_path / "b.csv").write_text("".join(lines[:1] + lines[half:]))
    before = fingerprint(tmp_path / "a.csv", tmp_path / "b.csv")
    run = run_dynid("identify", "a.csv", "--robot", "planar2", "b.csv", "--json", "o.json", cwd=tmp_path,
                    timeout=120)
    assert_clean(run)
    assert run.rc == 0, str(run)
    doc = json.loads((tmp_path / "o.json").read_text())
    sources = json.dumps(doc)
    assert "a.csv" in sources and "b.csv" in sources, "one of the two recordings is missing from the JSON"
    assert fingerprint(tmp_path / "a.csv", tmp_path / "b.csv") == before


def test_g14_unknown_option_after_the_data_is_still_refused(tmp_path, data):
    run = run_dynid(*identify_args("in.csv", "--no-such-option", "3", "--json", "o.json"), cwd=tmp_path)
    assert_input_error(run, "--no-such-option")
    assert not (tmp_path / "o.json").exists()


def _signal_when(proc, marker, sig, timeout=120.0):
    """Send `sig` to proc 1 s after a stderr line holds `marker` (inside the compiled loop by
    then); returns (stderr text, seconds to exit)."""
    return signal_when(proc, marker, lambda: proc.send_signal(sig), settle=1.0, timeout=timeout)


@pytest.mark.parametrize("sig", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_g12_long_compiled_simulation_stops_on_a_signal(tmp_path, sig):
    """A long closed-loop simulation (compiled, it ran no Python signal handler: `--v-s 1e-9` ignored
    SIGTERM for over 90 s) stops at once with exit 130 and writes nothing."""
    cmd = [sys.executable, "-c", DYNID_CODE.replace("main(sys.argv[1:])", "main()"), "simulate", "--robot",
           "tx40", "--duration", "3000", "--out", "run.csv", "--json", "run.json"]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    err, seconds = _signal_when(proc, "simulating", sig)
    assert proc.returncode == 130, f"exit {proc.returncode}\n{err}"
    assert "interrupted" in err and "Traceback" not in err, err
    assert seconds < 20, f"{seconds:.1f} s from the signal to the exit\n{err}"
    assert sorted(os.listdir(tmp_path)) == [], "partial output or temporary files left"


@pytest.mark.parametrize("options,name", [
    ({"bootstrap": 10**9, "physical": True}, "bootstrap"), ({"prior_weight": 1e300}, "prior_weight"),
    ({"method": "didim", "v_s": 1e-300}, "v_s"), ({"nd": 10**10}, "nd"), ({"holdout": float("inf")}, "holdout"),
    ({"alpha": 1.5}, "alpha"), ({"max_iter": 0, "method": "didim"}, "max_iter")])
def test_g13_python_api_checks_every_option_before_work(tmp_path, data, options, name):
    """dynid.identify / dynid.run refuse out-of-range options as the command line does, naming both
    spellings, before the data is even read (a file that does not exist is not reached)."""
    import dynid
    from dynid.errors import InputError
    before = fingerprint(data)
    calls = (dynid.run,) + ((dynid.identify,) if name not in ("holdout", "alpha") else ())   # identify's keywords
    for call in calls:
        with pytest.raises(InputError, match=rf"\({name}=\).*out of range"):
            call(tmp_path / "no-such-file.csv", "planar2", **options)
    assert fingerprint(data) == before and sorted(os.listdir(tmp_path)) == ["in.csv"]


@pytest.mark.slow
@pytest.mark.parametrize("args,option", [(("--alpha", "0"), "--alpha"), (("--max-effects", "1000"), "--max-effects")])
def test_g12_diagnose_option_out_of_range(tmp_path, data, args, option):
    run = run_dynid("diagnose", "in.csv", "--robot", "planar2", *args, "--json", "o.json", cwd=tmp_path)
    assert_input_error(run, option, "out of range")
    assert not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_g14_maximum_likelihood_advice_is_a_longer_recording(tmp_path, frame):
    """ML with too few usable equations once advised "lower the dead zone" (wrong: the guard
    around velocity reversals takes them); the advice now is a longer recording or IDIM, with
    the command line's flag."""
    write_csv(tmp_path / "in.csv", frame.iloc[:len(frame) // 4])
    before = fingerprint(tmp_path / "in.csv")
    run = run_dynid(*identify_args("in.csv", "--method", "ml", "--f0", "0.1", "--ml-harmonics", "3",
                                   "--json", "o.json"), cwd=tmp_path, timeout=120)
    assert_input_error(run, "maximum likelihood", "longer recording", "--method idim")
    assert "dead zone" not in run.err.split("need")[-1], f"advises a dead-zone change again\n{run}"
    assert "lower the" not in run.err, str(run)
    assert fingerprint(tmp_path / "in.csv") == before and not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_g14_too_many_harmonics_names_the_flag(tmp_path, frame):
    write_csv(tmp_path / "in.csv", frame)
    run = run_dynid(*identify_args("in.csv", "--method", "ml", "--f0", "0.1", "--json", "o.json"), cwd=tmp_path,
                    timeout=120)
    if run.rc == 2 and "harmonics" in run.err:
        assert_input_error(run, "--ml-harmonics")
        assert "n_harmonics" not in run.err.replace("n_harmonics=", ""), str(run)
    else:
        assert_clean(run)
    if run.rc != 0:
        assert not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_g14_rank_deficiency_advice_can_be_followed_on_the_command_line(tmp_path, frame):
    """A joint that moves one way only aliases its offset with its Coulomb friction: the advice is
    a richer trajectory (not "use base parameters", which the command line always does)."""
    frame = frame.copy()
    frame["q2"] = np.linspace(0.0, 1.0, len(frame))           # joint 2 only ever moves forward
    write_csv(tmp_path / "in.csv", frame.drop(columns=["qr1", "qr2"]))
    run = run_dynid(*identify_args("in.csv", "--json", "o.json"), cwd=tmp_path, timeout=120)
    if run.rc == 2 and "rank-deficient" in run.err:
        assert_input_error(run, "richer trajectory", "joint 2")
        assert "use base parameters" not in run.err, str(run)
    else:
        assert_clean(run)


@pytest.mark.parametrize("value,names", [("90.0", ("my.toml", "alpha", "degrees")),
                                         pytest.param("1e154", ("my.toml", "alpha", "radians"),
                                                      marks=pytest.mark.slow)])
def test_g11_robot_file_angles_in_degrees_through_the_cli(tmp_path, data, value, names):
    robot = planar2_toml(tmp_path, ("d = 1.0", f"d = 1.0\nalpha = {value}"))
    before = fingerprint(robot, data)
    run = run_dynid("identify", "in.csv", "--robot", "my.toml", "--json", "o.json", cwd=tmp_path)
    assert_input_error(run, *names)
    assert fingerprint(robot, data) == before and not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_g11_negative_pid_ki_through_the_cli(tmp_path):
    text = PLANAR2.read_text(encoding="utf-8")
    m = re.search(r"(?m)^kind\s*=\s*\"pd\"", text)
    if m is None:
        pytest.skip("planar2.toml's controller is not a PD")
    robot = planar2_toml(tmp_path, (m.group(0), 'kind = "pid"\nki = [1.0, -5.0]'))
    before = fingerprint(robot)
    run = run_dynid("simulate", "--robot", "my.toml", "--duration", "1", "--out", "o.csv", cwd=tmp_path)
    assert_input_error(run, "my.toml", "ki", "negative")
    assert fingerprint(robot) == before and not (tmp_path / "o.csv").exists()


@pytest.mark.slow
def test_g11_excite_limits_of_1e300_are_refused(tmp_path):
    text = PLANAR2.read_text(encoding="utf-8")
    m = re.search(r"(?m)^tau_max\s*=\s*[0-9.eE+-]+", text)
    if m is None:
        pytest.skip("planar2.toml has no tau_max line")
    robot = planar2_toml(tmp_path, (m.group(0), "tau_max = 1e300"))
    before = fingerprint(robot)
    run = run_dynid("excite", "--robot", "my.toml", "--f0", "0.2", "--harmonics", "3", "--out", "o.csv",
                    cwd=tmp_path)
    assert_input_error(run, "my.toml", "tau_max")
    assert fingerprint(robot) == before and not (tmp_path / "o.csv").exists()


@pytest.mark.slow
def test_g13_fleet_unknown_parameter_name(tmp_path, recording):
    """An unknown --parameters name crashed the monitor (TypeError); now exit 2 naming it."""
    fleet_catalogue(tmp_path, recording, n=1)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--workers", "1", "--parameters", "Xyz",
                    "--json", "f.json", cwd=tmp_path, timeout=180)
    assert_input_error(run, "--parameters", "Xyz")
    after = fleet_inputs(tmp_path)
    assert {p: after.get(p) for p in before} == before and not (tmp_path / "f.json").exists()


@pytest.mark.slow
def test_g11_fleet_partial_failure_exits_2_and_counts_it(tmp_path, recording):
    """One recording good, one broken: exit 2, 1 identified and 1 failed (it said "2 identified", exit 0);
    the failed file is named even with --quiet (a scheduled run)."""
    fleet_catalogue(tmp_path, recording)
    (tmp_path / "rec1.csv").write_text("t,q1\n0,garbage\n")
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--workers", "1", "--json", "f.json", "--quiet",
                    cwd=tmp_path, timeout=300)
    assert_input_error(run, "1 of 2 recordings could not be identified", "rec1.csv")
    after = fleet_inputs(tmp_path)
    assert {p: after.get(p) for p in before} == before, "an input changed"
    doc = json.loads((tmp_path / "f.json").read_text())
    assert doc["n_failed"] == 1 and doc["n_identified"] == 1


@pytest.mark.slow
def test_g12_excite_starts_far_out_of_range(tmp_path):
    run = run_dynid("excite", "--robot", "planar2", "--f0", "0.2", "--harmonics", "3", "--starts", "1000000000",
                    "--out", "o.csv", cwd=tmp_path)
    assert_input_error(run, "--starts", "out of range")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.slow
def test_g12_fleet_workers_far_out_of_range(tmp_path, recording):
    fleet_catalogue(tmp_path, recording, n=1)
    before = fleet_inputs(tmp_path)
    run = run_dynid("fleet", "cat.csv", "--out", "store", "--workers", "1000000", cwd=tmp_path)
    assert_fleet_refused(run, before, tmp_path, "--workers", "out of range")


@pytest.mark.slow
def test_g11_simulate_says_what_it_leaves_out(tmp_path):
    """A robot file without friction or rotor inertia (a URDF's, typically) was simulated with zero
    friction and rotor inertia without a word (issue 29): the run says so, and so does its JSON."""
    robot = planar2_toml(tmp_path, (", Ia1 = 0.05, Ia2 = 0.05, Fv1 = 0.5, Fv2 = 0.3, Fc1 = 1.0, Fc2 = 0.5",
                                    ", Fv2 = 0.3"))
    before = fingerprint(robot)
    run = run_dynid("simulate", "--robot", "my.toml", "--duration", "1", "--out", "o.csv", "--json", "o.json",
                    cwd=tmp_path)
    assert_clean(run)
    assert run.rc == 0, str(run)
    assert _has(run.err, "without friction on joint 1") and _has(run.err, "without rotor inertia"), str(run)
    assert not _has(run.err, "joint 1, 2|joints 1"), str(run)
    notices = json.loads((tmp_path / "o.json").read_text())["notices"]
    assert any("friction" in n for n in notices) and any("rotor inertia" in n for n in notices)
    assert fingerprint(robot) == before
    full = run_dynid("simulate", "--robot", "planar2", "--duration", "1", "--out", "p.csv", "--json", "p.json",
                     cwd=tmp_path)
    assert full.rc == 0 and "without" not in full.err, str(full)
    notices = json.loads((tmp_path / "p.json").read_text())["notices"]
    assert not any("friction" in n or "rotor inertia" in n for n in notices), notices   # left nothing out
    assert any("--torque-timing centred" in n for n in notices), notices               # how to read its torque


def test_g4_equal_descriptions_of_two_recordings_are_accepted(tmp_path, data, frame):
    """a/exp.toml and b/exp.toml, byte-identical, read a/run.csv and b/run.csv: two recordings."""
    for sub, scale in (("a", 1.0), ("b", 1.01)):
        (tmp_path / sub).mkdir()
        other = frame.copy()
        other["tau1"] *= scale
        other.to_csv(tmp_path / sub / "run.csv", index=False)
        (tmp_path / sub / "exp.toml").write_text('file = "run.csv"\n')
    run = run_dynid("identify", "a/exp.toml", "--validation", "b/exp.toml", "--robot", "planar2",
                    "--json", "o.json", cwd=tmp_path)
    assert run.rc == 0, str(run)


def test_g1_a_bundled_robot_name_guards_the_package_files():
    """`--robot planar2 --out <the package's planar2.toml>` wrote the recording over the bundled
    robot file (the guard compared the name, not the file it stands for). Checked on the guard's
    list, not by trying: a failing guard would destroy the file."""
    from types import SimpleNamespace

    from dynid.dynamics.robot_file import bundled_path
    from dynid.reports.terminal import _input_files
    files = dict((p, what) for what, p in _input_files(SimpleNamespace(command="simulate", robot="planar2")))
    assert str(bundled_path("planar2")) in files
    files = [p for _, p in _input_files(SimpleNamespace(command="identify", robot="kuka_lwr4", data=[]))]
    assert any(os.path.samefile(p, bundled_path("kuka_lwr4").with_suffix(".urdf")) for p in files)


def test_g1_fleet_outputs_onto_the_store_and_too_many_local_workers(tmp_path):
    """Refused before the catalogue is read or a cluster started (the first was found only after
    every recording was identified; the second hung on a 2-core machine)."""
    cat = tmp_path / "cat.csv"
    cat.write_text("robot_id,timestamp,path,robot\nR1,2026-01-01T00:00:00Z,a.csv,planar2\n")
    run = run_dynid("fleet", "cat.csv", "--out", "st", "--json", "st", cwd=tmp_path)
    assert_input_error(run, "--json st is the --out store folder")
    run = run_dynid("fleet", "cat.csv", "--out", "st", "--json", "r.out", "--report", "r.out", cwd=tmp_path)
    assert_input_error(run, "--json r.out and --report r.out are the same file")
    many = 4 * (os.cpu_count() or 1) + 1
    run = run_dynid("fleet", "cat.csv", "--out", "st", "--workers", str(many), cwd=tmp_path)
    assert_input_error(run, rf"--workers \(workers=\) {many}", "--scheduler")
    assert not (tmp_path / "st").exists()
    from dynid.errors import InputError
    from dynid.fleet import run as run_fleet
    with pytest.raises(InputError, match=rf"workers=\) {many}: a local cluster"):     # the API as the CLI
        run_fleet(str(cat), str(tmp_path / "st"), workers=many)
    assert not (tmp_path / "st").exists()
