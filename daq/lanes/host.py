"""The lanes that can wait, in their own process: the recorder's side of the lane host (issue 30, item 1).

Under load the near-live analysis (sensor health, the modal filter, the seed lane) competed with the drivers
and the log writer for the recorder's GIL: a 10-minute session at load 9-22 lost 8.9 % of its samples to writer
overruns. :class:`LaneHost` moves the analysis and confirmation lanes to a worker process
(:mod:`daq.lanes.host_worker`) at a lower priority and keeps in the recorder only what must stay there:

* a bounded fan-out subscription, as the analysis lane had, and a **forwarding thread** that copies each block of
  the analysed stream once into a shared-memory ring (:mod:`daq.lanes.shm_ring`) and sends a ~60-byte
  descriptor. When the ring is full (the worker fell behind) the block is shed and its range counted: the lane
  loses its own input, never the recording's; the ranges are the ``analysis_overrun`` event, as before;
* a **receiver thread** that hands every result record to the session's :class:`~daq.lanes.Results` (so the one
  log writer owns the file, and the view still sees the analysis' records). The window records (~140 a second at
  15 ch x 16384 Hz) come JSON-encoded, in batches (``sink_encoded``, D107): the bytes go to the log as they are;
* two facades in the recorder's stop order (:class:`HostedAnalysis` "analysis", :class:`HostedConfirm`
  "confirm"), each bounded by its deadline: a dead or hung worker is killed at the deadline and what was
  abandoned is said.

A worker that dies (pipe EOF) is restarted once: the samples in flight and those that passed while it restarted
are counted as shed, a ``lane_restarted`` event names that range and the IR events whose confirmations were lost.
A second death switches both lanes off with one line. Why forkserver and not fork: the recorder has threads
(a fork copies locks held by other threads); why not spawn: the fork server imports the analysis once, so a
worker starts in the time of a fork plus the numba cache load, not a fresh interpreter's imports.
"""

from __future__ import annotations

import atexit
import dataclasses
import json
import multiprocessing
import os
import select
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from multiprocessing import shared_memory
from typing import Any

from daq.fanout import FanOut
from daq.lanes.shm_ring import ByteRing, ShedLog
from daq.log import layout
from drivers.blocks import SampleBlock

Sink = Callable[[str, Any, int | None], None]
#: ``sink_encoded([(topic, json bytes, log_time_ns), ...])``: a batch of the worker's records, encoded there
EncodedSink = Callable[[list[tuple[str, bytes, int | None]]], None]
READY_TIMEOUT_S = 120.0  # a cold numba cache compiles ~5 s of kernels on a quiet machine; a loaded one, more
#: the ring holds this much of the analysed stream (at most RING_MAX_BYTES): at nice +10 on a loaded machine the
#: worker is starved for seconds at a time (a 3.2 s session at load 9 shed 1536 samples with a 2 s ring) and catches up
#: after; 8 s of 15 ch x 16384 Hz is 7.9 MB
RING_S = 8.0
#: after the data ends, the worker has this long to analyse what it still holds; then it skips the rest (counted as
#: shed, one line): at nice +10 beside 8 busy loops it worked through a 4 s session's backlog for 44 s, and a
#: recording that has ended is not worth making the engineer wait for a lane that can only shed
END_CATCH_UP_S = 5.0
RING_MAX_BYTES = 64 << 20
_LIVE: weakref.WeakSet[LaneHost] = weakref.WeakSet()


class HostFailed(Exception):
    """The worker did not start (one line: why)."""


def _context():
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["daq.lanes.host_worker"])
    return ctx


@atexit.register
def _kill_all() -> None:  # registered after multiprocessing's own exit handler, so it runs first: nothing to join
    for host in list(_LIVE):
        host.kill()


