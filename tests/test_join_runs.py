"""The device source's joined blocks (drivers/blocks.py ``join_runs``, issue 30 item 5): fewer blocks, nothing lost,
no flag moved off the sample it speaks of."""

from __future__ import annotations

import numpy as np

from drivers.blocks import BlockStatus, SampleBlock, join_runs

CH = ("a", "b")


def _blk(first: int, n: int, status: BlockStatus = BlockStatus.OK, stream: str = "s") -> SampleBlock:
    data = (np.arange(first, first + n, dtype=np.float32)[:, None] * np.array([1.0, -1.0], np.float32)).astype(np.float32)
    return SampleBlock(stream, first, 100.0, CH, data, status, {"k": first})


def _spans(blocks: list[SampleBlock]) -> list[tuple[int, int, int]]:
    return [(b.first_index, b.end_index, int(b.status)) for b in blocks]


def test_contiguous_flag_free_frames_become_one_block_with_every_sample():
    frames = [_blk(64 * k, 64) for k in range(13)]  # 13 serial frames: one join_s batch at 16384 Hz
    out = list(join_runs(frames, 4096))
    assert _spans(out) == [(0, 832, 0)]
    # every sample in order, per channel (the oracle is the index ramp the frames were built from)
    np.testing.assert_array_equal(out[0].data[:, 0], np.arange(832, dtype=np.float32))
    np.testing.assert_array_equal(out[0].data[:, 1], -np.arange(832, dtype=np.float32))
    assert out[0].extra == {"k": 0}


def test_flags_keep_their_samples_and_gaps_split():
    gap = BlockStatus.GAP_BEFORE
    crc = BlockStatus.CRC_ERROR
    frames = [_blk(0, 64), _blk(64, 64), _blk(200, 64, gap), _blk(264, 64), _blk(328, 64, crc), _blk(392, 64),
              _blk(456, 64, BlockStatus.CLIPPED), _blk(520, 64, stream="t"), _blk(584, 64, stream="t")]  # fmt: skip
    out = list(join_runs(frames, 4096))
    # a gap (index jump) splits; GAP_BEFORE speaks of before its first sample, so flag-free blocks join behind it;
    # CRC_ERROR and CLIPPED are of their own block's span: nothing joins them, and they join nothing
    assert _spans(out) == [(0, 128, 0), (200, 328, int(gap)), (328, 392, int(crc)), (392, 456, 0),
                           (456, 520, int(BlockStatus.CLIPPED)), (520, 648, 0)]  # fmt: skip
    assert [b.stream for b in out][-1] == "t"
    assert sum(b.n_samples for b in out) == sum(b.n_samples for b in frames)


def test_max_samples_bounds_a_joined_block_and_a_larger_block_is_never_split():
    out = list(join_runs([_blk(64 * k, 64) for k in range(10)], 256))
    assert _spans(out) == [(0, 256, 0), (256, 512, 0), (512, 640, 0)]
    big = list(join_runs([_blk(0, 1024), _blk(1024, 64)], 512))
    assert _spans(big) == [(0, 1024, 0), (1024, 1088, 0)]
