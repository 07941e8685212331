"""Several DAQ devices on one timeline: a clock-offset estimate and a merged stream on the reference index.

The seed's Ch. 6 test had the hammer on one acquisition system and the accelerometers on another.
Each device numbers its samples on its own clock (``SampleBlock.first_index``); a hit record needs the
hammer and the responses on one index. Two pieces, both fed from the live session:

:class:`ClockOffsetEstimator` — where is each device's sample 0 on the host's monotonic clock? For
every block the host notes its arrival time ``t``; ``x = t − end_index / fs`` is the host time of the
device's sample 0 *plus the link latency of that block*. Latency is never negative and its minimum is
nearly constant, so the lower envelope of ``x`` is the device's clock offset (the minimum-delay filter
of NTP, Mills, RFC 5905 §10). We keep one point per ``window_s`` of device time — the window's
minimum — in a bounded deque; once the points span ``drift_min_span_s`` a least-squares line through
them, refitted without the points far above it, gives the device clock's rate error against the host
(drift, ppm). The offset is the lowest detrended point within ``horizon_s`` (30 s): scheduling delay on a
loaded host only ever makes a block late, so a longer history can only bring the floor nearer the link's
minimum latency (issue 30: with the minimum of the last second, a host at load 5 put the offset at 0.78 s
against the true 0.2371 s, because every block of that second arrived late). A clock that steps later is
followed when the minima of the last ``step_s`` (5 s) sit together above the old floor (a step moves them
all alike; delay scatters them, though a starved reader can lag steadily for a second or more). The
uncertainty is the floor's sharpness: the lowest point to the 10th percentile of the points
(:func:`_floor_spread`).
The relative offset of a stream to the reference is the difference of the two offsets: valid when both
links have the same minimum latency (same transport), which the estimate cannot check — an asymmetric
link biases it by the latency difference.

:class:`StreamAligner` — merges the blocks of several streams into blocks on the reference stream's
sample index. Stream ``s``'s sample ``i`` is reference sample ``i + offset_samples[s]``. It buffers until
the offset is fixed (after ``settle_s`` of data from every estimated stream once the estimate's
uncertainty is within ``accept_s`` — one sample period unless told — and at the latest after ``settle_max_s``,
max(settle_s, max_buffer_s / 2) unless told, saying then that it was fixed above that bound; at once when
every offset is configured), then emits only index ranges where every stream has data: a gap in any stream
is an index discontinuity (``GAP_BEFORE``) in the merged stream, so the hit gate marks a record cut by
it ``too_short``. The offset, once fixed, is never changed (a jump would tear the merged stream); the
estimate keeps being tracked, and a move by more than max(2 samples, 3 × uncertainty) is reported.

Bounded memory: each stream's buffer holds at most ``max_buffer_s`` of samples; past that its oldest
samples are dropped (counted per stream in :attr:`StreamAligner.dropped_samples`) and become a gap in
the merged stream. A stalled device therefore costs the other streams' hit gate data, never memory.
The estimator keeps at most ``max_windows`` points per stream (5 min at 0.1 s windows).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivers.blocks import BlockStatus, SampleBlock

METHOD_ESTIMATED = "host-arrival-lower-envelope"
METHOD_CONFIGURED = "configured"


@dataclass(frozen=True)
class ClockEstimate:
    """One device clock against the host's monotonic clock."""

    x_s: float  # host time of device sample 0 at minimum latency, as seen at device time ``at_s``
    at_s: float  # device time (end_index / fs) of the newest envelope point
    drift_ppm: float  # device clock rate error against the host (0 until the points span drift_min_span_s)
    uncertainty_s: float  # robust spread of the recent detrended window minima (nan with a single point)
    n_windows: int
    span_s: float  # device time covered by the points


