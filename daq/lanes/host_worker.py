"""The lane-host worker process: the near-live analysis and the confirmation lane, away from the recorder.

Started by :class:`daq.lanes.host.LaneHost` (forkserver: the recorder has threads, so no plain fork), at nice
+10 (:mod:`daq.priority`; the confirmation pool it spawns inherits that). Everything slow happens here *before*
the device streams: imports (preloaded in the fork server), the rig model, the numba cache load and the
operator's warm-up; then one ``ready`` message. The worker runs the same lanes as an in-process session
(:class:`~daq.lanes.analysis.AnalysisLane`, :class:`~daq.lanes.confirm.ConfirmLane`) with its own
:class:`~daq.lanes.Results`: the analysis' IR events go to the confirmation lane here, and every result record
goes back to the recorder, whose one log writer owns the file.

Protocol (tuples through two one-way pipes; the sample data through the ring, :mod:`daq.lanes.shm_ring`):

* recorder → worker: ``("b", first_index, n, n_channels, start, end, t_host)`` a block in the ring;
  ``("end",)`` the stream ended; ``("drain", seconds, wait)`` finish the confirmations; during the drain
  ``("cut", seconds)`` a stop request: end it within ``seconds``;
* worker → recorder: ``("ready", info)`` | ``("failed", line)`` at start-up; ``("r", topic, obj, log_time_ns)``
  an IR event, a confirmation, an event or a hit (the recorder reads their fields); ``("rj", [(topic, json bytes,
  log_time_ns), ...])`` the other results (the window records), encoded here and sent together at most every
  ``BATCH_S`` (:class:`Batcher`, D107); ``("analysis_done",)``; ``("progress", done, total)``; ``("summary", dict)``
  last. Every message leaves after the records before it (a batch is sent first).
"""

from __future__ import annotations

import dataclasses
import json
import mmap
import os
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from analysis.operator import AnalysisSettings, RigModel
from daq.fanout import END, FanOut
from daq.lanes import Results
from daq.lanes.analysis import AnalysisLane
from daq.lanes.shm_ring import ByteRing
from daq.log import layout
from daq.priority import lower_priority
from drivers.blocks import SampleBlock


@dataclass(frozen=True)
class HostSpec:
    """What the worker needs to build its lanes (pickled once, at start)."""

    model: RigModel
    stream: str
    channels: tuple[str, ...]
    sample_rate: float
    settings: AnalysisSettings | None
    frame: dict
    confirm: bool
    shm_name: str
    ring_bytes: int
    recorder_pid: int
    base_nice: int
    event_offset: int = 0  # IR event ids already used by a worker that died (a restart numbers on)
    nice_step: int = 10  # the worker's nice: the recorder's starting value + this


#: the window records wait here at most this long (and at most BATCH_MAX of them) before they go to the recorder together
BATCH_S = 0.2
BATCH_MAX = 64
#: results the recorder needs as objects, sent one by one: it keeps the IR events and confirmations, and the log lane
#: reads the fields of events and hits
OBJECT_TOPICS = frozenset({layout.IR_EVENTS_TOPIC, layout.CONFIRMATIONS_TOPIC, layout.EVENTS_TOPIC, layout.HITS_TOPIC})


