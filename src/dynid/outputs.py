"""Writing outputs so that no run leaves a half-written file or loses one.

Every file dynid writes goes through `write_all` (several files, all or
none) or `atomic_write_text` / `atomic_open` (one file):

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
* temporary files carry this process's id (`.dynid-<pid>-<hex>.tmp`): those of
  a process that is no longer running (killed mid-write) are removed the next
  time dynid writes into that folder.
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import signal
import stat
import sys
from collections.abc import Iterator
from typing import IO

from dynid.errors import InputError, OutputError

__all__ = ["write_all", "atomic_open", "atomic_write_text", "atomic_write_bytes", "resolve_target"]

_TEMP_RE = re.compile(r"^\.dynid-(\d+)-[0-9a-f]{12}\.(tmp|bak)$")


def resolve_target(path) -> str:
    """The file a write to `path` lands in: symlinks followed, made absolute."""
    return os.path.realpath(os.fspath(path))


def _is_regular_or_missing(target: str) -> bool:
    try:
        return stat.S_ISREG(os.stat(target).st_mode)
    except FileNotFoundError:
        return True


def _temp_name(folder: str, kind: str = "tmp") -> str:
    return os.path.join(folder, f".dynid-{os.getpid()}-{secrets.token_hex(6)}.{kind}")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(folder: str) -> list:
    """Remove dynid's temporary files in `folder` left by processes that no longer run."""
    removed = []
    with contextlib.suppress(OSError):
        for name in os.listdir(folder):
            m = _TEMP_RE.match(name)
            if m and not _alive(int(m.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(folder, name))
                    removed.append(name)
    return removed


def _write_error(path, exc: OSError) -> OutputError:
    reason = "the disk is full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
    return OutputError(f"cannot write {path}: {reason}")


def _stage(target: str, data: bytes, label) -> str:
    """Write `data` to a new temporary file beside `target`; returns its path."""
    folder = os.path.dirname(target)
    tmp = _temp_name(folder)
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
    to_stdout = [data for path, data in outputs if os.fspath(path) == "-"]
    files = [(path, resolve_target(path), data.encode("utf-8") if isinstance(data, str) else bytes(data))
             for path, data in outputs if os.fspath(path) != "-"]
    seen = {}
    for path, target, _ in files:
        if target in seen:
            raise InputError(f"two outputs are the same file: {seen[target]} and {path}; give each its own path")
        seen[target] = path
    for folder in {os.path.dirname(t) for _, t, _ in files}:
        remove_stale_temporaries(folder)
    direct = [(p, t, d) for p, t, d in files if not _is_regular_or_missing(t)]
    staged_files = [(p, t, d) for p, t, d in files if _is_regular_or_missing(t)]
    staged, backups, replaced = [], [], []
    try:
        for path, target, data in staged_files:
            staged.append((_stage(target, data, path), target, path))
        with _signals_held():
            path = None                                     # the output being committed
            try:
                for _, target, path in staged:              # noqa: B007 (path: for the message)
                    if os.path.exists(target):
                        bak = _temp_name(os.path.dirname(target), "bak")
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
    for path, target, data in direct:
        _write_direct(target, data, path)
    written = [p for p, _, _ in files]
    if say is not None:
        for p in written:
            say(f"wrote {p}")
    for data in to_stdout:
        text = data if isinstance(data, str) else data.decode("utf-8")
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
        sys.stdout.flush()
    return written


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
    remove_stale_temporaries(folder)
    tmp = _temp_name(folder)
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
