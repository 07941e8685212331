"""The recording session: driver(s) → log writer (the sacred path) and → subscribers (hit gate, analysis, viewer).

Each device has its own reading thread: its blocks go to the MCAP writer first (never blocked by anyone;
its own overrun accounting), as the device's own stream on its own sample clock, and then to the
in-process fan-out, whose subscribers drop their own input when they fall behind. Driver events (gaps,
CRC errors, reconnects, overruns) are written to ``/daq/events``; every hit record and verdict to
``/daq/hits``; channels that clip on every hit to ``/daq/events`` as ``suspect_channel``.

With several devices (``[[devices]]``), the hit gate reads the streams through a
:class:`~daq.timeline.StreamAligner` that puts them on the reference device's sample index (hammer from
one stream, responses from the others); the clock-offset estimate goes to ``/daq/timeline`` when fixed
and once per ``timeline.report_s``, and the final one to the ``gvtlink.timeline`` metadata record.
SIGTERM or Ctrl-C stop the session cleanly and finalise the file; a dying driver stops the session and
is reported and logged. The main thread only waits, watches ``stop`` and renders the status.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.model.loader import ConfigError
from analysis.model.rig import Rig
from daq.config.session import DeviceSpec, SessionConfig, TimelineSpec
from daq.fanout import FanOut
from daq.hits import HitDetector, HitRecord, TriggerSettings
from daq.log.writer import ChannelInfo, LogWriter
from daq.sim_session import channel_infos
from daq.timeline import StreamAligner
from drivers.base import Driver, DriverError, make_driver

TIMELINE_TOPIC = "/daq/timeline"
META_TIMELINE = "gvtlink.timeline"


@dataclass
class SessionResult:
    path: Path
    hits: list[HitRecord] = field(default_factory=list)
    suspects: list[str] = field(default_factory=list)
    samples: int = 0
    lost_samples: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    events: dict[str, int] = field(default_factory=dict)
    driver_error: str | None = None
    writer_overrun_samples: int = 0
    seconds: float = 0.0
    files: list[str] = field(default_factory=list)
    streams: dict[str, int] = field(default_factory=dict)  # samples recorded per device stream
    stream_gaps: dict[str, list[tuple[int, int]]] = field(default_factory=dict)
    reference: str = ""  # the stream whose index the hit records use
    timeline: dict[str, dict] = field(default_factory=dict)  # final offset estimate per other stream
    aligner_dropped: dict[str, int] = field(default_factory=dict)  # samples the hit gate never saw, per stream
    analysis_events: list[dict] = field(default_factory=list)  # IR events of the near-live analysis
    analysis_dropped_samples: int = 0  # samples the analysis lane skipped because it fell behind
    view_dropped_samples: int = 0  # samples the live view did not show (lossy side channel, daq/view/lane.py)
    confirmations: list[dict] = field(default_factory=list)  # WBEMD + slow-flow records of the IR events


def _simulated_rig(rig: Rig, ranges: dict[str, float]) -> Rig:
    """The rig with sensor ranges overridden (e.g. a channel that clips on every hit)."""
    if not ranges:
        return rig
    import tomllib

    from analysis.model.config import RigConfig
    from analysis.model.loader import validate
    from analysis.model.rig import build_rig

    data = tomllib.loads(Path(rig.path).read_text())
    for s in data.get("sensors", []):
        if s["name"] in ranges:
            s["range"] = ranges[s["name"]]
    return build_rig(validate(RigConfig, data, rig.path), rig.path)


def _start_simulation(cfg: SessionConfig, rig: Rig) -> tuple[Any, dict[str, tuple[Any, dict[str, Any]]]]:
    """Start ONE simulated structure and a transport server for every simulated device of the session.

    Returns (device, {device name: (server, driver config overrides)}). Several devices are
    :class:`~drivers.sim.device.DelayedDeviceView` s of the one structure, each serving its own channels
    with its clock started ``simulate.start_delay`` after the first's. Serial servers hold their clock
    until :func:`run_session` has opened the drivers (``go()``)."""
    from drivers.sim.device import DelayedDeviceView, HitSchedule, SimulatedDevice
    from drivers.sim.faults import Faults

    specs = [d for d in cfg.device_list if d.simulate is not None]
    sim = specs[0].simulate
    assert sim is not None
    rig = _simulated_rig(rig, sim.ranges)
    times, forces = [], []
    for k, f in enumerate(sim.forces):
        t = sim.first + k * sim.period
        times.append(t)
        forces.append(f)
        if k in sim.double_hits:
            times.append(t + 0.004)
            forces.append(0.6 * f)
    delay = max(d.simulate.start_delay for d in specs if d.simulate is not None)
    duration = (cfg.duration or 0) + 1.0 + delay
    device = SimulatedDevice(rig, HitSchedule(tuple(times), tuple(forces)), duration=duration, seed=sim.seed)
    servers: dict[str, tuple[Any, dict[str, Any]]] = {}
    for i, d in enumerate(specs):
        s = d.simulate
        assert s is not None
        view = DelayedDeviceView(device, round(s.start_delay * device.fs)) if cfg.multi else device
        names = d.channel_names()
        if names is not None:
            missing = [c for c in names if c not in device.channels]
            if missing:
                raise ConfigError(cfg.name, f"{d.name}.channels", f"the rig has no channel {missing[0]!r}")
        faults = Faults(seed=s.seed + i)
        if d.driver == "serial":
            from drivers.serial.sim_server import SerialSimServer

            idx = None if names is None else [device.channels.index(c) for c in names]
            server = SerialSimServer(view, faults, fmt=s.format, channels=idx)
            server.start(hold=True)  # the clock starts once the driver has the port open (run_session)
            over: dict[str, Any] = {"port": server.path, "usb_cdc": True, "sample_format": s.format}
            if names is not None:
                over["channels"] = names
            servers[d.name] = (server, over)
        else:
            from drivers.modbus.sim_server import ModbusSimServer

            chans = names or d.config.get("channels", ["hammer", "a01", "a02"])
            server = ModbusSimServer(view, faults, chans)
            server.start()
            servers[d.name] = (server, {"port": server.port})
    return device, servers


def _driver_config(d: DeviceSpec, rig: Rig, cfg: SessionConfig, device: Any, overrides: dict[str, Any] | None) -> dict:
    dconf = dict(d.config)
    dconf.setdefault("stream", d.name)
    if overrides is not None:
        dconf.update(overrides)
        dconf.setdefault("sample_rate", device.fs)
        if d.driver == "serial":
            dconf.setdefault("channels", list(device.channels))
        dconf["expect_first_index"] = 0  # we started the device: loss before the first block counts
    if d.driver == "sim":  # the in-process simulated device: it is the rig itself
        dconf.setdefault("rig", rig.path)
        dconf.setdefault("sample_rate", rig.sample_rate)
        dconf.setdefault("channels", [p.name for p in [rig.hammer, *rig.sensors]])
        dconf.setdefault("duration", cfg.duration)
        dconf.setdefault("expect_first_index", 0)
    return dconf


@dataclass
class _Reader:
    """One device's reading thread and what it counted."""

    name: str
    driver: Driver
    channels: tuple[str, ...]
    levels: np.ndarray
    samples: int = 0
    error: str | None = None
    thread: threading.Thread | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)


