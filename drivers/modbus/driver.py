"""Modbus driver (pymodbus client, TCP or RTU): block-FIFO acquisition, polled slow channels, device control.

* **Register map** in TOML (:mod:`drivers.modbus.register_map`): addresses, types, scales, word order.
* **Block FIFO** (``mode = "fifo"``): one FC 23 read/write request per frame writes ``ack`` = the next
  sample index wanted and reads a frame (header: first sample index, count, samples buffered, flags; then
  interleaved int16 samples). Data are addressed by sample index, so a lost response is recovered by
  sending the same request again: no sample is lost or duplicated by a retry (docs/protocols/modbus.md).
  Frames are gathered into blocks of ``block_samples``; a jump in the device's first index is a gap,
  reported exactly by the base class (e.g. the device FIFO overflowed while the link was down).
* **Polling** (``poll = [...]``, ``poll_hz``): one read spanning the slow registers per tick, emitted as
  stream ``<stream>.poll`` with the tick number as sample index; a missed tick is a reported gap.
* **Control**: on open the driver checks the channel mask, writes sample rate / range and ``start``; on
  close ``stop``. Refusals (Modbus exception responses) are raised as one-line :class:`DriverError`.
* **Timeouts and retries** are the driver's own (pymodbus ``retries=0``) so they are counted in
  ``stats``; a dead link is reconnected (counted) until ``reconnect_s`` passes. TCP runs with TCP_NODELAY.
* **A restarted device is never stitched on.** After every reconnect, *before* the first FIFO ack (an
  ack releases everything before it, unread), the driver reads the device's status, sample counter and
  FIFO head. A counter below the index the driver wants, a head below what it acknowledged, or a device
  found stopped (then ``start`` is written if ``control``) means a new run: the driver reads from the
  device's head (ack 0 releases nothing) and the base begins a new segment. A frame that goes back further
  than a late duplicate can (the device restarted while connected) is taken the same way.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from drivers.base import Driver, DriverConfig, DriverError, DriverEvent, LinkBudget
from drivers.blocks import BlockStatus, SampleBlock
from drivers.modbus.register_map import MAX_READ, RegisterMap, load_register_map

if TYPE_CHECKING:  # pymodbus loads with a Modbus driver's link, not with every driver lookup
    from pymodbus.client import ModbusSerialClient, ModbusTcpClient

ROOT = Path(__file__).resolve().parents[2]
_EXC_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure", 6: "device busy"}
TCP_DEFAULT_CAPACITY = 1000.0  # requests/s; measured ~2-3k on loopback (bench/bench_modbus.py), less on a real network
RTU_BITS_PER_CHAR = 11  # 8E1: start + 8 data + parity + stop


class _Stopping(Exception):
    pass


def answers(rr: Any, function_code: int, registers: int | None = None, address: int | None = None) -> bool:
    """Is ``rr`` the answer to a request of ``function_code`` reading ``registers`` / writing at ``address``?

    Why: Modbus RTU has no transaction id, and pymodbus pairs whatever complete frame comes next with the request
    in hand, whatever its function code. A device that answers after the driver's timeout (a busy host reads it
    late) has its answer taken for the *retry's*, and the retry's answer for the next request's: a FIFO frame
    read as the status register said "stopped" (its first register, the index's high word, is 0), and the driver
    began a new segment, a false restart with an estimated gap, on a device that never stopped (issue 30, the
    ``modbus-rtu`` disconnect cell under load). The function code (an exception answer carries it + 0x80), the
    count of registers read and the address written (FC 16 echoes it) tell such an answer from the right one.
    A late answer *of the same kind* is harmless: the FIFO is addressed by sample index (a late frame is a
    duplicate, dropped by index), a late counter or head is older and lower, which no restart test can mistake
    (the device's count and head never fall while it runs)."""
    fc = getattr(rr, "function_code", None)
    if rr.isError():
        return fc is not None and fc & 0x7F == function_code
    if fc != function_code:
        return False
    if registers is not None and len(getattr(rr, "registers", None) or []) != registers:
        return False
    return address is None or getattr(rr, "address", address) == address


class _Relinked(Exception):
    """The link was re-opened inside a FIFO call: the device must be checked before the next ack."""


@dataclass
class _Chunk:
    """FIFO frames gathered into one block."""

    parts: list[np.ndarray] = field(default_factory=list)
    first: int = 0
    n: int = 0
    t: float = 0.0  # host time its last frame arrived
    produced: int = 0  # device samples that existed then (that frame's first index + buffered)


class ModbusConfig(DriverConfig):
    transport: Literal["tcp", "rtu"] = "tcp"
    host: str = "127.0.0.1"
    port: int = 502
    serial_port: str = ""
    baudrate: int = 115200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: int = 1
    device_id: int | None = None  # None: the register map's unit_id
    register_map: str = "configs/modbus/gvt_sim_device.toml"
    mode: Literal["fifo", "poll"] = "fifo"
    channels: list[str] = Field(
        default_factory=list
    )  # FIFO channels, as the device acquires them (checked against its channel mask)
    sample_rate: float | None = None  # fifo: written to the device; also what the link budget is computed for
    input_range_volts: float | None = None  # written to the device's range register if set
    control: bool = True  # write start on open and stop on close
    poll: list[str] = Field(default_factory=list)  # slow channels (register-map [[poll]] names)
    poll_hz: float = 10.0
    timeout_s: float = 0.1
    retries: int = 3
    reconnect_s: float = 30.0  # give up after this long without a connection
    capacity_req_s: float | None = None  # measured link capacity; None: TCP default / RTU from the baud rate
    block_samples: int = 1024
    # at a stop, seconds to read what the device's FIFO still holds (then what is left is a logged gap, not silence)
    stop_drain_s: float = Field(2.0, ge=0.0, le=60.0)

    @model_validator(mode="after")
    def _check(self) -> ModbusConfig:
        if self.mode == "fifo" and (not self.channels or self.sample_rate is None):
            raise ValueError("modbus fifo mode needs channels = [...] and sample_rate")
        if self.mode == "poll" and not self.poll:
            raise ValueError("modbus poll mode needs poll = [...] (register-map poll channel names)")
        if self.transport == "rtu" and not self.serial_port:
            raise ValueError("modbus rtu needs serial_port")
        return self

    @field_validator("register_map")
    @classmethod
    def _map_loads(cls, v: str) -> str:
        """A missing or broken register map is a config error naming the file, not a failure on open."""
        p = _map_path(v)
        if not p.is_file():
            raise ValueError(f"register map file {v!r} not found")
        try:
            load_register_map(p)
        except Exception as exc:
            raise ValueError(f"register map file {v!r} cannot be used: {type(exc).__name__}: {exc}") from None
        return v

    def map_path(self) -> Path:
        return _map_path(self.register_map)


def _map_path(name: str) -> Path:
    """A relative register map path is tried from the working directory, then from the project root."""
    p = Path(name)
    return p if p.is_absolute() or p.exists() else ROOT / p


class ModbusDriver(Driver):
    name = "modbus"
    config_model = ModbusConfig

    def __init__(self, config: ModbusConfig) -> None:  # type: ignore[override]
        super().__init__(config)
        self.cfg = config
        self.map: RegisterMap = load_register_map(config.map_path())
        self.unit = config.device_id if config.device_id is not None else self.map.device.unit_id
        self.wo = self.map.device.word_order
        self.fs = float(config.sample_rate or 0.0)
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._flags = BlockStatus.OK
        self._link_new = False  # set by every reconnect: check the device before the next FIFO ack
        self._next: int | None = None  # next device index wanted from the FIFO (None: from the device's head)
        self._chunk = _Chunk()
        self._restart_cause: str | None = None  # the next block starts a new device run, for this reason
        self._finishing = threading.Event()  # the owner's finish(): deliver what the device holds, then end
        self._produced: int | None = None  # the device's sample count when the last frame was read (first + buffered)
        self._device_stopped = False
        self._finishing_done = False
        self.stale_responses = 0  # answers to earlier requests that came instead of the one asked (RTU, a busy host)
        if config.mode == "fifo":
            if self.map.fifo is None:
                raise DriverError(f"register map {config.register_map} has no [fifo]; use mode = 'poll'")
            idx = [self.map.fifo_channel_index(n) for n in config.channels]
            if idx != sorted(idx):
                raise DriverError(
                    f"modbus channels must be in register-map order: {sorted(config.channels, key=self.map.fifo_channel_index)}"
                )
            self._mask = sum(1 << i for i in idx)
            self._scales = np.array([self.map.fifo.channels[i].scale for i in idx], np.float64)
            self.spf = self.map.fifo.samples_per_frame(len(idx))
        self._poll_regs = [self.map.poll_channel(n) for n in config.poll]
        if self._poll_regs:
            self._poll_lo = min(p.address for p in self._poll_regs)
            self._poll_n = max(p.end for p in self._poll_regs) - self._poll_lo
            if self._poll_n > MAX_READ:
                raise DriverError(f"poll channels span {self._poll_n} registers > {MAX_READ}: split them into two drivers")

    # --- budget ---------------------------------------------------------------------------
    def link_budget(self) -> LinkBudget:
        c = self.cfg
        poll_req = c.poll_hz if self._poll_regs else 0.0
        if c.transport == "tcp":
            cap = c.capacity_req_s or TCP_DEFAULT_CAPACITY
            src = "configured" if c.capacity_req_s else "TCP default"
        else:
            # FC23 frame: request 21 chars, response 5 + 2*125; plus 3.5 chars of silence after each
            chars = 21 + 5 + 2 * MAX_READ + 7
            cap = c.capacity_req_s or c.baudrate / (RTU_BITS_PER_CHAR * chars)
            src = f"RTU {c.baudrate} baud, {chars} chars x {RTU_BITS_PER_CHAR} bits per request"
        if c.mode == "fifo":
            n = len(c.channels)
            fifo_req = self.fs / self.spf
            detail = (
                f"{n} ch x {self.fs:g} Hz = {n * self.fs:,.0f} int16 values/s at {self.spf * n} per request "
                f"({self.spf} samples x {n} ch) -> {fifo_req:,.0f} req/s + {poll_req:g} poll req/s vs {cap:,.0f} req/s "
                f"({src}); select fewer channels or a lower rate"
            )
        else:
            fifo_req = 0.0
            detail = f"{poll_req:g} poll req/s vs {cap:,.0f} req/s ({src})"
        return LinkBudget(fifo_req + poll_req, cap, "req/s", detail)

    # --- link -----------------------------------------------------------------------------
    def _new_client(self) -> ModbusTcpClient | ModbusSerialClient:
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient
        from pymodbus.framer import FramerType

        c = self.cfg
        if c.transport == "tcp":
            return ModbusTcpClient(c.host, port=c.port, timeout=c.timeout_s, retries=0, reconnect_delay=0)
        return ModbusSerialClient(
            c.serial_port,
            framer=FramerType.RTU,
            baudrate=c.baudrate,
            parity=c.parity,
            stopbits=c.stopbits,
            bytesize=8,
            timeout=c.timeout_s,
            retries=0,
        )

    def _open_link(self) -> bool:
        if self._client is not None:
            self._client.close()
        self._client = self._new_client()
        if not self._client.connect():
            self._client.close()
            return False
        if self.cfg.transport == "tcp":
            self._client.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # Nagle off
        return True

    def _reconnect(self) -> None:
        deadline = time.monotonic() + self.cfg.reconnect_s
        where = f"{self.cfg.host}:{self.cfg.port}" if self.cfg.transport == "tcp" else self.cfg.serial_port
        while not self._open_link():
            if self.stopping or self._finishing.is_set():
                raise _Stopping
            if time.monotonic() > deadline:
                raise DriverError(f"modbus: no connection to {where} for {self.cfg.reconnect_s:g} s (is the device on?)")
            self._stop.wait(0.1)
        self.stats.reconnects += 1
        self._link_new = True
        self._flags |= BlockStatus.RECONNECT
        self._event(DriverEvent("reconnect", self.cfg.stream, message=f"reconnected to {where}"))

    def _drain(self) -> None:
        """After a timeout, discard a late response still in the socket so it cannot pair with the retry."""
        sock = getattr(self._client, "socket", None)
        if sock is None or self.cfg.transport != "tcp":
            return
        try:
            sock.setblocking(False)
            while sock.recv(4096):
                pass
        except OSError:
            pass

    def _call(
        self, what: str, fn: Any, expect: tuple[int, int | None, int | None], *, reconnect: bool = True, relink: bool = False
    ) -> Any:
        """One Modbus transaction with counted timeouts/retries and reconnects; returns the response.

        ``expect``: (function code, registers read or None, address written or None) of the request, which the
        response must match (:func:`answers`): else it is the late answer to an earlier request and the request is
        sent again. ``relink``: if the link had to be re-opened, raise :class:`_Relinked` instead of sending ``fn``
        on it (the FIFO read: its ack must not reach a device that may have restarted before it is checked)."""
        from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

        attempt = 0
        while True:
            if self._client is None or not self._client.connected:
                if not reconnect:
                    raise DriverError(f"modbus: {what}: not connected")
                self._reconnect()
                if relink:
                    raise _Relinked
            try:
                rr = fn(self._client)
                if not answers(rr, *expect):
                    self.stale_responses += 1  # a late answer to an earlier request: not this one's (below)
                    raise ModbusIOException(f"{what}: the answer to an earlier request came instead")
            except ModbusIOException:
                self.stats.timeouts += 1
                self._flags |= BlockStatus.TIMEOUT
                attempt += 1
                self._drain()
                if reconnect and (self.stopping or self._finishing.is_set()):  # a silent device is retried and
                    raise _Stopping from None  # relinked for ever: stop now (at a stop's drain: the rest is a gap)
                if attempt <= self.cfg.retries:
                    self.stats.retries += 1
                    continue
                self._event(
                    DriverEvent("timeout", self.cfg.stream, count=attempt, message=f"{what}: no answer after {attempt} tries")
                )
                if not reconnect:
                    raise DriverError(
                        f"modbus: {what}: no answer after {attempt} tries ({self.cfg.timeout_s:g} s each)"
                    ) from None
                self._client.close()  # a device that stopped answering: start over with a fresh connection
                attempt = 0
                continue
            except (ConnectionException, OSError) as exc:
                if self._client is not None:
                    self._client.close()
                if not reconnect:
                    raise DriverError(f"modbus: {what}: {exc}") from exc
                if self.stopping or self._finishing.is_set():
                    raise _Stopping from None
                continue
            except ModbusException as exc:
                raise DriverError(f"modbus: {what}: {exc}") from exc
            if rr.isError():
                code = getattr(rr, "exception_code", 0)
                raise DriverError(f"modbus: device refused {what}: exception {code} ({_EXC_NAMES.get(code, 'unknown')})")
            self.stats.frames_ok += 1
            self.stats.bytes_in += 9 + 2 * len(getattr(rr, "registers", []) or [])
            return rr

    def _write(self, reg: Any, raw: int, what: str, reconnect: bool = True) -> None:
        regs = reg.raw_to_regs(raw, self.wo)
        self._call(
            what,
            lambda c: c.write_registers(reg.address, regs, device_id=self.unit),
            (16, None, reg.address),
            reconnect=reconnect,
        )

    def _read(self, reg: Any, what: str) -> int | float:
        rr = self._call(
            what,
            lambda c: c.read_holding_registers(reg.address, count=reg.n_registers, device_id=self.unit),
            (3, reg.n_registers, None),
        )
        return reg.regs_to_raw(rr.registers, self.wo)

    # --- Driver hooks ---------------------------------------------------------------------
    def _connect(self) -> None:
        where = f"{self.cfg.host}:{self.cfg.port}" if self.cfg.transport == "tcp" else self.cfg.serial_port
        if not self._open_link():
            raise DriverError(f"modbus: cannot connect to {where} (is the device on, the port right?)")
        try:
            ctl = self.map.control
            if self.cfg.mode == "fifo":
                mask = int(self._read(ctl.channel_mask, "read channel mask"))
                if mask != self._mask:
                    have = [ch.name for k, ch in enumerate(self.map.fifo.channels) if mask >> k & 1]
                    raise DriverError(f"modbus: device acquires channels {have}, config asks for {self.cfg.channels}")
            if self.cfg.sample_rate is not None:
                self._write(
                    ctl.sample_rate, round(self.cfg.sample_rate), f"sample_rate = {self.cfg.sample_rate:g} Hz", reconnect=False
                )
            if self.cfg.input_range_volts is not None:
                raw = round(self.cfg.input_range_volts / ctl.range.scale)
                self._write(ctl.range, raw, f"range = {self.cfg.input_range_volts:g} V", reconnect=False)
            if self.cfg.mode == "fifo":
                self.fs = float(self._read(ctl.sample_rate, "read sample rate"))
            if self.cfg.control:
                self._write(ctl.command, 1, "start", reconnect=False)
        except BaseException:
            self._client.close()
            raise

    def _disconnect(self) -> None:
        pass  # the reader thread sends stop and closes the link (it owns the client)

    def finish(self) -> float:
        """Owner side, at a stop: end the run *after* delivering what the device already holds (its FIFO, and the
        frames gathered into the block in hand), within ``stop_drain_s``; then the reading thread ends by itself
        (``alive`` turns False). Returns that bound in seconds. What the drain cannot read in time is a ``gap`` event
        with its exact range (lost, counted), never silently missing. ``close()`` still ends it at once."""
        self._finishing.set()
        return self.cfg.stop_drain_s

    def _run(self) -> None:
        try:
            self._loop()
        except _Stopping:
            if self._finishing.is_set() and not self._finishing_done:  # no answer while the stop's drain waited
                self._held_accounted(None)
        finally:
            if self.cfg.control and not self._device_stopped and self._client is not None and self._client.connected:
                try:
                    self._write(self.map.control.command, 0, "stop", reconnect=False)
                except DriverError:
                    pass
            if self._client is not None:
                self._client.close()

    def _loop(self) -> None:
        c = self.cfg
        fifo_mode = c.mode == "fifo"
        poll_t0 = time.monotonic()
        poll_k = 0
        poll_period = 1.0 / c.poll_hz if self._poll_regs else 0.0

        def next_poll() -> float:
            return poll_t0 + poll_k * poll_period if self._poll_regs else math.inf

        while not self.stopping:
            if self._finishing.is_set():
                if fifo_mode:
                    self._drain_held()
                return
            now = time.monotonic()
            if now >= next_poll():
                poll_k = max(poll_k, int((now - poll_t0) * c.poll_hz))  # ticks we were too late for are a gap
                self._poll_once(poll_k)
                poll_k += 1
            if not fifo_mode:
                self._stop.wait(max(0.0, next_poll() - time.monotonic()))
                continue
            if self._link_new:
                self._link_new = False
                self._check_device()
                continue  # (the check may itself have reconnected: then check again)
            try:
                left = self._fifo_step()
            except _Relinked:
                continue
            if left < self.spf and not self._finishing.is_set():  # less than a frame waiting: sleep until one is
                wait = (self.spf - left) / self.fs
                self._stop.wait(min(wait, max(0.0, next_poll() - time.monotonic())))
        self._flush_chunk()

    def _drain_held(self) -> None:
        """The stop's drain: the device is stopped (``control``: it produces no more, its FIFO keeps what it holds),
        then frames are read until the index wanted reaches the device's count at the first read (one read at
        least, whatever the bound: it is what says how much the device holds), or ``stop_drain_s`` passes; the block
        in hand is delivered, and what was not read is one ``gap``."""
        until = time.monotonic() + self.cfg.stop_drain_s
        if self.cfg.control:
            try:
                self._write(self.map.control.command, 0, "stop", reconnect=False)
                self._device_stopped = True
            except DriverError:
                pass  # the link is down: the drain reads nothing either, and says so below
        target = None
        try:
            while not self.stopping and not self._link_new:  # one read at least: it tells what the device holds
                self._fifo_step()
                target = self._produced if target is None else target
                if target is None or (self._next is not None and self._next >= target) or time.monotonic() >= until:
                    break
        except (_Relinked, _Stopping, DriverError):
            pass  # a reconnect (the device may have restarted), no answer, a dead link: the rest is the gap below
        self._held_accounted(target)

    def _held_accounted(self, target: int | None) -> None:
        """The drain's end: the block in hand delivered, and what the device held beyond it one ``gap`` (``target``:
        the device's count at the drain's first read; None: the last count the driver saw)."""
        self._finishing_done = True
        self._flush_chunk()
        nxt = self._next
        if target is not None and nxt is not None and target > nxt:
            self._not_drained(nxt, target, answered=True)
        elif target is None and self._produced is not None and nxt is not None and self._produced > nxt:
            self._not_drained(nxt, self._produced, answered=False)

    def _not_drained(self, first: int, end: int, answered: bool) -> None:
        """What the device held and the drain did not read: a ``gap`` (lost, counted: the device said at the stop
        that it held them); when it answered nothing at the stop (a stalled or dead link, already a ``silence``
        or a timeout), a ``held_unread`` event with what its last answer said it held: where the recording ends
        and why, not a loss the stop caused."""
        seq = self._sequencers.get(self.cfg.stream)
        a = seq.next_stream_index if seq is not None else None
        a = first if a is None else a  # the stream's index where the device's ``first`` would have gone
        n = end - first
        if not answered:
            msg = (f"the device did not answer at the stop: the {n} samples it held at its last answer (its samples "
                   f"{first}-{end}) and any after them were not read")  # fmt: skip
            self._event(DriverEvent("held_unread", self.cfg.stream, a, a + n, count=n, message=msg, device_start=first,
                                    device_end=end))  # fmt: skip
            return
        self.stats.gaps.append((a, a + n))
        self.stats.lost_samples += n
        msg = (f"{n} samples the device held at the stop (its samples {first}-{end}) were not read within the "
               f"{self.cfg.stop_drain_s:g} s stop drain: not recorded")  # fmt: skip
        self._event(DriverEvent("gap", self.cfg.stream, a, a + n, count=n, message=msg, device_start=first, device_end=end))

    def _fifo_step(self) -> int:
        """One FC 23 request: ack ``_next``, read a frame, gather it. Returns the samples still buffered."""
        fifo = self.map.fifo
        assert fifo is not None
        ack_regs = fifo.ack.raw_to_regs(self._next or 0, self.wo)
        rr = self._call(
            "FIFO read",
            lambda cl: cl.readwrite_registers(
                read_address=fifo.window_address,
                read_count=fifo.window_registers,
                write_address=fifo.ack.address,
                values=ack_regs,
                device_id=self.unit,
            ),
            (23, fifo.window_registers, None),
            relink=True,
        )
        t = time.monotonic()
        regs = rr.registers
        first, n, buffered, _flags = struct.unpack(">QHIH", struct.pack(">4HH2HH", *regs[: fifo.header_registers]))
        self._produced = first + buffered
        nxt = self._next
        if nxt is not None and first < nxt:
            if first + n <= nxt and first + 2 * self.spf >= nxt:
                return buffered - n  # a late duplicate of a frame already gathered
            self._restart_from(f"its FIFO went back to index {first}, below the {nxt} the driver had acknowledged")
        if n:
            nch = len(self.cfg.channels)
            raw = np.array(regs[fifo.header_registers : fifo.header_registers + n * nch], np.uint16).view(np.int16)
            self._gather(first, raw.reshape(n, nch) * self._scales, t, first + buffered)
            self._next = first + n
        return buffered - n

    def _gather(self, first: int, data: np.ndarray, t: float, produced: int) -> None:
        ch = self._chunk
        if ch.n and first != ch.first + ch.n:
            self._flush_chunk()
            ch = self._chunk
        if not ch.n:
            ch.first = first
        ch.parts.append(data)
        ch.n += data.shape[0]
        ch.t, ch.produced = t, produced
        if ch.n >= self.cfg.block_samples:
            self._flush_chunk()

    def _flush_chunk(self) -> None:
        ch, self._chunk = self._chunk, _Chunk()
        if not ch.n:
            return
        c = self.cfg
        data = np.concatenate(ch.parts).astype(np.float32)
        status, self._flags = self._flags, BlockStatus.OK
        cause, self._restart_cause = self._restart_cause, None
        block = SampleBlock(c.stream, ch.first, self.fs, tuple(c.channels), data, status)
        self._emit(block, cause or "link", now=ch.t, produced=ch.produced, restart=cause is not None)

    def _restart_from(self, why: str) -> None:
        """The device started a new run: close the old run's block and read the new one from its head."""
        self._flush_chunk()
        self._restart_cause = why
        self._next = None

    def _check_device(self) -> None:
        """After a reconnect, before any ack: is this still the run the driver was reading?"""
        nxt = self._next
        if nxt is None:
            return  # nothing acknowledged yet: reading from the head releases nothing
        ctl = self.map.control
        fifo = self.map.fifo
        assert fifo is not None
        status = int(self._read(ctl.status, "read status"))
        counter = int(self._read(ctl.sample_counter, "read sample counter"))
        rr = self._call(
            "peek FIFO head",
            lambda cl: cl.read_holding_registers(fifo.window_address, count=fifo.header_registers, device_id=self.unit),
            (3, fifo.header_registers, None),
        )
        (head,) = struct.unpack(">Q", struct.pack(">4H", *rr.registers[:4]))
        why = None
        if counter < nxt:
            why = f"its sample counter reads {counter} after the reconnect, below the {nxt} the driver wanted"
        elif head + self.spf < nxt:
            why = f"its FIFO starts at {head} after the reconnect, below the {nxt} the driver had acknowledged"
        if not status & 1 and self.cfg.control:
            self._write(ctl.command, 1, "start")
            why = why or "it was found stopped after the reconnect; start began a new run"
        if why is not None:
            self._restart_from(why)

    def _poll_once(self, k: int) -> None:
        lo, n = self._poll_lo, self._poll_n
        try:
            rr = self._call("poll read", lambda cl: cl.read_holding_registers(lo, count=n, device_id=self.unit), (3, n, None))
        except _Stopping:
            raise
        regs = rr.registers
        vals = [p.decode(regs[p.address - lo : p.end - lo], self.wo) for p in self._poll_regs]
        data = np.array([vals], np.float32)
        self._emit(
            SampleBlock(f"{self.cfg.stream}.poll", k, self.cfg.poll_hz, tuple(self.cfg.poll), data), cause="missed poll tick"
        )

    # --- helpers for tools/tests -----------------------------------------------------------
    @property
    def socket(self) -> socket.socket | None:
        return getattr(self._client, "socket", None)
