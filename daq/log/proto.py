"""Protobuf schema of a sample block, and a fast codec for it.

The schema is stored in every log as a FileDescriptorSet, so MCAP tools and Foxglove decode blocks
without gvtlink. Format 2 (written now) is channel-major, one schema per stream (``block_schema``):

    message SampleBlock_<stream> {            // package gvtlink
      string stream = 1; int64 first_index = 2; double sample_rate = 3;
      uint32 n_channels = 4; uint32 n_samples = 5; reserved 6; uint32 status = 7; int64 t0_ns = 8;
      repeated float <channel k> = 16 + k [packed];  // that channel's n_samples samples, in order
    }

Why channel-major (docs/decisions.md D30): Foxglove's message paths have no stride and no nested arrays,
so one field per channel is the only layout where ``/daq/dev0/samples.hammer`` is a channel's waveform.
Field *names* are the channel names made protobuf identifiers (``field_names``); the wire carries only
field numbers, so ``decode_block`` needs no schema: fields 16.. are channels 0.., field 6 is format 1's
row-major ``data`` (logs written before; still read). Each packed payload is the channel's little-endian
float32 samples verbatim, so encoding and decoding are one (transposing) memory copy.
"""

from __future__ import annotations

import keyword
import re
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from google.protobuf import descriptor_pb2

from daq.log.layout import SAMPLE_BLOCK_SCHEMA


class BlockDecodeError(ValueError):
    """A sample-block message is malformed."""


SCHEMA_NAME = SAMPLE_BLOCK_SCHEMA  # format 1's single schema; format 2's are "<SCHEMA_NAME>_<stream>"
CHANNEL_FIELD_BASE = 16  # channel k is field 16 + k; 1..15 are the block's scalars (one-byte tags)
MAX_CHANNELS = 19000 - CHANNEL_FIELD_BASE  # protobuf reserves field numbers 19000-19999
_SCALARS = (
    ("stream", 1, descriptor_pb2.FieldDescriptorProto.TYPE_STRING),
    ("first_index", 2, descriptor_pb2.FieldDescriptorProto.TYPE_INT64),
    ("sample_rate", 3, descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE),
    ("n_channels", 4, descriptor_pb2.FieldDescriptorProto.TYPE_UINT32),
    ("n_samples", 5, descriptor_pb2.FieldDescriptorProto.TYPE_UINT32),
    ("status", 7, descriptor_pb2.FieldDescriptorProto.TYPE_UINT32),
    ("t0_ns", 8, descriptor_pb2.FieldDescriptorProto.TYPE_INT64),
)
# Names a channel field must not take: the block's own fields, and members of the message objects that
# protobufjs (JavaScript) and Python protobuf generate, which a field of that name would shadow.
_RESERVED = frozenset(
    [s[0] for s in _SCALARS]
    + ["data", "constructor", "prototype", "toJSON", "toString", "valueOf", "hasOwnProperty", "__proto__"]
    + ["DESCRIPTOR", "Extensions"]
)
_NOT_IDENT = re.compile(r"[^A-Za-z0-9_]")


def _json_name(name: str) -> str:
    """protobuf's default JSON name (lowerCamel): two fields with the same one are rejected by descriptor pools."""
    out, up = [], False
    for ch in name:
        if ch == "_":
            up = True
        else:
            out.append(ch.upper() if up else ch)
            up = False
    return "".join(out)


def field_names(channels: Sequence[str]) -> list[str]:
    """Protobuf field names for channel names, in order: unique, deterministic, readable.

    Not an identifier character -> ``_`` ("acc-3" -> "acc_3", "x y" -> "x_y"); a name that starts with a
    digit, is empty, a keyword or reserved gets ``ch_`` ("1st" -> "ch_1st", "status" -> "ch_status");
    a name already taken (also as protobuf's JSON name: "acc_3" and "acc3" collide) gets ``_2``, ``_3`` ...
    The mapping is stored in the channel metadata (``fields``), so nobody needs to redo this.
    """
    out: list[str] = []
    taken: set[str] = set()
    for raw in channels:
        base = _NOT_IDENT.sub("_", raw)
        if not base or base[0].isdigit() or base in _RESERVED or keyword.iskeyword(base) or base.startswith("_"):
            base = "ch_" + base.lstrip("_") if base.lstrip("_") else "ch"
        name, n = base, 1
        while name in taken or _json_name(name) in taken or _json_name(name) in {_json_name(r) for r in _RESERVED}:
            n += 1
            name = f"{base}_{n}"
        taken.update((name, _json_name(name)))
        out.append(name)
    return out