@dataclass(frozen=True)
class RelativeOffset:
    """Where a stream's sample 0 lies on the reference stream's timeline."""

    offset_s: float  # the stream's sample 0 is this long after the reference's sample 0
    offset_samples: int  # round(offset_s * fs): reference index = stream index + offset_samples
    uncertainty_s: float
    drift_ppm: float | None  # relative rate error (stream − reference); None when configured
    method: str

    def as_dict(self) -> dict:
        return {
            "offset_s": self.offset_s, "offset_samples": self.offset_samples, "uncertainty_s": self.uncertainty_s,
            "drift_ppm": self.drift_ppm, "method": self.method,
        }  # fmt: skip


class _Track:
    __slots__ = ("cache", "first_t", "fs", "last_t", "points", "w", "w_min", "w_t")

    def __init__(self, fs: float, max_windows: int) -> None:
        self.fs = fs
        self.first_t: float | None = None
        self.last_t = 0.0
        self.w: int | None = None  # current window number
        self.w_min = math.inf
        self.w_t = 0.0
        self.points: deque[tuple[float, float]] = deque(maxlen=max_windows)
        self.cache: ClockEstimate | None = None


class ClockOffsetEstimator:
    """Per-stream lower envelope of ``t_arrival − end_index / fs`` (see the module docstring)."""

    def __init__(
        self, window_s: float = 0.1, max_windows: int = 3000, drift_min_span_s: float = 10.0, recent_windows: int = 10,
        horizon_s: float = 30.0, step_s: float = 5.0,
    ) -> None:  # fmt: skip
        if window_s <= 0 or max_windows < 2 or drift_min_span_s <= 0 or recent_windows < 2 or horizon_s <= 0:
            raise ValueError("window_s, drift_min_span_s and horizon_s must be > 0, max_windows and recent_windows >= 2")
        self.window_s = float(window_s)
        self.horizon_s = float(horizon_s)
        self.step_s = float(step_s)
        self.recent_windows = int(recent_windows)
        self.max_windows = int(max_windows)
        self.drift_min_span_s = float(drift_min_span_s)
        self._tracks: dict[str, _Track] = {}

    def add(self, stream: str, t_arrival: float, end_index: int, fs: float) -> bool:
        """One block arrived. Returns True when it closed a window (the estimate may have changed)."""
        tr = self._tracks.get(stream)
        if tr is None:
            tr = self._tracks[stream] = _Track(float(fs), self.max_windows)
        t_dev = end_index / tr.fs
        x = t_arrival - t_dev
        if tr.first_t is None:
            tr.first_t = t_dev
        tr.last_t = max(tr.last_t, t_dev)
        w = math.floor(t_dev / self.window_s)
        closed = False
        if tr.w is not None and w != tr.w:
            tr.points.append((tr.w_t, tr.w_min))
            tr.w_min = math.inf
            closed = True
        tr.w = w
        if x < tr.w_min:
            tr.w_min, tr.w_t = x, t_dev
        tr.cache = None
        return closed

    def span_s(self, stream: str) -> float:
        """Device time covered by the blocks seen so far (0 if none)."""
        tr = self._tracks.get(stream)
        return 0.0 if tr is None or tr.first_t is None else tr.last_t - tr.first_t

    def streams(self) -> list[str]:
        return list(self._tracks)

    def estimate(self, stream: str) -> ClockEstimate | None:
        tr = self._tracks.get(stream)
        if tr is None or tr.w is None:
            return None
        if tr.cache is not None:
            return tr.cache
        pts = list(tr.points)
        if math.isfinite(tr.w_min):
            pts.append((tr.w_t, tr.w_min))
        t = np.array([p[0] for p in pts])
        x = np.array([p[1] for p in pts])
        t_last = float(t[-1])
        span = float(t[-1] - t[0])
        slope = _envelope_slope(t, x) if t.size >= 3 and span >= self.drift_min_span_s else 0.0
        d = x - slope * (t - t_last)  # every window minimum detrended to the newest point
        d = d[t >= t_last - self.horizon_s]
        if self._stepped(tr, d):
            d = d[-max(self.recent_windows, round(self.step_s / self.window_s)) :]
        est = ClockEstimate(float(d.min()), t_last, slope * 1e6, _floor_spread(d), int(t.size), span)
        tr.cache = est
        return est

    def _stepped(self, tr: _Track, d: np.ndarray) -> bool:
        """The device clock stepped later: the last ``step_s`` of window minima sit together, well above the floor.

        Scheduling delay raises window minima too, mostly unevenly, so their spread is large; a clock step moves
        every minimum by the same amount. But a starved reader can also lag by a steady half second for a second
        or more (measured at 6 busy loops on 2 cores: 0.54 s for 1 s), so a step must hold for ``step_s`` (5 s)
        and exceed max(2 samples, 4 × the robust spread of those minima). The older points are then forgotten."""
        n = max(self.recent_windows, round(self.step_s / self.window_s))
        r = d[-n:]
        if d.size <= n + 2:
            return False
        spread = float(1.4826 * np.median(np.abs(r - np.median(r))))
        excess = float(r.min() - d.min())
        if excess > max(2.0 / tr.fs, 4.0 * spread):
            keep = n - (1 if math.isfinite(tr.w_min) else 0)  # the open window is among them
            while len(tr.points) > max(keep, 0):
                tr.points.popleft()
            return True
        return False

    def relative(self, stream: str, reference: str) -> RelativeOffset | None:
        """Offset of ``stream``'s clock to ``reference``'s (both must have blocks)."""
        e, r = self.estimate(stream), self.estimate(reference)
        if e is None or r is None:
            return None
        fs = self._tracks[reference].fs
        off = e.x_s - r.x_s  # each at its newest point: both are "now" to within one window
        unc = math.hypot(e.uncertainty_s, r.uncertainty_s)
        return RelativeOffset(off, round(off * fs), unc, e.drift_ppm - r.drift_ppm, METHOD_ESTIMATED)


