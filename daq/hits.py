"""Hammer trigger and hit quality gate: a streaming kernel fed with SampleBlocks.

What a GVT engineer expects of it (anchors: pyTrigger, pyFRF's ``is_data_ok``, Simcenter's Smart Hit
Selection — landscape.md §1a, §2.2–2.3):

* **Trigger** on the rising edge of the hammer force through ``level`` with ``pre_trigger`` seconds of
  history kept (a bounded ring buffer, never the whole run) and ``record_length`` seconds after the
  edge. It re-arms only after the force fell below ``hysteresis × level`` and the record is complete.
* **Record** per hit: trigger index and time, peak force, pulse width (time above 10 % of the peak
  around it), impulse, and the input energy ``∫ F v dt`` over the pulse when a driving-point
  accelerometer is named (velocity from its integrated acceleration, pre-trigger mean removed).
* **Verdict** with its reason, first failing check wins but every reason is listed: ``too_short``
  (a data gap or the end of the stream cut the record), ``overload`` (a channel reached its range —
  named), ``double_hit`` (the force crossed ``level`` again after the main pulse), ``force_range``
  (peak outside the requested range), else ``accepted``.
* **Suspect channels**: a channel that clipped on every one of at least ``suspect_after`` hits — the
  seed lost its 9th accelerometer that way and found out only afterwards (L1320).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.blocks import SampleBlock

#: A sample at or above this fraction of a channel's range counts as clipped: a saturated value comes
#: back through the ADC quantised up to one step below full scale (24 bit: 6e-4 of a 2 m/s^2 range).
CLIP_FRACTION = 0.999


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

    def __post_init__(self) -> None:
        if self.level <= 0 or self.pre_trigger < 0 or self.record_length <= 0 or not 0 < self.hysteresis <= 1:
            raise ValueError("trigger: level and record_length must be > 0, pre_trigger >= 0, 0 < hysteresis <= 1")


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
    input_energy_J: float | None
    verdict: str
    reasons: tuple[str, ...]
    clipped_channels: tuple[str, ...]
    data: np.ndarray = field(repr=False, compare=False)  # float32 (n, channels): the record itself

    def summary(self) -> dict:
        return {
            "hit": self.hit, "index": self.index, "t_s": self.t_s, "peak_force_N": self.peak_force_N,
            "pulse_width_s": self.pulse_width_s, "impulse_Ns": self.impulse_Ns, "input_energy_J": self.input_energy_J,
            "verdict": self.verdict, "reason": "; ".join(self.reasons) or "ok", "clipped_channels": list(self.clipped_channels),
            "start_index": self.start_index, "end_index": self.end_index,
        }  # fmt: skip


@dataclass
class ChannelHealth:
    hits: int = 0
    clipped: dict[str, int] = field(default_factory=dict)

    def update(self, clipped: tuple[str, ...]) -> None:
        self.hits += 1
        for c in clipped:
            self.clipped[c] = self.clipped.get(c, 0) + 1

    def suspects(self, after: int) -> list[str]:
        """Channels that clipped on every hit so far (once there were at least ``after`` hits)."""
        if self.hits < after:
            return []
        return sorted(c for c, n in self.clipped.items() if n == self.hits)


class HitDetector:
    """Feed the blocks of one stream in order; get completed :class:`HitRecord` s back."""

    def __init__(
        self, settings: TriggerSettings, channels: tuple[str, ...], sample_rate: float, ranges: dict[str, float] | None = None
    ) -> None:
        if settings.channel not in channels:
            raise ValueError(f"trigger channel {settings.channel!r} is not among {list(channels)}")
        if settings.driving_point is not None and settings.driving_point not in channels:
            raise ValueError(f"driving-point channel {settings.driving_point!r} is not among {list(channels)}")
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
        energy = None
        if s.driving_point is not None:
            a = rec[:, self.channels.index(s.driving_point)].astype(np.float64)
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
        clipped = tuple(
            c
            for c, r, col in zip(self.channels, self.ranges, rec.T, strict=True)
            if np.isfinite(r) and np.max(np.abs(col)) >= r * CLIP_FRACTION
        )
        if clipped:
            reasons.append(("overload", f"overload: {', '.join(clipped)} reached the measurement range"))
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
        self.health.update(clipped)
        hit = HitRecord(
            hit=self._count, index=self._rec_edge, t_s=self._rec_edge / fs, start_index=self._rec_start,
            end_index=self._rec_start + rec.shape[0], peak_force_N=peak, pulse_width_s=width, impulse_Ns=impulse,
            input_energy_J=energy, verdict=reasons[0][0] if reasons else "accepted",
            reasons=tuple(r for _, r in reasons), clipped_channels=clipped, data=rec,
        )  # fmt: skip
        self._count += 1
        return hit

    def suspects(self) -> list[str]:
        return self.health.suspects(self.s.suspect_after)