def block_schema_name(stream: str) -> str:
    """``gvtlink.SampleBlock_<stream>``; a stream id that is not an identifier gets a crc32 suffix so two
    streams never share a schema name (viewers key message definitions by name)."""
    ident = _NOT_IDENT.sub("_", stream)
    if ident != stream or not ident:
        ident = f"{ident}_{zlib.crc32(stream.encode()):08x}"
    return f"{SCHEMA_NAME}_{ident}"


def block_schema(stream: str, channels: Sequence[str]) -> tuple[str, bytes, list[str]]:
    """(schema name, FileDescriptorSet bytes, field names) of ``stream``'s channel-major block message."""
    if len(channels) > MAX_CHANNELS:
        raise ValueError(f"stream {stream!r}: {len(channels)} channels, at most {MAX_CHANNELS} fit one block message")
    name = block_schema_name(stream)
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name=f"gvtlink/{name}.proto", package="gvtlink", syntax="proto3")
    msg = fdp.message_type.add(name=name.split(".", 1)[1])
    for fname, number, typ in _SCALARS:
        msg.field.add(name=fname, number=number, type=typ, label=F.LABEL_OPTIONAL)
    msg.reserved_range.add(start=6, end=7)  # format 1's row-major data
    names = field_names(channels)
    for k, fname in enumerate(names):
        f = msg.field.add(name=fname, number=CHANNEL_FIELD_BASE + k, type=F.TYPE_FLOAT, label=F.LABEL_REPEATED)
        f.options.packed = True
    return name, descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString(), names


@lru_cache(maxsize=1)
def sample_block_descriptor_set() -> bytes:
    """Format 1's schema (row-major ``data = 6``): kept to write old-layout files in tests and the benchmark."""
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="gvtlink/sample_block.proto", package="gvtlink", syntax="proto3")
    msg = fdp.message_type.add(name="SampleBlock")
    for name, number, typ in (*_SCALARS[:5], ("data", 6, F.TYPE_FLOAT), *_SCALARS[5:]):
        label = F.LABEL_REPEATED if number == 6 else F.LABEL_OPTIONAL
        msg.field.add(name=name, number=number, type=typ, label=label)
    msg.field[5].options.packed = True
    return descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString()


def _varint(n: int) -> bytes:
    if n < 0:
        n += 1 << 64
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _head(stream: str, first_index: int, sample_rate: float, n_c: int, n_s: int, status: int, t0_ns: int) -> bytes:
    s = stream.encode("utf-8")
    parts = [
        b"\x0a", _varint(len(s)), s,
        b"\x10", _varint(int(first_index)),
        b"\x19", struct.pack("<d", float(sample_rate)),
        b"\x20", _varint(n_c),
        b"\x28", _varint(n_s),
        b"\x38", _varint(int(status)),
        b"\x40", _varint(int(t0_ns)),
    ]  # fmt: skip
    return b"".join(parts)


@lru_cache(maxsize=64)
def _channel_headers(n_c: int, n_s: int) -> tuple[int, np.ndarray | None]:
    """Per-channel field headers (tag + length) as a (n_c, h) uint8 array when all have the same length h
    (channels 0..2031 have two-byte tags), which lets one strided array cover every channel's payload."""
    ln = _varint(4 * n_s)
    hdrs = [_varint(((CHANNEL_FIELD_BASE + k) << 3) | 2) + ln for k in range(n_c)]
    h = len(hdrs[0]) if hdrs else 0
    if any(len(x) != h for x in hdrs):
        return h, None
    return h, np.frombuffer(b"".join(hdrs), np.uint8).reshape(n_c, h)


