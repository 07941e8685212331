"""The live FRF lane: after each hit, the hammer checks, the averaged FRFs and their peaks (issue 20, item 3).

The hit gate (:mod:`daq.lanes.hits`) sends its hits on ``/daq/hits`` through the Results router; this lane
gets them by :meth:`FRFLane.offer` (a bounded queue: a hit that does not fit is dropped and counted) and
the samples by its own fan-out subscription, of which it keeps a bounded ring of the hammer's stream
(two records, the pre-trigger and one second: the gate reports a hit a record after its trigger). When a
hit's record ``[index - pre, index - pre + n)`` is in the ring, it is judged exactly as ``gvt frf`` judges
it (daq/studies/frf.py: the gate's verdict, a complete record, :func:`analysis.hammer.check_hit`) and an
accepted hit is added to an :class:`~analysis.frf.FRFAccumulator` (one FFT of the record, whatever the
number of hits so far). Per hit it publishes a small :class:`~analysis.records.FRFUpdate` on
``/analysis/frf`` (averages, peaks, coherence at the peaks: never the FRF arrays), one terminal line
(``say``) and, for the live view, the curves of the driving point and one chosen response (``view``).

Record and window are ``gvt frf``'s (:mod:`daq.studies.frf`): ``n`` = the rig's record length, the exponential
window's ``tau`` from the rig's lowest mode (:func:`analysis.frf.choose_tau`), the band 1000 Hz (fs / 2.56 when
lower: :func:`default_band`). One
difference, because a live lane cannot know later hits: ``gvt frf`` shortens every record to the smallest
spacing between hits, while this lane refuses a hit whose record holds the next hit it knows of. With
hits at least a record apart both average the same records and give the same FRFs (tests/test_frf_lane.py).

Several devices (two DAQs on one timeline, docs/session.md): the lane keeps a ring per stream and cuts each
stream's part of a record at the hit's index less the timeline's applied offset (the hit gate's aligner), so
the responses on the accelerometer device meet the force on the hammer device (tests/test_frf_lab.py).

Rules of the recording path (daq/lanes/__init__.py): ``offer`` never blocks, the subscription is bounded
(the fan-out drops this lane's blocks and counts them; a hit whose record lost samples is refused with
that reason), and an exception in the lane is one ``frf_error`` event, never the end of a recording.
"""

from __future__ import annotations

import dataclasses
import queue
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.frf import FRFAccumulator, FRFSet, choose_tau, stack_references
from analysis.frf_setup import PRE_TRIGGER_S, default_band, force_full_scale, lowest_decay_rate
from analysis.hammer import check_hit, force_spectrum, level_db
from analysis.records import FRF_TOPIC, PLAN_TOPIC, FRFUpdate, PlanRecord
from daq.fanout import END, FanOut, Subscription
from daq.lanes import Sink
from daq.log import layout
from daq.roving import PlanTracker
from drivers.blocks import SampleBlock

#: the view's topic for the curves of one update (in-process only: never written to a log)
FRF_CURVES = "frf/curves"
N_PEAKS = 6  # peaks in each update, as gvt frf's table
MIN_RECORD_S = 0.1  # the live record is not shortened below this (FRFLane._shorten): df 10 Hz
#: the log attachment holding a roving-hammer session's FRF matrix (analysis.frf.FRFSet.to_npz)
MATRIX_ATTACHMENT = "frf/matrix.npz"


@dataclass(frozen=True)
class FRFPlan:
    """What the lane computes, fixed at the start: the stream, its columns, record, window and band."""

    stream: str
    channels: tuple[str, ...]  # the stream's channels, in its order
    reference: str  # the force channel
    outputs: tuple[str, ...]  # responses, in the stream's order (as gvt frf)
    quantities: tuple[str, ...]  # acceleration | velocity | displacement per output
    fs: float
    n: int  # record samples
    pre: int  # pre-trigger samples
    tau: float | None
    band_hz: float
    full_scale: float  # the hammer channel's full scale, N
    driving_point: str | None  # the output at the reference's DOF
    shown: str  # the other response drawn in the view
    # responses on other devices' streams (two devices on one timeline: the hammer on one, accelerometers on
    # another): (stream, its channels), each cut at the hit's index less the timeline's applied offset
    others: tuple[tuple[str, tuple[str, ...]], ...] = ()
    sigma1: float = 0.0  # decay rate of the rig's lowest mode, 1/s: tau again when the record is shortened

    @property
    def layout(self) -> list[tuple[str, list[int]]]:
        """Per stream, its columns of the reference and the outputs: concatenated in this order they are the
        reference then the outputs (the outputs are listed stream by stream, the hammer's stream first)."""
        want, taken, out = (self.reference, *self.outputs), set(), []
        for stream, chans in ((self.stream, self.channels), *self.others):
            cols = [c for c in want if c in chans and c not in taken]
            taken.update(cols)
            out.append((stream, [chans.index(c) for c in cols]))
        return out


