"""A child process, forked from this one, that runs one object's methods in the order they are asked for.

Why (issue 30 item 5, D130): the pipelined operator ran its seed lane on a worker thread. Its numerics release the
interpreter lock, but the three stages together held the lock ~65 % of a replay's wall time (``py-spy --gil``), so
two cores gave ~1.4 cores of work. In a process of its own the seed lane neither waits for the lock nor holds it
from the other two stages.

Why fork: the child starts as a copy of this process: the object with its state, numpy and the compiled kernels
already loaded, in milliseconds; a spawned interpreter imports numpy, scipy and numba again (~1 s, longer than
replaying a 20 s log). A fork is only safe where no other thread can hold a lock the child will need (an import,
numba's compiler lock, a logging handler). :func:`can_fork` asks for Linux and the calling thread alone; elsewhere
the caller keeps its worker thread.

The protocol is sans-IO in spirit: :meth:`ForkedWorker.submit` sends ``(method, args)`` and returns a
:class:`Pending` whose :meth:`Pending.result` reads replies in order, the ``concurrent.futures`` shape the operator
already used. An exception in the child comes back and is raised by ``result()``; a child that dies raises
:class:`WorkerDied` with its exit code, never a hang.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable
from typing import Any


class WorkerDied(RuntimeError):
    """The worker process ended without answering (killed, out of memory, crashed)."""


def can_fork() -> bool:
    """True where a forked worker is safe and cheap: Linux (the fork start method) with this thread the only one."""
    return sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods() and threading.active_count() == 1


class Pending:
    """One call's reply, read in order by :meth:`result` (a ``Future``'s shape)."""

    def __init__(self, worker: ForkedWorker) -> None:
        self._worker = worker
        self._done = False
        self._ok = True
        self._value: Any = None

    def result(self) -> Any:
        while not self._done:
            self._worker._receive_one()
        if not self._ok:
            raise self._value
        return self._value


class ForkedWorker:
    """Fork a child holding ``obj`` (as it is now) and run ``getattr(obj, method)(*args)`` there, in submit order."""

    def __init__(self, obj: object, name: str) -> None:
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe(duplex=True)
        self._proc = ctx.Process(target=_serve, args=(obj, child, self._conn), name=name, daemon=True)
        self._proc.start()
        child.close()
        self._queue: deque[Pending] = deque()
        self.name = name
        self.died = False  # a call found the child gone (WorkerDied raised): what it still owed is lost

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def submit(self, method: str | Callable[..., Any], *args: Any) -> Pending:
        """Run ``obj.method(*args)`` (a name) or ``method(*args)`` (a module-level function, sent by reference) there."""
        try:
            self._conn.send((method, args))
        except OSError:  # BrokenPipeError: the child is gone
            raise self._died() from None
        p = Pending(self)
        self._queue.append(p)
        return p

    def _receive_one(self) -> None:
        try:
            ok, value = self._conn.recv()
        except (EOFError, OSError):
            raise self._died() from None
        p = self._queue.popleft()
        p._done, p._ok, p._value = True, ok, value

    def _died(self) -> WorkerDied:
        self.died = True
        self._proc.join(timeout=1.0)
        return WorkerDied(f"{self.name}: the worker process ended (exit code {self._proc.exitcode}) before it answered")

    def close(self, timeout_s: float = 5.0) -> None:
        """Ask the child to stop (it finishes the call it is in) and wait ``timeout_s``; then terminate it."""
        try:
            self._conn.send(None)
        except OSError:
            pass
        self._proc.join(timeout=timeout_s)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=timeout_s)
        self._conn.close()


def _serve(obj: object, conn: Any, parent_end: Any) -> None:  # pragma: no cover - runs in the child
    parent_end.close()  # so that the parent's end closing (or the parent dying) reads as EOF here
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it then closes us
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        method, args = msg
        try:
            fn = method if callable(method) else getattr(obj, method)
            reply = (True, fn(*args))
        except Exception as exc:  # raised again by the parent's result()
            reply = (False, exc)
        try:
            conn.send(reply)
        except OSError:
            return
        except Exception as exc:  # a result or exception that does not pickle
            conn.send((False, RuntimeError(f"{method}: {type(exc).__name__}: {exc}")))
