"""The driver interface: one way to get SampleBlocks out of any DAQ link (serial, CAN, Modbus, sim).

Modelled on python-can's ``Bus``: a driver is configured from TOML (a pydantic model per driver),
discovered through the ``gvtlink.drivers`` entry-point group, opened and closed as a context manager,
and read as an iterator of :class:`~drivers.blocks.SampleBlock`. What peers get wrong and this gets right
(landscape.md §2.1, §2.8, §4):

* **Exact loss accounting.** Subclasses call :meth:`Driver._emit` with blocks that carry the device's
  own sample index. A jump in the index is a gap: the exact missing range is recorded as a
  :class:`DriverEvent` with its cause, and the block is flagged ``GAP_BEFORE``. CRC/frame errors,
  timeouts, reconnects and overruns are counted in :class:`LinkStats`.
* **A dying driver thread is never silent.** The reader thread's exception is stored and raised to the
  owner from :meth:`Driver.blocks` (as :class:`DriverError`), after every block read before it.
* **Bounded everything.** Blocks wait in a bounded queue; if the owner stops reading, the driver counts
  an overrun with the exact range instead of growing without limit.
"""

from __future__ import annotations

import queue
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

from analysis.errors import RuntimeFailure
from drivers.blocks import BlockStatus, SampleBlock

ENTRY_POINT_GROUP = "gvtlink.drivers"


class DriverError(RuntimeFailure):
    """A driver failed; the message says what and how to fix it (one line)."""


class LinkBudgetError(DriverError):
    """The configured channels x rate cannot fit through the link: the configuration is to change (exit 2)."""

    exit_code = 2


class DriverConfig(BaseModel):
    """Base for driver configs (each driver adds its own fields)."""

    model_config = ConfigDict(extra="forbid")
    stream: str = "dev0"
    queue_blocks: int = 256
    # Set when the session starts the device itself (its first sample is this index): loss before the
    # first block that arrives is then a reported gap too. None when joining a device that already runs.
    expect_first_index: int | None = None


@dataclass(frozen=True)
class DriverEvent:
    """Something the log must say: ``gap`` (exact missing [start, end)), ``crc_error``, ``timeout``,
    ``reconnect``, ``overrun``, ``frame_error``, ``resync``…"""

    kind: str
    stream: str
    start_index: int | None = None
    end_index: int | None = None
    count: int = 0
    message: str = ""

    def as_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind, "stream": self.stream, "count": self.count, "message": self.message}
        if self.start_index is not None:
            d["start_index"] = self.start_index
            d["end_index"] = self.end_index
        return d


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
    lost_samples: int = 0  # sum of gap lengths (per stream row, not per channel)
    gaps: list[tuple[int, int]] = field(default_factory=list)


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
        self._next_index: dict[str, int] = {}

    # --- owner side ------------------------------------------------------------------------
    def open(self) -> Driver:
        self.link_budget().check()
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

    def _emit(self, block: SampleBlock, cause: str = "link") -> None:
        """Hand a block to the owner, detecting and reporting any gap before it."""
        expected = self._next_index.get(block.stream, self.config.expect_first_index)
        status = block.status
        if expected is not None and block.first_index > expected:
            gap = (expected, block.first_index)
            self.stats.gaps.append(gap)
            self.stats.lost_samples += gap[1] - gap[0]
            self._event(DriverEvent("gap", block.stream, gap[0], gap[1], gap[1] - gap[0], f"samples missing ({cause})"))
            status |= BlockStatus.GAP_BEFORE
        elif expected is not None and block.first_index < expected:
            self._event(
                DriverEvent(
                    "frame_error",
                    block.stream,
                    block.first_index,
                    block.end_index,
                    block.n_samples,
                    "block went back in time (duplicate or device reset); dropped",
                )
            )
            self.stats.frames_bad += 1
            return
        self._next_index[block.stream] = block.end_index
        if status != block.status:
            block = SampleBlock(
                block.stream, block.first_index, block.sample_rate, block.channels, block.data, status, block.extra
            )
        self.stats.samples += block.n_samples
        try:
            self._blocks.put_nowait(block)
        except queue.Full:
            self.stats.overruns += 1
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

    def _thread_main(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # reported to the owner through blocks()
            self._error = exc
        finally:
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
