"""The driver interface: one way to get SampleBlocks out of any DAQ link (serial, CAN, Modbus, sim).

Modelled on python-can's ``Bus``: a driver is configured from TOML (a pydantic model per driver),
discovered through the ``gvtlink.drivers`` entry-point group, opened and closed as a context manager,
and read as an iterator of :class:`~drivers.blocks.SampleBlock`. What peers get wrong and this gets right
(landscape.md §2.1, §2.8, §4):

* **Exact loss accounting.** Subclasses call :meth:`Driver._emit` with blocks that carry the device's
  own sample index. A jump in the index is a gap: the exact missing range is recorded as a
  :class:`DriverEvent` with its cause, and the block is flagged ``GAP_BEFORE``. CRC/frame errors,
  timeouts, reconnects and overruns are counted in :class:`LinkStats`.
* **An index is checked before it is believed** (:mod:`drivers.sequence`, the same kernel for every
  transport): one wild frame is rejected and counted (``implausible_index``), a device restart starts a
  new *segment* of the stream (``restart`` event, ``RESTART`` flag) instead of being stitched onto the
  old data. Blocks leave the driver with a *stream* index (device index + segment offset) that is
  continuous and monotonic and always fits a log's int64 nanosecond time.
* **A dying driver thread is never silent.** The reader thread's exception is stored and raised to the
  owner from :meth:`Driver.blocks` (as :class:`DriverError`), after every block read before it.
* **Bounded everything.** Blocks wait in a bounded queue; if the owner stops reading, the driver counts
  an overrun with the exact range instead of growing without limit.
"""

from __future__ import annotations

import queue
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

from analysis.errors import RuntimeFailure
from drivers.blocks import BlockStatus, SampleBlock
from drivers.sequence import Accepted, Dropped, StreamSequencer

ENTRY_POINT_GROUP = "gvtlink.drivers"


class DriverError(RuntimeFailure):
    """A driver failed; the message says what and how to fix it (one line)."""


class LinkBudgetError(DriverError):
    """The configured channels x rate cannot fit through the link: the configuration is to change (exit 2)."""

    exit_code = 2


class DriverConfig(BaseModel):
    """Base for driver configs (each driver adds its own fields)."""

    # No inf/nan anywhere in a driver config: a NaN timeout or rate would make every comparison false.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    stream: str = "dev0"
    queue_blocks: int = 256
    # Set when the session starts the device itself (its first sample is this index): loss before the
    # first block that arrives is then a reported gap too. None when joining a device that already runs.
    expect_first_index: int | None = None
    # A forward index jump beyond (elapsed host time + this) x fs x 1.25 is not believed as a gap: it is a
    # bad frame unless the next block continues it (then a device restart / counter re-base: a new segment).
    plausible_jump_s: float = Field(1.0, gt=0)


@dataclass(frozen=True)
class DriverEvent:
    """Something the log must say: ``gap`` (exact missing [start, end)), ``restart`` (a new segment; the
    range is the *estimated* gap), ``implausible_index`` (a rejected block), ``crc_error``, ``timeout``,
    ``reconnect``, ``overrun``, ``frame_error``, ``resync``…

    ``start_index``/``end_index`` are always *stream* indices (safe to turn into a time); a block's own
    device indices, which may be anything a bad frame claimed, go in ``device_start``/``device_end``.
    """

    kind: str
    stream: str
    start_index: int | None = None
    end_index: int | None = None
    count: int = 0
    message: str = ""
    device_start: int | None = None
    device_end: int | None = None

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "stream": self.stream, "count": self.count, "message": self.message}
        if self.start_index is not None:
            d["start_index"] = self.start_index
            d["end_index"] = self.end_index
        if self.device_start is not None:
            d["device_start"] = self.device_start
            d["device_end"] = self.device_end
        return d


@dataclass(frozen=True)
class Segment:
    """One run of a device within a stream: segment 0 from the stream's first block, one more per restart.

    Stream index = device index + (``stream_first`` - ``device_first``) for every block of the segment.
    ``estimated_gap``: samples placed between the previous segment's end and this one, estimated from the
    host clock (0 for segment 0)."""

    stream: str
    number: int
    stream_first: int
    device_first: int
    estimated_gap: int = 0


