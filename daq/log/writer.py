"""The session log writer: one dedicated thread per MCAP file, fed by a bounded queue.

Why a thread of its own: the ``mcap`` writer keeps the open chunk in memory, compresses it on the
calling thread and never fsyncs (dependency-notes.md §2). Producers (drivers, the session, analysis)
call ``write_*`` which only enqueue; this thread owns the file.

Crash safety: every ``flush_interval`` seconds (0.5 s default) the thread closes the open chunk
(``Writer.flush()``), flushes and ``fsync``s, so a SIGKILL loses at most the open chunk plus what is
still queued — about one second at the configured rate when the queue holds about 0.5 s.

No silent loss: ``write_block`` never blocks; when the queue is full the block is not recorded, its
exact sample range is remembered, and the thread writes an ``overrun`` event to ``/daq/events`` as
soon as it can. Control records (streams, metadata, attachments, events) wait for queue space, with
a timeout that raises rather than hangs.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from analysis.errors import RuntimeFailure
from daq.log import layout
from daq.log.proto import SCHEMA_NAME, encode_block, sample_block_descriptor_set
from drivers.blocks import SampleBlock

EVENT_SCHEMA = {
    "type": "object",
    "title": "gvtlink.Event",
    "properties": {
        "kind": {"type": "string"},
        "stream": {"type": "string"},
        "start_index": {"type": "integer"},
        "end_index": {"type": "integer"},
        "count": {"type": "integer"},
        "message": {"type": "string"},
    },
    "required": ["kind"],
}
HIT_SCHEMA = {"type": "object", "title": "gvtlink.Hit", "properties": {"index": {"type": "integer"}}}


class LogWriterError(RuntimeFailure):
    """The writer thread failed (e.g. disk full); the message says why. Raised to producers."""


@dataclass
class WriterStats:
    blocks_written: int = 0
    samples_written: int = 0
    messages_written: int = 0
    overrun_blocks: int = 0
    overrun_samples: int = 0
    flushes: int = 0
    files: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ChannelInfo:
    """Calibration of one channel (SEP005-like): what the numbers in the log mean."""

    name: str
    quantity: str
    unit: str
    sensitivity_mv_per_unit: float | None = None
    position_m: float | None = None
    model_dof: str | None = None
    sensor_model: str | None = None


_STOP = object()


class LogWriter:
    """Write a session log. Use as a context manager; ``close()`` finalises the file."""

    def __init__(
        self,
        path: str | Path,
        *,
        queue_size: int = 64,
        chunk_size: int = 4 * 1024 * 1024,
        flush_interval: float = 0.5,
        fsync: bool = True,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        session_metadata: Mapping[str, str] | None = None,
        control_timeout: float = 10.0,
    ) -> None:
        self.path = Path(path)
        self._queue: queue.Queue = queue.Queue(maxsize=max(2, queue_size))
        self._chunk_size = chunk_size
        self._flush_interval = flush_interval
        self._fsync = fsync
        self._rotate_bytes = rotate_bytes
        self._rotate_seconds = rotate_seconds
        self._control_timeout = control_timeout
        self._session_meta = {
            "format_version": layout.FORMAT_VERSION,
            "software": "gvtlink",
            "software_version": _version(),
            "created_unix_ns": str(time.time_ns()),
            **dict(session_metadata or {}),
        }
        self.stats = WriterStats()
        self._overruns: list[tuple[str, int, int]] = []
        self._overrun_lock = threading.Lock()
        self._error: BaseException | None = None
        self._streams: dict[str, dict[str, Any]] = {}  # registered in the thread, replayed on rotation
        self._attachments: list[tuple[str, bytes, str]] = []
        self._metadata: list[tuple[str, dict[str, str]]] = []
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"mcap-writer:{self.path.name}", daemon=True)
        self._thread.start()

    # --- producer side -----------------------------------------------------------------------
    @property
    def queue_depth(self) -> int:
        """Items waiting for the writer thread now (for live status and benchmarks)."""
        return self._queue.qsize()

    @property
    def queue_size(self) -> int:
        return self._queue.maxsize

    def add_stream(self, stream: str, channels: Sequence[ChannelInfo], sample_rate: float, t0_ns: int | None = None) -> None:
        spec = {
            "stream": stream,
            "channels": [c.__dict__ for c in channels],
            "sample_rate": float(sample_rate),
            "t0_ns": int(time.time_ns() if t0_ns is None else t0_ns),
        }
        self._control(("stream", spec))

    def write_block(self, block: SampleBlock, wait: bool = False) -> bool:
        """Queue a block; False if the queue was full (the range is logged as an overrun event).

        Live producers never wait. Offline producers (simulation, replay into a new log, recovery)
        pass ``wait=True`` and get back-pressure instead: they wait for space, up to the control
        timeout, and only then count an overrun.
        """
        self._raise_if_failed()
        try:
            if wait:
                self._queue.put(("block", block), timeout=self._control_timeout)
            else:
                self._queue.put_nowait(("block", block))
            return True
        except queue.Full:
            with self._overrun_lock:
                self._overruns.append((block.stream, block.first_index, block.end_index))
                self.stats.overrun_blocks += 1
                self.stats.overrun_samples += block.n_samples
            return False

    def write_event(self, kind: str, **fields: Any) -> None:
        self._control(("json", layout.EVENTS_TOPIC, {"kind": kind, **fields}))

    def write_hit(self, hit: Mapping[str, Any]) -> None:
        self._control(("json", layout.HITS_TOPIC, dict(hit)))

    def write_json(self, topic: str, obj: Mapping[str, Any], log_time_ns: int | None = None) -> None:
        self._control(("json", topic, dict(obj), log_time_ns))

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._control(("meta", name, {str(k): str(v) for k, v in data.items()}))

    def add_attachment(self, name: str, data: bytes, media_type: str = "application/octet-stream") -> None:
        self._control(("attach", name, bytes(data), media_type))

    def close(self) -> WriterStats:
        """Finish the file (summary, indexes, footer); re-raises a writer-thread failure."""
        if not self._closed:
            self._closed = True
            self._queue.put(_STOP)
            self._thread.join()
        self._raise_if_failed()
        return self.stats

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _control(self, item: tuple) -> None:
        self._raise_if_failed()
        if self._closed:
            raise LogWriterError(f"{self.path}: writer is closed")
        try:
            self._queue.put(item, timeout=self._control_timeout)
        except queue.Full:
            raise LogWriterError(f"{self.path}: writer thread stalled for {self._control_timeout} s") from None

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise LogWriterError(f"{self.path}: log writer failed: {self._error}") from self._error

    # --- writer thread -----------------------------------------------------------------------
    def _open(self, path: Path) -> None:
        self._file = open(path, "wb")
        self._mcap = Writer(self._file, chunk_size=self._chunk_size, compression=CompressionType.ZSTD)
        self._mcap.start(profile=layout.PROFILE, library=f"gvtlink {_version()}")
        self._file_started = time.monotonic()
        self._channel_ids: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._block_schema = self._mcap.register_schema(SCHEMA_NAME, "protobuf", sample_block_descriptor_set())
        self._json_schemas: dict[str, int] = {}
        self._mcap.add_metadata(layout.META_SESSION, self._session_meta)
        for spec in self._streams.values():
            self._register_stream(spec)
        for name, data in self._metadata:
            self._mcap.add_metadata(name, data)
        for name, data, media in self._attachments:
            self._attach(name, data, media)
        self.stats.files.append(str(path))

    def _rotated_path(self) -> Path:
        n = len(self.stats.files)
        return self.path.with_name(f"{self.path.stem}-{n:04d}{self.path.suffix}")

    def _register_stream(self, spec: dict[str, Any]) -> None:
        topic = layout.samples_topic(spec["stream"])
        meta = {
            "stream": spec["stream"],
            "sample_rate": repr(spec["sample_rate"]),
            "t0_ns": str(spec["t0_ns"]),
            "channels": json.dumps([c["name"] for c in spec["channels"]]),
            "units": json.dumps([c["unit"] for c in spec["channels"]]),
        }
        self._channel_ids[topic] = self._mcap.register_channel(topic, "protobuf", self._block_schema, meta)
        self._mcap.add_metadata(
            layout.META_CALIBRATION.format(stream=spec["stream"]),
            {"sample_rate": repr(spec["sample_rate"]), "t0_ns": str(spec["t0_ns"]), "channels": json.dumps(spec["channels"])},
        )

    def _json_channel(self, topic: str) -> int:
        if topic not in self._channel_ids:
            schema = (
                EVENT_SCHEMA if topic == layout.EVENTS_TOPIC else HIT_SCHEMA if topic == layout.HITS_TOPIC else {"type": "object"}
            )
            title = schema.get("title", topic)
            if title not in self._json_schemas:
                self._json_schemas[title] = self._mcap.register_schema(title, "jsonschema", json.dumps(schema).encode())
            self._channel_ids[topic] = self._mcap.register_channel(topic, "json", self._json_schemas[title])
        return self._channel_ids[topic]

    def _attach(self, name: str, data: bytes, media: str) -> None:
        now = time.time_ns()
        self._mcap.add_attachment(create_time=now, log_time=now, name=name, media_type=media, data=data)

    def _message(self, channel_id: int, log_time: int, data: bytes) -> None:
        seq = self._seq.get(channel_id, 0)
        self._seq[channel_id] = seq + 1
        self._mcap.add_message(channel_id, log_time=log_time, data=data, publish_time=time.time_ns(), sequence=seq)
        self.stats.messages_written += 1

    def _handle(self, item: tuple) -> None:
        kind = item[0]
        if kind == "block":
            b: SampleBlock = item[1]
            spec = self._streams.get(b.stream)
            if spec is None:
                raise LogWriterError(f"block for unregistered stream {b.stream!r}; call add_stream first")
            t0 = spec["t0_ns"]
            log_time = t0 + round(b.first_index * 1e9 / b.sample_rate)
            raw = encode_block(b.stream, b.first_index, b.sample_rate, b.data, int(b.status), t0)
            self._message(self._channel_ids[layout.samples_topic(b.stream)], log_time, raw)
            self.stats.blocks_written += 1
            self.stats.samples_written += b.n_samples
        elif kind == "json":
            topic, obj = item[1], item[2]
            log_time = item[3] if len(item) > 3 and item[3] is not None else time.time_ns()
            self._message(self._json_channel(topic), log_time, json.dumps(obj, separators=(",", ":")).encode())
        elif kind == "stream":
            spec = item[1]
            self._streams[spec["stream"]] = spec
            self._register_stream(spec)
        elif kind == "meta":
            self._metadata.append((item[1], item[2]))
            self._mcap.add_metadata(item[1], item[2])
        elif kind == "attach":
            self._attachments.append((item[1], item[2], item[3]))
            self._attach(item[1], item[2], item[3])

    def _emit_overruns(self) -> None:
        with self._overrun_lock:
            pending, self._overruns = self._overruns, []
        for stream, start, end in _merge(pending):
            obj = {
                "kind": "overrun",
                "stream": stream,
                "start_index": start,
                "end_index": end,
                "count": end - start,
                "message": "log writer queue full: these samples were not recorded",
            }
            self._message(self._json_channel(layout.EVENTS_TOPIC), time.time_ns(), json.dumps(obj).encode())

    def _sync(self) -> None:
        self._mcap.flush()  # closes the open chunk and writes it out
        if self._fsync:
            os.fsync(self._file.fileno())
        self.stats.flushes += 1

    def _finish(self) -> None:
        self._emit_overruns()
        self._mcap.finish()
        self._file.flush()
        if self._fsync:
            os.fsync(self._file.fileno())
        self._file.close()

    def _run(self) -> None:
        try:
            self._open(self.path)
            next_flush = time.monotonic() + self._flush_interval
            while True:
                timeout = max(0.0, next_flush - time.monotonic())
                try:
                    item = self._queue.get(timeout=timeout)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    break
                if item is not None:
                    self._handle(item)
                if self._overruns:
                    self._emit_overruns()
                now = time.monotonic()
                if now >= next_flush:
                    self._sync()
                    next_flush = now + self._flush_interval
                    if self._should_rotate(now):
                        self._finish()
                        self._open(self._rotated_path())
            self._finish()
        except BaseException as exc:  # reported to producers on their next call and on close()
            self._error = exc
            try:
                self._file.close()
            except Exception:
                pass
            # Keep draining so producers never block on a dead writer; count what is lost.
            while True:
                try:
                    item = self._queue.get(timeout=0.1)
                except queue.Empty:
                    if self._closed:
                        return
                    continue
                if item is _STOP:
                    return

    def _should_rotate(self, now: float) -> bool:
        if self._rotate_seconds is not None and now - self._file_started >= self._rotate_seconds:
            return True
        return self._rotate_bytes is not None and self._file.tell() >= self._rotate_bytes


def _merge(ranges: list[tuple[str, int, int]]) -> list[tuple[str, int, int]]:
    out: list[tuple[str, int, int]] = []
    for stream, a, b in sorted(ranges):
        if out and out[-1][0] == stream and out[-1][2] >= a:
            out[-1] = (stream, out[-1][1], max(out[-1][2], b))
        else:
            out.append((stream, a, b))
    return out


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gvtlink")
    except Exception:
        return "0+unknown"
