"""Hammer trigger and hit quality gate: a streaming kernel fed with SampleBlocks.

What a GVT engineer expects of it (anchors: pyTrigger, pyFRF's ``is_data_ok``, Simcenter's Smart Hit
Selection — landscape.md §1a, §2.2–2.3):

* **Trigger** on the rising edge of the hammer force through ``level`` with ``pre_trigger`` seconds of
  history kept (a bounded ring buffer, never the whole run) and ``record_length`` seconds after the
  edge. It re-arms only after the force fell below ``hysteresis × level`` and the record is complete.
* **Record** per hit: trigger index and time, peak force, pulse width (time above 10 % of the peak
  around it), impulse, and the input energy ``∫ F v dt`` over the pulse when a driving-point
  accelerometer is named (velocity from its integrated acceleration, pre-trigger mean removed) and
  usable on that hit.
* **Per-channel verdicts**: every channel gets ``ok``, ``clipped``, ``dead`` or ``excluded`` on every hit
  (:func:`judge_channels`). One bad accelerometer must not cost the other thirteen: the seed's 9th
  accelerometer clipped on every hit (L1320), and rejecting the whole hit for it threw away every good
  channel with it. A failed response channel is only left out of that hit (``excluded_channels``);
  channels listed in ``exclude`` (known bad or unused) are ignored altogether.
* **Verdict** with its reason, first failing check wins but every reason is listed: ``too_short``
  (a data gap or the end of the stream cut the record), ``overload`` (the force channel clipped, or a
  channel listed in ``required`` clipped or is dead — named), ``double_hit`` (the force crossed
  ``level`` again after the main pulse), ``force_range`` (peak outside the requested range), else
  ``accepted``. Response channels left out of an accepted hit are listed in its reasons ("a09 excluded:
  clipped …") without changing the verdict.
* **Suspect channels**: a channel that failed (clipped or dead) on every one of at least
  ``suspect_after`` hits it could be judged on, named with why (:meth:`ChannelHealth.suspect_reasons`)
  — the seed found out about its 9th accelerometer only afterwards.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from analysis.records import Hit
from drivers.blocks import SampleBlock

#: A sample at or above this fraction of a channel's range counts as clipped: a saturated value comes
#: back through the ADC quantised up to one step below full scale (24 bit: 6e-4 of a 2 m/s^2 range).
CLIP_FRACTION = 0.999

# --- the dead-channel rule (judge_channels) ---------------------------------------------------------
# A response channel is dead on a hit when it is
#   * non-finite: any NaN/inf sample in the record (a driver or cable fault; nothing it says can be used);
#   * flat: at most 3 distinct values over the whole record, i.e. peak-to-peak of at most two ADC steps
#     whatever the step is (a stuck or disconnected input; a live 24-bit channel shows
#     hundreds of codes of sensor noise alone) — unless at least half of the judged response channels
#     are flat too, which is the ADC's resolution or a switched-off front end, not one channel's fault;
#   * silent: its response rise (:func:`response_rise`) is at most DEAD_RISE while the median rise of the
#     other judged response channels (finite, not flat, not clipped) is at least LIVE_RISE: the structure
#     clearly answered the hammer and this channel did not. Too little of either (a weak tap, a soft tip
#     at a high rate, a too-short pre-trigger) decides nothing: the channel stays "ok", and that hit does
#     not count towards its suspect tally either way.
# Measured with this kernel on the simulated beam (beam_ch4_exp at 16 kHz with an extra sensor 7 mm from the
# clamped root; bench_64ch, 63 accelerometers at 51.2 kHz, 1 ms and 5 ms tips; 22-2600 N hits 0.5 s apart,
# so each pre-trigger still rings from the previous hit; sensor noise swept 0.005-30 m/s^2 on top):
#   * a dead channel (zeroed + the sensor's 0.02 m/s^2 noise) rises 0.83-1.47x, median 1.03x (3000 hits:
#     150 noise seeds × the 20-hit session); DEAD_RISE = 1.75 leaves it a wide margin, and caught it on all
#     3000;
#   * in the 20-hit session every live channel rose >= 132x and the median >= 232x, so every hit is judged;
#     a 22 N tap from rest gives a median of ~330x, a 25 N tap right after a 2600 N hit only 6-12x (nothing
#     is judged then: a weak hit never makes a channel dead);
#   * the weakest live channel is a sensor near the clamped root (0.69 m from the hammer, hardly moving):
#     with the others' median just at 50 / 100 / 150 / 200 / 300x its rise fell to 1.16 / 1.65 / 2.26 /
#     2.86 / 4.04x. LIVE_RISE = 200 keeps it >= 2.86x, 1.6x above DEAD_RISE: a far but alive channel is
#     not called dead, while LIVE_RISE = 100 would have called it dead (1.65x < 1.75x).
DEAD_RISE = 1.75
LIVE_RISE = 200.0
#: The baseline ends this long before the pulse start: the force (and the response) is already rising
#: when it crosses ``level`` — on a 200 N hit the sample before the edge holds 7.6 N and a driving-point
#: response of 29 m/s^2 — and a sigma-delta DAQ's linear-phase filter rings ahead of a step.
BASELINE_GUARD_S = 0.001
#: The response is measured over this window from the pulse start: the impact's broadband kick is largest
#: in its first milliseconds (first-difference view: live channels' minimum rise 10x over 10 ms, 8.4x
#: over 20 ms, 5.9x over 50 ms), while 20 ms still holds the lowest modes' first half-cycle at ~25 Hz.
RESPONSE_WINDOW_S = 0.02
MIN_BASELINE = 32  # samples: fewer and the noise-over-noise rise scatters too much to call anything dead
MIN_RESPONSE = 16  # samples after the pulse start


def response_rise(base: np.ndarray, post: np.ndarray) -> np.ndarray:
    """Per column, how far a hit lifted the signal above its own pre-trigger level: the largest of three
    RMS ratios post/baseline — of the signal (baseline mean removed), of its first and of its second
    difference.

    Why three views: the signal itself is right for a structure at rest and for soft tips (low-frequency
    response), but 0.5 s after the previous hit the pre-trigger still rings in the low modes of a lightly
    damped structure and that ratio falls to 1.4-2.4x for live channels; differencing suppresses that
    ringing (a 31 Hz mode by 0.012 per difference at 16 kHz) and keeps the impact's broadband kick
    (the 20-hit session's live channels >= 132x). Sensor noise is white, so a dead channel stays
    near 1 in every view. Columns with a zero baseline get ``inf`` if anything moved after, else 1.
    """
    base = np.asarray(base, np.float64)
    post = np.asarray(post, np.float64)
    best = np.zeros(base.shape[1])
    for order in (0, 1, 2):
        if order:
            b, p = np.diff(base, n=order, axis=0), np.diff(post, n=order, axis=0)
        else:
            m = base.mean(axis=0)
            b, p = base - m, post - m
        rb = np.sqrt(np.mean(b * b, axis=0))
        rp = np.sqrt(np.mean(p * p, axis=0))
        r = np.divide(rp, rb, out=np.where(rp > 0, np.inf, 1.0), where=rb > 0)
        best = np.maximum(best, r)
    return best


def _flat(rec: np.ndarray) -> np.ndarray:
    """Per column: at most 3 distinct values (the flat rule above). Only the columns that look flat in the first
    256 samples (live ones never do) are checked over the whole record."""
    out = _distinct_below_4(rec[:256])
    if rec.shape[0] > 256 and out.any():
        maybe = np.nonzero(out)[0]
        out[maybe] = _distinct_below_4(rec[:, maybe])
    return out


def column_extrema(rec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column (max, min) of ``rec`` (rows x columns), NaN where a column holds one. A reduction along the rows of a
    narrow C-ordered array runs one column at a time (15 channels x 16548 rows: ~0.6 ms each); reshaped to rows of
    ``64 x columns`` it runs across them (~0.03 ms), and max and min are exact whatever the grouping."""
    n, c = rec.shape
    k = 64
    m = n - n % k
    if m == 0:
        return rec.max(axis=0), rec.min(axis=0)
    head = rec[:m].reshape(m // k, k * c)
    hi = head.max(axis=0).reshape(k, c).max(axis=0)
    lo = head.min(axis=0).reshape(k, c).min(axis=0)
    if m < n:
        hi, lo = np.maximum(hi, rec[m:].max(axis=0)), np.minimum(lo, rec[m:].min(axis=0))
    return hi, lo


def _median_without(vals: np.ndarray, skip: np.ndarray) -> np.ndarray:
    """For each entry ``s`` of ``skip``: the median of ``vals`` without its element ``s`` (``-1``: of all of them),
    as ``np.median`` gives it (the mean of the two middle values for an even count), from one sort; 0 for none."""
    n = vals.size
    order = np.argsort(vals, kind="stable")
    srt = np.append(vals[order], 0.0)  # the extra slot is read only when nothing is left
    pos = np.empty(n, np.int64)
    pos[order] = np.arange(n)
    gone = np.where(skip >= 0, pos[np.maximum(skip, 0)] if n else n, n)  # sorted position removed (n: none)
    m = np.where(skip >= 0, n - 1, n)
    lo_i, hi_i = np.maximum((m - 1) // 2, 0), m // 2
    lo, hi = srt[lo_i + (lo_i >= gone)], srt[hi_i + (hi_i >= gone)]
    return np.where(m == 0, 0.0, np.where(m % 2 == 1, hi, 0.5 * (lo + hi)))


def _distinct_below_4(rec: np.ndarray) -> np.ndarray:
    """Per column: at most 3 distinct values — in O(n), without sorting."""
    mn, mx = rec.min(axis=0), rec.max(axis=0)
    mid = (rec != mn) & (rec != mx)
    has_mid = mid.any(axis=0)
    mid_lo = np.where(mid, rec, np.inf).min(axis=0)
    mid_hi = np.where(mid, rec, -np.inf).max(axis=0)
    return (mn == mx) | ~has_mid | (mid_lo == mid_hi)


@dataclass(frozen=True)
class ChannelJudgement:
    verdicts: dict[str, str]  # every channel: "ok" | "clipped" | "dead" | "stuck" | "excluded"
    why: dict[str, str]  # failed channels: what was seen
    unjudged: frozenset[str]  # "ok" channels whose life could not be checked on this hit (see the rule above)


def _flat_kind(x: np.ndarray) -> tuple[str, str]:
    """A flat record's verdict and why: ``stuck`` when it holds one value far from zero (a frozen front end or
    converter repeats its last reading: the value is not the sensor's rest, and the channel is not silent but
    lying), else ``dead`` (a sensor with no output reads zero plus the converter's last bit or two)."""
    lo, hi = float(x.min()), float(x.max())
    mid = 0.5 * (lo + hi)
    if mid != 0.0 and abs(mid) > 10.0 * (hi - lo):
        return "stuck", f"one value, {mid:.4g}, over the record while the others move"
    return "dead", "flat: at most 3 distinct values over the record"


def judge_channels(
    rec: np.ndarray, channels: tuple[str, ...], ranges: np.ndarray, force: int, pulse_start: int,
    sample_rate: float, exclude: Iterable[str] = (),
) -> ChannelJudgement:  # fmt: skip
    """Verdict of every channel of one hit record (``rec``: samples × channels, the pulse starting at row
    ``pulse_start``). The force channel can only be ``clipped`` (or ``dead`` if non-finite): it triggered,
    so it is alive. See the dead-channel rule above for the thresholds and the measurements behind them."""
    excl = set(exclude)
    n, nc = rec.shape
    if n:  # one pass for the extrema; a column is finite when both are (max and min propagate NaN)
        hi, lo = column_extrema(rec)
        finite = np.isfinite(hi) & np.isfinite(lo)
    else:
        finite = np.ones(nc, bool)
    if finite.all():
        safe = rec
        peak = np.maximum(hi, -lo) if n else np.zeros(nc)
    else:
        safe = np.where(np.isfinite(rec), rec, 0.0)
        hi, lo = column_extrema(safe)
        peak = np.maximum(hi, -lo)
    clipped = np.isfinite(ranges) & (peak >= ranges * CLIP_FRACTION) & finite
    flat = _flat(safe) if n else np.ones(nc, bool)
    resp = [k for k, c in enumerate(channels) if k != force and c not in excl]
    verdicts: dict[str, str] = {}
    why: dict[str, str] = {}
    for k, c in enumerate(channels):
        if c in excl and k != force:
            verdicts[c] = "excluded"
        elif not finite[k]:
            verdicts[c], why[c] = "dead", "non-finite samples in the record"
        elif clipped[k]:
            verdicts[c], why[c] = "clipped", f"reached its ±{ranges[k]:g} range"
        else:
            verdicts[c] = "ok"
    # flat: a fault only when it is the exception among the judged response channels
    live = [k for k in resp if finite[k]]
    flat_ok = [k for k in live if flat[k] and verdicts[channels[k]] == "ok"]
    unjudged: set[str] = set()
    if 2 * len([k for k in live if flat[k]]) < len(live):
        for k in flat_ok:
            verdicts[channels[k]], why[channels[k]] = _flat_kind(safe[:, k])
    else:
        unjudged.update(channels[k] for k in flat_ok)
    # silent: no response while the others clearly answered
    g = round(BASELINE_GUARD_S * sample_rate)
    base_end = max(0, pulse_start - g)
    post_end = min(n, pulse_start + max(1, round(RESPONSE_WINDOW_S * sample_rate)))
    cand = [k for k in resp if verdicts[channels[k]] == "ok" and channels[k] not in unjudged]
    ref = [k for k in live if not flat[k] and not clipped[k]]
    if not cand:
        return ChannelJudgement(verdicts, why, frozenset(unjudged))
    if base_end < MIN_BASELINE or post_end - pulse_start < MIN_RESPONSE or len(ref) < 2:
        unjudged.update(channels[k] for k in cand)
        return ChannelJudgement(verdicts, why, frozenset(unjudged))
    cols = sorted(set(cand) | set(ref))
    rise = dict(zip(cols, response_rise(safe[:base_end, cols], safe[pulse_start:post_end, cols]).tolist(), strict=True))
    ref_rise = np.array([rise[j] for j in ref])
    where = {j: i for i, j in enumerate(ref)}
    meds = _median_without(ref_rise, np.array([where.get(k, -1) for k in cand]))  # the other judged channels' median
    for k, med in zip(cand, meds.tolist(), strict=True):
        if med < LIVE_RISE:
            unjudged.add(channels[k])
        elif rise[k] <= DEAD_RISE:
            verdicts[channels[k]] = "dead"
            why[channels[k]] = f"no response: rose {rise[k]:.2f}x while the other channels' median rose {med:.0f}x"
    return ChannelJudgement(verdicts, why, frozenset(unjudged))


@dataclass(frozen=True)
class TriggerSettings:
    level: float  # N, rising edge on the hammer channel
    channel: str = "hammer"
    pre_trigger: float = 0.01  # s kept before the edge
    record_length: float = 1.0  # s after the edge
    hysteresis: float = 0.5  # re-arm below hysteresis × level
    force_range: tuple[float, float] | None = None  # requested peak force, N
    driving_point: str | None = None  # accelerometer at the hammer position, for the input energy
    suspect_after: int = 3
    required: tuple[str, ...] = ()  # response channels whose failure (clipped or dead) rejects the hit
    exclude: tuple[str, ...] = ()  # channels the gate ignores entirely (known bad or unused): never judged, never suspect
    # a roving-hammer plan's points in order, (the sensor at the point or None, its averages): the input energy is
    # computed where the hammer hits, each point until its accepted hits are in (as daq/roving.py PlanTracker), not
    # at the fixed ``driving_point`` (at another point F v integrates to any sign: negative energies, issue 29)
    roving: tuple[tuple[str | None, int], ...] = ()

    def __post_init__(self) -> None:
        if self.level <= 0 or self.pre_trigger < 0 or self.record_length <= 0 or not 0 < self.hysteresis <= 1:
            raise ValueError("trigger: level and record_length must be > 0, pre_trigger >= 0, 0 < hysteresis <= 1")
        object.__setattr__(self, "required", tuple(self.required))  # a config's lists, kept hashable
        object.__setattr__(self, "exclude", tuple(self.exclude))
        if self.channel in self.required or self.channel in self.exclude:
            raise ValueError(f"trigger: the force channel {self.channel!r} is always required: not in required/exclude")
        both = sorted(set(self.required) & set(self.exclude))
        if both:
            raise ValueError(f"trigger: channel {both[0]!r} is both required and excluded")


@dataclass(frozen=True)
class HitRecord:
    hit: int
    index: int  # sample index of the trigger edge
    t_s: float
    start_index: int
    end_index: int  # one past the last sample of the record
    peak_force_N: float
    pulse_width_s: float
    impulse_Ns: float
    input_energy_J: float | None  # None without a driving point, or when it failed on this hit
    verdict: str
    reasons: tuple[str, ...]  # failing checks first, then notes that do not change the verdict (excluded channels)
    clipped_channels: tuple[str, ...]  # every channel not excluded (force included) that reached its range
    data: np.ndarray = field(repr=False, compare=False)  # float32 (n, channels): the record itself
    channel_verdicts: dict[str, str] = field(default_factory=dict)  # every channel: ok | clipped | dead | excluded
    excluded_channels: tuple[str, ...] = ()  # response channels not usable for this hit (failed or configured out)

    def summary(self) -> dict:
        """The ``/daq/hits`` record (analysis/records.py ``Hit``) as JSON: the hit without its samples."""
        return Hit(
            self.hit, self.index, self.t_s, self.peak_force_N, self.pulse_width_s, self.input_energy_J, self.verdict,
            impulse_Ns=self.impulse_Ns, reason="; ".join(self.reasons) or "ok", clipped_channels=tuple(self.clipped_channels),
            start_index=self.start_index, end_index=self.end_index, channels=dict(self.channel_verdicts),
            excluded_channels=tuple(self.excluded_channels),
        ).to_json()  # fmt: skip


@dataclass
class ChannelHealth:
    """Per-channel tally over the hits so far: which failed how often, and on how many hits each could be judged.

    A hit counts for a channel only when it could be judged there: an ``excluded`` channel never, and an
    ``ok`` channel not when its life could not be checked (a weak tap nobody answered) — so one weak tap
    does not hide a dead channel, and a channel that cannot be judged is never accused."""

    hits: int = 0
    clipped: dict[str, int] = field(default_factory=dict)
    failures: dict[str, dict[str, int]] = field(default_factory=dict)  # channel -> {"clipped"|"dead"|"stuck": hits}
    judged: dict[str, int] = field(default_factory=dict)

    def update(self, verdicts: dict[str, str], unjudged: Iterable[str] = ()) -> None:
        """Count one hit: its verdict per channel, and the ``ok`` channels whose life could not be checked."""
        skip = set(unjudged)
        self.hits += 1
        for c, v in verdicts.items():
            if v == "excluded" or (v == "ok" and c in skip):
                continue
            self.judged[c] = self.judged.get(c, 0) + 1
            if v in ("clipped", "dead", "stuck"):
                kinds = self.failures.setdefault(c, {})
                kinds[v] = kinds.get(v, 0) + 1
                if v == "clipped":
                    self.clipped[c] = self.clipped.get(c, 0) + 1

    def suspect_reasons(self, after: int) -> dict[str, str]:
        """Channels that failed on every hit they could be judged on (at least ``after`` of them), with why."""
        out: dict[str, str] = {}
        for c in sorted(self.failures):
            kinds = self.failures[c]
            n, judged = sum(kinds.values()), self.judged.get(c, 0)
            if judged < after or n != judged:
                continue
            what = next(iter(kinds)) if len(kinds) == 1 else "failed"
            text = f"{what} on every one of {judged} hits"
            if len(kinds) > 1:
                text += " (" + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())) + ")"
            if judged < self.hits:
                text += f"; {self.hits - judged} more could not be judged"
            out[c] = text
        return out

    def suspects(self, after: int) -> list[str]:
        """Names of :meth:`suspect_reasons`, sorted."""
        return list(self.suspect_reasons(after))


class HitDetector:
    """Feed the blocks of one stream in order; get completed :class:`HitRecord` s back."""

    def __init__(
        self, settings: TriggerSettings, channels: tuple[str, ...], sample_rate: float, ranges: dict[str, float] | None = None
    ) -> None:
        if settings.channel not in channels:
            raise ValueError(f"trigger channel {settings.channel!r} is not among {list(channels)}")
        if settings.driving_point is not None and settings.driving_point not in channels:
            raise ValueError(f"driving-point channel {settings.driving_point!r} is not among {list(channels)}")
        for what, names in (("required", settings.required), ("excluded", settings.exclude)):
            unknown = [c for c in names if c not in channels]
            if unknown:
                raise ValueError(f"{what} channel {unknown[0]!r} is not among {list(channels)}")
        self.s = settings
        self.channels = tuple(channels)
        self.fs = float(sample_rate)
        self.h = self.channels.index(settings.channel)
        self.ranges = np.array([(ranges or {}).get(c, np.inf) for c in self.channels])
        self.n_pre = round(settings.pre_trigger * self.fs)
        self.n_post = round(settings.record_length * self.fs)
        self.health = ChannelHealth()
        self._ring = np.zeros((self.n_pre, len(self.channels)), np.float32)
        self._ring_fill = 0
        self._ring_end = 0  # sample index one past the ring's last sample
        self._armed = True
        self._rec: list[np.ndarray] | None = None
        self._rec_start = 0
        self._rec_edge = 0
        self._rec_have = 0
        self._next = None  # expected next sample index
        self._count = 0
        self._prev_force = 0.0
        self._rove = [0, 0]  # roving plan: current point, its accepted hits

    def driving_point(self) -> tuple[str | None, str]:
        """The response at the point being hit (a roving plan's current point's sensor, else the trigger's driving
        point) and, when there is none to use, why."""
        if not self.s.roving:
            return self.s.driving_point, ""
        sensor = self.s.roving[self._rove[0]][0]
        if sensor is None or sensor not in self.channels:
            return None, f"no input energy: no sensor of this stream at hit point {self._rove[0] + 1}"
        return sensor, ""

    def _advance(self) -> None:
        """An accepted hit counts for the current roving point; when it has its averages, the next point."""
        if not self.s.roving:
            return
        k, done = self._rove[0], self._rove[1] + 1
        if done >= self.s.roving[k][1] and k < len(self.s.roving) - 1:
            k, done = k + 1, 0
        self._rove = [k, done]

    # --- streaming ---------------------------------------------------------------------------
    def feed(self, block: SampleBlock) -> list[HitRecord]:
        out: list[HitRecord] = []
        data = block.data
        first = block.first_index
        if self._next is not None and first != self._next:
            if self._rec is not None:  # a gap cuts the record short
                out.append(self._close(truncated=f"data gap of {first - self._next} samples at index {self._next}"))
            self._ring_fill = 0
            self._prev_force = 0.0
        self._next = block.end_index
        pos = 0
        n = data.shape[0]
        while pos < n:
            if self._rec is not None:
                take = min(n - pos, self.n_pre + self.n_post - self._rec_have)
                self._rec.append(data[pos : pos + take])
                self._rec_have += take
                pos += take
                if self._rec_have >= self.n_pre + self.n_post:
                    out.append(self._close())
                continue
            f = data[pos:, self.h]
            if not self._armed:
                below = np.nonzero(f < self.s.hysteresis * self.s.level)[0]
                if below.size == 0:
                    self._push_ring(data[pos:], first + pos)
                    self._prev_force = float(f[-1])
                    break
                self._push_ring(data[pos : pos + below[0]], first + pos)
                pos += int(below[0])
                self._armed = True
                self._prev_force = float(data[pos - 1, self.h]) if pos > 0 else self._prev_force
                continue
            prev = np.concatenate([[self._prev_force], f[:-1]])
            edges = np.nonzero((f >= self.s.level) & (prev < self.s.level))[0]
            if edges.size == 0:
                self._push_ring(data[pos:], first + pos)
                self._prev_force = float(f[-1])
                break
            e = int(edges[0])
            self._push_ring(data[pos : pos + e], first + pos)
            self._start_record(first + pos + e)
            pos += e
        return out

    def finish(self) -> list[HitRecord]:
        """End of stream: a record still open is too short."""
        if self._rec is not None:
            return [self._close(truncated="the stream ended")]
        return []

    # --- internals -------------------------------------------------------------------------
    def _push_ring(self, rows: np.ndarray, first_index: int) -> None:
        if self.n_pre == 0 or rows.shape[0] == 0:
            return
        if rows.shape[0] >= self.n_pre:
            self._ring[:] = rows[-self.n_pre :]
            self._ring_fill = self.n_pre
        else:
            k = rows.shape[0]
            self._ring = np.roll(self._ring, -k, axis=0)
            self._ring[-k:] = rows
            self._ring_fill = min(self.n_pre, self._ring_fill + k)
        self._ring_end = first_index + rows.shape[0]

    def _start_record(self, edge: int) -> None:
        have = self._ring_fill if self._ring_end == edge else 0
        pre = self._ring[self.n_pre - have :] if have else np.zeros((0, len(self.channels)), np.float32)
        self._rec = [pre.copy()]
        self._rec_have = pre.shape[0]
        self._rec_start = edge - pre.shape[0]
        self._rec_edge = edge
        self._missing_pre = self.n_pre - pre.shape[0]
        self._armed = False
        self._ring_fill = 0

    def _close(self, truncated: str | None = None) -> HitRecord:
        assert self._rec is not None
        rec = np.concatenate(self._rec) if len(self._rec) > 1 else self._rec[0]
        self._rec = None
        self._ring_fill = 0
        # the tail of the record is the new pre-trigger history
        tail = rec[-self.n_pre :] if self.n_pre else rec[:0]
        self._push_ring(tail, self._rec_start + rec.shape[0] - tail.shape[0])
        self._prev_force = float(rec[-1, self.h]) if rec.shape[0] else 0.0
        self._armed = self._prev_force < self.s.hysteresis * self.s.level
        return self._judge(rec, truncated)

    def _judge(self, rec: np.ndarray, truncated: str | None) -> HitRecord:
        s, fs = self.s, self.fs
        f = rec[:, self.h].astype(np.float64)
        edge = self._rec_edge - self._rec_start
        after = f[edge:]
        low = np.nonzero(after < s.hysteresis * s.level)[0]
        end = edge + (int(low[0]) if low.size else after.size)  # end of the main pulse
        main = f[edge:end] if end > edge else f[edge : edge + 1]
        peak = float(main.max())
        k_peak = edge + int(main.argmax())
        lo = k_peak
        while lo > 0 and f[lo - 1] > 0.1 * peak:
            lo -= 1
        hi = k_peak
        while hi < f.size - 1 and f[hi + 1] > 0.1 * peak:
            hi += 1
        width = (hi - lo + 1) / fs
        impulse = float(f[lo : hi + 1].sum() / fs)
        judged = judge_channels(rec, self.channels, self.ranges, self.h, lo, fs, s.exclude)
        verdicts = judged.verdicts
        energy = None
        dp, why_not = self.driving_point()
        notes: list[str] = [why_not] if why_not else []  # reasons that do not change the verdict
        if dp is not None and verdicts[dp] != "ok":
            how = judged.why.get(dp, "excluded in the session")
            notes.append(f"no input energy: driving point {dp} {verdicts[dp]} ({how})")
        elif dp is not None:
            a = rec[:, self.channels.index(dp)].astype(np.float64)
            a = a - (a[:edge].mean() if edge > 0 else 0.0)
            v = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]))]) / fs
            v = v - v[lo]
            energy = float(np.sum(f[lo : hi + 1] * v[lo : hi + 1]) / fs)
        reasons: list[tuple[str, str]] = []
        if truncated is not None or rec.shape[0] < self.n_pre + self.n_post:
            got = (rec.shape[0] - (self._rec_edge - self._rec_start)) / fs
            reasons.append(("too_short", f"response too short: {got:.3f} s of {s.record_length:g} s ({truncated or 'cut'})"))
        if self._missing_pre:
            reasons.append(("too_short", f"pre-trigger incomplete: {self._missing_pre} samples missing before the edge"))
        clipped = tuple(c for c in self.channels if verdicts[c] == "clipped")
        gate = [s.channel, *s.required]  # channels whose failure rejects the hit
        gate_clipped = [c for c in gate if verdicts[c] == "clipped"]
        if gate_clipped:
            reasons.append(("overload", f"overload: {', '.join(gate_clipped)} reached the measurement range"))
        for c in gate:
            if verdicts[c] in ("dead", "stuck"):
                role = "force channel" if c == s.channel else "required channel"
                reasons.append(("overload", f"overload: {role} {c} dead ({judged.why[c]})"))
        excluded = tuple(c for c in self.channels if c != s.channel and verdicts[c] != "ok")
        notes[:0] = [f"{c} excluded: {verdicts[c]} ({judged.why[c]})" for c in excluded
                     if verdicts[c] != "excluded" and c not in s.required]  # fmt: skip
        again = np.nonzero((f[end:] >= s.level) & (np.concatenate([[0.0], f[end:-1]]) < s.level))[0] if end < f.size else []
        if len(again):
            k = end + int(again[0])
            reasons.append(
                (
                    "double_hit",
                    f"double hit: the force rose through {s.level:g} N again "
                    f"{1000 * (k - edge) / fs:.1f} ms after the first edge ({f[k:].max():.0f} N)",
                )
            )
        if s.force_range is not None and not s.force_range[0] <= peak <= s.force_range[1]:
            reasons.append(
                ("force_range", f"peak {peak:.0f} N outside the requested {s.force_range[0]:g}–{s.force_range[1]:g} N")
            )
        self.health.update(verdicts, judged.unjudged)
        hit = HitRecord(
            hit=self._count, index=self._rec_edge, t_s=self._rec_edge / fs, start_index=self._rec_start,
            end_index=self._rec_start + rec.shape[0], peak_force_N=peak, pulse_width_s=width, impulse_Ns=impulse,
            input_energy_J=energy, verdict=reasons[0][0] if reasons else "accepted",
            reasons=tuple(r for _, r in reasons) + tuple(notes), clipped_channels=clipped, data=rec,
            channel_verdicts=verdicts, excluded_channels=excluded,
        )  # fmt: skip
        self._count += 1
        if hit.verdict == "accepted":
            self._advance()
        return hit

    def suspects(self) -> list[str]:
        """Channels that failed on every hit they could be judged on so far (at least ``suspect_after``)."""
        return self.health.suspects(self.s.suspect_after)

    def suspect_reasons(self) -> dict[str, str]:
        """:meth:`suspects` with why, e.g. ``{"a09": "clipped on every one of 20 hits"}``."""
        return self.health.suspect_reasons(self.s.suspect_after)
