"""The stream sequencer kernel (drivers/sequence.py): in order, gaps, duplicates, wild frames, restarts."""

from __future__ import annotations

import itertools
import os
import random
from dataclasses import dataclass, field

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.sequence import MAX_STREAM_NS, Accepted, Dropped, StreamSequencer

FS = 1000.0
WINDOW = 250  # duplicate_window_s = 0.25 s at FS
EXAMPLES = int(os.environ.get("GVT_FUZZ_EXAMPLES", 200))  # make fuzz: 200000 (make test: 200, 1.7 CPU-s: its budget)


# --- explicit cases ------------------------------------------------------------------------------
def feed_all(seq: StreamSequencer, blocks) -> list[Accepted | Dropped]:
    out = []
    for first, n, t in blocks:
        out += seq.feed(first, n, t, (first, n))
    return out + seq.finish()


def test_one_wild_frame_is_rejected_and_costs_no_good_block():
    seq = StreamSequencer(FS)
    out = feed_all(seq, [(0, 10, 0.01), (10, 10, 0.02), (10**9, 10, 0.021), (20, 10, 0.03), (2**62, 10, 0.031), (30, 10, 0.04)])
    acc = [o for o in out if isinstance(o, Accepted)]
    assert [(a.stream_first, a.n) for a in acc] == [(0, 10), (10, 10), (20, 10), (30, 10)]
    assert all(a.gap is None and a.restart is None for a in acc)
    rej = [o for o in out if isinstance(o, Dropped)]
    assert [(d.kind, d.device_first, d.stream_at) for d in rej] == [
        ("implausible_index", 10**9, 20),
        ("implausible_index", 2**62, 30),
    ]
    assert seq.counts.rejected == 2 and seq.counts.gap_samples == 0 and seq.counts.restarts == 0


def test_confirmed_restart_starts_a_new_segment_placed_by_the_host_clock():
    seq = StreamSequencer(FS)
    # old run: 0..500 produced by t = 0.5 s; down 0.3 s; the new run's sample 0 exists at 0.8 s
    out = feed_all(seq, [(0, 250, 0.25), (250, 250, 0.5), (0, 20, 0.82), (20, 20, 0.84), (40, 20, 0.86)])
    acc = [o for o in out if isinstance(o, Accepted)]
    assert [a.stream_first for a in acc] == [0, 250, 800, 820, 840]  # device 0 of the new run at 0.8 s = stream 800
    rs = acc[2].restart
    assert rs is not None and (rs.segment, rs.device_first, rs.prev_end, rs.estimated_gap) == (1, 0, 500, 300)
    assert acc[2].starts_segment and acc[3].restart is None and acc[3].segment == 1
    assert seq.counts.restarts == 1 and seq.counts.estimated_gap_samples == 300 and seq.counts.rejected == 0


def test_a_backlog_the_transport_reports_moves_the_segment_start_back():
    """A FIFO device buffered 300 samples of its new run before the first block arrived: the run began
    300 samples before that block's end, not just its 20 samples."""
    seq = StreamSequencer(FS)
    seq.feed(0, 500, 0.5)
    out = seq.feed(0, 20, 1.1, produced=300, restart=True)  # confirmed by the transport: not held
    (acc,) = out
    assert isinstance(acc, Accepted) and acc.restart is not None
    assert acc.stream_first == 500 + round((1.1 - 0.3 - 0.5) * FS)  # sample 0 existed at 1.1 - 300/fs = 0.8 s


def test_suspect_still_held_at_the_end_is_rejected():
    seq = StreamSequencer(FS)
    seq.feed(0, 10, 0.01)
    assert seq.feed(5_000_000, 10, 0.02) == [] and seq.holding
    (d,) = seq.finish()
    assert d.kind == "implausible_index" and d.device_first == 5_000_000 and seq.counts.rejected == 1 and not seq.holding


def test_duplicates_within_the_window_are_dropped_further_back_is_a_suspect():
    seq = StreamSequencer(FS)
    for k in range(4):
        seq.feed(100 * k, 100, 0.1 * (k + 1))
    (d,) = seq.feed(390, 20, 0.41)  # overlaps the end: dropped as a duplicate
    assert d.kind == "duplicate" and d.stream_first == 390 and seq.counts.duplicates == 1
    assert seq.feed(100, 20, 0.42) == []  # 300 back (> 0.25 s): held, not dropped
    out = seq.feed(400, 10, 0.43)  # the old stream goes on: the suspect was a bad frame
    assert [type(o).__name__ for o in out] == ["Dropped", "Accepted"] and out[1].gap is None