def frf_plan(rig, streams: dict[str, tuple[str, ...]], fs: float, band_hz: float | None = None, end_level: float = 1e-3,
             shown: str | None = None) -> FRFPlan | None:  # fmt: skip
    """The plan for ``rig`` on the session's ``streams``; None when the rig has no hammer or sensors, or no
    stream carries the hammer, or none carries a sensor (the lane is then off). The responses are the hammer
    stream's sensors, then those of the other streams (several devices: placed by the timeline's offsets).
    ``band_hz``: the band of interest (default :func:`default_band`)."""
    hammer, sensors = getattr(rig, "hammer", None), tuple(getattr(rig, "sensors", ()) or ())
    if hammer is None or not sensors:
        return None
    quantity = {s.name: s.quantity for s in sensors if s.quantity != "force"}
    with_hammer = [n for n in sorted(streams) if hammer.name in streams[n]]
    stream = next((n for n in with_hammer if any(c in quantity for c in streams[n])), with_hammer[0] if with_hammer else None)
    if stream is None:
        return None
    chans = tuple(streams[stream])
    others = tuple((s, tuple(ch)) for s, ch in streams.items() if s != stream and any(c in quantity for c in ch))
    outs = tuple(c for c in chans if c in quantity and c != hammer.name)
    outs += tuple(c for _s, ch in others for c in ch if c in quantity and c != hammer.name and c not in outs)
    if not outs:
        return None
    band_hz = default_band(fs) if band_hz is None else band_hz
    n = round(rig.config.daq.record_length * fs)
    dp = next((s.name for s in sensors if s.dof == hammer.dof and s.name in outs), None)
    pick = shown if shown in outs else outs[-1]
    tau = choose_tau(lowest_decay_rate(rig), n / fs, end_level)
    return FRFPlan(stream=stream, channels=chans, reference=hammer.name, outputs=outs,
                   quantities=tuple(quantity[c] for c in outs), fs=float(fs), n=n, pre=round(PRE_TRIGGER_S * fs), tau=tau,
                   band_hz=float(band_hz), full_scale=force_full_scale(rig), driving_point=dp, shown=pick,
                   others=others, sigma1=lowest_decay_rate(rig))  # fmt: skip


class SampleRing:
    """The last ``capacity`` samples of one stream (contiguous: a gap restarts it), for cutting hit records.

    A linear buffer twice the capacity, compacted when full: appending is one copy, a record is a view."""

    def __init__(self, capacity: int, n_channels: int) -> None:
        self.capacity = int(capacity)
        self.buf = np.zeros((2 * self.capacity, n_channels), dtype=np.float32)
        self.start = 0  # absolute index of buf[self.lo]
        self.lo = 0
        self.hi = 0

    @property
    def end(self) -> int:
        return self.start + self.hi - self.lo

    def append(self, first_index: int, rows: np.ndarray) -> None:
        m = rows.shape[0]
        if first_index != self.end or m > self.capacity:  # a gap (or a first block): start again at this block
            rows = rows[-self.capacity :]
            first_index += m - rows.shape[0]
            self.start, self.lo, self.hi = first_index, 0, 0
            m = rows.shape[0]
        if self.hi + m > self.buf.shape[0]:  # compact: keep the last capacity - m rows
            keep = max(0, min(self.hi - self.lo, self.capacity - m))
            self.buf[:keep] = self.buf[self.hi - keep : self.hi]
            self.start += self.hi - self.lo - keep
            self.lo, self.hi = 0, keep
        self.buf[self.hi : self.hi + m] = rows
        self.hi += m
        if self.hi - self.lo > self.capacity:
            drop = self.hi - self.lo - self.capacity
            self.lo += drop
            self.start += drop

    def span(self, lo: int, hi: int) -> np.ndarray | None:
        """Rows ``[lo, hi)`` (absolute indices), or None unless all of them are held."""
        if lo < self.start or hi > self.end:
            return None
        a = self.lo + lo - self.start
        return self.buf[a : a + hi - lo]


