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

from analysis.errors import BadInput


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
    """Who holds an ``flock`` on the file ``path`` names ("a recorder (pid N)"), or None when nobody does.

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
                return "a recorder in this process"
            return f"a running recorder (pid {pid})"
    return None


def _probe_lock(path: str | Path) -> str | None:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return "a running recorder"
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
        raise BadInput(f"{what} {out}: {who} is writing that file; --overwrite does not replace a live log; "
                       "choose another name, or stop the recorder first")  # fmt: skip


def part_path(target: str | Path) -> Path:
    """The temporary file for ``target``: same directory (same file system, so the rename is atomic), and the
    same suffix, because writers pick the format by it (matplotlib's ``savefig``; ``np.savez`` appends
    ``.npz`` to a name without it)."""
    t = Path(target)
    return t.with_name(f".{t.stem}.{os.getpid()}.part{t.suffix}")


@contextlib.contextmanager
def atomic_output(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``target``, on any exception it is removed.

    The caller has already checked ``--overwrite`` and the input (``check_output``); this only makes the
    replacement all-or-nothing.
    """
    refuse_live(target)
    tmp = part_path(target)
    try:
        yield tmp
        refuse_live(target)  # a recorder may have started on that name while the verb worked
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
