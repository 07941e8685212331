"""The preview topic: per-channel min and max of every sample stream, one message per bucket of samples.

Why (issue 31, docs/log-format.md "Preview topic", decisions D87-D88): a sample block is an array per channel, so a
viewer that plots message fields over time (rerun's Time series view, Foxglove's Plot panel) sees one array per
message, not a signal. A preview message holds one *scalar* per channel and statistic, stamped with its bucket's
first sample, so ``/preview/dev0`` is a plottable series per channel in both viewers, with no gvtlink code:

    message Preview_<stream> {                 // package gvtlink; protobuf, FileDescriptorSet in the file
      sfixed64 first_index = 1;                // the bucket's first sample on the stream's device index
      fixed32 n_samples = 2;                   // samples in it: BUCKET, fewer at a block edge off the bucket grid
      float <field>_min = 16 + 2k; float <field>_max = 17 + 2k;      // channel k
    }

The min/max envelope is what an oscilloscope's peak-detect shows: a hammer pulse or a clipped sample is in it
even when the bucket is wider than the pulse. No mean (decisions D88): it is not on the ADC's grid, so zstd
cannot shrink it as it shrinks the samples and the min/max (a third more bytes, +1.5 % of the file), and a
third reduction over every sample; the envelope's middle shows the slow part of a signal well enough.

Buckets are ``BUCKET`` samples on the stream's own index grid (bucket j holds samples [j*BUCKET, (j+1)*BUCKET)),
whatever the rate: the preview then costs the same share of the samples at every rate — 2 values of 6 bytes on
the wire per channel per 256 samples of 4 bytes, 1.2 % before compression, 3.3 % of the compressed file at 64 ch
x 51.2 kHz — and a slow stream (256 Hz) is not inflated by a fixed time bucket. In time it is 5 ms at 51.2 kHz,
15.6 ms at 16384 Hz, 1 s at 256 Hz. A 1 ms bucket (51 samples at 51.2 kHz) misses the 5 % goal
(bench/bench_preview.py measures both).

Encoding is vectorised over a whole block: every message of a stream has the same length (fixed-width fields),
so one template is broadcast to (n_buckets, length) bytes and the values are written through strided views,
as ``daq.log.proto.encode_block`` writes samples. No per-sample Python.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from google.protobuf import descriptor_pb2

from daq.log.proto import _varint, block_schema_name, field_names

#: samples per preview bucket (module docstring: a fixed share of the samples at every rate)
BUCKET = 256
PREVIEW_SCHEMA = "gvtlink.Preview"
STATS = ("min", "max")
FIELD_BASE = 16  # channel k's statistics are fields 16 + 2k and 17 + 2k
#: protobuf reserves field numbers 19000-19999: a stream with more channels than fit below them gets no preview
MAX_PREVIEW_CHANNELS = (19000 - FIELD_BASE) // len(STATS)


def preview_schema_name(stream: str) -> str:
    """``gvtlink.Preview_<stream>`` (the stream part made an identifier as the block schema's is)."""
    return PREVIEW_SCHEMA + block_schema_name(stream)[len("gvtlink.SampleBlock") :]


def preview_fields(channels: Sequence[str]) -> list[str]:
    """``<channel field>_min, _max`` per channel, in field order. The channel part is the block schema's field
    name (``daq.log.proto.field_names``: unique, also as protobuf JSON names), so the suffixed names are unique too:
    two names that differ in their base differ after the same suffix, and the suffixes differ in their last letter."""
    return [f"{f}_{s}" for f in field_names(channels) for s in STATS]


def preview_schema(stream: str, channels: Sequence[str]) -> tuple[str, bytes]:
    """(schema name, FileDescriptorSet bytes) of ``stream``'s preview message."""
    if len(channels) > MAX_PREVIEW_CHANNELS:
        raise ValueError(f"stream {stream!r}: {len(channels)} channels, a preview message holds at most {MAX_PREVIEW_CHANNELS}")
    name = preview_schema_name(stream)
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name=f"gvtlink/{name}.proto", package="gvtlink", syntax="proto3")
    msg = fdp.message_type.add(name=name.split(".", 1)[1])
    msg.field.add(name="first_index", number=1, type=F.TYPE_SFIXED64, label=F.LABEL_OPTIONAL)
    msg.field.add(name="n_samples", number=2, type=F.TYPE_FIXED32, label=F.LABEL_OPTIONAL)
    for i, fname in enumerate(preview_fields(channels)):
        msg.field.add(name=fname, number=FIELD_BASE + i, type=F.TYPE_FLOAT, label=F.LABEL_OPTIONAL)
    return name, descriptor_pb2.FileDescriptorSet(file=[fdp]).SerializeToString()


@dataclass(frozen=True)
class Buckets:
    """The statistics of a block's buckets: ``first`` (int64, n) the buckets' first samples, ``count`` (n) their
    sizes, ``stats`` float32 (n, n_channels, len(STATS)): min, max."""

    first: np.ndarray
    count: np.ndarray
    stats: np.ndarray


def _tree(part: np.ndarray, op: np.ufunc) -> np.ndarray:
    """``op`` reduced over axis 1 of (n_buckets, bucket, n_channels) by halving: log2(bucket) elementwise ops on
    large contiguous slices. Why not ``part.min(axis=1)``: measured here (thread CPU, 64 ch x 1024-sample block,
    min and max) 55-58 us against 64-70 us, and 100 us with ``out=`` a strided view; the preview must stay a few %
    of the writer's time."""
    x = part
    while x.shape[1] > 1:
        h = x.shape[1] // 2
        y = op(x[:, :h], x[:, h : 2 * h])
        if x.shape[1] % 2:
            y[:, 0] = op(y[:, 0], x[:, 2 * h])
        x = y
    return x[:, 0]