def peak_summary(frf: FRFSet, driving_point: str | None, n_peaks: int = N_PEAKS) -> dict:
    """Peaks of the mode indicator (as ``gvt frf``'s table) with the driving point's |H| and coherence there and
    the lowest coherence over all responses."""
    pk = frf.peaks(n_peaks)
    o = frf.outputs.index(driving_point) if driving_point in frf.outputs else None
    coh = frf.coherence[:, 0, :]
    return {
        "peaks_hz": tuple(float(f) for f in frf.freq[pk]),
        "dp_mag": tuple(float(abs(frf.H[o, 0, k])) for k in pk) if o is not None else (),
        "dp_coherence": tuple(float(coh[o, k]) for k in pk) if o is not None else (),
        "min_coherence": tuple(float(coh[:, k].min()) for k in pk),
    }  # fmt: skip


def view_curves(frf: FRFSet, plan: FRFPlan, force: np.ndarray, t_s: float) -> dict:
    """What the view draws after an accepted hit: magnitude, phase and coherence of the driving point and the
    shown response, the hit's hammer spectrum (dB re. DC, up to twice the band) and the averages."""
    chans = [c for c in dict.fromkeys([plan.driving_point, plan.shown]) if c is not None]
    ff, mag = force_spectrum(force, plan.fs)
    k = int(np.searchsorted(ff, 2.0 * plan.band_hz))
    curves = {}
    for c in chans:
        o = frf.outputs.index(c)
        h = frf.H[o, 0]
        curves[c] = {"mag": np.abs(h), "phase_deg": np.degrees(np.angle(h)), "coherence": frf.coherence[o, 0]}
    return {"t_s": t_s, "averages": int(frf.n_averages[0]), "freq": frf.freq, "units": frf.units, "curves": curves,
            "driving_point": plan.driving_point, "force_freq": ff[:k], "force_db": level_db(mag)[:k],
            "band_hz": plan.band_hz}  # fmt: skip