@dataclass
class LinkStats:
    bytes_in: int = 0
    frames_ok: int = 0
    frames_bad: int = 0  # CRC or framing errors
    timeouts: int = 0
    retries: int = 0
    reconnects: int = 0
    overruns: int = 0
    garbage_bytes: int = 0  # byte streams: bytes skipped while hunting for a frame (line noise)
    resyncs: int = 0
    samples: int = 0
    # Sum of gap lengths (per stream row, not per channel), in stream indices. Includes the gaps before
    # restart segments, which are estimates (their part: estimated_lost_samples); all other gaps are exact.
    lost_samples: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    estimated_lost_samples: int = 0
    restarts: int = 0  # confirmed device restarts / counter re-bases (each began a new segment)
    rejected_blocks: int = 0  # blocks (frames) with an implausible index, never emitted
    segments: list[Segment] = field(default_factory=list)  # every stream's segments, in order

    def device_index(self, stream: str, index: int) -> int:
        """The device's own sample index of stream index ``index`` (a restarted device counts from 0 again)."""
        seg = [s for s in self.segments if s.stream == stream and s.stream_first <= index][-1]
        return index - seg.stream_first + seg.device_first


@dataclass(frozen=True)
class LinkBudget:
    """Needed throughput against the link's capacity, both in bytes/s (or requests/s where stated)."""

    needed: float
    capacity: float
    unit: str
    detail: str

    @property
    def utilisation(self) -> float:
        return self.needed / self.capacity if self.capacity > 0 else float("inf")

    def check(self, limit: float = 0.9) -> None:
        if self.utilisation > limit:
            raise LinkBudgetError(
                f"link budget exceeded: needs {self.needed:,.0f} {self.unit}, the link carries {self.capacity:,.0f} "
                f"{self.unit} ({100 * self.utilisation:.0f} % > {100 * limit:.0f} %): {self.detail}"
            )


_END = object()


