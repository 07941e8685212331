"""read_stream returns exactly what was written (issue 28: each block is now copied once, from its verified chunk
straight into the result): every bit, every index, gap and status, across block sizes, channel counts, channel
selections, time windows, both block layouts, and logs whose blocks are out of order, duplicated or overlapping.

The reference is computed the plain way, independently of read_stream's path: every block through mcap's own
reader and ``decode_block`` (a copy), sorted by first index, a block overlapping the one kept before it dropped.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from daq.log.proto import block_schema, decode_block, encode_block, encode_block_f1
from daq.log.reader import LogReader
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import BlockStatus, SampleBlock

FS = 2048.0
T0 = 1_700_000_000_000_000_000


def _data(n: int, n_ch: int, seed: int = 7) -> np.ndarray:
    """float32 samples whose bits matter: signed zero, ±inf (a clipped ADC), subnormals, a value near the 1e30 cap."""
    d = np.random.default_rng(seed).standard_normal((n, n_ch)).astype(np.float32)
    specials = np.array([-0.0, np.inf, -np.inf, 1e-42, -1e-45, 9.9e29, -9.9e29], np.float32)
    d.flat[: min(d.size, specials.size)] = specials[: d.size]
    return d


def _reference(path: Path, sel: list[int] | None = None) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]], np.ndarray]:
    """(index, data, gaps, statuses) of stream dev0 read the plain way: mcap's reader, a decoded copy per block."""
    blocks = []
    with open(path, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/daq/dev0/samples"], log_time_order=True):
            blocks.append(decode_block(bytes(m.data)))
    blocks.sort(key=lambda b: b.first_index)  # stable: the block read first wins a tie
    kept, reach = [], None
    for b in blocks:
        if reach is None or b.first_index >= reach:
            kept.append(b)
            reach = b.first_index + b.data.shape[0]
    index = np.concatenate([np.arange(b.first_index, b.first_index + b.data.shape[0]) for b in kept])
    data = np.concatenate([np.array(b.data) for b in kept])
    gaps = [(a.first_index + a.data.shape[0], b.first_index) for a, b in itertools.pairwise(kept)]
    statuses = np.array([b.status for b in kept], np.uint32)
    return index, data if sel is None else data[:, sel], [g for g in gaps if g[1] > g[0]], statuses


def _write(path: Path, sizes: list[int], n_ch: int, skip: set[int] = frozenset(), **kw) -> np.ndarray:
    """A LogWriter log of blocks of ``sizes`` samples (block k left out when k in ``skip``: a gap); all samples."""
    total = _data(sum(sizes), n_ch)
    chans = [ChannelInfo(f"c{k}", "acceleration", "m/s^2", 1.0) for k in range(n_ch)]
    names = tuple(c.name for c in chans)
    with LogWriter(path, **kw) as w:
        w.add_stream("dev0", chans, FS, t0_ns=T0)
        at = 0
        for k, n in enumerate(sizes):
            if k not in skip:
                w.write_block(SampleBlock("dev0", at, FS, names, total[at : at + n], status=BlockStatus(k % 3)), wait=True)
            at += n
    return total


def _assert_same(d, ref) -> None:
    index, data, gaps, statuses = ref
    assert d.data.dtype == np.float32 and d.data.flags.c_contiguous and d.data.flags.writeable
    assert d.data.shape == data.shape and d.data.tobytes() == data.tobytes()
    assert d.index.dtype == np.int64 and np.array_equal(d.index, index)
    assert d.gaps == gaps and np.array_equal(d.block_status, statuses) and d.damaged == []


@pytest.mark.parametrize("n_ch", [1, 3, 64])
@pytest.mark.parametrize("block", [1, 7, 256, 4096, 5000])  # 4096: a 3-byte length varint in each channel's header
def test_read_stream_is_bit_identical_across_block_sizes_and_channel_counts(tmp_path, n_ch, block):
    p = tmp_path / "log.mcap"
    n_blocks = max(3, min(40, 20_000 // block))
    total = _write(p, [block] * n_blocks, n_ch, chunk_size=64 * 1024)  # several chunks
    d = LogReader(p).read_stream("dev0")
    assert d.data.tobytes() == total.tobytes() and np.array_equal(d.index, np.arange(len(total)))
    _assert_same(d, _reference(p))
    sel = [n_ch - 1, 0] if n_ch > 1 else [0]
    ds = LogReader(p).read_stream("dev0", [f"c{k}" for k in sel])
    assert ds.data.flags.c_contiguous and ds.data.tobytes() == np.ascontiguousarray(total[:, sel]).tobytes()


def test_varying_block_sizes_gaps_and_windows(tmp_path):
    p = tmp_path / "log.mcap"
    sizes = [100, 1, 2048, 300, 77, 1024, 1024, 5, 4000, 9]
    total = _write(p, sizes, 5, skip={3, 7}, chunk_size=16 * 1024)
    _assert_same(LogReader(p).read_stream("dev0"), _reference(p))
    idx = np.arange(len(total))
    kept = np.ones(len(total), bool)
    ends = np.cumsum(sizes)
    for k in (3, 7):
        kept[ends[k] - sizes[k] : ends[k]] = False
    for start, end in [(None, 1.0), (0.5, None), (0.1, 0.2), (1.0, 4.0), (0.001, 0.0015), (2.0, 1.0), (-1.0, 100.0)]:
        d = LogReader(p).read_stream("dev0", ["c3", "c1"], start=start, end=end)
        t = idx / FS
        m = kept & (t >= (-np.inf if start is None else start)) & (t < (np.inf if end is None else end))
        assert np.array_equal(d.index, idx[m]) and d.data.tobytes() == np.ascontiguousarray(total[m][:, [3, 1]]).tobytes()
        assert d.data.flags.c_contiguous


def test_more_channels_than_fit_two_byte_tags(tmp_path):
    """Over 2032 channels the fields' tags differ in length: the general decoder, the same result."""
    p = tmp_path / "wide.mcap"
    total = _write(p, [16] * 5, 2100)
    _assert_same(LogReader(p).read_stream("dev0"), _reference(p))
    assert LogReader(p).read_stream("dev0").data.tobytes() == total.tobytes()


def _raw_log(path: Path, blocks: list[tuple[int, int, int]], n_ch: int, layout: int = 2) -> np.ndarray:
    """A log written record by record: blocks (first_index, n_samples, log position) in that order, several
    chunks; sample i of the stream is row i of the returned array wherever a block holding it is."""
    truth = _data(max(f + n for f, n, _ in blocks), n_ch, seed=11)
    names = [f"c{k}" for k in range(n_ch)]
    md = {
        "stream": "dev0",
        "sample_rate": repr(FS),
        "t0_ns": str(T0),
        "channels": json.dumps(names),
        "units": json.dumps(["m"] * n_ch),
    }
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=8 * 1024, compression=CompressionType.ZSTD)
        w.start(profile="gvtlink", library="test")
        name, fds, _fields = block_schema("dev0", names)
        cid = w.register_channel("/daq/dev0/samples", "protobuf", w.register_schema(name, "protobuf", fds), md)
        enc = encode_block if layout == 2 else encode_block_f1
        for seq, (first, n, pos) in enumerate(blocks):
            lt = T0 + round(pos * 1e9 / FS)
            w.add_message(
                cid,
                log_time=lt,
                data=enc("dev0", first, FS, truth[first : first + n], seq % 5, T0),
                publish_time=lt,
                sequence=seq,
            )
        w.finish()
    return truth


@pytest.mark.parametrize("layout", [1, 2])
def test_out_of_order_duplicated_and_overlapping_blocks(tmp_path, layout):
    """Blocks logged out of sample order, a block twice, one overlapping its neighbour: sorted, each sample once."""
    p = tmp_path / "messy.mcap"
    blocks = [(k * 64, 64, k * 64) for k in range(60)]
    blocks[10], blocks[12] = (12 * 64, 64, 10 * 64), (10 * 64, 64, 12 * 64)  # swapped, logged where the other was
    blocks.insert(30, (29 * 64, 64, 29 * 64 + 1))  # a duplicate
    blocks.insert(40, (38 * 64 + 10, 64, 38 * 64 + 2))  # overlaps block 38: dropped
    blocks = [b for b in blocks if b[0] != 50 * 64]  # a gap
    truth = _raw_log(p, blocks, 4, layout)
    ref = _reference(p)
    _assert_same(LogReader(p).read_stream("dev0"), ref)
    index = ref[0]
    assert np.array_equal(index, np.concatenate([np.arange(50 * 64), np.arange(51 * 64, 60 * 64)]))
    assert LogReader(p).read_stream("dev0").data.tobytes() == truth[index].tobytes()
    d = LogReader(p).read_stream("dev0", ["c2"], start=700 / FS, end=3300 / FS)
    m = (index >= 700) & (index < 3300)
    assert np.array_equal(d.index, index[m]) and d.data.tobytes() == np.ascontiguousarray(truth[index[m]][:, [2]]).tobytes()
    assert d.gaps == [(50 * 64, 51 * 64)]


def test_a_large_first_block_does_not_size_the_result_for_every_block(tmp_path):
    """The result array is sized from the first block times the block count, but never beyond what the chunks hold:
    a 60000-sample block followed by 2000 one-sample blocks is not 120 M rows."""
    import tracemalloc

    p = tmp_path / "uneven.mcap"
    blocks = [(0, 60_000, 0)] + [(60_000 + k, 1, 60_000 + k) for k in range(2000)]
    truth = _raw_log(p, blocks, 2)
    tracemalloc.start()
    d = LogReader(p).read_stream("dev0")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert d.data.tobytes() == truth.tobytes() and np.array_equal(d.index, np.arange(62_000))
    assert peak < 20 * truth.nbytes  # 120 M rows of 2 channels would be 960 MB
