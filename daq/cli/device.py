"""``gvt device serve RIG --transport serial|can|modbus``: the simulated DAQ device as a process."""

from __future__ import annotations

import os
import signal
import threading
from typing import Annotated

import typer

from daq.cli.common import err, fail, open_rig, out

device_app = typer.Typer(no_args_is_help=True, help="The simulated DAQ device.")


@device_app.command("serve")
def serve(
    rig: Annotated[str, typer.Argument(help="Rig TOML file or the name of a rig in configs/rigs.")],
    transport: Annotated[str, typer.Option(help="serial (a pty), can (python-can interface) or modbus (TCP).")] = "serial",
    hits: Annotated[int, typer.Option(min=0, max=1000, help="Hits on the schedule, rising to the rig's nominal force.")] = 5,
    period: Annotated[float, typer.Option(min=0.05, help="Seconds between scheduled hits.")] = 2.0,
    seconds: Annotated[float | None, typer.Option(min=0.1, help="Stop after this long (default: until Ctrl-C/SIGTERM).")] = None,
    seed: Annotated[int, typer.Option(help="Noise and fault seed.")] = 0,
    channels: Annotated[str | None, typer.Option(help="Comma-separated channel subset (default: what the link carries).")] = None,
    fmt: Annotated[str, typer.Option("--format", help="Serial sample format: int16, int24, int32, float32 or ascii.")] = "int24",
    host: Annotated[str, typer.Option(help="Modbus bind address (loopback unless you say otherwise).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Modbus TCP port (0: a free one).")] = 0,
    can_interface: Annotated[str, typer.Option(help="python-can interface for the CAN node.")] = "virtual",
    can_channel: Annotated[str, typer.Option(help="python-can channel for the CAN node.")] = "gvt0",
    corrupt: Annotated[float, typer.Option(min=0.0, max=1.0, help="Serial: byte corruption probability.")] = 0.0,
    drop: Annotated[float, typer.Option(min=0.0, max=1.0, help="Serial/CAN: frame drop probability.")] = 0.0,
    timeouts: Annotated[float, typer.Option(min=0.0, max=1.0, help="Modbus: probability of not answering a request.")] = 0.0,
) -> None:
    """Serve the simulated device over a real transport, print how to connect; Ctrl-C or SIGTERM stops it."""
    from drivers.sim.device import HitSchedule, SimulatedDevice
    from drivers.sim.faults import Faults

    if transport not in ("serial", "can", "modbus"):
        fail(f"--transport must be serial, can or modbus, got {transport!r}")
    r = open_rig(rig)
    peak = r.config.hammer.peak_force
    forces = [peak * (k + 1) / hits for k in range(hits)]
    horizon = (hits + 1) * period + 2.0
    device = SimulatedDevice(r, HitSchedule.every(period, forces), duration=horizon, seed=seed)
    faults = Faults(byte_corruption_rate=corrupt, frame_drop_rate=drop, timeout_rate=timeouts, seed=seed)
    subset = [c.strip() for c in channels.split(",") if c.strip()] if channels else None
    if subset:
        unknown = [c for c in subset if c not in device.channels]
        if unknown:
            fail(f"--channels: unknown {unknown}; the device has {list(device.channels)}")
    stop = threading.Event()

    def _stop(*_: object) -> None:
        stop.set()

    # Ctrl-C and SIGTERM (from here on, the start included) end the wait: the server stops, the loss line prints
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        if transport == "serial":
            from drivers.serial.sim_server import SerialSimServer

            idx = [device.channels.index(c) for c in subset] if subset else None
            server = SerialSimServer(device, faults, fmt=fmt, channels=idx)
        elif transport == "can":
            from drivers.can.sim_node import CanSimNode

            if can_interface == "virtual":
                err.print(
                    "note: python-can's virtual bus is in-process only; another process cannot see it. Use a real "
                    "interface (socketcan with vcan where the kernel has it, udp_multicast, slcan).",
                    markup=False,
                )
            server = CanSimNode(device, faults, interface=can_interface, channel=can_channel)
        else:
            from drivers.modbus.sim_server import ModbusSimServer

            server = ModbusSimServer(device, faults, subset or ["hammer", "a01", "a02"], port=port, host=host)
        info = server.start()
    except Exception as exc:  # a bad option combination or a port in use: one line, exit 2
        fail(f"cannot start the {transport} device: {type(exc).__name__}: {exc}")
    out.print(info, markup=False)
    how = f"Ctrl-C or SIGTERM (kill {os.getpid()})"
    out.print(f"serving for {seconds:g} s; {how} stops it sooner" if seconds else f"serving until {how}", markup=False)
    try:
        stop.wait(seconds)
    except KeyboardInterrupt:  # the handlers above make this unlikely; stop cleanly all the same
        pass
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C while stopping: the usual way out
        server.stop()
    lost = faults.injected_samples()
    out.print(f"stopped; injected loss: {lost} samples in {len(faults.injected)} ranges", markup=False)
