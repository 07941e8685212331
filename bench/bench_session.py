"""Session benchmark (issue: gvt record). Prints a table, writes bench/results/bench_session.json.

1. 64 ch x 51.2 kHz from the simulated device (in-process transport) into MCAP with the trigger on,
   60 s of data paced at real time: loss (target 0), CPU seconds per second of data; and the same
   unpaced, for the margin to real time.
2. The seed's rig (hammer + 14 accelerometers, 16384 Hz) over the pty serial transport, paced.

    python bench/bench_session.py [--seconds 60] [--quick]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

from analysis.model.rigs import open_rig
from daq.config.session import DeviceSpec, SessionConfig, SimulateSpec, TriggerSpec
from daq.session import run_session

ROOT = Path(__file__).resolve().parents[1]


def _run(cfg: SessionConfig, rig_name: str, out: Path) -> dict:
    rig = open_rig(rig_name)
    c0, t0 = time.process_time(), time.perf_counter()
    res = run_session(cfg, rig, out)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    fs = rig.sample_rate
    n_ch = len(rig.sensors) + 1
    data_s = res.samples / fs
    return {
        "session": cfg.name, "channels": n_ch, "sample_rate": fs, "data_seconds": data_s, "wall_s": wall,
        "cpu_s": cpu, "cpu_per_data_s": cpu / data_s if data_s else float("nan"),
        "x_real_time": data_s / wall if wall else float("nan"), "samples_per_s": res.samples * n_ch / wall,
        "lost_samples": res.lost_samples, "writer_overrun_samples": res.writer_overrun_samples, "hits": len(res.hits),
        "file_bytes": sum(Path(f).stat().st_size for f in res.files),
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="10 s instead of 60 s")
    args = ap.parse_args()
    secs = 10.0 if args.quick else args.seconds
    trig = TriggerSpec(level=20.0, record_length=0.3, driving_point="a13")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for paced in (True, False):
            cfg = SessionConfig(
                name=f"64ch x 51.2 kHz, in-process, {'paced' if paced else 'full speed'}", rig="bench_64ch", duration=secs,
                device=DeviceSpec(driver="sim", config={"paced": paced, "block_size": 1024, "forces": [800.0, 1500.0],
                                                        "period": 1.0, "physics_seconds": 3.0}),
                trigger=TriggerSpec(level=20.0, record_length=0.3),
            )  # fmt: skip
            print(f"running: {cfg.name}, {secs:g} s of data", flush=True)
            rows.append(_run(cfg, "bench_64ch", Path(tmp) / f"s64_{paced}.mcap"))
        cfg = SessionConfig(
            name="seed rig 15 ch x 16384 Hz over the pty serial transport", rig="beam_ch4_exp", duration=min(secs, 20.0),
            device=DeviceSpec(driver="serial", simulate=SimulateSpec(forces=[400.0, 800.0, 1200.0, 1583.0] * 10, period=0.5)),
            trigger=trig,
        )  # fmt: skip
        print(f"running: {cfg.name}", flush=True)
        rows.append(_run(cfg, "beam_ch4_exp", Path(tmp) / "serial.mcap"))
    print()
    print(f"{'session':58s} {'data s':>7s} {'x RT':>6s} {'CPU/s':>6s} {'M S/s':>6s} {'lost':>6s} {'overrun':>8s} {'hits':>5s}")
    for r in rows:
        print(
            f"{r['session']:58s} {r['data_seconds']:7.1f} {r['x_real_time']:6.2f} {r['cpu_per_data_s']:6.3f} "
            f"{r['samples_per_s'] / 1e6:6.2f} {r['lost_samples']:6d} {r['writer_overrun_samples']:8d} {r['hits']:5d}"
        )
    print(
        f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB;"
        " targets: paced 64 ch no loss; CPU per s of data < 1 core (2-core machine)"
    )
    res_dir = ROOT / "bench" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    (res_dir / "bench_session.json").write_text(json.dumps({"rows": rows}, indent=2))
    print(f"wrote {res_dir / 'bench_session.json'}")


if __name__ == "__main__":
    main()
