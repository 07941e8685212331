"""The simulated devices a session starts for itself (``[device.simulate]``), over the real transports.

One simulated structure is shared by every simulated device of a session (several devices are
:class:`~drivers.sim.device.DelayedDeviceView` s of it, each serving its own channels, its clock started
``start_delay`` after the first). Each device is served over the transport its driver reads:

* ``serial``: a pty speaking the framed binary protocol (``format`` int16/24/32, float32) or ASCII lines;
* ``modbus``: the block FIFO over Modbus TCP on 127.0.0.1, or Modbus RTU on a pty (``transport = "rtu"``);
* ``can``: a CAN FD node on python-can's in-process ``virtual`` bus (a channel name of its own);
* ``sim``: no server: the in-process driver is the device.

Servers whose output would be lost before the driver listens (a pty flushed on open, a CAN bus with no
reader yet) hold their clocks until :meth:`SimHarness.go`, which the recorder calls once every link is
open. The fault knobs of ``simulate`` (stall, disconnect, restart, wild frames) go to each device's
:class:`~drivers.sim.faults.Faults`.
"""

from __future__ import annotations

import itertools
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from analysis.model.config import RigConfig
from analysis.model.loader import ConfigError, validate
from analysis.model.rig import Rig, build_rig
from daq.config.session import DeviceSpec, SessionConfig

_CAN_CHANNELS = itertools.count()
FAULT_FIELDS = ("stall_at_s", "stall_for_s", "disconnect_at_s", "disconnect_for_s", "restart_at_s", "restart_down_s",
                "wild_frames")  # fmt: skip


@dataclass
class SimHarness:
    """The simulated structure, one server per simulated device, and each driver's config overrides."""

    device: Any = None
    servers: dict[str, Any] = field(default_factory=dict)
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    rig: Rig | None = None

    def go(self) -> None:
        """Start the held clocks (every link is open now). Views of one structure keep their offsets in any order."""
        for server in self.servers.values():
            if hasattr(server, "go"):
                server.go()

    def stop(self) -> None:
        for server in self.servers.values():
            try:
                server.stop()
            except Exception:  # a server that fails to stop must not hide the session's own outcome
                pass


def simulated_rig(rig: Rig, sample_rate: float | None, ranges: dict[str, float]) -> Rig:
    """The rig with sensor ranges overridden (e.g. a channel that clips on every hit) and, if given, its DAQ
    sample rate changed (a device served at 2048 Hz instead of the rig's 16384 Hz)."""
    if not ranges and (sample_rate is None or sample_rate == rig.sample_rate):
        return rig
    data = tomllib.loads(Path(rig.path).read_text())
    for s in data.get("sensors", []):
        if s["name"] in ranges:
            s["range"] = ranges[s["name"]]
    if sample_rate is not None:
        data.setdefault("daq", {})["sample_rate"] = float(sample_rate)
    return build_rig(validate(RigConfig, data, rig.path), rig.path)


def _faults(spec, seed: int):
    from drivers.sim.faults import Faults

    knobs = {k: getattr(spec, k) for k in FAULT_FIELDS if getattr(spec, k, None) not in (None, 0, 0.0, [], ())}
    if "wild_frames" in knobs:
        knobs["wild_frames"] = tuple(tuple(w) for w in knobs["wild_frames"])
    return Faults(seed=seed, **knobs)


