"""Scheduling priority: the recording path above the lanes that can wait (issue 30, item 1).

On a busy lab PC the recorder competes with everything else; the lanes that may fall behind (near-live analysis,
confirmation) run in a worker process at ``nice + 10`` (:func:`lower_priority`), and the recorder asks for
``nice - 5`` (:func:`raise_priority`). Lowering one's own priority is always allowed; raising it needs
``CAP_SYS_NICE`` (root, or ``RLIMIT_NICE`` set by the administrator), which a lab account usually lacks: then
the recorder says so in one line and records at the priority it has.

Linux sets the nice value per thread (``setpriority(PRIO_PROCESS, 0)`` changes the calling thread; threads and
processes it starts afterwards inherit it), so both calls belong at the start, before any thread is started.
"""

from __future__ import annotations

import os

RAISE_BY = 5  # the recorder's step above its start (a modest step: the desktop stays usable)
LOWER_BY = 10  # the lane worker's step below the recorder's start

_base: int | None = None  # the process's nice value before the first raise (a test process runs many sessions)
_verdict: str | None = None


def base_nice() -> int:
    """The nice value this process started its sessions at (before :func:`raise_priority`)."""
    return os.getpriority(os.PRIO_PROCESS, 0) if _base is None else _base


def raise_priority(step: int = RAISE_BY) -> str | None:
    """Ask for ``base - step``; None when granted, else the one line that says it was not (and why). Idempotent:
    a second session in the same process asks for the same value, not ``step`` more."""
    global _base, _verdict
    if _base is None:
        _base = os.getpriority(os.PRIO_PROCESS, 0)
        want = max(-20, _base - step)
        try:
            os.setpriority(os.PRIO_PROCESS, 0, want)
            _verdict = None
        except OSError as exc:  # EPERM / EACCES without CAP_SYS_NICE
            _verdict = (f"recording at normal priority (nice {_base}): raising it to {want} was refused "
                        f"({exc.strerror or exc}); the lanes that can wait run at nice {_base + LOWER_BY} "
                        "(grant CAP_SYS_NICE or an RLIMIT_NICE to raise it)")  # fmt: skip
    return _verdict


def lower_priority(base: int, step: int = LOWER_BY) -> int:
    """In a worker, before it starts threads: nice ``base + step`` (always permitted); returns the value set."""
    want = min(19, base + step)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, want)
    except OSError:
        pass  # an exotic platform: the worker runs at the recorder's priority
    return os.getpriority(os.PRIO_PROCESS, 0)