def encode_block(stream: str, first_index: int, sample_rate: float, data: np.ndarray, status: int = 0, t0_ns: int = 0) -> bytes:
    """Serialise one block (``data`` float32, shape (n_samples, n_channels)) channel-major: one transposing copy."""
    d = np.asarray(data, dtype="<f4")
    n_s, n_c = d.shape
    head = _head(stream, first_index, sample_rate, n_c, n_s, status, t0_ns)
    if n_s == 0 or n_c == 0:
        return head
    h, hdrs = _channel_headers(n_c, n_s)
    if hdrs is None:  # > 2032 channels: tags of different lengths
        ln = _varint(4 * n_s)
        cols = [_varint(((CHANNEL_FIELD_BASE + k) << 3) | 2) + ln + d[:, k].tobytes() for k in range(n_c)]
        return head + b"".join(cols)
    stride = h + 4 * n_s
    out = np.empty(len(head) + n_c * stride, np.uint8)
    out[: len(head)] = np.frombuffer(head, np.uint8)
    np.ndarray((n_c, h), np.uint8, buffer=out, offset=len(head), strides=(stride, 1))[...] = hdrs
    np.ndarray((n_c, n_s), "<f4", buffer=out, offset=len(head) + h, strides=(stride, 4))[...] = d.T
    return out.tobytes()


@dataclass(frozen=True)
class DecodedBlock:
    stream: str
    first_index: int
    sample_rate: float
    #: float32 (n_samples, n_channels); format 2: a C-contiguous copy (decoded with ``view``: a transposed view of
    #: the message); format 1: a read-only C-contiguous view of the message
    data: np.ndarray
    status: int
    t0_ns: int


