"""CAN driver benchmark (issue: CAN driver). Prints a table, writes bench/results/bench_can.json.

1. Decoder speed per DBC message: cantools ``Message.decode`` per frame (the reference) against the
   DBC-derived numpy fast path, per frame and batched (the driver decodes a block of frames at once).
2. Frames/s through ``CanDriver`` on python-can's in-process virtual bus, no pacing, against the physical
   limits of the links (classic CAN 1 Mbit/s with 8-byte frames ≈ 8.8 k frames/s; CAN FD 1/8 Mbit/s with
   64-byte frames ≈ 9.8 k frames/s; landscape.md §3.3):
   - driver only: the node's frames are queued on the virtual bus first, then the driver drains them
     (receive + counter check + block assembly + decode + hand-off);
   - end to end: node (quantise, encode, send) and driver run concurrently.
   Loss must be zero in every row.

    python bench/bench_can.py [--frames 60000]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import can
import numpy as np

from analysis.model.rig import load_rig
from drivers.can.dbc_map import load_layouts
from drivers.can.driver import DEFAULT_DBC, CanConfig, CanDriver, budget_frames_per_s
from drivers.can.sim_node import CanSimNode
from drivers.sim.device import HitSchedule, SimulatedDevice

ROOT = Path(__file__).resolve().parents[1]


def decode_speeds(n: int = 20000) -> list[dict]:
    rows = []
    rng = np.random.default_rng(0)
    for lay in load_layouts(DEFAULT_DBC, ["GVT_FD3", "GVT_CC1"]):
        frames = rng.integers(0, 256, (n, lay.length), dtype=np.uint8)
        blob = frames.tobytes()
        singles = [r.tobytes() for r in frames]
        m = min(n, 5000)
        t0 = time.perf_counter()
        for d in singles[:m]:
            lay.decode_cantools(d)
        t_ct = (time.perf_counter() - t0) / m
        t0 = time.perf_counter()
        for d in singles[:m]:
            lay.decode_fast(d)
        t_one = (time.perf_counter() - t0) / m
        per = max(1, 256 // lay.spf)  # frames per driver block
        t0 = time.perf_counter()
        for i in range(0, n - per + 1, per):
            lay.decode_frames(blob[i * lay.length : (i + per) * lay.length], per)
        t_batch = (time.perf_counter() - t0) / (n - n % per)
        rows.append(
            {
                "message": lay.name,
                "cantools_fps": 1 / t_ct,
                "fast_single_fps": 1 / t_one,
                "fast_batched_fps": 1 / t_batch,
                "batch_frames": per,
            }
        )
    return rows


def through_driver(dev: SimulatedDevice, message: str, frames: int, mode: str) -> dict:
    lay = load_layouts(DEFAULT_DBC, [message])[0]
    ch = f"bench-{message}-{mode}"
    cfg = CanConfig(channel=ch, fd=lay.is_fd, messages=[message], sample_rate=dev.fs, queue_blocks=1_000_000)
    node = CanSimNode(dev, message=message, channel=ch, paced=False, max_frames=frames)
    if mode == "driver only":
        rx = can.Bus(interface="virtual", channel=ch)
        node.start()
        node.join()
        drv = CanDriver(cfg, bus_factory=lambda: rx)
        t0 = time.perf_counter()
        drv.open()
    else:
        drv = CanDriver(cfg)
        drv.open()
        t0 = time.perf_counter()
        node.start()
    deadline = time.monotonic() + 120
    while drv.stats.frames_ok < frames and time.monotonic() < deadline:
        time.sleep(0.002)
    wall = time.perf_counter() - t0
    node.stop()
    drv.close()
    samples = sum(b.n_samples for b in drv.blocks(timeout=1))
    limit = budget_frames_per_s(lay.is_fd)
    return {
        "message": message,
        "link": "CAN FD 1/8 Mbit/s" if lay.is_fd else "classic CAN 1 Mbit/s",
        "mode": mode,
        "frames": frames,
        "fps": frames / wall,
        "physical_fps": limit,
        "x_physical": frames / wall / limit,
        "samples": samples,
        "expected_samples": frames * lay.spf,
        "lost_samples": drv.stats.lost_samples,
        "frames_bad": drv.stats.frames_bad,
        "overruns": drv.stats.overruns,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=60000)
    args = ap.parse_args()
    rig = load_rig(ROOT / "configs" / "rigs" / "beam_ch4_exp.toml")
    dev = SimulatedDevice(rig, HitSchedule.every(2.0, [200.0, 800.0]), duration=4.0, block_size=256, seed=1)
    dec = decode_speeds()
    runs = [through_driver(dev, m, args.frames, mode) for m in ("GVT_FD3", "GVT_CC1") for mode in ("driver only", "end to end")]
    print("\nDecoder (frames/s)")
    print(f"{'message':10} {'cantools':>10} {'fast 1/frame':>13} {'fast batched':>13} {'batched/cantools':>17}")
    for r in dec:
        print(
            f"{r['message']:10} {r['cantools_fps']:10,.0f} {r['fast_single_fps']:13,.0f} {r['fast_batched_fps']:13,.0f} "
            f"{r['fast_batched_fps'] / r['cantools_fps']:16.0f}x"
        )
    print("\nThrough CanDriver on the virtual bus (no pacing)")
    print(
        f"{'message':9} {'link':22} {'mode':12} {'frames/s':>9} {'physical':>9} {'x phys':>7} "
        f"{'samples':>9} {'lost':>5} {'bad':>4}"
    )
    for r in runs:
        ok = r["samples"] == r["expected_samples"] and r["lost_samples"] == 0
        print(
            f"{r['message']:9} {r['link']:22} {r['mode']:12} {r['fps']:9,.0f} {r['physical_fps']:9,.0f} {r['x_physical']:6.1f}x "
            f"{r['samples']:9,d} {r['lost_samples']:5d} {r['frames_bad']:4d}{'' if ok else '  LOSS!'}"
        )
    out = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "can": can.__version__,
        "decoder": dec,
        "driver": runs,
    }
    path = ROOT / "bench" / "results" / "bench_can.json"
    path.write_text(json.dumps(out, indent=2))
    print(f"\nwrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