def start_simulation(cfg: SessionConfig, rig: Rig) -> SimHarness:
    """Start ONE simulated structure and a server for every simulated device of the session."""
    from drivers.sim.device import DelayedDeviceView, HitSchedule, SimulatedDevice
    from drivers.sim.faults import SensorFaults

    specs = [d for d in cfg.device_list if d.simulate is not None]
    harness = SimHarness()
    if not specs:
        return harness
    sim = specs[0].simulate
    assert sim is not None
    rig = simulated_rig(rig, getattr(sim, "sample_rate", None), sim.ranges)
    harness.rig = rig
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
    dofs = None
    if cfg.plan is not None:  # a roving hammer: each hit where the plan says (double taps repeat at their point)
        from daq.roving import scheduled_dofs

        per_hit = scheduled_dofs(cfg.plan, rig, list(sim.forces), list(sim.double_hits))
        dofs = tuple(d for k, d in enumerate(per_hit) for _ in range(2 if k in sim.double_hits else 1))
    faults = None
    if sim.hum_rms or sim.reversed_polarity or sim.stuck:
        faults = SensorFaults(hum_hz=sim.hum_hz, hum_rms=dict(sim.hum_rms), reversed=tuple(sim.reversed_polarity),
                              stuck=dict(sim.stuck))  # fmt: skip
    device = SimulatedDevice(rig, HitSchedule(tuple(times), tuple(forces), dofs), duration=duration, seed=sim.seed,
                             sensor_faults=faults)  # fmt: skip
    harness.device = device
    try:
        for i, d in enumerate(specs):
            s = d.simulate
            assert s is not None
            view = DelayedDeviceView(device, round(s.start_delay * device.fs)) if cfg.multi else device
            names = d.channel_names()
            if names is not None:
                missing = [c for c in names if c not in device.channels]
                if missing:
                    raise ConfigError(cfg.name, f"{d.name}.channels", f"the rig has no channel {missing[0]!r}")
            faults = _faults(s, s.seed + i)
            harness.faults[d.name] = faults
            server, over = _serve(d, view, faults, names)
            harness.servers[d.name] = server
            harness.overrides[d.name] = over
    except BaseException:
        harness.stop()
        raise
    return harness


def _serve(d: DeviceSpec, view: Any, faults: Any, names: list[str] | None) -> tuple[Any, dict[str, Any]]:
    s = d.simulate
    assert s is not None
    if d.driver == "serial":
        from drivers.serial.sim_server import SerialSimServer

        idx = None if names is None else [view.channels.index(c) for c in names]
        server = SerialSimServer(view, faults, fmt=s.format, channels=idx)
        server.start(hold=True)  # the clock starts once the driver has the port open (SimHarness.go)
        over: dict[str, Any] = {"port": server.path, "usb_cdc": True}
        if s.format == "ascii":
            over["mode"] = "ascii"
        else:
            over["sample_format"] = s.format
        over["channels"] = names if names is not None else list(view.channels)
        return server, over
    if d.driver == "modbus":
        chans = names or d.config.get("channels", ["hammer", "a01", "a02"])
        if getattr(s, "transport", "tcp") == "rtu":
            from drivers.modbus.rtu_server import ModbusRtuSimServer

            server = ModbusRtuSimServer(view, faults, chans)
            server.start()
            # 8N2 (11 bits a character like 8E1): a pty has no parity (tests/test_modbus_rtu.py)
            return server, {"transport": "rtu", "serial_port": server.path, "parity": "N", "stopbits": 2, "channels": chans}
        from drivers.modbus.sim_server import ModbusSimServer

        server = ModbusSimServer(view, faults, chans)
        server.start()
        return server, {"port": server.port, "channels": chans}
    if d.driver == "can":
        from drivers.can.sim_node import CanSimNode

        channel = f"gvt-session-{os.getpid()}-{next(_CAN_CHANNELS)}"
        message = d.config.get("messages", ["GVT_FD3"])[0]
        dbc = {"dbc": d.config["dbc"]} if "dbc" in d.config else {}
        node = _StartOnGo(CanSimNode(view, faults, message=message, interface="virtual", channel=channel, **dbc))
        return node, {"interface": "virtual", "channel": channel, "fd": node.node.fd, "messages": [message]}
    raise ConfigError("session", f"{d.name}.simulate", f"driver {d.driver!r} has no simulated transport")


class _StartOnGo:
    """A CAN node started by :meth:`SimHarness.go`: python-can's virtual bus delivers a frame only to the buses
    that exist when it is sent, so the node sends nothing before the driver's bus is open."""

    def __init__(self, node: Any) -> None:
        self.node = node

    def go(self) -> None:
        self.node.start()

    def stop(self) -> None:
        self.node.stop()
