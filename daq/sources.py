"""Sources of sample blocks for a :class:`~daq.recorder.Recorder`: a device (a driver and its reading thread),
or a log being replayed.

A device source is the recording path: each block goes to the log lane first (never blocked by anyone),
then to the fan-out. When it ends is the session's business, and it ends only for a reason it can state
(docs/session.md, "When a session ends"):

* the stream reached the session's **duration in data time** (``end_index``: the first sample index plus
  duration × fs); the block that crosses it is cut so that the log holds exactly that span;
* the driver ended or died (the error is kept, one line);
* the recorder told it to stop (Ctrl-C, SIGTERM, the wall-clock deadline, a writer failure).

A quiet link never ends it: silence longer than ``silence_s`` is a ``silence`` event with its range
(the sample index where the data stopped and where it resumed, and how long on the host clock), and the
driver reconnects as it already can.

**Joined blocks** (``join_s``, issue 30 item 5): the reading thread takes what the driver queued, joins the
contiguous flag-free runs (:func:`drivers.blocks.join_runs`: nothing moves, nothing is lost), records them, then
waits ``join_s`` before it takes the next batch. A serial device's 64-sample frames (256 a second at 16384 Hz)
then cost the writer, the hit gate and the lanes ~20 blocks a second instead of 256: each block costs every
consumer a fixed Python overhead, most of the recording process's CPU at that rate; the driver may let its input
gather too (``Driver.gather_s``: the serial driver reads every 20 ms instead of at every frame). The first block is taken
the moment it arrives (its arrival stamp gives the session's UTC origin); later stamps are late by up to
``join_s``, which is why a session with a second device, whose clock offset is estimated from the arrival
stamps of every block, does not join (``join_s = 0``: block by block, as the driver delivers them).
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from daq.fanout import FanOut
from daq.lanes import Sink
from daq.lanes.log import LogLane
from daq.log import layout
from drivers.base import Driver, DriverError
from drivers.blocks import SampleBlock, join_runs


class Source(Protocol):
    """What a recorder needs of a source of blocks (a device, or a log being replayed)."""

    name: str
    need: int | None  # samples the session asks of it (None: until stopped)
    report: SourceReport
    done: threading.Event  # set when it stopped putting blocks on the fan-out, for any reason

    def open(self) -> None: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...
    def join(self, timeout: float) -> None: ...
    def drain_events(self) -> None: ...
    def failure(self) -> tuple[str, int] | None:
        """(one line, exit code) when it ended because something failed; None otherwise."""


@dataclass
class SourceReport:
    """What one source recorded and why it ended."""

    name: str
    samples: int = 0
    end_index: int | None = None  # the data-time end the session asked for (None: until stopped)
    reached_end: bool = False
    last_index: int | None = None  # one past the last sample recorded
    error: str | None = None
    silences: list[tuple[int, int, float]] = field(default_factory=list)  # (last index before, first after, seconds)


#: a joined batch takes at most this many queued blocks, and joins blocks up to this many samples (a larger block
#: from the driver is never split): 4096 samples of 64 channels are 1 MB, a backlog burst after a stall stays bounded
JOIN_MAX_BLOCKS = 256
JOIN_MAX_SAMPLES = 4096
#: the wait between joined batches of a single-device session (module docstring): ~13 serial frames at 16384 Hz; the
#: hit gate and the lanes see the data this much later, the log's crash bound grows by as much
JOIN_S = 0.05
#: ... cut short when the driver holds this many blocks (a quarter of its default queue)
JOIN_WAKE_BLOCKS = 64
#: ... and how long the driver may let input gather before it reads (``Driver.gather_s``)
GATHER_S = 0.02


class DeviceSource:
    """One device: its driver, opened and closed here, and the thread that reads it."""

    def __init__(
        self, name: str, driver: Driver, log: LogLane | None, fan: FanOut, sink: Sink, *, need_samples: int | None,
        silence_s: float, poll_s: float = 0.1, held: bool = False, join_s: float = 0.0,
    ) -> None:  # fmt: skip
        self.name = name
        self.driver = driver
        self.log = log
        self.fan = fan
        self.sink = sink
        self.need = need_samples
        self.silence_s = silence_s
        self.poll_s = poll_s
        self.join_s = join_s
        if join_s > 0:  # the driver may gather input too (a serial port: reads per 20 ms instead of per frame)
            driver.gather_s = min(join_s, GATHER_S)
        self.report = SourceReport(name)
        #: a second device's streams wait in the writer for the timeline's clock offset: each one's first index
        #: is logged at once (a ``stream_held`` event), so a recorder killed before the offset is fixed leaves
        #: a trace of what it held (issue 30)
        self.held = held
        self._held_seen: set[str] = set()
        #: per stream: (channels, peak |value| per channel since the last status); CAN streams' channels come from the DBC
        self._levels: dict[str, tuple[tuple[str, ...], np.ndarray]] = {}
        self.levels_lock = threading.Lock()
        self.events: dict[str, int] = {}
        #: sample ranges (start, end) the driver's full queue dropped inside the session: never written, so lost like
        #: a gap on the wire (the session adds them to its lost samples and exit code 3; before, only an event said so)
        self.queue_lost: list[tuple[int, int]] = []
        self.done = threading.Event()
        self._stop = threading.Event()
        self._last_t: float | None = None
        self._silent_since: float | None = None
        self._thread: threading.Thread | None = None
        self._opened = False
        self._finish_by: float | None = None  # a stop's drain of what the device holds ends by then (``stop``)

    # --- owner side -----------------------------------------------------------------------------------
    def open(self) -> None:
        """Open the link (raises :class:`DriverError`, one line; a link budget error is bad input)."""
        self.driver.open()
        self._opened = True

    def start(self) -> None:
        self._last_t = time.monotonic()  # a device that never starts delivering is silent from here
        self._thread = threading.Thread(target=self._main, name=f"read:{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop reading and close the link (the driver's own thread ends with it). A driver whose device holds
        samples it has not sent yet (``finish``: a Modbus FIFO) first delivers them within its own bound, and this
        thread records them until the driver's blocks end; :meth:`join` waits for that, then closes the link.
        Before, this thread stopped at once and they were never written, without a word. A source that reached its
        duration has nothing left to take: closed at once."""
        finish = getattr(self.driver, "finish", None)
        if finish is not None and self._opened and self._thread is not None and not self.done.is_set():
            self._finish_by = time.monotonic() + finish() + 1.0  # its bound, and a second to hand over the last block
            return
        self._halt()

    def _halt(self) -> None:
        self._stop.set()
        if self._opened:
            self._opened = False
            try:
                self.driver.close()
            except Exception as exc:  # a link that fails to close is said, never a traceback
                self.report.error = self.report.error or f"closing the link failed: {type(exc).__name__}: {exc}"

    def join(self, timeout: float) -> None:
        if self._finish_by is not None and self._thread is not None:
            t_end = time.monotonic() + timeout
            self._thread.join(max(0.0, min(t_end, self._finish_by) - time.monotonic()))
            self._finish_by = None
            self._halt()
            timeout = max(0.0, t_end - time.monotonic())
        if self._thread is not None:
            self._thread.join(timeout)

    def take_levels(self) -> dict[str, float]:
        """Peak |value| per channel since the last call (the live status)."""
        out: dict[str, float] = {}
        with self.levels_lock:
            for chans, lv in self._levels.values():
                out.update(zip(chans, lv.tolist(), strict=True))
                lv[:] = 0
        return out

    def failure(self) -> tuple[str, int] | None:
        if self.report.error is None:
            return None
        return f"the driver stopped: {self.name}: {self.report.error}", 1

    @property
    def silent_for(self) -> float:
        """Seconds without a block right now (0 while data flows)."""
        return 0.0 if self._last_t is None else max(0.0, time.monotonic() - self._last_t)

    # --- the reading thread ---------------------------------------------------------------------------
    def _main(self) -> None:
        try:
            while not self._stop.is_set():
                if self.join_s > 0:
                    took = self._joined_batch()
                    if took is None:
                        return
                    if took:
                        continue  # more may be queued behind an ended driver: look only after an empty poll
                else:
                    for blk in self.driver.blocks(timeout=self.poll_s):
                        if not self._on_block(blk) or self._stop.is_set():
                            return
                if not self.driver.alive:  # ended: what it queued before its end marker is still the recording's
                    for blk in self.driver.blocks(timeout=0.0):
                        if not self._on_block(blk):
                            return
                    return
                self._watch_silence(time.monotonic())
        except DriverError as exc:
            self.report.error = str(exc)
            self.sink(layout.EVENTS_TOPIC, {"kind": "driver_error", "stream": self.name, "message": str(exc)}, None)
        except Exception as exc:  # never a traceback from a reading thread: the session stops and says why
            self.report.error = f"reading {self.name} failed: {type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "driver_error", "stream": self.name, "message": self.report.error}, None)
        finally:
            self._close_silence(None)
            self.drain_events()
            self.done.set()

    def _joined_batch(self) -> bool | None:
        """The first block (waiting up to ``poll_s``) and whatever queued behind it, joined and recorded; then wait
        ``join_s`` while the next batch queues up. True if it took blocks, False if none came within ``poll_s``
        (silence, or the driver ended: the caller looks), None once the duration is reached or a stop came."""
        first = next(iter(self.driver.blocks(timeout=self.poll_s)), None)
        if first is None:
            return False
        batch, failed = [first], None
        try:
            batch.extend(itertools.islice(self.driver.blocks(timeout=0.0), JOIN_MAX_BLOCKS))
        except DriverError as exc:  # the driver died behind these blocks: record them first
            failed = exc
        for blk in join_runs(batch, max(first.n_samples, JOIN_MAX_SAMPLES)):
            if not self._on_block(blk) or self._stop.is_set():
                return None
        if failed is not None:
            raise failed
        return None if self._wait_for_batch(len(batch)) else True

    def _wait_for_batch(self, taken: int) -> bool:
        """Wait ``join_s`` for the next batch, in 10 ms steps, and stop waiting as soon as the driver holds
        ``JOIN_WAKE_BLOCKS`` (a backlog arriving: a device that delivers what it held when the link opened, or
        after a stall, decodes thousands of frames a second and would fill the driver's queue of 256 within one
        50 ms wait: measured, 216-283 blocks dropped a session). True if a stop came."""
        if taken >= JOIN_WAKE_BLOCKS:
            return self._stop.is_set()  # behind: take the next batch at once
        until = time.monotonic() + self.join_s
        while (left := until - time.monotonic()) > 0:
            if self._stop.wait(min(left, 0.01)):
                return True
            if self.driver.queued() >= JOIN_WAKE_BLOCKS:
                return False
        return False

    def _on_block(self, blk: SampleBlock) -> bool:
        """Record one block; False once the session's duration is reached."""
        now = time.monotonic()
        if self._silent_since is not None or (self._last_t is not None and now - self._last_t > self.silence_s):
            self._close_silence(blk.first_index)
        self._last_t = now
        # arrival: the clock-offset estimate's input, and the analysis' latency origin; a driver that knows when the
        # block's first byte came (serial: Driver extra "t_arrival", D95) gives that, which does not grow with its length
        blk.extra["t_host"] = blk.extra.get("t_arrival", now)
        rep = self.report
        if self.need is not None:
            if rep.end_index is None:
                start = self.driver.config.expect_first_index
                rep.end_index = (blk.first_index if start is None else start) + self.need
            if blk.first_index >= rep.end_index:
                rep.reached_end = True
                return False
            if blk.end_index > rep.end_index:  # cut the block at the session's end: exactly duration × fs
                n = rep.end_index - blk.first_index
                blk = SampleBlock(blk.stream, blk.first_index, blk.sample_rate, blk.channels, blk.data[:n], blk.status, blk.extra)
        if self.held and blk.stream not in self._held_seen:
            self._held_seen.add(blk.stream)
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "stream_held", "stream": blk.stream, "first_index": blk.first_index,
                "message": f"{blk.stream} held in memory from sample {blk.first_index} until the clock offset is fixed",
            }, None)  # fmt: skip
        if self.log is not None:
            self.log.write_block(blk, wait=not self.driver.realtime)
        self.fan.publish(blk)
        rep.samples += blk.n_samples
        rep.last_index = blk.end_index
        if blk.n_samples:  # peak |value| per channel, in place (one array per stream: CAN may have several)
            with self.levels_lock:
                lv = self._levels.get(blk.stream)
                if lv is None or lv[0] != blk.channels:
                    lv = self._levels[blk.stream] = (blk.channels, np.zeros(len(blk.channels), np.float32))
                np.maximum(lv[1], np.abs(blk.data).max(axis=0), out=lv[1])
        if not self.driver.events.empty():
            self.drain_events()
        if rep.end_index is not None and blk.end_index >= rep.end_index:
            rep.reached_end = True
            return False
        return True

    def drain_events(self) -> None:
        end, last = self.report.end_index, self.report.last_index
        if self._stop.is_set() and last is not None:  # a stop request ends the recording where it stands
            end = last if end is None else min(end, last)
        for ev in self.driver.drain_events():
            d = ev.as_dict()
            if ev.kind == "overrun" and end is not None and (d.get("start_index") or 0) >= end:
                # a block past the session's end, dropped because this source stopped reading at the end: never part
                # of the recording, so not a loss (issue 30 item 6; a loaded host left 371 such "overrun" events)
                self.events["overrun_after_end"] = self.events.get("overrun_after_end", 0) + 1
                continue
            if ev.kind == "overrun" and d.get("start_index") is not None and d.get("end_index") is not None:
                a, b = int(d["start_index"]), int(d["end_index"])
                b = b if end is None else min(b, end)  # a block the end cuts: only its part inside the session is lost
                if b > a:
                    self.queue_lost.append((a, b))
            self.events[ev.kind] = self.events.get(ev.kind, 0) + 1
            self.sink(layout.EVENTS_TOPIC, d, None)

    def _watch_silence(self, now: float) -> None:
        if self._silent_since is None and self._last_t is not None and now - self._last_t > self.silence_s:
            self._silent_since = self._last_t

    def _close_silence(self, resumed_at: int | None) -> None:
        """The link was quiet longer than ``silence_s`` and now delivers again (or the session ends): one event."""
        if self._last_t is None:
            return
        now = time.monotonic()
        quiet = now - self._last_t
        if self._silent_since is None and not (resumed_at is not None and quiet > self.silence_s):
            return
        self._silent_since = None
        last = self.report.last_index
        after = "the start" if last is None else f"sample {last}"
        ev: dict = {"kind": "silence", "stream": self.name, "seconds": round(quiet, 3)}
        if last is not None:
            ev["start_index"] = last
            ev["end_index"] = resumed_at if resumed_at is not None else last
        if resumed_at is None:
            ev["message"] = f"no data for {quiet:.2f} s (host clock) after {after}, until the session ended"
        else:
            ev["message"] = f"no data for {quiet:.2f} s (host clock) after {after}; resumed at sample {resumed_at}"
        self.report.silences.append((-1 if last is None else last, -1 if resumed_at is None else resumed_at, quiet))
        self.events["silence"] = self.events.get("silence", 0) + 1
        self.sink(layout.EVENTS_TOPIC, ev, None)
