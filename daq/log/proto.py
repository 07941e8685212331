"""Protobuf schema of a sample block, and a fast codec for it.

The schema is stored in every log as a FileDescriptorSet, so MCAP tools and Foxglove decode blocks
without gvtlink. The data field is a packed ``repeated float``: its payload on the wire is exactly the
little-endian float32 samples, so encoding and decoding here are a header plus one memory copy
(``np.frombuffer``), while any protobuf library reads the same bytes (tests check both ways).

    message SampleBlock {
      string stream = 1; int64 first_index = 2; double sample_rate = 3;
      uint32 n_channels = 4; uint32 n_samples = 5; repeated float data = 6 [packed];  // row-major
      uint32 status = 7; int64 t0_ns = 8;  // stream start, ns since the Unix epoch
    }
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from google.protobuf import descriptor_pb2

from daq.log.layout import SAMPLE_BLOCK_SCHEMA


class BlockDecodeError(ValueError):
    """A sample-block message is malformed."""


@lru_cache(maxsize=1)
def sample_block_descriptor_set() -> bytes:
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="gvtlink/sample_block.proto", package="gvtlink", syntax="proto3")
    msg = fdp.message_type.add(name="SampleBlock")
    for name, number, typ, label in [
        ("stream", 1, F.TYPE_STRING, F.LABEL_OPTIONAL),
        ("first_index", 2, F.TYPE_INT64, F.LABEL_OPTIONAL),
        ("sample_rate", 3, F.TYPE_DOUBLE, F.LABEL_OPTIONAL),
        ("n_channels", 4, F.TYPE_UINT32, F.LABEL_OPTIONAL),
        ("n_samples", 5, F.TYPE_UINT32, F.LABEL_OPTIONAL),
        ("data", 6, F.TYPE_FLOAT, F.LABEL_REPEATED),
        ("status", 7, F.TYPE_UINT32, F.LABEL_OPTIONAL),
        ("t0_ns", 8, F.TYPE_INT64, F.LABEL_OPTIONAL),
    ]:
        msg.field.add(name=name, number=number, type=typ, label=label)
    msg.field[5].options.packed = True
    return descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString()


SCHEMA_NAME = SAMPLE_BLOCK_SCHEMA


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


def encode_block(stream: str, first_index: int, sample_rate: float, data: np.ndarray, status: int = 0, t0_ns: int = 0) -> bytes:
    """Serialise one block (``data`` float32, shape (n_samples, n_channels))."""
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


@dataclass(frozen=True)
class DecodedBlock:
    stream: str
    first_index: int
    sample_rate: float
    data: np.ndarray  # float32 (n_samples, n_channels), read-only view of the message bytes
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


def decode_block(raw: bytes | memoryview) -> DecodedBlock:
    """Parse any valid encoding of the schema (field order free, unknown fields skipped)."""
    buf = memoryview(raw)
    pos = 0
    stream = ""
    first_index = 0
    fs = 0.0
    n_c = n_s = 0
    status = 0
    t0 = 0
    data_bytes: memoryview | None = None
    unpacked: list[float] = []
    while pos < len(buf):
        key, pos = _read_varint(buf, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            val, pos = _read_varint(buf, pos)
            if field == 2:
                first_index = val - (1 << 64) if val >= 1 << 63 else val
            elif field == 4:
                n_c = val
            elif field == 5:
                n_s = val
            elif field == 7:
                status = val
            elif field == 8:
                t0 = val - (1 << 64) if val >= 1 << 63 else val
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
                data_bytes = buf[pos : pos + ln] if data_bytes is None else None
                if data_bytes is None:
                    raise BlockDecodeError("data field repeated")
            pos += ln
        elif wire == 5:
            if pos + 4 > len(buf):
                raise BlockDecodeError("truncated fixed32")
            if field == 6:  # unpacked repeated float (legal protobuf)
                unpacked.append(struct.unpack_from("<f", buf, pos)[0])
            pos += 4
        else:
            raise BlockDecodeError(f"unsupported wire type {wire}")
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
    return DecodedBlock(stream, first_index, fs, arr.reshape(n_s, n_c) if n_c else arr.reshape(0, 0), status, t0)
