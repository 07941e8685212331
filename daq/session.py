"""A recording session (``gvt record``): the session config turned into a :class:`~daq.recorder.Recorder`.

What this module decides, and nothing else (the recorder runs it, docs/session.md):

* the devices: each ``[device]`` / ``[[devices]]`` table validated against its driver's own config model
  (a mistake is one line naming ``device.config.<field>``, exit 2), its simulated server started if the
  session asks for one (:mod:`daq.sim_devices`), its streams and channels (CAN: from the DBC);
* the lanes, in their stop order: hit gate (through the timeline aligner with several devices),
  live FRFs (when the rig has a hammer and sensors; ``frf=False``: ``--no-frf``), near-live analysis,
  confirmation, view; the log lane owns the file;
* the session's end: ``duration`` is data time; a device that delivers less ends it ``end_grace_s``
  (wall clock) after the duration with a ``duration_not_reached`` event and exit 3; silence longer than
  ``silence_s`` is an event, never an end.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from analysis.model.loader import ConfigError
from analysis.model.rig import Rig
from daq.config.rig_checks import check_session_against_rig
from daq.config.session import DeviceSpec, SessionConfig, TimelineSpec, driver_table_error
from daq.fanout import FanOut
from daq.hits import HitDetector, HitRecord, TriggerSettings
from daq.lanes import Lane, Results
from daq.lanes.hits import HitGateLane
from daq.lanes.log import LogLane
from daq.log import layout
from daq.log.rig import channel_infos
from daq.log.writer import ChannelInfo
from daq.recorder import Outcome, Recorder
from daq.sim_devices import SimHarness, start_simulation
from daq.sources import JOIN_S, DeviceSource
from drivers.base import Driver, available_drivers

#: samples per block each driver delivers, for queue sizes (a serial frame, the Modbus block, a CAN block)
BLOCK_GUESS = {"serial": 64, "modbus": 1024, "can": 256, "sim": 1024}


def rig_identity(rig) -> dict[str, str]:
    """Which model the session used (issue 21): the rig file's SHA-256 and, for a rig written by ``gvt model update``,
    where its parameters came from (its ``[update.provenance]``); the file itself is attached as ``rig/<name>``."""
    import hashlib

    path = Path(rig.path)
    out = {"rig_sha256": hashlib.sha256(path.read_bytes()).hexdigest()} if path.exists() else {}
    upd = getattr(getattr(rig, "config", None), "update", None)
    prov = getattr(upd, "provenance", None)
    if prov is not None:
        out["rig_updated_from"] = f"{prov.source} ({prov.objective})"
    return out


@dataclass
class SessionResult:
    path: Path
    hits: list[HitRecord] = field(default_factory=list)
    suspects: list[str] = field(default_factory=list)
    suspect_reasons: dict[str, str] = field(default_factory=dict)
    samples: int = 0
    lost_samples: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    events: dict[str, int] = field(default_factory=dict)
    driver_error: str | None = None
    writer_overrun_samples: int = 0
    writer_backlog: dict[str, float] = field(default_factory=dict)  # LogWriter.backlog() at the end: how far it fell behind
    seconds: float = 0.0
    files: list[str] = field(default_factory=list)
    streams: dict[str, int] = field(default_factory=dict)  # samples recorded per device stream
    stream_gaps: dict[str, list[tuple[int, int]]] = field(default_factory=dict)
    reference: str = ""  # the stream whose index the hit records use
    timeline: dict[str, dict] = field(default_factory=dict)  # final offset estimate per other stream
    host_stalls: list[tuple[float, float]] = field(default_factory=list)  # (at s, for s): the process did not run
    aligner_dropped: dict[str, int] = field(default_factory=dict)  # samples the hit gate never saw, per stream
    analysis_events: list[dict] = field(default_factory=list)  # IR events of the near-live analysis
    analysis_dropped_samples: int = 0  # samples the analysis lane skipped because it fell behind
    analysis_cpu_s: float = 0.0  # CPU of the analysis lane's thread
    analysis_latencies_s: list[float] = field(default_factory=list)  # per base-grid window: first block arrival → result
    view_dropped_samples: int = 0  # samples the live view did not show (lossy side channel, daq/lanes/view.py)
    confirmations: list[dict] = field(default_factory=list)  # WBEMD + slow-flow records of the IR events
    outcome: Outcome | None = None  # why it ended, the one line, the exit code
    restarts: int = 0  # device restarts (new segments)
    estimated_lost_samples: int = 0  # the part of lost_samples estimated from the host clock (restart gaps)
    simulated_faults: dict[str, Any] = field(default_factory=dict)  # a simulated session's injected faults (the oracle)
    rejected_blocks: int = 0  # implausible blocks the drivers refused
    frf: list[dict] = field(default_factory=list)  # the live FRF lane's /analysis/frf records, one per hit


@dataclass
class SessionOptions:
    """What the command line adds to a session config."""

    stop: threading.Event | None = None
    status: Callable[[dict], None] | None = None
    view: Any = None  # a daq.lanes.view.ViewTarget
    overwrite: bool | None = None  # None: the session's own ``overwrite``
    wait_confirmations: bool = True  # False: --no-wait
    drain_progress: Callable[[int, int], None] | None = None  # confirmations done / total after the data ends
    analysis_frame_s: float | None = None  # the analysis lane's frame wait (None: its default; 0: block by block)
    frf: bool = True  # the live FRF lane (False: --no-frf)
    frf_line: Callable[[str], None] | None = None  # where its one line per hit goes (the terminal)
    line: Callable[[str], None] | None = None  # other one-line notices (the timeline's); None: frf_line's terminal


def run_session(cfg: SessionConfig, rig: Rig, out: Path, stop: threading.Event | None = None,
                status: Callable[[dict], None] | None = None, view=None, **options: Any) -> SessionResult:  # fmt: skip
    """Record the session into ``out`` until the duration (data time), a stop, or a device ends; see the
    module docstring. ``options``: the rest of :class:`SessionOptions`."""
    opts = SessionOptions(stop=stop, status=status, view=view, **options)
    _check_against_rig(cfg, rig)
    harness = start_simulation(cfg, rig)
    try:
        session = Session(cfg, harness.rig or rig, Path(out), harness, opts)
        return session.run()
    finally:
        harness.stop()


def _check_against_rig(cfg: SessionConfig, rig: Rig) -> None:
    check_session_against_rig(cfg, rig, cfg.source)


def driver_config(d: DeviceSpec, field_prefix: str, source: str, overrides: dict[str, Any], rig: Rig,
                  duration: float | None) -> Any:  # fmt: skip
    """The device's driver table validated by its driver's own model (python-can style: each interface owns its
    arguments); a mistake is one :class:`ConfigError` line naming ``device.config.<field>``."""
    drivers = available_drivers()
    if d.driver not in drivers:
        raise ConfigError(source, f"{field_prefix}.driver", f"unknown driver {d.driver!r}; installed: {sorted(drivers)}")
    table = {**d.config, **overrides}
    table.setdefault("stream", d.name)
    if overrides:  # the session started the device: loss before its first block counts
        table["expect_first_index"] = 0
    if d.driver == "sim":  # the in-process simulated device: it is the rig itself
        table.setdefault("rig", rig.path)
        table.setdefault("sample_rate", rig.sample_rate)
        table.setdefault("channels", [p.name for p in [rig.hammer, *rig.sensors]])
        table.setdefault("duration", duration)
        table.setdefault("expect_first_index", 0)
    if d.driver in ("serial", "modbus", "can") and overrides:
        table.setdefault("sample_rate", rig.sample_rate)
    if d.driver == "serial" and overrides:
        table.setdefault("channels", [p.name for p in [rig.hammer, *rig.sensors]])
    model = drivers[d.driver].config_model
    try:
        return model.model_validate(table)
    except ValidationError as exc:
        raise driver_table_error(source, field_prefix, exc) from None


def device_streams(drv: Driver) -> dict[str, tuple[tuple[str, ...], float]]:
    """Every stream a driver delivers: {name: (channels, sample rate)} (CAN: one per DBC message; Modbus: the
    polled slow channels as ``<stream>.poll``)."""
    c = drv.config
    if hasattr(drv, "streams") and isinstance(getattr(drv, "streams", None), dict):  # CAN: channels from the DBC
        return {name: (tuple(lay.channels), float(c.sample_rate)) for name, lay in drv.streams.items()}
    out: dict[str, tuple[tuple[str, ...], float]] = {}
    if getattr(c, "channels", None) and getattr(c, "mode", "fifo") != "poll":
        out[c.stream] = (tuple(c.channels), float(c.sample_rate))
    if getattr(c, "poll", None):
        out[f"{c.stream}.poll"] = (tuple(c.poll), float(c.poll_hz))
    return out


class Session:
    """The parts of one recording and its result (built in ``__init__``, run once by :meth:`run`)."""

    def __init__(self, cfg: SessionConfig, rig: Rig, out: Path, harness: SimHarness, opts: SessionOptions) -> None:
        self.cfg, self.rig, self.out, self.harness, self.opts = cfg, rig, out, harness, opts
        from daq.priority import base_nice, raise_priority

        self.base_nice = base_nice()
        priority_line = raise_priority()  # before any thread of the session starts: Linux sets nice per thread
        self.host = None  # the lane-host worker (daq/lanes/host.py) when the analysis runs in one
        self.result = SessionResult(path=out, reference=cfg.reference_device())
        self.stop = opts.stop or threading.Event()
        self.drivers = self._make_drivers()
        self.streams = {n: ch for drv in self.drivers.values() for n, (ch, _r) in device_streams(drv).items()}
        self.fs = self._sample_rate()
        self.fan = FanOut()
        self.results = Results()
        self.log = self._log_lane()
        self.results.log = self.log.sink
        self.results.log_encoded = self.log.sink_encoded
        if priority_line is not None:  # said once per session: in the log and on the console
            self.results.emit(layout.EVENTS_TOPIC, {"kind": "priority_not_raised", "message": priority_line}, None)
            if (say := self.opts.line or self.opts.frf_line) is not None:
                say(priority_line)
        self.sources = self._sources()
        self.hits = self._hit_gate()
        self.frf = self._frf_lane()
        self.analysis = self._analysis_lane()
        self.confirm = self._confirm_lane()
        self.view = self._view_lane()
        if self.frf is not None and self.view is not None:
            self.frf.view = self.view.offer  # the curves: in-process only, never logged
        lanes: list[Lane] = [lane for lane in (self.hits, self.frf, self.analysis, self.confirm, self.view) if lane is not None]
        self.recorder = Recorder(
            fan=self.fan, results=self.results, sources=self.sources, lanes=lanes, log=self.log, stop=self.stop,
            duration_s=cfg.duration, end_grace_s=cfg.end_grace_s, start_servers=harness.go,
            stopped_finish_s={"confirm": cfg.analysis.confirm_stop_s}, say=self.opts.line or self.opts.frf_line,
        )  # fmt: skip

    # --- parts ----------------------------------------------------------------------------------------
    def _make_drivers(self) -> dict[str, Driver]:
        out: dict[str, Driver] = {}
        for i, d in enumerate(self.cfg.device_list):
            prefix = f"devices[{i}]" if self.cfg.multi else "device"
            over = self.harness.overrides.get(d.name, {})
            if d.driver == "sim" and self.cfg.plan is not None:  # the in-process device hits where the plan says
                from daq.roving import scheduled_dofs

                dofs = scheduled_dofs(self.cfg.plan, self.rig, list(d.config.get("forces", [800.0])))
                over = {**over, "hit_dofs": [self.rig.structure.dofs[i].name for i in dofs]}
            conf = driver_config(d, prefix, self.cfg.source, over, self.rig, self.cfg.duration)
            out[d.name] = available_drivers()[d.driver](conf)
        return out

    def _sample_rate(self) -> float:
        rates = {n: float(getattr(drv, "fs", 0) or drv.config.sample_rate) for n, drv in self.drivers.items()}
        if len(set(rates.values())) > 1:
            shown = ", ".join(f"{n} {v:g} Hz" for n, v in rates.items())
            why = f"the devices sample at different rates ({shown}); resampling is not supported"
            raise ConfigError(self.cfg.source, "devices", why)
        return next(iter(rates.values()))

    def _log_lane(self) -> LogLane:
        cfg = self.cfg
        overwrite = self.opts.overwrite if self.opts.overwrite is not None else cfg.overwrite
        hold_s = (cfg.timeline or TimelineSpec()).max_buffer_s  # a second device waits at most this for its offset
        meta = {"session": cfg.name, "rig": self.rig.name, **rig_identity(self.rig)}
        lane = LogLane(self.out, buffer_bytes=round(cfg.writer_buffer_mib * 2**20), rotate_bytes=cfg.rotate_bytes,
                       rotate_seconds=cfg.rotate_seconds, metadata=meta,
                       overwrite=overwrite, max_hold_s=hold_s, preview=cfg.log.preview)  # fmt: skip
        infos = {c.name: c for c in channel_infos(self.rig)}
        offsets = (cfg.timeline or TimelineSpec()).offsets if cfg.multi else {}
        ref = self.result.reference
        for dev, drv in self.drivers.items():
            for name, (chans, rate) in device_streams(drv).items():
                # one device: every stream on its clock; several: the reference's, the others placed by the timeline
                own = name.removesuffix(".poll")
                on_ref = not cfg.multi or dev == ref or own == ref
                off = offsets.get(own, offsets.get(dev))
                lane.add_stream(name, [infos.get(c, ChannelInfo(c, "other", "")) for c in chans], rate, reference=on_ref,
                                offset_s=off, method="configured")  # fmt: skip
        lane.add_metadata(layout.META_CONFIG, {"session_toml": cfg.model_dump_json()})
        if Path(self.rig.path).exists():
            lane.add_attachment(f"rig/{Path(self.rig.path).name}", Path(self.rig.path).read_bytes(), "application/toml")
        return lane

    def _queue_blocks(self, seconds: float) -> int:
        return sum(max(8, int(seconds * self.fs / BLOCK_GUESS.get(d.driver, 256))) for d in self.cfg.device_list)

    def _sources(self) -> list[DeviceSource]:
        out = []
        need = None if self.cfg.duration is None else round(self.cfg.duration * self.fs)
        offsets = (self.cfg.timeline or TimelineSpec()).offsets
        for d in self.cfg.device_list:
            block_s = BLOCK_GUESS.get(d.driver, 256) / self.fs
            silence = self.cfg.silence_s or max(2.0, 4 * block_s)
            held = self.cfg.multi and d.name != self.result.reference and d.name not in offsets  # waits for its offset
            out.append(DeviceSource(d.name, self.drivers[d.name], self.log, self.fan, self.results.emit, need_samples=need,
                                    silence_s=silence, held=held, join_s=0.0 if self.cfg.multi else JOIN_S))  # fmt: skip
        return out

    def _ranges(self) -> dict[str, float]:
        ranges = {p.name: p.props.range for p in [self.rig.hammer, *self.rig.sensors] if p.props.range is not None}
        for d in self.cfg.device_list:
            if d.simulate is not None:
                ranges.update(d.simulate.ranges)
        return ranges

    def _hit_gate(self) -> HitGateLane:
        cfg, ref = self.cfg, self.result.reference
        aligner = None
        det_channels = self.streams[ref] if ref in self.streams else next(iter(self.streams.values()))
        if cfg.multi:
            from daq.timeline import StreamAligner

            tl = cfg.timeline or TimelineSpec()
            data = {n: ch for n, ch in self.streams.items() if not n.endswith(".poll")}
            aligner = StreamAligner(data, ref, self.fs, offsets=tl.offsets, settle_s=tl.settle_s, window_s=tl.window_s,
                                    max_buffer_s=tl.max_buffer_s, report_s=tl.report_s)  # fmt: skip
            det_channels = aligner.channels
        t = cfg.trigger
        extra = {"exclude": tuple(cfg.channels.exclude), "required": tuple(cfg.channels.required)}
        for c, what in ((t.channel, "trigger.channel"), (t.driving_point, "trigger.driving_point")):
            if c is not None and c not in det_channels:
                raise ConfigError(cfg.source, what, f"channel {c!r} is not recorded (channels: {', '.join(det_channels)})")
        if cfg.plan is not None:  # roving hammer: the input energy where the hammer hits (daq/hits.py TriggerSettings.roving)
            from daq.roving import resolve_plan

            extra["roving"] = tuple((p.sensor, p.averages) for p in resolve_plan(cfg.plan, self.rig))
        settings = TriggerSettings(level=t.level, channel=t.channel, pre_trigger=t.pre_trigger, record_length=t.record_length,
                                   hysteresis=t.hysteresis, force_range=t.force_range, driving_point=t.driving_point,
                                   suspect_after=t.suspect_after, **extra)  # fmt: skip
        detector = HitDetector(settings, det_channels, self.fs, self._ranges())
        maxsize = max(64, self._queue_blocks(cfg.queue_seconds))
        sink = self.results.emit if aligner is None else self._timeline_sink()
        return HitGateLane(self.fan, detector, sink, aligner=aligner, maxsize=maxsize,
                           metadata=self.log.add_metadata, offsets=self.log.set_offset).start()  # fmt: skip

    def _timeline_sink(self) -> Callable[[str, Any, int | None], None]:
        """The hit gate's results, and a console line when the timeline fixes or moves an offset (issue 30: a moved
        offset used to be only an event in the log) or when a hit's driving-point response leads its force."""
        from daq.timeline import timeline_line

        say, emit = self.opts.line or self.opts.frf_line, self.results.emit

        def sink(topic: str, obj: Any, log_time_ns: int | None) -> None:
            emit(topic, obj, log_time_ns)
            line = None
            if topic == layout.TIMELINE_TOPIC:
                line = timeline_line(obj, self.fs)
            elif topic == layout.HITS_TOPIC:
                line = self._check_causality(obj)
            if say is not None and line is not None:
                say(line)

        return sink

    def _check_causality(self, summary: dict) -> str | None:
        """The physics check of the clock offset on one hit (daq/timeline.py ``response_lead``): an event, and the
        console line the first time, when the driving point (on another device) moves before the hammer hits."""
        from daq.timeline import response_lead

        lane = getattr(self, "hits", None)
        t, ref = self.cfg.trigger, self.result.reference
        if lane is None or lane.aligner is None or t.driving_point is None or t.driving_point in self.streams.get(ref, ()):
            return None
        rec = next((h for h in reversed(list(lane.hits)) if h.hit == summary.get("hit")), None)
        chans = list(lane.aligner.channels)
        force = t.channel or self.rig.hammer.name
        if rec is None or force not in chans or t.driving_point not in chans:
            return None
        lead = response_lead(rec.data[:, chans.index(force)], rec.data[:, chans.index(t.driving_point)])
        limit = rec.pulse_width_s * self.fs / 2 + 2  # the force's steepest rise lies in its first half; 2 samples' grace
        if lead is None or lead <= limit:
            return None
        self._acausal = getattr(self, "_acausal", 0) + 1
        msg = (f"hit {rec.hit} at {rec.t_s:.3f} s: {t.driving_point} moved {lead} samples before the hammer hit: the clock "
               f"offset of its device is wrong by at least {lead - limit:.0f} samples (set timeline.offsets)")
        self.results.emit(layout.EVENTS_TOPIC, {"kind": "timeline_acausal", "hit": rec.hit, "lead_samples": lead,
                                                "limit_samples": limit, "message": msg}, None)  # fmt: skip
        return f"timeline ACAUSAL: {msg}" if self._acausal == 1 else None

    def _frf_lane(self):
        """Live FRFs of the accepted hits (daq/lanes/frf.py), after the hit gate: its last hits come first."""
        if not self.opts.frf:
            return None
        from daq.lanes.frf import start_frf_lane

        ref = self.result.reference
        streams = {ref: self.streams[ref]} if ref in self.streams else self.streams  # the hits' index is the reference's
        timeline: dict[str, Any] = {}
        aligner = self.hits.aligner
        if aligner is not None:  # several devices: responses from every device, placed by the gate's fixed offsets
            streams = {n: self.streams[n] for n in aligner.order}
            timeline = {"offsets": lambda: aligner.applied, "lead_s": (self.cfg.timeline or TimelineSpec()).max_buffer_s}
        points = None
        if self.cfg.plan is not None:
            from daq.roving import resolve_plan

            points = resolve_plan(self.cfg.plan, self.rig)
        lane = start_frf_lane(self.fan, self.rig, streams, self.fs, self.results.emit, say=self.opts.frf_line,
                              points=points, attach=self.log.add_attachment,
                              maxsize=max(64, self._queue_blocks(self.cfg.queue_seconds)), **timeline)  # fmt: skip
        if lane is not None:
            self.results.route(lane, [layout.HITS_TOPIC])
        return lane

    def _analysis_lane(self):
        spec = self.cfg.analysis
        if not spec.enabled:
            return None
        from analysis.operator import AnalysisSettings
        from daq.lanes.analysis import LaneUnavailable, start_analysis_lane

        settings = AnalysisSettings(window_s=spec.window_s, n_keep=spec.n_keep, seed_lane=spec.seed_lane)
        block = min(BLOCK_GUESS.get(d.driver, 256) for d in self.cfg.device_list)
        maxsize = max(64, int(spec.queue_seconds * self.fs / max(1, block)))
        frame = {} if self.opts.analysis_frame_s is None else {
            "frame_wait_s": self.opts.analysis_frame_s, "frame_samples": 1024 if self.opts.analysis_frame_s > 0 else 1}
        try:
            if spec.process == "worker":
                from daq.lanes.host import start_lane_host

                self.host = start_lane_host(self.fan, self.rig, self.streams, self.fs, self.results.emit, settings, maxsize,
                                            frame, confirm=spec.confirm, say=self.opts.line or self.opts.frf_line,
                                            base_nice=self.base_nice, room=self._writer_room(),
                                            nice_step=spec.worker_nice, sink_encoded=self.results.emit_encoded)  # fmt: skip
                lane = self.host.analysis_lane()
            else:
                lane = start_analysis_lane(self.fan, self.rig, self.streams, self.fs, self.results.emit, settings, maxsize,
                                           **frame)  # fmt: skip
            self.log.clocks[layout.ANALYSIS_PREFIX] = lane.stream  # its windows are timed on the analysed stream's clock
            return lane
        except LaneUnavailable as exc:
            self.results.emit(layout.EVENTS_TOPIC, {"kind": "analysis_error", "message": f"analysis off: {exc}"}, None)
            return None

    def _writer_room(self) -> Callable[[], bool]:
        """True while the log writer keeps up (less than half a second of data queued): the lane host's results wait
        otherwise, so a starved worker's burst of records never takes the writer's time while the blocks are behind
        (records have their own bound in the writer, D67, so they cannot take the blocks' memory)."""
        w = self.log.writer

        def room() -> bool:
            return w.backlog()["seconds"] < 0.5

        return room

    def _confirm_lane(self):
        if self.analysis is None or not self.cfg.analysis.confirm:
            return None
        if self.host is not None:  # in the worker beside the analysis; here only its place in the stop order
            return self.host.confirm_lane(self.opts.drain_progress, self.opts.wait_confirmations)
        from daq.lanes.confirm import DrainingConfirmLane, start_confirm_lane

        lane = start_confirm_lane(self.fan, self.analysis, self.results.emit, say=self.opts.line or self.opts.frf_line)
        self.results.route(lane, [layout.IR_EVENTS_TOPIC])
        return DrainingConfirmLane(lane, self.opts.drain_progress, self.opts.wait_confirmations)

    def _view_lane(self):
        target = self.opts.view
        if target is None:
            return None
        from daq.lanes.view import start_view_lane

        block = min(BLOCK_GUESS.get(d.driver, 256) for d in self.cfg.device_list)
        # one second of blocks (64-sample serial blocks: 256): a hit's wavelet or a results batch may outlast less
        size = max(64, int(1.0 * self.fs * len(self.cfg.device_list) / min(64, block)))
        lane = start_view_lane(self.fan, self.rig, self.streams, self.fs, target, maxsize=size)
        lane.report_sink = self.log.sink
        self.results.route(lane)
        return lane

    # --- running --------------------------------------------------------------------------------------
    def run(self) -> SessionResult:
        status = None
        if self.opts.status is not None:
            def status(seconds: float) -> None:
                self.opts.status(self.status(seconds))
        outcome = self.recorder.run(status=status)
        return self._result(outcome)

    def status(self, seconds: float) -> dict:
        verdicts: dict[str, int] = {}
        for h in list(self.hits.hits):
            verdicts[h.verdict] = verdicts.get(h.verdict, 0) + 1
        levels: dict[str, float] = {}
        for s in self.sources:
            levels.update(s.take_levels())
        samples = sum(s.report.samples for s in self.sources)
        stats = [s.driver.stats for s in self.sources]
        current = self.log.stats.files[-1] if self.log.stats.files else None
        ranges = self._ranges()
        return {
            "seconds": seconds, "samples": samples, "rate": samples / max(seconds, 1e-9), "hits": len(self.hits.hits),
            "lost": sum(s.lost_samples for s in stats), "verdicts": verdicts, "levels": levels,
            "ranges": {c: ranges.get(c) for c in levels}, "crc_errors": sum(s.frames_bad for s in stats),
            "reconnects": sum(s.reconnects for s in stats), "writer_overruns": self.log.stats.overrun_samples,
            "file_bytes": Path(current).stat().st_size if current and Path(current).exists() else 0,
            "silent": {s.name: s.silent_for for s in self.sources if s.silent_for > 2.0},
            "frf": None if self.frf is None else {"averages": self.frf.acc.count, "refused": sum(
                r.verdict == "refused" for r in list(self.frf.records))},
            "plan": self._plan_status(),
        }  # fmt: skip

    def _plan_status(self) -> dict | None:
        """A roving-hammer plan's progress for the status line: the prompt and each point's accepted averages."""
        t = None if self.frf is None else self.frf.tracker
        if t is None:
            return None
        pts = [{"name": p.name, "done": d, "averages": p.averages} for p, d in zip(t.points, list(t.done), strict=True)]
        return {"prompt": t.prompt(), "current": None if t.complete else t.point.name, "points": pts}

    def _result(self, outcome: Outcome) -> SessionResult:
        res = self.result
        res.outcome = outcome
        res.seconds = outcome.seconds
        res.simulated_faults = dict(self.harness.faults)
        res.hits = list(self.hits.hits)
        res.suspect_reasons = self.hits.suspects()
        res.suspects = sorted(res.suspect_reasons)
        for s in self.sources:
            st = s.driver.stats
            res.streams[s.name] = s.report.samples
            res.stream_gaps[s.name] = sorted([*st.gaps, *s.queue_lost])  # a block the driver's queue dropped: a gap
            for k, v in s.events.items():
                res.events[k] = res.events.get(k, 0) + v
            res.restarts += st.restarts
            res.rejected_blocks += st.rejected_blocks
            res.estimated_lost_samples += st.estimated_lost_samples
        res.samples = sum(res.streams.values())
        res.lost_samples = sum(s.driver.stats.lost_samples + sum(b - a for a, b in s.queue_lost) for s in self.sources)
        res.gaps = [g for gs in res.stream_gaps.values() for g in gs]
        errors = [s for s in self.sources if s.report.error]
        if errors:
            one = errors[0].report.error
            res.driver_error = "; ".join(f"{s.name}: {s.report.error}" for s in errors) if self.cfg.multi else one
        if self.hits.aligner is not None:
            res.timeline = self.hits.aligner.current()
            res.aligner_dropped = dict(self.hits.aligner.dropped_samples)
        if self.host is not None:  # the worker's results, as they reached the log (a restarted worker's included)
            h = self.host
            res.analysis_events = [{k: v for k, v in e.items() if k != "id"} for e in h.events]
            res.analysis_dropped_samples = h.shed.samples + h.sub.dropped_samples
            res.analysis_cpu_s = h.cpu_s
            res.analysis_latencies_s = list(h.latencies_s)
            res.confirmations = list(h.confirmations) if self.confirm is not None else []
        elif self.analysis is not None:
            res.analysis_events = [e.as_dict() for e in self.analysis.op.events]
            res.analysis_dropped_samples = self.analysis.sub.dropped_samples
            res.analysis_cpu_s = self.analysis.thread_cpu_s
            res.analysis_latencies_s = list(self.analysis.op.stats.latencies_s)
        if self.confirm is not None and self.host is None:
            res.confirmations = list(self.confirm.lane.results)
        if self.frf is not None:
            res.frf = [r.to_json() for r in self.frf.records]
        if self.view is not None:
            res.view_dropped_samples = self.view.sub.dropped_samples
        res.writer_overrun_samples = self.log.stats.overrun_samples
        res.host_stalls = [(st.at_s, st.seconds) for st in self.recorder.stalls.stalls]
        res.writer_backlog = self.log.backlog()
        res.files = list(self.log.stats.files)
        return res