def test_gap_within_the_bound_is_exact_beyond_it_a_suspect():
    seq = StreamSequencer(FS, plausible_jump_s=1.0)
    seq.feed(0, 10, 0.01)
    (a,) = seq.feed(1010, 10, 1.02)  # 1000 samples missing over 1 s: a real gap
    assert a.gap == (10, 1010)
    assert seq.feed(1020 + 3000, 10, 1.03) == []  # 3 s ahead after 10 ms: (0.01 + 1) * 1250 + slack < 3000


def test_no_index_can_overflow_a_log_time():
    for first in (2**62, 2**64 - 1):
        joining = StreamSequencer(16384.0)  # nothing to compare with: only the log-time bound can refuse it
        (d,) = joining.feed(first, 64, 0.0)
        assert isinstance(d, Dropped) and d.kind == "implausible_index"
    seq = StreamSequencer(16384.0)
    seq.feed(0, 64, 0.0)
    seq.feed(2**62, 64, 0.01)
    out = seq.feed(2**62 + 64, 64, 0.02)  # even a confirmed re-base is placed by the host clock, not its index
    acc = [o for o in out if isinstance(o, Accepted)]
    assert acc and all(a.stream_end * 1e9 / 16384.0 < MAX_STREAM_NS for a in acc)


def test_expected_first_index_makes_early_loss_a_gap():
    seq = StreamSequencer(FS, expect_first=0, start_time=0.0)
    (a,) = seq.feed(30, 10, 0.04)
    assert a.gap == (0, 30) and a.stream_first == 30


# --- the property ----------------------------------------------------------------------------------
@dataclass
class Script:
    """A device's stream as it reaches the host, with the truth for every block.

    ``g`` is a global clock index (the sample the device would be at had it never restarted); device index
    = g - run_offset. Each block arrives when its last sample exists (+ a small latency)."""

    blocks: list[tuple[int, int, float, object]] = field(default_factory=list)  # (first, n, t, id)
    good: dict[object, tuple[int, int]] = field(default_factory=dict)  # id -> (g of first sample, run number)
    restarts: list[object] = field(default_factory=list)  # ids of the first block of each new run
    dups: int = 0
    wild: int = 0


