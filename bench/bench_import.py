"""Import throughput of binary UFF 58 (issue 31: >= 50 M samples/s for CSV-free formats). Prints a table, writes
bench/results/bench_import.json.

One file of ``--channels`` time histories x ``--samples`` samples (58b, float64, as gvtlink's export and Testlab
write them), read in the same run by:

1. gvtlink's reader (``daq/studies/importing/uff.py``: datasets split by their byte counts, each 58b data block one
   ``numpy.frombuffer``) into the import record (SI, channel table) -- the issue's figure;
2. the whole ``gvt import`` (reader + the format-2 log writer: float32 blocks, zstd chunks, the hit gate);
3. pyuff alone (``pyuff.UFF(path).read_sets()``: ``struct.unpack`` of each block) -- the baseline;
4. reading the file and its sha256 alone: what any import with provenance must do, so the reader's floor (the hash
   runs on a second core beside the parsing; on a CPU without SHA instructions it is ~0.1-0.2 s per 64 MB).

Each is the best of ``--repeats`` runs (the page cache is warm after the first: this is parsing, not the disk).

    python bench/bench_import.py [--channels 8] [--samples 1000000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.model.channels import Channel
from daq.studies.uff import datasets as uff

ROOT = Path(__file__).resolve().parents[1]
GOAL = 50e6  # samples/s (issue 31, "Speed")


def make_file(path: Path, n_ch: int, n: int, fs: float = 51200.0) -> None:
    """A hammer and ``n_ch - 1`` accelerometers, a hit every second, as one binary 58b file."""
    rng = np.random.default_rng(1)
    data = rng.normal(scale=0.1, size=(n, n_ch))
    for t in range(int(0.1 * fs), n, int(fs)):
        data[t : t + 64, 0] += 100 * np.sin(np.linspace(0, np.pi, 64))
    chans = [Channel("hammer", "force", 1, (0.0, 0.0, 0.0), 3)]
    chans += [Channel(f"a{k:02d}", "acceleration", 1 + k, (0.1 * k, 0.0, 0.0), 3) for k in range(1, n_ch)]
    uff.write_uff(path, [uff.units_set(), *uff.time_sets(data, fs, chans, chans[0], binary=True)])


def best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--channels", type=int, default=8)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    import pyuff

    from daq.studies.importing import uff as reader
    from daq.studies.importing.log import write_log

    total = a.channels * a.samples
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "big.uff"
        make_file(src, a.channels, a.samples)
        size = src.stat().st_size
        out = Path(d) / "big.mcap"
        rows = {
            "gvtlink reader (numpy.frombuffer)": best(lambda: reader.read(src), a.repeats),
            "gvt import (reader + log writer)": best(lambda: write_log(reader.read(src), out, overwrite=True), a.repeats),
            "pyuff read_sets (baseline)": best(lambda: pyuff.UFF(str(src)).read_sets(), a.repeats),
            "file read + sha256 alone (the floor)": best(lambda: hashlib.sha256(src.read_bytes()).digest(), a.repeats),
        }
    print(f"binary UFF 58: {a.channels} channels x {a.samples} samples = {total / 1e6:.1f} M samples, {size / 1e6:.0f} MB")
    print(f"{'reader':<36} {'s':>8} {'M samples/s':>12} {'MB/s':>8}  goal >= {GOAL / 1e6:.0f} M/s")
    result = {"channels": a.channels, "samples": a.samples, "bytes": size, "goal_samples_per_s": GOAL, "rows": {}}
    for name, s in rows.items():
        rate = total / s
        print(f"{name:<36} {s:>8.3f} {rate / 1e6:>12.1f} {size / s / 1e6:>8.0f}  {'ok' if rate >= GOAL else '-'}")
        result["rows"][name] = {"seconds": s, "samples_per_s": rate, "meets_goal": rate >= GOAL}
    base = rows["pyuff read_sets (baseline)"]
    print(f"gvtlink reader: {base / rows['gvtlink reader (numpy.frombuffer)']:.1f}x pyuff on the same file")
    result["machine"] = platform.platform()
    out_json = ROOT / "bench" / "results" / "bench_import.json"
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(result, indent=1))
    print(f"wrote {out_json.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
