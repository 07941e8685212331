"""In-process fan-out of sample blocks to subscribers through bounded queues.

The same object serves a live session and a replay (architecture.md). Publishing never blocks: a
subscriber that falls behind loses its own input, and the fan-out counts exactly which sample ranges
each subscriber missed, so the subscriber can say so. The recording path (the log writer) is not a
subscriber: it has its own queue and its own overrun accounting.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field

from drivers.blocks import SampleBlock

END = object()  # sentinel a subscriber receives when the source ends


@dataclass
class Subscription:
    name: str
    queue: queue.Queue
    dropped_blocks: int = 0
    dropped_samples: int = 0
    dropped_ranges: list[tuple[str, int, int]] = field(default_factory=list)
    #: when > 0, ``wake`` is set as soon as this many items are queued (and when the source ends): a
    #: subscriber that lets blocks pile up on purpose (the view, drawing in frames) waits on it instead of a
    #: timer, so a burst cannot overflow its queue while it waits
    high_water: int = 0
    wake: threading.Event = field(default_factory=threading.Event)

    def get(self, timeout: float | None = None) -> SampleBlock | object:
        """Next block, or ``END``; raises ``queue.Empty`` on timeout."""
        return self.queue.get(timeout=timeout)

    def __iter__(self):
        while True:
            item = self.queue.get()
            if item is END:
                return
            yield item


class FanOut:
    def __init__(self) -> None:
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()
        self.published_blocks = 0

    def subscribe(self, name: str, maxsize: int = 256) -> Subscription:
        sub = Subscription(name, queue.Queue(maxsize=max(1, maxsize)))
        with self._lock:
            self._subs.append(sub)
        return sub

    def publish(self, block: SampleBlock) -> None:
        with self._lock:
            subs = list(self._subs)
        for sub in subs:
            try:
                sub.queue.put_nowait(block)
            except queue.Full:
                sub.dropped_blocks += 1
                sub.dropped_samples += block.n_samples
                sub.dropped_ranges.append((block.stream, block.first_index, block.end_index))
            if sub.high_water and sub.queue.qsize() >= sub.high_water:
                sub.wake.set()
        self.published_blocks += 1

    def close(self) -> None:
        """Tell every subscriber the source ended, without ever blocking.

        END must arrive, so for a subscriber whose queue is full the oldest queued block makes room
        (and is counted as dropped, like any block that subscriber could not take).
        """
        with self._lock:
            subs = list(self._subs)
        for sub in subs:
            sub.wake.set()
            while True:
                try:
                    sub.queue.put_nowait(END)
                    break
                except queue.Full:
                    try:
                        old = sub.queue.get_nowait()
                    except queue.Empty:
                        continue
                    if isinstance(old, SampleBlock):
                        sub.dropped_blocks += 1
                        sub.dropped_samples += old.n_samples
                        sub.dropped_ranges.append((old.stream, old.first_index, old.end_index))
