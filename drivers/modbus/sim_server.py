"""The simulated device as a Modbus TCP server on 127.0.0.1: block FIFO, control and slow registers.

The server speaks Modbus TCP (MBAP framing; FC 3, 4, 6, 16, 23) itself on its own asyncio loop in a
thread, rather than through pymodbus's server, because the fault knobs need what that server cannot do:
process a request and then *not answer it* (a lost response), and close every connection and the
listening socket for N seconds. The driver side uses the pymodbus client, so the two are checked
against an independent implementation.

The FIFO protocol (docs/protocols/modbus.md) is addressed by sample index, so a lost response is
recoverable: one FC 23 read/write request writes ``ack`` = the next sample index the reader wants
(releasing everything before it) and reads the frame that starts there. A retry of the same request
returns the same frame. The FIFO holds ``fifo_seconds`` of samples; what overflows is recorded in
``faults.record`` with its exact range (the only way this transport destroys samples).

Fault knobs besides lost responses and the disconnect: a stall (``stall_at_s``/``stall_every_s`` +
``stall_for_s``) answers nothing for a while, the FIFO keeps filling (nothing lost); a restart
(``restart_at_s``/``restart_down_s``) closes every connection and stops listening, then comes back with its
FIFO empty and its clock and index restarted at 0 (running, or stopped until a start command if
``come_back_running`` is False), recorded in ``faults.restarts``. Device time counts from the first start.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivers.modbus.register_map import RegisterMap, load_register_map
from drivers.sim.device import SimulatedDevice
from drivers.sim.faults import Faults, RestartRecord

DEFAULT_MAP = Path(__file__).resolve().parents[2] / "configs" / "modbus" / "gvt_sim_device.toml"

ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE = 1, 2, 3
_CHUNK = 4096  # samples quantised at a time


class _ModbusError(Exception):
    def __init__(self, code: int) -> None:
        self.code = code


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ModbusSimServer:
    """``device`` served over Modbus TCP; ``channels`` (names) is the FIFO's channel subset."""

    def __init__(
        self,
        device: SimulatedDevice,
        faults: Faults | None = None,
        channels: Sequence[str] | None = None,
        *,
        register_map: RegisterMap | str | Path = DEFAULT_MAP,
        port: int = 0,
        fifo_seconds: float = 8.0,
        input_range_volts: float = 10.0,
        host: str = "127.0.0.1",
    ) -> None:
        self.device = device
        self.faults = faults or Faults()
        self.map = register_map if isinstance(register_map, RegisterMap) else load_register_map(register_map)
        if self.map.fifo is None:
            raise ValueError("the sim server needs a register map with a [fifo]")
        names = list(channels) if channels is not None else list(device.channels)
        self.channels = tuple(names)
        self._dev_idx = [device.channels.index(n) for n in names]
        self._map_idx = [self.map.fifo_channel_index(n) for n in names]
        if self._map_idx != sorted(self._map_idx):
            raise ValueError("FIFO channels must be given in register-map order")
        self._scales = np.array([self.map.fifo.channels[i].scale for i in self._map_idx])
        self.samples_per_frame = self.map.fifo.samples_per_frame(len(names))
        self.capacity = round(fifo_seconds * device.fs)
        self.port = port or free_port()
        self.host = host  # 127.0.0.1 unless the caller (gvt device serve --host) says otherwise
        self.input_range_volts = input_range_volts
        self.running = False
        self.overflowed = False
        self._frozen: int | None = None  # samples produced when stopped
        self._head = 0  # first sample still held in the FIFO
        self._delivered = 0  # end of the last frame whose response was sent (the reader has everything before it)
        self._frame_end = 0
        self._t_start = time.monotonic()
        self._epoch: float | None = None  # first start: device time of the fault knobs counts from here
        self._restart_pending = self.faults.restart_at_s is not None
        self._down_until: float | None = None
        self.come_back_running = True  # after a restart: running at once, or stopped until a start command
        self._chunks: dict[int, np.ndarray] = {}
        # counters (read by tests)
        self.requests = 0
        self.dropped_responses = 0
        self.connections = 0
        self.outages = 0
        self.unanswered = 0  # requests met with silence while the device was down or stalled
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: asyncio.base_events.Server | None = None
        self._transports: set[asyncio.Transport] = set()
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._outage_task: asyncio.Task | None = None
        self._restart_task: asyncio.Task | None = None

    # --- lifecycle ------------------------------------------------------------------------
    def start(self) -> str:
        """Serve in a background thread; returns how to connect (one line)."""
        self._thread = threading.Thread(target=self._thread_main, name="modbus-sim", daemon=True)
        self._thread.start()
        if not self._ready.wait(5.0):
            raise RuntimeError("modbus sim server did not start within 5 s")
        if self._start_error is not None:
            raise RuntimeError(f"modbus sim server failed to start: {self._start_error}") from self._start_error
        return (
            f"Modbus TCP {self.host}:{self.port} unit {self.map.device.unit_id}: "
            f"{len(self.channels)} FIFO channels {','.join(self.channels)} at {self.device.fs:g} Hz, "
            f"{self.samples_per_frame} samples/frame (driver: modbus host={self.host} port={self.port})"
        )

    def stop(self) -> None:
        if self._loop is None:
            return
        loop = self._loop
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout=5)
        except Exception:
            pass
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._loop = None
        self._account_overflow()

    def __enter__(self) -> ModbusSimServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def disconnect_for(self, seconds: float) -> None:
        """Fault: drop every connection and stop listening for ``seconds``, then listen again."""
        assert self._loop is not None
        asyncio.run_coroutine_threadsafe(self._outage(seconds), self._loop)

    # --- asyncio side ---------------------------------------------------------------------
    def _thread_main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._listen())
        except BaseException as exc:
            self._start_error = exc
            self._ready.set()
            return
        if self.faults.disconnect_at_s is not None:
            self._outage_task = loop.create_task(self._scheduled_outage())
        if self.faults.restart_at_s is not None:
            self._restart_task = loop.create_task(self._scheduled_restart())
        self._ready.set()
        loop.run_forever()
        for t in asyncio.all_tasks(loop):
            t.cancel()
        loop.run_until_complete(asyncio.sleep(0))
        loop.close()

    async def _listen(self) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Protocol(self), self.host, self.port, reuse_address=True)

    async def _close_all(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        for t in list(self._transports):
            t.abort()
        self._transports.clear()
        await asyncio.sleep(0)

    async def _shutdown(self) -> None:
        await self._close_all()

    async def _outage(self, seconds: float) -> None:
        self.outages += 1
        await self._close_all()
        await asyncio.sleep(seconds)
        await self._listen()

    async def _scheduled_outage(self) -> None:
        # device time counts from the start command
        while not self.running:
            await asyncio.sleep(0.01)
        at = self._t_start + float(self.faults.disconnect_at_s or 0.0)
        await asyncio.sleep(max(0.0, at - time.monotonic()))
        await self._outage(self.faults.disconnect_for_s)

    async def _scheduled_restart(self) -> None:
        """TCP side of the restart: the device (and with it the listener) goes away, then comes back."""
        while self._epoch is None:
            await asyncio.sleep(0.01)
        at = self._epoch + float(self.faults.restart_at_s or 0.0)
        await asyncio.sleep(max(0.0, at - time.monotonic()))
        self._faults_now(time.monotonic())
        await self._close_all()
        if self._down_until is not None:
            await asyncio.sleep(max(0.0, self._down_until - time.monotonic()))
        self._faults_now(time.monotonic())
        await self._listen()

    # --- device state ---------------------------------------------------------------------
    def _faults_now(self, now: float) -> bool:
        """Apply a restart that is due; True while the device is down or stalled (it answers nothing).

        Called for every request (TCP and RTU alike) and by the TCP restart task, so the device's state
        follows the schedule whatever the transport."""
        f = self.faults
        if self._epoch is None:
            return False
        if self._restart_pending and now >= self._epoch + float(f.restart_at_s or 0.0):
            self._go_down()
        if self._down_until is not None:
            if now < self._down_until:
                return True
            t0, self._down_until = self._down_until, None
            if self.come_back_running:
                self._start(t0)
        return f.stall_end(now - self._epoch) is not None

    def _go_down(self) -> None:
        f = self.faults
        self._restart_pending = False
        assert self._epoch is not None
        t_down = self._epoch + float(f.restart_at_s or 0.0)
        old_end = self.device.samples_available(t_down) if self.running else self.produced()
        f.record_restart(RestartRecord(old_end, self._delivered, self._t_start, t_down + f.restart_down_s))
        self.running = False
        self._frozen = None
        self._down_until = t_down + f.restart_down_s

    def produced(self) -> int:
        if self._frozen is not None:
            return self._frozen
        if not self.running:
            return 0
        return self.device.samples_available()

    def _account_overflow(self) -> None:
        oldest = self.produced() - self.capacity
        if oldest > self._head:
            # destroyed for the reader: what it had not received (it may hold a frame it has not acknowledged yet)
            lo = max(self._head, min(self._delivered, oldest))
            if oldest > lo:
                self.faults.record(lo, oldest)
            self._head = oldest
            self.overflowed = True

    def _start(self, t0: float | None = None) -> None:
        if self.running:
            return  # idempotent: a retried start must not restart the run
        self._chunks.clear()
        self._head = self._delivered = self._frame_end = 0
        self._frozen = None
        self.overflowed = False
        self._t_start = time.monotonic() if t0 is None else t0
        if self._epoch is None:
            self._epoch = self._t_start
        self.device.start_clock(self._t_start)
        self.running = True

    def _stop(self) -> None:
        if self.running:
            self._frozen = self.device.samples_available()
            self.running = False

    def _quantised(self, start: int, stop: int) -> np.ndarray:
        out = []
        for c in range(start // _CHUNK, (stop - 1) // _CHUNK + 1):
            q = self._chunks.get(c)
            if q is None:
                x = self.device.samples(c * _CHUNK, (c + 1) * _CHUNK)[:, self._dev_idx].astype(np.float64)
                q = np.clip(np.round(x / self._scales), -32768, 32767).astype(np.int16)
                if len(self._chunks) > 8:
                    self._chunks.pop(min(self._chunks))
                self._chunks[c] = q
            a, b = max(start, c * _CHUNK), min(stop, (c + 1) * _CHUNK)
            out.append(q[a - c * _CHUNK : b - c * _CHUNK])
        return np.concatenate(out)

    def _frame(self) -> list[int]:
        fifo = self.map.fifo
        assert fifo is not None
        self._account_overflow()
        produced = self.produced()
        first = self._head
        n = max(0, min(self.samples_per_frame, produced - first))
        hdr = struct.pack(">QHIH", first, n, max(0, produced - first), 2 * self.overflowed + self.running)
        regs = list(struct.unpack(">4HH2HH", hdr))
        self._frame_end = first + n
        if n:
            regs += self._quantised(first, first + n).reshape(-1).view(np.uint16).tolist()
        return regs + [0] * (fifo.window_registers - len(regs))

    # --- register space -------------------------------------------------------------------
    def _snapshot(self) -> dict[int, int]:
        m, wo = self.map, self.map.device.word_order
        c = m.control
        mask = sum(1 << i for i in self._map_idx)
        t = time.monotonic() - self._t_start
        vals = {
            c.status: 1 * self.running + 2 * self.overflowed,
            c.sample_rate: round(self.device.fs),
            c.range: round(self.input_range_volts / c.range.scale),
            c.channel_mask: mask,
            c.sample_counter: self.produced(),
            c.command: 1 * self.running,
        }
        out: dict[int, int] = {}
        for reg, raw in vals.items():
            for k, w in enumerate(reg.raw_to_regs(raw, wo)):
                out[reg.address + k] = w
        slow = {"temperature": 21.5 + 0.01 * t, "supply_voltage": 24.0, "uptime": t}
        for p in m.poll:
            for k, w in enumerate(p.encode(slow.get(p.name, 0.0), wo)):
                out[p.address + k] = w
        return out

    def read(self, address: int, count: int) -> list[int]:
        fifo = self.map.fifo
        assert fifo is not None
        w0, w1 = fifo.window_address, fifo.window_address + fifo.window_registers
        if address < w1 and address + count > w0:
            if address != w0 or count > fifo.window_registers:
                raise _ModbusError(ILLEGAL_ADDRESS)
            regs = self._frame()[:count]
            if count <= fifo.header_registers:
                self._frame_end = -1  # a peek at the header: no sample reached the reader
            return regs
        snap = self._snapshot()
        return [snap.get(a, 0) for a in range(address, address + count)]

    def write(self, address: int, values: list[int]) -> None:
        m, wo = self.map, self.map.device.word_order
        c = m.control
        fifo = m.fifo
        assert fifo is not None
        end = address + len(values)

        def field(reg) -> int | float | None:
            if address <= reg.address and reg.end <= end:
                return reg.regs_to_raw(values[reg.address - address : reg.end - address], wo)
            if address < reg.end and reg.address < end:
                raise _ModbusError(ILLEGAL_ADDRESS)  # partial write of a multi-register value
            return None

        touched = False
        if (v := field(fifo.ack)) is not None:
            touched = True
            self._account_overflow()
            # release everything before v (never past what exists)
            self._head = max(self._head, min(int(v), self.produced()))
        if (v := field(c.sample_rate)) is not None:
            touched = True
            if int(v) != round(self.device.fs):
                raise _ModbusError(ILLEGAL_VALUE)
        if (v := field(c.range)) is not None:
            touched = True
            if not 0 < int(v) <= 100:
                raise _ModbusError(ILLEGAL_VALUE)
            self.input_range_volts = int(v) * c.range.scale
        if (v := field(c.command)) is not None:
            touched = True
            if int(v) == 1:
                self._start()
            elif int(v) == 0:
                self._stop()
            else:
                raise _ModbusError(ILLEGAL_VALUE)
        if not touched:
            raise _ModbusError(ILLEGAL_ADDRESS)

    def handle(self, unit: int, pdu: bytes) -> bytes | None:
        """One request PDU -> response PDU, or None to not answer (the timeout fault)."""
        self.requests += 1
        if self._faults_now(time.monotonic()):
            self.unanswered += 1  # down (restarting) or stalled: silence, nothing processed
            return None
        fc = pdu[0]
        self._frame_end = -1
        try:
            if unit not in (0, self.map.device.unit_id):
                return None  # not addressed to us: a real device stays silent
            if fc in (3, 4):
                addr, count = struct.unpack(">HH", pdu[1:5])
                if not 1 <= count <= 125:
                    raise _ModbusError(ILLEGAL_VALUE)
                regs = self.read(addr, count)
                resp = struct.pack(f">BB{count}H", fc, 2 * count, *regs)
            elif fc == 6:
                addr, value = struct.unpack(">HH", pdu[1:5])
                self.write(addr, [value])
                resp = pdu[:5]
            elif fc == 16:
                addr, count, _nbytes = struct.unpack(">HHB", pdu[1:6])
                self.write(addr, list(struct.unpack(f">{count}H", pdu[6 : 6 + 2 * count])))
                resp = pdu[:5]
            elif fc == 23:
                raddr, rcount, waddr, wcount, _nbytes = struct.unpack(">HHHHB", pdu[1:10])
                if not 1 <= rcount <= 125:
                    raise _ModbusError(ILLEGAL_VALUE)
                self.write(waddr, list(struct.unpack(f">{wcount}H", pdu[10 : 10 + 2 * wcount])))  # write first (spec)
                regs = self.read(raddr, rcount)
                resp = struct.pack(f">BB{rcount}H", fc, 2 * rcount, *regs)
            else:
                raise _ModbusError(ILLEGAL_FUNCTION)
        except _ModbusError as e:
            resp = bytes([fc | 0x80, e.code])
        except struct.error:
            resp = bytes([fc | 0x80, ILLEGAL_VALUE])
        if self.faults.timeout_rate > 0 and self.faults.rng.random() < self.faults.timeout_rate:
            self.dropped_responses += 1  # processed, but the response is lost
            return None
        self._delivered = max(self._delivered, self._frame_end)
        return resp

    def bound_address(self) -> tuple[str, int] | None:
        """(host, port) the listening socket is bound to (None during an outage)."""
        srv = self._server
        return srv.sockets[0].getsockname()[:2] if srv is not None and srv.sockets else None


class _Protocol(asyncio.Protocol):
    def __init__(self, server: ModbusSimServer) -> None:
        self.server = server
        self.buf = b""
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.server._transports.add(transport)
        self.server.connections += 1

    def connection_lost(self, exc: Exception | None) -> None:
        if self.transport is not None:
            self.server._transports.discard(self.transport)

    def data_received(self, data: bytes) -> None:
        self.buf += data
        while len(self.buf) >= 8:
            tid, pid, length, unit = struct.unpack(">HHHB", self.buf[:7])
            if pid != 0 or not 2 <= length <= 254:
                assert self.transport is not None
                self.transport.abort()  # garbage: a real device drops the connection
                return
            if len(self.buf) < 6 + length:
                return
            pdu, self.buf = self.buf[7 : 6 + length], self.buf[6 + length :]
            resp = self.server.handle(unit, pdu)
            if resp is not None and self.transport is not None:
                self.transport.write(struct.pack(">HHHB", tid, 0, len(resp) + 1, unit) + resp)
