"""Replay a session log into the same fan-out a live session uses (``gvt replay``).

Blocks keep their boundaries and device sample indices, streams are interleaved in time order, and
pacing is either full speed or a multiple of real time (1.0 = as recorded). Pacing waits on an event
until each block's due time — no polling loop — so ``stop()`` ends a replay at once.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from daq.fanout import FanOut
from daq.log.reader import OVERLAP, Damage, DamageRanges, LogDamagedError, LogReader, LogReadError
from drivers.blocks import BlockStatus, SampleBlock


@dataclass
class ReplayStats:
    blocks: int = 0
    samples: dict[str, int] = field(default_factory=dict)
    gaps: dict[str, list[tuple[int, int]]] = field(default_factory=dict)
    log_seconds: float = 0.0
    wall_seconds: float = 0.0
    error: str | None = None  # the log could not be read on from here (one line: what and where)
    bad_blocks: list[str] = field(default_factory=list)  # undecodable blocks, skipped (gaps downstream)


#: Blocks per stream held to put blocks back in sample order. The writer writes each stream in order, so
#: this only matters for a log assembled out of order; it bounds replay memory (64 blocks of 1024 × 15
#: float32 are 4 MB) where sorting a whole stream held every decoded sample of the log (3.5 GB an hour
#: at 15 ch × 16384 Hz).
REORDER_BLOCKS = 64


def iter_log_blocks(
    reader: LogReader, streams: Iterable[str] | None = None, reorder: int = REORDER_BLOCKS, bad: list[str] | None = None
) -> Iterator[SampleBlock]:
    """Every sample block of every stream (or of ``streams``), merged in time order (ties: stream name).

    Blocks are decoded as they are read, with at most ``reorder`` blocks per stream held back to restore
    sample order. A block further out of place than that is yielded where it is found (consumers treat
    it like any discontinuity). A block over samples already yielded is never yielded (D78, as an export):
    a bit-identical repeat (a chunk logged twice) quietly, a block that disagrees or holds samples no yielded
    block has as damage over its range (:data:`~daq.log.reader.OVERLAP`). Every chunk is CRC-checked and
    every block checked (``block_problem``); a damaged chunk or a block that does not decode or is
    implausible is skipped — a gap to the consumer, like a lost block — and its exact sample range described
    in ``bad`` (one line each) when a list is given; without one it raises :class:`LogDamagedError` (exit 3,
    naming ``gvt log recover``).
    """
    infos = reader.streams()
    names = sorted(infos) if streams is None else sorted(set(streams))
    missing = [n for n in names if n not in infos]
    if missing:
        raise LogReadError(f"{reader.path}: no stream(s) {missing}; streams: {sorted(infos)}")

    def one(name: str) -> Iterator[tuple[float, str, int, SampleBlock]]:
        info = infos[name]
        held: list[tuple[int, int, SampleBlock]] = []
        tracker = DamageRanges(info, {ch.id for ch in reader.channels() if ch.topic == info.topic})

        def out(b) -> tuple[float, str, int, SampleBlock]:
            blk = SampleBlock(name, b.first_index, b.sample_rate, tuple(info.channels), b.data, BlockStatus(b.status))
            return (info.t0_ns / 1e9 + b.first_index / b.sample_rate, name, b.first_index, blk)

        yielded: list[list[int]] = []  # merged [first, end) ranges yielded (one, in a log as written)

        def overlaps(b) -> bool:
            """Block ``b`` is over samples already yielded: judged against the log as the reader keeps it (first
            read wins, compared bit for bit over the block's own window), reported if they disagree, dropped."""
            a, z = b.first_index, b.first_index + b.data.shape[0]
            if not yielded or a >= yielded[-1][1] or not any(lo < z and a < hi for lo, hi in yielded):
                _merge_into(yielded, a, z)
                return False
            rate = info.sample_rate
            kept = reader.read_stream(name, start=a / rate, end=z / rate, on_damage="skip")
            if any(why == OVERLAP for _lo, _hi, why in kept.damaged):
                report([(a, z, OVERLAP)])
            return True

        def report(ranges: list[tuple[int, int, str]]) -> None:
            for a, z, why in ranges:
                what = f"{reader.path}: {name} samples [{a}, {z}) skipped: {why}"
                if bad is None:
                    raise LogDamagedError(f"{what}; `gvt log recover {reader.path} FIXED.mcap` keeps the rest")
                bad.append(what)

        if bad is not None:  # what the log had lost before `gvt log recover` (D101): said, never a refusal
            report(reader.recovered_damage(name))
        for seq, item in enumerate(reader.iter_blocks(name)):
            if isinstance(item, Damage):
                tracker.damage(item)
                continue
            b = item[1]
            done = len(tracker.ranges)
            tracker.block(b.first_index, b.first_index + b.data.shape[0])
            report(tracker.ranges[done:])
            heapq.heappush(held, (b.first_index, seq, b))
            if len(held) > reorder and not overlaps(nxt := heapq.heappop(held)[2]):
                yield out(nxt)
        done = len(tracker.ranges)
        report(tracker.finish(reader.stream_records().get(name, {}).get("end_index"))[done:])
        while held:
            if not overlaps(nxt := heapq.heappop(held)[2]):
                yield out(nxt)

    for _t, _name, _i, blk in heapq.merge(*(one(n) for n in names), key=lambda x: x[:3]):
        yield blk


def _merge_into(ranges: list[list[int]], a: int, z: int) -> None:
    """Add [a, z) to the sorted, merged ``ranges`` (blocks come in order: the last range grows, O(1))."""
    if ranges and ranges[-1][0] <= a <= ranges[-1][1]:
        ranges[-1][1] = max(ranges[-1][1], z)
        return
    ranges.append([a, z])
    ranges.sort()
    merged = [ranges[0]]
    for lo, hi in ranges[1:]:
        if lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    ranges[:] = merged


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

    def run(self, close: bool = True) -> ReplayStats:
        """Publish every block (paced or at full speed); ``close``: end the fan-out afterwards (a
        :class:`~daq.recorder.Recorder` closes it itself, after all its sources stopped)."""
        streams = self.reader.streams()
        start_wall = time.monotonic()
        t_first: float | None = None
        last_end: dict[str, int] = {}
        blocks = iter_log_blocks(self.reader, bad=self.stats.bad_blocks)
        while True:
            try:
                blk = next(blocks)
            except StopIteration:
                break
            except LogReadError as exc:  # what came before is replayed and analysed; the caller reports the rest
                self.stats.error = str(exc)
                break
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
        if close:
            self.fanout.close()
        self.stats.wall_seconds = time.monotonic() - start_wall
        return self.stats
