"""Verified access to MCAP records: every check a read of a gvtlink log relies on, and nothing else.

The `mcap` package parses records but leaves the checks to its caller: its indexed ``iter_messages`` does not
verify chunk CRCs (a bit flip was served as data), a record's declared sizes are allocated as declared (a 60 kB
decompression bomb cost 3 GB), and a file cut inside its summary raised ``struct.error`` from deep inside.
Here: the footer and ``summary_crc`` (:func:`read_summary`), a chunk's header against its index
(:func:`parse_chunk`), decompression against the declared size with caps (:func:`chunk_payload`), its
records (:func:`chunk_records`), message-index times (:func:`_message_index_times`) and attachments
(:func:`_attachment`). Anything that fails raises :class:`_Damaged` or one of :data:`_EXPECTED_ERRORS`;
``daq/log/reader.py`` turns that into damage with sample ranges.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from typing import BinaryIO

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    Message,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.summary import Summary
from zstandard import ZstdError

MAGIC = b"\x89MCAP0\r\n"
#: Uncompressed bytes one chunk may hold. The writer closes a chunk at 4 MB or every 0.5 s (6.5 MB at
#: 64 ch × 51.2 kHz); 128 MB is 20× that. A chunk declaring more, or expanding beyond what it declares, is
#: damage: decompressing it is what made a 60 kB bomb cost 3 GB.
MAX_CHUNK_BYTES = 128 << 20
#: zstd window the decompressor will allocate (a frame may declare a 2 GB window)
MAX_WINDOW_BYTES = 1 << 27
#: the summary section (schemas, channels, indexes: about 100 bytes per chunk, so a 64 MB summary indexes
#: 600 000 chunks, 40 TB of log)
MAX_SUMMARY_BYTES = 64 << 20
#: an attachment (a rig or config file: kilobytes)
MAX_ATTACHMENT_BYTES = 16 << 20
#: any other record in a linear scan (a chunk record is at most its compressed data plus a header)
MAX_RECORD_BYTES = MAX_CHUNK_BYTES + (1 << 16)

#: off only in bench/bench_log.py, to measure what the CRC check costs
VERIFY_CRC = True

_FOOTER = 1 + 8 + 20  # opcode, length, summary_start, summary_offset_start, summary_crc
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_ATTACHMENT, _OP_METADATA = 0x06, 0x07, 0x09, 0x0C
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05
_OP_CHUNK_INDEX, _OP_ATTACHMENT_INDEX, _OP_STATISTICS, _OP_METADATA_INDEX = 0x08, 0x0A, 0x0B, 0x0D
_OP_FOOTER, _OP_DATA_END = 0x02, 0x0F


class _Damaged(Exception):
    """A chunk or record that failed a check (internal; becomes a :class:`Damage`)."""


#: what reading a damaged file raises, besides mcap's own errors: zstandard's ZstdError (a corrupt chunk),
#: struct.error (a record cut short: 976 of 1977 cuts in a log's summary raised it), UnicodeDecodeError (a
#: flipped string)
_EXPECTED_ERRORS = (
    McapError, ZstdError, EOFError, ValueError, OSError, KeyError, IndexError, MemoryError, OverflowError, struct.error,
    _Damaged,
)  # fmt: skip


def _u64(buf: bytes | memoryview, at: int) -> int:
    return struct.unpack_from("<Q", buf, at)[0]


def parse_chunk(raw: bytes | memoryview) -> Chunk:
    """A Chunk record's body (after opcode and length), every length checked against the bytes there are."""
    start, end, usize, ucrc, clen = struct.unpack_from("<QQQII", raw, 0)
    if 32 + clen + 8 > len(raw):
        raise _Damaged("chunk header cut or corrupt")
    comp = bytes(raw[32 : 32 + clen]).decode("utf-8", "replace")
    dlen = _u64(raw, 32 + clen)
    at = 40 + clen
    if at + dlen > len(raw):
        raise _Damaged("chunk data longer than its record")
    return Chunk(
        compression=comp,
        data=memoryview(raw)[at : at + dlen],  # no copy: zstd, lz4 and crc32 take any buffer
        message_end_time=end,
        message_start_time=start,
        uncompressed_crc=ucrc,
        uncompressed_size=usize,
    )


