"""The log lane: the session's MCAP file, the recording path every other lane stands beside.

It owns the :class:`~daq.log.writer.LogWriter` (and so the writer thread and the file's lock). Sources
hand it every block *before* the fan-out (:meth:`LogLane.write_block`, never blocking for a live device);
results arrive through :meth:`LogLane.sink` (the :class:`~daq.lanes.Results` router's log). A writer that
fails (disk full, the file deleted, an I/O error) is reported once through :attr:`LogLane.failure`; the
recorder then stops the session, and everything already written is finalised by :meth:`finish`.

The writer's buffer is a memory budget (``buffer_bytes``, the session's ``writer_buffer_mib``, D67): a stall's
burst or a busy host waits in memory and only an exhausted budget loses blocks (counted, ``overrun``).
:meth:`backlog` says how far the writer is behind, now and at its peak; a SIGKILL loses that plus one flush
interval, and a peak above :data:`~daq.log.writer.BACKLOG_NOTE_S` is a ``writer_backlog`` event in the log.

The time base (docs/log-format.md, "Time base"): the lane tells the writer the session's origin — the host's
UTC at the reference stream's sample 0, taken once from its first block — and each stream's offset on the
reference's timeline (0 for the reference's device; a second device's when the timeline fixes it).
Results are timed relative to the origin; ``/analysis/*`` on the analysed stream's own clock (``clock``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from daq.log import layout
from daq.log.writer import BACKLOG_NOTE_S, ChannelInfo, LogWriter, wall_at_sample0
from drivers.blocks import SampleBlock


class LogLane:
    name = "log"

    def __init__(
        self, path: str | Path, *, buffer_bytes: int = 256 << 20, queue_size: int | None = None,
        rotate_bytes: int | None = None, rotate_seconds: float | None = None,
        metadata: Mapping[str, str] | None = None, overwrite: bool = False, max_hold_s: float = 5.0,
        preview: bool = True,
    ) -> None:  # fmt: skip
        self.path = Path(path)
        self.writer = LogWriter(
            self.path, queue_size=queue_size, buffer_bytes=buffer_bytes, rotate_bytes=rotate_bytes,
            rotate_seconds=rotate_seconds, session_metadata=metadata, overwrite=overwrite, origin_ns=None,
            max_hold_s=max_hold_s, note_backlog_s=BACKLOG_NOTE_S, preview=preview,
        )  # fmt: skip
        self.dropped_results = 0
        self.reference: set[str] = set()  # streams on the reference's clock: the first block of one sets the origin
        self.clocks: dict[str, str] = {}  # topic prefix -> the stream whose own clock its results' times are on
        self._rates: dict[str, float] = {}
        self._origin_set = False

    # --- set-up (before the sources start) ------------------------------------------------------------
    def add_stream(
        self, stream: str, channels: Sequence[ChannelInfo], sample_rate: float, *, reference: bool = True,
        offset_s: float | None = 0.0, method: str = "reference",
    ) -> None:  # fmt: skip
        """``reference``: on the reference device's clock (offset 0; its first block sets the origin). Else
        ``offset_s`` (configured, rounded to whole samples as the aligner does) or None: set by :meth:`set_offset`."""
        self._rates[stream] = float(sample_rate)
        if reference:
            self.reference.add(stream)
            offset_s, method = 0.0, "reference"
        off = None if offset_s is None else round(round(offset_s * sample_rate) * 1e9 / sample_rate)
        self.writer.add_stream(stream, channels, sample_rate, offset_ns=off, offset_method=method)

    def set_offset(self, stream: str, offset_samples: int, method: str) -> None:
        """The timeline fixed ``stream``'s offset (whole samples on the reference's index); its ``.poll`` stream,
        on the same device clock, follows. Called from the hit-gate lane's thread; never blocks."""
        for s in (stream, f"{stream}.poll"):
            if s in self._rates:
                fs = self._rates[stream]
                self.writer.set_offset(s, round(offset_samples * 1e9 / fs), method)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        if self.failure is None:
            self.writer.add_metadata(name, data)

    def add_attachment(self, name: str, data: bytes, media_type: str) -> None:
        self.writer.add_attachment(name, data, media_type)

    # --- the recording path ------------------------------------------------------------------------
    def write_block(self, block: SampleBlock, wait: bool = False) -> None:
        """Queue a block for the file (first, before any other lane sees it); never raises into a reading thread.
        The reference's first block sets the session's origin (before it is queued: it is never held)."""
        if not self._origin_set and block.stream in self.reference:
            self._origin_set = True
            origin = wall_at_sample0(block)  # None without an arrival time: then it arrived now
            if origin is None:
                origin = time.time_ns() - round(block.end_index * 1e9 / block.sample_rate)
            self.writer.set_origin(origin, f"host clock at {block.stream} sample 0")
        self.writer.write_block(block, wait=wait)

    def sink(self, topic: str, obj: Mapping[str, Any], log_time_ns: int | None) -> None:
        """Results to the file: ``/daq/events`` and ``/daq/hits`` by their typed writers, the rest as JSON."""
        if self.failure is not None:
            self.dropped_results += 1
            return
        if topic == layout.EVENTS_TOPIC:
            fields = {k: v for k, v in obj.items() if k not in ("kind", "log_time_ns")}
            self.writer.write_event(obj["kind"], log_time_ns=log_time_ns, **fields)
        elif topic == layout.HITS_TOPIC:
            self.writer.write_hit(obj, log_time_ns=log_time_ns)
        else:
            clock = next((s for prefix, s in self.clocks.items() if topic.startswith(prefix)), None)
            self.writer.write_json(topic, obj, log_time_ns=log_time_ns, clock=clock)

    def sink_encoded(self, batch: Sequence[tuple[str, bytes, int | None]]) -> None:
        """Records already JSON-encoded (the lane worker's, ``daq/lanes/host.py``), as ``(topic, bytes, log_time_ns)``:
        written as :meth:`sink` writes them (the same bytes, the same times), queued as one item."""
        if self.failure is not None:
            self.dropped_results += len(batch)
            return
        clocks = self.clocks.items()
        self.writer.write_json_encoded(
            [(topic, raw, t, next((s for prefix, s in clocks if topic.startswith(prefix)), None)) for topic, raw, t in batch]
        )

    # --- state ---------------------------------------------------------------------------------------
    @property
    def failure(self) -> str | None:
        """One line saying why the writer stopped writing (None while it works)."""
        return self.writer.failure

    @property
    def failure_exit_code(self) -> int:
        return self.writer.failure_exit_code or 1

    @property
    def stats(self):
        return self.writer.stats

    def backlog(self) -> dict[str, float]:
        """Blocks waiting for the writer: ``bytes``, ``seconds`` of data, and their peaks (``LogWriter.backlog``)."""
        return self.writer.backlog()

    def offer(self, topic: str, obj: dict) -> None:  # the log takes results through sink(), first of all
        pass

    def finish(self, deadline: float) -> None:
        """Finalise the file (summary, indexes, footer); after a failure the writer has finalised what it could."""
        self.writer.close()
