"""The rerun entity layout, the blueprint and the logging functions every gvtlink view uses (docs/view.md).

One layout for the live view (``gvt record --view``, ``gvt replay --view``) and the offline recording
(``gvt analyze LOG --rrd``, ``gvt demo``), so a viewer shows the same thing either way. Everything is
logged on one timeline, ``time``: seconds on the analysed stream's sample clock (sample index / fs —
the same clock as ``/analysis/*`` and ``/daq/hits``; ``t0_ns`` is not added).

Bulk data goes through ``send_columns`` (dependency-notes §3: ~10 M values/s against ~17 k per-row logs/s).
Raw channels are never shown sample by sample: each display bucket of ``fs / bucket_hz`` samples becomes
one (min, max) pair, aligned to absolute sample indices so the picture does not depend on block sizes.
Every function takes an explicit :class:`rerun.RecordingStream` (never the global one), and nothing here
spawns a viewer (dependency-notes §3: ``spawn`` fails headless).

2-D views (RQ-FEP, POM shapes, slow-flow phase planes) are in display units, because rerun's 2-D space
has y pointing down and one unit per pixel: the mapping is stated in each entity's label and below.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from daq.view.scores import MODAL_EXCHANGE, ROBUST_RQ_SPIKES, score_note
from daq.view.setup import rqfep_points  # noqa: F401 (re-exported: the view logger draws with it)

TIMELINE = "time"
APP_ID = "gvtlink"

RAW = "/raw"  # /raw/<stream>: (min, max) envelope per display bucket of every sensor channel, SI units
HAMMER = "/hammer/force"  # hammer channel envelope, N
HITS = "/hammer/hits"  # one point per hit at (t_s, peak force), coloured by verdict
RQ = "/rq"
RQ_NNM = "/rq/nnm"  # series NNM1..NNMk: RQ frequency per base-grid window, Hz (one entity: one send_columns per batch)
RQ_SEED_SPIKES = "/rq/seed_spikes"  # the seed's literal spike rule, marker at the window's RQ of NNM2
RQ_IR_EVENTS = "/rq/ir_events"  # per IR event: markers at (start_s, f_give) and (start_s, f_recv)
MODAL_ENERGY = "/modal/energy"  # series mode 1..r: windowed linear modal energy, J
MODAL_FREQ = "/modal/freq"  # series mode 1..r: windowed instantaneous frequency, Hz
RQFEP = "/rqfep"  # points (FEP_X_PER_DECADE·log10 E, −f/Hz), one per NNM and window, coloured by NNM
POM_CURRENT = "/pom/current"  # line strips along the structure, latest window
POM_EVENTS = "/pom/events"  # /pom/events/e<id>: POMs over an IR event's span
WAVELET = "/wavelet"  # /wavelet/<channel>: |Z| of a hit record, Morlet CWT (amplitude normalisation, eq. 3.2)
SLOWFLOW = "/slowflow"  # /slowflow/e<id>: (phi, phi_dot) trajectory of a confirmation
LOG_DAQ = "/log/daq"  # loss, gaps, overruns, driver errors, view drops
LOG_ANALYSIS = "/log/analysis"  # IR events, robust spikes, warnings, confirmations

FEP_X_PER_DECADE = 100.0  # display units per decade of total modal energy
POM_X_SPAN = 1000.0  # the structure's sensor span drawn over this many display units
POM_Y_SCALE = 150.0  # display units for a POM entry of 1 (POMs are normalised to max|ψ| = 1)
SLOWFLOW_X_PER_RAD = 100.0

VERDICT_COLORS = {"accepted": (40, 170, 60), "overload": (220, 40, 40), "double_hit": (230, 140, 20)}
MODE_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def color(k: int) -> tuple[int, int, int]:
    return MODE_COLORS[k % len(MODE_COLORS)]


#: streaming to a viewer, rerun-sdk's micro-batcher thread woke ~150 times a second (measured; its LOW_LATENCY
#: tick is 8 ms, its DEFAULT 200 ms) and cost 0.0025 CPU-s per data-s in a 15 ch x 16384 Hz session. Everything
#: gvtlink logs live comes in 0.25-0.5 s frames anyway, so a 0.1 s tick delays nothing visible and cut that thread
#: to 0.0008 (bench_view.py --path record, view:tick=0.1)
FLUSH_TICK_S = 0.1


def new_recording(recording_id: str | None = None) -> rr.RecordingStream:
    """A recording stream of its own (not the global one); the caller picks its sink."""
    return rr.RecordingStream(
        APP_ID, recording_id=recording_id, batcher_config=rr.ChunkBatcherConfig(flush_tick=FLUSH_TICK_S)
    )


def blueprint() -> rrb.Blueprint:
    """Tabs of views over the layout above, a text log always visible underneath."""
    everything = rrb.VisibleTimeRange(
        TIMELINE, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
    )
    tabs = rrb.Tabs(
        rrb.Vertical(
            rrb.TimeSeriesView(origin=RAW, name="raw channels (min/max per display bucket)"),
            rrb.TimeSeriesView(origin="/hammer", name="hammer force [N], hits by verdict"),
            name="signals",
        ),
        rrb.Vertical(
            rrb.TimeSeriesView(origin=RQ, name="RQ per NNM [Hz], IR-event markers"),
            rrb.TimeSeriesView(origin=MODAL_ENERGY, name="modal energies [J]"),
            name="RQ and energy",
        ),
        rrb.Horizontal(
            rrb.Spatial2DView(origin=RQFEP, name="RQ-FEP (x: 100/decade of E, y: −f Hz)", time_ranges=everything),
            rrb.Spatial2DView(origin="/pom", name="POM shapes along the structure"),
            name="RQ-FEP and POMs",
        ),
        rrb.Horizontal(
            rrb.TensorView(origin=WAVELET, name="wavelet |Z| of a hit record"),
            rrb.Spatial2DView(origin=SLOWFLOW, name="slow-flow phase (x: 100/rad φ, y: −φ̇)", time_ranges=everything),
            name="wavelet and slow flow",
        ),
        rrb.Vertical(  # live FRFs (daq/view/frf.py): x Hz, y down
            rrb.Horizontal(rrb.Spatial2DView(origin="/frf/magnitude", name="|H| (y: -10/dB)"),
                           rrb.Spatial2DView(origin="/frf/phase", name="phase (y: -deg)")),
            rrb.Horizontal(rrb.Spatial2DView(origin="/frf/coherence", name="coherence (y: -1000 x)"),
                           rrb.Spatial2DView(origin="/frf/hammer", name="hammer spectrum (y: -10/dB re DC)")),
            rrb.TimeSeriesView(origin="/frf/averages", name="averages"),
            name="live FRFs",
        ),
    )
    return rrb.Blueprint(
        rrb.Vertical(tabs, rrb.TextLogView(origin="/log", name="events"), row_shares=[4, 1]), collapse_panels=True
    )


def log_styles(
    rec: rr.RecordingStream, streams: dict[str, tuple[str, ...]], hammer: str | None, n_nnm: int, n_modes: int
) -> None:
    """Static series names and colours (once per recording)."""
    for s, chans in streams.items():
        if hammer in chans:
            rec.log(HAMMER, rr.SeriesLines(names=[f"{hammer} min", f"{hammer} max"], colors=[(120, 120, 120), (30, 30, 30)]),
                    static=True)  # fmt: skip
        others = [c for c in chans if c != hammer]
        if others:
            names = [f"{c} {m}" for c in others for m in ("min", "max")]
            cols = [color(j) for j in range(len(others)) for _ in range(2)]
            rec.log(f"{RAW}/{s}", rr.SeriesLines(names=names, colors=cols), static=True)
    rec.log(HITS, rr.SeriesPoints(names=["hit peak"], markers=["circle"], marker_sizes=[6.0]), static=True)
    rec.log(
        RQ_NNM,
        rr.SeriesLines(names=[f"RQ NNM{k + 1}" for k in range(n_nnm)], colors=[color(k) for k in range(n_nnm)]),
        static=True,
    )
    rec.log(RQFEP, rr.Points2D.from_fields(radii=[2.0]), static=True)
    rec.log(RQ_SEED_SPIKES, rr.SeriesPoints(names=["seed-rule spike"], markers=["cross"], colors=[(200, 0, 0)]), static=True)
    ir = rr.SeriesPoints(names=["IR give", "IR receive"], markers=["down", "up"], colors=[(0, 0, 0), (200, 0, 200)],
                         marker_sizes=[8, 8])  # fmt: skip
    rec.log(RQ_IR_EVENTS, ir, static=True)
    cols = [color(k) for k in range(n_modes)]
    rec.log(MODAL_ENERGY, rr.SeriesLines(names=[f"E mode {k + 1}" for k in range(n_modes)], colors=cols), static=True)
    rec.log(MODAL_FREQ, rr.SeriesLines(names=[f"f mode {k + 1}" for k in range(n_modes)], colors=cols), static=True)


def envelope(data: np.ndarray, bucket: int) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) per bucket of ``bucket`` rows of ``data`` (n, ch); n must be a multiple of ``bucket``."""
    n = data.shape[0] // bucket
    x = data[: n * bucket].reshape(n, bucket, data.shape[1])
    return x.min(axis=1), x.max(axis=1)


