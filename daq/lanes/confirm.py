"""The confirmation lane: each near-live IR event is confirmed (WBEMD + slow flow) in the background.

Why a separate process: a confirmation runs WBEMD (dozens of sifts and wavelet transforms, seconds of
CPU per event) — in a thread it would hold the GIL against the near-live analysis and the hit gate. It
runs in one worker process instead, so the near-live path never waits for it (architecture.md). The
lane's own inputs are both lossy and bounded, like every subscriber's:

* sample blocks from its own fan-out subscription, kept in a ring of the last ``buffer_s`` seconds of
  the analysed stream's sensor channels (a bounded buffer of the current hit, not of the run);
* IR events from the analysis lane (:meth:`ConfirmLane.offer`, never blocks).

An event is cut out of the ring once the ring holds the stretch its confirmation uses (the context's
``span_s``: 0.5 s before its start to 0.5 s after its end), and handed to the
worker. Whatever cannot be confirmed is said, never dropped silently: an event whose data left the
ring, fell in a gap, or arrived while ``max_pending`` confirmations were already queued gets a
confirmation record with ``status="skipped"`` and the reason. Results go to the sink (the session
log's ``/analysis/confirmations`` topic) as they complete.

A worker that dies (killed, out of memory: the pool is then *broken* and fails every confirmation in hand)
is restarted once: the events it had in hand get ``status="error"`` with the reason ``worker restarted``,
and later events are confirmed by the new worker. A second death switches the lane off with one line
(a ``confirm_off`` event, and ``say`` on the console); every later event is ``skipped`` with the reason
``confirmation worker failed twice``. The drain after the data ends is bounded by ``finish_timeout_s``
(and the caller's deadline) whatever the worker does, and says how many confirmations it abandoned.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from analysis.records import Confirmation
from daq.children import die_with_parent
from daq.fanout import FanOut, Subscription
from daq.log import layout
from drivers.blocks import SampleBlock

if TYPE_CHECKING:  # the analysis side is imported where it runs (worker, lane start)
    from analysis.confirm import ConfirmSettings

CONFIRM_TOPIC = layout.CONFIRMATIONS_TOPIC
_END_EVENTS = object()

Sink = Callable[[str, dict, int | None], None]


@dataclass(frozen=True)
class LaneSettings:
    buffer_s: float = 8.0  # ring length: the longest stretch of data an event's confirmation can use
    max_pending: int = 16  # confirmations queued in the worker at once (~1.5 MB of samples each); more are skipped and said
    event_queue: int = 256
    finish_timeout_s: float = 120.0  # at the end, confirmations still running after this are skipped and said
    restarts: int = 1  # a worker that dies is restarted this many times; the next death switches the lane off


#: reasons of the records of events a dead worker took with it, and of those after the lane was switched off
RESTARTED = "worker restarted: the confirmation worker died while this event was in hand"
FAILED_TWICE = "confirmation worker failed twice"
DIED_OFF = f"{FAILED_TWICE}: it died again while this event was in hand"


def skipped(event: Mapping[str, Any], reason: str, status: str = "skipped") -> dict:
    """The confirmation record (records.Confirmation, as JSON) of an event that was not examined (``status``
    skipped, or error), with the reason."""
    return Confirmation.skipped(event, reason, status).to_json()


class _Ring:
    """The last ``capacity`` samples of a contiguous run of the stream (a gap restarts it)."""

    def __init__(self, capacity: int, n_channels: int) -> None:
        self.buf = np.zeros((capacity, n_channels), np.float32)
        self.capacity = capacity
        self.first = 0  # oldest index held
        self.end = 0  # one past the newest index held

    def push(self, first_index: int, data: np.ndarray) -> None:
        if first_index != self.end:  # a gap (or the start): nothing before it is contiguous with what follows
            self.first = self.end = first_index
        n = data.shape[0]
        if n >= self.capacity:
            data, first_index = data[-self.capacity:], first_index + n - self.capacity
            self.first = first_index
            n = self.capacity
        pos = first_index % self.capacity
        head = min(n, self.capacity - pos)
        self.buf[pos: pos + head] = data[:head]
        self.buf[: n - head] = data[head:]
        self.end = first_index + n
        self.first = max(self.first, self.end - self.capacity)

    def get(self, a: int, b: int) -> np.ndarray | None:
        if a < self.first or b > self.end or b <= a:
            return None
        idx = np.arange(a, b) % self.capacity
        return self.buf[idx].copy()


class ConfirmLane:
    """Confirms the analysis lane's IR events of one stream in a worker process; results to ``sink``.

    ``confirm`` is a picklable function ``(segment, fs, t0_s, event, context) -> dict`` run in the
    worker (default :func:`analysis.confirm.confirm_segment`), ``context`` whatever it needs of the rig.
    """

    def __init__(
        self, fan: FanOut, stream: str, channels: tuple[str, ...], sensors: tuple[str, ...], fs: float, sink: Sink,
        context: Any, confirm: Callable | None = None, settings: LaneSettings = LaneSettings(),
        fetch: Callable[[int, int], np.ndarray | None] | None = None, say: Callable[[str], None] | None = None,
    ) -> None:  # fmt: skip
        if confirm is None:
            from analysis.confirm import confirm_segment as confirm
        self.stream, self.fs, self.sink, self.context, self.confirm, self.s = stream, fs, sink, context, confirm, settings
        self.cols = [channels.index(c) for c in sensors]
        self.fetch = fetch  # replay: samples [a, b) of the sensors straight from the log, no ring, nothing to lose
        self.sub: Subscription | None = None if fetch is not None else fan.subscribe(f"confirm:{stream}", maxsize=1024)
        self.events: queue.Queue = queue.Queue(maxsize=settings.event_queue)
        self.ring = _Ring(max(1, int(settings.buffer_s * fs)), len(self.cols))
        self.results: list[dict] = []
        self.dropped_events = 0
        self.error: str | None = None
        self._ended = threading.Event()  # the end marker has been taken off the event queue
        self._waiting: list[dict] = []
        self._running: list[tuple[dict, Future]] = []
        self.say = say  # the console's one line when the lane is switched off (None: the event only)
        self.worker_deaths = 0
        self.off: str | None = None  # why the lane was switched off (a worker died more than ``restarts`` times)
        self.abandoned = 0  # confirmations still running when the drain's time ran out
        self.cut_at: float | None = None  # a stop request during the drain: it ends by then (:meth:`cut`)
        self._pool = _new_pool()
        self._thread = threading.Thread(target=self._main, name=f"confirm:{stream}", daemon=True)

    def start(self) -> ConfirmLane:
        self._thread.start()
        return self

    name = "confirm"

    def offer(self, topic: str, obj: dict) -> None:
        """The Lane protocol (daq/lanes): IR events from ``/analysis/events`` are submitted; other topics ignored."""
        if topic == layout.IR_EVENTS_TOPIC:
            self.submit(obj)

    def submit(self, event: Mapping[str, Any]) -> None:
        """Hand over an IR event (called from the analysis lane; never blocks)."""
        try:
            self.events.put_nowait(dict(event))
        except queue.Full:
            self.dropped_events += 1
            self._emit(skipped(event, "the confirmation lane's event queue was full"))

    def join(self, timeout: float | None = None) -> list[dict]:
        """After the stream ended *and the analysis lane was joined* (its last events come at its finish):
        confirm what is still waiting, wait for every queued confirmation, return all records."""
        self.finish(time.monotonic() + (self.s.finish_timeout_s if timeout is None else timeout))
        return list(self.results)

    def finish(self, deadline: float, progress: Callable[[int, int], None] | None = None, wait: bool = True) -> None:
        """The Lane protocol's end (after the analysis lane finished): dispatch what is still waiting, then wait
        for the confirmations in hand — reporting ``progress(done, total)`` about twice a second — until they
        are done, ``deadline`` or ``finish_timeout_s`` passes. ``wait=False`` (``gvt record --no-wait``) waits
        for none: each is recorded as skipped, saying how to confirm it later. The worker is always stopped."""
        if self.fetch is not None:
            self.events.put(_END_EVENTS)  # blocking put: the end marker must arrive
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self.error is None:
            self._dispatch(final=True)
            # a replay reads from the log: no deadline of its own (the caller's), nothing skipped for time
            limit = deadline if self.fetch is not None else min(deadline, time.monotonic() + self.s.finish_timeout_s)
            self._drain(limit, progress, wait)
        self._pool.shutdown(wait=False, cancel_futures=True)
        _stop_workers(self._pool)
        if self.abandoned:
            line = (f"confirmation: gave up on {self.abandoned} confirmation(s) still running at the drain's time limit "
                    "(each recorded as skipped; 'gvt confirm LOG' confirms them afterwards)")  # fmt: skip
            self.sink(layout.EVENTS_TOPIC, {"kind": "confirm_abandoned", "stream": self.stream, "count": self.abandoned,
                                            "message": line}, None)  # fmt: skip
            if self.say is not None:
                self.say(line)

    def cut(self, deadline: float) -> None:
        """A stop request (Ctrl-C, SIGTERM) arrived: the drain ends by ``deadline`` (``time.monotonic()``) at the
        latest, whatever it was given; what is still running then is recorded as skipped, for ``gvt confirm``.
        Safe from any thread (the drain reads it every 0.2 s)."""
        self.cut_at = deadline if self.cut_at is None else min(self.cut_at, deadline)

    def _drain(self, deadline: float, progress: Callable[[int, int], None] | None, wait: bool) -> None:
        total = len(self._running)
        if not wait:
            for ev, _fut in self._running:
                self._emit(skipped(ev, "not confirmed: the recorder did not wait (--no-wait); run 'gvt confirm LOG "
                                       f"--event {ev.get('id')}'"))  # fmt: skip
            self._running = []
            return
        last = 0.0
        t0 = time.monotonic()
        while self._running and time.monotonic() < min(deadline, self.cut_at or deadline):
            self._collect()
            now = time.monotonic()
            if progress is not None and (now - last >= 0.5 or not self._running):
                progress(total - len(self._running), total)
                last = now
            if self._running:
                wait_futures([f for _, f in self._running], timeout=0.2, return_when=FIRST_COMPLETED)
        self.abandoned += len(self._running)
        why = " (a stop request cut the drain)" if self.cut_at is not None and self._running else ""
        for ev, _fut in self._running:
            self._emit(skipped(ev, f"still running {time.monotonic() - t0:.0f} s after the stream ended{why}; run "
                                   f"'gvt confirm LOG --event {ev.get('id')}'"))  # fmt: skip
        self._running = []

    # -- internals -------------------------------------------------------------------------------------
    def _emit(self, rec: dict) -> None:
        self.results.append(rec)
        t = rec.get("event", {}).get("end_s")
        self.sink(CONFIRM_TOPIC, rec, None if t is None else round(float(t) * 1e9))

    def _take_events(self) -> None:
        while True:
            try:
                ev = self.events.get_nowait()
            except queue.Empty:
                return
            if ev is _END_EVENTS:
                self._ended.set()  # seen here, the fetch loop must still learn of it (it waits on the queue)
            else:
                self._waiting.append(ev)

    def _span(self, ev: dict) -> tuple[int, int]:
        a, b = self.context.span_s(ev)
        return int(np.floor(a * self.fs)), int(np.ceil(b * self.fs))

    def _dispatch(self, final: bool = False) -> None:
        self._take_events()
        keep = []
        for ev in self._waiting:
            a, b = self._span(ev)
            a = max(a, 0)
            if self.fetch is not None:
                seg = self.fetch(a, b)
            elif b > self.ring.end and not final:
                keep.append(ev)  # its data has not all arrived yet
                continue
            else:
                seg = self.ring.get(a, min(b, self.ring.end))
            if seg is None:
                where = "the log has a gap there" if self.fetch is not None else (
                    f"not in the lane's buffer: older than {self.s.buffer_s} s, or in a gap")
                self._emit(skipped(ev, f"its data ({a / self.fs:.3f}–{b / self.fs:.3f} s) is missing ({where})"))
            elif self.off is not None:
                self._emit(skipped(ev, FAILED_TWICE))
            elif self.fetch is None and len(self._running) >= self.s.max_pending:  # a replay has no deadline: all queue
                self._emit(skipped(ev, f"{self.s.max_pending} confirmations were already queued (the lane fell behind)"))
            else:
                self._submit(ev, seg, a)
        self._waiting = keep

    def _submit(self, ev: dict, seg: np.ndarray, a: int) -> None:
        """Hand one event to the worker; a pool found broken here is handled (restart or off) and tried once more."""
        for _attempt in range(2):
            try:
                self._running.append((ev, self._pool.submit(self.confirm, seg, self.fs, a / self.fs, ev, self.context)))
                return
            except BrokenProcessPool as exc:
                self._worker_died(exc)
                if self.off is not None:
                    break
        self._emit(skipped(ev, FAILED_TWICE))

    def _worker_died(self, exc: BaseException) -> None:
        """The pool is broken (its worker died): every confirmation in hand failed with it. Mark them, then start a
        new worker — or, after ``restarts`` restarts, switch the lane off with one line."""
        self.worker_deaths += 1
        restart = self.worker_deaths <= self.s.restarts
        lost, self._running = self._running, []
        for ev, _fut in lost:
            self._emit(skipped(ev, RESTARTED if restart else DIED_OFF, status="error"))
        self._pool.shutdown(wait=False, cancel_futures=True)
        _stop_workers(self._pool)
        why = "killed or crashed" if isinstance(exc, BrokenProcessPool) else f"{type(exc).__name__}: {exc}"[:200]
        if restart:
            self._pool = _new_pool()
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "confirm_restarted", "stream": self.stream, "count": len(lost),
                "message": f"the confirmation worker died ({why}); restarted, {len(lost)} event(s) in hand marked error",
            }, None)  # fmt: skip
            return
        self.off = (f"confirmation off: the worker died {self.worker_deaths} times ({why}); {len(lost)} event(s) in hand "
                    "marked error, later IR events skipped; 'gvt confirm LOG' confirms them afterwards")  # fmt: skip
        self.sink(layout.EVENTS_TOPIC, {"kind": "confirm_off", "stream": self.stream, "count": len(lost),
                                        "message": self.off}, None)  # fmt: skip
        if self.say is not None:
            self.say(self.off)

    def _collect(self) -> None:
        """Emit the confirmations that are done. A future failed with BrokenProcessPool means the worker died: every
        one still in hand failed with it, which is one death (``_worker_died``), not one per event."""
        still, broken = [], None
        for ev, fut in self._running:
            if not fut.done():
                still.append((ev, fut))
                continue
            exc = fut.exception()
            if isinstance(exc, BrokenProcessPool):
                broken = exc
                still.append((ev, fut))
            elif exc is not None:  # reported as the event's record; the lane goes on
                self._emit(skipped(ev, f"{type(exc).__name__}: {exc}", status="error"))
            else:
                self._emit(fut.result())
        self._running = still
        if broken is not None:
            self._worker_died(broken)

    def _main_fetch(self) -> None:
        try:
            while not self._ended.is_set():
                try:
                    ev = self.events.get(timeout=0.1)
                except queue.Empty:
                    continue
                if ev is _END_EVENTS:
                    return
                self._waiting.append(ev)
                self._dispatch()
                self._collect()
        except Exception as exc:  # said; the replay is unaffected
            self.error = f"{type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "confirm_error", "stream": self.stream, "message": self.error}, None)

    def _main(self) -> None:
        if self.sub is None:
            self._main_fetch()
            return
        try:
            for blk in self.sub:
                if isinstance(blk, SampleBlock) and blk.stream == self.stream:
                    self.ring.push(blk.first_index, np.asarray(blk.data)[:, self.cols])
                    self._dispatch()
                    self._collect()
        except Exception as exc:  # said on /daq/events; the recording is unaffected
            self.error = f"{type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "confirm_error", "stream": self.stream, "message": self.error}, None)
            for _ in self.sub:
                pass
        if self.sub is not None and self.sub.dropped_blocks:
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "confirm_overrun", "stream": self.stream, "count": self.sub.dropped_samples,
                "message": f"the confirmation lane fell behind and skipped {self.sub.dropped_blocks} blocks "
                           f"({self.sub.dropped_samples} samples); events in those ranges were skipped",
            }, None)  # fmt: skip


class DrainingConfirmLane:
    """A confirmation lane in a recorder's stop order with what the command line adds: progress of the drain
    after the data ends, and ``--no-wait`` (``wait=False``)."""

    name = "confirm"

    def __init__(self, lane: ConfirmLane, progress: Callable[[int, int], None] | None, wait: bool = True) -> None:
        self.lane, self.progress, self.wait = lane, progress, wait

    def offer(self, topic: str, obj: dict) -> None:
        self.lane.offer(topic, obj)

    def finish(self, deadline: float) -> None:
        self.lane.finish(deadline, self.progress, self.wait)

    def cut(self, deadline: float) -> None:
        self.lane.cut(deadline)


def _new_pool() -> ProcessPoolExecutor:
    """One spawned worker that exits when this process dies (daq/children.py)."""
    return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                               initializer=die_with_parent, initargs=(os.getpid(),))  # fmt: skip


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """End the worker processes now: ``shutdown(wait=False)`` lets a running confirmation finish on its own
    (seconds of CPU, ~300 MB), which nobody waits for any more."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        if proc.is_alive():
            proc.terminate()