@st.composite
def scripts(draw) -> Script:
    sc = Script()
    g = 0  # global clock index of the next sample
    dev = 0  # device index of the next sample
    run = 0
    seg_first = 0
    sent: list[tuple[int, int, object]] = []  # good blocks of the current run (first, n, id)
    uid = iter(range(10**6))

    def send_good(n: int) -> None:
        nonlocal g, dev
        i = next(uid)
        lat = draw(st.integers(0, 2)) / FS
        sc.blocks.append((dev, n, (g + n) / FS + lat, i))
        sc.good[i] = (g, run)
        sent.append((dev, n, i))
        g += n
        dev += n

    send_good(draw(st.integers(1, 40)))
    last_wild = False
    for _ in range(draw(st.integers(1, 60))):
        kind = draw(st.sampled_from(["ok", "ok", "ok", "gap", "dup", "wild", "restart", "rebase"]))
        if kind == "wild" and last_wild:
            continue  # two wild frames in a row that continue each other ARE a re-base; keep them single
        last_wild = kind == "wild"
        t_now = sc.blocks[-1][2]
        if kind == "gap":
            k = draw(st.integers(1, 400))
            g += k
            dev += k
        elif kind == "dup":
            recent = [b for b in sent if b[0] >= dev - WINDOW and b[0] >= seg_first]
            if recent:
                first, n, _ = draw(st.sampled_from(recent))
                sc.blocks.append((first, n, t_now, ("dup", next(uid))))
                sc.dups += 1
            continue
        elif kind == "wild":
            n = draw(st.integers(1, 40))
            # never continued by what may follow (a restart at 0..50, a re-base at dev + 10^8 or more)
            choices = [dev + 10**7 + draw(st.integers(0, 10**7)), 2**62, 2**64 - n]
            if dev > WINDOW + 2000:
                choices.append(draw(st.integers(100, dev - WINDOW - 1100)))
            sc.blocks.append((draw(st.sampled_from(choices)), n, t_now, ("wild", next(uid))))
            sc.wild += 1
            continue
        elif kind in ("restart", "rebase"):
            first0 = draw(st.integers(0, 50)) if kind == "restart" else dev + 10**8 + draw(st.integers(0, 10**6))
            if kind == "restart" and dev < first0 + WINDOW + 100:
                continue  # too early to tell from a duplicate by its index alone (see the module docstring)
            if kind == "restart":
                g += draw(st.integers(0, 2000))  # down time, in samples of the global clock
            run += 1
            dev = seg_first = first0
            sent = []
            send_good(draw(st.integers(1, 40)))
            sc.restarts.append(sc.blocks[-1][3])
        send_good(draw(st.integers(1, 40)))  # ("ok", and the block confirming a restart)
    return sc


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
@given(scripts())
def test_property_every_good_sample_once_monotonic_segments_counts(sc: Script):
    seq = StreamSequencer(FS, plausible_jump_s=1.0, duplicate_window_s=WINDOW / FS)
    out: list[Accepted | Dropped] = []
    for first, n, t, i in sc.blocks:
        out += seq.feed(first, n, t, i)
    out += seq.finish()
    acc = [o for o in out if isinstance(o, Accepted)]
    # every good block exactly once, nothing else (a wild frame never costs a good block)
    assert [a.item for a in acc] == [b[3] for b in sc.blocks if b[3] in sc.good]
    # stream indices strictly increase, never overlap, and always fit a log's time
    for a, b in itertools.pairwise(acc):
        assert b.stream_first >= a.stream_end
        if b.restart is None:  # within a segment: the offset is constant, a gap is exactly the device's jump
            assert b.stream_first - b.device_first == a.stream_first - a.device_first
            assert b.gap == (None if b.device_first == a.device_first + a.n else (a.stream_end, b.stream_first))
        else:  # a new segment: placed by the host clock, within the latency (2 ms) and rounding
            true_gap = sc.good[b.item][0] - (sc.good[a.item][0] + a.n)
            assert b.stream_first - a.stream_end == max(1, b.restart.estimated_gap)
            assert abs(b.restart.estimated_gap - true_gap) <= 4 or (true_gap <= 0 and b.restart.estimated_gap <= 4)
    assert all(a.stream_end * 1e9 / FS < MAX_STREAM_NS for a in acc)
    # exactly the scripted restarts start segments, with the flag on their first block
    assert [a.item for a in acc if a.restart is not None] == sc.restarts
    assert [a.segment for a in acc if a.restart is not None] == list(range(1, len(sc.restarts) + 1))
    assert [sc.good[a.item][1] for a in acc] == [a.segment for a in acc]
    # counts
    kinds = [o.kind for o in out if isinstance(o, Dropped)]
    assert kinds.count("duplicate") == sc.dups == seq.counts.duplicates
    assert kinds.count("implausible_index") == sc.wild == seq.counts.rejected
    assert seq.counts.restarts == len(sc.restarts)
    assert seq.counts.accepted_samples == sum(a.n for a in acc)
    assert seq.counts.gap_samples == sum(a.gap[1] - a.gap[0] for a in acc if a.gap is not None)


def test_a_backlog_before_a_restart_does_not_shorten_the_estimated_gap():
    """Issue 30, the serial restart cell under load: the old run's last 0.35 s were read 0.33 s late, in a burst
    (a busy host), and the new run arrived on time 0.5 s after the old one went down. The gap is taken from the
    device clock as the old run's prompt blocks showed it, not from its late last block (that gave 0.17 s)."""
    fs = 16384.0
    seq = StreamSequencer(fs)
    late = 0.33
    for k in range(16):  # 0 .. 1.0 s, each 1024-sample block on time (+1 ms)
        seq.feed(1024 * k, 1024, (1024 * (k + 1)) / fs + 0.001)
    for k in range(16, 24):  # 1.0 .. 1.5 s: read as one burst, 0.33 s behind
        seq.feed(1024 * k, 1024, 1.5 + late)
    (acc,) = seq.feed(0, 1024, 2.0 + 1024 / fs + 0.001, restart=True)  # new run: sample 0 at 2.0 s, on time
    rs = acc.restart
    assert rs is not None and rs.prev_end == 24 * 1024
    # truth 0.5 s = 8192 samples; both runs' blocks came 1 ms after their last sample, so the estimate is exact
    # to the rounding of the clock slack (1000 ppm x 0.5 s of the burst's samples = 8 samples)
    assert abs(rs.estimated_gap - 0.5 * fs) <= 10, rs.estimated_gap
    assert abs(rs.old_late_s - late) < 0.002  # said in the restart event, left out of the estimate