def log_envelopes(
    rec: rr.RecordingStream, stream: str, channels: Sequence[str], hammer: str | None, first_index: int, fs: float,
    data: np.ndarray, bucket: int,
) -> int:  # fmt: skip
    """Log whole buckets of ``data`` (first row at ``first_index``, a bucket boundary); returns rows used.

    All sensor channels of a stream go to one entity, ``/raw/<stream>``, as 2·n series (min, max per
    channel): one ``send_columns`` per flush instead of one per channel — 1.0 ms against 0.06 ms for
    15 channels of 250 buckets (measured, rerun-sdk 0.41), the largest share of the view's cost. The
    blueprint draws every raw channel in one plot anyway; the legend toggles single series.
    """
    mn, mx = envelope(data, bucket)
    if mn.shape[0] == 0:
        return 0
    t = (first_index + bucket * np.arange(mn.shape[0]) + 0.5 * bucket) / fs
    times = [rr.TimeColumn(TIMELINE, duration=t)]
    both = np.stack([mn, mx], axis=2).astype(np.float64)  # (buckets, channel, min|max)
    others = [j for j, c in enumerate(channels) if c != hammer]
    if len(others) < len(channels):
        j = list(channels).index(hammer)
        rec.send_columns(HAMMER, indexes=times, columns=rr.Scalars.columns(scalars=both[:, j, :]))
    if others:
        vals = both[:, others, :].reshape(both.shape[0], 2 * len(others))
        rec.send_columns(f"{RAW}/{stream}", indexes=times, columns=rr.Scalars.columns(scalars=vals))
    return mn.shape[0] * bucket


