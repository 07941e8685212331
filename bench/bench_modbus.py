"""Modbus benchmark on loopback. Prints a table, writes bench/results/bench_modbus.json.

1. ``read_holding_registers`` of 125 registers (FC 3), pymodbus sync client (TCP_NODELAY) against
   ModbusSimServer on 127.0.0.1: requests/s (target >= 1000/s, the driver's default TCP capacity).
2. Block-FIFO drain: the device runs for a few seconds with nobody reading, then ModbusDriver (FIFO
   mode, FC 23 ack+read per frame) drains the backlog as fast as the link allows: samples/s (per
   channel row) and requests/s, for 1 and 3 channels; real time is 16384 samples/s.

Client and server share one Python process (and its GIL): a real device answers faster.

    python bench/bench_modbus.py [--requests 5000]
"""

from __future__ import annotations

import argparse
import json
import platform
import socket
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pymodbus.client import ModbusTcpClient  # noqa: E402

from analysis.model.rig import load_rig  # noqa: E402
from drivers.base import make_driver  # noqa: E402
from drivers.modbus.sim_server import ModbusSimServer  # noqa: E402
from drivers.sim.device import HitSchedule, SimulatedDevice  # noqa: E402
from drivers.sim.faults import Faults  # noqa: E402


def bench_reads(device: SimulatedDevice, n: int) -> dict:
    srv = ModbusSimServer(device, Faults(), ["hammer"])
    srv.start()
    try:
        c = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=1, retries=0)
        assert c.connect()
        c.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(100):
            c.read_holding_registers(0, count=125, device_id=1)
        t = time.perf_counter()
        for _ in range(n):
            rr = c.read_holding_registers(0, count=125, device_id=1)
            assert not rr.isError()
        dt = time.perf_counter() - t
        c.close()
    finally:
        srv.stop()
    return {"test": "FC3 read 125 registers", "requests": n, "seconds": dt, "req_per_s": n / dt, "registers_per_s": 125 * n / dt}


def bench_fifo(device: SimulatedDevice, channels: list[str], backlog_s: float) -> dict:
    srv = ModbusSimServer(device, Faults(), channels, fifo_seconds=backlog_s + 2)
    srv.start()
    try:
        c = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=1, retries=0)
        assert c.connect()
        c.write_register(srv.map.control.command.address, 1, device_id=1)  # start; nobody reads for backlog_s
        c.close()
        time.sleep(backlog_s)
        cfg = {"port": srv.port, "channels": channels, "sample_rate": device.fs, "control": False, "block_samples": 4096}
        drv = make_driver("modbus", cfg)
        req0 = srv.requests
        t = time.perf_counter()
        total = 0
        with drv:
            for b in drv.blocks(timeout=3.0):
                total += b.n_samples
                produced = srv.produced()
                if b.end_index >= produced - srv.samples_per_frame:  # caught up with the live device
                    break
        dt = time.perf_counter() - t
        reqs = srv.requests - req0
    finally:
        srv.stop()
    # while draining, the device kept producing: rate = samples read / time
    return {
        "test": f"FIFO drain, {len(channels)} ch",
        "channels": channels,
        "samples_per_frame": srv.samples_per_frame,
        "samples": total,
        "seconds": dt,
        "samples_per_s": total / dt,
        "values_per_s": total * len(channels) / dt,
        "req_per_s": reqs / dt,
        "x_real_time": total / dt / device.fs,
        "lost": drv.stats.lost_samples,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--requests", type=int, default=5000)
    ap.add_argument("--backlog", type=float, default=4.0)
    a = ap.parse_args()
    rig = load_rig(ROOT / "configs" / "rigs" / "beam_ch4_exp.toml")
    device = SimulatedDevice(rig, HitSchedule.every(2.0, [200.0, 800.0]), duration=12.0, block_size=256, seed=1)
    rows = [bench_reads(device, a.requests)]
    rows.append(bench_fifo(device, ["hammer"], a.backlog))
    rows.append(bench_fifo(device, ["hammer", "a01", "a02"], a.backlog))
    print(f"{'test':28s} {'req/s':>8s} {'samples/s':>11s} {'x real time':>11s}")
    for r in rows:
        s = f"{r['samples_per_s']:11,.0f}" if "samples_per_s" in r else f"{'-':>11s}"
        x = f"{r['x_real_time']:11.2f}" if "x_real_time" in r else f"{'-':>11s}"
        print(f"{r['test']:28s} {r['req_per_s']:8,.0f} {s} {x}")
    out = ROOT / "bench" / "results" / "bench_modbus.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "note": "client and server in one process, loopback",
    }
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
