"""Stream sequencing: is a device block in order, after a gap, a duplicate, a bad frame or a device restart?

Sans-IO (like :mod:`drivers.serial.protocol`): :class:`StreamSequencer` takes, per block of one stream,
the device's own sample index, the sample count and the host monotonic arrival time, and returns what
to do with it. Nothing here touches a link, a queue or a clock, so the decisions are property-tested on
their own (tests/test_sequence.py) and every transport gets the same ones through ``Driver._emit``.

Why a kernel at all: the device index is the only thing that says where a block belongs, and it can lie.
A restarted device counts from 0 again; one CRC-valid frame with a wild index (line noise that happens
to pass, a firmware bug) claims to be 10^9 samples ahead. Taken at face value the first is stitched onto
the old data (or dropped for ever as "going back in time") and the second makes a false gap, drops every
later frame, and at 2^62 overflows the log's int64 nanosecond time. So an index that goes back beyond a
recent window, or jumps forward beyond what the host clock allows, is only a *suspect*: it is held (not
emitted) until the next block. If that block continues it contiguously the device really restarted (or
re-based its counter): both start a new *segment*. Otherwise the suspect was a bad frame: it is rejected
and counted, and the stream goes on as if it never came. One wild frame therefore never costs a good
block, and a confirmed restart is never stitched.

Stream index = device index + segment offset, continuous and monotonic across segments. The first block
of a new segment is placed after the old segment's end by the gap the host clock implies (an *estimate*:
the device's own clock restarted, so nothing exact is left to count), at least one sample so that no
reader can join the two runs as if they were contiguous.

The host time at which the old run's end existed is not the arrival of its last block: on a busy host that
block may be read a backlog late (0.33 s seen at load 7-9 on 2 cores), and the restart gap then shrank to 1
sample (issue 30). It is the device's clock as its *earliest* blocks showed it: each block bounds the time its
last sample existed from above (arrival minus what the device held beyond it), so the smallest bound over the
run, carried forward at the sample rate, is the one a backlog does not move (a minimum of arrival times, the
usual estimator of a one-way delay's fixed part). Carried forward with a slack of ``CLOCK_SLACK`` (1000 ppm,
above a crystal's 100 ppm and NTP's 500 ppm slew), so that a device clock slower than the host's is followed.

The new run's start has no such envelope yet: its first block is all there is when its index must be given, and
that block came as late as blocks usually do behind the envelope (a serial driver reads in turns every 20 ms:
+17 ms at 2048 Hz, systematically, on an otherwise quiet host). So the new run's start is moved back by the
*median* lateness of the old run's recent blocks (``LATE_WINDOW`` of them): the usual delay, which a backlog at the
old run's end (a minority of the window) does not move. The first block is one draw from that lateness, so the gap may
be off either way by its spread: the 10th and 90th percentiles about the median go with the restart
(``Restart.usual_spread_s``), and the restart event says them in samples (docs/decisions.md D128).
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass
from typing import Any

#: Stream time must stay far inside int64 nanoseconds (2^63 ns = 292 years) even after a log adds its
#: wall-clock t0 (~1.7e18 ns): stream indices end below 2^62 ns of stream time (146 years).
MAX_STREAM_NS = 2**62
#: the device-clock estimate (the earliest arrival bound, carried forward) may run this much faster than the
#: samples it counts: 1000 ppm, above crystal tolerance (~100 ppm) and NTP slew (<= 500 ppm), so a slow device
#: clock is followed; a backlog older than ``lateness / CLOCK_SLACK`` (0.3 s late: 300 s) is forgotten
CLOCK_SLACK = 1e-3
#: blocks whose lateness behind the device clock gives the usual delay a restart's first block is corrected by
LATE_WINDOW = 2048


@dataclass(frozen=True)
class Restart:
    """A confirmed device restart (or counter re-base): where the new segment starts."""

    segment: int  # number of the new segment (the stream's first segment is 0)
    device_first: int  # device index of the new segment's first block
    prev_end: int  # stream index one past the old segment's last sample
    stream_first: int  # stream index given to the new segment's first sample
    by_transport: bool = False  # the transport confirmed it (else: the next block continued the suspect)
    old_late_s: float = 0.0  # how late the old run's last block arrived behind the device clock (a backlog, not counted)
    #: how much earlier / later than usual a block of this link arrives (the median lateness minus its 10th percentile,
    #: the 90th minus the median, over the old run's recent blocks): the new run's first block was one of them, so the
    #: gap may be this much longer / shorter than estimated (module docstring)
    usual_spread_s: tuple[float, float] = (0.0, 0.0)

    @property
    def estimated_gap(self) -> int:
        """Samples the device did not deliver between the two runs, estimated from the host clock."""
        return self.stream_first - self.prev_end


@dataclass(frozen=True)
class Accepted:
    """A block to emit, at its stream index."""

    item: Any
    device_first: int
    stream_first: int
    n: int
    segment: int
    gap: tuple[int, int] | None = None  # exact missing stream range before this block
    restart: Restart | None = None  # set on the first block of a segment a restart began
    starts_segment: bool = False  # first block of a segment (the stream's first block, or a restart)

    @property
    def stream_end(self) -> int:
        return self.stream_first + self.n


@dataclass(frozen=True)
class Dropped:
    """A block not emitted: ``duplicate`` (re-sent or overlapping recent data) or ``implausible_index``."""

    item: Any
    kind: str
    device_first: int
    n: int
    stream_at: int | None  # stream index the stream had reached when it was dropped (None: nothing yet)
    reason: str
    stream_first: int | None = None  # duplicates: where the block lies in the stream (it repeats data there)


@dataclass
class SequencerCounts:
    accepted_samples: int = 0
    duplicates: int = 0
    rejected: int = 0  # implausible blocks (bad frames, unconfirmed restarts)
    rejected_samples: int = 0
    restarts: int = 0
    gap_samples: int = 0  # exact
    estimated_gap_samples: int = 0  # restarts: from the host clock


@dataclass(frozen=True)
class _Block:
    first: int
    n: int
    now: float
    produced: int  # device samples that existed at ``now`` (>= first + n)
    item: Any


class StreamSequencer:
    """Decide, block by block, where one stream's device blocks go (see the module docstring).

    ``fs``: the stream's sample rate. ``plausible_jump_s``: a forward jump is a real gap only if it is at
    most ``(elapsed + plausible_jump_s) * fs * 1.25 + slack`` samples, ``elapsed`` being the host time since
    the last accepted block (1.25: clock tolerance; slack: a few blocks). ``duplicate_window_s``: a block
    going back at most this far (or one block) re-sends or overlaps recent data and is dropped; further
    back it is a restart suspect. ``expect_first``: the device's first index when the session started the
    device (loss before the first block is then a gap), with ``start_time`` the host time it started.
    """

    def __init__(
        self,
        fs: float,
        *,
        plausible_jump_s: float = 1.0,
        duplicate_window_s: float = 0.25,
        expect_first: int | None = None,
        start_time: float | None = None,
    ) -> None:
        if not fs > 0:
            raise ValueError("StreamSequencer: fs must be positive")
        self.fs = float(fs)
        self.plausible_jump_s = float(plausible_jump_s)
        self.window = max(1, round(duplicate_window_s * self.fs))
        self.max_index = int(MAX_STREAM_NS / 1e9 * self.fs)
        self.counts = SequencerCounts()
        self.segment = 0
        self._expected = expect_first  # next device index wanted
        self._seg_first = expect_first  # device index the current segment started at
        self._offset = 0  # stream index - device index in the current segment
        self._t_ref = start_time  # host time of the last accepted block (plausibility reference)
        self._t_end: float | None = None  # host time at which device sample ``_expected`` existed (device clock)
        self._late_s = 0.0  # how far behind that clock the last accepted block arrived
        self._lates: deque[float] = deque(maxlen=LATE_WINDOW)  # the same, for the run's recent blocks
        self._last_n = 0
        self._held: _Block | None = None
        self._started = False

    @property
    def next_stream_index(self) -> int | None:
        """Stream index the next in-order block would get (None before the first block)."""
        return None if self._expected is None else self._expected + self._offset

    @property
    def holding(self) -> bool:
        return self._held is not None

    # --- the decisions ------------------------------------------------------------------------
    def feed(
        self, first: int, n: int, now: float, item: Any = None, *, produced: int | None = None, restart: bool = False
    ) -> list[Accepted | Dropped]:
        """One block: device index ``first``, ``n`` samples, arrived at host time ``now``.

        ``produced``: device samples existing at ``now`` when the transport knows (a FIFO's backlog; default
        ``first + n``), for the restart estimate. ``restart``: the transport has already confirmed that this
        block starts a new device run (CAN: two frames; Modbus: the sample counter), so it is not held.
        """
        blk = _Block(int(first), int(n), float(now), int(produced) if produced is not None else int(first) + int(n), item)
        out: list[Accepted | Dropped] = []
        held, self._held = self._held, None
        if held is not None:
            if not restart and blk.first == held.first + held.n:
                out.append(self._new_segment(held))  # the suspect is continued: a restart or a re-base
            else:
                out.append(self._reject(held, "implausible index, not continued by the next block (bad frame)"))
        out.append(self._place(blk, restart))
        return [o for o in out if o is not None]

    def finish(self) -> list[Dropped]:
        """The stream ended: a suspect still held was never confirmed, so it is rejected."""
        held, self._held = self._held, None
        return [] if held is None else [self._reject(held, "implausible index, stream ended before a block confirmed it")]

    def _place(self, blk: _Block, restart: bool) -> Accepted | Dropped | None:
        if self._expected is None:  # the stream's first block (joining a device that already runs)
            return self._accept(blk, None, None)
        if restart:
            return self._new_segment(blk, by_transport=True)
        d = blk.first - self._expected
        if d == 0:
            return self._accept(blk, None, None)
        if d > 0 and d <= self._bound(blk):
            s = self._expected + self._offset
            return self._accept(blk, (s, s + d), None)
        recent = -d <= max(self.window, self._last_n, blk.n)
        if d < 0 and recent and self._seg_first is not None and blk.first >= self._seg_first:
            self.counts.duplicates += 1
            why = "block went back in time (duplicate or overlap)"
            return Dropped(blk.item, "duplicate", blk.first, blk.n, self.next_stream_index, why, blk.first + self._offset)
        self._held = blk  # a suspect: the next block decides
        return None

    def _bound(self, blk: _Block) -> float:
        elapsed = max(0.0, blk.now - (self._t_ref if self._t_ref is not None else blk.now))
        return (elapsed + self.plausible_jump_s) * self.fs * 1.25 + 64 + 2 * max(blk.n, self._last_n)

    def _new_segment(self, blk: _Block, by_transport: bool = False) -> Accepted | Dropped:
        if self._t_end is None:  # nothing accepted yet: this is simply where the stream starts
            self._expected = self._seg_first = None
            return self._accept(blk, None, None)
        t_first = blk.now - (blk.produced - blk.first) / self.fs  # host time device sample blk.first existed
        usual = statistics.median(self._lates) if self._lates else 0.0  # its usual lateness (module docstring)
        gap = max(1, round((t_first - usual - self._t_end) * self.fs))
        prev_end = self.next_stream_index
        assert prev_end is not None
        spread = (0.0, 0.0)
        if len(self._lates) >= 10:
            q = statistics.quantiles(self._lates, n=10)  # the 10th ... 90th percentiles
            spread = (max(0.0, usual - q[0]), max(0.0, q[-1] - usual))
        rs = Restart(self.segment + 1, blk.first, prev_end, prev_end + gap, by_transport, self._late_s, spread)
        if rs.stream_first + blk.n > self.max_index:
            return self._reject(blk, "the new segment would end beyond the log's time range")
        self.segment += 1
        self._offset = rs.stream_first - blk.first
        self._expected = self._seg_first = blk.first
        self.counts.restarts += 1
        self.counts.estimated_gap_samples += gap
        return self._accept(blk, None, rs)

    def _accept(self, blk: _Block, gap: tuple[int, int] | None, restart: Restart | None) -> Accepted | Dropped:
        offset = self._offset if self._expected is not None else 0
        stream_first = blk.first + offset
        if stream_first < 0 or stream_first + blk.n > self.max_index:
            return self._reject(blk, f"index beyond the log's time range ({MAX_STREAM_NS / 1e9 / 86400 / 365:.0f} years)")
        starts = restart is not None or not self._started
        self._started = True
        if self._expected is None:
            self._seg_first = blk.first
        end, old_end = blk.first + blk.n, self._expected
        self._t_ref = blk.now
        bound = blk.now + (end - blk.produced) / self.fs  # sample ``end`` existed no later than this
        if restart is None and self._t_end is not None and old_end is not None:  # same run: the device clock so far
            carried = self._t_end + (end - old_end) / self.fs * (1.0 + CLOCK_SLACK)
            self._t_end, self._late_s = min(bound, carried), max(0.0, bound - carried)
        else:
            self._t_end, self._late_s = bound, 0.0
            self._lates.clear()
        self._lates.append(self._late_s)
        self._expected = end
        self._last_n = blk.n
        self.counts.accepted_samples += blk.n
        if gap is not None:
            self.counts.gap_samples += gap[1] - gap[0]
        return Accepted(blk.item, blk.first, stream_first, blk.n, self.segment, gap, restart, starts)

    def _reject(self, blk: _Block, reason: str) -> Dropped:
        self.counts.rejected += 1
        self.counts.rejected_samples += blk.n
        return Dropped(blk.item, "implausible_index", blk.first, blk.n, self.next_stream_index, reason)