def start_confirm_lane(
    fan: FanOut, analysis_lane, sink: Sink, settings: LaneSettings = LaneSettings(), log_path: str | None = None,
    confirm_settings: ConfirmSettings | None = None, say: Callable[[str], None] | None = None,
) -> ConfirmLane:  # fmt: skip
    """The confirmation lane beside a started analysis lane (same stream, same rig model). Feed it the
    analysis lane's ``/analysis/events`` with :meth:`ConfirmLane.offer`; join it after the analysis lane.
    ``log_path`` (replay): read each event's samples from the log instead of a ring of the fan-out.
    ``confirm_settings``: an :class:`analysis.confirm.ConfirmSettings` (None: its defaults; bench/bench_confirm.py
    passes ``fast=False`` to time the path before issue 21 in a session)."""
    from analysis.confirm import ConfirmContext, ConfirmSettings

    op = analysis_lane.op
    ctx = ConfirmContext.from_model(op.model, confirm_settings or ConfirmSettings())
    fetch = None
    if log_path is not None:
        from daq.log.reader import LogReader

        reader, sensors, stream = LogReader(log_path), list(op.model.sensors), analysis_lane.stream

        def fetch(a: int, b: int) -> np.ndarray | None:
            d = reader.read_stream(stream, sensors, a / op.fs, b / op.fs)
            return None if d.gaps or d.data.shape[0] == 0 or int(d.index[0]) != a else np.asarray(d.data)

    return ConfirmLane(fan, analysis_lane.stream, tuple(analysis_lane.channels), tuple(op.model.sensors), op.fs, sink, ctx,
                       settings=settings, fetch=fetch, say=say).start()  # fmt: skip
