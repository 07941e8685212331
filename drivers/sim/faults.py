"""Fault knobs of the simulated device's transports, seeded so every run injects the same faults.

Each transport applies the knobs that make sense for it and *records what it injected* (the exact
sample ranges it destroyed), so tests can check reported loss == injected loss.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

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


@dataclass
class Faults:
    byte_corruption_rate: float = 0.0  # serial: probability per byte of flipping a random bit
    frame_drop_rate: float = 0.0  # serial / CAN: probability per frame of not sending it
    timeout_rate: float = 0.0  # Modbus: probability per request of not answering
    stall_every_s: float | None = None  # pause output this often…
    stall_for_s: float = 0.0  # …for this long (data keeps accruing in the device buffer)
    disconnect_at_s: float | None = None  # close the link at this device time…
    disconnect_for_s: float = 0.0  # …for this long (samples produced meanwhile are lost)
    seed: int = 0
    injected: list[tuple[int, int]] = field(default_factory=list)  # sample ranges destroyed [start, end)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def record(self, start: int, end: int) -> None:
        with self._lock:
            self.injected.append((int(start), int(end)))

    def injected_samples(self) -> int:
        with self._lock:
            return sum(b - a for a, b in merge_ranges(self.injected))
