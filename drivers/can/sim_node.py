"""The simulated device as a CAN (FD) node: one DBC sample message, sent on a python-can bus.

The node owns the device clock (``device.start_clock()``) and runs in its own thread. It waits on an
Event until the next device block is due (no sleep-polling), then sends every frame whose samples exist:
frame ``c`` carries samples ``[c * spf, (c + 1) * spf)`` of the DBC message's channels, quantised to the
DBC's int16 scale, with ``FrameCounter = c mod 2**bits``. Fault knobs (:class:`~drivers.sim.faults.Faults`):
``frame_drop_rate`` (a frame is not sent) and ``disconnect_at_s``/``disconnect_for_s`` (the node closes its
bus and reopens it later); every destroyed sample range is recorded with ``faults.record``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import can

from drivers.can.dbc_map import load_layouts
from drivers.sim.device import SimulatedDevice
from drivers.sim.faults import Faults

DEFAULT_DBC = Path(__file__).resolve().parents[2] / "configs" / "can" / "gvt_sim_node.dbc"


class CanSimNode:
    def __init__(
        self,
        device: SimulatedDevice,
        faults: Faults | None = None,
        *,
        dbc: str | Path = DEFAULT_DBC,
        message: str = "GVT_FD3",
        interface: str = "virtual",
        channel: str | int = "gvt0",
        fd: bool | None = None,
        paced: bool = True,
        max_frames: int | None = None,
        bus_factory: Callable[[], can.BusABC] | None = None,
    ) -> None:
        self.device = device
        self.faults = faults or Faults()
        self.layout = load_layouts(dbc, [message])[0]
        missing = [c for c in self.layout.channels if c not in device.channels]
        if missing:
            raise ValueError(f"DBC message {message} carries channels {missing} the device does not have ({device.channels})")
        self.columns = [device.channels.index(c) for c in self.layout.channels]
        self.fd = self.layout.is_fd if fd is None else fd
        if self.layout.is_fd and not self.fd:
            raise ValueError(f"DBC message {message} is a CAN FD frame ({self.layout.length} B): fd must be true")
        self.interface, self.channel = interface, channel
        self.paced = paced
        self.max_frames = max_frames
        self._bus_factory = bus_factory or (lambda: can.Bus(interface=interface, channel=channel, fd=self.fd))
        self._bus: can.BusABC | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames_sent = 0
        self.frames_destroyed = 0
        self.next_frame = 0  # frames [0, next_frame) were sent or destroyed
        self.error: BaseException | None = None

    @property
    def samples_done(self) -> int:
        return self.next_frame * self.layout.spf

    def start(self) -> str:
        self._bus = self._bus_factory()
        if self.paced:
            self.device.start_clock()
        self._thread = threading.Thread(target=self._main, name=f"can-sim:{self.layout.name}", daemon=True)
        self._thread.start()
        lay = self.layout
        return (
            f"CAN sim node: {lay.name} (id 0x{lay.frame_id:X}, {'CAN FD' if self.fd else 'classic CAN'}, {lay.length} B, "
            f"{', '.join(lay.channels)}, {lay.spf} samples/frame) on {self.interface}:{self.channel} — connect with "
            f'[driver] kind = "can", interface = "{self.interface}", channel = "{self.channel}", '
            f'fd = {str(self.fd).lower()}, messages = ["{lay.name}"], sample_rate = {self.device.fs:g}'
        )

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self._close()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    # --- the node thread ---------------------------------------------------------------------
    def _main(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # kept for the test/owner to inspect
            self.error = exc
            raise

    def _loop(self) -> None:
        dev, lay, f = self.device, self.layout, self.faults
        spf, bs = lay.spf, dev.block_size
        chunk = max(1, 4096 // spf)  # frames per numpy step when unpaced
        down_from = down_to = None
        if f.disconnect_at_s is not None:
            down_from = int(f.disconnect_at_s * dev.fs)
            down_to = int((f.disconnect_at_s + f.disconnect_for_s) * dev.fs)
        while not self._stop.is_set():
            if self.max_frames is not None and self.next_frame >= self.max_frames:
                return
            if self.paced:
                avail = dev.blocks_available() * bs // spf
                if avail <= self.next_frame:
                    block = ((self.next_frame + 1) * spf - 1) // bs
                    self._stop.wait(max(0.0, dev.time_of_block(block) - time.monotonic()))
                    continue
            else:
                avail = self.next_frame + chunk
            if self.max_frames is not None:
                avail = min(avail, self.max_frames)
            k0 = self.next_frame
            raw = lay.quantise(dev.samples(k0 * spf, avail * spf)[:, self.columns])
            frames = lay.encode_frames(k0, raw)
            for i in range(avail - k0):
                k = k0 + i
                a, b = k * spf, (k + 1) * spf
                if down_from is not None and down_to is not None and b > down_from and a < down_to:
                    if self._bus is not None:  # the link goes down: every frame until it is back is lost
                        self._close()
                    f.record(a, b)
                    self.frames_destroyed += 1
                    continue
                if self._bus is None:
                    self._bus = self._bus_factory()
                if f.frame_drop_rate and f.rng.random() < f.frame_drop_rate:
                    f.record(a, b)
                    self.frames_destroyed += 1
                    continue
                self._bus.send(
                    can.Message(
                        arbitration_id=lay.frame_id,
                        is_extended_id=lay.is_extended,
                        is_fd=self.fd,
                        bitrate_switch=self.fd,
                        data=frames[i].tobytes(),
                    )
                )
                self.frames_sent += 1
            self.next_frame = avail