def warm_up(plan: FRFPlan) -> float:
    """One throwaway hit through every step (checks, accumulator, FRF, peaks, curves) *now*, before a device
    streams; returns the seconds it took. Why: the first hit in a fresh process cost 553 ms against 2-13 ms
    for the next ones (scipy.fft, scipy.signal.find_peaks and their plans loaded on first use; measured on
    the 15-channel 16384 Hz replay of tests/test_frf_lane.py) — ten times the budget, on the first hit."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    force = np.zeros(plan.n)
    force[plan.pre : plan.pre + 8] = np.hanning(8)
    acc = FRFAccumulator(plan.fs, plan.n, list(plan.outputs), plan.reference, tau=plan.tau, t0=plan.pre / plan.fs,
                         f_max=plan.band_hz, quantities=list(plan.quantities))  # fmt: skip
    check_hit(force, plan.fs, plan.band_hz, plan.full_scale)
    acc.add(force, 1e-3 * rng.standard_normal((plan.n, len(plan.outputs))))
    view_curves(frf := acc.frf(), plan, force, 0.0)
    peak_summary(frf, plan.driving_point)
    return time.perf_counter() - t0


class FRFLane:
    """Hits in (:meth:`offer`), records from the ring, one :class:`FRFUpdate` per hit out; on its own thread."""

    name = "frf"

    def __init__(self, fan: FanOut, plan: FRFPlan, sink: Sink, *, say: Callable[[str], None] | None = None,
                 view: Callable[[str, dict], None] | None = None, maxsize: int = 256, hit_queue: int = 1024,
                 points: tuple | None = None, attach: Callable[[str, bytes, str], None] | None = None,
                 offsets: Callable[[], dict[str, int] | None] | None = None, lead_s: float = 0.0) -> None:  # fmt: skip
        """``offsets``: the timeline's applied offsets (reference index = stream index + offset; the hit gate's
        aligner, None until fixed) when the plan reads other streams; ``lead_s``: how far a stream may run ahead
        of the hits (the aligner's buffer), added to every ring."""
        self.plan = plan
        self.offsets = offsets
        self.attach = attach
        self.tracker = None if not points else PlanTracker(tuple(points))
        self.sink, self.say, self.view = sink, say, view
        self.sub: Subscription = fan.subscribe("frf", maxsize=maxsize)
        self.hits: queue.Queue = queue.Queue(maxsize=max(1, hit_queue))
        self.dropped_hits = 0
        cap = 2 * plan.n + plan.pre + round(plan.fs * (1.0 + lead_s))
        self.rings = {s: SampleRing(cap, len(ch)) for s, ch in ((plan.stream, plan.channels), *plan.others)}
        self.ring = self.rings[plan.stream]  # the hammer's stream
        # one accumulator per reference: the hammer, or each hit point of a roving-hammer plan (daq/roving.py)
        self.accs = self._accumulators()
        self.records: list[FRFUpdate] = []
        self.costs_s: list[float] = []  # computing time per hit (wall clock)
        # the lane thread's own CPU time per hit: what the lane costs, whatever else the machine is doing (a
        # loaded test run stretches the wall clock, not this)
        self.cpu_costs_s: list[float] = []
        self._c0 = 0.0
        self.error: str | None = None
        self._pending: list[dict] = []
        self._layout = plan.layout
        self._hits_done = threading.Event()
        self._thread = threading.Thread(target=self._main, name="frf", daemon=True)
        warm_up(plan)

    def _accumulators(self) -> list[FRFAccumulator]:
        """One accumulator per reference: the hammer, or each hit point of a roving-hammer plan (daq/roving.py)."""
        p = self.plan
        return [FRFAccumulator(p.fs, p.n, list(p.outputs), p.reference, tau=p.tau, t0=p.pre / p.fs, f_max=p.band_hz,
                               quantities=list(p.quantities), end_level=1e-3)
                for _ in (self.tracker.points if self.tracker is not None else (None,))]  # fmt: skip

    def _shorten(self, hit: dict, nxt: int) -> bool:
        """Before any hit is averaged, a record that holds the next hit: shorten the record to the hits' spacing, as
        ``gvt frf`` does afterwards (the smallest spacing), and say so; True if it was shortened.

        Why: the shipped CAN, Modbus and two-device sessions hit every 0.5-0.8 s, under the rig's 2 s record; a lane
        that refused every hit as "record holds the next hit" averaged nothing all session while ``gvt frf`` on the
        log worked. Only before the first average (the sums of two record lengths do not add), and not below
        ``MIN_RECORD_S``: a later, closer hit is refused with its reason, on screen."""
        p = self.plan
        n = nxt - int(hit["index"])
        if any(a.count for a in self.accs) or n >= p.n or n < round(MIN_RECORD_S * p.fs):
            return False
        self.plan = dataclasses.replace(p, n=n, tau=choose_tau(p.sigma1, n / p.fs, 1e-3))
        self.accs = self._accumulators()
        if self.say is not None:
            self.say(f"live FRF: hits {n / p.fs:.3f} s apart, under the {p.n / p.fs:g} s record: records shortened to "
                     f"{n / p.fs:.3f} s (df {p.fs / n:.2f} Hz), as gvt frf does; a closer hit is refused")  # fmt: skip
        return True

    def _next_hit(self, i0: int) -> int | None:
        """The index of a pending hit whose record starts inside the record starting at ``i0``."""
        p = self.plan
        return next((int(h["index"]) for h in self._pending if i0 < int(h["index"]) - p.pre < i0 + p.n), None)

    @property
    def acc(self) -> FRFAccumulator:
        """The accumulator the next accepted hit joins (the current hit point's)."""
        return self.accs[self.tracker.current if self.tracker is not None else 0]

    def _dp_plan(self) -> FRFPlan:
        """The plan with the driving point of the current hit point (the sensor on its DOF, if any)."""
        if self.tracker is None:
            return self.plan
        pt = self.tracker.point
        dp = next((s for s in self.plan.outputs if s == pt.sensor), None)
        return dataclasses.replace(self.plan, reference=pt.name, driving_point=dp)

    def _plan_record(self, event: str, **kw) -> None:
        t = self.tracker
        assert t is not None
        done = {"point": t.point.name, "done": t.done[t.current], "required": t.point.averages}
        rec = PlanRecord(event=event, next_point=None if t.complete else t.point.name, message=t.prompt(), **{**done, **kw})
        self.sink(PLAN_TOPIC, rec, None)
        if self.say is not None:
            self.say(rec.message)

    def start(self) -> FRFLane:
        if self.tracker is not None:
            self._plan_record("plan", points=tuple(p.as_dict() for p in self.tracker.points))
        self._thread.start()
        return self

    def offer(self, topic: str, obj: dict) -> None:
        if topic != layout.HITS_TOPIC:
            return
        try:
            self.hits.put_nowait(dict(obj))
        except queue.Full:
            self.dropped_hits += 1

    # --- thread -------------------------------------------------------------------------------------------
    def _main(self) -> None:
        ended = False
        try:
            while True:
                if not ended:
                    try:
                        item = self.sub.get(timeout=0.05)
                    except queue.Empty:
                        item = None
                    if item is END:
                        ended = True
                    elif item is not None and item.stream in self.rings:
                        self._block(item)
                done = ended and self._hits_done.is_set()
                self._take_hits()
                self._process(final=done and self.hits.empty())
                if done and self.hits.empty():
                    return
                if ended:
                    self._hits_done.wait(0.05)
        except Exception as exc:  # said in the log; the recording goes on without live FRFs
            self.error = f"{type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "frf_error", "message": f"live FRFs stopped: {self.error}"}, None)
            while not ended and self.sub.get() is not END:
                pass

    def _block(self, blk: SampleBlock) -> None:
        self.rings[blk.stream].append(blk.first_index, blk.data)

    def _offset(self, stream: str) -> int | None:
        """Samples to add to ``stream``'s index for the hits' (reference) index: 0 with one stream, the timeline's
        applied offset with several (None while it is not fixed)."""
        if not self.plan.others:
            return 0
        applied = self.offsets() if self.offsets is not None else None
        return None if applied is None or stream not in applied else int(applied[stream])

    def _arriving(self, i0: int) -> bool:
        """Whether some stream's part of the record ``[i0, i0 + n)`` (hits' index) is still to come: the ring has
        not reached its end yet and has not restarted past its start (a gap: it never will)."""
        for s, ring in self.rings.items():
            off = self._offset(s)
            if off is not None and i0 - off + self.plan.n > ring.end and i0 - off >= ring.start:
                return True
        return False

    def _take_hits(self) -> None:
        while True:
            try:
                self._pending.append(self.hits.get_nowait())
            except queue.Empty:
                break
        self._pending.sort(key=lambda h: int(h["index"]))

    def _process(self, final: bool) -> None:
        """Judge the pending hits in index order, as far as their records are in (all of them when ``final``)."""
        p = self.plan
        while self._pending:
            hit = self._pending[0]
            i0 = int(hit["index"]) - p.pre
            if hit.get("verdict") == "accepted" and not final and self._arriving(i0):
                return  # the record is still arriving
            self._pending.pop(0)
            self._judge(hit, i0)

    def _judge(self, hit: dict, i0: int) -> None:
        t0 = time.perf_counter()
        self._c0 = time.thread_time()
        rec, missing = self._record(i0)
        nxt = self._next_hit(i0)
        if nxt is not None and rec is not None and hit.get("verdict") == "accepted" and self._shorten(hit, nxt):
            rec, missing = self._record(i0)
            nxt = self._next_hit(i0)
        p = self.plan
        checks, why, force = None, None, None
        if hit.get("verdict") != "accepted":
            why = f"hit gate: {hit.get('reason') or hit.get('verdict')}"
        elif rec is None:
            why = f"record incomplete: {missing}"
        elif nxt is not None:
            why = f"record holds the next hit ({(nxt - i0 - p.pre) / p.fs:.3f} s after this one; gvt frf shortens the records)"
        else:
            data = rec
            chk = check_hit(data[:, 0], p.fs, p.band_hz, p.full_scale)
            checks = chk.as_dict()
            if chk.verdict == "accepted":
                force = data[:, 0]
                excluded = hit.get("excluded_channels") or ()  # the gate's per-channel verdicts: a clipped response
                self.acc.add(force, data[:, 1:], use=[o not in excluded for o in self.plan.outputs])
            else:
                why = chk.reason
        self._publish(hit, why, checks, force, t0)
        if self.tracker is not None:
            self._progress(hit, why)

    def _record(self, i0: int) -> tuple[np.ndarray | None, str]:
        """The record ``[i0, i0 + n)`` (hits' index): the reference then the outputs, cut from each stream's ring
        at its offset; or None and why not."""
        n, parts = self.plan.n, []
        for s, cols in self._layout:
            off, ring = self._offset(s), self.rings[s]
            if off is None:
                return None, f"no timeline offset for stream {s} (not fixed yet)"
            rows = ring.span(i0 - off, i0 - off + n)
            if rows is None:
                at = f" of stream {s} (offset {off})" if self.plan.others else ""
                return None, (f"samples {i0 - off}..{i0 - off + n}{at} not all held (end of data, a gap, or the lane fell "
                              f"behind; held {ring.start}..{ring.end})")  # fmt: skip
            parts.append(rows[:, cols])
        return np.concatenate(parts, axis=1).astype(float), ""

    def _progress(self, hit: dict, why: str | None) -> None:
        """After a hit at the current point: count it, move on when the point has its averages, prompt."""
        t = self.tracker
        assert t is not None
        pt, k = t.point, t.current
        moved = why is None and t.accept()
        event = "complete" if moved and t.complete else "progress"
        self._plan_record(event, point=pt.name, done=t.done[k], required=pt.averages, hit=int(hit.get("hit", -1)),
                          verdict="refused" if why else "accepted")  # fmt: skip

    def _publish(self, hit: dict, why: str | None, checks: dict | None, force: np.ndarray | None, t0: float) -> None:
        p = self._dp_plan()
        frf = self.acc.frf() if self.acc.count else None
        peaks = peak_summary(frf, p.driving_point) if frf is not None else {}
        refused = sum(r.verdict == "refused" for r in self.records) + (why is not None)
        t_s = float(hit.get("t_s", int(hit["index"]) / p.fs))
        curves = view_curves(frf, p, force, t_s) if frf is not None and force is not None and self.view is not None else None
        elapsed = time.perf_counter() - t0
        rec = FRFUpdate(hit=int(hit.get("hit", -1)), index=int(hit["index"]), t_s=t_s, reference=p.reference,
                        verdict="refused" if why else "accepted", reason=why or "ok", averages=self.acc.count, refused=refused,
                        driving_point=p.driving_point, record_s=p.n / p.fs, tau_s=p.tau, band_hz=p.band_hz, checks=checks,
                        elapsed_s=elapsed, **peaks)  # fmt: skip
        self.costs_s.append(elapsed)
        self.cpu_costs_s.append(time.thread_time() - self._c0)
        self.records.append(rec)
        self.sink(FRF_TOPIC, rec, round(t_s * 1e9))
        if self.say is not None:
            from daq.terminal import frf_line

            self.say(frf_line(rec))
        if curves is not None and self.view is not None:
            self.view(FRF_CURVES, curves)

    # --- end ----------------------------------------------------------------------------------------------
    def finish(self, deadline: float) -> None:
        """After the hit gate finished (its last hits are offered): judge what is left, then say what was lost."""
        self._hits_done.set()
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self.tracker is not None and not self._thread.is_alive():
            self._write_matrix()
        if self.sub.dropped_blocks or self.dropped_hits:
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "frf_overrun", "count": self.sub.dropped_samples,
                "message": f"live FRFs fell behind: {self.sub.dropped_blocks} blocks ({self.sub.dropped_samples} samples) "
                           f"and {self.dropped_hits} hits not seen; hits whose record lost samples were refused",
            }, None)  # fmt: skip

    def matrix(self) -> FRFSet | None:
        """The FRF matrix: every hit point with at least one average, one reference each, named by the point."""
        t = self.tracker
        assert t is not None
        sets = [dataclasses.replace(a.frf(), references=[p.name]) for a, p in zip(self.accs, t.points, strict=True) if a.count]
        return stack_references(sets) if sets else None

    def _write_matrix(self) -> None:
        """At the end: the ``end`` plan record (points short of their averages) and the matrix as ``frf/matrix.npz``."""
        t = self.tracker
        assert t is not None
        self._plan_record("end", missing=tuple(t.missing()))
        m = self.matrix()
        if m is None or self.attach is None:
            return
        with tempfile.TemporaryDirectory() as tmp:  # to_npz writes a path
            path = Path(tmp) / "matrix.npz"
            m.to_npz(path)
            self.attach(MATRIX_ATTACHMENT, path.read_bytes(), "application/x-npz")


def start_frf_lane(fan: FanOut, rig, streams: dict[str, tuple[str, ...]], fs: float, sink: Sink, **kw) -> FRFLane | None:
    """The lane for ``rig`` on ``streams`` (started), or None when the rig has no hammer and sensors on one stream.
    ``kw``: ``say``, ``view``, ``maxsize`` of :class:`FRFLane`."""
    plan = frf_plan(rig, streams, fs)
    return None if plan is None else FRFLane(fan, plan, sink, **kw).start()