class Driver(ABC):
    """Base class. Subclasses implement :meth:`_connect`, :meth:`_run` and :meth:`_disconnect`."""

    name: ClassVar[str] = "base"
    config_model: ClassVar[type[DriverConfig]] = DriverConfig
    #: seconds a driver that reads a byte stream may let input gather after the first byte before it reads and
    #: decodes it (fewer wake-ups and reads); set by the owner, who knows what latency it can afford (the device
    #: source of a single-device session, daq/sources.py); 0: read at once. Drivers without such a loop ignore it.
    gather_s: float = 0.0

    @property
    def realtime(self) -> bool:
        """True for a live link (the recorder must never wait on it); False for a source that can be
        paused, such as the simulated device at full speed, which then gets back-pressure instead."""
        return True

    def __init__(self, config: DriverConfig) -> None:
        self.config = config
        self.stats = LinkStats()
        self.events: queue.Queue[DriverEvent] = queue.Queue(maxsize=10_000)
        self._blocks: queue.Queue = queue.Queue(maxsize=max(2, config.queue_blocks))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._sequencers: dict[str, StreamSequencer] = {}
        self._t_open: float | None = None

    # --- owner side ------------------------------------------------------------------------
    def open(self) -> Driver:
        self.link_budget().check()
        self._t_open = time.monotonic()
        self._connect()
        self._thread = threading.Thread(target=self._thread_main, name=f"driver:{self.name}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        try:
            self._disconnect()
        finally:
            if self._thread is not None:
                self._thread.join(timeout=10)

    @property
    def alive(self) -> bool:
        """The reading thread runs: blocks may still come (False once the driver ended, died or closed)."""
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> Driver:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def blocks(self, timeout: float | None = None) -> Iterator[SampleBlock]:
        """Blocks as they arrive; ends when the driver stops; raises DriverError if its thread died.

        ``timeout``: seconds without a block after which iteration ends (None: wait for ever).
        """
        while True:
            try:
                item = self._blocks.get(timeout=timeout)
            except queue.Empty:
                return
            if item is _END:
                if self._error is not None:
                    raise DriverError(f"{self.name} driver stopped: {type(self._error).__name__}: {self._error}") from self._error
                return
            yield item

    def queued(self) -> int:
        """Blocks waiting for the owner now (an owner that reads in batches looks before it waits: see
        ``daq/sources.py``)."""
        return self._blocks.qsize()

    def drain_events(self) -> list[DriverEvent]:
        out = []
        while True:
            try:
                out.append(self.events.get_nowait())
            except queue.Empty:
                return out

    # --- subclass API ------------------------------------------------------------------------
    @abstractmethod
    def link_budget(self) -> LinkBudget: ...

    @abstractmethod
    def _connect(self) -> None: ...

    @abstractmethod
    def _run(self) -> None:
        """Read the link until ``self._stop`` is set, calling ``self._emit`` for each block."""

    def _disconnect(self) -> None:  # noqa: B027 - optional hook
        pass

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def _event(self, ev: DriverEvent) -> None:
        try:
            self.events.put_nowait(ev)
        except queue.Full:
            pass  # counters in LinkStats still hold the totals

    def _emit(
        self,
        block: SampleBlock,
        cause: str = "link",
        *,
        now: float | None = None,
        produced: int | None = None,
        restart: bool = False,
    ) -> None:
        """Hand a block (carrying the *device* index) to the sequencer of its stream, and what it lets
        through to the owner at its *stream* index, reporting any gap, restart or rejected block.

        ``now``: host monotonic time the block's last sample arrived (default: now). ``produced``: device
        samples that existed then, if the transport knows (a FIFO backlog; default ``block.end_index``).
        ``restart``: the transport has confirmed that this block starts a new device run. ``cause`` goes
        into the gap or restart message.
        """
        seq = self._sequencers.get(block.stream)
        if seq is None:
            seq = self._sequencers[block.stream] = StreamSequencer(
                block.sample_rate,
                plausible_jump_s=self.config.plausible_jump_s,
                expect_first=self.config.expect_first_index,
                start_time=self._t_open if self.config.expect_first_index is not None else None,
            )
        t = time.monotonic() if now is None else now
        for out in seq.feed(block.first_index, block.n_samples, t, (block, cause), produced=produced, restart=restart):
            if isinstance(out, Accepted):
                self._deliver(out)
            else:
                self._dropped(out)

    def _finish_streams(self) -> None:
        """The driver ends: suspects still held by a sequencer were never confirmed; reject them."""
        for seq in self._sequencers.values():
            for out in seq.finish():
                self._dropped(out)

    def _deliver(self, acc: Accepted) -> None:
        block, cause = acc.item
        status = block.status
        stats = self.stats
        if acc.gap is not None:
            a, b = acc.gap
            stats.gaps.append(acc.gap)
            stats.lost_samples += b - a
            self._event(DriverEvent("gap", block.stream, a, b, b - a, f"samples missing ({cause})"))
            status |= BlockStatus.GAP_BEFORE
        if acc.restart is not None:
            status |= self._restarted(block.stream, acc, cause)
        elif acc.starts_segment:
            stats.segments.append(Segment(block.stream, acc.segment, acc.stream_first, acc.device_first))
        if status != block.status or acc.stream_first != block.first_index:
            block = SampleBlock(
                block.stream, acc.stream_first, block.sample_rate, block.channels, block.data, status, block.extra
            )
        stats.samples += block.n_samples
        try:
            self._blocks.put_nowait(block)
        except queue.Full:
            stats.overruns += 1
            self._event(
                DriverEvent(
                    "overrun",
                    block.stream,
                    block.first_index,
                    block.end_index,
                    block.n_samples,
                    "owner is not reading: block dropped from the driver queue",
                )
            )

    def _restarted(self, stream: str, acc: Accepted, cause: str) -> BlockStatus:
        rs = acc.restart
        assert rs is not None
        gap = rs.estimated_gap
        stats = self.stats
        stats.restarts += 1
        stats.gaps.append((rs.prev_end, rs.stream_first))
        stats.lost_samples += gap
        stats.estimated_lost_samples += gap
        stats.segments.append(Segment(stream, rs.segment, rs.stream_first, rs.device_first, gap))
        why = cause if rs.by_transport else "its index went back or jumped, and the next block continued it"
        late_ms = round(rs.old_late_s * 1e3)
        fs = acc.item[0].sample_rate
        # the new run's first block came as late as this link's blocks do, within their spread either way
        longer, sooner = round(rs.usual_spread_s[0] * fs), min(gap - 1, round(rs.usual_spread_s[1] * fs))
        spread = (
            f"; within {sooner} fewer to {longer} more samples by how late this link's blocks arrive "
            "(10th to 90th percentile of the old run's recent blocks)"
            if longer or sooner > 0
            else ""
        )
        # the new run's first block may have waited behind the same backlog: that is the estimate's uncertainty
        shorter = min(gap - 1, round(rs.old_late_s * fs))
        backlog = (
            f"; the host read the old run's end {late_ms} ms behind that clock: if it was still behind when the new "
            f"run began, the gap is up to {shorter} samples shorter"
            if late_ms and shorter > 0
            else ""
        )
        self._event(
            DriverEvent(
                "restart",
                stream,
                rs.prev_end,
                rs.stream_first,
                gap,
                f"device restarted ({why}): its index went to {rs.device_first}; segment {rs.segment} starts at stream "
                f"index {rs.stream_first}, after an estimated {gap} missing samples (gap length estimated from the "
                f"host clock: the device's clock as its earliest blocks showed it{spread}{backlog})",
                device_start=rs.device_first,
                device_end=rs.device_first + acc.n,
            )
        )
        return BlockStatus.RESTART | BlockStatus.GAP_BEFORE

    def _dropped(self, d: Dropped) -> None:
        block, _cause = d.item
        dev = {"device_start": d.device_first, "device_end": d.device_first + d.n}
        if d.kind == "duplicate":  # counted with the frame errors, as always
            self.stats.frames_bad += 1
            a = d.stream_first
            self._event(
                DriverEvent("frame_error", block.stream, a, None if a is None else a + d.n, d.n, f"{d.reason}; dropped", **dev)
            )
            return
        self._implausible(block.stream, d.device_first, d.n, d.reason, d.stream_at)

    def _implausible(self, stream: str, device_first: int, n: int, reason: str, stream_at: int | None = None) -> None:
        """Count and report a block rejected for its index (``stream_at``: where the stream was; default
        where its sequencer is)."""
        if stream_at is None and stream in self._sequencers:
            stream_at = self._sequencers[stream].next_stream_index
        self.stats.rejected_blocks += 1
        self._event(
            DriverEvent(
                "implausible_index",
                stream,
                stream_at,
                stream_at,
                n,
                f"block at device index {device_first} ({n} samples) rejected: {reason}",
                device_start=device_first,
                device_end=device_first + n,
            )
        )

    def _thread_main(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # reported to the owner through blocks()
            self._error = exc
        finally:
            self._finish_streams()
            while True:
                try:
                    self._blocks.put(_END, timeout=0.5)
                    break
                except queue.Full:
                    if self._stop.is_set():
                        try:
                            self._blocks.get_nowait()
                        except queue.Empty:
                            pass


def available_drivers() -> dict[str, type[Driver]]:
    """Drivers registered under the ``gvtlink.drivers`` entry-point group (like python-can interfaces)."""
    out: dict[str, type[Driver]] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            out[ep.name] = ep.load()
        except Exception as exc:  # a broken plugin must not hide the others
            raise DriverError(f"driver plugin {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
    return out


def make_driver(kind: str, config: dict[str, Any]) -> Driver:
    drivers = available_drivers()
    if kind not in drivers:
        raise DriverError(f"unknown driver {kind!r}; installed: {sorted(drivers)}")
    cls = drivers[kind]
    return cls(cls.config_model.model_validate(config))