def _series(rec: rr.RecordingStream, path: str, t: np.ndarray, v: np.ndarray) -> None:
    """One send_columns for all series of ``v`` (n, k); rows with no finite value are left out."""
    keep = np.isfinite(v).any(axis=1) if v.ndim == 2 else np.isfinite(v)
    if keep.any():
        rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])], columns=rr.Scalars.columns(scalars=v[keep]))


def log_rq(rec: rr.RecordingStream, rows: Sequence[dict]) -> None:
    """``/analysis/rq`` windows: RQ of each kept POM at the window's end (eqs. 2.17–2.18), seed spikes."""
    if not rows:
        return
    t = np.array([r["t_end_s"] for r in rows], float)
    f = np.array([r["rq_hz"] for r in rows], float)
    _series(rec, RQ_NNM, t, f)
    spike = np.array([bool(r.get("seed_spike")) for r in rows])
    if spike.any() and f.shape[1] > 1:
        _series(rec, RQ_SEED_SPIKES, t[spike], f[spike, 1])


def log_modal(rec: rr.RecordingStream, rows: Sequence[dict]) -> None:
    """``/analysis/modal`` windows: linear modal energies and instantaneous frequencies per mode."""
    if not rows:
        return
    t = np.array([r["t_end_s"] for r in rows], float)
    e = np.array([r["modal_energy_J"] for r in rows], float)
    f = np.array([r["modal_freq_hz"] for r in rows], float)
    _series(rec, MODAL_ENERGY, t, e)
    _series(rec, MODAL_FREQ, t, f)


def log_rqfep(rec: rr.RecordingStream, t: np.ndarray, log_e: np.ndarray, f: np.ndarray) -> None:
    """One row per window with one point per NNM (coloured by NNM); one send_columns per batch."""
    if f.ndim != 2 or f.shape[0] == 0:
        return
    ok = np.isfinite(f)
    lengths = ok.sum(axis=1)
    rows = lengths > 0
    if not rows.any():
        return
    k = np.broadcast_to(np.arange(f.shape[1]), f.shape)[ok]
    pos = np.stack([FEP_X_PER_DECADE * np.broadcast_to(log_e[:, None], f.shape)[ok], -f[ok]], axis=1)
    cols = np.asarray(MODE_COLORS, np.uint8)[k % len(MODE_COLORS)]
    rec.send_columns(RQFEP, indexes=[rr.TimeColumn(TIMELINE, duration=t[rows])],
                     columns=rr.Points2D.columns(positions=pos, colors=cols).partition(lengths[rows]))  # fmt: skip