def chunk_payload(chunk: Chunk) -> bytes | memoryview:
    """The chunk's records, decompressed against its declared size (capped) and CRC-checked; _Damaged if not."""
    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise _Damaged(f"chunk declares {size} bytes uncompressed, over the {MAX_CHUNK_BYTES >> 20} MB limit")
    if chunk.compression == "zstd":
        try:
            params = zstandard.get_frame_parameters(chunk.data)
            if params.content_size not in (size, zstandard.CONTENTSIZE_UNKNOWN):
                raise _Damaged(f"zstd frame holds {params.content_size} bytes, the chunk declares {size}")
            if params.window_size > MAX_WINDOW_BYTES:
                raise _Damaged(f"zstd window of {params.window_size} bytes, over the {MAX_WINDOW_BYTES >> 20} MB limit")
            data = zstandard.ZstdDecompressor(max_window_size=MAX_WINDOW_BYTES).decompress(chunk.data, max_output_size=size)
        except ZstdError as exc:
            raise _Damaged(f"chunk does not decompress ({exc})") from None
    elif chunk.compression == "lz4":
        try:
            import lz4.frame

            d = lz4.frame.LZ4FrameDecompressor()
            data = d.decompress(chunk.data, max_length=size + 1)
        except Exception as exc:
            raise _Damaged(f"lz4 chunk does not decompress ({type(exc).__name__})") from None
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise _Damaged(f"unknown chunk compression {chunk.compression[:20]!r}")
    if len(data) != size:
        raise _Damaged(f"chunk holds {len(data)} bytes uncompressed, declares {size}")
    if VERIFY_CRC and chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _Damaged("chunk fails its CRC")
    return data


def chunk_records(data: bytes | memoryview, views: bool = False) -> list[Schema | Channel | Message]:
    """The schemas, channels and messages in a chunk's uncompressed bytes (others skipped); _Damaged when a
    record runs past the end (a chunk without a CRC can still be cut or garbled). ``views``: a message's data is
    a memoryview of ``data`` instead of a copy (``read_stream`` copies each block once, into its output; a
    message kept longer would keep the whole chunk alive)."""
    out: list[Schema | Channel | Message] = []
    view, pos, n = memoryview(data), 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise _Damaged("chunk records cut short")
        op, length = data[pos], _u64(view, pos + 1)
        body = pos + 9
        if body + length > n:
            raise _Damaged("chunk record runs past the chunk")
        if op == _OP_MESSAGE:
            if length < 22:
                raise _Damaged("message record too short")
            cid, seq, lt, pt = struct.unpack_from("<HIQQ", view, body)
            payload = view[body + 22 : body + length]
            out.append(
                Message(channel_id=cid, log_time=lt, data=payload if views else bytes(payload), publish_time=pt, sequence=seq)
            )
        elif op in (_OP_SCHEMA, _OP_CHANNEL):
            s = ReadDataStream(io.BytesIO(view[body : body + length]))
            out.append(Schema.read(s) if op == _OP_SCHEMA else Channel.read(s))
        pos = body + length
    return out


def _records_in(buf: bytes) -> Iterator[tuple[int, memoryview]]:
    """(opcode, body) of each record in ``buf`` (a summary section, a message index run); stops at a cut."""
    view, pos = memoryview(buf), 0
    while pos + 9 <= len(buf):
        op, length = buf[pos], _u64(view, pos + 1)
        if pos + 9 + length > len(buf):
            raise _Damaged("record runs past its section")
        yield op, view[pos + 9 : pos + 9 + length]
        pos += 9 + length


_SUMMARY_READERS = {
    _OP_SCHEMA: Schema.read, _OP_CHANNEL: Channel.read, _OP_CHUNK_INDEX: ChunkIndex.read,
    _OP_ATTACHMENT_INDEX: AttachmentIndex.read, _OP_STATISTICS: Statistics.read, _OP_METADATA_INDEX: MetadataIndex.read,
}  # fmt: skip