class LaneHost:
    """The worker process, the ring and the two threads; :meth:`analysis_lane` / :meth:`confirm_lane` are its
    places in the recorder's stop order."""

    def __init__(
        self, fan: FanOut, model, stream: str, channels: tuple[str, ...], fs: float, sink: Sink, settings=None,
        maxsize: int = 512, frame: dict | None = None, confirm: bool = True, ring_s: float = RING_S,
        say: Callable[[str], None] | None = None, base_nice: int = 0, room: Callable[[], bool] | None = None,
        nice_step: int = 10, sink_encoded: EncodedSink | None = None,
    ) -> None:  # fmt: skip
        self.stream, self.channels, self.fs, self.sink, self.say = stream, tuple(channels), fs, sink, say
        self.sink_encoded = sink_encoded  # the worker's JSON-encoded batches (None: decoded and given to ``sink``)
        self.room = room  # False while the log writer's queue is too full for a burst of results (see _receive)
        self.confirm = confirm
        frame_bytes = len(self.channels) * 4
        size = ByteRing.size_for(max(1 << 16, min(int(ring_s * fs) * frame_bytes, RING_MAX_BYTES)))
        self.shm = shared_memory.SharedMemory(create=True, size=size)
        self.ring = ByteRing(self.shm.buf)
        from daq.lanes.host_worker import HostSpec

        self.spec = HostSpec(model, stream, self.channels, fs, settings, dict(frame or {}), confirm, self.shm.name, size,
                             os.getpid(), base_nice, nice_step=nice_step)  # fmt: skip
        self.sub = fan.subscribe(f"analysis:{stream}", maxsize=maxsize)
        self.shed = ShedLog()
        self.events: list[dict] = []  # IR events received (as logged, with their ids)
        self.confirmations: list[dict] = []
        self.latencies_s: list[float] = []
        self.cpu_s = 0.0
        self.pids: list[int] = []
        self.deaths = 0
        self.off: str | None = None
        self.progress: Callable[[int, int], None] | None = None
        self._lock = threading.Lock()
        self._alive = False
        self._inflight: deque[tuple[int, int, int]] = deque()  # (ring end, first index, end index) not yet released
        self._seen_end = 0
        self._end_sent = False
        self._restart_note: tuple[int, list, int | None] | None = None
        self._analysis_done = threading.Event()
        self._summary = threading.Event()
        self._cut_at: float | None = None  # a stop request during the drain: it ends by then (:meth:`cut`)
        self._drain_sent = False
        self.late: list[tuple[int, int]] = []  # ranges the worker skipped after the end (END_CATCH_UP_S)
        self.proc = None
        self._hurry = _context().Event()  # set: the worker skips what it still holds (the end's catch-up is over)
        _LIVE.add(self)
        try:
            self._spawn()
        except BaseException:
            self.kill()
            raise
        self._alive = True
        self._fwd = threading.Thread(target=self._forward, name=f"lanes-fwd:{stream}", daemon=True)
        self._recv = threading.Thread(target=self._receive, name=f"lanes-recv:{stream}", daemon=True)
        self._fwd.start()
        self._recv.start()

    # --- the worker ----------------------------------------------------------------------------------
    def _spawn(self, event_offset: int = 0, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Start a worker and wait for its ``ready`` (its warm-up happens before the device streams)."""
        from daq.lanes.host_worker import main

        ctx = _context()
        to_worker, tx = ctx.Pipe(duplex=False)
        rx, from_worker = ctx.Pipe(duplex=False)
        spec = dataclasses.replace(self.spec, event_offset=event_offset)
        proc = ctx.Process(target=main, args=(spec, to_worker, from_worker, self._hurry), name=f"gvt-lanes:{self.stream}")
        proc.start()
        to_worker.close()
        from_worker.close()  # ours closed: the worker's death is EOF on rx
        _grow(tx)
        self.proc = proc
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                msg = rx.recv() if rx.poll(max(0.0, min(0.5, deadline - time.monotonic()))) else None
            except (EOFError, OSError):
                proc.join(1.0)
                raise HostFailed(f"the lane worker exited during start-up (exit code {proc.exitcode})") from None
            if msg is not None and msg[0] == "ready":
                break
            if msg is not None and msg[0] == "failed":
                proc.join(5.0)
                raise HostFailed(msg[1])
            if time.monotonic() >= deadline:
                proc.kill()
                raise HostFailed(f"the lane worker was not ready within {timeout_s:g} s")
        self.pids.append(msg[1]["pid"])
        self.ready_info = msg[1]
        self._tx, self._rx = tx, rx

    def kill(self) -> None:
        """End the worker now and free the ring (idempotent)."""
        proc = self.proc
        if proc is not None and proc.pid is not None and proc.exitcode is None:
            proc.kill()
            proc.join(2.0)
        if self.shm is not None:
            with self._lock:
                self._alive = False
                self.ring.close()
            try:
                self.shm.close()
            except BufferError:  # a view still held by a thread being torn down: the unlink is what matters
                pass
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass
            self.shm = None
        _LIVE.discard(self)

    # --- the recorder's threads ------------------------------------------------------------------------
    def _forward(self) -> None:
        for blk in self.sub:
            if not isinstance(blk, SampleBlock) or blk.stream != self.stream:
                continue
            self._seen_end = blk.end_index
            with self._lock:
                slot = self.ring.put(blk.data) if self._alive and _writable(self._tx) else None
                if slot is not None:
                    self._prune()
                    self._inflight.append((slot.end, blk.first_index, blk.end_index))
                    tx, note, self._restart_note = self._tx, self._restart_note, None
            if slot is None:
                self.shed.add(blk.stream, blk.first_index, blk.end_index)
                continue
            if note is not None:
                self._restarted(note, blk.first_index)
            try:
                tx.send(("b", blk.first_index, blk.n_samples, blk.data.shape[1], slot.start, slot.end, blk.extra.get("t_host")))
            except (OSError, ValueError):
                pass  # the worker died: the receiver counts this block as in flight
        with self._lock:
            self._end_sent = True
            tx, alive = self._tx, self._alive
        if alive:
            try:
                tx.send(("end",))
            except (OSError, ValueError):
                pass

    def _prune(self) -> None:
        read = self.ring.read_pos
        while self._inflight and self._inflight[0][0] <= read:
            self._inflight.popleft()

    def _receive(self) -> None:
        while True:
            try:
                msg = self._rx.recv()
            except (EOFError, OSError):
                if self._died():
                    continue
                return
            kind = msg[0]
            if kind == "rj":  # a batch of window records, JSON-encoded in the worker (host_worker.Batcher, D107)
                self._wait_for_room()
                if self.sink_encoded is not None:
                    self.sink_encoded(msg[1])
                else:
                    for topic, raw, t in msg[1]:
                        self.sink(topic, json.loads(raw), t)
            elif kind == "r":
                _, topic, obj, t = msg
                self._wait_for_room()
                if topic == layout.IR_EVENTS_TOPIC:
                    self.events.append(obj.to_json() if hasattr(obj, "to_json") else dict(obj))
                elif topic == layout.CONFIRMATIONS_TOPIC:
                    self.confirmations.append(obj)
                self.sink(topic, obj, t)
            elif kind == "say":  # a lane's one console line (the confirmation lane switched off)
                if self.say is not None:
                    self.say(msg[1])
            elif kind == "late":  # what the worker skipped at the end, before its "analysis_done"
                self.late.extend((int(a), int(b)) for a, b in msg[1])
                for a, b in msg[1]:
                    self.shed.add(self.stream, int(a), int(b))
            elif kind == "analysis_done":
                self._analysis_done.set()
            elif kind == "progress" and self.progress is not None:
                self.progress(msg[1], msg[2])
            elif kind == "summary":
                s = msg[1]
                self.cpu_s += s["cpu_s"] - self.ready_info.get("cpu_s", 0.0)  # the lanes' CPU, not the start-up's
                self.latencies_s.extend(s["latencies_s"])
                self._summary.set()
                return

    def _wait_for_room(self, limit_s: float = 1.0) -> None:
        """Results share the log writer's queue with the blocks. A worker that was starved catches up in a burst
        (hundreds of window records at once: 2048 samples overran the writer in a quiet 12 s session, 14 272 with 4
        hogs); the records wait here instead, up to ``limit_s`` each, while the worker waits on its pipe and the ring
        sheds if it must: the lane pays, not the recording."""
        if self.room is None:
            return
        t_end = time.monotonic() + limit_s
        while not self.room() and time.monotonic() < t_end:
            time.sleep(0.005)

    def _died(self) -> bool:
        """The worker is gone (EOF): restart it once (True), or give up (False: finishing, or a second death)."""
        self.proc.join(2.0)
        code = self.proc.exitcode
        self.cpu_s += _cpu_of(self.proc.pid)
        with self._lock:
            self._alive = False
            self._prune()
            lost = list(self._inflight)
            self._inflight.clear()
            finishing = self._end_sent
        for _end, a, b in lost:
            self.shed.add(self.stream, a, b)
        done = {c.get("event", {}).get("id") for c in self.confirmations}
        waiting = [e.get("id") for e in self.events if e.get("id") not in done] if self.confirm else []
        first = lost[0][1] if lost else self._seen_end
        self.deaths += 1
        if finishing or self.deaths >= 2:
            why = "while finishing" if finishing else "a second time"
            self._switch_off(f"the lane worker died {why} (exit code {code}): analysis and confirmation off after sample "
                             f"{first}; {len(waiting)} IR events unconfirmed")  # fmt: skip
            return False
        try:
            self._spawn(event_offset=len(self.events))
        except HostFailed as exc:
            self._switch_off(f"the lane worker died (exit code {code}) and did not restart: {exc}")
            return False
        with self._lock:  # a fresh ring; the end, if it passed while the worker restarted, to the new one
            self.ring.reset()
            self._alive = True
            self._restart_note = (first, waiting, code)
            end_sent, tx = self._end_sent, self._tx
        if end_sent:
            try:
                tx.send(("end",))
            except (OSError, ValueError):
                pass
        return True

    def _restarted(self, note: tuple[int, list, int | None], to_index: int) -> None:
        first, waiting, code = note
        msg = (f"the lane worker died (exit code {code}) and was restarted: samples {first}-{to_index} of {self.stream} "
               f"were not analysed; {len(waiting)} IR events in flight lost their confirmation {waiting}")  # fmt: skip
        self.sink(layout.EVENTS_TOPIC, {"kind": "lane_restarted", "stream": self.stream, "from_index": first,
                                        "to_index": to_index, "events": waiting, "message": msg}, None)  # fmt: skip

    def _switch_off(self, line: str) -> None:
        self.off = line
        self.sink(layout.EVENTS_TOPIC, {"kind": "analysis_error", "stream": self.stream, "message": line}, None)
        if self.say is not None:
            self.say(line)
        self._analysis_done.set()
        self._summary.set()

    # --- finishing (the recorder's stop order) ----------------------------------------------------------
    def finish_analysis(self, deadline: float) -> None:
        """After the fan-out closed: the forwarder sends the end, the worker's last windows and events come back.

        The catch-up time covers the forwarder too: on a loaded host it waits on a pipe the worker at nice +10 does not
        read, and joining it up to the whole deadline held the session 60 s after its data (the load matrix at 8 hogs).
        Once the catch-up time is over, the worker is hurried: it skips what it still holds, which frees the pipe."""
        catch_up = time.monotonic() + max(0.0, min(END_CATCH_UP_S, deadline - time.monotonic()))
        self._fwd.join(max(0.0, catch_up - time.monotonic()))
        if not self._analysis_done.wait(max(0.0, catch_up - time.monotonic())):
            self._hurry.set()  # the worker skips the rest and says which ranges
            self._fwd.join(max(0.0, deadline - time.monotonic()))
            if not self._analysis_done.wait(max(0.0, deadline - time.monotonic())):
                self._abandon("the analysis of the stream's last blocks")
                self._recv.join(3.0)  # the killed worker's EOF: its in-flight blocks become shed ranges (``_died``)
                with self._lock:  # and what is still listed, were the receiver slower, before the count is written
                    self._prune()
                    left, self._inflight = list(self._inflight), deque()
                for _end, a, b in left:
                    self.shed.add(self.stream, a, b)
        if self.late:
            n = sum(b - a for a, b in self.late)
            line = (f"analysis: the last {n / self.fs:.1f} s of {self.stream} were not analysed: the lane was that far behind "
                    f"when the data ended and had {END_CATCH_UP_S:g} s to catch up (it runs below the recorder's priority)")
            if self.say is not None:
                self.say(line)
        with self._lock:
            note, self._restart_note = self._restart_note, None
        if note is not None:
            self._restarted(note, self._seen_end)
        sub = self.sub
        blocks, samples = self.shed.blocks + sub.dropped_blocks, self.shed.samples + sub.dropped_samples
        if blocks:
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "analysis_overrun", "stream": self.stream, "count": samples,
                "ranges": _merge([(a, b) for _s, a, b in self.shed.ranges + sub.dropped_ranges])[:1000],
                "message": f"the analysis fell behind and skipped {blocks} blocks ({samples} samples); it restarted after "
                           "each gap",
            }, None)  # fmt: skip

    def _until(self, deadline: float) -> float:
        return deadline if self._cut_at is None else min(deadline, self._cut_at)

    def cut(self, deadline: float) -> None:
        """A stop request (Ctrl-C, SIGTERM) arrived: the drain ends by ``deadline`` at the latest. The worker is told
        (its confirmation lane records what it then abandons as skipped, for ``gvt confirm``), keeping a second for
        its last records to come back; a worker that does not answer is killed at ``deadline``."""
        self._cut_at = self._until(deadline)
        with self._lock:
            if self._alive and self._drain_sent:
                try:
                    self._tx.send(("cut", max(0.0, self._cut_at - time.monotonic() - 1.0)))
                except (OSError, ValueError):
                    pass

    def finish_all(self, deadline: float, wait: bool = True) -> None:
        """The confirmations drain (``wait=False``: none waited for), then the worker is stopped, by ``deadline``
        (or by an earlier one a stop request gives, :meth:`cut`)."""
        if not self._summary.is_set() and self._lock.acquire(timeout=max(0.0, min(1.0, deadline - time.monotonic()))):
            try:
                if self._alive:
                    self._tx.send(("drain", max(0.0, self._until(deadline) - time.monotonic() - 1.0), wait))
                    self._drain_sent = True
            except (OSError, ValueError):
                pass
            finally:
                self._lock.release()
        while not self._summary.wait(0.1) and time.monotonic() < self._until(deadline):
            pass
        if not self._summary.is_set():
            done = {c.get("event", {}).get("id") for c in self.confirmations}
            left = [e.get("id") for e in self.events if e.get("id") not in done] if self.confirm else []
            self._abandon(f"{len(left)} unconfirmed IR events {left}" if left else "its last results")
        proc = self.proc
        if proc is not None:
            proc.join(min(3.0, max(0.5, self._until(deadline) - time.monotonic())))
            if proc.exitcode is None:
                self.cpu_s += _cpu_of(proc.pid)
        self.kill()
        self._recv.join(1.0)

    def _abandon(self, what: str) -> None:
        line = f"the lane worker did not finish by its deadline: abandoned {what}"
        self.sink(layout.EVENTS_TOPIC, {"kind": "lane_abandoned", "stream": self.stream, "message": line}, None)
        if self.say is not None:
            self.say(line)
        with self._lock:
            self._alive = False
        if self.proc is not None and self.proc.exitcode is None:
            self.proc.kill()
        self._analysis_done.set()
        self._summary.set()

    # --- the facades ------------------------------------------------------------------------------------
    def analysis_lane(self) -> HostedAnalysis:
        return HostedAnalysis(self)

    def confirm_lane(self, progress: Callable[[int, int], None] | None = None, wait: bool = True) -> HostedConfirm:
        self.progress = progress
        return HostedConfirm(self, wait)


def _merge(ranges: list[tuple[int, int]]) -> list[list[int]]:
    out: list[list[int]] = []
    for a, b in sorted(ranges):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


def _grow(conn, size: int = 1 << 20) -> None:
    """Room in the descriptor pipe for every record the ring can hold (64 KiB held ~900 descriptors, fewer than 8 s
    of 64-sample serial blocks); best effort (Linux ``F_SETPIPE_SZ``, capped by /proc/sys/fs/pipe-max-size)."""
    try:
        import fcntl

        fcntl.fcntl(conn.fileno(), fcntl.F_SETPIPE_SZ, size)
    except (ImportError, AttributeError, OSError):
        pass


def _writable(conn) -> bool:
    """The descriptor can be sent without waiting (a pipe is writable with at least PIPE_BUF bytes free, and a
    descriptor is ~60): a forwarder never blocks on a starved worker, it sheds and counts."""
    try:
        return bool(select.select([], [conn.fileno()], [], 0)[1])
    except (OSError, ValueError):
        return False


def _cpu_of(pid: int | None) -> float:
    """CPU seconds (user + system) of a live or not yet reaped process, from /proc (0 where unavailable)."""
    try:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, TypeError):
        return 0.0


class HostedAnalysis:
    """The analysis lane's place in the recorder (stop order "analysis"); without a confirmation lane it also
    stops the worker."""

    name = "analysis"

    def __init__(self, host: LaneHost) -> None:
        self.host = host
        self.stream = host.stream

    def offer(self, topic: str, obj: dict) -> None:
        pass

    def finish(self, deadline: float) -> None:
        self.host.finish_analysis(deadline)
        if not self.host.confirm:
            self.host.finish_all(deadline)


class HostedConfirm:
    """The confirmation lane's place in the recorder (stop order "confirm"): the drain, bounded, then the worker
    stops. ``wait=False``: ``gvt record --no-wait``."""

    name = "confirm"

    def __init__(self, host: LaneHost, wait: bool) -> None:
        self.host, self.wait = host, wait

    def offer(self, topic: str, obj: dict) -> None:  # its IR events reach it inside the worker
        pass

    def finish(self, deadline: float) -> None:
        self.host.finish_all(deadline, self.wait)

    def cut(self, deadline: float) -> None:
        self.host.cut(deadline)


def start_lane_host(
    fan: FanOut, rig, streams: dict[str, tuple[str, ...]], fs: float, sink: Sink, settings=None, maxsize: int = 512,
    frame: dict | None = None, confirm: bool = True, say: Callable[[str], None] | None = None, base_nice: int = 0,
    room: Callable[[], bool] | None = None, nice_step: int = 10, sink_encoded: EncodedSink | None = None,
) -> LaneHost:  # fmt: skip
    """The analysis (and confirmation) lanes of ``rig`` in a worker; :class:`~daq.lanes.analysis.LaneUnavailable`
    (one line) when the rig does not fit the streams or the worker does not start."""
    from daq.lanes.analysis import LaneUnavailable, rig_stream

    model, name = rig_stream(rig, streams)
    try:
        return LaneHost(fan, model, name, streams[name], fs, sink, settings, maxsize, frame, confirm, say=say,
                        base_nice=base_nice, room=room, nice_step=nice_step, sink_encoded=sink_encoded)  # fmt: skip
    except HostFailed as exc:
        raise LaneUnavailable(f"rig {rig.name}: {exc}") from None
