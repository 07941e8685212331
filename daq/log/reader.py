"""Read session logs: a verified indexed path to numpy, and a tolerant linear scan for broken files.

Every byte of sample data that leaves this module was checked (docs/log-format.md, "Reading"; the
record-level checks are in ``daq/log/verify.py``, the metadata seal in ``daq/log/seal.py``):

* the footer's ``summary_crc`` before the summary is trusted (a bad one: the file is read as damaged);
* each chunk's ``uncompressed_crc`` (mcap's ``iter_messages`` does not check it: a bit flip was served as
  data), after decompressing against the chunk's *declared* size, capped at :data:`MAX_CHUNK_BYTES` (a
  zstd frame that expands to gigabytes is damage, not an allocation);
* each sample block for plausibility (:func:`block_problem`): it decodes, has the stream's channels and
  rate, finite values, and the ``first_index`` its ``log_time`` says — so a log without chunk CRCs (mcap
  allows compression "" and CRC 0) does not pass garbage on either;
* attachments against their record CRC and :data:`MAX_ATTACHMENT_BYTES`.

A chunk or block that fails is *damage*: it is skipped, remembered (:class:`Damage`, with the log times of
the messages it held, from the chunk's message indexes) and turned into exact sample ranges per stream by
the readers (``read_stream``'s ``damaged``, ``iter_blocks``). ``open_log`` falls back to a linear scan when
the footer or summary is missing or broken; nothing here raises on a damaged file except
:class:`LogReadError` (BadInput, exit 2) and :class:`LogDamagedError` (DataLost, exit 3), one line each.
"""

from __future__ import annotations

import heapq
import io
import json
import os
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import (
    Attachment,
    Channel,
    ChunkIndex,
    Message,
    Metadata,
    Schema,
)
from mcap.summary import Summary

from analysis.errors import BadInput, DataLost
from daq.log import layout
from daq.log.proto import BlockDecodeError, DecodedBlock, decode_block
from daq.log.seal import unseal
from daq.log.verify import (  # noqa: F401  (read_summary, chunk_payload, MAX_*: part of this module's API)
    _EXPECTED_ERRORS,
    _OP_ATTACHMENT,
    _OP_CHANNEL,
    _OP_CHUNK,
    _OP_DATA_END,
    _OP_FOOTER,
    _OP_MESSAGE,
    _OP_MESSAGE_INDEX,
    _OP_METADATA,
    _OP_SCHEMA,
    MAGIC,
    MAX_ATTACHMENT_BYTES,
    MAX_CHUNK_BYTES,
    MAX_RECORD_BYTES,
    MAX_SUMMARY_BYTES,
    _attachment,
    _Damaged,
    _describe,
    _message_index_times,
    _reason,
    _u64,
    chunk_payload,
    chunk_records,
    parse_chunk,
    read_summary,
)

#: samples in one block (the drivers use 64..8192)
MAX_BLOCK_SAMPLES = 1 << 20
#: a block's first_index may differ from what its log time says by this much (s) before it is absurd: the writer
#: logs it exactly, but logs assembled otherwise (tests reorder blocks by seconds) are still read
MAX_INDEX_DRIFT_S = 3600.0
#: |value| beyond this is not a measurement in SI units (a flipped float32 exponent gives 1e19..1e38)
MAX_ABS_VALUE = 1e30


#: The lowest stream rate a log may claim (Hz): a sample every ~17 min, below any polled stream a device serves
#: (a Modbus ``poll_hz`` of a slow temperature) and far below the configs' 1 Hz for acquisition. A 1e-300 Hz stream
#: used to reach replay and divide by zero there (issue 30).
MIN_STREAM_RATE = 1e-3


def _header_profile(f: BinaryIO) -> str | None:
    """The profile string of the MCAP header record that follows the magic (opcode 0x01, u64 length, then the
    profile as u32 length + UTF-8); None when the first record is not a header."""
    head = f.read(13)
    if len(head) < 13 or head[0] != 0x01:
        return None
    n = int.from_bytes(head[9:13], "little")
    return f.read(n).decode("utf-8", "replace") if n <= 256 else None


class LogReadError(BadInput):
    """The file cannot be read as a gvtlink log; ``str()`` is one line for the user."""


class LogDamagedError(LogReadError, DataLost):
    """Part of the log is damaged and the reader was asked not to skip it (one line naming ``gvt log recover``);
    a LogReadError too, so every caller that handles a bad log handles it, but data was lost: exit 3."""

    exit_code = 3


@dataclass
class Damage:
    """One damaged chunk (or implausible block): where, why, and the log times of the messages it held per
    channel id (from its message indexes; None when those are unreadable too)."""

    offset: int
    reason: str
    start_ns: int
    end_ns: int
    lost: dict[int, list[int]] | None = None


@dataclass
class SalvageReport:
    """What a read of the file found. ``complete`` means footer and summary were intact."""

    complete: bool
    messages: int = 0
    chunks_ok: int = 0
    chunks_bad: int = 0
    bytes_scanned: int = 0
    file_size: int = 0
    stopped_because: str | None = None
    expected_messages: int | None = None  # from the summary, when there is one
    summary_problem: str | None = None  # why the summary was not used (a cut, a CRC mismatch)
    duplicates: int = 0  # messages seen twice (a duplicated chunk) and kept once
    #: messages whose per-channel sequence numbers are missing between the first and last seen (``recover``):
    #: a chunk cut out of the middle of a file leaves no other trace once the summary no longer matches
    missing_by_sequence: int = 0

    @property
    def data_lost(self) -> bool:
        if self.chunks_bad or self.missing_by_sequence:
            return True
        if self.expected_messages is not None:
            return self.messages < self.expected_messages
        return not self.complete and self.stopped_because is not None


@dataclass
class StreamInfo:
    stream: str
    topic: str
    sample_rate: float
    t0_ns: int
    channels: list[str]
    units: list[str]

    def index_at(self, log_time: int) -> int:
        """The sample index whose time is ``log_time`` (the inverse of the writer's log_time rule)."""
        return round((log_time - self.t0_ns) * self.sample_rate / 1e9)


