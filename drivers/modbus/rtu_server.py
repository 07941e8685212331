"""The simulated device as a Modbus RTU slave on a pseudo-terminal (no serial hardware, no socat).

``ModbusRtuSimServer`` reuses ``ModbusSimServer.handle`` (the application layer: FIFO via FC 23 with
acknowledge, control and polled registers, the response-loss fault) and replaces the TCP listener with
RTU framing on the master side of ``os.openpty()``. The slave side is put in raw mode and its path is
what a serial client opens (``start()`` returns it in the "how to connect" line). A pty ignores the baud
rate, so the link runs as fast as the two processes can exchange bytes.

Framing is by function code (the request lengths are fixed or carry a byte count): FC 3/4/6 are 8 bytes,
FC 16 is 9 + byte count, FC 23 is 13 + byte count; an unknown function code discards one byte (resync).
The CRC-16/MODBUS (low byte first) is checked: a frame with a bad CRC is dropped without an answer, as a
real slave does, and the client times out and retries. Bytes of an incomplete frame followed by
``gap_s`` of silence are dropped too (the RTU inter-frame silence, stretched to what a thread can time).
"""

from __future__ import annotations

import os
import select
import threading
import tty

from drivers.modbus.sim_server import ModbusSimServer


def _crc_table() -> list[int]:
    table = []
    for b in range(256):
        crc = b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS: reflected poly 0xA001, init 0xFFFF; appended to a frame low byte first."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ b) & 0xFF]
    return crc


def with_crc(frame: bytes) -> bytes:
    """``frame`` + its CRC (low byte first)."""
    return frame + crc16(frame).to_bytes(2, "little")


def request_length(buf: bytes) -> int | None:
    """Length of the RTU request frame at the start of ``buf`` (unit .. CRC), 0 for an unknown function
    code, or None if more bytes are needed to tell."""
    if len(buf) < 2:
        return None
    fc = buf[1]
    if fc in (3, 4, 6):
        return 8
    if fc == 16:
        return 9 + buf[6] if len(buf) >= 7 else None
    if fc == 23:
        return 13 + buf[10] if len(buf) >= 11 else None
    return 0


class ModbusRtuSimServer(ModbusSimServer):
    """``device`` served over Modbus RTU on a pty; ``channels`` (names) is the FIFO's channel subset.

    Keyword arguments are those of ``ModbusSimServer`` (register_map, fifo_seconds, ...) plus ``gap_s``.
    The TCP-only fault (disconnect) does not apply; ``faults.timeout_rate`` (lost responses), the stalls and
    the restart (the device answers nothing while down, then counts from 0 again) do, through ``handle``.
    """

    def __init__(self, device, faults=None, channels=None, *, gap_s: float = 0.05, **kw) -> None:
        super().__init__(device, faults, channels, **kw)
        self.gap_s = gap_s
        self.path = ""
        self.bad_crc = 0  # counters (read by tests)
        self.discarded_bytes = 0
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._stopping = threading.Event()
        self._rtu_thread: threading.Thread | None = None

    # --- lifecycle ------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty and serve in a background thread; returns how to connect (one line)."""
        if self._rtu_thread is not None:
            raise RuntimeError("modbus RTU sim server already started")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes pass unchanged (no echo, no CR/LF mapping, no line discipline)
        self.path = os.ttyname(self._slave)  # the slave stays open here, so the master never reads EIO
        self._wake_r, self._wake_w = os.pipe()
        self._stopping.clear()
        self._rtu_thread = threading.Thread(target=self._serve, name="modbus-rtu-sim", daemon=True)
        self._rtu_thread.start()
        return (
            f"Modbus RTU {self.path} unit {self.map.device.unit_id}: "
            f"{len(self.channels)} FIFO channels {','.join(self.channels)} at {self.device.fs:g} Hz, "
            f"{self.samples_per_frame} samples/frame (driver: modbus transport=rtu serial_port={self.path})"
        )

    def stop(self) -> None:
        if self._rtu_thread is None:
            return
        self._stopping.set()
        assert self._wake_w is not None
        os.write(self._wake_w, b"x")
        self._rtu_thread.join(timeout=5)
        self._rtu_thread = None
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = None
        self._account_overflow()

    def __enter__(self) -> ModbusRtuSimServer:
        self.start()
        return self

    def disconnect_for(self, seconds: float) -> None:
        raise NotImplementedError("a serial line has no connection to drop")

    def _faults_now(self, now: float) -> bool:
        """On a serial line a disconnect (a cable pulled, ``disconnect_at_s`` for ``disconnect_for_s``) is
        silence: no request reaches the device and no answer comes back, while it keeps acquiring into its
        FIFO — on the line it looks like a stall."""
        f = self.faults
        if self._epoch is not None and f.disconnect_at_s is not None:
            t = now - self._epoch
            if f.disconnect_at_s <= t < f.disconnect_at_s + f.disconnect_for_s:
                return True
        return super()._faults_now(now)

    def bound_address(self) -> tuple[str, int] | None:
        return None

    # --- RTU side -------------------------------------------------------------------------
    def _serve(self) -> None:
        master, wake = self._master, self._wake_r
        assert master is not None and wake is not None
        buf = b""
        while not self._stopping.is_set():
            # wait for bytes; with a partial frame held, a silence of gap_s ends it
            ready, _, _ = select.select([master, wake], [], [], self.gap_s if buf else 1.0)
            if wake in ready or self._stopping.is_set():
                break
            if not ready:
                if buf:
                    self.discarded_bytes += len(buf)
                    buf = b""
                continue
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: nobody has the slave open (cannot happen while we hold it)
                break
            buf += data
            buf = self._process(buf)

    def _process(self, buf: bytes) -> bytes:
        """Answer every complete frame at the start of ``buf``; returns what is left."""
        while True:
            n = request_length(buf)
            if n is None or len(buf) < n:
                return buf
            if n == 0:  # unknown function code: not a frame start
                buf = buf[1:]
                self.discarded_bytes += 1
                continue
            frame, buf = buf[:n], buf[n:]
            if crc16(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                self.bad_crc += 1  # a real slave stays silent; the master times out and retries
                continue
            unit = frame[0]
            resp = self.handle(unit, frame[1:-2])
            if resp is not None and unit != 0:  # no answer to a broadcast
                self._write(with_crc(bytes([unit]) + resp))

    def _write(self, data: bytes) -> None:
        assert self._master is not None
        view = memoryview(data)
        while view:
            k = os.write(self._master, view)
            view = view[k:]