def log_pom(rec: rr.RecordingStream, path: str, t: float, x: np.ndarray, poms: np.ndarray, povs: np.ndarray) -> None:
    """POMs (n_sensors, k) as line strips along the structure: sensor position → x, ψ → −y (display units)."""
    span = float(np.ptp(x)) or 1.0
    xs = POM_X_SPAN * (x - x.min()) / span
    order = np.argsort(xs)
    total = float(np.sum(povs)) or 1.0
    strips = [np.stack([xs[order], -POM_Y_SCALE * poms[order, k]], axis=1) for k in range(poms.shape[1])]
    labels = [f"POM{k + 1} ({100 * povs[k] / total:.1f} %)" for k in range(poms.shape[1])]
    rec.set_time(TIMELINE, duration=t)
    rec.log(path, rr.LineStrips2D(strips, colors=[color(k) for k in range(len(strips))], labels=labels, radii=[1.5]))


def log_wavelet(
    rec: rr.RecordingStream, channel: str, t: float, amp: np.ndarray, freqs_hz: np.ndarray, t0: float, t1: float
) -> None:
    """|Z| (n_freq, n_time) as a tensor, highest frequency in row 0; extents in the dimension names."""
    rows = np.ascontiguousarray(amp[::-1].astype(np.float32))
    rec.set_time(TIMELINE, duration=t)
    rec.log(f"{WAVELET}/{channel}", rr.Tensor(rows, dim_names=[
        f"frequency {freqs_hz[-1]:.1f} → {freqs_hz[0]:.1f} Hz (log, {len(freqs_hz)} rows)",
        f"time {t0:.3f} → {t1:.3f} s ({rows.shape[1]} cols)",
    ]))  # fmt: skip


def log_slowflow(rec: rr.RecordingStream, event_id: int, t: float, phi: np.ndarray, phi_dot: np.ndarray, label: str) -> None:
    pd = np.asarray(phi_dot, float)
    scale = 100.0 / (float(np.max(np.abs(pd))) or 1.0)
    pts = np.stack([SLOWFLOW_X_PER_RAD * np.asarray(phi, float), -scale * pd], axis=1)
    rec.set_time(TIMELINE, duration=t)
    rec.log(
        f"{SLOWFLOW}/e{event_id}", rr.LineStrips2D([pts], labels=[f"{label} (y: {scale:.3g}/(rad/s))"], colors=[color(event_id)])
    )


def log_text(rec: rr.RecordingStream, path: str, t: float, text: str, level: str = "INFO") -> None:
    rec.set_time(TIMELINE, duration=t)
    rec.log(path, rr.TextLog(text, level=level))


def log_hit(rec: rr.RecordingStream, hit: dict) -> None:
    verdict = str(hit.get("verdict", "?"))
    rec.set_time(TIMELINE, duration=float(hit["t_s"]))
    rec.log(
        HITS,
        rr.Scalars([float(hit.get("peak_force_N", 0.0))]),
        rr.SeriesPoints(colors=[VERDICT_COLORS.get(verdict, (90, 90, 90))]),
    )
    rec.log(LOG_DAQ, rr.TextLog(
        f"hit {hit.get('hit', '?')}: {hit.get('peak_force_N', 0):.0f} N, {verdict} ({hit.get('reason', 'ok')})",
        level="INFO" if verdict == "accepted" else "WARN",
    ))  # fmt: skip


_MX_NOTE = score_note(MODAL_EXCHANGE)  # what an event and a spike are worth, measured (issue 21)
RQ_SPIKE_NOTE = score_note(ROBUST_RQ_SPIKES)


def log_ir_event(rec: rr.RecordingStream, ev: dict) -> None:
    t = float(ev["start_s"])
    rec.set_time(TIMELINE, duration=t)
    rec.log(RQ_IR_EVENTS, rr.Scalars([float(ev["f_give_hz"]), float(ev["f_recv_hz"])]))
    modes = ev.get("modes", ["?", "?"])
    rec.log(LOG_ANALYSIS, rr.TextLog(
        f"IR event {ev.get('id', '?')}: modes {modes[0]}→{modes[1]} {ev.get('ratio', '?')} from {t:.3f} to {ev['end_s']:.3f} s, "
        f"f {ev['f_give_hz']:.1f}/{ev['f_recv_hz']:.1f} Hz, gain {ev.get('gain', float('nan')):.1f}, "
        f"confidence {ev.get('confidence', float('nan')):.2f}, label confidence {ev.get('label_confidence') or float('nan'):.2f} "
        f"(calibrated probabilities; modal-exchange detector: {_MX_NOTE})",
        level="WARN",
    ))  # fmt: skip
