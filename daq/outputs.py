"""Output files the verbs write: atomically, and never over their own input.

A derived file (an export, a report, a companion log, a recovered log, a simulated log) is written to a
temporary file beside its target and renamed over it only when complete (``os.replace`` is atomic on one file
system): an interrupted verb leaves the user's previous file — or nothing — under the name, never half a file.
The temporary name starts with a dot and has ``.part`` before the target's suffix, so it is easy to spot.
The live recording (``gvt record``) is the exception, by design: it writes in place under its lock so that a
crash leaves the log where the user looks for it (docs/log-format.md, "Writer guarantees").

No verb replaces a file a running recorder holds, not even with ``--overwrite`` (:func:`refuse_live`): the
rename would swap the name to the new file while the recorder went on writing into the old, now nameless,
inode — the whole session gone (issue 30: 34 s of a live log replaced by an npz). The check runs when the verb
checks its output (before the work) and again just before the rename (a recorder may have started since).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from analysis.errors import BadInput, RuntimeFailure


def jsonable(x: object) -> object:
    """``json.dumps(..., default=jsonable)``: numpy scalars and arrays as plain JSON values, anything else refused."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def same_file(a: str | Path, b: str | Path) -> bool:
    """``a`` and ``b`` name one file (a hard link, a symlink or another spelling of the path included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def refuse_own_input(out: str | Path, inputs: Sequence[str | Path], what: str = "--out") -> None:
    """One line (exit 2) when ``out`` is one of ``inputs``: even ``--overwrite`` never replaces what is being read."""
    for src in inputs:
        if Path(out).exists() and same_file(out, src):
            raise BadInput(f"{what} {out}: that is the input file {src}; choose another output name")


def lock_holder(path: str | Path) -> str | None:
    """Who holds an ``flock`` on the file ``path`` names ("another recorder (pid N)"), or None when nobody does.

    Why ``/proc/locks`` first: it answers without taking a lock, so the check can never make a recorder that
    starts at the same instant fail with "in use". Where it cannot be read (not Linux), a shared lock is tried
    and released at once: it fails exactly when a writer holds its exclusive lock.
    """
    try:
        st = os.stat(path)
    except OSError:
        return None  # no file (or unreadable): nothing to protect here; the write itself reports what fails
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return _probe_lock(path)
    for ln in lines:
        parts = ln.split()
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == key:  # waiters ("->") have parts[1] == "->"
            pid = parts[4]
            if pid.isdigit() and int(pid) == os.getpid():
                return "another writer in this process"
            return f"another recorder (pid {pid})"
    return None


def _probe_lock(path: str | Path) -> str | None:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return "another recorder"
    except OSError as exc:  # a file system without locks: nothing can be known, nothing is held
        if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP):
            return None
    finally:
        os.close(fd)
    return None


def refuse_live(out: str | Path, what: str = "--out") -> None:
    """One line (exit 2) when ``out`` is a log a recorder is writing: even ``--overwrite`` never replaces it."""
    who = lock_holder(out)
    if who is not None:
        raise BadInput(f"{what} {out}: in use by {who}, which is writing it; --overwrite does not replace a live "
                       "log; choose another name, or stop the recorder first")  # fmt: skip


def part_path(target: str | Path) -> Path:
    """The temporary file for ``target``: same directory (same file system, so the rename is atomic), and the
    same suffix, because writers pick the format by it (matplotlib's ``savefig``; ``np.savez`` appends
    ``.npz`` to a name without it)."""
    t = Path(target)
    return t.with_name(f".{t.stem}.{os.getpid()}.part{t.suffix}")


@contextlib.contextmanager
def atomic_output(target: str | Path, what: str = "--out") -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``target``, on any exception it is removed.

    The caller has already checked ``--overwrite`` and the input (``check_output``); this only makes the
    replacement all-or-nothing, refuses a live log (:func:`refuse_live`), and turns a failed write (a full or
    read-only disk) into one line naming it (:func:`write_error`, exit 1).
    """
    refuse_live(target, what)
    tmp = part_path(target)
    try:
        yield tmp
        refuse_live(target, what)  # a recorder may have started on that name while the verb worked
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise write_error(target, exc) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


#: What a failed write means, by errno, said to the user instead of "internal error: OSError" (issue 30).
_WRITE_ERRORS = {
    errno.ENOSPC: "the disk is full; free some space or choose another disk",
    errno.EDQUOT: "the disk quota is used up; free some space or choose another disk",
    errno.EROFS: "the file system is read-only; choose a writable location",
    errno.EACCES: "permission denied; choose a location you can write to",
    errno.EPERM: "permission denied; choose a location you can write to",
    errno.EIO: "the disk reported an input/output error",
    errno.EFBIG: "the file grew too large for the file system",
}


def write_error(target: str | Path, exc: OSError) -> RuntimeFailure:
    """One line for a write to ``target`` that failed (exit 1: the input was fine, the disk was not); the
    user's previous file, if any, is untouched (the temporary file is removed by the caller)."""
    why = _WRITE_ERRORS.get(exc.errno or 0, f"cannot write: {exc.strerror or exc}")
    return RuntimeFailure(f"{target}: not written: {why}")


def refuse_unwritable(out: str | Path, what: str = "--out") -> None:
    """One line (exit 2) before any work when ``out``'s directory cannot be written (a read-only file system,
    no permission): a report built for a minute used to end as "internal error: OSError" at its last step."""
    parent = Path(out).parent if str(Path(out).parent) else Path(".")
    if os.access(parent, os.W_OK):
        return
    try:  # say why: EROFS even for root; EACCES otherwise
        os.statvfs(parent)
        ro = bool(os.statvfs(parent).f_flag & os.ST_RDONLY)
    except OSError:
        ro = False
    why = "is on a read-only file system" if ro else "is not writable (permission denied)"
    raise BadInput(f"{what} {out}: the directory {parent} {why}; choose a writable location")