def run_session(
    cfg: SessionConfig, rig: Rig, out: Path, stop: threading.Event | None = None, status: Callable[[dict], None] | None = None,
    view=None,
) -> SessionResult:
    """Record the session's device(s) into ``out`` until ``stop``, the duration, or a driver ends; ``view``: a
    :class:`daq.view.lane.ViewTarget` for the live view (a lossy fan-out subscriber)."""
    stop = stop or threading.Event()
    result = SessionResult(path=out)
    specs = cfg.device_list
    device, servers = _start_simulation(cfg, rig) if any(d.simulate is not None for d in specs) else (None, {})
    try:
        return _run(cfg, rig, out, stop, status, result, specs, device, servers, view)
    finally:
        for server, _ in servers.values():
            server.stop()


def _run(cfg, rig, out, stop, status, result, specs, device, servers, view=None) -> SessionResult:
    infos: list[ChannelInfo] = channel_infos(rig)
    by_name = {c.name: c for c in infos}
    readers: dict[str, _Reader] = {}
    for d in specs:
        over = servers[d.name][1] if d.name in servers else None
        drv = make_driver(d.driver, _driver_config(d, rig, cfg, device, over))
        chans = tuple(drv.config.channels)
        readers[d.name] = _Reader(d.name, drv, chans, np.zeros(len(chans), np.float32))
    rates = {n: float(r.driver.config.sample_rate) for n, r in readers.items()}
    fs = next(iter(rates.values()))
    if len(set(rates.values())) > 1:
        shown = ", ".join(f"{n} {v:g} Hz" for n, v in rates.items())
        raise ConfigError(cfg.name, "devices", f"the devices sample at different rates ({shown}); resampling is not supported")
    ref = cfg.reference_device()
    result.reference = ref
    ranges = {}
    for p in [rig.hammer, *rig.sensors]:
        if p.props.range is not None:
            ranges[p.name] = p.props.range
    for d in specs:
        if d.simulate is not None:
            ranges.update(d.simulate.ranges)
    aligner: StreamAligner | None = None
    det_channels = readers[ref].channels
    if cfg.multi:
        tl = cfg.timeline or TimelineSpec()
        aligner = StreamAligner(
            {n: r.channels for n, r in readers.items()}, ref, fs, offsets=tl.offsets, settle_s=tl.settle_s,
            window_s=tl.window_s, max_buffer_s=tl.max_buffer_s, report_s=tl.report_s,
        )  # fmt: skip
        det_channels = aligner.channels
    t = cfg.trigger
    detector = HitDetector(
        TriggerSettings(level=t.level, channel=t.channel, pre_trigger=t.pre_trigger, record_length=t.record_length,
                        hysteresis=t.hysteresis, force_range=t.force_range, driving_point=t.driving_point,
                        suspect_after=t.suspect_after),
        det_channels, fs, ranges,
    )  # fmt: skip
    queue_size = 0
    for d in specs:
        drv = readers[d.name].driver
        block_guess = {"serial": 64, "modbus": 39}.get(d.driver, getattr(drv.config, "block_size", 256))
        queue_size += max(8, int(cfg.queue_seconds * fs / block_guess))
    fan = FanOut()
    sub = fan.subscribe("hits", maxsize=max(64, queue_size))
    vlane = None
    if view is not None:
        from daq.view.lane import start_view_lane

        # one second of blocks (64-sample serial blocks: 256, not a fixed 64 = 0.25 s that a hit's wavelet
        # or a results batch could outlast); it is still lossy past that
        view_blocks = max(64, int(1.0 * fs * len(specs) / min(64, block_guess)))
        vlane = start_view_lane(fan, rig, {n: r.channels for n, r in readers.items()}, fs, view, maxsize=view_blocks)
    tee = vlane.offer if vlane is not None else (lambda topic, obj: None)
    ev_lock = threading.Lock()
    halt = threading.Event()  # the session ends: stop, duration reached, or a driver ended or died
    with LogWriter(
        out,
        queue_size=queue_size,
        rotate_bytes=cfg.rotate_bytes,
        rotate_seconds=cfg.rotate_seconds,
        session_metadata={"session": cfg.name, "rig": rig.name},
    ) as writer:
        for n, r in readers.items():
            writer.add_stream(n, [by_name.get(c, ChannelInfo(c, "other", "")) for c in r.channels], fs, t0_ns=0)
        writer.add_metadata("gvtlink.config", {"session_toml": cfg.model_dump_json()})
        if Path(rig.path).exists():
            writer.add_attachment(f"rig/{Path(rig.path).name}", Path(rig.path).read_bytes(), "application/toml")

        def write_events(r: _Reader) -> None:
            for ev in r.driver.drain_events():
                writer.write_event(ev.kind, **{k: v for k, v in ev.as_dict().items() if k != "kind"})
                tee("/daq/events", ev.as_dict())
                with ev_lock:
                    result.events[ev.kind] = result.events.get(ev.kind, 0) + 1

        def timeline_messages() -> None:
            assert aligner is not None
            for m in aligner.drain_messages():
                writer.write_json(TIMELINE_TOPIC, m)
                if m["kind"] == "moved":
                    writer.write_event(
                        "timeline_moved", stream=m["stream"],
                        message=f"clock offset of {m['stream']} to {ref} moved by {m['moved_samples']:.1f} samples "
                        f"(limit {m['limit_samples']:.1f}); the merged stream keeps {m['applied_samples']}",
                    )  # fmt: skip

        def hit_gate() -> None:
            def run(blk) -> None:
                for h in detector.feed(blk):
                    result.hits.append(h)
                    writer.write_hit(h.summary())
                    tee("/daq/hits", h.summary())

            for blk in sub:
                if aligner is None:
                    run(blk)
                    continue
                for m in aligner.feed(blk):
                    run(m)
                timeline_messages()
            if aligner is not None:
                for m in aligner.finish():
                    run(m)
                timeline_messages()
            for h in detector.finish():
                result.hits.append(h)
                writer.write_hit(h.summary())
                tee("/daq/hits", h.summary())

        timeout = 0.2 if cfg.duration else None
        # a device may start later than the others (its own power-on, the simulated start_delay)
        grace = None if timeout is None else timeout if not cfg.multi else 2.0 + max(
            (d.simulate.start_delay for d in specs if d.simulate is not None), default=0.0
        )  # fmt: skip
        need = None if cfg.duration is None else cfg.duration * fs

        def read(r: _Reader) -> None:
            """The recording path: this device's blocks → log writer first, then the fan-out."""
            stamp = aligner is not None
            try:
                it = r.driver.blocks(timeout=grace)
                first = next(it, None)
                if first is None:
                    return
                for blk in _chain(first, r.driver.blocks(timeout=timeout)):
                    if stamp:
                        blk.extra["t_host"] = time.monotonic()  # arrival: the clock-offset estimate's input
                    writer.write_block(blk, wait=not r.driver.realtime)  # the recording path first
                    fan.publish(blk)
                    r.samples += blk.n_samples
                    if status is not None:
                        with r.lock:
                            np.maximum(r.levels, np.max(np.abs(blk.data), axis=0), out=r.levels)
                    write_events(r)
                    if halt.is_set() or stop.is_set():
                        break
                    if need is not None and r.name == ref and r.samples >= need:
                        break
            except DriverError as exc:
                r.error = str(exc)
                writer.write_event("driver_error", stream=r.name, message=str(exc))
            finally:
                halt.set()  # one device ending (duration, silence, error) ends the session

        clane_box: list = []  # the confirmation lane, once the analysis lane says which stream it reads

        def tee_events(topic: str, obj: dict) -> None:
            tee(topic, obj)
            if topic == "/analysis/events" and clane_box:
                clane_box[0].offer(obj)

        lane = _analysis_lane(cfg, rig, fan, {n: r.channels for n, r in readers.items()}, fs, writer, block_guess, tee_events)
        if lane is not None and cfg.analysis.confirm:
            clane_box.append(_confirm_lane(fan, lane, writer, tee))
        worker = threading.Thread(target=hit_gate, name="hit-gate", daemon=True)
        worker.start()
        t0 = time.monotonic()
        last_status = t0
        try:
            with ExitStack() as stack:
                try:
                    for r in readers.values():
                        stack.enter_context(r.driver)
                except DriverError as exc:
                    r.error = str(exc)
                    writer.write_event("driver_error", stream=r.name, message=str(exc))
                    halt.set()
                if not halt.is_set():
                    for server, _o in servers.values():  # views of one structure: any order keeps their offsets
                        if hasattr(server, "go"):
                            server.go()
                    for r in readers.values():
                        r.thread = threading.Thread(target=read, args=(r,), name=f"read:{r.name}", daemon=True)
                        r.thread.start()
                while not halt.wait(0.05):
                    if stop.is_set():
                        halt.set()
                    now = time.monotonic()
                    if status is not None and now - last_status >= 1.0:
                        status(_status(result, readers, writer, ranges, now - t0))
                        last_status = now
                for r in readers.values():  # readers stop at their next block; a silent one when its driver closes
                    if r.thread is not None:
                        r.thread.join(timeout=1.0)
            for r in readers.values():  # drivers closed
                if r.thread is not None:
                    r.thread.join(timeout=10)
        finally:
            halt.set()
            for r in readers.values():
                write_events(r)
            fan.close()
            worker.join(timeout=30)
            if lane is not None:
                result.analysis_events = [e.as_dict() for e in lane.join(timeout=60)]
                result.analysis_dropped_samples = lane.sub.dropped_samples
            if clane_box:  # after the analysis lane: its last events come at its finish
                result.confirmations = clane_box[0].join(timeout=60)
            if vlane is not None:
                vlane.join()
                result.view_dropped_samples = vlane.sub.dropped_samples
                if (vev := vlane.overrun_event()) is not None:
                    writer.write_event(vev.pop("kind"), **vev)
        result.suspects = detector.suspects()
        for c in result.suspects:
            writer.write_event("suspect_channel", message=f"channel {c} clipped on every one of {detector.health.hits} hits")
        if sub.dropped_blocks:
            writer.write_event(
                "subscriber_overrun", count=sub.dropped_samples, message=f"hit gate fell behind by {sub.dropped_blocks} blocks"
            )
        errors = [r for r in readers.values() if r.error]
        if errors:
            result.driver_error = errors[0].error if not cfg.multi else "; ".join(f"{r.name}: {r.error}" for r in errors)
        for n, r in readers.items():
            result.streams[n] = r.samples
            result.stream_gaps[n] = list(r.driver.stats.gaps)
        result.samples = sum(result.streams.values())
        result.lost_samples = sum(r.driver.stats.lost_samples for r in readers.values())
        result.gaps = [g for gs in result.stream_gaps.values() for g in gs]
        if aligner is not None:
            result.timeline = aligner.current()
            result.aligner_dropped = dict(aligner.dropped_samples)
            fixed = {s: {**o.as_dict(), "applied_samples": o.offset_samples} for s, o in aligner.fixed_offsets.items()}
            writer.add_metadata(
                META_TIMELINE,
                {
                    "reference": ref, "sample_rate": repr(fs), "channels": json.dumps(list(aligner.channels)),
                    "fixed": json.dumps(fixed), "final": json.dumps(result.timeline),
                    "dropped_samples": json.dumps(result.aligner_dropped),
                },
            )  # fmt: skip
        result.seconds = time.monotonic() - t0
    result.writer_overrun_samples = writer.stats.overrun_samples
    result.files = list(writer.stats.files)
    return result