def test_a_restart_says_how_far_either_way_the_gap_may_be_off():
    """The new run's first block is one of this link's blocks: it may have come earlier or later than the usual
    (median) lateness the estimate assumes. The restart carries that spread both ways (the old run's recent blocks'
    10th and 90th percentiles about their median) and the event says it in samples; a first block read at either
    percentile leaves the true gap inside the stated range (frames read 0-20 ms late: about 8 ms either way)."""
    fs = 2048.0
    for first_late in (0.002, 0.010, 0.018):  # the new run's first frame read at the 10th, 50th, 90th percentile
        rng = random.Random(5)
        seq = StreamSequencer(fs)
        for k in range(256):  # 8 s of 64-sample frames, each read 0-20 ms after its last sample
            seq.feed(64 * k, 64, 64 * (k + 1) / fs + rng.uniform(0.0, 0.02))
        (acc,) = seq.feed(0, 64, 8.3 + 64 / fs + first_late, restart=True)  # down 0.3 s after 8.0 s
        rs = acc.restart
        earlier, later = rs.usual_spread_s
        assert 0.006 < earlier < 0.010 and 0.006 < later < 0.010, rs.usual_spread_s
        gap, truth = rs.estimated_gap, round(0.3 * fs)
        assert gap - round(later * fs) - 2 <= truth <= gap + round(earlier * fs) + 2, (first_late, gap, rs.usual_spread_s)
    # with fewer than 10 blocks behind it there is no spread to state
    seq = StreamSequencer(fs)
    for k in range(5):
        seq.feed(64 * k, 64, 64 * (k + 1) / fs + 0.01)
    (acc,) = seq.feed(0, 64, 1.0, restart=True)
    assert acc.restart.usual_spread_s == (0.0, 0.0)


def test_the_device_clock_estimate_follows_a_slow_device():
    """A device clock 200 ppm slower than the host's: its blocks come later and later on the host clock; the
    estimate, carried forward 1000 ppm fast, follows them (a pure minimum would lag by 200 ppm of the run)."""
    fs = 1000.0
    seq = StreamSequencer(fs)
    for k in range(600):  # 600 s of 1000-sample blocks, each on time on the slow device's clock
        seq.feed(1000 * k, 1000, (k + 1) * 1.0002)
    (acc,) = seq.feed(0, 1000, 600 * 1.0002 + 1.0 + 1.0, restart=True)  # down 1 s, then a prompt first block
    # the device clock at the old end is 600.12 s; the estimate can lag a block's worth of slack (1 ms) at most
    assert abs(acc.restart.estimated_gap - 1.0 * fs) <= 2, acc.restart.estimated_gap


def test_the_new_runs_first_block_is_taken_as_late_as_blocks_usually_are():
    """A serial driver reads in turns (every 20 ms while data flows): each block comes 0-20 ms after its last
    sample, and the device-clock envelope of the old run is its earliest. The new run's first block comes as late as
    blocks usually do, so the gap estimate takes that usual (median) lateness off it: without it the gap came out
    +17 ms long at 2048 Hz, systematically (tests/test_frf_lab.py's restart hit 20.8 ms late in a quiet make test)."""
    fs = 2048.0
    rng = random.Random(5)
    seq = StreamSequencer(fs)
    for k in range(64):  # 2 s of 64-sample frames, each read 0-20 ms after its last sample
        seq.feed(64 * k, 64, 64 * (k + 1) / fs + rng.uniform(0.0, 0.02))
    # down 0.3 s after sample 4096 (2.0 s); the new run's first frame read 10 ms after its last sample (the median)
    (acc,) = seq.feed(0, 64, 2.3 + 64 / fs + 0.010, restart=True)
    err_s = acc.restart.estimated_gap / fs - 0.3
    assert abs(err_s) <= 0.003, err_s  # a frame's lateness scatters +-10 ms about its median; the median is the 10 ms