def _envelope_slope(t: np.ndarray, x: np.ndarray) -> float:
    """Slope of a least-squares line through the lower envelope: refitted without the points far above it."""
    keep = np.ones(t.size, bool)
    for _ in range(3):
        b, a = np.polyfit(t[keep], x[keep], 1)
        r = x - (a + b * t)
        s = float(np.std(r[keep]))
        new = r <= 2.0 * s if s > 0 else keep
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    return float(np.polyfit(t[keep], x[keep], 1)[0])


def _floor_spread(d: np.ndarray) -> float:
    """How sharply the floor of the window minima is defined: the lowest one to their 10th percentile (at least
    the third lowest: the gap to the second of five windows was 6 µs in a run whose offset was 99 µs off).
    The offset is the lowest; a late arrival only ever raises a point, so this is the distance within which
    another window could have set the floor — small on a quiet host, large when scheduling delay leaves few
    windows at the link's minimum latency. It cannot include the links' latency asymmetry. nan with one point."""
    if d.size < 2:
        return math.nan
    srt = np.sort(d)
    return float(srt[min(d.size - 1, max(2, d.size // 10))] - srt[0])


def response_lead(force: np.ndarray, response: np.ndarray) -> int | None:
    """Samples by which the driving point's response leads the hammer's force in one merged hit record (the
    physics check of the clock offset).

    A structure cannot move before it is hit, and a driving-point accelerometer answers a hammer at once: the
    impact's broadband content makes its steepest change lie within the pulse, whatever the structure rang with
    before. The force rises steepest in the pulse's first half, so the lead — the index of the force's steepest
    rise minus that of the response's steepest change — is at most half the pulse width for aligned devices; more
    means the offset places the other device too early by at least the excess. None when a trace is flat."""
    f, r = np.asarray(force, np.float64), np.asarray(response, np.float64)
    if f.size != r.size or f.size < 3:
        return None
    df, dr = np.diff(f), np.abs(np.diff(r))
    df = df * (1.0 if f.max() >= -f.min() else -1.0)  # the force's rise (a hammer pushes one way)
    if not (df.max() > 0 and dr.max() > 0):
        return None
    return int(np.argmax(df)) - int(np.argmax(dr))


def timeline_line(msg: Mapping, fs: float) -> str | None:
    """The one console line of a ``/daq/timeline`` message worth a person's attention (fixed, moved), else None."""
    kind, s, ref = msg.get("kind"), msg.get("stream"), msg.get("reference")
    off, unc = float(msg.get("offset_s", math.nan)), float(msg.get("uncertainty_s", math.nan))
    pm = f"± {unc * 1e3:.3f} ms" if math.isfinite(unc) else "± ?"
    if kind == "fixed":
        how = "configured" if msg.get("method") == METHOD_CONFIGURED else f"{pm}, from host arrival times"
        line = f"timeline: {s} placed {msg.get('applied_samples')} samples ({off:.5f} s, {how}) after {ref}"
        if msg.get("within_accept") is False:
            line += (f"; NOT within one sample ({float(msg.get('accept_s', 1 / fs)) * 1e3:.3f} ms) after "
                     f"{float(msg.get('settled_s', 0)):.1f} s: a loaded host; set timeline.offsets if the clocks are in sync")
        return line
    if kind == "moved":
        return (f"timeline MOVED: {s}'s clock offset to {ref} is now {off:.5f} s {pm} ({float(msg.get('moved_samples', 0)):+.1f} "
                f"samples); the merged stream keeps {msg.get('applied_samples')} (check the device clocks)")
    return None


class _Buffer:
    """One stream's pending samples: contiguous runs ``[first_index, data]`` in the stream's own index."""

    __slots__ = ("end", "n", "segs")

    def __init__(self) -> None:
        self.segs: deque[list] = deque()
        self.n = 0
        self.end: int | None = None  # one past the last sample received

    def push(self, first: int, data: np.ndarray) -> None:
        if self.end is not None and first < self.end:  # overlap (a duplicate): keep only what is new
            data = data[self.end - first :]
            first = self.end
        if data.shape[0] == 0:
            return
        self.segs.append([first, data])
        self.n += data.shape[0]
        self.end = first + data.shape[0]

    def drop_before(self, index: int) -> int:
        """Drop samples before ``index`` (own index); returns how many."""
        dropped = 0
        while self.segs:
            first, data = self.segs[0]
            if first >= index:
                break
            k = min(index - first, data.shape[0])
            dropped += k
            if k == data.shape[0]:
                self.segs.popleft()
            else:
                self.segs[0] = [first + k, data[k:]]
        self.n -= dropped
        return dropped

    def drop_oldest(self, count: int) -> int:
        return self.drop_before(self.segs[0][0] + count) if self.segs and count > 0 else 0


class StreamAligner:
    """Merge blocks of several streams onto the reference stream's sample index (module docstring).

    ``streams``: name → channel names, for every stream (the reference included). ``offsets``: seconds
    by which a stream's sample 0 follows the reference's, for clocks synchronised by other means (no
    estimate then). Feed every block with its host arrival time; the result is a list of merged blocks
    (stream ``name``, channels = the reference's then the others' in ``streams`` order).
    """

    def __init__(
        self,
        streams: Mapping[str, Sequence[str]],
        reference: str,
        sample_rate: float,
        *,
        offsets: Mapping[str, float] | None = None,
        settle_s: float = 0.5,
        window_s: float = 0.1,
        max_buffer_s: float = 5.0,
        report_s: float = 1.0,
        name: str = "timeline",
        estimator: ClockOffsetEstimator | None = None,
        accept_s: float | None = None,
        settle_max_s: float | None = None,
    ) -> None:
        if reference not in streams:
            raise ValueError(f"reference {reference!r} is not among the streams {list(streams)}")
        if len(streams) < 2:
            raise ValueError("an aligner needs at least two streams")
        if max_buffer_s < settle_s:
            raise ValueError("max_buffer_s must be at least settle_s (the buffer holds the settling data)")
        self.reference = reference
        self.fs = float(sample_rate)
        self.name = name
        self.order = [reference, *[s for s in streams if s != reference]]
        self.columns = {s: tuple(streams[s]) for s in self.order}
        self.channels = tuple(c for s in self.order for c in self.columns[s])
        self.configured = {s: float(v) for s, v in (offsets or {}).items() if s != reference}
        unknown = set(self.configured) - set(streams)
        if unknown:
            raise ValueError(f"offsets for unknown streams {sorted(unknown)}")
        self.estimated = [s for s in self.order[1:] if s not in self.configured]
        self.settle_s = float(settle_s)
        self.accept_s = 1.0 / self.fs if accept_s is None else float(accept_s)
        self.settle_max_s = max(self.settle_s, max_buffer_s / 2 if settle_max_s is None else float(settle_max_s))
        self.max_buffer = max(1, round(max_buffer_s * self.fs))
        self.report_every = max(1, round(report_s * self.fs))
        self.estimator = estimator or ClockOffsetEstimator(window_s=window_s)
        self.applied: dict[str, int] | None = None  # offset samples per stream once fixed
        self.unsure: dict[str, float] = {}  # streams fixed with an uncertainty above accept_s (the deadline came)
        self.fixed_offsets: dict[str, RelativeOffset] = {}
        self.dropped_samples = {s: 0 for s in self.order}
        self.merged_samples = 0
        self.merged_gaps = 0
        self._buf = {s: _Buffer() for s in self.order}
        self._next: int | None = None
        self._messages: list[dict] = []
        self._moved_from: dict[str, float] = {}
        self._next_report: int | None = None

    @property
    def fixed(self) -> bool:
        return self.applied is not None

    @property
    def reference_end(self) -> int | None:
        """One past the newest reference sample received (the data time the aligner has reached), or None."""
        return self._buf[self.reference].end

    # --- input --------------------------------------------------------------------------------
    def feed(self, block: SampleBlock, t_arrival: float | None = None) -> list[SampleBlock]:
        """One block of any stream (in index order within its stream). ``t_arrival``: host monotonic
        time the block arrived (default ``block.extra['t_host']``); needed for estimated streams."""
        s = block.stream
        if s not in self._buf:
            raise ValueError(f"block of unknown stream {s!r}; the aligner merges {self.order}")
        if block.sample_rate != self.fs:
            raise ValueError(
                f"stream {s!r} samples at {block.sample_rate:g} Hz, not {self.fs:g} Hz: resampling is not supported"
            )
        if t_arrival is None:
            t_arrival = block.extra.get("t_host")
        if t_arrival is not None and (s in self.estimated or (s == self.reference and self.estimated)):
            if self.estimator.add(s, float(t_arrival), block.end_index, self.fs) and self.fixed:
                self._track(s)
        buf = self._buf[s]
        buf.push(block.first_index, block.data)
        if buf.n > self.max_buffer:
            self.dropped_samples[s] += buf.drop_oldest(buf.n - self.max_buffer)
        if not self.fixed:
            if not self._ready():
                return []
            self._fix("fixed")
        out = self._merge()
        if s == self.reference and self._next_report is not None and buf.end is not None and buf.end >= self._next_report:
            self._report("periodic")
            self._next_report = buf.end + self.report_every
        return out

    def finish(self) -> list[SampleBlock]:
        """End of input: a session shorter than ``settle_s`` fixes the offset with what it has, and the
        final estimate is reported. Samples only some streams have are not emitted."""
        out: list[SampleBlock] = []
        if not self.fixed and all(self._can_estimate(s) for s in [self.reference, *self.estimated]):
            self._fix("fixed")
            out = self._merge()
        if self.fixed:
            self._report("final")
        return out

    def drain_messages(self) -> list[dict]:
        """Timeline reports since the last call: ``kind`` = fixed | periodic | moved | final, one per
        non-reference stream, with offset_s, offset_samples, uncertainty_s, drift_ppm, method, and
        ``applied_samples`` (the offset the merged stream uses)."""
        out, self._messages = self._messages, []
        return out

    def current(self) -> dict[str, dict]:
        """The latest estimate per non-reference stream (configured ones as configured)."""
        out = {}
        for s in self.order[1:]:
            rel = self._relative(s)
            if rel is None:
                continue
            d = rel.as_dict()
            if self.applied is not None:
                d["applied_samples"] = self.applied[s]
            out[s] = d
        return out

    # --- internals ----------------------------------------------------------------------------
    def _can_estimate(self, s: str) -> bool:
        return self.estimator.estimate(s) is not None

    def _ready(self) -> bool:
        if any(self._buf[s].end is None for s in self.order):
            return False
        if not self.estimated:
            return True
        spans = [self.estimator.span_s(s) for s in [self.reference, *self.estimated]]
        if min(spans) < self.settle_s:
            return False
        if min(spans) >= self.settle_max_s:
            return True  # fixed with what it has; the message says the uncertainty was above accept_s
        for s in self.estimated:
            rel = self.estimator.relative(s, self.reference)
            if rel is None or not rel.uncertainty_s <= self.accept_s:
                return False
        return True

    def _relative(self, s: str) -> RelativeOffset | None:
        if s in self.configured:
            v = self.configured[s]
            return RelativeOffset(v, round(v * self.fs), 0.0, None, METHOD_CONFIGURED)
        return self.estimator.relative(s, self.reference)

    def _fix(self, kind: str) -> None:
        applied = {self.reference: 0}
        for s in self.order[1:]:
            rel = self._relative(s)
            assert rel is not None
            self.fixed_offsets[s] = rel
            applied[s] = rel.offset_samples
            if s in self.estimated and not rel.uncertainty_s <= self.accept_s:
                self.unsure[s] = rel.uncertainty_s
            self._moved_from[s] = rel.offset_s * self.fs
        self.applied = applied
        ref_end = self._buf[self.reference].end or 0
        self._next_report = ref_end + self.report_every
        self._report(kind)

    def _report(self, kind: str) -> None:
        for s, d in self.current().items():
            extra = {}
            if kind == "fixed" and s in self.estimated:
                extra = {"accept_s": self.accept_s, "settled_s": self.estimator.span_s(s), "within_accept": s not in self.unsure}
            self._messages.append({"kind": kind, "reference": self.reference, "stream": s, **d, **extra})

    def _track(self, s: str) -> None:
        """After fixing: report when the estimate moved by more than max(2 samples, 3 × uncertainty)."""
        streams = self.estimated if s == self.reference else [s] if s in self.estimated else []
        for t in streams:
            rel = self.estimator.relative(t, self.reference)
            if rel is None:
                continue
            now = rel.offset_s * self.fs
            unc = rel.uncertainty_s * self.fs if math.isfinite(rel.uncertainty_s) else 0.0
            limit = max(2.0, 3.0 * unc)
            if abs(now - self._moved_from[t]) > limit:
                self._messages.append({
                    "kind": "moved", "reference": self.reference, "stream": t, **rel.as_dict(),
                    "applied_samples": self.applied[t] if self.applied else None, "moved_samples": now - self._moved_from[t],
                    "limit_samples": limit,
                })  # fmt: skip
                self._moved_from[t] = now

    def _merge(self) -> list[SampleBlock]:
        assert self.applied is not None
        out: list[SampleBlock] = []
        bufs = [(self._buf[s], self.applied[s]) for s in self.order]
        while all(b.segs for b, _ in bufs):
            start = max(b.segs[0][0] + off for b, off in bufs)
            for b, off in bufs:
                b.drop_before(start - off)  # samples no other stream can match: never emitted
            if not all(b.segs for b, _ in bufs):
                break
            if any(b.segs[0][0] + off != start for b, off in bufs):
                continue  # a stream's next run starts later (a gap): move the start up
            end = min(b.segs[0][0] + off + b.segs[0][1].shape[0] for b, off in bufs)
            parts = []
            for b, off in bufs:
                parts.append(b.segs[0][1][: end - start])
                b.drop_before(end - off)
            status = BlockStatus.OK
            if self._next is not None and start != self._next:
                status |= BlockStatus.GAP_BEFORE
                self.merged_gaps += 1
            data = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
            out.append(SampleBlock(self.name, start, self.fs, self.channels, np.ascontiguousarray(data, np.float32), status))
            self._next = end
            self.merged_samples += end - start
        return out
