"""Load benchmark (issue 30, "Must show"): record on a busy 2-core host and lose nothing.

1. **The load matrix at full length**: {serial, CAN FD, Modbus TCP, two devices} × {0, 4, 8, 16 CPU hogs},
   ``--seconds`` (60, the issue's figure) per cell at 16384 Hz with the near-live analysis on — the cells and
   checks of tests/test_load_matrix.py (which runs them with short cells in ``make test``). 16 hogs is the row
   the issue asks to be measured, not passed: lost samples, shed analysis, offset error, window latency.
2. **A long session at 8 hogs** (``--minutes``, default 10): 15 ch × 16384 Hz from the in-process simulated device
   paced to real time (a device over a pty computes its span ahead, at most ~68 s at this size), analysis on; 0 lost
   and memory flat — the recorder's RSS (this process: the recorder runs in-process, with the simulated device's
   server threads, as ``gvt record`` of a simulated session does) sampled every ``--rss-every`` s; start, peak,
   end and the slope of a least-squares line over the second half of the samples (before it: the device's 60 s of
   physics computed ahead — at 8 hogs ~100 s and a transient ~900 MB peak — the lanes' buffers, the first chunks).

The hogs are busy loops at the recorder's own priority (tests/hogs.py), started once the simulated devices are
built (tests/test_load_matrix.py ``load_from_device_start`` says why).

    python bench/bench_load.py [--seconds 60] [--hogs 0,4,8,16] [--cells serial,can-fd,modbus-tcp,two-devices]
                               [--repeat 1] [--minutes 10] [--no-matrix] [--no-long]
    GVT_LOAD_JSON=cells.jsonl pytest tests/test_load_matrix.py; python bench/bench_load.py --table cells.jsonl

Prints a table per part; writes bench/results/bench_load.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.hogs import Hogs  # noqa: E402
from tests.test_load_matrix import CELLS, FS, run_cell, small_rig  # noqa: E402


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


class RssSampler:
    """This process's RSS every ``period_s`` seconds on a thread: (seconds since start, MB)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._main, name="rss", daemon=True)

    def _main(self) -> None:
        t0 = time.monotonic()
        while True:
            self.samples.append((time.monotonic() - t0, rss_mb()))
            if self._stop.wait(self.period_s):
                return

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.samples.append((self.samples[-1][0] + self.period_s if self.samples else 0.0, rss_mb()))

    def summary(self, settle_s: float) -> dict:
        t = np.array([s[0] for s in self.samples])
        mb = np.array([s[1] for s in self.samples])
        late = t >= max(settle_s, t[-1] / 2)  # the second half: after the warm-up and the device's physics are built
        slope = float(np.polyfit(t[late], mb[late], 1)[0] * 60) if late.sum() >= 3 else float("nan")
        return {"start_mb": float(mb[0]), "peak_mb": float(mb.max()), "end_mb": float(mb[-1]),
                "after_warmup_mb": float(mb[late][0]) if late.any() else float("nan"),
                "slope_mb_per_min": slope, "samples": len(mb), "settle_s": settle_s,
                "series": [[round(a, 1), round(b, 1)] for a, b in self.samples]}  # fmt: skip


def _fmt(v, spec: str = ".0f") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def row(m: dict) -> str:
    off = m["offset"]
    err = "-" if off is None else f"{off['error_s'] * FS:+.2f}"
    streams = sum(s["samples"] for s in m["streams"].values())
    lost = m["lost_samples"] + m["writer_overrun_samples"]
    verdict = "ok" if not m["failures"] else "FAIL"
    return (f"{m['cell']:<12} {m['hogs']:>4} {m['load']['runnable_mean']:>6.1f} {m['load']['loadavg_1m']:>6.1f} "
            f"{streams:>10} {lost:>8} {m['analysis_dropped_samples']:>9} {m['coverage']['uncovered']:>8} {err:>8} "
            f"{_fmt(m['latency_p50_ms'])!s:>7} {_fmt(m['latency_p99_ms'])!s:>7}  {verdict}")  # fmt: skip


HEADER = (f"{'cell':<12} {'hogs':>4} {'run-q':>6} {'load1':>6} {'samples':>10} {'lost':>8} {'shed':>9} {'uncov':>8} "
          f"{'off/smp':>8} {'p50 ms':>7} {'p99 ms':>7}  verdict")  # fmt: skip