def _analysis_lane(cfg: SessionConfig, rig: Rig, fan, streams: dict, fs: float, writer: LogWriter, block: int, tee=None):
    """Start the near-live analysis on the stream that carries the rig's sensors (None if off or absent)."""
    spec = cfg.analysis
    if not spec.enabled:
        return None
    from analysis.operator import AnalysisSettings
    from daq.analysis_lane import LaneUnavailable, start_analysis_lane

    sink = _log_sink(writer, tee)
    settings = AnalysisSettings(window_s=spec.window_s, n_keep=spec.n_keep, seed_lane=spec.seed_lane)
    maxsize = max(64, int(spec.queue_seconds * fs / max(1, block)))
    try:
        return start_analysis_lane(fan, rig, streams, fs, sink, settings, maxsize)
    except LaneUnavailable as exc:
        writer.write_event("analysis_error", message=f"analysis off: {exc}")
        return None


def _confirm_lane(fan, lane, writer: LogWriter, tee):
    """The background confirmation of the analysis lane's IR events; records to the log (and the view)."""
    from daq.confirm_lane import start_confirm_lane

    return start_confirm_lane(fan, lane, _log_sink(writer, tee))


def _log_sink(writer: LogWriter, tee=None):
    """A lane's sink: ``/daq/events`` as events, everything else as JSON on its topic, then to ``tee`` (the view)."""

    def sink(topic: str, obj: dict, log_time_ns: int | None) -> None:
        if topic == "/daq/events":
            writer.write_event(obj["kind"], **{k: v for k, v in obj.items() if k != "kind"})
        else:
            writer.write_json(topic, obj, log_time_ns=log_time_ns)
        if tee is not None:
            tee(topic, obj)

    return sink


def _chain(first, rest):
    yield first
    yield from rest


def _status(result: SessionResult, readers: dict[str, _Reader], writer: LogWriter, ranges: dict, seconds: float) -> dict:
    verdicts: dict[str, int] = {}
    for h in list(result.hits):
        verdicts[h.verdict] = verdicts.get(h.verdict, 0) + 1
    levels: dict[str, float] = {}
    for r in readers.values():
        with r.lock:
            levels.update(zip(r.channels, r.levels.tolist(), strict=True))
            r.levels[:] = 0
    samples = sum(r.samples for r in readers.values())
    current = writer.stats.files[-1] if writer.stats.files else None
    stats = [r.driver.stats for r in readers.values()]
    return {
        "seconds": seconds, "samples": samples, "rate": samples / seconds, "hits": len(result.hits),
        "lost": sum(s.lost_samples for s in stats), "verdicts": verdicts, "levels": levels,
        "ranges": {c: ranges.get(c) for c in levels}, "crc_errors": sum(s.frames_bad for s in stats),
        "reconnects": sum(s.reconnects for s in stats), "writer_overruns": writer.stats.overrun_samples,
        "file_bytes": Path(current).stat().st_size if current and Path(current).exists() else 0,
    }  # fmt: skip
