"""Foxglove can plot each channel: the sample-block layout read the way Foxglove reads it (docs/decisions.md D30).

What is tested, honestly: not Foxglove itself. An independent reader here — the plain ``mcap`` package, the
FileDescriptorSet stored in the file, ``google.protobuf``'s ``message_factory`` (not our codec) — resolves
Foxglove-style message paths ``<topic>.<field>``: a topic, one dot, one field name, no index, no slice,
no filter, no nested array. Foxglove's Plot panel in "Array index" mode plots exactly such a path's array
of the latest message; this test shows that the array is one channel's contiguous samples of the block,
and that their concatenation over all blocks is that channel as written, bit for bit.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.descriptor import FieldDescriptor
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from daq.log.proto import (
    BlockDecodeError,
    block_schema,
    decode_block,
    encode_block,
    encode_block_f1,
    field_names,
)
from daq.log.reader import LogReader
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock

FORMAT1 = Path(__file__).resolve().parent / "data" / "format1"
EXAMPLES = int(os.environ.get("GVT_FUZZ_EXAMPLES", 200))
# names that are not protobuf identifiers, or collide once made identifiers, or shadow the block's own fields
AWKWARD = ["hammer", "acc-3", "x y", "1st", "acc_3", "acc3", "status", "data", "", "acc-3", "naïve"]
_PATH = re.compile(r"^(/[A-Za-z0-9_/-]+)\.([A-Za-z_][A-Za-z0-9_]*)$")  # <topic>.<field>: nothing else


class MessagePathReader:
    """A Foxglove-compatible message-path reader over one MCAP file, independent of gvtlink's codec."""

    def __init__(self, path: Path) -> None:
        self.path = path
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None
        self.channels = {c.topic: c for c in summary.channels.values()}
        self.classes: dict[int, Any] = {}
        for sid, schema in summary.schemas.items():
            if schema.encoding != "protobuf":
                continue
            pool = descriptor_pool.DescriptorPool()
            for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                pool.Add(fd)
            self.classes[sid] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))

    def series(self, message_path: str) -> list[np.ndarray]:
        """The value of ``<topic>.<field>`` in each message, in log-time order; the field must be a flat
        repeated number (what Array-index mode plots), else AssertionError."""
        m = _PATH.match(message_path)
        assert m, f"{message_path!r} is not a plain <topic>.<field> path"
        topic, field = m.groups()
        channel = self.channels[topic]
        cls = self.classes[channel.schema_id]
        fd = cls.DESCRIPTOR.fields_by_name[field]
        assert fd.is_repeated and fd.type in (FieldDescriptor.TYPE_FLOAT, FieldDescriptor.TYPE_DOUBLE)
        out = []
        with open(self.path, "rb") as f:
            for _s, _c, msg in make_reader(f).iter_messages(topics=[topic], log_time_order=True):
                out.append(np.array(getattr(cls.FromString(msg.data), field), dtype=np.float32))
        return out

    def scalar(self, message_path: str) -> list[float]:
        topic, field = _PATH.match(message_path).groups()  # type: ignore[union-attr]
        cls = self.classes[self.channels[topic].schema_id]
        with open(self.path, "rb") as f:
            return [getattr(cls.FromString(msg.data), field) for _s, _c, msg in make_reader(f).iter_messages(topics=[topic])]


def _write(path: Path, streams: dict[str, tuple[list[str], float, np.ndarray]], block: int) -> None:
    with LogWriter(path) as w:
        for s, (names, fs, _d) in streams.items():
            w.add_stream(s, [ChannelInfo(n, "acceleration", "m/s^2", 1.0) for n in names], fs, t0_ns=0)
        n_blocks = max(d.shape[0] for _n, _f, d in streams.values()) // block
        for k in range(n_blocks):
            for s, (names, fs, d) in streams.items():
                part = d[k * block : (k + 1) * block]
                if part.shape[0]:
                    assert w.write_block(SampleBlock(s, k * block, fs, tuple(names), part), wait=True)


