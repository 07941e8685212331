"""Issue 31 item 3: the cost of the preview topic (/preview/<stream>, daq/log/preview.py), measured.

The same synthetic blocks (bench_log's pool: 64 ch x 51.2 kHz, 1024-sample blocks, a beam's decaying modes after two
hits, sensor noise and hum, quantised like a 24-bit ADC) go through ``LogWriter`` with the preview off — the writer
as it was at the commit before, which only adds the ``if`` that skips it — and on, with the chosen bucket (256
samples = 5 ms), 128 samples and a 1 ms bucket (51 samples), alternating in the same run, best of ``--repeats``.

Reported per case: file size and its ratio to the preview-off file, the writer thread's CPU time (``thread_time``
of the writer thread itself: encoding, the preview, zstd, the writes) per second of data and its ratio to the
preview-off run's (best against best), and the share of the thread's time spent computing the preview's messages
(``_preview_messages``), which a busy machine disturbs less than the difference of two runs.
Goal (issue 31): <= 5 % file size and <= 5 % writer CPU. Prints a table, writes bench/results/bench_preview.json.

    python bench/bench_preview.py [--seconds 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.bench_log import BLOCK, FS, N_CH, STREAM, block, channels, make_pool
from daq.log.writer import LogWriter

RESULTS = Path(__file__).resolve().parents[1] / "bench" / "results"
GOAL = 0.05
CASES = {"preview off (the commit before)": None, "preview, 256-sample buckets (5 ms, chosen)": 256,
         "preview, 128-sample buckets (2.5 ms)": 128, "preview, 51-sample buckets (1 ms)": 51}  # fmt: skip


class _TimedWriter(LogWriter):
    """The writer thread's own CPU time, read by the thread as it ends, and the part of it spent computing the
    preview's messages (``thread_time`` around ``_preview_messages``: reductions, times, encoding; not the
    ``add_message`` calls, inside which mcap compresses and writes whichever chunk they fill). The same thread under
    the same load: steadier than the difference of two runs' totals on a busy machine."""

    thread_cpu = 0.0
    preview_cpu = 0.0

    def _run(self) -> None:
        try:
            super()._run()
        finally:
            self.thread_cpu = time.thread_time()

    def _preview_messages(self, b, t0: int) -> list:
        c0 = time.thread_time()
        out = super()._preview_messages(b, t0)
        self.preview_cpu += time.thread_time() - c0
        return out


def one(path: Path, bucket: int | None, n_blocks: int, pool: list) -> dict:
    if path.exists():
        path.unlink()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    w = _TimedWriter(path, queue_size=None, buffer_bytes=512 << 20, fsync=False, preview=bucket is not None,
                     preview_bucket=bucket or 256)  # fmt: skip
    w.add_stream(STREAM, channels(), FS)
    for i in range(n_blocks):
        w.write_block(block(pool, i), wait=True)
    w.close()
    return {"size_bytes": path.stat().st_size, "writer_cpu_s": w.thread_cpu, "preview_cpu_s": w.preview_cpu,
            "process_cpu_s": time.process_time() - cpu0,
            "wall_s": time.perf_counter() - wall0, "messages": w.stats.messages_written}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dir", default=None, help="where the logs are written (default: a temporary directory)")
    a = ap.parse_args()
    pool = make_pool()
    n_blocks = int(a.seconds * FS / BLOCK)
    data_s = n_blocks * BLOCK / FS
    runs: dict[str, list[dict]] = {k: [] for k in CASES}
    with tempfile.TemporaryDirectory(dir=a.dir) as tmp:
        for _ in range(a.repeats):  # alternating: the machine's load hits every case alike
            for name, bucket in CASES.items():
                runs[name].append(one(Path(tmp) / "bench.mcap", bucket, n_blocks, pool))
    base = runs[next(iter(CASES))]
    best_base_cpu = min(r["writer_cpu_s"] for r in base)
    size_base = base[0]["size_bytes"]
    rows = []
    for name, bucket in CASES.items():
        rs = runs[name]
        cpu = min(r["writer_cpu_s"] for r in rs)
        rows.append({
            "case": name, "bucket_samples": bucket, "bucket_ms": None if bucket is None else 1e3 * bucket / FS,
            "size_bytes": rs[0]["size_bytes"], "size_ratio": rs[0]["size_bytes"] / size_base - 1.0,
            "writer_cpu_s_per_s": cpu / data_s, "writer_cpu_ratio": cpu / best_base_cpu - 1.0,
            "preview_share": min(r["preview_cpu_s"] / (r["writer_cpu_s"] - r["preview_cpu_s"]) for r in rs),
            "process_cpu_s_per_s": min(r["process_cpu_s"] for r in rs) / data_s,
            "messages": rs[0]["messages"], "writer_cpu_all_s": [round(r["writer_cpu_s"], 4) for r in rs],
        })  # fmt: skip
    print(f"preview topic cost: {N_CH} ch x {FS:g} Hz, {data_s:.2f} s of data, best of {a.repeats} alternating; "
          f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"{'case':44s} {'file MB':>8s} {'size +%':>8s} {'writer CPU s/s':>15s} {'CPU +%':>7s} {'compute %':>11s} "
          f"{'messages':>9s}  goal")  # fmt: skip
    for r in rows:
        size_ok, cpu_ok = r["size_ratio"] <= GOAL, min(r["writer_cpu_ratio"], r["preview_share"]) <= GOAL
        verdict = {True: "met", False: "MISSED"}
        goal = "-" if r["bucket_samples"] is None else f"size {verdict[size_ok]}, CPU {verdict[cpu_ok]}"
        print(f"{r['case']:44s} {r['size_bytes'] / 1e6:8.2f} {100 * r['size_ratio']:8.2f} {r['writer_cpu_s_per_s']:15.4f} "
              f"{100 * r['writer_cpu_ratio']:7.2f} {100 * r['preview_share']:11.2f} {r['messages']:9d}  {goal}")  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {"n_channels": N_CH, "sample_rate": FS, "block": BLOCK, "data_seconds": data_s, "repeats": a.repeats,
           "goal": GOAL, "load_1min": os.getloadavg()[0], "cores": os.cpu_count(), "python": platform.python_version(),
           "rows": rows}  # fmt: skip
    (RESULTS / "bench_preview.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {RESULTS / 'bench_preview.json'}")


if __name__ == "__main__":
    main()
