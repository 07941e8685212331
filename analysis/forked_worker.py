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

Large arrays cross in shared memory, copied once (issue 30 item 1's "a shared-memory ring ... that copies each block
once"): ``slot_bytes`` > 0 maps ``slots`` slots shared with the child before the fork. An array argument of at least
``SHARED_MIN_BYTES`` that fits a free slot is copied into it and the child gets a read-only view; a slot is free again
once the call that read it has been answered. Through the pipe instead, a replay's 1.8 MB block was pickled, and the
write waited for the child to finish its previous block before it read (the pipe holds 64 kB): 44 ms of the parent's
~0.3 s of CPU per 20 s of data.
"""

from __future__ import annotations

import mmap
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from analysis.errors import RuntimeFailure


class WorkerDied(RuntimeFailure, RuntimeError):
    """The worker process ended without answering (killed, out of memory, crashed): a runtime failure, so ``gvt``
    says it in one line and exits 1 whatever verb ran the worker (``gvt confirm`` said "internal error")."""


def _how_it_ended(exitcode: int | None) -> str:
    """The child's end in words: a SIGKILL is most often the kernel's out-of-memory killer, which a user should know."""
    if exitcode is None:
        return "exit code unknown"
    if exitcode == -signal.SIGKILL:
        return "exit code -9: killed by SIGKILL, the system's out-of-memory killer or a kill -9"
    if exitcode < 0:
        try:
            return f"exit code {exitcode}: killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"exit code {exitcode}"
    return f"exit code {exitcode}"


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


#: smaller arrays cross the pipe: pickling a few kB costs less than a slot, which a block would then find taken (an event's
#: phase-lock fit sends three 300-sample arrays)
SHARED_MIN_BYTES = 1 << 16


class _Shared(NamedTuple):
    """An array argument waiting in shared slot ``slot`` (from the slot's first byte): what crosses the pipe for it."""

    slot: int
    dtype: str
    shape: tuple[int, ...]


class ForkedWorker:
    """Fork a child holding ``obj`` (as it is now) and run ``getattr(obj, method)(*args)`` there, in submit order;
    array arguments of up to ``slot_bytes`` cross in one of ``slots`` shared-memory slots."""

    def __init__(self, obj: object, name: str, slot_bytes: int = 0, slots: int = 2) -> None:
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe(duplex=True)
        self._slot_bytes = max(0, int(slot_bytes))
        self._shm = mmap.mmap(-1, self._slot_bytes * slots) if self._slot_bytes else None  # MAP_SHARED: the child's too
        self._slot_user: list[Pending | None] = [None] * (slots if self._shm is not None else 0)
        self._proc = ctx.Process(target=_serve, args=(obj, child, self._conn, self._shm, self._slot_bytes), name=name,
                                 daemon=True)  # fmt: skip
        # SIGINT blocked across the fork: a Ctrl-C in the child's first moments (before it ignores SIGINT) killed it with
        # a KeyboardInterrupt (make test beside 4 hogs). The child inherits the mask, ignores SIGINT, then unblocks
        # (a pending one is discarded there); here it is unblocked after the fork, so a pending Ctrl-C is the parent's
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            self._proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        child.close()
        self._queue: deque[Pending] = deque()
        self.name = name
        self.died = False  # a call found the child gone (WorkerDied raised): what it still owed is lost
        # CPU seconds each side has used since the fork: the child's as of its last answer (each answer carries it),
        # this process's from here (its process_time, every thread). balance() compares them
        self._cpu_child, self._cpu_child_at, self._cpu_here0 = 0.0, time.monotonic(), time.process_time()

    def balance(self) -> float:
        """CPU seconds the child has used since the fork minus this process's: positive, the child is the busier side.
        The child's is its last answer's figure plus the wall time since (a worker is given its next call before it
        answers, so it is computing meanwhile). For placing work that may run on either side (the events' lock fits)."""
        child = self._cpu_child + (time.monotonic() - self._cpu_child_at if self._queue else 0.0)
        return child - (time.process_time() - self._cpu_here0)

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def submit(self, method: str | Callable[..., Any], *args: Any) -> Pending:
        """Run ``obj.method(*args)`` (a name) or ``method(*args)`` (a module-level function, sent by reference) there."""
        p = Pending(self)
        args, used = self._share(args, p)
        try:
            self._conn.send((method, args))
        except OSError:  # BrokenPipeError: the child is gone
            for k in used:
                self._slot_user[k] = None
            raise self._died() from None
        self._queue.append(p)
        return p

    def _share(self, args: tuple, p: Pending) -> tuple[tuple, list[int]]:
        """Arrays that fit a free slot copied into it (a slot is free once its call was answered), the rest as they are."""
        out, used = [], []
        for a in args:
            if isinstance(a, np.ndarray) and SHARED_MIN_BYTES <= a.nbytes <= self._slot_bytes and not a.dtype.hasobject:
                free = [k for k, u in enumerate(self._slot_user) if u is None or u._done]
                if free:
                    k = free[0]
                    view = np.ndarray(a.shape, a.dtype, buffer=self._shm, offset=k * self._slot_bytes)
                    view[...] = a
                    self._slot_user[k] = p
                    used.append(k)
                    a = _Shared(k, a.dtype.str, a.shape)
            out.append(a)
        return tuple(out), used

    def _receive_one(self) -> None:
        try:
            ok, value, self._cpu_child = self._conn.recv()
        except (EOFError, OSError):
            raise self._died() from None
        self._cpu_child_at = time.monotonic()
        p = self._queue.popleft()
        p._done, p._ok, p._value = True, ok, value

    def _died(self) -> WorkerDied:
        self.died = True
        self._proc.join(timeout=1.0)
        return WorkerDied(f"{self.name}: the worker process ended ({_how_it_ended(self._proc.exitcode)}) before it answered")

    def close(self, timeout_s: float = 5.0, wait: bool = True) -> None:
        """Ask the child to stop (it finishes the call it is in) and wait ``timeout_s``; then terminate it. ``wait=False``:
        do not wait for it to end (the kernel's teardown of a forked copy of a few hundred MB takes ~10 ms, paid for
        nothing by a caller whose calls have all been answered); :func:`reap` or multiprocessing's own bookkeeping (its
        next start, the interpreter's exit) collects it."""
        try:
            self._conn.send(None)
        except OSError:
            pass
        self._conn.close()
        if self._shm is not None:
            self._shm.close()
        if not wait:
            # the ones that ended since are collected now (exitcode polls without blocking): a long-lived process that
            # replays log after log keeps neither zombies nor a growing list until someone calls reap()
            _stopping[:] = [(p, t) for p, t in _stopping if p.exitcode is None]
            _stopping.append((self._proc, timeout_s))
            return
        _join(self._proc, timeout_s)


#: workers closed without waiting, not yet collected (:func:`reap`)
_stopping: list[tuple[Any, float]] = []


def _join(proc: Any, timeout_s: float) -> None:
    proc.join(timeout=timeout_s)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=timeout_s)


def reap() -> None:
    """Wait for the workers closed with ``wait=False`` to end (each within its timeout, then terminated): their CPU time
    then counts in ``RUSAGE_CHILDREN`` (the bench reads it), and no ended child is left unreaped."""
    while _stopping:
        _join(*_stopping.pop())


def _serve(obj: object, conn: Any, parent_end: Any, shm: mmap.mmap | None, slot_bytes: int) -> None:  # pragma: no cover
    """The child's loop (runs in the child): a call at a time, its shared arguments as read-only views."""
    parent_end.close()  # so that the parent's end closing (or the parent dying) reads as EOF here
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it then closes us
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked across the fork (ForkedWorker.__init__)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:  # asked to stop: nothing of the child's to flush or finalise, so end it here (multiprocessing's
            os._exit(0)  # own exit path ran its finalisers and took ~10 ms, inside the parent's close on every replay)
        method, args = msg
        if shm is not None:
            args = tuple(_view(a, shm, slot_bytes) if isinstance(a, _Shared) else a for a in args)
        try:
            fn = method if callable(method) else getattr(obj, method)
            reply = (True, fn(*args), time.process_time())
        except Exception as exc:  # raised again by the parent's result()
            reply = (False, exc, time.process_time())
        try:
            conn.send(reply)
        except OSError:
            return
        except Exception as exc:  # a result or exception that does not pickle
            conn.send((False, RuntimeError(f"{method}: {type(exc).__name__}: {exc}"), time.process_time()))


def _view(a: _Shared, shm: mmap.mmap, slot_bytes: int) -> np.ndarray:  # pragma: no cover - runs in the child
    v = np.ndarray(a.shape, np.dtype(a.dtype), buffer=shm, offset=a.slot * slot_bytes)
    v.flags.writeable = False  # the parent writes the slot again once this call is answered: a call must not keep it
    return v