def test_each_channel_is_a_contiguous_series_by_message_path(tmp_path: Path) -> None:
    rng = np.random.default_rng(19)
    hammer_data = rng.standard_normal((7 * 128, len(AWKWARD))).astype(np.float32)
    hammer_data[0, 0], hammer_data[1, 1] = np.float32(-0.0), np.float32(np.inf)  # bits must survive
    acc_names = ["z", "y", "x"]
    acc_data = rng.standard_normal((5 * 128, 3)).astype(np.float32)
    p = tmp_path / "fox.mcap"
    _write(p, {"dev0": (AWKWARD, 2048.0, hammer_data), "dev-1": (acc_names, 1024.0, acc_data)}, block=128)

    r = MessagePathReader(p)
    for stream, names, data in (("dev0", AWKWARD, hammer_data), ("dev-1", acc_names, acc_data)):
        topic = f"/daq/{stream}/samples"
        meta = r.channels[topic].metadata
        fields = json.loads(meta["fields"])
        assert json.loads(meta["channels"]) == names and len(set(fields)) == len(fields) == len(names)
        assert meta["layout"] == "channel-major"
        for k, f in enumerate(fields):
            blocks = r.series(f"{topic}.{f}")
            assert [b.size for b in blocks] == [128] * (data.shape[0] // 128)  # one block's waveform per message
            assert np.concatenate(blocks).tobytes() == data[:, k].tobytes(), (stream, names[k], f)
        assert r.scalar(f"{topic}.first_index") == list(range(0, data.shape[0], 128))
    # both streams' schemas are distinct (viewers key definitions by name)
    assert r.channels["/daq/dev0/samples"].schema_id != r.channels["/daq/dev-1/samples"].schema_id
    # and gvtlink's own reader reads the same file unchanged
    got = LogReader(p).read_stream("dev0")
    assert got.data.tobytes() == hammer_data.tobytes() and got.channels == AWKWARD


def test_awkward_channel_names_become_distinct_identifiers() -> None:
    f = field_names(AWKWARD)
    assert f[:4] == ["hammer", "acc_3", "x_y", "ch_1st"]
    assert f[6] == "ch_status" and f[7] == "ch_data"  # the block's own field names are not taken
    assert len(set(f)) == len(f) and all(_PATH.match(f"/t.{x}") for x in f)
    assert field_names(AWKWARD) == f  # deterministic: the same names give the same fields in every file


@settings(max_examples=EXAMPLES)
@given(st.lists(st.text(min_size=0, max_size=12), min_size=1, max_size=40))
def test_property_any_channel_names_give_a_loadable_schema(names: list[str]) -> None:
    """Any names: valid identifiers, unique (also as protobuf's JSON names), and the descriptor pool accepts them."""
    name, fds, fields = block_schema("dev0", names)
    assert len(fields) == len(names) == len(set(fields))
    assert all(_PATH.match(f"/t.{x}") for x in fields)
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
        pool.Add(fd)  # raises on duplicate names or JSON names
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    assert [f.name for f in cls.DESCRIPTOR.fields if f.number >= 16] == fields


@settings(max_examples=EXAMPLES)
@given(st.integers(0, 40), st.integers(1, 12), st.integers(-(2**62), 2**62), st.booleans())
def test_property_both_layouts_round_trip(n: int, c: int, first: int, old: bool) -> None:
    data = np.arange(n * c, dtype=np.float32).reshape(n, c) * np.float32(0.37) - 3
    enc = encode_block_f1 if old else encode_block
    b = decode_block(enc("s", first, 51200.0, data, 5, -7))
    assert (b.first_index, b.sample_rate, b.status, b.t0_ns, b.stream) == (first, 51200.0, 5, -7, "s")
    assert b.data.shape == (n, c) and b.data.dtype == np.float32 and np.array_equal(b.data, data)
    assert b.data.flags.c_contiguous  # what the reader and replay's consumers get, as before


def test_official_protobuf_encodings_decode_schema_free() -> None:
    """What another tool writes: python protobuf's own serialisation, fields out of order, unpacked floats."""
    names = ["a", "b-1", "c"]
    name, fds, fields = block_schema("dev0", names)
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    data = np.array([[1.5, -2.0, 3.25], [4.0, 5.5, -6.0]], np.float32)
    m = cls(stream="dev0", first_index=9, sample_rate=100.0, n_channels=3, n_samples=2)
    for k, f in enumerate(fields):
        getattr(m, f).extend(data[:, k].tolist())
    assert np.array_equal(decode_block(m.SerializeToString()).data, data)
    # the same block written by hand: channel fields last-to-first, channel 1 unpacked (wire type 5)
    head = encode_block("dev0", 9, 100.0, data[:0].reshape(0, 3))
    head = head.replace(b"\x20\x03\x28\x00", b"\x20\x03\x28\x02")  # n_channels 3, n_samples 2
    raw = bytearray(head)
    for k in (2, 0):
        raw += _tag(16 + k, 2) + b"\x08" + data[:, k].tobytes()
    for x in data[:, 1]:
        raw += _tag(17, 5) + x.tobytes()
    assert np.array_equal(decode_block(bytes(raw)).data, data)
    with pytest.raises(BlockDecodeError, match="channel fields"):
        decode_block(head + _tag(16, 2) + b"\x08" + data[:, 0].tobytes())  # channels 1 and 2 missing


def _tag(field: int, wire: int) -> bytes:
    """A protobuf field key as a varint (two bytes for fields 16..2047)."""
    key = field << 3 | wire
    return bytes([key & 0x7F | 0x80, key >> 7]) if key >= 0x80 else bytes([key])


@pytest.mark.parametrize("name", sorted(p.name for p in FORMAT1.glob("*.mcap")))
def test_format1_logs_still_decode(name: str) -> None:
    """Old logs (row-major field 6, one gvtlink.SampleBlock schema): decode_block equals protobuf with their own schema."""
    with open(FORMAT1 / name, "rb") as f:
        seen = 0
        for schema, _ch, msg in make_reader(f).iter_messages():
            if schema is None or schema.encoding != "protobuf" or not schema.name.startswith("gvtlink.SampleBlock"):
                continue
            pool = descriptor_pool.DescriptorPool()
            for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                pool.Add(fd)
            m = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(msg.data)
            b = decode_block(msg.data)
            want = np.array(m.data, np.float32).reshape(m.n_samples, m.n_channels)
            assert b.data.tobytes() == want.tobytes() and b.first_index == m.first_index
            seen += 1
            if seen >= 50:
                break
    assert seen > 0


@settings(max_examples=EXAMPLES)
@given(st.integers(0, 2**62), st.integers(0, 2**62), st.binary(max_size=8), st.integers(0, 400))
def test_fuzz_hostile_sizes_and_bytes_never_crash(n_c: int, n_s: int, noise: bytes, pos: int) -> None:
    """A block claiming any n_channels / n_samples, or with bytes overwritten, decodes or raises BlockDecodeError:
    the sizes in the message never size an allocation before the payload proves them."""
    good = encode_block("dev0", 3, 100.0, np.ones((6, 4), np.float32))
    forged = good.replace(b"\x20\x04\x28\x06", b"\x20" + _varint(n_c) + b"\x28" + _varint(n_s), 1)
    raw = bytearray(forged)
    p = pos % len(raw)
    raw[p : p + len(noise)] = noise
    for candidate in (forged, bytes(raw)):
        try:
            b = decode_block(candidate)
        except BlockDecodeError:
            continue
        assert b.data.dtype == np.float32 and b.data.ndim == 2 and b.data.size <= len(candidate) // 4


def _varint(n: int) -> bytes:
    out = bytearray()
    while n >= 0x80:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)
