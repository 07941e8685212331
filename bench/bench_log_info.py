"""`gvt log info` on large logs: time against file size, from the summary and with ``--verify``.

Issue 19: ``gvt log info`` must answer from the summary "in well under a second for any size" (it decoded
every block, 5.8 s per GB). Writes 64 ch × 51.2 kHz logs of several lengths (blocks from bench_log's pool,
a hit and an event every 3 s of data, as a session writes them), then times ``log_info(path)`` (summary) and
``log_info(path, verify=True)`` (every chunk CRC-checked, every block decoded), each in a fresh process
(cold Python import included, page cache warm). Prints a table, writes JSON to bench/results/.

    .venv/bin/python bench/bench_log_info.py [--seconds 30 120] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.bench_log import BLOCK, FS, STREAM, block, channels, make_pool
from daq.log.writer import LogWriter

RESULTS = Path(__file__).resolve().parent / "results"


def write_log(path: Path, seconds: float) -> int:
    pool = make_pool()
    n_blocks = int(seconds * FS / BLOCK)
    with LogWriter(path, origin_ns=0, fsync=False) as w:
        w.add_stream(STREAM, channels(), FS, t0_ns=0)
        every = int(3 * FS / BLOCK)
        for i in range(n_blocks):
            w.write_block(block(pool, i), wait=True)
            if i % every == every // 2:
                t = i * BLOCK / FS
                w.write_hit({"index": i * BLOCK, "t_s": t, "peak_force_N": 100.0, "verdict": "accepted"})
                w.write_event("note", message=f"hit at {t:.1f} s", log_time_ns=round(t * 1e9))
    return path.stat().st_size


def timed(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import sys; from daq.log.tools import log_info; "
                    f"log_info(sys.argv[1], verify={args[1]})", args[0]], check=True)  # fmt: skip
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, nargs="+", default=[30.0, 120.0])
    ap.add_argument("--dir", default=None)
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(dir=a.dir) as d:
        for s in a.seconds:
            p = Path(d) / f"info_{int(s)}.mcap"
            size = write_log(p, s)
            plain = min(timed([str(p), "False"]) for _ in range(3))
            verify = timed([str(p), "True"])
            rows.append({"seconds": s, "bytes": size, "info_s": plain, "verify_s": verify,
                         "verify_s_per_gb": verify / (size / 1e9), "load": os.getloadavg()[0]})  # fmt: skip
            p.unlink()
    print(f"{'data [s]':>9} {'file [MB]':>10} {'info [s]':>9} {'--verify [s]':>13} {'verify [s/GB]':>14} {'load':>5}")
    for r in rows:
        print(f"{r['seconds']:9.0f} {r['bytes'] / 1e6:10.1f} {r['info_s']:9.3f} {r['verify_s']:13.2f} "
              f"{r['verify_s_per_gb']:14.2f} {r['load']:5.2f}")  # fmt: skip
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bench_log_info.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
