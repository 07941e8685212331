"""Serial benchmark (issue: serial driver). Prints a table, writes bench/results/bench_serial.json.

"The link, not the decoder, must be the limit." Measured, for 15 channels (the beam_ch4_exp rig) in
64-sample frames, per sample format:

1. decoder alone: ``FrameDecoder.feed`` over an in-memory stream of frames fed in 4 KiB chunks (what a
   pty read returns): MB/s and samples/s (one sample = one row of all channels);
2. end to end over a pty at full speed: SerialSimServer(pace=False) -> pty -> SerialDriver -> blocks,
   same counts;
3. what a 921600-baud 8N1 UART carries (92 160 B/s) and native-USB CDC (~1 MB/s) in samples/s for the
   same frames, against the rig's nominal 16 384 samples/s.

    python bench/bench_serial.py [--seconds 4]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from drivers.serial.driver import SerialConfig, SerialDriver
from drivers.serial.protocol import FORMATS, FrameDecoder, encode_frame, frame_length
from drivers.serial.sim_server import SerialSimServer
from drivers.sim.device import HitSchedule, SimulatedDevice

ROOT = Path(__file__).resolve().parents[1]
FRAME = 64


def decoder_rate(dev: SimulatedDevice, fmt: str, scales: np.ndarray, n_samples: int) -> tuple[float, float]:
    vals = dev.samples(0, n_samples)
    stream = b"".join(encode_frame(a, vals[a : a + FRAME], fmt, scales, seq=a // FRAME) for a in range(0, n_samples, FRAME))
    dec = FrameDecoder()
    t = time.perf_counter()
    got = 0
    for i in range(0, len(stream), 4096):
        got += sum(f.n_samples for f in dec.feed(stream[i : i + 4096]))
    dt = time.perf_counter() - t
    assert got == n_samples and dec.stats.frames_bad == 0
    return len(stream) / dt / 1e6, n_samples / dt


def pty_rate(dev: SimulatedDevice, fmt: str, n_samples: int) -> tuple[float, float, int]:
    srv = SerialSimServer(dev, fmt=fmt, frame_samples=FRAME, pace=False)
    srv.start()
    cfg = SerialConfig(port=srv.path, usb_cdc=True, usb_bytes_per_s=1e9, sample_rate=dev.fs, channels=list(dev.channels))
    drv = SerialDriver(cfg)
    got = 0
    t = time.perf_counter()
    with drv:
        for b in drv.blocks(timeout=5):
            got += b.n_samples
            if b.end_index >= n_samples:
                break
    dt = time.perf_counter() - t
    srv.stop()
    return drv.stats.bytes_in / dt / 1e6, got / dt, drv.stats.lost_samples + drv.stats.overruns


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=4.0, help="seconds of device data per measurement")
    args = ap.parse_args()
    from analysis.model.rig import load_rig

    rig = load_rig(ROOT / "configs/rigs/beam_ch4_exp.toml")
    dev = SimulatedDevice(rig, HitSchedule.every(2.0, [200.0, 800.0]), duration=args.seconds + 1, block_size=256, seed=1)
    n = int(args.seconds * dev.fs) // FRAME * FRAME
    ch = dev.n_channels
    rows = []
    for fmt in FORMATS:
        scales = SerialSimServer(dev, fmt=fmt).scales
        dec_mb, dec_sps = decoder_rate(dev, fmt, scales, n)
        pty_mb, pty_sps, lost = pty_rate(dev, fmt, n)
        bytes_per_sample = frame_length(FRAME, ch, fmt) / FRAME
        rows.append(
            {
                "format": fmt,
                "bytes_per_sample_row": round(bytes_per_sample, 2),
                "decoder_MB_s": round(dec_mb, 1),
                "decoder_samples_s": round(dec_sps),
                "pty_MB_s": round(pty_mb, 2),
                "pty_samples_s": round(pty_sps),
                "pty_lost": lost,
                "uart_921600_samples_s": round(92160 / bytes_per_sample),
                "usb_cdc_1MBs_samples_s": round(1e6 / bytes_per_sample),
                "nominal_samples_s": dev.fs,
            }
        )
    hdr = f"{'format':8} {'B/row':>7} {'decoder MB/s':>12} {'decoder S/s':>12} {'pty MB/s':>9} {'pty S/s':>10} {'lost':>5} "
    hdr += f"{'921600 S/s':>10} {'USB S/s':>9} {'need S/s':>9}"
    print(f"{ch} channels, {FRAME}-sample frames, {n} samples per run; S/s = sample rows (all channels) per second")
    print(hdr)
    for r in rows:
        print(
            f"{r['format']:8} {r['bytes_per_sample_row']:7.1f} {r['decoder_MB_s']:12.1f} {r['decoder_samples_s']:12,d} "
            f"{r['pty_MB_s']:9.2f} {r['pty_samples_s']:10,d} {r['pty_lost']:5d} {r['uart_921600_samples_s']:10,d} "
            f"{r['usb_cdc_1MBs_samples_s']:9,d} {r['nominal_samples_s']:9,.0f}"
        )
    out = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "channels": ch,
        "frame_samples": FRAME,
        "rows": rows,
    }
    path = ROOT / "bench/results/bench_serial.json"
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
