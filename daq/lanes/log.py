"""The log lane: the session's MCAP file, the recording path every other lane stands beside.

It owns the :class:`~daq.log.writer.LogWriter` (and so the writer thread and the file's lock). Sources
hand it every block *before* the fan-out (:meth:`LogLane.write_block`, never blocking for a live device);
results arrive through :meth:`LogLane.sink` (the :class:`~daq.lanes.Results` router's log). A writer that
fails (disk full, the file deleted, an I/O error) is reported once through :attr:`LogLane.failure`; the
recorder then stops the session, and everything already written is finalised by :meth:`finish`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from daq.log import layout
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock


class LogLane:
    name = "log"

    def __init__(
        self, path: str | Path, *, queue_size: int, rotate_bytes: int | None = None, rotate_seconds: float | None = None,
        metadata: Mapping[str, str] | None = None, overwrite: bool = False,
    ) -> None:  # fmt: skip
        self.path = Path(path)
        self.writer = LogWriter(
            self.path, queue_size=queue_size, rotate_bytes=rotate_bytes, rotate_seconds=rotate_seconds,
            session_metadata=metadata, overwrite=overwrite,
        )  # fmt: skip
        self.dropped_results = 0

    # --- set-up (before the sources start) ------------------------------------------------------------
    def add_stream(self, stream: str, channels: Sequence[ChannelInfo], sample_rate: float, t0_ns: int = 0) -> None:
        self.writer.add_stream(stream, channels, sample_rate, t0_ns=t0_ns)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        if self.failure is None:
            self.writer.add_metadata(name, data)

    def add_attachment(self, name: str, data: bytes, media_type: str) -> None:
        self.writer.add_attachment(name, data, media_type)

    # --- the recording path ------------------------------------------------------------------------
    def write_block(self, block: SampleBlock, wait: bool = False) -> None:
        """Queue a block for the file (first, before any other lane sees it); never raises into a reading thread."""
        self.writer.write_block(block, wait=wait)

    def sink(self, topic: str, obj: Mapping[str, Any], log_time_ns: int | None) -> None:
        """Results to the file: ``/daq/events`` and ``/daq/hits`` by their typed writers, the rest as JSON."""
        if self.failure is not None:
            self.dropped_results += 1
            return
        if topic == layout.EVENTS_TOPIC:
            self.writer.write_event(obj["kind"], **{k: v for k, v in obj.items() if k != "kind"})
        elif topic == layout.HITS_TOPIC:
            self.writer.write_hit(obj)
        else:
            self.writer.write_json(topic, obj, log_time_ns=log_time_ns)

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

    def offer(self, topic: str, obj: dict) -> None:  # the log takes results through sink(), first of all
        pass

    def finish(self, deadline: float) -> None:
        """Finalise the file (summary, indexes, footer); after a failure the writer has finalised what it could."""
        self.writer.close()
