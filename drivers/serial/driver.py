"""Serial driver (pyserial): binary frames or ASCII lines (docs/protocols/serial.md) -> SampleBlocks.

The reader thread reads whatever the port has, feeds the incremental decoder and emits one block per
frame (binary) or per run of consecutive lines (ASCII), always with the device's own sample index, so
the base class reports every missing range exactly. A frame failing its CRC or a line failing to parse
is dropped and counted; its samples become a gap. The port is re-opened, with exponential back-off,
after an I/O error or after ``silence_reconnect_s`` without a valid frame.

Config (TOML)::

    [driver]
    kind = "serial"
    port = "/dev/ttyACM0"
    usb_cdc = true            # native-USB CDC: the baud rate is ignored, ~1 MB/s
    sample_rate = 16384
    channels = ["hammer", "a1", "a2"]
    sample_format = "int24"   # for the link budget; frames say their own format
"""

from __future__ import annotations

import os
import time
from collections import deque
from typing import Literal

import numpy as np
import serial
from pydantic import Field, model_validator

from drivers.base import Driver, DriverConfig, DriverError, DriverEvent, LinkBudget
from drivers.blocks import BlockStatus, SampleBlock
from drivers.serial.protocol import FORMATS, WIDTH, FrameDecoder, LineDecoder, frame_overhead

#: bytes one turn of the reading loop takes at most: a device delivering a backlog (what it held when the link opened)
#: keeps the port full, and reading it all in one turn decoded seconds of frames at once, faster than the owner takes
#: blocks (its queue overran); 64 kB is what a tty buffers, ~22 frames of 15 ch x 64 samples int24
READ_MAX_BYTES = 1 << 16


class SerialConfig(DriverConfig):
    port: str
    sample_rate: float = Field(gt=0)
    channels: list[str] = Field(min_length=1, max_length=255)
    mode: Literal["binary", "ascii"] = "binary"
    baudrate: int = Field(921600, gt=0)
    usb_cdc: bool = False  # native-USB CDC ACM: baud ignored, capacity usb_bytes_per_s
    usb_bytes_per_s: float = Field(1_000_000.0, gt=0)
    # binary mode
    sample_format: Literal["int16", "int24", "int32", "float32"] = "int24"
    frame_samples: int = Field(64, ge=1, le=65535)  # samples per frame the device sends (link budget)
    stream_id: int | None = Field(None, ge=0, le=255)  # accept only frames of this stream id
    # ASCII mode: line = index column + value columns
    index_column: int = Field(0, ge=0)
    columns: list[int] | None = None  # column of each channel; default 1..n (after the index)
    delimiter: Literal["auto", ",", ";", "\t", "whitespace"] = "auto"
    scale: list[float] | None = None  # value = float(column) * scale + offset, per channel
    offset: list[float] | None = None
    ascii_block_lines: int = Field(256, ge=1)
    ascii_line_bytes: int | None = Field(None, ge=2)  # for the link budget; default 12 + 14 per channel
    # link behaviour
    read_timeout_s: float = Field(0.05, gt=0)
    silence_reconnect_s: float = Field(1.0, gt=0)
    backoff_initial_s: float = Field(0.1, gt=0)
    backoff_max_s: float = Field(2.0, gt=0)

    @model_validator(mode="after")
    def _check_columns(self) -> SerialConfig:
        n = len(self.channels)
        for name in ("columns", "scale", "offset"):
            v = getattr(self, name)
            if v is not None and len(v) != n:
                raise ValueError(f"{name} needs one entry per channel ({n}), got {len(v)}")
        return self


