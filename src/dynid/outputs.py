"""Writing outputs so that no run leaves a half-written file or loses one.

Every file dynid writes goes through `write_all` (several files, all or
none) or `atomic_write_text` / `atomic_open` (one file), after
`check_outputs` has refused, before any work, an output that is one of the run's
inputs (the same file through a symlink, a hard link or `..`), two outputs on one
file, an empty name or one ending in '/':

* each file is first written to a temporary file in its target's folder, then
  renamed over the target (an atomic rename on POSIX);
* with several files, the existing targets are kept as hard-linked backups until
  every rename has succeeded; if one fails, the ones already renamed are rolled
  back, so the folder holds either all the old files or all the new ones;
  SIGINT and SIGTERM are held back during the renames (they are short);
* a symlinked target is written through the link (the link stays); an existing
  target keeps its permission bits; a target that is not a regular file (a
  character device such as `/dev/null`, a FIFO) is written directly, never
  renamed over;
* temporary files belong to a *lease*: a lock file `.dynid-<host>-<pid>-<token>.lock`
  on which the writer holds an advisory lock (flock; over NFS the kernel maps it
  to a POSIX lock the server arbitrates) for as long as it writes; its temporary
  and backup files are `.dynid-<host>-<pid>-<token>-<n>.tmp|.bak`. A later run
  removes them only when it can take that lock itself: the writer is then proven
  gone (killed mid-write), whatever host, container or PID namespace it ran in.
  A process id alone proves nothing across PID namespaces or hosts (issue 31: a
  second container on a shared volume deleted a running dynid's backups).
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import signal
import socket
import stat
import sys
import time
from collections.abc import Iterator
from typing import IO

from dynid.errors import InputError, OutputError

try:
    import fcntl
except ImportError:             # not POSIX: no advisory locks, so nothing is ever proven abandoned
    fcntl = None

__all__ = ["write_all", "atomic_open", "atomic_write_text", "atomic_write_bytes", "resolve_target",
           "check_outputs", "check_output_formats", "same_file"]

#: a lease's lock file, and its temporary / backup files (the lease's base name, then -<n>)
_LOCK_RE = re.compile(r"^(\.dynid-(?P<host>[A-Za-z0-9.-]*)-(?P<pid>\d+)-[0-9a-f]{16})\.lock$")
_PENDING_RE = re.compile(r"^\.dynid-[A-Za-z0-9.-]*-\d+-[0-9a-f]{16}\.new$")
#: a lock file not yet published (the few microseconds between its creation and its lock)
#: is left alone for this long
_PENDING_GRACE_SECONDS = 60.0


def _host() -> str:
    name = re.sub(r"[^A-Za-z0-9.-]", "-", socket.gethostname() or "host")[:40]
    return name or "host"


class _Lease:
    """This process's claim on the temporary files it writes in one folder (see the module's notes)."""

    def __init__(self, folder: str):
        self.base = os.path.join(folder, f".dynid-{_host()}-{os.getpid()}-{secrets.token_hex(8)}")
        self.n = 0
        self.fd = None
        pending = self.base + ".new"
        try:
            fd = os.open(pending, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except OSError as exc:
            reason = "the disk is full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
            raise OutputError(f"cannot write in the folder {folder}: {reason}") from None
        try:
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:             # no locks on this file system: nothing of ours can be proven abandoned
            pass
        # published locked: another process never sees this lease's lock file unlocked
        os.rename(pending, self.base + ".lock")
        self.fd = fd

    def path(self, kind: str) -> str:
        self.n += 1
        return f"{self.base}-{self.n}.{kind}"

    def release(self) -> None:
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.base + ".lock")
        os.close(self.fd)
        self.fd = None


@contextlib.contextmanager
def _leases(folders):
    """A lease per folder (stale temporaries of dead writers cleaned first), released at the end."""
    leases = {}
    try:
        for folder in folders:
            remove_stale_temporaries(folder)
            leases[folder] = _Lease(folder)
        yield leases
    finally:
        for lease in leases.values():
            lease.release()


def _abandoned(lock_path: str) -> bool:
    """Whether the writer of a lease is gone: its lock can be taken (then released again)."""
    if fcntl is None:
        return False
    try:
        fd = os.open(lock_path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:                 # held (EWOULDBLOCK), or unknown: not proven
        return False
    finally:
        os.close(fd)
    return True


#: the largest robot / experiment TOML read for the file names it refers to
_TOML_PEEK_BYTES = 1 << 20


def _file_keys(table):
    """`(key, value)` of every `urdf` and `file` string in a TOML document, its tables at any depth
    (an experiment's `[time]`, `[positions]`, `[torques]` ... name their own files)."""
    if isinstance(table, list):
        return [kv for item in table for kv in _file_keys(item)]
    if not isinstance(table, dict):
        return []
    found = [(k, v) for k, v in table.items() if k in ("urdf", "file") and isinstance(v, str) and v]
    return found + [kv for v in table.values() if isinstance(v, (dict, list)) for kv in _file_keys(v)]


def referenced_files(path) -> list:
    """`(key, path)` of the files a robot or experiment TOML refers to (`urdf`, `file`, in any
    table), relative to its folder; [] for another file or one that cannot be read (its loader
    reports that properly)."""
    import tomllib
    path = os.fspath(path)
    try:
        if not path.lower().endswith(".toml") or not os.path.isfile(path) \
                or os.path.getsize(path) > _TOML_PEEK_BYTES:
            return []
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except Exception:           # noqa: BLE001 - the loader reports a bad file properly later
        return []
    found = []
    for key, v in _file_keys(doc):
        ref = os.path.join(os.path.dirname(path), v)
        if (key, ref) not in found:
            found.append((key, ref))
    return found


def resolve_target(path) -> str:
    """The file a write to `path` lands in: symlinks followed, made absolute."""
    return os.path.realpath(os.fspath(path))


#: longest file name (bytes) when the file system does not say
NAME_MAX = 255


def same_file(a, b) -> bool:
    """Whether paths `a` and `b` are one file: symlinks and `..` resolved, hard links too."""
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _check_one_output(label: str, path: str) -> None:
    """A single output name: not empty, a file name (no trailing '/'), its folder writable."""
    if path == "":
        raise InputError(f"{label} '': the file name is empty, so nothing would be written; "
                         f"give {label} a file name")
    if "\0" in path:
        raise InputError(f"{label} {path!r}: the name contains a NUL byte, which no file name can; "
                         f"give {label} a plain file name")
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)):
        raise InputError(f"{label} {path}: the name ends with '{os.sep}', which names a folder; "
                         f"give {label} a file name (without the trailing '{os.sep}')")
    folder = os.path.dirname(os.path.abspath(path)) or "."
    name = os.path.basename(os.path.abspath(path))
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = NAME_MAX
    if len(os.fsencode(name)) > name_max:
        raise InputError(f"{label} {name[:40]}...: the file name is {len(os.fsencode(name))} bytes "
                         f"long, more than the {name_max} the file system allows; give {label} a "
                         f"shorter name")
    if not os.path.isdir(folder):
        raise InputError(f"{label} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise InputError(f"{label} {path}: the folder {folder} is not writable")
    if os.path.isdir(path):
        raise InputError(f"{label} {path} is a folder; give a file name")


#: what each output option writes, and the names of its format; a name of another format is
#: refused (`--mjcf arm.urdf` wrote MJCF that `dynid robot arm.urdf` then could not read), any
#: other name is taken (`--json result.txt`)
OUTPUT_FORMATS = {"json": ("JSON", (".json",)), "report": ("HTML report", (".html", ".htm")),
                  "csv": ("CSV table", (".csv",)), "urdf": ("URDF", (".urdf",)),
                  "mjcf": ("MJCF (MuJoCo XML)", (".xml", ".mjcf"))}


def check_output_formats(outputs) -> None:
    """Refuse an output named as another output's format (`--mjcf arm.urdf`, `--json run.csv`).

    Parameters
    ----------
    outputs : iterable of (label, path)
        `label` the option (`--json`, or `--json (json=)`): its first word without the dashes
        is the key of `OUTPUT_FORMATS`; other options and a path None or `-` are skipped.
    """
    known = {ext: opt for opt, (_, exts) in OUTPUT_FORMATS.items() for ext in exts}
    for label, path in outputs:
        opt = label.split()[0].lstrip("-").rstrip("=")
        if opt not in OUTPUT_FORMATS or path is None or os.fspath(path) == "-":
            continue
        what, exts = OUTPUT_FORMATS[opt]
        ext = os.path.splitext(os.fspath(path))[1].lower()
        if ext in known and ext not in exts:
            raise InputError(f"{label} {os.fspath(path)}: the {what} under a {ext} name (the name of "
                             f"--{known[ext]}'s format); give it a {exts[0]} name")


def check_outputs(outputs, inputs=()) -> None:
    """Refuse, before any work, outputs that would destroy an input or each other.

    Parameters
    ----------
    outputs : iterable of (label, path)
        The outputs to be written; `label` names the option (`--json`, `json=`).
        A path `None` is not written and skipped; `-` means stdout (allowed for a
        label containing "json" only).
    inputs : iterable of (what, path)
        Every file the run reads (`what` as the message should name it: "the
        catalogue", "the recording").

    Raises
    ------
    InputError
        An empty name, a name ending in '/', a missing or read-only folder, a folder
        given as a file, an output that is an input (the same file through a symlink,
        a hard link or `..`), or two outputs on one file.
    """
    inputs = [(what, os.fspath(p)) for what, p in inputs if p is not None]
    seen = []
    for label, path in outputs:
        if path is None:
            continue
        path = os.fspath(path)
        if path == "-":
            if "json" not in label:
                raise InputError(f"{label} -: only --json (json=) can be written to stdout")
            continue
        _check_one_output(label, path)
        for what, p in inputs:
            if "\0" not in p and os.path.exists(p) and same_file(path, p):
                how = "" if os.path.abspath(path) == os.path.abspath(p) else " (the same file under another name)"
                raise InputError(f"{label} {path} is {what} {p}{how}: writing it would destroy the "
                                 f"input; give {label} another path")
        for other, q in seen:
            if same_file(path, q) or os.path.abspath(path) == os.path.abspath(q):
                raise InputError(f"{other} {q} and {label} {path} are the same file: one would "
                                 f"overwrite the other; give each its own path")
        seen.append((label, path))


def _is_regular_or_missing(target: str) -> bool:
    try:
        return stat.S_ISREG(os.stat(target).st_mode)
    except FileNotFoundError:
        return True
    except NotADirectoryError:
        raise InputError(f"{target}: a part of the folder path is a file, not a folder; give a path in "
                         "an existing folder") from None


def remove_stale_temporaries(folder: str) -> list:
    """Remove dynid's temporary and backup files in `folder` whose writer is proven gone.

    Proof: the writer's lease lock can be taken (see the module's notes). Files of this
    process, of a live writer anywhere, or without a lease are left alone.
    """
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    me = (_host(), str(os.getpid()))
    for name in names:
        path = os.path.join(folder, name)
        if _PENDING_RE.match(name):
            with contextlib.suppress(OSError):
                old = os.stat(path).st_mtime < time.time() - _PENDING_GRACE_SECONDS
                if old and _abandoned(path):
                    os.unlink(path)
                    removed.append(name)
            continue
        m = _LOCK_RE.match(name)
        if not m or (m.group("host"), m.group("pid")) == me or not _abandoned(path):
            continue
        prefix = m.group(1) + "-"
        for other in names:
            if other.startswith(prefix) and other.endswith((".tmp", ".bak")):
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(folder, other))
                    removed.append(other)
        with contextlib.suppress(OSError):      # last: until then a crash here leaves the proof
            os.unlink(path)
            removed.append(name)
    return removed


