"""Replay a session log into the same fan-out a live session uses (``gvt replay``).

Blocks keep their boundaries and device sample indices, streams are interleaved in time order, and
pacing is either full speed or a multiple of real time (1.0 = as recorded). Pacing waits on an event
until each block's due time — no polling loop — so ``stop()`` ends a replay at once.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from daq.blocks import BlockStatus, SampleBlock
from daq.fanout import FanOut
from daq.log.proto import decode_block
from daq.log.reader import LogReader


@dataclass
class ReplayStats:
    blocks: int = 0
    samples: dict[str, int] = field(default_factory=dict)
    gaps: dict[str, list[tuple[int, int]]] = field(default_factory=dict)
    log_seconds: float = 0.0
    wall_seconds: float = 0.0


def iter_log_blocks(reader: LogReader) -> Iterator[SampleBlock]:
    """Every sample block of every stream, merged in time order (ties: stream name)."""
    streams = reader.streams()

    def one(name: str) -> Iterator[tuple[float, str, int, SampleBlock]]:
        info = streams[name]
        decoded = []
        for _ch, msg in reader.iter_messages([info.topic]):
            b = decode_block(msg.data)
            decoded.append(b)
        decoded.sort(key=lambda b: b.first_index)
        for b in decoded:
            blk = SampleBlock(name, b.first_index, b.sample_rate, tuple(info.channels), b.data, BlockStatus(b.status))
            yield (info.t0_ns / 1e9 + b.first_index / b.sample_rate, name, b.first_index, blk)

    for _t, _name, _i, blk in heapq.merge(*(one(n) for n in sorted(streams)), key=lambda x: x[:3]):
        yield blk


class Replayer:
    def __init__(self, path: str | Path, fanout: FanOut, speed: float | None = None) -> None:
        """``speed=None`` or ``0``: full speed; ``1.0``: real time; ``2.0``: twice as fast."""
        self.reader = LogReader(path)
        self.fanout = fanout
        self.speed = speed if speed else None
        self._stop = threading.Event()
        self.stats = ReplayStats()

    def stop(self) -> None:
        self._stop.set()

    def run(self) -> ReplayStats:
        streams = self.reader.streams()
        start_wall = time.monotonic()
        t_first: float | None = None
        last_end: dict[str, int] = {}
        for blk in iter_log_blocks(self.reader):
            if self._stop.is_set():
                break
            t_block = streams[blk.stream].t0_ns / 1e9 + blk.first_index / blk.sample_rate
            if t_first is None:
                t_first = t_block
            if self.speed is not None:
                due = start_wall + (t_block - t_first) / self.speed
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
            prev = last_end.get(blk.stream)
            if prev is not None and blk.first_index > prev:
                self.stats.gaps.setdefault(blk.stream, []).append((prev, blk.first_index))
            last_end[blk.stream] = blk.end_index
            self.fanout.publish(blk)
            self.stats.blocks += 1
            self.stats.samples[blk.stream] = self.stats.samples.get(blk.stream, 0) + blk.n_samples
            self.stats.log_seconds = max(self.stats.log_seconds, t_block + blk.n_samples / blk.sample_rate - (t_first or 0.0))
        self.fanout.close()
        self.stats.wall_seconds = time.monotonic() - start_wall
        return self.stats
