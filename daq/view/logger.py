"""ViewLogger: blocks and results in, rerun entities out — the one piece the live lane and the offline
builder share, so both draw the same picture (docs/view.md).

It keeps only bounded state: per stream the rows of an unfinished display bucket, a few seconds of the
sensor stream (for POM shapes of IR events and the wavelet spectrum of a hit record) and the recent modal
windows (to pair RQ windows with energies for the RQ-FEP).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import rerun as rr
import scipy.signal

from analysis.pod import pod
from analysis.records import FRF_TOPIC
from analysis.wavelet import morlet_cwt
from daq.lanes.frf import FRF_CURVES
from daq.log import layout
from daq.view import recording as R
from daq.view.setup import ViewSetup  # also re-exported: the view lane and the .rrd builder take it from here
from drivers.blocks import SampleBlock


@dataclass
class _Pending:
    first: int
    parts: list[np.ndarray] = field(default_factory=list)
    n: int = 0


class ViewLogger:
    def __init__(
        self, rec: rr.RecordingStream, setup: ViewSetup, bucket_hz: float = 500.0, flush_s: float = 0.5,
        pom_step_s: float = 0.5, pom_window_s: float = 0.1, history_s: float = 4.0, wavelet_record_s: float = 0.5,
        pom_rows: int = 2048,
    ) -> None:  # fmt: skip
        self.rec = rec
        self.s = setup
        fs = setup.sample_rate
        self.bucket = max(1, round(fs / bucket_hz))
        self.flush_rows = max(self.bucket, round(flush_s * fs / self.bucket) * self.bucket)
        self._pending: dict[str, _Pending] = {}
        self.sensor_stream = next(
            (n for n in sorted(setup.streams) if setup.sensors and all(c in setup.streams[n] for c in setup.sensors)), None
        )
        cols = setup.streams.get(self.sensor_stream, ())
        self._sensor_cols = [cols.index(c) for c in setup.sensors] if self.sensor_stream else []
        self._x = np.asarray(setup.sensor_x, float)
        self._hist: deque[tuple[int, np.ndarray]] = deque()  # (first index, sensor rows) of the sensor stream
        self._hist_rows = 0
        self._hist_max = int(history_s * fs)
        self._wave_stream = next((n for n in sorted(setup.streams) if setup.wavelet_channel in setup.streams[n]), None)
        self._wave_hist: deque[tuple[int, np.ndarray]] = deque()
        self._pom_step = max(2, int(pom_step_s * fs))
        self._pom_len = max(2, int(pom_window_s * fs))
        self._next_pom: int | None = None
        self._modal_t: deque[float] = deque(maxlen=4096)
        self._modal_e: deque[float] = deque(maxlen=4096)
        self._wave_len = wavelet_record_s
        self.pom_rows = max(2, pom_rows)
        self._wave_pending: list[dict] = []  # hits whose record is not all in the history yet
        self.t_now = 0.0
        self.counts: dict[str, int] = {}
        R.log_styles(rec, setup.streams, setup.hammer, setup.n_nnm, setup.n_modes)

    # --- samples ----------------------------------------------------------------------------------
    def block(self, blk: SampleBlock) -> None:
        p = self._pending.get(blk.stream)
        if p is not None and p.first + p.n != blk.first_index:  # a gap (or the view's own drop): flush what we have
            self._flush(blk.stream, final=True)
            p = None
        if p is None:
            p = self._pending[blk.stream] = _Pending(blk.first_index)
        p.parts.append(blk.data)
        p.n += blk.n_samples
        if p.n >= self.flush_rows:
            self._flush(blk.stream)
        self.t_now = max(self.t_now, blk.end_index / blk.sample_rate)
        if blk.stream == self.sensor_stream:
            self._remember(self._hist, blk.first_index, blk.data[:, self._sensor_cols])
            self._current_pom(blk.end_index)
        if blk.stream == self._wave_stream:
            self._remember(self._wave_hist, blk.first_index, blk.data[:, [blk.channels.index(self.s.wavelet_channel)]])
            if self._wave_pending:
                waiting, self._wave_pending = self._wave_pending, []
                for h in waiting:
                    self._wavelet(h)

    def _flush(self, stream: str, final: bool = False) -> None:
        p = self._pending.pop(stream, None)
        if p is None or p.n == 0:
            return
        data = np.concatenate(p.parts) if len(p.parts) > 1 else p.parts[0]
        # buckets sit on absolute multiples of `bucket`: a partial first bucket is drawn as its own bucket
        head = (-p.first) % self.bucket
        first = p.first
        if head and head <= data.shape[0]:
            R.log_envelopes(self.rec, stream, self.s.streams[stream], self.s.hammer, first, self.s.sample_rate, data[:head], head)
            data, first = data[head:], first + head
        used = R.log_envelopes(
            self.rec, stream, self.s.streams[stream], self.s.hammer, first, self.s.sample_rate, data, self.bucket
        )
        rest = data[used:]
        if rest.shape[0] and final:
            R.log_envelopes(
                self.rec, stream, self.s.streams[stream], self.s.hammer, first + used, self.s.sample_rate, rest, rest.shape[0]
            )
        elif rest.shape[0]:
            self._pending[stream] = _Pending(first + used, [rest], rest.shape[0])

    def _remember(self, hist: deque, first: int, rows: np.ndarray) -> None:
        if hist and hist[-1][0] + hist[-1][1].shape[0] != first:
            hist.clear()  # gaps break the record; keep only contiguous data
        hist.append((first, rows))
        total = hist[-1][0] + rows.shape[0] - hist[0][0]  # contiguous: the rows held are end - first
        while hist and total - hist[0][1].shape[0] >= self._hist_max:
            total -= hist.popleft()[1].shape[0]

    @staticmethod
    def _span(hist: deque, lo: int, hi: int) -> np.ndarray | None:
        """Rows [lo, hi) from the history, or None if they are not all there."""
        if not hist or lo < hist[0][0] or hi > hist[-1][0] + hist[-1][1].shape[0] or hi <= lo:
            return None
        parts = [r[max(0, lo - f) : max(0, hi - f)] for f, r in hist if f < hi and f + r.shape[0] > lo]
        return np.concatenate(parts) if parts else None

    def _current_pom(self, end: int) -> None:
        if self._next_pom is None:
            self._next_pom = end - end % self._pom_step + self._pom_step
        if end < self._next_pom:
            return
        x = self._span(self._hist, end - self._pom_len, end)
        self._next_pom = end - end % self._pom_step + self._pom_step
        if x is not None and np.ptp(x, axis=0).max() > 0:
            self._log_pom(R.POM_CURRENT, end / self.s.sample_rate, x)

    def _log_pom(self, path: str, t: float, x: np.ndarray) -> None:
        # a display shape: every q-th row keeps the covariance (and so the POMs) to display accuracy while the
        # SVD of an event's seconds of data (16384 rows/s) would cost ms each
        q = max(1, x.shape[0] // self.pom_rows)
        poms, povs = pod(x[::q].astype(np.float64))
        k = min(self.s.n_nnm, poms.shape[1])
        R.log_pom(self.rec, path, t, self._x, poms[:, :k], povs[:k])
        self._count(path.rsplit("/", 1)[0] if path.startswith(R.POM_EVENTS) else path)

    def finish(self) -> None:
        waiting, self._wave_pending = self._wave_pending, []
        for h in waiting:
            self._wavelet(h, final=True)
        for s in list(self._pending):
            self._flush(s, final=True)

    # --- results ----------------------------------------------------------------------------------
    def result(self, topic: str, obj: dict) -> None:
        self.results(topic, [obj])

    def results(self, topic: str, objs: list[dict]) -> None:
        if not objs:
            return
        self._count(topic, len(objs))
        if topic == layout.RQ_TOPIC:
            R.log_rq(self.rec, objs)
            R.log_rqfep(self.rec, *R.rqfep_points(objs, np.fromiter(self._modal_t, float), np.fromiter(self._modal_e, float)))
        elif topic == layout.MODAL_TOPIC:
            R.log_modal(self.rec, objs)
            self._modal_t.extend(float(o["t_end_s"]) for o in objs)
            self._modal_e.extend(np.nansum(np.array([o["modal_energy_J"] for o in objs], float), axis=1).tolist())
        elif topic == layout.IR_EVENTS_TOPIC:
            for ev in objs:
                self._ir_event(ev)
        elif topic == layout.RQ_SPIKES_TOPIC:
            for sp in objs:
                text = (f"window-robust RQ spike {sp['start_s']:.3f}–{sp['end_s']:.3f} s "
                        f"(agreement {sp.get('agreement', 0):.2f}; {R.RQ_SPIKE_NOTE})")  # fmt: skip
                R.log_text(self.rec, R.LOG_ANALYSIS, sp["start_s"], text, "INFO")
        elif topic == layout.WARNINGS_TOPIC:
            for w in objs:
                R.log_text(
                    self.rec, R.LOG_ANALYSIS, self.t_now, f"analysis warning ({w.get('kind')}): {w.get('message')}", "WARN"
                )
        elif topic == layout.CONFIRMATIONS_TOPIC:
            for c in objs:
                self._confirmation(c)
        elif topic == layout.HITS_TOPIC:
            for h in objs:
                R.log_hit(self.rec, h)
                self._wavelet(h)
        elif topic == layout.EVENTS_TOPIC:
            for e in objs:
                self.daq_event(e)
        elif topic == FRF_TOPIC:  # the live FRF lane's verdicts: one text line each (the curves come on FRF_CURVES)
            from daq.terminal import frf_line

            for u in objs:
                level = "INFO" if u["verdict"] == "accepted" else "WARN"
                R.log_text(self.rec, R.LOG_ANALYSIS, float(u["t_s"]), frf_line(u), level)
        elif topic == FRF_CURVES:
            from daq.view.frf import FRF, log_frf

            for c in objs:
                log_frf(self.rec, c)
                self._count(FRF)

    def daq_event(self, e: dict) -> None:
        fs = self.s.sample_rate
        t = e["start_index"] / fs if isinstance(e.get("start_index"), int | float) else self.t_now
        detail = ", ".join(f"{k}={v}" for k, v in e.items() if k not in ("kind", "message"))
        text = f"{e.get('kind', 'event')}: {e.get('message') or detail}"
        R.log_text(self.rec, R.LOG_DAQ, t, text, "WARN" if e.get("kind") not in ("note",) else "INFO")

    def _ir_event(self, ev: dict) -> None:
        R.log_ir_event(self.rec, ev)
        fs = self.s.sample_rate
        x = self._span(self._hist, math.floor(ev["start_s"] * fs), math.ceil(ev["end_s"] * fs))
        if x is not None and x.shape[0] >= 2:
            self._log_pom(f"{R.POM_EVENTS}/e{ev.get('id', 0)}", float(ev["end_s"]), x)

    def _wavelet(self, hit: dict, final: bool = False) -> None:
        ch = self.s.wavelet_channel
        if ch is None or self._wave_stream is None:
            return
        fs = self.s.sample_rate
        t0 = float(hit["t_s"]) - 0.02
        t1 = t0 + self._wave_len
        lo, hi = int(t0 * fs), int(t1 * fs)
        h = self._wave_hist
        end = h[-1][0] + h[-1][1].shape[0] if h else 0
        if end < hi and not final and (not h or lo >= h[0][0]):
            self._wave_pending.append(hit)  # the record is still arriving
            return
        x = self._span(h, max(lo, h[0][0]) if h else lo, min(hi, end))
        if x is None or x.shape[0] < 16:
            return
        # display resolution is enough: decimate to >= 2.5 f_max and single precision (~25 ms -> ~1.5 ms a hit).
        # Rows start where two periods fit in the record: below that a row is all end effect, and its 9-sigma
        # padding (analysis/wavelet.py) made the transform ~10x longer than the record (34 ms a hit, measured)
        f_lo = min(max(self.s.f_min_hz, 2.0 / self._wave_len), 0.5 * self.s.f_max_hz)
        freqs = np.geomspace(f_lo, self.s.f_max_hz, 48)
        q = max(1, int(fs // (2.5 * self.s.f_max_hz)))
        sig = x[:, 0].astype(np.float64)
        if q > 1 and sig.size > 64 * q:
            sig = scipy.signal.decimate(sig, q, ftype="fir")
        else:
            q = 1
        # 4 sigma of zero padding instead of the analysis' 9: 2e-5 of the largest |Z| apart, 1.3 -> 0.95 ms a hit
        # for beam_ch4_exp's 10-2000 Hz rows (7.7 -> 1.5 ms on a rig whose rows go down to 4 Hz), measured
        z = np.abs(morlet_cwt(sig, fs / q, freqs, normalization="amplitude", dtype=np.complex64, pad_sigmas=4.0))
        step = max(1, z.shape[1] // 500)
        R.log_wavelet(self.rec, ch, float(hit["t_s"]), z[:, ::step], freqs, t0, t1)
        self._count(R.WAVELET)

    def _confirmation(self, c: dict) -> None:
        ev = c.get("event") or {}
        eid = int(c.get("event_id", ev.get("id", 0)))
        t = float(c.get("end_s") or ev.get("end_s") or self.t_now)
        status = c.get("status", "?")
        ratio = f" {c['ratio']}" if c.get("ratio") else ""
        text = f"confirmation of IR event {eid}: {status}{ratio} (orthogonality {c.get('orthogonality_index', float('nan')):.3f})"
        R.log_text(self.rec, R.LOG_ANALYSIS, t, text, "WARN" if status == "confirmed" else "INFO")
        tr = c.get("trajectory") or {}
        if tr.get("phi") and tr.get("phi_dot") and len(tr["phi"]) >= 2:
            R.log_slowflow(
                self.rec, eid, t, np.asarray(tr["phi"]), np.asarray(tr["phi_dot"]), f"event {eid} {c.get('ratio') or ''} {status}"
            )
            self._count(R.SLOWFLOW)

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n
