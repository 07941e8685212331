"""Session benchmark (issue 18): the Recorder against the previous recorder, and the analysis lane's frames.

1. **Recorder vs the previous recorder**, in the same run: ``gvt record`` of the same session TOML from this
   tree and from a git worktree of the base commit (default 3ccae7c: the last commit with ``daq/session.py``'s
   ``_run``), alternating A/B so the machine's drift hits both alike. CPU (user + sys of the recorder and its
   children, from ``os.wait4``) per second of data; the ratio new/base per pair, median and range.
   Sessions: 15 ch × 16384 Hz over a pty (serial), 64 ch × 51.2 kHz in-process (paced), both with the
   near-live analysis off (the recording path the Recorder replaced), and the serial one with it on.
2. **The analysis lane's frames**: the same serial session in-process, the lane fed block by block (64-sample
   serial blocks) against joined into frames (up to 1024 samples, at most ``frame_wait_s`` after the first
   block arrived): the lane thread's CPU per second of data and the per-window latency (first block arrival →
   result) p50 / p99 / max.

    python bench/bench_session.py [--seconds 20] [--pairs 5] [--base 3ccae7c] [--quick]

Each case first runs once per tree unrecorded (page cache, numba cache), then the counted pairs.

Prints tables; writes bench/results/bench_session.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASE_DEFAULT = "3ccae7c"

SERIAL = """name = "bench-serial-15ch"
rig = "beam_ch4_exp"
duration = {seconds}

[device]
name = "dev0"
driver = "serial"

[device.simulate]
forces = {forces}
period = 0.5
seed = 1

[trigger]
level = 20.0
record_length = 0.3
driving_point = "a13"

[analysis]
enabled = {analysis}
confirm = false
"""

SIM64 = """name = "bench-sim-64ch"
rig = "bench_64ch"
duration = {seconds}

[device]
name = "dev0"
driver = "sim"
config = {{ paced = true, block_size = 1024, forces = [800.0, 1500.0], period = 1.0, physics_seconds = 3.0 }}

[trigger]
level = 20.0
record_length = 0.3

[analysis]
enabled = {analysis}
confirm = false
"""


def worktree(base: str) -> Path:
    path = Path(tempfile.gettempdir()) / f"gvt-bench-base-{base}"
    if not (path / "daq").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), base], check=True,
                       capture_output=True)  # fmt: skip
    return path


def record_cpu(tree: Path, toml: Path, out: Path) -> tuple[float, float]:
    """(CPU s, wall s) of one ``gvt record`` from ``tree`` (its own daq/ first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "daq.cli", "record", str(toml), "--out", str(out)], cwd=tree, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    _pid, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"gvt record failed in {tree}: {proc.stderr.read().decode()[-400:] if proc.stderr else ''}")
    return ru.ru_utime + ru.ru_stime, wall


def compare(base_tree: Path, seconds: float, pairs: int, tmp: Path) -> list[dict]:
    forces = [400.0, 800.0, 1200.0, 1583.0] * int(seconds)
    cases = {
        "serial 15 ch x 16384 Hz, analysis off": SERIAL.format(seconds=seconds, forces=forces, analysis="false"),
        "sim 64 ch x 51.2 kHz paced, analysis off": SIM64.format(seconds=seconds, analysis="false"),
        "serial 15 ch x 16384 Hz, analysis on": SERIAL.format(seconds=seconds, forces=forces, analysis="true"),
    }
    rows = []
    for name, text in cases.items():
        toml = tmp / "s.toml"
        toml.write_text(text)
        new_cpu, base_cpu = [], []
        for tag, tree in (("new", ROOT), ("base", base_tree)):  # one warm-up each (page cache, numba cache): not counted
            record_cpu(tree, toml, tmp / f"warm-{tag}.mcap")
            (tmp / f"warm-{tag}.mcap").unlink(missing_ok=True)
        for k in range(pairs):
            order = [("new", ROOT), ("base", base_tree)] if k % 2 == 0 else [("base", base_tree), ("new", ROOT)]
            for tag, tree in order:
                out = tmp / f"{tag}-{k}.mcap"
                cpu, wall = record_cpu(tree, toml, out)
                (new_cpu if tag == "new" else base_cpu).append(cpu / seconds)
                print(f"  {name}: pair {k + 1} {tag}: {cpu / seconds:.4f} CPU-s per data-s ({wall:.1f} s wall)", flush=True)
                out.unlink(missing_ok=True)
        ratios = [n / b for n, b in zip(new_cpu, base_cpu, strict=True)]
        rows.append({"session": name, "new_cpu_per_s": new_cpu, "base_cpu_per_s": base_cpu, "ratios": ratios,
                     "ratio_median": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios)})  # fmt: skip
    return rows