def _reduce(part: np.ndarray) -> np.ndarray:
    """(n_buckets, bucket, n_channels) -> (n_buckets, n_channels, len(STATS)): exact (min and max are samples)."""
    out = np.empty((part.shape[0], part.shape[2], len(STATS)), np.float32)
    for j, s in enumerate(STATS):
        out[:, :, j] = _tree(part, _OPS[s])
    return out


_OPS = {"min": np.minimum, "max": np.maximum}


def bucket_stats(first_index: int, data: np.ndarray, bucket: int = BUCKET) -> Buckets:
    """Min and max per channel of each bucket of ``data`` (float32 (n_samples, n_channels), first sample at
    ``first_index``), buckets on the stream's grid of ``bucket`` samples: a block that does not start or end on
    the grid has a short first or last bucket (``count`` says so). Whole buckets are one reshape and two reductions."""
    d = np.asarray(data, dtype=np.float32)
    n, n_c = d.shape
    head = min((-int(first_index)) % bucket, n)
    if 0 < n_c < REDUCEAT_BELOW and n:
        return _by_reduceat(int(first_index), d, head, bucket)
    n_full = (n - head) // bucket
    tail = n - head - n_full * bucket
    if head == 0 and tail == 0 and n_full:  # a block on the grid (the usual case): one reshape, no concatenation
        first = first_index + bucket * np.arange(n_full, dtype=np.int64)
        return Buckets(first, np.full(n_full, bucket, np.int64), _reduce(d.reshape(n_full, bucket, n_c)))
    if n == 0 or n_c == 0:
        return Buckets(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, n_c, len(STATS)), np.float32))
    firsts, counts, parts = [], [], []
    if head:
        firsts.append([first_index])
        counts.append([head])
        parts.append(_reduce(d[None, :head]))
    if n_full:
        firsts.append(first_index + head + bucket * np.arange(n_full, dtype=np.int64))
        counts.append(np.full(n_full, bucket))
        parts.append(_reduce(d[head : head + n_full * bucket].reshape(n_full, bucket, n_c)))
    if tail:
        firsts.append([first_index + n - tail])
        counts.append([tail])
        parts.append(_reduce(d[None, n - tail :]))
    return Buckets(np.concatenate(firsts).astype(np.int64), np.concatenate(counts).astype(np.int64), np.concatenate(parts))


#: below this many channels a block's buckets are reduced by ``ufunc.reduceat`` (one call per statistic, any alignment);
#: from it on by :func:`_tree` (thread CPU per block of 1408 samples off the grid, min and max: 15 ch 44 us against
#: 111, 4 ch 20 against 99, 64 ch 210 against 130 — a wide row favours the tree's elementwise halving)
REDUCEAT_BELOW = 32


def _by_reduceat(first_index: int, d: np.ndarray, head: int, bucket: int) -> Buckets:
    """:func:`bucket_stats` for a narrow block: the buckets' starts (a short head first when the block begins off the
    grid; the last bucket ends with the block) and a ``reduceat`` per statistic. Exact: min and max are samples."""
    n = d.shape[0]
    starts = np.arange(head, n, bucket, dtype=np.int64)
    if head:
        starts = np.concatenate(([0], starts))
    out = np.empty((len(starts), d.shape[1], len(STATS)), np.float32)
    for j, s in enumerate(STATS):
        out[:, :, j] = _OPS[s].reduceat(d, starts, axis=0)
    return Buckets(first_index + starts, np.diff(starts, append=n), out)


class PreviewEncoder:
    """Serialises a stream's buckets, all messages of one fixed length: a template row broadcast to every bucket,
    then ``first_index``, ``n_samples`` and the values written through strided views (runs of fields whose tags
    have the same length: 2 bytes for fields 16..2047, 3 bytes above)."""

    def __init__(self, n_channels: int) -> None:
        self.n_values = len(STATS) * n_channels
        parts: list[bytes] = [b"\x09", bytes(8), b"\x15", bytes(4)]  # first_index (sfixed64), n_samples (fixed32)
        self._runs: list[tuple[int, int, int, int]] = []  # (offset of the first value, stride, first value, count)
        pos = 14
        for i in range(self.n_values):
            tag = _varint(((FIELD_BASE + i) << 3) | 5)
            if self._runs and self._runs[-1][1] == len(tag) + 4:
                off, stride, v0, cnt = self._runs[-1]
                self._runs[-1] = (off, stride, v0, cnt + 1)
            else:
                self._runs.append((pos + len(tag), len(tag) + 4, i, 1))
            parts += [tag, bytes(4)]
            pos += len(tag) + 4
        self.length = pos
        self._template = np.frombuffer(b"".join(parts), np.uint8)

    def encode(self, b: Buckets) -> list[bytes]:
        """One serialised message per bucket of ``b``."""
        n = len(b.first)
        if n == 0:
            return []
        out = np.empty((n, self.length), np.uint8)
        out[:] = self._template
        np.ndarray((n,), "<i8", buffer=out, offset=1, strides=(self.length,))[...] = b.first
        np.ndarray((n,), "<u4", buffer=out, offset=10, strides=(self.length,))[...] = b.count
        vals = b.stats.reshape(n, self.n_values)
        for off, stride, v0, cnt in self._runs:
            np.ndarray((n, cnt), "<f4", buffer=out, offset=off, strides=(self.length, stride))[...] = vals[:, v0 : v0 + cnt]
        raw = out.tobytes()
        L = self.length
        return [raw[i * L : (i + 1) * L] for i in range(n)]

