"""The recording session: driver → log writer (the sacred path) and → subscribers (hit gate, analysis, viewer).

The driver's blocks go to the MCAP writer first (never blocked by anyone; its own overrun accounting)
and then to the in-process fan-out, whose subscribers drop their own input when they fall behind.
Driver events (gaps, CRC errors, reconnects, overruns) are written to ``/daq/events``; every hit record
and verdict to ``/daq/hits``; channels that clip on every hit to ``/daq/events`` as ``suspect_channel``.
SIGTERM or Ctrl-C stop the session cleanly and finalise the file; a dying driver is reported and logged.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from analysis.model.rig import Rig
from daq.config.session import SessionConfig
from daq.fanout import FanOut
from daq.hits import HitDetector, HitRecord, TriggerSettings
from daq.log.writer import ChannelInfo, LogWriter
from daq.sim_session import channel_infos
from drivers.base import Driver, DriverError, make_driver


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


def _start_simulation(cfg: SessionConfig, rig: Rig):
    """Start the simulated device for the session's driver; returns (server, driver config overrides)."""
    import tomllib

    from analysis.model.rig import build_rig
    from daq.config.loader import validate
    from daq.config.rig import RigConfig
    from drivers.sim.device import HitSchedule, SimulatedDevice
    from drivers.sim.faults import Faults

    sim = cfg.device.simulate
    assert sim is not None
    if sim.ranges:
        data = tomllib.loads(Path(rig.path).read_text())
        for s in data.get("sensors", []):
            if s["name"] in sim.ranges:
                s["range"] = sim.ranges[s["name"]]
        rig = build_rig(validate(RigConfig, data, rig.path), rig.path)
    times, forces = [], []
    for k, f in enumerate(sim.forces):
        t = sim.first + k * sim.period
        times.append(t)
        forces.append(f)
        if k in sim.double_hits:
            times.append(t + 0.004)
            forces.append(0.6 * f)
    duration = (cfg.duration or 0) + 1.0
    device = SimulatedDevice(rig, HitSchedule(tuple(times), tuple(forces)), duration=duration, seed=sim.seed)
    faults = Faults(seed=sim.seed)
    if cfg.device.driver == "serial":
        from drivers.serial.sim_server import SerialSimServer

        server = SerialSimServer(device, faults, fmt=sim.format)
        server.start(hold=True)  # the clock starts once the driver has the port open (run_session)
        return server, device, {"port": server.path, "usb_cdc": True, "sample_format": sim.format}
    from drivers.modbus.sim_server import ModbusSimServer

    chans = cfg.device.config.get("channels", ["hammer", "a01", "a02"])
    server = ModbusSimServer(device, faults, chans)
    server.start()
    return server, device, {"port": server.port}


