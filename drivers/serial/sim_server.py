"""The simulated device served over a pseudo-terminal, speaking docs/protocols/serial.md.

A pty ignores the baud rate, so output is paced by the device clock: the server thread waits on an
Event until the next block is due (no sleep-polling), then encodes and writes every block that exists.
Fault knobs (:class:`~drivers.sim.faults.Faults`), each recording exactly the sample ranges it destroys
(in the *served* stream's index space, i.e. after ``decimate``):

* ``byte_corruption_rate``: per byte, flip one random bit. Binary: the hit frame fails its CRC, so its
  whole sample range is recorded. ASCII: the hit character is replaced by ``?`` (a line with a bit
  error that still parses cannot be detected without a checksum; see the protocol doc), so that line's
  index is recorded.
* ``frame_drop_rate``: a frame (or line) is not sent at all; its range is recorded.
* ``stall_every_s`` / ``stall_at_s`` / ``stall_for_s``: output pauses (periodically / once); the device
  keeps buffering, nothing is lost.
* ``disconnect_at_s`` / ``disconnect_for_s``: the link goes dead: nothing is written while the device
  clock runs on, so every frame due in that window is lost (recorded as one range).
* ``restart_at_s`` / ``restart_down_s``: the device goes away after its last whole frame before
  ``restart_at_s`` (nothing is written), and comes back ``restart_down_s`` later with its clock and its
  index restarted at 0 (recorded in ``faults.restarts``, not as loss).
* ``wild_frames``: extra CRC-valid frames (ASCII: lines) with a wild first index, written once the device
  time passes theirs; the stream around them is untouched.

The server keeps its own slave fd open for its whole life, so the tty (and its buffered input) survives
the driver closing and re-opening the port.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import numpy as np

from drivers.serial.protocol import BITS, FORMATS, encode_frame, encode_lines
from drivers.sim.device import SimulatedDevice
from drivers.sim.faults import Faults, RestartRecord
from drivers.sim.timing import precise_wakeups


class SerialSimServer:
    def __init__(
        self,
        device: SimulatedDevice,
        faults: Faults | None = None,
        fmt: str = "int24",
        frame_samples: int = 64,
        usb: bool = True,
        *,
        channels: list[int] | None = None,
        decimate: int = 1,
        stream_id: int = 0,
        pace: bool = True,
    ) -> None:
        if fmt != "ascii" and fmt not in FORMATS:
            raise ValueError(f"fmt must be one of {[*FORMATS, 'ascii']}, not {fmt!r}")
        self.device = device
        self.faults = faults or Faults()
        self.fmt = fmt
        self.frame_samples = int(frame_samples)
        self.usb = usb
        self.channels = list(range(device.n_channels)) if channels is None else list(channels)
        self.decimate = int(decimate)
        self.stream_id = stream_id
        self.pace = pace  # False: write as fast as the pty takes it (benchmark)
        self.fs = device.fs / self.decimate
        self.scales = self._scales()
        self.bytes_out = 0
        self.frames_out = 0
        self.next_index = 0  # next served sample index to send
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.precise_wakeups: bool | None = None  # the sending thread runs with 1 ns timer slack (drivers/sim/timing.py)
        self._master: int | None = None
        self._slave: int | None = None
        self.path = ""

    def _scales(self) -> np.ndarray:
        """Per-channel value of one count: the device ADC's own LSB when the format is wide enough."""
        adc = self.device.adc
        out = []
        for c in self.channels:
            sens = self.device.channel_models[c].sensitivity_v_per_unit
            bits = BITS.get(FORMATS.get(self.fmt, 3), 32)
            if bits >= adc.bits:
                out.append(adc.lsb_volts / sens)
            else:
                out.append(adc.input_range_volts / sens / (2 ** (bits - 1) - 1))
        return np.asarray(out, np.float32)

    def start(self, hold: bool = False) -> str:
        """Create the pty and serve. ``hold=True``: the device clock starts only at :meth:`go` — a
        session opens its driver first, because pyserial flushes the input buffer on open and frames
        written before that would be lost (and reported as a gap)."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: a clean 8-bit byte pipe
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._go = threading.Event()
        self._thread = threading.Thread(target=self._main, name="serial-sim", daemon=True)
        self._thread.start()
        if not hold:
            self.go()
        return f"serial sim: port = {self.path!r} ({self.fmt}, {len(self.channels)} ch @ {self.fs:g} Hz, pty ignores baud)"

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def __enter__(self) -> SerialSimServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- the thread --------------------------------------------------------------------------
    def _due_time(self, served_end: int) -> float:
        """Monotonic time at which served sample ``served_end - 1`` exists on the device."""
        t0 = self.device._t0
        assert t0 is not None
        return t0 + served_end * self.decimate / self.device.fs

    def go(self) -> None:
        """Start the device clock (sample 0 is now)."""
        self.device.start_clock()
        self._go.set()

    def _main(self) -> None:
        self.precise_wakeups = precise_wakeups()  # sent when due, not up to a host timer's slack later (drivers/sim/timing.py)
        try:
            while not self._go.wait(0.1):
                if self._stop.is_set():
                    return
            self._loop()
        except BaseException as exc:  # a test reads .error
            self.error = exc

    def _loop(self) -> None:
        f = self.faults
        fsz = self.frame_samples
        self._epoch = self.device._t0 or 0.0  # device time of the stall and wild-frame knobs counts from here
        self._restart_lo = None if f.restart_at_s is None else int(f.restart_at_s * self.fs)
        self._wild = sorted(f.wild_frames)
        self._dis: tuple[int, int] | None = None
        if f.disconnect_at_s is not None:
            t1 = f.disconnect_at_s + f.disconnect_for_s
            self._dis = (int(np.ceil(f.disconnect_at_s * self.fs)), int(np.ceil(t1 * self.fs)))
        self._dis_recorded = False
        self._seq = 0
        ahead: tuple[int, bytes] | None = None  # (first index, bytes) of the next frame, encoded before it is due
        while not self._stop.is_set():
            if self._restart_lo is not None and self.next_index + fsz > self._restart_lo:
                if not self._restart():
                    return
                ahead = None
                continue
            end = self.next_index + fsz
            if self.pace:
                # Encode the frame before it is due and write it when it is: a real device sends a block a fixed
                # latency after its last sample, whatever its channel count. Encoding after the wait put a
                # 14-channel device's frames 20-55 µs later than a 1-channel device's: a clock-offset bias of
                # 0.4-0.9 samples between the two that no link has (D95). Encoded half a frame before it is due,
                # not at once after the last write: the reader that write woke needs the GIL this encoding holds
                # (a device in the recorder's process; a real one is not), longer for more channels.
                if ahead is None or ahead[0] != self.next_index:
                    half = 0.5 * fsz * self.decimate / self.device.fs
                    if self._stop.wait(max(0.0, self._due_time(end) - half - time.monotonic())):
                        return
                    ahead = (self.next_index, self._frames(self.next_index, 1, wild=False))
                delay = self._due_time(end) - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
            stall_end = f.stall_end(time.monotonic() - self._epoch)
            if stall_end is not None and self._stop.wait(max(0.0, self._epoch + stall_end - time.monotonic())):
                return
            # every whole frame that exists now (at least the one we waited for), never past a restart
            avail = self.device.samples_available() // self.decimate if self.pace else end + 63 * fsz
            n_frames = max(1, (avail - self.next_index) // fsz)
            if self._restart_lo is not None:
                n_frames = max(1, min(n_frames, (self._restart_lo - self.next_index) // fsz))
            if ahead is not None and ahead[0] == self.next_index:
                data = ahead[1] + (self._frames(end, n_frames - 1) if n_frames > 1 or self._wild else b"")
            else:
                data = self._frames(self.next_index, n_frames)
            ahead = None
            self.next_index += n_frames * fsz
            self._write_all(data)
            self.frames_out += n_frames

    def _restart(self) -> bool:
        """The device goes away now and comes back ``restart_down_s`` after ``restart_at_s``, counting from 0.
        False if the server was stopped meanwhile."""
        f = self.faults
        old_t0 = self.device._t0 or 0.0
        new_t0 = old_t0 + float(f.restart_at_s or 0.0) + f.restart_down_s
        assert self._restart_lo is not None
        f.record_restart(RestartRecord(self._restart_lo, self.next_index, old_t0, new_t0))
        self._restart_lo = None
        if self._stop.wait(max(0.0, new_t0 - time.monotonic())):
            return False
        self.device.start_clock(new_t0)
        self.next_index = 0
        self._seq = 0
        self._dis = None  # a disconnect window is in the old run's index space
        return True

    def _frames(self, lo: int, n_frames: int, wild: bool = True) -> bytes:
        """Frames ``lo // fsz …`` (none if ``n_frames`` is 0) encoded with the per-frame faults applied, plus any
        wild frame now due (``wild``)."""
        f = self.faults
        fsz = self.frame_samples
        hi = lo + max(n_frames, 1) * fsz  # the wild frames take the values of one frame
        vals = self.device.samples(lo * self.decimate, hi * self.decimate)[:: self.decimate][:, self.channels]
        chunks = []
        for j in range(n_frames):
            a = lo + j * fsz
            b = a + fsz
            self._seq += 1
            if self._dis is not None and b > self._dis[0] and a < self._dis[1]:
                if not self._dis_recorded:  # the whole dead window, whole frames, as one range
                    f.record(a, -(-self._dis[1] // fsz) * fsz)  # frames are aligned to frame_samples
                    self._dis_recorded = True
                continue
            if f.frame_drop_rate > 0 and f.rng.random() < f.frame_drop_rate:
                f.record(a, b)
                continue
            v = vals[j * fsz : (j + 1) * fsz]
            if self.fmt == "ascii":
                chunks.append(self._ascii_with_faults(a, v))
            else:
                fr = encode_frame(a, v, self.fmt, self.scales, seq=self._seq - 1, stream_id=self.stream_id)
                chunks.append(self._corrupt(fr, a, b))
        dev_t = time.monotonic() - self._epoch
        while wild and self._wild and self._wild[0][0] <= dev_t:
            _, index = self._wild.pop(0)
            v = vals[:fsz]
            if self.fmt == "ascii":
                chunks.append(encode_lines(index, v[:1]))
            else:
                chunks.append(encode_frame(index, v, self.fmt, self.scales, seq=self._seq, stream_id=self.stream_id))
        return b"".join(chunks)

    def _corrupt(self, fr: bytes, a: int, b: int) -> bytes:
        f = self.faults
        if f.byte_corruption_rate <= 0:
            return fr
        hits = int(f.rng.binomial(len(fr), f.byte_corruption_rate))
        if hits == 0:
            return fr
        ba = bytearray(fr)
        for pos in f.rng.integers(0, len(fr), hits):
            ba[pos] ^= 1 << int(f.rng.integers(0, 8))
        f.record(a, b)
        return bytes(ba)

    def _ascii_with_faults(self, a: int, v: np.ndarray) -> bytes:
        f = self.faults
        if f.byte_corruption_rate <= 0:
            return encode_lines(a, v)
        out = []
        for i in range(v.shape[0]):
            line = bytearray(encode_lines(a + i, v[i : i + 1]))
            hits = int(f.rng.binomial(len(line) - 1, f.byte_corruption_rate))
            if hits:
                for pos in f.rng.integers(0, len(line) - 1, hits):
                    line[pos] = ord("?")
                f.record(a + i, a + i + 1)
            out.append(bytes(line))
        return b"".join(out)

    def _write_all(self, data: bytes) -> None:
        mv = memoryview(data)
        while mv and not self._stop.is_set():
            assert self._master is not None
            try:
                n = os.write(self._master, mv)
            except BlockingIOError:  # pty buffer full (the reader is slow): wait until it drains
                select.select([], [self._master], [], 0.1)
                continue
            mv = mv[n:]
            self.bytes_out += n