def frames(seconds: float, tmp: Path) -> list[dict]:
    from analysis.model.loader import load_config
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import run_session

    toml = tmp / "frames.toml"
    toml.write_text(SERIAL.format(seconds=seconds, forces=[400.0, 800.0, 1200.0, 1583.0] * int(seconds), analysis="true"))
    cfg = load_config(SessionConfig, toml)
    rows = []
    for label, frame in (("block by block", 0.0), ("frames (default)", None)):
        res = run_session(cfg, open_rig(cfg.rig), tmp / "frames.mcap", overwrite=True, analysis_frame_s=frame)
        lat = np.asarray(res.analysis_latencies_s) * 1000
        data_s = res.samples / 16384
        rows.append({"lane": label, "cpu_per_data_s": res.analysis_cpu_s / data_s, "windows": int(lat.size),
                     "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p99": float(np.percentile(lat, 99)),
                     "latency_ms_max": float(lat.max()), "events": len(res.analysis_events),
                     "dropped_samples": res.analysis_dropped_samples, "lost_samples": res.lost_samples})  # fmt: skip
        r = rows[-1]
        print(f"  analysis lane {label}: {r['cpu_per_data_s']:.4f} CPU-s/data-s, p99 {r['latency_ms_p99']:.1f} ms", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--base", default=BASE_DEFAULT, help="git revision of the previous recorder")
    ap.add_argument("--quick", action="store_true", help="6 s sessions, 1 pair")
    args = ap.parse_args()
    seconds, pairs = (6.0, 1) if args.quick else (args.seconds, args.pairs)
    base_tree = worktree(args.base)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print(f"Recorder vs the recorder of {args.base}: {pairs} alternating pairs of {seconds:g} s sessions", flush=True)
        rows = compare(base_tree, seconds, pairs, tmp)
        print("analysis lane: block by block vs frames", flush=True)
        lanes = frames(seconds, tmp)
    print()
    print(f"{'session':44s} {'base CPU/s':>10s} {'new CPU/s':>10s} {'new/base':>9s} {'range':>13s}")
    for r in rows:
        base, new = statistics.median(r["base_cpu_per_s"]), statistics.median(r["new_cpu_per_s"])
        spread = f"{r['ratio_min']:6.3f}-{r['ratio_max']:.3f}"
        print(f"{r['session']:44s} {base:10.4f} {new:10.4f} {r['ratio_median']:9.3f} {spread}")
    print("target: new/base <= 1.05 (analysis off: the recording path)")
    print()
    heads = " ".join(f"{h:>7s}" for h in ("p50 ms", "p99 ms", "max ms"))
    print(f"{'analysis lane':18s} {'CPU/data-s':>10s} {'windows':>8s} {heads} {'events':>6s}")
    for r in lanes:
        lat = f"{r['latency_ms_p50']:7.1f} {r['latency_ms_p99']:7.1f} {r['latency_ms_max']:7.1f}"
        print(f"{r['lane']:18s} {r['cpu_per_data_s']:10.4f} {r['windows']:8d} {lat} {r['events']:6d}")
    print("target: per-window latency p99 <= 50 ms")
    res_dir = ROOT / "bench" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    (res_dir / "bench_session.json").write_text(json.dumps({"base": args.base, "seconds": seconds, "pairs": pairs,
                                                            "recorder": rows, "analysis_lane": lanes}, indent=2))  # fmt: skip
    print(f"wrote {res_dir / 'bench_session.json'}")


if __name__ == "__main__":
    main()