def _read_varint(buf: memoryview, pos: int) -> tuple[int, int]:
    result = 0
    shift = 0
    while True:
        if pos >= len(buf):
            raise BlockDecodeError("truncated varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise BlockDecodeError("varint too long")


def _signed(v: int) -> int:
    return v - (1 << 64) if v >= 1 << 63 else v


def _channels_fast(buf: memoryview, pos: int, n_c: int, n_s: int, view: bool = False) -> np.ndarray | None:
    """The usual case, checked rather than assumed: channels 0..n_c-1 in order, each exactly n_s samples,
    up to the end of the message (what encode_block and protobuf libraries write). One transposing copy, or
    none with ``view`` (the caller copies it where it wants it)."""
    if n_c <= 0 or n_s <= 0 or n_c > MAX_CHANNELS or 4 * n_s * n_c > len(buf) - pos:
        return None  # also keeps a hostile n_channels / n_samples from sizing anything
    h, hdrs = _channel_headers(n_c, n_s)
    stride = h + 4 * n_s
    if hdrs is None or pos + n_c * stride != len(buf):
        return None
    if not (np.ndarray((n_c, h), np.uint8, buffer=buf, offset=pos, strides=(stride, 1)) == hdrs).all():  # same shape
        return None
    cols = np.ndarray((n_c, n_s), "<f4", buffer=buf, offset=pos + h, strides=(stride, 4))
    return cols.T if view else np.ascontiguousarray(cols.T)


def _assemble(chans: dict[int, memoryview | list[float]], n_c: int, n_s: int) -> np.ndarray:
    """Channel fields in any order or encoding (packed or not) into (n_s, n_c): the slow, general path."""
    if n_c == 0:
        raise BlockDecodeError("n_channels missing")
    if len(chans) != n_c or min(chans) != 0 or max(chans) != n_c - 1:
        raise BlockDecodeError(f"channel fields {sorted(chans)[:8]} for a {n_c}-channel block")
    cols = {k: np.frombuffer(v, "<f4") if isinstance(v, memoryview) else np.asarray(v, "<f4") for k, v in chans.items()}
    for k, col in cols.items():  # before allocating: n_samples comes from the message
        if col.size != n_s:
            raise BlockDecodeError(f"channel {k} has {col.size} samples, the block {n_s}")
    out = np.empty((n_s, n_c), np.float32)
    for k, col in cols.items():
        out[:, k] = col
    return out


def decode_block(raw: bytes | memoryview, view: bool = False) -> DecodedBlock:
    """Parse either layout schema-free by field numbers (field order free, unknown fields skipped).

    Format 2: fields 16.. are channels, returned as one C-contiguous copy (``view``: a transposed view of ``raw``,
    for a reader that copies it into its result). Format 1: field 6 is the row-major payload, a read-only view."""
    buf = memoryview(raw).cast("B")
    pos = 0
    stream, first_index, fs, n_c, n_s, status, t0 = "", 0, 0.0, 0, 0, 0, 0
    data_bytes: memoryview | None = None
    unpacked: list[float] = []
    chans: dict[int, memoryview | list[float]] = {}
    fast: np.ndarray | None = None
    while pos < len(buf):
        start = pos
        key, pos = _read_varint(buf, pos)
        field, wire = key >> 3, key & 7
        if field >= CHANNEL_FIELD_BASE and not chans and fast is None and data_bytes is None:
            fast = _channels_fast(buf, start, n_c, n_s, view)
            if fast is not None:
                break
        if wire == 0:
            val, pos = _read_varint(buf, pos)
            if field == 2:
                first_index = _signed(val)
            elif field == 4:
                n_c = val
            elif field == 5:
                n_s = val
            elif field == 7:
                status = val
            elif field == 8:
                t0 = _signed(val)
        elif wire == 1:
            if pos + 8 > len(buf):
                raise BlockDecodeError("truncated double")
            if field == 3:
                fs = struct.unpack_from("<d", buf, pos)[0]
            pos += 8
        elif wire == 2:
            ln, pos = _read_varint(buf, pos)
            if pos + ln > len(buf):
                raise BlockDecodeError("truncated length-delimited field")
            if field == 1:
                stream = bytes(buf[pos : pos + ln]).decode("utf-8", errors="replace")
            elif field == 6:
                if data_bytes is not None:
                    raise BlockDecodeError("data field repeated")
                data_bytes = buf[pos : pos + ln]
            elif field >= CHANNEL_FIELD_BASE:
                if field - CHANNEL_FIELD_BASE in chans:
                    raise BlockDecodeError(f"channel field {field} repeated")
                if ln % 4:
                    raise BlockDecodeError(f"channel field {field}: length is not a multiple of 4")
                chans[field - CHANNEL_FIELD_BASE] = buf[pos : pos + ln]
            pos += ln
        elif wire == 5:
            pos = _fixed32(buf, pos, field, unpacked, chans)
        else:
            raise BlockDecodeError(f"unsupported wire type {wire}")
    return DecodedBlock(stream, first_index, fs, _block_array(fast, chans, data_bytes, unpacked, n_c, n_s), status, t0)


def _fixed32(buf: memoryview, pos: int, field: int, unpacked: list[float], chans: dict) -> int:
    """One unpacked float (legal protobuf, never written by us) of format 1's data or of a channel."""
    if pos + 4 > len(buf):
        raise BlockDecodeError("truncated fixed32")
    if field == 6:
        unpacked.append(struct.unpack_from("<f", buf, pos)[0])
    elif field >= CHANNEL_FIELD_BASE:
        col = chans.setdefault(field - CHANNEL_FIELD_BASE, [])
        if not isinstance(col, list):
            raise BlockDecodeError(f"channel field {field} both packed and unpacked")
        col.append(struct.unpack_from("<f", buf, pos)[0])
    return pos + 4


def _block_array(
    fast: np.ndarray | None, chans: dict, data_bytes: memoryview | None, unpacked: list[float], n_c: int, n_s: int
) -> np.ndarray:
    if fast is not None:
        return fast
    if chans:
        if data_bytes is not None or unpacked:
            raise BlockDecodeError("both the row-major data field and channel fields")
        return _assemble(chans, n_c, n_s)
    if data_bytes is not None:
        if len(data_bytes) % 4:
            raise BlockDecodeError("data length is not a multiple of 4")
        arr = np.frombuffer(data_bytes, dtype="<f4")
    else:
        arr = np.asarray(unpacked, dtype="<f4")
    if n_c == 0 and arr.size:
        raise BlockDecodeError("n_channels missing")
    if arr.size != n_s * n_c:
        raise BlockDecodeError(f"{arr.size} samples for a {n_s} x {n_c} block")
    return arr.reshape(n_s, n_c) if n_c else arr.reshape(0, 0)


def encode_block_f1(
    stream: str, first_index: int, sample_rate: float, data: np.ndarray, status: int = 0, t0_ns: int = 0
) -> bytes:
    """Format 1's row-major layout (one ``data = 6`` field): for tests and the benchmark's same-run baseline."""
    d = np.ascontiguousarray(data, dtype="<f4")
    n_s, n_c = d.shape
    s = stream.encode("utf-8")
    payload = d.tobytes()
    parts = [
        b"\x0a", _varint(len(s)), s,
        b"\x10", _varint(int(first_index)),
        b"\x19", struct.pack("<d", float(sample_rate)),
        b"\x20", _varint(n_c),
        b"\x28", _varint(n_s),
        b"\x32", _varint(len(payload)), payload,
        b"\x38", _varint(int(status)),
        b"\x40", _varint(int(t0_ns)),
    ]  # fmt: skip
    return b"".join(parts)