class SerialDriver(Driver):
    name = "serial"
    config_model = SerialConfig

    def __init__(self, config: SerialConfig) -> None:  # type: ignore[override]
        super().__init__(config)
        self.cfg = config
        self._port: serial.Serial | None = None
        self._channels = tuple(config.channels)
        if config.mode == "binary":
            self.decoder: FrameDecoder | LineDecoder = FrameDecoder()
        else:
            cols = tuple(config.columns) if config.columns is not None else tuple(range(1, len(config.channels) + 1))
            self.decoder = LineDecoder(
                cols,
                index_column=config.index_column,
                delimiter=config.delimiter,
                scale=tuple(config.scale) if config.scale is not None else None,
                offset=tuple(config.offset) if config.offset is not None else None,
            )
        self._bad_seen = 0
        self._counted_bad = 0
        self._fed = 0  # bytes fed to the decoder so far (its stream offsets)
        self._reads: deque[tuple[int, float]] = deque()  # (stream offset past a read's last byte, its host time)
        self._reconnected = False
        self.wrong_shape = 0
        self._next_read = 0.0  # monotonic time of the next turn's read while data flows (``gather_s``)

    # --- link budget -----------------------------------------------------------------------
    def link_budget(self) -> LinkBudget:
        c = self.cfg
        n = len(c.channels)
        if c.usb_cdc:
            capacity, link = c.usb_bytes_per_s, "native-USB CDC"
        else:
            capacity, link = c.baudrate / 10.0, f"{c.baudrate} baud 8N1 (10 bits per byte)"
        if c.mode == "binary":
            width = WIDTH[FORMATS[c.sample_format]]
            ovh = frame_overhead(n, c.sample_format)
            needed = c.sample_rate * n * width + c.sample_rate / c.frame_samples * ovh
            detail = (
                f"{n} ch x {width} B ({c.sample_format}) x {c.sample_rate:g} Hz + {ovh} B per {c.frame_samples}-sample frame "
                f"over {link}"
            )
        else:
            line = c.ascii_line_bytes or 12 + 14 * n
            needed = c.sample_rate * line
            detail = f"{c.sample_rate:g} lines/s x ~{line} B per ASCII line ({n} ch) over {link}"
        return LinkBudget(needed=needed, capacity=capacity, unit="B/s", detail=detail)

    # --- port ------------------------------------------------------------------------------
    def _open_port(self) -> serial.Serial:
        return serial.Serial(self.cfg.port, self.cfg.baudrate, timeout=self.cfg.read_timeout_s)

    def _connect(self) -> None:
        try:
            self._port = self._open_port()
        except (serial.SerialException, OSError) as exc:
            raise DriverError(f"serial: cannot open {self.cfg.port!r}: {exc} (check the port name and permissions)") from exc

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    def _reconnect(self, why: str) -> None:
        """Close, then re-open with exponential back-off until it works or the driver stops."""
        self._close_port()
        delay = self.cfg.backoff_initial_s
        while not self.stopping:
            if self._stop.wait(delay):
                return
            try:
                self._port = self._open_port()
            except (serial.SerialException, OSError) as exc:
                self.stats.retries += 1
                self._event(DriverEvent("timeout", self.cfg.stream, message=f"re-open {self.cfg.port} failed: {exc}"))
                delay = min(2 * delay, self.cfg.backoff_max_s)
                continue
            self.stats.reconnects += 1
            self._reconnected = True
            self._event(DriverEvent("reconnect", self.cfg.stream, message=f"port re-opened after {why}"))
            return

    # --- reader thread ---------------------------------------------------------------------
    def _run(self) -> None:
        last_good = time.monotonic()
        try:
            while not self.stopping:
                if self._port is None:
                    self._reconnect("a failed open")
                    last_good = time.monotonic()
                    continue
                try:
                    data = self._read_available(self._port)
                except (serial.SerialException, OSError, TypeError) as exc:
                    if self.stopping:
                        break
                    self._reconnect(f"I/O error: {exc}")
                    last_good = time.monotonic()
                    continue
                now = time.monotonic()
                if data:
                    self.stats.bytes_in += len(data)
                    if self._handle(data, now):
                        last_good = now
                if now - last_good > self.cfg.silence_reconnect_s:
                    self.stats.timeouts += 1
                    self._event(DriverEvent("timeout", self.cfg.stream, message=f"no valid data for {now - last_good:.2f} s"))
                    self._reconnect(f"{now - last_good:.2f} s of silence")
                    last_good = time.monotonic()
        finally:
            self._close_port()

    def _read_available(self, port: serial.Serial) -> bytes:
        """Wait up to ``read_timeout_s`` for the first byte, let input gather ``gather_s``, then take all the port
        holds. Reading ``max(1, in_waiting)`` on an empty port returned the first byte alone and the rest on the next
        turn: two decodes and two turns of this loop per frame (issue 30 item 5: 256 frames a second at 16384 Hz).
        With ``gather_s`` a turn also begins at most every ``gather_s`` while data flows: a steady stream always has
        bytes waiting, and taking them at once read one frame a turn (147 turns a second at 15 ch x 16384 Hz, 0.02
        core; D106). The pause is bounded far below what the link buffers (a tty holds 64 kB: 87 ms at 15 ch x 16384
        Hz int24)."""
        if self.gather_s > 0 and (wait := self._next_read - time.monotonic()) > 0 and self._stop.wait(wait):
            return b""
        n = port.in_waiting
        if n:
            data = port.read(n)
        else:
            data = port.read(1)
            if not data:
                return data
            if self.gather_s > 0 and self._stop.wait(self.gather_s):
                return data
        data = _drain(port, data)
        self._next_read = time.monotonic() + self.gather_s
        return data

    def _status(self) -> tuple[BlockStatus, str]:
        st = BlockStatus.OK
        cause = "frame dropped"
        bad = self._bad_total()
        if bad > self._bad_seen:
            st |= BlockStatus.CRC_ERROR
            cause = "CRC/parse errors"
            self._bad_seen = bad
        if self._reconnected:
            st |= BlockStatus.RECONNECT
            cause = "link down, reconnected"
            self._reconnected = False
        return st, cause

    def _began(self, at: int) -> float:
        """Host time of the read that brought stream byte ``at`` (a frame's or line's first byte).

        Why the first byte, not the read that completed the block (issue 30 item 4, docs/decisions.md D95): a
        device sends a block once it is sampled, so its first byte leaves "block sampled + the device's fixed
        latency" after the block's last sample, whatever the frame's length, while the last byte also carries the
        frame's transfer time (frame bytes × 10 / baud on a UART; several reads over a pty). Stamping the last
        byte biased the clock offset between a 14-channel and a 1-channel device by the difference. Offsets only
        grow, so the reads before ``at`` are forgotten."""
        reads = self._reads
        while len(reads) > 1 and reads[0][0] <= at:
            reads.popleft()
        return reads[0][1]

    def _bad_total(self) -> int:
        d = self.decoder
        return (d.stats.frames_bad if isinstance(d, FrameDecoder) else d.stats.lines_bad) + self.wrong_shape

    def _handle(self, data: bytes, now: float | None = None) -> bool:
        """Decode ``data`` (read at host time ``now``) and emit blocks; True if anything valid arrived."""
        now = time.monotonic() if now is None else now
        self._fed += len(data)
        self._reads.append((self._fed, now))
        if isinstance(self.decoder, FrameDecoder):
            got = self._handle_frames(data, now)
        else:
            got = self._handle_lines(data, now)
        self._began(self._fed - self.decoder.buffered)  # forget the reads whose bytes are all decoded or skipped
        total = self._bad_total()
        self.stats.frames_bad += total - self._counted_bad  # the base counts its own (duplicates) too
        self._counted_bad = total
        return got

    def _handle_frames(self, data: bytes, now: float) -> bool:
        c = self.cfg
        assert isinstance(self.decoder, FrameDecoder)
        bad_before = self.decoder.stats.frames_bad
        frames = self.decoder.feed(data)
        if self.decoder.stats.frames_bad > bad_before:
            n_bad = self.decoder.stats.frames_bad - bad_before
            self._event(DriverEvent("crc_error", c.stream, count=n_bad, message=f"{n_bad} bad frame(s) dropped"))
        frames = [fr for fr in frames if c.stream_id is None or fr.stream_id == c.stream_id]
        produced = _run_ends([(fr.first_index, fr.first_index + fr.n_samples) for fr in frames])
        for fr, prod in zip(frames, produced, strict=True):
            if fr.data.shape[1] != len(self._channels):
                self.wrong_shape += 1
                msg = f"frame has {fr.data.shape[1]} channels, config has {len(self._channels)}"
                dev = {"device_start": fr.first_index, "device_end": fr.first_index + fr.n_samples}
                self._event(DriverEvent("frame_error", c.stream, count=fr.n_samples, message=msg, **dev))
                continue
            status, cause = self._status()
            extra = {"seq": fr.seq, "t_arrival": self._began(fr.at)}
            block = SampleBlock(c.stream, fr.first_index, c.sample_rate, self._channels, fr.data, status, extra)
            self._emit(block, cause, now=now, produced=prod)
        self.stats.frames_ok = self.decoder.stats.frames_ok
        self.stats.garbage_bytes = self.decoder.stats.garbage_bytes
        self.stats.resyncs = self.decoder.stats.resyncs
        return bool(frames)

    def _handle_lines(self, data: bytes, now: float) -> bool:
        c = self.cfg
        assert isinstance(self.decoder, LineDecoder)
        lines = self.decoder.feed(data)
        self.stats.frames_ok = self.decoder.stats.lines_ok
        runs = []
        i = 0
        while i < len(lines):  # runs of consecutive indices, at most ascii_block_lines long
            j = i + 1
            while j < len(lines) and j - i < c.ascii_block_lines and lines[j].index == lines[j - 1].index + 1:
                j += 1
            runs.append((i, j))
            i = j
        produced = _run_ends([(lines[i].index, lines[j - 1].index + 1) for i, j in runs])
        for (i, j), prod in zip(runs, produced, strict=True):
            block = np.stack([ln.values for ln in lines[i:j]])
            status, cause = self._status()
            extra = {"t_arrival": self._began(lines[i].at)}
            blk = SampleBlock(c.stream, lines[i].index, c.sample_rate, self._channels, block, status, extra)
            self._emit(blk, cause, now=now, produced=prod)
        return bool(lines)


