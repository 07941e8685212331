"""``gvt analyze LOG``: the near-live analysis kernels run in batch over a session log.

The log's blocks go through the same :class:`~analysis.operator.AnalysisOperator` a live session runs
(architecture.md: streaming is batch applied to windows as they complete), so ``gvt analyze`` of a
session's log reproduces what the session computed live. Consecutive blocks are coalesced into chunks
of up to ``chunk_s`` seconds (:func:`replay_chunk`: one second where that is at most ``CHUNK_VALUES`` values) before
they are fed (the operator's results do not depend on the block split, up to rounding), and the operator runs
pipelined (its seed lane one block ahead on a worker thread), which is what makes replay analysis fast. The rig
comes from ``--rig`` or from the log's own ``rig/*.toml`` attachment.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from analysis import records
from analysis.model.rig import Rig
from analysis.operator import AnalysisOperator, AnalysisSettings, RigModel
from daq.lanes.analysis import analysis_stream
from daq.log import layout
from daq.log.reader import LogReader, LogReadError
from daq.log.rig import AnalyzeError, rig_from_log
from daq.replay import iter_log_blocks
from drivers.blocks import SampleBlock, coalesce


@dataclass
class AnalysisRun:
    stream: str
    rig: str
    seconds_of_data: float = 0.0
    wall_seconds: float = 0.0
    results: dict[str, list[dict]] = field(default_factory=dict)
    bad_blocks: list[str] = field(default_factory=list)  # undecodable sample blocks, skipped (gaps to the operator)

    @property
    def events(self) -> list[dict]:
        return self.results.get(layout.IR_EVENTS_TOPIC, [])

    @property
    def speed(self) -> float:
        return self.seconds_of_data / self.wall_seconds if self.wall_seconds > 0 else float("inf")


def pick_stream(reader: LogReader, model: RigModel, stream: str | None) -> str:
    streams = reader.streams()
    if stream is not None:
        if stream not in streams:
            raise AnalyzeError(f"{reader.path}: no stream {stream!r}; streams: {sorted(streams)}")
        return stream
    name = analysis_stream({n: tuple(i.channels) for n, i in streams.items()}, model)
    if name is None:
        raise AnalyzeError(
            f"{reader.path}: no stream holds all the rig's sensor channels {list(model.sensors)}; "
            f"streams: { {n: list(i.channels) for n, i in streams.items()} }; give the rig that recorded it with --rig"
        )
    return name


#: a replay chunk holds at most this many values (samples x channels, 2 MB as float64) unless that is under half a
#: second: the operator's per-block work (~1.5 ms a block at 14 channels: the spike rules' and health screens' calls,
#: the pipeline's hand-offs) is paid half as often with 1 s chunks as with 0.5 s ones (bench/bench_analysis.py: 71 ->
#: 80x real time at 14 ch x 16384 Hz), while 64 ch x 51.2 kHz keeps its 0.5 s chunks (13 MB each as float64)
CHUNK_VALUES = 1 << 18


def replay_chunk(fs: float, n_channels: int) -> int:
    """Samples per replay chunk: one second of data, cut to ``CHUNK_VALUES`` values but never under half a second."""
    seconds = min(1.0, max(0.5, CHUNK_VALUES / (fs * max(1, n_channels))))
    return max(1, round(seconds * fs))


def open_for_analysis(path: str | Path, rig: Rig | None, stream: str | None) -> tuple[LogReader, Rig, RigModel, str]:
    """The log, its rig (given, or attached to the log), the rig's model and the stream that carries its sensors;
    :class:`AnalyzeError` (one line) when any of them cannot be had."""
    try:
        reader = LogReader(path)
    except LogReadError as exc:
        raise AnalyzeError(str(exc)) from None
    rig = rig if rig is not None else rig_from_log(reader)
    try:
        model = RigModel.from_rig(rig)
    except ValueError as exc:
        raise AnalyzeError(f"rig {rig.name}: {exc}") from None
    return reader, rig, model, pick_stream(reader, model, stream)


def analyze_log(
    path: str | Path,
    rig: Rig | None = None,
    stream: str | None = None,
    settings: AnalysisSettings | None = None,
    chunk_s: float | None = None,
    progress: Callable[[float], None] | None = None,
    pipelined: bool = True,
) -> AnalysisRun:
    """Run the operator over ``stream`` of the log in chunks of ``chunk_s`` (None: :func:`replay_chunk`);
    ``progress(fraction)`` about twice a second. ``pipelined``: the
    operator's three stages on three threads (D72), what one log alone wants; a campaign runs a log per core and its
    workers ask for one thread (``pipelined=False``: the same emits in the same order, docs/campaign.md)."""
    reader, rig, model, name = open_for_analysis(path, rig, stream)
    info = reader.streams()[name]
    run = AnalysisRun(stream=name, rig=rig.name)

    def emit(topic: str, obj: Mapping[str, Any]) -> None:  # kept as the log keeps it: the record's JSON
        run.results.setdefault(topic, []).append(records.encode(obj))

    try:
        op = AnalysisOperator(model, tuple(info.channels), info.sample_rate, settings, emit, pipelined=pipelined)
    except ValueError as exc:
        raise AnalyzeError(f"{path}: {exc}") from None
    # blocks are decoded as they are read (bounded memory, daq/replay.py); progress counts blocks from the index
    total = max(1, reader.message_count(info.topic))
    done = 0

    def counted() -> Iterator[SampleBlock]:
        nonlocal done
        for b in iter_log_blocks(reader, [name], bad=run.bad_blocks):
            done += 1
            yield b

    t0 = time.perf_counter()
    last = t0
    per = replay_chunk(info.sample_rate, len(info.channels)) if chunk_s is None else max(1, round(chunk_s * info.sample_rate))
    blocks = coalesce(counted(), per)
    try:
        while True:
            try:
                blk = next(blocks)
            except StopIteration:
                break
            except LogReadError as exc:
                raise AnalyzeError(f"{exc}; 'gvt log recover {path} fixed.mcap' rewrites what is readable") from None
            op.feed(blk)
            run.seconds_of_data += blk.n_samples / info.sample_rate
            now = time.perf_counter()
            if progress is not None and now - last > 0.5:
                progress(min(1.0, done / total))
                last = now
        op.finish()
    finally:
        op.close()  # the pipelined operator's worker thread, also when the log breaks off
    run.wall_seconds = time.perf_counter() - t0
    return run