@dataclass
class StreamData:
    """Samples of one stream in index order; ``index`` are device sample indices (int64)."""

    info: StreamInfo
    channels: list[str]
    index: np.ndarray
    data: np.ndarray  # float32 (n, n_channels)
    block_first_index: np.ndarray
    block_status: np.ndarray
    gaps: list[tuple[int, int]] = field(default_factory=list)  # [start, end) missing sample ranges
    damaged: list[tuple[int, int, str]] = field(default_factory=list)  # [start, end) skipped as damage, and why

    @property
    def t(self) -> np.ndarray:
        """Seconds since the stream's t0."""
        return self.index / self.info.sample_rate


def block_problem(b: DecodedBlock, info: StreamInfo, log_time: int) -> str | None:
    """Why a decoded block is not data of ``info`` (None: it is). A chunk CRC guards the bytes; this guards a
    log without CRCs and a writer's garbage: shape, rate, the first_index its log time says, finite values."""
    n, c = b.data.shape
    if c != len(info.channels):
        return f"{c} channels in a {len(info.channels)}-channel stream"
    if not 0 < n <= MAX_BLOCK_SAMPLES:
        return f"{n} samples in a block"
    if b.sample_rate != info.sample_rate:
        return f"rate {b.sample_rate:g} Hz in a {info.sample_rate:g} Hz stream"
    if abs(b.first_index - info.index_at(log_time)) > MAX_INDEX_DRIFT_S * info.sample_rate:
        return f"first_index {b.first_index} but its log time says {info.index_at(log_time)}"
    lo, hi = float(b.data.min()), float(b.data.max())  # two passes at memory speed; NaN propagates
    if lo != lo or hi != hi:
        return "NaN values"
    if not (-MAX_ABS_VALUE <= lo and hi <= MAX_ABS_VALUE):  # rare: ±inf is a value (a clipped ADC), 1e38 is not
        a = np.abs(b.data)
        if ((a > MAX_ABS_VALUE) & np.isfinite(a)).any():
            return f"values beyond ±{MAX_ABS_VALUE:g}"
    return None


@dataclass
class _ScanState:
    """What the linear scan carries from record to record: the damage still open (a failed chunk waits for its
    message indexes), whether DataEnd was seen, and the messages seen (a duplicated chunk's are dropped)."""

    pending: Damage | None = None
    data_end: bool = False
    seen: set[tuple[int, int, int, int]] = field(default_factory=set)


def _note_lost_times(d: Damage, body: bytes) -> None:
    """Add a message index's log times (one channel's) to the damage of the chunk it indexes."""
    try:
        cid, n = struct.unpack_from("<HI", body, 0)
        times = [t for t, _o in struct.iter_unpack("<QQ", body[6 : 6 + n])]
        d.lost = {**(d.lost or {}), cid: times}
    except struct.error:
        pass


