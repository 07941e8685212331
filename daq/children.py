"""Child processes die with the process that started them — SIGKILL included.

A recorder starts a confirmation worker (a spawned Python process, ~300 MB) and possibly the rerun viewer
server. Killed with SIGKILL, the recorder runs no clean-up, and children that outlive it keep the CPU,
the memory and the recorder's stdout. Two mechanisms, both from the child's side:

* :func:`pdeathsig` (Linux ``prctl(PR_SET_PDEATHSIG)``), used as ``preexec_fn`` of a ``Popen``: the kernel
  signals the child when the thread that forked it ends. The viewer is started from the main thread, so
  that is the recorder's own death.
* :func:`die_with_parent`, the initializer of a ``ProcessPoolExecutor`` worker: a daemon thread that
  exits the worker once its parent pid changes. PDEATHSIG would be wrong there: the pool forks its
  workers from whichever thread first submits (the confirmation lane's), and that thread ends before the
  last confirmation does.
"""

from __future__ import annotations

import ctypes
import os
import signal
import threading
import time

PR_SET_PDEATHSIG = 1


def pdeathsig(sig: int = signal.SIGTERM) -> None:
    """In a forked child before exec: ask the kernel for ``sig`` when the parent dies (no-op off Linux)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def die_with_parent(parent_pid: int, every_s: float = 0.5) -> None:
    """Pool-worker initializer: exit (no clean-up needed, the parent is gone) when ``parent_pid`` is no longer
    our parent."""

    def watch() -> None:
        while True:
            if os.getppid() != parent_pid:
                os._exit(1)
            time.sleep(every_s)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()