def matrix(work: Path, rig_small: Path, cells: list[str], hogs: list[int], seconds: float, repeat: int = 1) -> list[dict]:
    print(f"\nload matrix: {seconds:g} s per cell at {FS} Hz, analysis on, each cell {repeat}x "
          "(lost = driver + writer; shed = analysis input skipped; uncov = samples neither in a window nor shed; "
          "off/smp = two-device offset error in samples; run-q = runnable tasks, mean)")  # fmt: skip
    print(HEADER)
    out = []
    for n in hogs:
        for cell in [c for c in cells for _ in range(repeat)]:
            t0 = time.perf_counter()
            c = run_cell(work, cell, Hogs(n, limit_s=seconds + 300), seconds, rig_small)
            m = c.check()
            m["cell_wall_s"] = time.perf_counter() - t0
            print(row(m), flush=True)
            for f in m["failures"]:
                print(f"    {f}")
            out.append(m)
            for p in work.glob("*.mcap"):
                p.unlink()
    return out


#: the long session: a simulated device served over a pty computes its whole span ahead (at most ~68 s at 15 ch x
#: 16384 Hz, daq/config/rig_checks.py), so minutes of data come from the in-process device, paced to real time, its
#: physics 60 s long (hits every 2 s in it) and its noise floor after; the hogs, lanes and writer are the matrix's
LONG = """name = "load-long"
rig = "beam_ch4_exp"
duration = {seconds}
end_grace_s = 10.0

[device]
name = "dev0"
driver = "sim"
config = {{ paced = true, block_size = 256, forces = [300.0, 800.0], period = 2.0, physics_seconds = 60.0, seed = 3 }}

[trigger]
level = 20.0
record_length = 0.3

[analysis]
enabled = true
"""


def long_session(work: Path, minutes: float, hogs: int, rss_every: float) -> dict:
    from analysis.model.loader import load_config
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import run_session
    from tests.test_load_matrix import Cell, load_from_device_start

    seconds = minutes * 60
    print(f"\nlong session: in-process device paced, 15 ch x {FS} Hz, analysis on, {minutes:g} min at {hogs} hogs "
          f"(RSS every {rss_every:g} s)")  # fmt: skip
    path = work / "long.toml"
    path.write_text(LONG.format(seconds=seconds))
    cfg = load_config(SessionConfig, path)
    h = Hogs(hogs, limit_s=seconds + 300)
    with RssSampler(rss_every) as rss:
        try:
            with load_from_device_start(h):
                res = run_session(cfg, open_rig(cfg.rig), work / "long.mcap")
        finally:
            seen = h.stop()
    m = Cell("sim-paced", hogs, seconds, res, work / "long.mcap", seen).check()
    m["failures"] = [f for f in m["failures"] if not f.startswith("hits")]  # its own schedule: hits only in 60 s of physics
    m["rss"] = rss.summary(settle_s=60.0)
    print(HEADER)
    print(row(m))
    for f in m["failures"]:
        print(f"    {f}")
    r = m["rss"]
    print(f"RSS: start {r['start_mb']:.0f} MB, after warm-up {r['after_warmup_mb']:.0f} MB, peak {r['peak_mb']:.0f} MB, "
          f"end {r['end_mb']:.0f} MB; slope over the second half: {r['slope_mb_per_min']:+.2f} MB/min")  # fmt: skip
    for p in work.glob("*.mcap"):
        p.unlink()
    return m


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="data seconds per matrix cell")
    ap.add_argument("--hogs", default="0,4,8,16", help="hog counts of the matrix")
    ap.add_argument("--cells", default=",".join(sorted(CELLS)))
    ap.add_argument("--repeat", type=int, default=1, help="runs of each matrix cell (the offset's scatter, a rare loss)")
    ap.add_argument("--minutes", type=float, default=10.0, help="the long session's length")
    ap.add_argument("--long-hogs", type=int, default=8)
    ap.add_argument("--rss-every", type=float, default=5.0)
    ap.add_argument("--no-matrix", action="store_true")
    ap.add_argument("--no-long", action="store_true")
    ap.add_argument("--table", type=Path, help="print the table of a make-test run's cells (GVT_LOAD_JSON=FILE) and exit")
    a = ap.parse_args(argv)
    if a.table is not None:
        print(HEADER)
        for line in a.table.read_text().splitlines():
            m = json.loads(line)
            print(row(m))
            for f in m["failures"]:
                print(f"    {f}")
        return 0
    cells = [c for c in a.cells.split(",") if c]
    unknown = [c for c in cells if c not in CELLS]
    if unknown:
        print(f"bench_load: unknown cells {unknown}; known: {sorted(CELLS)}", file=sys.stderr)
        return 2
    hogs = [int(x) for x in a.hogs.split(",") if x]
    result: dict = {"cpus": os.cpu_count(), "seconds": a.seconds, "fs": FS, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    with tempfile.TemporaryDirectory(prefix="bench_load_") as tmp:
        work = Path(tmp)
        if not a.no_matrix:
            result["matrix"] = matrix(work, small_rig(work), cells, hogs, a.seconds, max(1, a.repeat))
        if not a.no_long:
            result["long"] = long_session(work, a.minutes, a.long_hogs, a.rss_every)
    out = ROOT / "bench" / "results" / "bench_load.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=str))
    print(f"\nwrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