class LogReader:
    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise LogReadError(f"{self.path}: is a directory; give a log file (.mcap) inside it")
        try:
            self.file_size = os.path.getsize(self.path)
        except FileNotFoundError:
            raise LogReadError(f"{self.path}: file not found") from None
        except OSError as exc:
            raise LogReadError(f"{self.path}: cannot read: {exc.strerror}") from None
        if self.file_size == 0:
            raise LogReadError(f"{self.path}: empty file, not an MCAP log")
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise LogReadError(f"{self.path}: cannot read: {exc.strerror}") from None
        with f:
            if f.read(8) != MAGIC:
                raise LogReadError(f"{self.path}: not an MCAP file (bad magic bytes)")
            #: the MCAP header's profile ("gvtlink" in every log this project writes; None when unreadable)
            self.profile = _header_profile(f)
            try:
                self.summary: Summary | None = read_summary(f, self.file_size)
                problem = None
            except _EXPECTED_ERRORS as exc:
                self.summary, problem = None, _describe(exc)
        self._indexed = self.summary is not None
        #: damaged chunks and implausible blocks met so far, by file offset (a block: its chunk's, plus its log time)
        self.damage: dict[tuple[int, int], Damage] = {}
        self.problems: list[str] = []  # attachments or metadata records that failed their checks
        self.report = SalvageReport(complete=self._indexed, file_size=self.file_size, summary_problem=problem)
        self._scan_cache: dict[str, Any] | None = None
        if self.summary is not None:
            self.report.expected_messages = int(self.summary.statistics.message_count)
            self.report.messages = self.report.expected_messages
            self.report.chunks_ok = len(self.summary.chunk_indexes)
            self.report.bytes_scanned = self.file_size
        else:
            self._scan()

    @property
    def indexed(self) -> bool:
        return self._indexed

    def require_log(self) -> None:
        """One line (:class:`LogReadError`, exit 2) for an MCAP file that is not a gvtlink log: another
        profile and no sample stream. ``info``, ``replay`` and ``report`` used to describe such a file as an
        empty session and exit 0 (issue 30). A gvtlink log without streams (a recorder that stopped before
        the first block) is still a log."""
        if self.profile == layout.PROFILE or self.streams():
            return
        if self.profile is None and not self.channels():  # the magic, then no header: a log cut at its start
            raise LogReadError(f"{self.path}: damaged: no MCAP header record after the magic "
                               f"({self.path.stat().st_size} bytes); nothing in it can be read")  # fmt: skip
        topics = sorted({c.topic for c in self.channels()})
        shown = ", ".join(topics[:3]) + (", …" if len(topics) > 3 else "") if topics else "no channels"
        raise LogReadError(
            f"{self.path}: an MCAP file but not a gvtlink session log (profile {self.profile!r}, no sample streams; "
            f"{shown}); give a log written by gvt record or gvt simulate"
        )

    # --- verified indexed path ------------------------------------------------------------------
    def _chunk(self, f: BinaryIO, ci: ChunkIndex, views: bool = False) -> list[Schema | Channel | Message]:
        """One indexed chunk's records, its header matched against its index, decompressed (capped), CRC-checked;
        ``views``: messages' data as views of the chunk (:func:`chunk_records`)."""
        if ci.chunk_length > MAX_RECORD_BYTES:
            raise _Damaged(f"chunk of {ci.chunk_length} bytes, over the {MAX_RECORD_BYTES >> 20} MB limit")
        f.seek(ci.chunk_start_offset)
        raw = f.read(ci.chunk_length)
        if len(raw) != ci.chunk_length or raw[0] != _OP_CHUNK or _u64(raw, 1) != ci.chunk_length - 9:
            raise _Damaged("no chunk record where the index says")
        chunk = parse_chunk(memoryview(raw)[9:])
        if (chunk.uncompressed_size, len(chunk.data), chunk.compression) != (
            ci.uncompressed_size, ci.compressed_size, ci.compression,
        ):  # fmt: skip
            raise _Damaged("chunk header disagrees with its index")
        return chunk_records(chunk_payload(chunk), views)

    def _chunk_plan(self, cids: set[int] | None, start_ns: int | None, end_ns: int | None, time_order: bool) -> list[ChunkIndex]:
        """The chunks the index says hold messages of ``cids`` (None: all) in the time range, each once, in the
        order they are read: by start time (``time_order``) or by offset."""
        assert self.summary is not None
        plan, seen = [], set()
        for ci in self.summary.chunk_indexes:
            if ci.chunk_start_offset in seen:
                continue
            seen.add(ci.chunk_start_offset)
            if cids is not None and not cids & set(ci.message_index_offsets):
                continue
            if (start_ns is not None and ci.message_end_time < start_ns) or (
                end_ns is not None and ci.message_start_time >= end_ns
            ):
                continue
            plan.append(ci)
        plan.sort(
            key=(lambda c: (c.message_start_time, c.chunk_start_offset)) if time_order else (lambda c: c.chunk_start_offset)
        )
        return plan

    def _iter_indexed(
        self, cids: set[int] | None, start_ns: int | None, end_ns: int | None, time_order: bool, rep: SalvageReport,
        views: bool = False,
    ) -> Iterator[Message | Damage]:  # fmt: skip
        """Verified messages of the channels ``cids`` (None: all) from the chunks the index says hold them, in
        log-time order (a heap across overlapping chunks, one chunk decompressed at a time) or file order; a
        chunk that fails is yielded as a :class:`Damage` where it would have been read."""
        heap: list[tuple[int, int, Message]] = []
        n = 0
        with open(self.path, "rb") as f:
            for ci in self._chunk_plan(cids, start_ns, end_ns, time_order):
                while heap and heap[0][0] < ci.message_start_time:
                    yield heapq.heappop(heap)[2]
                try:
                    records = self._chunk(f, ci, views)
                except _EXPECTED_ERRORS as exc:
                    rep.chunks_bad += 1
                    d = Damage(ci.chunk_start_offset, _reason(exc), ci.message_start_time, ci.message_end_time,
                               _message_index_times(f, ci, self.file_size))  # fmt: skip
                    self.damage.setdefault((d.offset, -1), d)
                    yield d
                    continue
                rep.chunks_ok += 1
                for m in records:
                    if not isinstance(m, Message) or (cids is not None and m.channel_id not in cids):
                        continue
                    if (start_ns is not None and m.log_time < start_ns) or (end_ns is not None and m.log_time >= end_ns):
                        continue
                    rep.messages += 1
                    if time_order:
                        heapq.heappush(heap, (m.log_time, n, m))
                        n += 1
                    else:
                        yield m
        while heap:
            yield heapq.heappop(heap)[2]

    # --- tolerant path ---------------------------------------------------------------------------
    _KNOWN = frozenset({0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F})

    def _records(self, rep: SalvageReport) -> Iterator[Any]:
        """Every readable record in file order, a chunk's contents flattened in place of the chunk, reading one
        record at a time (memory: one chunk). A chunk that fails (CRC, decompression, caps) is yielded as a
        :class:`Damage` after its message indexes (the log times it held); a record whose header is garbage
        is skipped by searching for the next chunk that passes its CRC. Messages seen before (a duplicated
        chunk) are dropped and counted. Sets ``rep.stopped_because`` only when the data section was not read
        to its end (DataEnd): a cut in the summary loses nothing."""
        scan = _ScanState()
        with open(self.path, "rb") as f:
            for offset, op, body in self._file_records(f, rep, scan):
                if op == _OP_MESSAGE_INDEX and scan.pending is not None:
                    _note_lost_times(scan.pending, body)  # the damaged chunk's message indexes follow it
                    continue
                yield from self._release_pending(scan)
                yield from self._record_items(offset, op, body, rep, scan)
        yield from self._release_pending(scan)

    def _file_records(self, f: BinaryIO, rep: SalvageReport, scan: _ScanState) -> Iterator[tuple[int, int, bytes]]:
        """(offset, opcode, body) of each record from the magic to the footer. Garbage where a record header
        should be opens a damage (``scan.pending``) and the walk goes on at the next chunk that passes its CRC;
        a cut or an unreadable tail ends it, and why goes to ``rep.stopped_because`` unless DataEnd was seen."""
        pos = 8
        while True:
            f.seek(pos)
            head = f.read(9)
            if len(head) < 9:
                if not scan.data_end:
                    rep.stopped_because = "the file ends inside its data section" if head else "the file ends before its data end"
                break
            op, length = head[0], _u64(head, 1)
            rep.bytes_scanned = pos
            sane = op in self._KNOWN and length <= MAX_RECORD_BYTES
            if sane and pos + 9 + length > self.file_size:
                if not scan.data_end:
                    rep.stopped_because = "the file ends inside a record"
                break
            if not sane:
                nxt = self._skip_garbage(f, pos, rep, scan)
                if nxt is None:
                    break
                pos = nxt
                continue
            body = f.read(length)
            yield pos, op, body
            pos += 9 + length
            if op == _OP_FOOTER:
                break
        rep.bytes_scanned = min(pos, self.file_size)

    def _skip_garbage(self, f: BinaryIO, pos: int, rep: SalvageReport, scan: _ScanState) -> int | None:
        """Where the walk goes on after a garbled record header at ``pos`` (None: nowhere), counted as one damaged
        chunk (together with a failed chunk just before it) whose message times are unknown."""
        nxt = self._resync(f, pos + 1)
        if scan.pending is None:
            rep.chunks_bad += 1
            scan.pending = Damage(pos, "unreadable bytes", -1, -1, None)
        if nxt is None:
            rep.stopped_because = rep.stopped_because or f"unreadable bytes from {pos} on"
        return nxt

    def _release_pending(self, scan: _ScanState) -> Iterator[Damage]:
        """The open damage, once its message indexes (if any) have been read: remembered and yielded."""
        if scan.pending is not None:
            self.damage.setdefault((scan.pending.offset, -1), scan.pending)
            yield scan.pending
            scan.pending = None

    def _record_items(self, offset: int, op: int, body: bytes, rep: SalvageReport, scan: _ScanState) -> Iterator[Any]:
        """What one record of the data section gives a reader: a chunk's messages (or its damage, left open for
        its message indexes), a loose message, schema, channel, metadata or attachment; DataEnd is noted."""
        if op == _OP_CHUNK:
            yield from self._chunk_messages(offset, body, rep, scan)
        elif op == _OP_MESSAGE and len(body) >= 22:  # an unchunked log: no CRC; block_problem still checks
            cid, seq, lt, pt = struct.unpack_from("<HIQQ", body, 0)
            yield Message(channel_id=cid, log_time=lt, data=body[22:], publish_time=pt, sequence=seq)
        elif op == _OP_DATA_END:  # the data section is whole up to here
            scan.data_end = True
        elif op in (_OP_METADATA, _OP_ATTACHMENT, _OP_SCHEMA, _OP_CHANNEL):
            rec = self._loose_record(op, body)
            if rec is not None:
                yield rec

    def _chunk_messages(self, offset: int, body: bytes, rep: SalvageReport, scan: _ScanState) -> Iterator[Any]:
        """A chunk's records, verified, each message once (a duplicated chunk's are counted, not yielded); a chunk
        that fails becomes the open damage."""
        try:
            records = chunk_records(chunk_payload(parse_chunk(body)))
        except _EXPECTED_ERRORS as exc:
            rep.chunks_bad += 1
            scan.pending = Damage(offset, _reason(exc), -1, -1, None)
            return
        rep.chunks_ok += 1
        for r in records:
            if isinstance(r, Message):
                key = (r.channel_id, r.sequence, r.log_time, hash(r.data))
                if key in scan.seen:
                    rep.duplicates += 1
                    continue
                scan.seen.add(key)
            yield r

    def _loose_record(self, op: int, body: bytes) -> Any:
        """A schema, channel, metadata or attachment record outside a chunk; None (noted) when it is garbled."""
        try:
            if op == _OP_ATTACHMENT:
                return _attachment(body)
            s = ReadDataStream(io.BytesIO(body))
            return {_OP_METADATA: Metadata.read, _OP_SCHEMA: Schema.read, _OP_CHANNEL: Channel.read}[op](s)
        except (*_EXPECTED_ERRORS, UnicodeDecodeError) as exc:
            self.problems.append(f"a record of type {op:#x} is unreadable ({_reason(exc)})")
            return None

    def _resync(self, f: BinaryIO, pos: int) -> int | None:
        """The offset of the next chunk record at or after ``pos`` that passes its checks (None: none)."""
        window = 1 << 20
        while pos < self.file_size:
            f.seek(pos)
            buf = f.read(window + 64)
            at = buf.find(b"\x06")
            while 0 <= at < window:
                cand = pos + at
                if self._chunk_ok_at(f, cand):
                    return cand
                at = buf.find(b"\x06", at + 1)
            pos += window
        return None

    def _chunk_ok_at(self, f: BinaryIO, cand: int) -> bool:
        f.seek(cand)
        head = f.read(9 + 41)
        if len(head) < 50:
            return False
        length = _u64(head, 1)
        clen = struct.unpack_from("<I", head, 9 + 28)[0]
        if length > MAX_RECORD_BYTES or cand + 9 + length > self.file_size or clen > 8:
            return False
        f.seek(cand + 9)
        try:
            chunk_payload(parse_chunk(f.read(length)))
        except _EXPECTED_ERRORS:
            return False
        return True

    def _scan(self) -> dict[str, Any]:
        """Linear scan of everything readable; cached. Fills ``self.report``. Keeps schemas, channels,
        metadata, attachments and per-channel message counts — not the messages: a damaged log of an hour
        is gigabytes (``iter_messages`` scans again, a chunk at a time)."""
        if self._scan_cache is not None:
            return self._scan_cache
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        counts: dict[int, int] = {}
        metadata: list[Metadata] = []
        attachments: list[Attachment] = []
        rep = self.report
        for r in self._records(rep):
            if isinstance(r, Message):
                counts[r.channel_id] = counts.get(r.channel_id, 0) + 1
            elif isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
            elif isinstance(r, Metadata):
                metadata.append(r)
            elif isinstance(r, Attachment):
                attachments.append(r)
        rep.messages = sum(counts.values())
        self._scan_cache = {
            "schemas": schemas,
            "channels": channels,
            "counts": counts,
            "metadata": metadata,
            "attachments": attachments,
        }
        return self._scan_cache

    # --- common API --------------------------------------------------------------------------
    def schemas(self) -> dict[int, Schema]:
        """Schemas by id, from the summary or, in a damaged file, from what the scan salvaged."""
        if self.summary is not None:
            return dict(self.summary.schemas)
        return dict(self._scan()["schemas"])

    def channels(self) -> list[Channel]:
        if self.summary is not None:
            return list(self.summary.channels.values())
        return list(self._scan()["channels"].values())

    def streams(self) -> dict[str, StreamInfo]:
        out = {}
        for ch in self.channels():
            stream = layout.stream_of(ch.topic)
            if stream is None:
                continue
            md = ch.metadata
            try:
                info = StreamInfo(
                    stream, ch.topic, float(md["sample_rate"]), int(md["t0_ns"]), json.loads(md["channels"]),
                    json.loads(md.get("units", "[]")),
                )  # fmt: skip
            except (KeyError, ValueError) as exc:
                raise LogReadError(f"{self.path}: channel {ch.topic} lacks valid stream metadata ({exc})") from None
            if not (MIN_STREAM_RATE <= info.sample_rate <= 1e7 and isinstance(info.channels, list) and info.channels):
                raise LogReadError(
                    f"{self.path}: channel {ch.topic} claims an implausible stream (sample rate {info.sample_rate:g} Hz, "
                    f"outside {MIN_STREAM_RATE:g} .. 1e7 Hz, or no channels): its metadata is damaged and the samples "
                    "cannot be placed in time"
                )
            out[stream] = info
        return out

    def _messages(
        self, topics: Sequence[str] | None, start_ns: int | None, end_ns: int | None, time_order: bool, rep: SalvageReport,
        views: bool = False,
    ) -> Iterator[tuple[Channel, Message] | Damage]:  # fmt: skip
        chans = {ch.id: ch for ch in self.channels()}
        cids = None if topics is None else {cid for cid, ch in chans.items() if ch.topic in set(topics)}
        if self.summary is not None:
            source: Iterator[Any] = self._iter_indexed(cids, start_ns, end_ns, time_order, rep, views)
        else:
            source = self._records(rep)
        for m in source:
            if isinstance(m, Damage):
                yield m
                continue
            if not isinstance(m, Message):
                continue
            ch = chans.get(m.channel_id)
            if ch is None or (cids is not None and m.channel_id not in cids):
                continue
            if (start_ns is not None and m.log_time < start_ns) or (end_ns is not None and m.log_time >= end_ns):
                continue
            yield ch, m

    def iter_messages(
        self,
        topics: Sequence[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
        time_order: bool = False,
        salvage: bool = False,
    ) -> Iterator[tuple[Channel, Message]]:
        """Verified messages (every chunk CRC-checked), in file order or, ``time_order``, by log time (a chunk
        decompressed at a time: mcap's own reader held the whole log for that, and checked no CRC).

        A chunk that fails is skipped and remembered in ``self.damage``; after the good messages the pass then
        raises :class:`LogDamagedError`, unless ``salvage`` (``gvt log recover``): then the pass's counts go to
        ``self.report`` (``messages``, ``chunks_bad``, so ``data_lost``)."""  # fmt: skip
        rep = SalvageReport(complete=self._indexed, file_size=self.file_size)
        first: Damage | None = None
        for item in self._messages(topics, start_ns, end_ns, time_order, rep):
            if not isinstance(item, Damage):
                yield item
            elif first is None:
                first = item
        if first is not None and not salvage:
            where = f" at byte {first.offset}" if first.offset >= 0 else ""
            raise LogDamagedError(
                f"{self.path}: {rep.chunks_bad} damaged chunk(s), the first{where}: {first.reason}; "
                f"'gvt log recover {self.path} fixed.mcap' rewrites what is readable"
            )
        if salvage:
            r = self.report
            r.messages, r.chunks_ok, r.chunks_bad, r.duplicates = rep.messages, rep.chunks_ok, rep.chunks_bad, rep.duplicates
            if not self._indexed:
                r.stopped_because = rep.stopped_because
                r.messages = self.report.messages if rep.messages == 0 else rep.messages

    def message_count(self, topic: str) -> int:
        """Messages on ``topic``: from the summary's statistics (no data read) or from the salvage scan."""
        if self.summary is not None:
            counts = self.summary.statistics.channel_message_counts
            return sum(int(counts.get(ch.id, 0)) for ch in self.summary.channels.values() if ch.topic == topic)
        scan = self._scan()
        ids = {cid for cid, ch in scan["channels"].items() if ch.topic == topic}
        return sum(n for cid, n in scan["counts"].items() if cid in ids)

    def _indexed_record(self, offset: int, length: int, op: int) -> bytes:
        if length > MAX_ATTACHMENT_BYTES + (1 << 16) or offset + length > self.file_size:
            raise _Damaged(f"a record of {length} bytes, over the {MAX_ATTACHMENT_BYTES >> 20} MB limit")
        with open(self.path, "rb") as f:
            f.seek(offset)
            raw = f.read(length)
        if len(raw) < 9 or raw[0] != op or _u64(raw, 1) != length - 9:
            raise _Damaged("no record where the index says")
        return raw[9:]

    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records that pass their seal (``daq/log/seal.py``); the others are named in ``self.problems``."""
        records = self._scan()["metadata"] if self.summary is None else self._indexed_metadata()
        out = {}
        for m in records:
            body, ok = unseal(m.name, m.metadata)
            if ok:
                out[m.name] = body
            else:
                self.problems.append(f"metadata record {m.name!r} fails its CRC (left out)")
        return out

    def _indexed_metadata(self) -> list[Metadata]:
        assert self.summary is not None
        out = []
        for mi in self.summary.metadata_indexes:
            try:
                out.append(Metadata.read(ReadDataStream(io.BytesIO(self._indexed_record(mi.offset, mi.length, _OP_METADATA)))))
            except (*_EXPECTED_ERRORS, UnicodeDecodeError) as exc:
                self.problems.append(f"metadata record {mi.name!r} is unreadable ({_reason(exc)})")
        return out

    def attachments(self) -> dict[str, tuple[str, bytes]]:
        """Attachments that pass their CRC and the size cap; the others are named in ``self.problems``."""
        if self.summary is None:
            return {a.name: (a.media_type, bytes(a.data)) for a in self._scan()["attachments"]}
        out = {}
        for ai in self.summary.attachment_indexes:
            try:
                a = _attachment(self._indexed_record(ai.offset, ai.length, _OP_ATTACHMENT))
                out[a.name] = (a.media_type, bytes(a.data))
            except (*_EXPECTED_ERRORS, UnicodeDecodeError) as exc:
                self.problems.append(f"attachment {ai.name!r} is unusable ({_reason(exc)})")
        return out

    def json_messages(self, topic: str) -> list[dict[str, Any]]:
        """The verified JSON records of ``topic`` in log-time order; a damaged chunk's are missing (``self.damage``)."""
        out = []
        rep = SalvageReport(complete=self._indexed, file_size=self.file_size)
        for item in self._messages([topic], None, None, True, rep):
            if isinstance(item, Damage):
                continue
            msg = item[1]
            try:
                obj = json.loads(msg.data)
                out.append(obj if isinstance(obj, dict) else {"kind": "undecodable", "raw_bytes": len(msg.data)})
            except ValueError:
                out.append({"kind": "undecodable", "raw_bytes": len(msg.data)})
        return out

    def recovered_damage(self, stream: str) -> list[tuple[int, int, str]]:
        """The sample ranges of ``stream`` a log lost before ``gvt log recover`` rewrote it (its
        ``gvtlink.recovered`` record): damage on every read of the recovered file, which no longer holds the
        chunks (nor, for a damaged first chunk, anything else) that said where those samples were."""
        rec = self.metadata().get(layout.META_RECOVERED) or {}
        try:
            return [(int(a), int(b), str(why)) for a, b, why in json.loads(rec.get(stream, "[]"))]
        except (ValueError, TypeError):
            self.problems.append(f"metadata record {layout.META_RECOVERED!r} does not parse (left out)")
            return []

    def stream_records(self) -> dict[str, dict[str, Any]]:
        """The writer's ``gvtlink.streams`` record (counts, gaps, segments per stream) when the file is complete
        and the record parses; {} otherwise (older logs, damaged ones)."""
        if self.summary is None:
            return {}
        rec = self.metadata().get(layout.META_STREAMS)
        out = {}
        for name, text in (rec or {}).items():
            try:
                v = json.loads(text)
                out[name] = {
                    k: v[k] for k in ("blocks", "samples", "first_index", "end_index", "gaps", "segments", "status_flags")
                }
            except (ValueError, KeyError, TypeError):
                return {}
        return out

    def iter_blocks(
        self, stream: str, start_ns: int | None = None, end_ns: int | None = None
    ) -> Iterator[tuple[int, DecodedBlock] | Damage]:
        """``stream``'s verified, plausible blocks as (log_time, block) in log-time order, and a :class:`Damage`
        where a chunk holding its messages failed or a block is implausible (:func:`block_problem`)."""
        yield from self._verified_blocks(self.streams()[stream], start_ns, end_ns)

    def _verified_blocks(
        self, info: StreamInfo, start_ns: int | None, end_ns: int | None, view: bool = False
    ) -> Iterator[tuple[int, DecodedBlock] | Damage]:
        """:meth:`iter_blocks` of ``info``; ``view``: each block's data a view of its chunk (decoded without a copy),
        valid until the caller copies it — the chunk's CRC was checked before any block of it is yielded."""
        cids = self._channel_ids(info)
        rep = SalvageReport(complete=self._indexed, file_size=self.file_size)
        for item in self._messages([info.topic], start_ns, end_ns, True, rep, views=view):
            if isinstance(item, Damage):
                if item.lost is None or cids & set(item.lost):
                    yield item
                continue
            _ch, msg = item
            try:
                b = decode_block(msg.data, view=view)
                why = block_problem(b, info, msg.log_time)
            except BlockDecodeError as exc:
                b, why = None, f"undecodable ({exc})"
            if why is not None or b is None:
                d = Damage(-1, f"bad sample block (sequence {msg.sequence}): {why}", msg.log_time, msg.log_time,
                           {msg.channel_id: [msg.log_time]})  # fmt: skip
                self.damage.setdefault((-1, msg.log_time), d)
                yield d
                continue
            yield msg.log_time, b

    def _channel_ids(self, info: StreamInfo) -> set[int]:
        return {ch.id for ch in self.channels() if ch.topic == info.topic}

    def read_stream(
        self,
        stream: str,
        channels: Sequence[str] | None = None,
        start: float | None = None,
        end: float | None = None,
        on_damage: str = "refuse",
    ) -> StreamData:
        """All samples of ``stream`` (optionally some channels, and ``start <= t < end`` seconds). Damage in
        the range: ``on_damage="refuse"`` raises :class:`LogDamagedError` (exit 3, naming the samples and
        ``gvt log recover``); ``"skip"`` leaves it out and lists it in ``damaged``. A duplicated block is
        kept once. Each block is copied once, from its verified chunk straight into the result."""  # fmt: skip
        info = self._stream_info(stream)
        sel = self._channel_indices(info, channels)
        start_ns, end_ns = _fetch_window(info, start, end)
        samples = _Samples(sel, len(info.channels), self.message_count(info.topic), self._max_rows(info, start_ns, end_ns))
        recorded = self.stream_records().get(stream, {})
        tracker = DamageRanges(info, self._channel_ids(info), recorded.get("first_index") if start is None else None)
        for item in self._verified_blocks(info, start_ns, end_ns, view=True):
            if isinstance(item, Damage):
                tracker.damage(item)
                continue
            b = item[1]
            tracker.block(b.first_index, b.first_index + b.data.shape[0])
            samples.add(b)
        end_hint = recorded.get("end_index")
        lo_i = None if start is None else int(np.ceil(start * info.sample_rate))
        hi_i = None if end is None else int(np.ceil(end * info.sample_rate))
        damaged = tracker.finish(end_hint, lo_i, hi_i)
        if samples.firsts:  # samples two blocks claim with different values: damage, never merged silently
            damaged += _clipped(samples.kept()[1], lo_i, hi_i)
        if damaged and on_damage == "refuse":
            raise self.damaged_error(info, damaged)
        # what the log had lost before `gvt log recover` (D101): listed, never a refusal (nothing in this file is
        # damaged, and a recover would not give them back); a verb that needs whole data reads around them as a gap
        damaged += _clipped(self.recovered_damage(stream), lo_i, hi_i)
        return samples.assemble(info, [info.channels[i] for i in sel], start, end, damaged)

    def _max_rows(self, info: StreamInfo, start_ns: int | None, end_ns: int | None) -> int | None:
        """At most how many samples the blocks logged in [start_ns, end_ns) hold, whatever their sizes: what their
        chunks hold uncompressed at 4 bytes a value, and what their log times span plus a block (None: no index, a
        damaged log)."""
        if self.summary is None:
            return None
        plan = self._chunk_plan(self._channel_ids(info), start_ns, end_ns, False)
        rows = sum(ci.uncompressed_size for ci in plan) // (4 * len(info.channels))
        if start_ns is not None and end_ns is not None:
            rows = min(rows, int(np.ceil((end_ns - start_ns) * info.sample_rate / 1e9)) + MAX_BLOCK_SAMPLES)
        return rows

    def _stream_info(self, stream: str) -> StreamInfo:
        infos = self.streams()
        if stream not in infos:
            raise LogReadError(f"{self.path}: no stream {stream!r}; streams: {sorted(infos)}")
        return infos[stream]

    def _channel_indices(self, info: StreamInfo, channels: Sequence[str] | None) -> list[int]:
        """Positions of ``channels`` in the stream (all of them when None or empty); LogReadError naming the missing."""
        if not channels:
            return list(range(len(info.channels)))
        missing = [c for c in channels if c not in info.channels]
        if missing:
            raise LogReadError(f"{self.path}: stream {info.stream!r} has no channel(s) {missing}; it has {info.channels}")
        return [info.channels.index(c) for c in channels]

    def damaged_error(self, info: StreamInfo, damaged: list[tuple[int, int, str]]) -> LogDamagedError:
        """The one line (exit 3) for ``damaged`` samples of ``info``'s stream: the first range, how many more, why."""
        a, b, why = damaged[0]
        more = f" and {len(damaged) - 1} more range(s)" if len(damaged) > 1 else ""
        # recover copies every block it can read: it cannot choose between two that disagree
        then = ("; gvt record never writes that: use the original file, or export a range without them (--start/--end)"
                if why == OVERLAP
                else f"; `gvt log recover {self.path} FIXED.mcap` keeps the rest, the damage as a gap")  # fmt: skip
        return LogDamagedError(
            f"{self.path}: samples [{a}, {b}) of stream {info.stream} "
            f"(t = {a / info.sample_rate:.3f}–{b / info.sample_rate:.3f} s){more} are damaged ({why}){then}"
        )


def _fetch_window(info: StreamInfo, start: float | None, end: float | None) -> tuple[int | None, int | None]:
    """The log times of the blocks to fetch for ``start <= t < end``: a block's log time is its first sample's, so
    from 65536 samples (more than any block holds) before ``start``."""
    start_ns = None if start is None else info.t0_ns + int(np.floor(start * 1e9)) - int(1e9 * 65536 / info.sample_rate)
    end_ns = None if end is None else info.t0_ns + int(np.ceil(end * 1e9)) + 1
    return start_ns, end_ns


class DamageRanges:
    """Exact [start, end) sample ranges of one stream lost to damage: a damaged chunk's lost blocks start at the
    indices their log times say (its message indexes; else the previous block's end; before any block was read,
    the stream's recorded first index ``first_hint``, else the chunk's first log time) and end where the next
    block read starts (at the end: the stream's recorded end, or one block on). A damaged first chunk whose
    message indexes were damaged too used to give no range at all: its samples left an export without a word."""

    def __init__(self, info: StreamInfo, cids: set[int], first_hint: int | None = None) -> None:
        self.info, self.cids, self.first_hint = info, cids, first_hint
        self.pending: list[tuple[int | None, int | None, str]] = []
        self.ranges: list[tuple[int, int, str]] = []
        self.prev_end: int | None = None
        self.last_n = 0

    def damage(self, d: Damage) -> None:
        times = [t for c in self.cids for t in (d.lost or {}).get(c, [])]
        at = " at byte " + str(d.offset) if d.offset >= 0 else ""
        why = f"{d.reason}{at}"
        if times:
            self.pending.append((self.info.index_at(min(times)), self.info.index_at(max(times)), why))
        elif self.prev_end is None and (self.first_hint is not None or d.start_ns >= self.info.t0_ns):
            # nothing read yet: the stream starts inside this chunk (or a later one: then no range is left)
            start = self.first_hint if self.first_hint is not None else self.info.index_at(d.start_ns)
            self.pending.append((start, None, why))
        else:
            self.pending.append((None, None, why))

    def _lo(self, a: int | None) -> int | None:
        if a is None:
            return self.prev_end
        return a if self.prev_end is None else max(a, self.prev_end)

    def block(self, first: int, end: int) -> None:
        still = []
        for a, last, why in self.pending:
            lo = self._lo(a)
            if lo is None or (a is not None and first < a):
                still.append((a, last, why))
            elif first > lo:
                self.ranges.append((lo, first, why))
        self.pending = still
        self.prev_end = end if self.prev_end is None else max(self.prev_end, end)
        self.last_n = end - first

    def finish(self, end_hint: int | None, lo_i: int | None = None, hi_i: int | None = None) -> list[tuple[int, int, str]]:
        for a, last, why in self.pending:
            lo = self._lo(a)
            if lo is None:
                continue
            hi = max(end_hint or 0, (last if last is not None else lo) + max(self.last_n, 1))
            if hi > lo:
                self.ranges.append((lo, hi, why))
        self.pending = []
        return _clipped(self.ranges, lo_i, hi_i)


def _clipped(ranges: list[tuple[int, int, str]], lo_i: int | None, hi_i: int | None) -> list[tuple[int, int, str]]:
    """``ranges`` cut to ``[lo_i, hi_i)`` (None: open), the empty ones left out."""
    out = []
    for a, b, why in ranges:
        a, b = max(a, lo_i) if lo_i is not None else a, min(b, hi_i) if hi_i is not None else b
        if b > a:
            out.append((a, b, why))
    return out


class _Samples:
    """One stream's blocks as they are read, each copied once into a growing (rows, channels) float32 array —
    straight from its chunk, the one transposing copy a format-2 block needs anyway. A copy per block and another
    to concatenate them, plus a per-sample index built from two ``np.repeat``, were 38 % of a read (issue 28).

    The first block sizes the array for the stream's message count (within ``max_rows``, what the chunks can hold;
    a damaged log has no index to say: doubling from there), so a log as written is never copied again; anything
    else grows it by doubling. :meth:`assemble` puts the blocks in
    index order (nothing to do in a log as written) and drops a block overlapping an earlier one."""

    def __init__(self, sel: list[int], n_channels: int, n_messages: int, max_rows: int | None) -> None:
        self.sel = None if sel == list(range(n_channels)) else np.asarray(sel, np.intp)
        self.n_messages, self.max_rows = n_messages, max_rows
        self.buf = np.empty((0, len(sel)), np.float32)
        self.rows = 0
        self.firsts: list[int] = []
        self.lengths: list[int] = []
        self.statuses: list[int] = []
        self._kept: tuple[np.ndarray, list[tuple[int, int, str]]] | None = None

    def add(self, b: DecodedBlock) -> None:
        """Copy block ``b`` (its selected channels) to the end."""
        n = b.data.shape[0]
        self._reserve(n)
        dst = self.buf[self.rows : self.rows + n]
        if self.sel is None:
            dst[...] = b.data
        else:
            dst[...] = b.data.T[self.sel].T  # the channels' columns gathered first: 2x faster than [:, sel], 3x np.take
        self.rows += n
        self.firsts.append(b.first_index)
        self.lengths.append(n)
        self.statuses.append(b.status)

    def kept(self) -> tuple[np.ndarray, list[tuple[int, int, str]]]:
        """The blocks that make the stream (:func:`kept_blocks`) and the samples of a dropped block that are not the
        kept blocks' same values (:data:`OVERLAP`): a chunk logged twice is kept once quietly; a block that says
        something else about samples, or holds samples no kept block has, is damage."""
        if self._kept is None:
            firsts, lengths = np.asarray(self.firsts, np.int64), np.asarray(self.lengths, np.int64)
            keep, dropped = kept_blocks(firsts, lengths)
            conflicts = [(int(firsts[i]), int(firsts[i] + lengths[i]), OVERLAP) for i in dropped
                         if not self._repeats(i, keep, firsts, lengths)]  # fmt: skip
            self._kept = keep, _merged_ranges(conflicts)
        return self._kept

    def _repeats(self, i: int, keep: np.ndarray, firsts: np.ndarray, lengths: np.ndarray) -> bool:
        """Every sample of block ``i`` is in the kept blocks, bit for bit."""
        offsets = np.cumsum(lengths) - lengths
        k_first, k_end = firsts[keep], firsts[keep] + lengths[keep]
        pos, end = int(firsts[i]), int(firsts[i] + lengths[i])
        k = int(np.searchsorted(k_first, pos, side="right")) - 1
        while pos < end:
            if k < 0 or k >= len(keep) or k_end[k] <= pos:
                return False  # samples only this block holds: dropping it would lose them
            j, hi = keep[k], min(end, int(k_end[k]))
            mine = self.buf[offsets[i] + pos - firsts[i] : offsets[i] + hi - firsts[i]]
            kept = self.buf[offsets[j] + pos - firsts[j] : offsets[j] + hi - firsts[j]]
            if mine.tobytes() != kept.tobytes():
                return False
            pos, k = hi, k + 1
        return True

    def _reserve(self, n: int) -> None:
        if self.rows + n <= len(self.buf):
            return
        guess = 0
        if not len(self.buf) and self.max_rows is not None:  # the first block: its size times the stream's blocks
            guess = min(n * self.n_messages, self.max_rows)
        grown = np.empty((max(self.rows + n, guess, 2 * len(self.buf)), self.buf.shape[1]), np.float32)
        grown[: self.rows] = self.buf[: self.rows]
        self.buf = grown

    def assemble(
        self, info: StreamInfo, names: list[str], start: float | None, end: float | None, damaged: list[tuple[int, int, str]]
    ) -> StreamData:
        """The blocks in index order as one array, their sample indices and gaps, cut to ``start <= t < end``."""
        if not self.firsts:
            none = np.zeros(0, np.int64)
            return StreamData(info, names, none, np.zeros((0, len(names)), np.float32), none, np.zeros(0, np.uint32), [], damaged)
        firsts, lengths = np.asarray(self.firsts, np.int64), np.asarray(self.lengths, np.int64)
        keep = self.kept()[0]
        data = self._rows_of(keep, lengths)
        first, lengths = firsts[keep], lengths[keep]
        index = _sample_index(first, lengths)
        ends = first + lengths
        gaps = [(int(ends[i]), int(first[i + 1])) for i in np.flatnonzero(first[1:] > ends[:-1])]
        if start is not None or end is not None:
            index, data, gaps = _window(info, index, data, gaps, start, end)
        if data.base is self.buf and 2 * data.shape[0] < len(self.buf):
            data = data.copy()  # a short window of a long read: do not hold the whole buffer
        return StreamData(info, names, index, data, first, np.asarray(self.statuses, np.uint32)[keep], gaps, damaged)

    def _rows_of(self, keep: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """The kept blocks' rows in order: the buffer itself when that is every block as read."""
        if len(keep) == len(lengths) and (keep[:-1] < keep[1:]).all():
            return self.buf[: self.rows]
        offsets = np.cumsum(lengths) - lengths
        return np.concatenate([self.buf[offsets[i] : offsets[i] + lengths[i]] for i in keep])


#: why samples two blocks hold are damage: the log says two things about them (issue 30: merged silently before)
OVERLAP = "two overlapping blocks hold them and do not agree: which is right cannot be told"


def kept_blocks(firsts: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Which blocks make the stream, in index order, and which were dropped: sorted by first index (stable: the
    first read wins), a block that starts before the previous kept one ends is dropped (a duplicated chunk, an
    overlap; :meth:`_Samples.kept` says whether it agrees with what was kept). In a log as written every block
    follows the one before: all of them, as read, without sorting."""
    if (firsts[1:] >= firsts[:-1] + lengths[:-1]).all():
        return np.arange(len(firsts)), []
    keep: list[int] = []
    dropped: list[int] = []
    reach = None
    for i in np.argsort(firsts, kind="stable"):
        if reach is None or firsts[i] >= reach:
            keep.append(i)
            reach = firsts[i] + lengths[i]
        else:
            dropped.append(int(i))
    return np.asarray(keep, np.intp), dropped


def _merged_ranges(ranges: list[tuple[int, int, str]]) -> list[tuple[int, int, str]]:
    out: list[tuple[int, int, str]] = []
    for a, b, why in sorted(ranges):
        if out and a <= out[-1][1] and why == out[-1][2]:
            out[-1] = (out[-1][0], max(out[-1][1], b), why)
        else:
            out.append((a, b, why))
    return out


def _sample_index(first: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Each sample's device index: one ``arange`` when the blocks follow each other (no gap), else each block's
    offset from its row added to the row number."""
    n = int(lengths.sum())
    if (first[1:] == first[:-1] + lengths[:-1]).all():
        return np.arange(first[0], first[0] + n, dtype=np.int64)
    rows = np.cumsum(lengths) - lengths
    return np.repeat(first - rows, lengths) + np.arange(n, dtype=np.int64)


def _window(
    info: StreamInfo, index: np.ndarray, data: np.ndarray, gaps: list[tuple[int, int]], start: float | None, end: float | None
) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:  # fmt: skip
    """The samples with ``start <= t < end`` (t = index / rate, rising: one slice) and the gaps inside the window:
    blocks are fetched from before ``start`` (a block's log time is its first sample's), and a gap there is not one
    of this read (it refused every hit after a device restart in gvt frf)."""
    t = index / info.sample_rate
    a = 0 if start is None else int(np.searchsorted(t, start, side="left"))
    b = len(t) if end is None else max(a, int(np.searchsorted(t, end, side="left")))
    lo = -np.inf if start is None else start * info.sample_rate
    hi = np.inf if end is None else end * info.sample_rate
    gaps = [(int(max(g0, np.ceil(lo))), int(min(g1, np.ceil(hi)))) for g0, g1 in gaps if g1 > lo and g0 < hi]
    return index[a:b], data[a:b], [(g0, g1) for g0, g1 in gaps if g1 > g0]


def open_log(path: str | Path) -> LogReader:
    return LogReader(path)