def read_summary(f: BinaryIO, size: int) -> Summary:
    """The summary section, trusted only if the footer is whole, its CRC matches (when set) and every index
    points inside the data section; _Damaged (why) otherwise."""
    if size < 8 + _FOOTER + 8:
        raise _Damaged("too short for a footer")
    f.seek(size - _FOOTER - 8)
    tail = f.read(_FOOTER + 8)
    if tail[_FOOTER:] != MAGIC or tail[0] != 0x02 or _u64(tail, 1) != 20:
        raise _Damaged("no footer (the file ends early)")
    s_start, _offsets, crc = struct.unpack_from("<QQI", tail, 9)
    end = size - _FOOTER - 8
    if s_start == 0:
        raise _Damaged("the file has no summary")
    if not 8 < s_start <= end or end - s_start > MAX_SUMMARY_BYTES:
        raise _Damaged("the footer points outside the file")
    f.seek(s_start)
    buf = f.read(end - s_start)
    if crc and zlib.crc32(tail[:25], zlib.crc32(buf)) != crc:
        raise _Damaged("the summary fails its CRC")
    summ = Summary()
    for op, body in _records_in(buf):
        reader = _SUMMARY_READERS.get(op)
        if reader is None:
            continue
        rec = reader(ReadDataStream(io.BytesIO(body)))
        if isinstance(rec, Schema):
            summ.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            summ.channels[rec.id] = rec
        elif isinstance(rec, ChunkIndex):
            if rec.chunk_start_offset + rec.chunk_length > s_start or rec.chunk_start_offset < 8:
                raise _Damaged("a chunk index points outside the data section")
            summ.chunk_indexes.append(rec)
        elif isinstance(rec, AttachmentIndex):
            summ.attachment_indexes.append(rec)
        elif isinstance(rec, MetadataIndex):
            summ.metadata_indexes.append(rec)
        elif isinstance(rec, Statistics):
            summ.statistics = rec
    if summ.statistics is None:
        raise _Damaged("the summary has no statistics")
    return summ


def _message_index_times(f: BinaryIO, ci: ChunkIndex, size: int) -> dict[int, list[int]] | None:
    """Log times of the messages a chunk held, per channel id, from its message indexes (None: unreadable)."""
    if not ci.message_index_offsets or ci.message_index_length > MAX_SUMMARY_BYTES:
        return None
    start = min(ci.message_index_offsets.values())
    if start + ci.message_index_length > size:
        return None
    f.seek(start)
    out: dict[int, list[int]] = {}
    try:
        for op, body in _records_in(f.read(ci.message_index_length)):
            if op == _OP_MESSAGE_INDEX:
                cid, n = struct.unpack_from("<HI", body, 0)
                out[cid] = [t for t, _o in struct.iter_unpack("<QQ", body[6 : 6 + n])]
    except (_Damaged, struct.error):
        return None
    return out if set(out) >= set(ci.message_index_offsets) else None


def _attachment(body: bytes) -> Attachment:
    """An Attachment record's body, its data size capped and its CRC (when set) checked."""
    s = ReadDataStream(io.BytesIO(body))
    log_time, create_time = s.read8(), s.read8()
    name, media = s.read_prefixed_string(), s.read_prefixed_string()
    size = s.read8()
    if size > MAX_ATTACHMENT_BYTES:
        raise _Damaged(f"{size} bytes, over the {MAX_ATTACHMENT_BYTES >> 20} MB limit for an attachment")
    data = s.read(size)
    if len(data) != size or len(body) < s.count + 4:
        raise _Damaged("attachment cut short")
    (crc,) = struct.unpack_from("<I", body, s.count)
    if crc and zlib.crc32(body[: s.count]) != crc:
        raise _Damaged("attachment fails its CRC")
    return Attachment(create_time=create_time, log_time=log_time, name=name, media_type=media, data=data)


def _reason(exc: BaseException) -> str:
    return str(exc) if isinstance(exc, _Damaged) else _describe(exc)


def _describe(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}"[:200] if text else type(exc).__name__
