"""The SampleBlock contract (architecture.md): what crosses every boundary between drivers, session,
log, analysis and viewers. Blocks, never single samples.

Time of sample i of a block = stream t0 + (first_index + i) / sample_rate.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import IntFlag

import numpy as np


class BlockStatus(IntFlag):
    """Per-block status flags; the details of each go to ``/daq/events``."""

    OK = 0
    GAP_BEFORE = 1  # samples are missing between the previous block of this stream and this one
    CRC_ERROR = 2  # frames of this block's span failed their CRC and were dropped
    OVERRUN = 4  # a queue overflowed in this block's span
    TIMEOUT = 8
    RECONNECT = 16  # the link reconnected just before this block
    CLIPPED = 32  # at least one sample reached a channel's range
    RESTART = 64  # first block of a new segment: the device restarted (or re-based its index) before it


@dataclass(frozen=True)
class SampleBlock:
    stream: str
    first_index: int
    sample_rate: float
    channels: tuple[str, ...]
    data: np.ndarray  # float32 (n_samples, n_channels), SI units
    status: BlockStatus = BlockStatus.OK
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        d = self.data
        if not isinstance(d, np.ndarray) or d.dtype != np.float32 or d.ndim != 2:
            raise ValueError("SampleBlock.data must be a float32 array of shape (n_samples, n_channels)")
        if d.shape[1] != len(self.channels):
            raise ValueError(f"SampleBlock: {d.shape[1]} data columns but {len(self.channels)} channel names")
        if self.sample_rate <= 0:
            raise ValueError("SampleBlock.sample_rate must be positive")

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[0])

    @property
    def end_index(self) -> int:
        """One past the last sample index of this block."""
        return self.first_index + self.n_samples


def coalesce(blocks: Iterable[SampleBlock], max_samples: int) -> Iterator[SampleBlock]:
    """Join consecutive, contiguous blocks of one stream into blocks of up to ``max_samples`` (statuses OR-ed).

    Never across a ``RESTART`` block: two runs of a device are never one block.

    Fewer, larger blocks cost per-call consumers less: ``gvt analyze`` feeds 0.5 s chunks, the live view
    draws what queued up since its last turn in one go.
    """
    for run in _runs(blocks, max_samples, lambda _run, b: bool(b.status & BlockStatus.RESTART)):
        yield _join(run)


def _runs(
    blocks: Iterable[SampleBlock], max_samples: int, breaks: Callable[[list[SampleBlock], SampleBlock], bool]
) -> Iterator[list[SampleBlock]]:
    """Consecutive, contiguous blocks of one stream, up to ``max_samples`` a run; ``breaks(run, block)`` ends a run
    before ``block`` for the caller's own reasons (:func:`coalesce`, :func:`join_runs`)."""
    pending: list[SampleBlock] = []
    n = 0
    for b in blocks:
        if pending and (b.stream != pending[-1].stream or b.first_index != pending[-1].end_index
                        or n + b.n_samples > max_samples or breaks(pending, b)):  # fmt: skip
            yield pending
            pending, n = [], 0
        pending.append(b)
        n += b.n_samples
    if pending:
        yield pending


def _join(parts: list[SampleBlock]) -> SampleBlock:
    if len(parts) == 1:
        return parts[0]
    status = BlockStatus.OK
    for p in parts:
        status |= p.status
    p0 = parts[0]
    return SampleBlock(p0.stream, p0.first_index, p0.sample_rate, p0.channels, np.concatenate([p.data for p in parts]), status)


#: flags that speak of what came before a block (a gap, a restart, a reconnect): a joined run may start with them
_BEFORE = BlockStatus.GAP_BEFORE | BlockStatus.RESTART | BlockStatus.RECONNECT


def join_runs(blocks: Iterable[SampleBlock], max_samples: int) -> Iterator[SampleBlock]:
    """Join consecutive, contiguous blocks of one stream into blocks of up to ``max_samples``, losing nothing:
    unlike :func:`coalesce` no flag moves. A block joins the run before it only when it has no flag at all and the
    run's flags all speak of what came before its first sample (``GAP_BEFORE``, ``RESTART``, ``RECONNECT``); a
    block with any other flag (CRC errors, an overrun, clipping: of its own span) keeps its own boundaries.

    Why (issue 30 item 5): a serial device sends 64-sample frames, 256 a second at 16384 Hz, and every block
    costs each consumer of the recording process (the writer's message, preview and index entry; the hit
    gate; the ring to the lane worker) a fixed Python overhead: the device source joins what queued up over
    a few tens of milliseconds. The first block's ``extra`` is kept (the source stamps the arrival after).
    """
    def breaks(run: list[SampleBlock], b: SampleBlock) -> bool:
        p0 = run[0]
        return bool(b.status or p0.status & ~_BEFORE or b.channels != p0.channels or b.sample_rate != p0.sample_rate)

    for run in _runs(blocks, max_samples, breaks):
        yield _join_same(run)


def _join_same(parts: list[SampleBlock]) -> SampleBlock:
    if len(parts) == 1:
        return parts[0]
    p0 = parts[0]
    return SampleBlock(p0.stream, p0.first_index, p0.sample_rate, p0.channels, np.concatenate([p.data for p in parts]),
                       p0.status, dict(p0.extra))  # fmt: skip
