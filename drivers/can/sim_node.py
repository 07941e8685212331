"""The simulated device as a CAN (FD) node: one DBC sample message, sent on a python-can bus.

The node owns the device clock (``device.start_clock()``) and runs in its own thread. It waits on an
Event until the next device block is due (no sleep-polling), then sends every frame whose samples exist:
frame ``c`` carries samples ``[c * spf, (c + 1) * spf)`` of the DBC message's channels, quantised to the
DBC's int16 scale, with ``FrameCounter = c mod 2**bits``. Fault knobs (:class:`~drivers.sim.faults.Faults`):
``frame_drop_rate`` (a frame is not sent) and ``disconnect_at_s``/``disconnect_for_s`` (the node closes its
bus and reopens it later); every destroyed sample range is recorded with ``faults.record``. A stall
(``stall_at_s``/``stall_every_s`` + ``stall_for_s``) sends nothing for a while and then the backlog (nothing
lost); a restart (``restart_at_s``/``restart_down_s``) sends nothing after the last whole frame before
``restart_at_s`` and comes back with its clock and counter restarted at 0 (recorded in ``faults.restarts``).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can

from drivers.can.dbc_map import load_layouts
from drivers.sim.device import SimulatedDevice
from drivers.sim.faults import Faults, RestartRecord
from drivers.sim.timing import precise_wakeups

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
        self.dbc = str(dbc)
        self.max_frames = max_frames
        self._bus_factory = bus_factory or (lambda: can.Bus(interface=interface, channel=channel, fd=self.fd))
        self._bus: can.BusABC | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.precise_wakeups: bool | None = None  # the sending thread runs with 1 ns timer slack (drivers/sim/timing.py)
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
            f"{', '.join(lay.channels)}, {lay.spf} samples/frame) on {self.interface}:{self.channel}; session TOML: "
            f"{self.session_toml()}"
        )

    def session_toml(self) -> str:
        """The session-config line that records this node: ``device = { driver = "can", config = {...} }`` is
        TOML for the ``[device]`` table, so it pastes into a session file as it is (one line)."""
        lay = self.layout

        def q(v: object) -> str:  # a TOML basic string is a JSON string for these (paths, names)
            return json.dumps(v) if isinstance(v, str) else str(v)

        cfg = {"interface": q(self.interface), "channel": q(self.channel), "fd": str(self.fd).lower()}
        cfg |= {"messages": f"[{q(lay.name)}]", "sample_rate": repr(float(self.device.fs))}
        if Path(self.dbc).resolve() != DEFAULT_DBC.resolve():
            cfg["dbc"] = q(str(Path(self.dbc).resolve()))
        inner = ", ".join(f"{k} = {v}" for k, v in cfg.items())
        return f'device = {{ driver = "can", config = {{ {inner} }} }}'

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
        self.precise_wakeups = precise_wakeups()  # sent when due, not up to a host timer's slack later (drivers/sim/timing.py)
        try:
            self._loop()
        except BaseException as exc:  # kept for the test/owner to inspect
            self.error = exc
            raise

    def _loop(self) -> None:
        dev, lay, f = self.device, self.layout, self.faults
        spf, bs = lay.spf, dev.block_size
        chunk = max(1, 4096 // spf)  # frames per numpy step when unpaced
        self._down = None
        if f.disconnect_at_s is not None:
            self._down = (int(f.disconnect_at_s * dev.fs), int((f.disconnect_at_s + f.disconnect_for_s) * dev.fs))
        self._epoch = dev._t0 or 0.0  # device time of the stall knobs counts from the first start
        restart_frame = None if f.restart_at_s is None or not self.paced else int(f.restart_at_s * dev.fs) // spf
        while not self._stop.is_set():
            if self.max_frames is not None and self.next_frame >= self.max_frames:
                return
            if restart_frame is not None and self.next_frame >= restart_frame:
                restart_frame = None
                if not self._restart():
                    return
                continue
            if self.paced:
                stall_end = f.stall_end(time.monotonic() - self._epoch)
                if stall_end is not None:
                    self._stop.wait(max(0.0, self._epoch + stall_end - time.monotonic()))
                    continue
                avail = dev.blocks_available() * bs // spf
                if avail <= self.next_frame:
                    block = ((self.next_frame + 1) * spf - 1) // bs
                    self._stop.wait(max(0.0, dev.time_of_block(block) - time.monotonic()))
                    continue
            else:
                avail = self.next_frame + chunk
            if self.max_frames is not None:
                avail = min(avail, self.max_frames)
            if restart_frame is not None:
                avail = min(avail, restart_frame)
            self._send(self.next_frame, avail)
            self.next_frame = avail

    def _restart(self) -> bool:
        """The node goes silent now and comes back ``restart_down_s`` after ``restart_at_s`` with its clock and
        counter at 0. False if it was stopped meanwhile."""
        dev, f = self.device, self.faults
        old_t0 = dev._t0 or 0.0
        new_t0 = old_t0 + float(f.restart_at_s or 0.0) + f.restart_down_s
        old_end = int(float(f.restart_at_s or 0.0) * dev.fs)
        f.record_restart(RestartRecord(old_end, self.samples_done, old_t0, new_t0))
        if self._stop.wait(max(0.0, new_t0 - time.monotonic())):
            return False
        dev.start_clock(new_t0)
        self.next_frame = 0
        self._down = None  # a disconnect window is in the old run's index space
        return True

    def _send(self, k0: int, k1: int) -> None:
        """Encode frames ``[k0, k1)`` and send them, applying the drop and disconnect knobs."""
        dev, lay, f = self.device, self.layout, self.faults
        spf = lay.spf
        raw = lay.quantise(dev.samples(k0 * spf, k1 * spf)[:, self.columns])
        frames = lay.encode_frames(k0, raw)
        for i in range(k1 - k0):
            k = k0 + i
            a, b = k * spf, (k + 1) * spf
            if self._down is not None and b > self._down[0] and a < self._down[1]:
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