class Batcher:
    """The worker's pipe to the recorder: the window records JSON-encoded and sent in batches, everything else at once
    (after the batch that came before it, so the order holds).

    Why (issue 30 item 5, D107): ~140 window records a second at 15 ch x 16384 Hz, each a pickled message, cost the
    recording process a pipe read and an unpickling per record, and its log writer a JSON encoding and a queue turn
    per record (~0.02 core of its 0.1). Encoded here, the bytes are what the writer would have written
    (``json.dumps(dict(obj), separators=(",", ":"))``); the log is the same, message for message."""

    def __init__(self, tx) -> None:
        self.tx = tx
        self.lock = threading.Lock()
        self.items: list[tuple[str, bytes, int | None]] = []
        self.since = 0.0
        threading.Thread(target=self._tick, name="results-batch", daemon=True).start()

    def send(self, msg: tuple) -> None:
        with self.lock:
            self._flush()
            self.tx.send(msg)

    def record(self, topic: str, obj: Any, t: int | None) -> None:
        if topic in OBJECT_TOPICS:
            self.send(("r", topic, obj, t))
            return
        raw = json.dumps(dict(obj), separators=(",", ":")).encode()
        with self.lock:
            if not self.items:
                self.since = time.monotonic()
            self.items.append((topic, raw, t))
            if len(self.items) >= BATCH_MAX or time.monotonic() - self.since >= BATCH_S:
                self._flush()

    def _flush(self) -> None:
        if self.items:
            items, self.items = self.items, []
            self.tx.send(("rj", items))

    def _tick(self) -> None:
        """A batch never waits longer than BATCH_S for the next record (the stream paused, or ended)."""
        while True:
            time.sleep(BATCH_S / 2)
            try:
                with self.lock:
                    if self.items and time.monotonic() - self.since >= BATCH_S:
                        self._flush()
            except (OSError, ValueError):  # the recorder is gone
                return


class RingFeed:
    """The analysis lane's "subscription" in the worker: blocks rebuilt over the ring, from the recorder's
    descriptors. Nothing is dropped here (the recorder sheds when the ring is full and counts it)."""

    dropped_blocks = 0
    dropped_samples = 0

    def __init__(self, rx, ring: ByteRing, spec: HostSpec, hurry=None) -> None:
        self.rx, self.ring, self.spec, self.hurry = rx, ring, spec, hurry
        self.late: list[tuple[int, int]] = []  # blocks skipped once the recorder's catch-up time was over
        self.pending: deque[tuple[int, int]] = deque()  # (end sample index, ring end position) handed out
        self.publish = None  # the confirmation lane's fan-out (it keeps its own copy of the sensor columns)

    def subscribe(self, name: str, maxsize: int = 0) -> RingFeed:  # AnalysisLane subscribes to its "fan-out"
        return self

    def get(self, timeout: float | None = None) -> SampleBlock | object:
        if timeout is not None and not self.rx.poll(timeout):
            raise queue.Empty
        try:
            msg = self.rx.recv()
        except (EOFError, OSError):  # the recorder is gone
            return END
        while msg[0] == "b" and self.hurry is not None and self.hurry.is_set():  # the end's catch-up is over: skip
            late = self.late
            if late and late[-1][1] == msg[1]:
                late[-1] = (late[-1][0], msg[1] + msg[2])
            else:
                late.append((msg[1], msg[1] + msg[2]))
            try:
                msg = self.rx.recv()
            except (EOFError, OSError):
                return END
        if msg[0] != "b":
            return END
        _, first, n, ncols, start, end, t_host = msg
        s = self.spec
        data = self.ring.view(start, (n, ncols))  # in place: the operator copies what it keeps
        self.pending.append((first + n, end))
        extra = {} if t_host is None else {"t_host": t_host}
        if self.publish is not None:
            self.publish(SampleBlock(s.stream, first, s.sample_rate, s.channels, data.copy(), extra=extra))
        return SampleBlock(s.stream, first, s.sample_rate, s.channels, data, extra=extra)

    def release_through(self, frame: SampleBlock) -> None:
        """The operator has consumed everything up to ``frame``'s end: give those records back to the writer."""
        last = None
        while self.pending and self.pending[0][0] <= frame.end_index:
            last = self.pending.popleft()[1]
        if last is not None:
            self.ring.release(last)

    def __iter__(self):
        while (item := self.get()) is not END:
            self.release_through(item)
            yield item


def attach(name: str, size: int) -> mmap.mmap:
    """The recorder's shared memory, mapped without registering it with a resource tracker (the recorder
    created it and unlinks it; a second registration made Python 3.11 warn of a leak at exit)."""
    fd = os.open(f"/dev/shm/{name.lstrip('/')}", os.O_RDWR)
    try:
        return mmap.mmap(fd, size)
    finally:
        os.close(fd)


