"""CAN / CAN FD driver on python-can: any python-can interface by config, signals mapped by a DBC file.

Frames follow the sample-message convention of :mod:`drivers.can.dbc_map` (a ``FrameCounter`` plus
``<channel>_<k>`` int16 samples per message). Each selected DBC message is one stream; frames are
collected into blocks of ``block_samples`` and decoded in one numpy step (the DBC-derived fast path,
proven equal to cantools in tests/test_can.py). A dropped frame is a counter jump → the base reports the
exact missing sample range. A counter that goes back or jumps implausibly is held until the next frame:
continued, the node restarted (the unwrapping re-bases, the base starts a new segment); else it is rejected.
Error frames and bus-off are counted; a bus that raises is closed and reopened
with exponential back-off; ``raw_log`` writes every received frame to a BLF/ASC file (python-can
``Logger``, format from the extension). Details and limits: docs/protocols/can.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import Field, model_validator

from drivers.base import Driver, DriverConfig, DriverError, DriverEvent, LinkBudget
from drivers.blocks import BlockStatus, SampleBlock

if TYPE_CHECKING:  # python-can and cantools load with a CAN driver, not with every driver lookup
    import can

    from drivers.can.dbc_map import MessageLayout

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_DBC = ROOT / "configs" / "can" / "gvt_sim_node.dbc"
CAN_ERR_BUSOFF = 0x40  # SocketCAN error class bit in an error frame's id (linux/can/error.h)


# --- link budget ---------------------------------------------------------------------------
def frame_time_s(payload: int, *, fd: bool, bitrate: float = 1e6, data_bitrate: float = 8e6) -> float:
    """Bus time of one data frame with an 11-bit id and ``payload`` bytes (average bit stuffing).

    Classic: 47 + 8n bits plus about 1/8 of the worst-case stuff bits ⌊(34 + 8n − 1)/4⌋ → 114 bits for
    8 bytes = 8,772 frames/s at 1 Mbit/s (landscape.md §3.3: 8,771). CAN FD: ≈30 bits at the nominal rate
    plus ≈1.045 × (8n + 38) bits (CRC-21, stuff count, fixed and dynamic stuffing) at the data rate →
    ≈102 µs for 64 bytes at 1/8 Mbit/s ≈ 9.8 k frames/s (landscape.md §3.3: 9.5–10 k).
    """
    if not fd:
        return (47 + 8 * payload + ((34 + 8 * payload - 1) // 4) / 8) / bitrate
    return 30 / bitrate + 1.045 * (8 * payload + 38) / data_bitrate


def _bus_name(fd: bool, bitrate: float, data_bitrate: float) -> str:
    return f"CAN FD {bitrate / 1e6:g}/{data_bitrate / 1e6:g} Mbit/s" if fd else f"classic CAN {bitrate / 1e6:g} Mbit/s"


def layouts_budget(
    layouts: Sequence[MessageLayout], sample_rate: float, *, fd: bool, bitrate: float = 1e6, data_bitrate: float = 8e6
) -> LinkBudget:
    """Frames/s the selected messages need against frames/s the bus carries with that frame mix."""
    fps = [sample_rate / lay.spf for lay in layouts]
    times = [frame_time_s(lay.length, fd=fd and lay.is_fd, bitrate=bitrate, data_bitrate=data_bitrate) for lay in layouts]
    needed = sum(fps)
    load = sum(f * t for f, t in zip(fps, times, strict=True))
    capacity = needed / load if load > 0 else float("inf")
    parts = ", ".join(
        f"{lay.name} {len(lay.channels)} ch × {lay.spf} samples/frame → {f:,.0f} frames/s of {lay.length} B"
        for lay, f in zip(layouts, fps, strict=True)
    )
    return LinkBudget(
        needed,
        capacity,
        "frames/s",
        f"{parts} at {sample_rate:,.0f} Hz on {_bus_name(fd, bitrate, data_bitrate)}; "
        "select fewer channels (DBC messages) or a lower sample rate",
    )


def channels_budget(
    n_channels: int, sample_rate: float, *, fd: bool, bitrate: float = 1e6, data_bitrate: float = 8e6, sample_bytes: int = 2
) -> LinkBudget:
    """Budget for ``n_channels`` × ``sample_rate`` packed into full frames (64 B FD with a 4-byte counter,
    8 B classic with a 2-byte counter): the check before any DBC is written."""
    payload, counter = (64, 4) if fd else (8, 2)
    per_frame = (payload - counter) // sample_bytes
    fps = n_channels * sample_rate / per_frame
    capacity = 1.0 / frame_time_s(payload, fd=fd, bitrate=bitrate, data_bitrate=data_bitrate)
    return LinkBudget(
        fps,
        capacity,
        "frames/s",
        f"{n_channels} ch × {sample_rate:,.0f} Hz × {sample_bytes} B = {n_channels * sample_rate * sample_bytes:,.0f} "
        f"B/s in {payload}-byte frames ({counter}-byte FrameCounter, {per_frame} samples each) on "
        f"{_bus_name(fd, bitrate, data_bitrate)}; select fewer channels or a lower sample rate",
    )


# --- config --------------------------------------------------------------------------------
class CanConfig(DriverConfig):
    interface: str = "virtual"  # any python-can interface: socketcan, pcan, vector, kvaser, slcan, virtual…
    channel: str | int = "gvt0"
    bitrate: int = 1_000_000
    fd: bool = False
    data_bitrate: int = 8_000_000  # CAN FD data phase
    bus_options: dict[str, Any] = Field(default_factory=dict)  # extra keyword arguments for can.Bus
    dbc: str = str(DEFAULT_DBC)
    messages: list[str] | None = None  # DBC message names to record (default: every sample message)
    sample_rate: float = 16384.0  # the node's sample rate (Hz)
    block_samples: int = 256  # samples per emitted block (a partial block is flushed after flush_s)
    flush_s: float = 0.05
    max_bus_load: float = 0.7  # refuse above this utilisation (landscape.md §3.3: plan <= 70 %)
    # plausible_jump_s (DriverConfig): a counter jump beyond elapsed time + this, or a counter going back, is
    # held until the next frame: continued, the node restarted (the unwrapping re-bases); else it is rejected
    silence_timeout_s: float = 1.0  # no frame for this long → a timeout event
    reconnect_initial_s: float = 0.1
    reconnect_max_s: float = 5.0
    raw_log: str | None = None  # .blf / .asc (python-can Logger) written beside the MCAP

    @model_validator(mode="after")
    def _dbc_loads(self) -> CanConfig:
        """The DBC must exist and parse, and the messages be sample messages in it: a config error (one
        line naming the file) instead of a driver that fails on open. A relative path is tried from the
        working directory, then from the project root."""
        from drivers.can.dbc_map import load_layouts

        p = Path(self.dbc)
        if not p.is_absolute() and not p.exists() and (ROOT / p).exists():
            p = ROOT / p
        if not p.is_file():
            raise ValueError(f"dbc: DBC file {self.dbc!r} not found")
        try:
            load_layouts(p, self.messages)
        except Exception as exc:
            raise ValueError(f"dbc: DBC file {self.dbc!r} cannot be used: {type(exc).__name__}: {exc}") from None
        self.dbc = str(p)
        return self


@dataclass
class CanCounters:
    error_frames: int = 0
    bus_off: int = 0
    ignored_frames: int = 0  # ids not in the selected DBC messages
    rejected_frames: int = 0  # wrong length/kind, duplicate, or a backwards/implausible counter never confirmed
    backoff_waits: list[float] = field(default_factory=list)


@dataclass
class _Stream:
    layout: MessageLayout
    name: str
    fps: float
    last_counter: int | None = None
    last_full: int = 0
    last_t: float = 0.0
    suspect: tuple[int, bytes, float] | None = None  # (counter, data, arrival) of a frame held for confirmation
    restart: bool = False  # the block being built starts a new node run (the base makes a new segment)
    first_full: int = 0
    buf: bytearray = field(default_factory=bytearray)
    n: int = 0
    status: BlockStatus = BlockStatus.OK
    cause: str = "dropped frames"


class CanDriver(Driver):
    name = "can"
    config_model = CanConfig

    def __init__(self, config: CanConfig, bus_factory: Callable[[], can.BusABC] | None = None) -> None:
        super().__init__(config)
        from drivers.can.dbc_map import load_layouts

        self.cfg = config
        self.layouts = load_layouts(config.dbc, config.messages)
        if not self.layouts:
            raise DriverError(
                f"{config.dbc}: no sample messages (a FrameCounter plus <channel>_<k> signals); see docs/protocols/can.md"
            )
        multi = len(self.layouts) > 1
        self._streams = {
            (lay.frame_id, lay.is_extended): _Stream(
                lay, f"{config.stream}/{lay.name}" if multi else config.stream, config.sample_rate / lay.spf
            )
            for lay in self.layouts
        }
        self._bus_factory = bus_factory or self._open_bus
        self._bus: can.BusABC | None = None
        self._raw: Any = None
        self.can = CanCounters()
        self._last_frame_t = 0.0
        self._silent = False
        self._reconnected = False
        self._backoff = config.reconnect_initial_s

    @property
    def streams(self) -> dict[str, MessageLayout]:
        return {s.name: s.layout for s in self._streams.values()}

    def link_budget(self) -> LinkBudget:
        c = self.cfg
        return layouts_budget(self.layouts, c.sample_rate, fd=c.fd, bitrate=c.bitrate, data_bitrate=c.data_bitrate)

    def open(self) -> CanDriver:
        fd_msgs = [lay.name for lay in self.layouts if lay.is_fd]
        if fd_msgs and not self.cfg.fd:
            raise DriverError(f"DBC messages {fd_msgs} are CAN FD frames: set fd = true in the CAN config")
        self.link_budget().check(self.cfg.max_bus_load)
        super().open()
        return self

    # --- bus ---------------------------------------------------------------------------------
    def _open_bus(self) -> can.BusABC:
        import can

        c = self.cfg
        kw: dict[str, Any] = {"bitrate": c.bitrate, **c.bus_options}
        if c.fd:
            kw.update(fd=True, data_bitrate=c.data_bitrate)
        return can.Bus(interface=c.interface, channel=c.channel, **kw)

    def _connect(self) -> None:
        try:
            self._bus = self._bus_factory()
        except Exception as exc:
            raise DriverError(
                f"cannot open CAN bus {self.cfg.interface}:{self.cfg.channel}: {exc} "
                "(check interface/channel and that the adapter is plugged in)"
            ) from exc
        if self.cfg.raw_log:
            import can

            self._raw = can.Logger(self.cfg.raw_log)
        self._last_frame_t = time.monotonic()

    def _close_bus(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # a broken bus may fail to close; it is dropped either way
                pass

    def _bus_failed(self, exc: BaseException) -> None:
        text = str(exc).lower()
        if "bus-off" in text or "bus off" in text or "busoff" in text:
            self.can.bus_off += 1
        self._event(DriverEvent("link_error", self.cfg.stream, message=f"{type(exc).__name__}: {exc}; reconnecting"))
        self._close_bus()
        self._flush_all()
        # the back-off keeps growing across reopen attempts until a frame arrives on a reopened bus
        backoff = self._backoff
        while not self.stopping:
            self.can.backoff_waits.append(backoff)
            if self._stop.wait(backoff):
                return
            try:
                self._bus = self._bus_factory()
            except Exception as exc2:
                self._event(DriverEvent("reconnect_failed", self.cfg.stream, message=f"{type(exc2).__name__}: {exc2}"))
                backoff = min(2 * backoff, self.cfg.reconnect_max_s)
                continue
            self._backoff = min(2 * backoff, self.cfg.reconnect_max_s)
            self.stats.reconnects += 1
            self._reconnected = True
            self._event(
                DriverEvent("reconnect", self.cfg.stream, message=f"bus reopened after {len(self.can.backoff_waits)} waits")
            )
            return

    # --- frames ------------------------------------------------------------------------------
    def handle(self, msg: can.Message, now: float) -> None:
        """Account for one received frame (public so tests and the fuzzer can drive it without a bus)."""
        if msg.is_error_frame:
            self.can.error_frames += 1
            self.stats.frames_bad += 1
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self.can.bus_off += 1
            return
        st = self._streams.get((msg.arbitration_id, bool(msg.is_extended_id)))
        if st is None:
            self.can.ignored_frames += 1
            return
        lay = st.layout
        data = msg.data
        if not lay.accepts(msg):
            self._reject(st, "frame of wrong length or kind for the DBC message")
            return
        self.stats.frames_ok += 1
        c = lay.counter_of(data)
        full = self._unwrap(st, c, bytes(data), now)
        if full is not None:
            self._append(st, full, c, data, now)

    def _unwrap(self, st: _Stream, c: int, data: bytes, now: float) -> int | None:
        """The full (unwrapped) counter of frame ``c``; None if the frame is rejected or held.

        A counter that goes back, or jumps further than the elapsed time allows, is held as a suspect. If
        the next frame continues it, the node restarted (or re-based its counter): the unwrapping restarts
        from the suspect's counter and the block is marked so the base begins a new segment. Otherwise the
        suspect was a bad frame: rejected and counted, the next frame judged as if it never came.
        """
        if st.last_counter is None:
            return c
        mod = st.layout.counter_modulus
        if st.suspect is not None:
            sc, sdata, s_t = st.suspect
            st.suspect = None
            if c == (sc + 1) % mod:
                self._flush(st)  # the old run's last block
                st.restart = True
                self._append(st, sc, sc, sdata, s_t)
                return sc + 1
            why = "frame counter implausible, not continued by the next frame"
            self._implausible(st.name, sc * st.layout.spf, st.layout.spf, why)
            self.can.rejected_frames += 1
        delta = (c - st.last_counter) % mod
        if delta == 0:
            self._reject(st, "duplicate frame counter")
            return None
        elapsed = max(0.0, now - st.last_t)
        backwards = False
        if elapsed * st.fps > mod / 2:  # long silence with a short counter: add the wraps the clock implies
            delta += max(0, round((elapsed * st.fps - delta) / mod)) * mod
        else:
            backwards = delta > mod // 2
        if backwards or delta > (elapsed + self.cfg.plausible_jump_s) * st.fps * 1.25 + 8:
            st.suspect = (c, data, now)
            return None
        if delta > 1 and st.n:
            self._flush(st)
        return st.last_full + delta

    def _append(self, st: _Stream, full: int, c: int, data: bytes | bytearray, now: float) -> None:
        if st.n == 0:
            st.first_full = full
            if self._reconnected:
                st.status |= BlockStatus.RECONNECT
                st.cause = "reconnect"
        st.buf += data
        st.n += 1
        st.last_counter, st.last_full, st.last_t = c, full, now
        if st.n * st.layout.spf >= self.cfg.block_samples:
            self._flush(st)

    def _reject(self, st: _Stream, why: str) -> None:
        self.stats.frames_bad += 1
        self.can.rejected_frames += 1
        if self.can.rejected_frames <= 1000:  # the counters keep the totals; the event log stays bounded
            self._event(DriverEvent("frame_error", st.name, count=1, message=why))

    def _flush(self, st: _Stream) -> None:
        if st.n == 0:
            return
        lay = st.layout
        data = lay.decode_frames(st.buf, st.n)
        block = SampleBlock(st.name, st.first_full * lay.spf, self.cfg.sample_rate, lay.channels, data, st.status)
        st.buf = bytearray()
        st.n = 0
        st.status = BlockStatus.OK
        restart, st.restart = st.restart, False
        cause = "its frame counter went back or jumped, and the next frame continued it" if restart else st.cause
        self._emit(block, cause, now=st.last_t, restart=restart)
        st.cause = "dropped frames"
        self._reconnected = False

    def _flush_all(self) -> None:
        for st in self._streams.values():
            self._flush(st)

    def _reject_suspects(self) -> None:
        """The driver ends: a frame still held was never confirmed by a next one."""
        for st in self._streams.values():
            if st.suspect is not None:
                sc = st.suspect[0]
                st.suspect = None
                self.can.rejected_frames += 1
                self._implausible(st.name, sc * st.layout.spf, st.layout.spf, "frame counter implausible, the stream ended")

    # --- the reader thread -------------------------------------------------------------------
    def _run(self) -> None:
        flush_s = self.cfg.flush_s
        next_flush = time.monotonic() + flush_s
        handle = self.handle
        stats = self.stats
        try:
            while not self.stopping:
                bus = self._bus
                if bus is None:
                    self._bus_failed(DriverError("bus closed"))
                    continue
                try:
                    msg = bus.recv(timeout=flush_s)
                except Exception as exc:  # python-can raises CanError/OSError subclasses per interface
                    self._bus_failed(exc)
                    continue
                now = time.monotonic()
                if msg is not None:
                    stats.bytes_in += len(msg.data)
                    if self._raw is not None:
                        self._raw(msg)
                    handle(msg, now)
                    self._backoff = self.cfg.reconnect_initial_s
                    self._last_frame_t = now
                    self._silent = False
                elif not self._silent and now - self._last_frame_t > self.cfg.silence_timeout_s:
                    self._silent = True
                    stats.timeouts += 1
                    self._event(
                        DriverEvent("timeout", self.cfg.stream, message=f"no CAN frame for {self.cfg.silence_timeout_s:g} s")
                    )
                if now >= next_flush:
                    self._flush_all()
                    next_flush = now + flush_s
        finally:
            self._flush_all()
            self._reject_suspects()
            self._close_bus()
            if self._raw is not None:
                self._raw.stop()
                self._raw = None

    def _disconnect(self) -> None:
        if self._thread is None or not self._thread.is_alive():  # never started: nothing else will close it
            self._close_bus()


def budget_frames_per_s(fd: bool, payload: int | None = None, bitrate: float = 1e6, data_bitrate: float = 8e6) -> float:
    """Physical frames/s of one frame size (64 B FD / 8 B classic by default)."""
    n = payload if payload is not None else (64 if fd else 8)
    return 1.0 / frame_time_s(n, fd=fd, bitrate=bitrate, data_bitrate=data_bitrate)


__all__ = ["CanConfig", "CanDriver", "budget_frames_per_s", "channels_budget", "frame_time_s", "layouts_budget"]