def _drain(port: serial.Serial, data: bytes) -> bytes:
    """``data`` and whatever else the port holds, up to READ_MAX_BYTES. A tty hands out at most 4 kB a read (~190 reads
    a second at 15 ch x 16384 Hz int24): straight ``os.read`` calls on pyserial's non-blocking descriptor until it has
    nothing (EAGAIN), instead of ``in_waiting`` + ``read`` (an ioctl, a select and pyserial's timeout loop, ~30 us a
    read). A port without a descriptor (another pyserial backend) is read the portable way."""
    fd = getattr(port, "fd", None)
    if not isinstance(fd, int):
        while len(data) < READ_MAX_BYTES and (n := port.in_waiting):
            data += port.read(n)
        return data
    buf = bytearray(data)
    while len(buf) < READ_MAX_BYTES:
        try:
            chunk = os.read(fd, READ_MAX_BYTES - len(buf))
        except BlockingIOError:
            break
        except OSError as exc:  # as pyserial reports it: the driver's I/O-error path reconnects
            raise serial.SerialException(f"read failed: {exc}") from exc
        if not chunk:
            break
        buf += chunk
    return bytes(buf)


def _run_ends(spans: list[tuple[int, int]]) -> list[int]:
    """For each [first, end) of one read, the end of the contiguous run it starts: the device had produced
    at least that much when the read returned (what the restart estimate needs). A frame not continued by
    the next one (a wild index, a gap) ends its own run, so one bad frame cannot inflate another's."""
    out = [0] * len(spans)
    run_end = 0
    for k in range(len(spans) - 1, -1, -1):
        end = spans[k][1]
        run_end = run_end if k + 1 < len(spans) and spans[k + 1][0] == end else end
        out[k] = run_end
    return out
