"""Fault knobs of the simulated device's transports, seeded so every run injects the same faults.

Each transport applies the knobs that make sense for it and *records what it injected* (the exact
sample ranges it destroyed), so tests can check reported loss == injected loss.

A device restart (``restart_at_s``) destroys nothing in that sense: the device goes away and comes back
counting from 0. What the oracle needs to check the new segment is recorded in :attr:`Faults.restarts`
(:class:`RestartRecord`): where the old run stopped and both runs' clocks. A restart needs a
:class:`~drivers.sim.device.SimulatedDevice`: a ``DelayedDeviceView``'s clock is bound to its base and is
not restarted by ``start_clock``, so its index would run on.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np


def merge_ranges(ranges) -> list[tuple[int, int]]:
    """Sorted, overlapping or touching ``[start, end)`` ranges merged into disjoint ones."""
    out: list[list[int]] = []
    for a, b in sorted(ranges):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


@dataclass(frozen=True)
class RestartRecord:
    """One simulated device restart, as the transport did it (the oracle of the restart tests)."""

    old_end: int  # served index the old run had reached (every sample before it was produced; see delivered)
    delivered: int  # end of what the old run put on the link (== old_end where the link has no buffer)
    old_t0: float  # host monotonic time of the old run's sample 0
    new_t0: float  # host monotonic time of the new run's sample 0 (its index restarts at 0)

    def stream_index(self, new_index: int, fs: float) -> float:
        """Where the new run's sample ``new_index`` falls on the old run's clock: the stream index a
        perfect restart estimate gives it (the old index the device would have reached then)."""
        return (self.new_t0 - self.old_t0) * fs + new_index


@dataclass
class Faults:
    byte_corruption_rate: float = 0.0  # serial: probability per byte of flipping a random bit
    frame_drop_rate: float = 0.0  # serial / CAN: probability per frame of not sending it
    timeout_rate: float = 0.0  # Modbus: probability per request of not answering
    stall_every_s: float | None = None  # pause output this often…
    stall_for_s: float = 0.0  # …for this long (data keeps accruing in the device buffer)
    disconnect_at_s: float | None = None  # close the link at this device time…
    disconnect_for_s: float = 0.0  # …for this long (samples produced meanwhile are lost)
    stall_at_s: float | None = None  # one stall at this device time, for stall_for_s (nothing lost)
    restart_at_s: float | None = None  # every transport: the device goes away at this device time…
    restart_down_s: float = 0.0  # …for this long, then comes back with its index (and clock) restarted at 0
    # serial: extra CRC-valid frames (lines in ASCII) injected at (device time s, first index), e.g. (1.0, 10**9)
    wild_frames: tuple[tuple[float, int], ...] = ()
    seed: int = 0
    injected: list[tuple[int, int]] = field(default_factory=list)  # sample ranges destroyed [start, end)
    restarts: list[RestartRecord] = field(default_factory=list)  # what each restart did (not in injected)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def record(self, start: int, end: int) -> None:
        with self._lock:
            self.injected.append((int(start), int(end)))

    def stall_end(self, t: float) -> float | None:
        """Device time at which the stall that device time ``t`` falls in ends, or None if there is none:
        the one-shot ``[stall_at_s, stall_at_s + stall_for_s)`` or a periodic ``[k * stall_every_s, … +
        stall_for_s)``, k >= 1. Device time here counts from the device's first start (a restart does not
        replay a one-shot stall)."""
        if self.stall_for_s <= 0:
            return None
        if self.stall_at_s is not None and self.stall_at_s <= t < self.stall_at_s + self.stall_for_s:
            return self.stall_at_s + self.stall_for_s
        every = self.stall_every_s
        if every is not None and every > 0 and t >= every:
            start = (t // every) * every
            if t < start + self.stall_for_s:
                return start + self.stall_for_s
        return None

    def record_restart(self, rec: RestartRecord) -> None:
        with self._lock:
            self.restarts.append(rec)

    def injected_samples(self) -> int:
        with self._lock:
            return sum(b - a for a, b in merge_ranges(self.injected))


@dataclass(frozen=True)
class SensorFaults:
    """Sensor-side faults of the simulated device, per channel name (issue 29): mains hum picked up in the cable,
    a sensor mounted or wired the wrong way round, a channel stuck at one value. Applied to the device's channel
    models (:meth:`apply`), so that a simulated session, its log and its replay carry them; the sensor model
    (drivers/sim/sensor_model.py) makes them, sample-exact."""

    hum_hz: float = 50.0
    hum_rms: dict[str, float] = field(default_factory=dict)  # channel -> hum RMS, SI units
    reversed: tuple[str, ...] = ()
    stuck: dict[str, float] = field(default_factory=dict)  # channel -> the value it reads

    def apply(self, channels: Sequence) -> list:
        """The channel models (drivers.sim.sensor_model.ChannelModel) with these faults; an unknown name is an error."""
        names = {c.name for c in channels}
        unknown = sorted((set(self.hum_rms) | set(self.reversed) | set(self.stuck)) - names)
        if unknown:
            raise ValueError(f"sensor faults name no channel {unknown[0]!r}; channels are {', '.join(sorted(names))}")
        return [
            replace(c, hum_hz=self.hum_hz if c.name in self.hum_rms else 0.0, hum_rms=self.hum_rms.get(c.name, 0.0),
                    polarity=-1 if c.name in self.reversed else 1, stuck_at=self.stuck.get(c.name))
            for c in channels
        ]  # fmt: skip