def run_session(
    cfg: SessionConfig, rig: Rig, out: Path, stop: threading.Event | None = None, status: Callable[[dict], None] | None = None
) -> SessionResult:
    stop = stop or threading.Event()
    result = SessionResult(path=out)
    server = None
    dconf = dict(cfg.device.config)
    dconf.setdefault("stream", cfg.device.name)
    infos: list[ChannelInfo] = channel_infos(rig)
    if cfg.device.simulate is not None:
        server, device, overrides = _start_simulation(cfg, rig)
        dconf.update(overrides)
        dconf.setdefault("sample_rate", device.fs)
        if cfg.device.driver == "serial":
            dconf.setdefault("channels", list(device.channels))
        dconf["expect_first_index"] = 0  # we started the device: loss before the first block counts
    if cfg.device.driver == "sim":  # the in-process simulated device: it is the rig itself
        dconf.setdefault("rig", rig.path)
        dconf.setdefault("sample_rate", rig.sample_rate)
        dconf.setdefault("channels", [p.name for p in [rig.hammer, *rig.sensors]])
        dconf.setdefault("duration", cfg.duration)
        dconf.setdefault("expect_first_index", 0)
    by_name = {c.name: c for c in infos}
    driver: Driver = make_driver(cfg.device.driver, dconf)
    channels = tuple(driver.config.channels)
    fs = float(driver.config.sample_rate)
    ranges = {}
    for p in [rig.hammer, *rig.sensors]:
        if p.props.range is not None:
            ranges[p.name] = p.props.range
    if cfg.device.simulate is not None:
        ranges.update(cfg.device.simulate.ranges)
    t = cfg.trigger
    detector = HitDetector(
        TriggerSettings(level=t.level, channel=t.channel, pre_trigger=t.pre_trigger, record_length=t.record_length,
                        hysteresis=t.hysteresis, force_range=t.force_range, driving_point=t.driving_point,
                        suspect_after=t.suspect_after),
        channels, fs, ranges,
    )  # fmt: skip
    block_guess = {"serial": 64, "modbus": 39}.get(cfg.device.driver, getattr(driver.config, "block_size", 256))
    queue_size = max(8, int(cfg.queue_seconds * fs / block_guess))
    fan = FanOut()
    sub = fan.subscribe("hits", maxsize=max(64, queue_size))
    with LogWriter(
        out,
        queue_size=queue_size,
        rotate_bytes=cfg.rotate_bytes,
        rotate_seconds=cfg.rotate_seconds,
        session_metadata={"session": cfg.name, "rig": rig.name},
    ) as writer:
        writer.add_stream(cfg.device.name, [by_name.get(c, ChannelInfo(c, "other", "")) for c in channels], fs, t0_ns=0)
        writer.add_metadata("gvtlink.config", {"session_toml": cfg.model_dump_json()})
        if Path(rig.path).exists():
            writer.add_attachment(f"rig/{Path(rig.path).name}", Path(rig.path).read_bytes(), "application/toml")

        def hit_worker() -> None:
            for blk in sub:
                for h in detector.feed(blk):
                    result.hits.append(h)
                    writer.write_hit(h.summary())
            for h in detector.finish():
                result.hits.append(h)
                writer.write_hit(h.summary())

        worker = threading.Thread(target=hit_worker, name="hit-gate", daemon=True)
        worker.start()
        t0 = time.monotonic()
        last_status = t0
        import numpy as np

        levels = np.zeros(len(channels), np.float32)  # per-channel peak |value| since the last status
        try:
            with driver:
                if server is not None and hasattr(server, "go"):
                    server.go()
                for blk in driver.blocks(timeout=0.2 if cfg.duration else None):
                    writer.write_block(blk, wait=not driver.realtime)  # the recording path first
                    fan.publish(blk)
                    result.samples += blk.n_samples
                    if status is not None:
                        np.maximum(levels, np.max(np.abs(blk.data), axis=0), out=levels)
                    for ev in driver.drain_events():
                        writer.write_event(ev.kind, **{k: v for k, v in ev.as_dict().items() if k != "kind"})
                        result.events[ev.kind] = result.events.get(ev.kind, 0) + 1
                    now = time.monotonic()
                    if status and now - last_status >= 1.0:
                        verdicts: dict[str, int] = {}
                        for h in list(result.hits):
                            verdicts[h.verdict] = verdicts.get(h.verdict, 0) + 1
                        current = writer.stats.files[-1] if writer.stats.files else None
                        status({
                            "seconds": now - t0, "samples": result.samples, "rate": result.samples / (now - t0),
                            "hits": len(result.hits), "lost": driver.stats.lost_samples, "verdicts": verdicts,
                            "levels": dict(zip(channels, levels.tolist(), strict=True)),
                            "ranges": {c: ranges.get(c) for c in channels},
                            "crc_errors": driver.stats.frames_bad, "reconnects": driver.stats.reconnects,
                            "writer_overruns": writer.stats.overrun_samples,
                            "file_bytes": Path(current).stat().st_size if current and Path(current).exists() else 0,
                        })  # fmt: skip
                        levels[:] = 0
                        last_status = now
                    if stop.is_set() or (cfg.duration is not None and result.samples >= cfg.duration * fs):
                        break
        except DriverError as exc:
            result.driver_error = str(exc)
            writer.write_event("driver_error", message=str(exc))
        finally:
            for ev in driver.drain_events():
                writer.write_event(ev.kind, **{k: v for k, v in ev.as_dict().items() if k != "kind"})
                result.events[ev.kind] = result.events.get(ev.kind, 0) + 1
            fan.close()
            worker.join(timeout=30)
            if server is not None:
                server.stop()
        result.suspects = detector.suspects()
        for c in result.suspects:
            writer.write_event("suspect_channel", message=f"channel {c} clipped on every one of {detector.health.hits} hits")
        if sub.dropped_blocks:
            writer.write_event(
                "subscriber_overrun", count=sub.dropped_samples, message=f"hit gate fell behind by {sub.dropped_blocks} blocks"
            )
        result.lost_samples = driver.stats.lost_samples
        result.gaps = list(driver.stats.gaps)
        result.seconds = time.monotonic() - t0
    result.writer_overrun_samples = writer.stats.overrun_samples
    result.files = list(writer.stats.files)
    return result