def _write_error(path, exc: OSError) -> OutputError:
    reason = "the disk is full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
    return OutputError(f"cannot write {path}: {reason}")


def _stage(target: str, data: bytes, label, lease: _Lease) -> str:
    """Write `data` to a new temporary file of `lease` beside `target`; returns its path."""
    tmp = lease.path("tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        with contextlib.suppress(FileNotFoundError):
            mode = stat.S_IMODE(os.stat(target).st_mode)
            os.chmod(tmp, mode)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise _write_error(label, exc) from None
    except BaseException:
        # Ctrl-C or SIGTERM in the write: the file is not yet among the staged ones that the
        # caller cleans up, and its lease is released on the way out, so no later run could
        # prove it abandoned and remove it
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return tmp


def _write_direct(target: str, data: bytes, label) -> None:
    """Write into a non-regular file (device, FIFO) as it is, without a rename."""
    try:
        with open(target, "wb") as fh:
            fh.write(data)
            fh.flush()
    except OSError as exc:
        raise _write_error(label, exc) from None


@contextlib.contextmanager
def _signals_held():
    """Defer SIGINT and SIGTERM for the duration (delivered afterwards, in order of arrival).

    The Python-level handlers are swapped for one that only records the signal: a signal
    mask would not do, because a process-directed signal goes to any thread that does not
    block it (NumPy's, Dask's), and Python then runs the handler in the main thread anyway.
    """
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield                                   # handlers can only be set from the main thread
        return
    pending = []
    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            old[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
        except (ValueError, OSError):           # not settable here
            pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(pending):
            signal.raise_signal(sig)


def write_all(outputs, say=None) -> list:
    """Write `(path, text_or_bytes)` pairs all or none; the path `-` means stdout, written last.

    Returns the paths written. Raises `OutputError` naming the
    file when one cannot be written; the folder is then as it was before.
    """
    outputs = list(outputs)
    for path, _ in outputs:
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"an output path must be a file name (str or os.PathLike), got "
                             f"{type(path).__name__} {path!r}")
    to_stdout = [data for path, data in outputs if os.fspath(path) == "-"]
    files = [(path, resolve_target(path), data.encode("utf-8") if isinstance(data, str) else bytes(data))
             for path, data in outputs if os.fspath(path) != "-"]
    seen = {}
    for path, target, _ in files:
        if target in seen:
            raise InputError(f"two outputs are the same file: {seen[target]} and {path}; give each its own path")
        seen[target] = path
    direct = [(p, t, d) for p, t, d in files if not _is_regular_or_missing(t)]
    staged_files = [(p, t, d) for p, t, d in files if _is_regular_or_missing(t)]
    # devices and pipes first: they cannot be staged or rolled back, and they are the likeliest
    # to fail (/dev/full); when one fails, no file has been replaced yet
    for path, target, data in direct:
        _write_direct(target, data, path)
    with _leases(sorted({os.path.dirname(t) for _, t, _ in staged_files})) as leases:
        _commit(staged_files, leases)
    written = [p for p, _, _ in files]
    if say is not None:
        for p in written:
            say(f"wrote {p}")
    for data in to_stdout:
        text = data if isinstance(data, str) else data.decode("utf-8")
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
        sys.stdout.flush()
    return written


def _commit(staged_files, leases) -> None:
    """Stage every `(path, target, data)`, then rename them all or none (backups kept meanwhile)."""
    staged, backups, replaced = [], [], []
    try:
        for path, target, data in staged_files:
            staged.append((_stage(target, data, path, leases[os.path.dirname(target)]), target, path))
        with _signals_held():
            path = None                                     # the output being committed
            try:
                for _, target, path in staged:              # noqa: B007 (path: for the message)
                    if os.path.exists(target):
                        bak = leases[os.path.dirname(target)].path("bak")
                        os.link(target, bak)
                        backups.append((bak, target))
                for tmp, target, path in staged:            # noqa: B007 (path: for the message)
                    replaced.append(target)                 # before: an interruption may land right after
                    os.replace(tmp, target)
            except BaseException as exc:
                # a failed rename, or an interruption that was not deferred (outside the main
                # thread): undo the renames done
                kept = {t: b for b, t in backups}
                for target in replaced:                     # roll back
                    with contextlib.suppress(OSError):
                        if target in kept:
                            os.replace(kept.pop(target), target)
                        else:
                            os.unlink(target)
                if isinstance(exc, OSError):
                    raise _write_error(path, exc) from None
                raise
            finally:
                # Still deferred: a signal held back during the renames is delivered after
                # the clean-up, so its handler cannot cut it short.
                for bak, _ in backups:
                    with contextlib.suppress(OSError):
                        os.unlink(bak)
    finally:
        for tmp, _, _ in staged:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", *, encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file beside `path`; when the `with` body succeeds, it replaces `path`.

    If the body raises, the temporary file is removed and `path` is untouched.
    `mode` is `'w'` (text, no newline translation) or `'wb'`.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', not {mode!r}")
    with staged_path(path) as tmp:
        if mode == "wb":
            fh = open(tmp, "wb")
        else:
            fh = open(tmp, "w", encoding=encoding, newline="")
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())


@contextlib.contextmanager
def staged_path(path) -> Iterator[str]:
    """A temporary path beside `path` for a writer that wants a file name (netCDF ...).

    On success it is renamed over `path` (symlinks followed, permissions kept);
    on failure it is removed.
    """
    target = resolve_target(path)
    folder = os.path.dirname(target)
    with _leases([folder]) as leases:
        tmp = leases[folder].path("tmp")
        try:
            yield tmp
            with contextlib.suppress(FileNotFoundError):
                os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
            with _signals_held():
                os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


def atomic_write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write `text` to `path` atomically (no newline translation)."""
    write_all([(path, text.encode(encoding))])


def atomic_write_bytes(path, data: bytes) -> None:
    """Write `data` to `path` atomically."""
    write_all([(path, data)])