def _watch(pid: int, every_s: float = 0.5) -> None:
    """Exit when the recorder is gone (SIGKILL included): the fork server, not the recorder, is our parent."""

    def run() -> None:
        while True:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except PermissionError:
                pass
            time.sleep(every_s)

    threading.Thread(target=run, name="watch-recorder", daemon=True).start()


class _Host:
    def __init__(self, spec: HostSpec, rx, send, hurry=None, record=None) -> None:
        self.spec, self.rx, self.send, self.record = spec, rx, send, record
        self.mem = attach(spec.shm_name, spec.ring_bytes)
        self.feed = RingFeed(rx, ByteRing(self.mem), spec, hurry)
        self.results = Results(log=self._to_recorder)
        self.lane = AnalysisLane(self.feed, spec.model, spec.stream, spec.channels, spec.sample_rate, self._from_lane,
                                 spec.settings, **spec.frame)  # fmt: skip (warm_up: kernels built or loaded now)
        self.lane.after_feed = self.feed.release_through
        self.confirm = None
        if spec.confirm:
            from daq.lanes.confirm import start_confirm_lane

            cfan = FanOut()
            self.confirm = start_confirm_lane(cfan, self.lane, self.results.emit,
                                              say=lambda line: self.send(("say", line)))  # the recorder's console
            self.results.route(self.confirm, [layout.IR_EVENTS_TOPIC])
            self.feed.publish, self.cfan = cfan.publish, cfan

    def _from_lane(self, topic: str, obj: Any, t: int | None) -> None:
        if topic == layout.IR_EVENTS_TOPIC and self.spec.event_offset and dataclasses.is_dataclass(obj):
            obj = dataclasses.replace(obj, id=obj.id + self.spec.event_offset)
        self.results.emit(topic, obj, t)

    def _to_recorder(self, topic: str, obj: Any, t: int | None) -> None:
        if self.record is not None:
            self.record(topic, obj, t)
        else:
            self.send(("r", topic, obj, t))

    def run(self) -> None:
        self.lane.start()
        self.lane.join()  # until the recorder's END (the operator's last windows and events are sent by then)
        if self.feed.late:
            self.send(("late", list(self.feed.late)))
        self.send(("analysis_done",))
        try:
            msg = self.rx.recv()
        except (EOFError, OSError):
            return
        seconds, wait = (msg[1], msg[2]) if msg[0] == "drain" else (0.0, False)
        if self.confirm is not None:
            self.cfan.close()
            threading.Thread(target=self._cuts, name="drain-cut", daemon=True).start()
            self.confirm.finish(time.monotonic() + seconds, lambda d, n: self.send(("progress", d, n)), wait)
        op = self.lane.op
        self.send(("summary", {"cpu_s": time.process_time(), "latencies_s": list(op.stats.latencies_s),
                               "error": self.lane.error, "events": len(op.events)}))  # fmt: skip


    def _cuts(self) -> None:
        """During the drain: a stop request's ``("cut", seconds)`` shortens it (the recorder sends nothing else)."""
        while True:
            try:
                msg = self.rx.recv()
            except (EOFError, OSError):
                return
            if msg[0] == "cut" and self.confirm is not None:
                self.confirm.cut(time.monotonic() + msg[1])


def main(spec: HostSpec, rx, tx, hurry=None) -> None:
    """The worker's entry point (``rx``: from the recorder, ``tx``: to it)."""
    _watch(spec.recorder_pid)
    batcher = Batcher(tx)
    send = batcher.send
    t0 = time.perf_counter()
    try:
        host = _Host(spec, rx, send, hurry, batcher.record)
    except Exception as exc:  # one line to the recorder, which records without the lanes
        send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    # the start-up (imports, model, warm-up) runs at the recorder's priority, before the device streams: at +10 beside
    # 8 busy loops it took ~40 s of a session's start; the lanes run below the recorder from here on
    nice = lower_priority(spec.base_nice, spec.nice_step)
    send(("ready", {"pid": os.getpid(), "nice": nice, "start_s": time.perf_counter() - t0, "cpu_s": time.process_time()}))
    try:
        host.run()
    except (BrokenPipeError, EOFError, OSError):  # the recorder went away: nothing left to tell
        pass
