"""`gvt import` readers' throughput (issue 31, "Speed": import >= 50 M samples/s for CSV-free formats).

Writes a TDMS file (npTDMS ``TdmsWriter``, one group, ``wf_increment``, float32 in g) and a SEP005 HDF5 file
(h5py, one group per channel, float32 in g) of CH channels x N samples, then times, best of REPEATS, warm page
cache, pint's registry already built (it loads once a process, ~1 s, and is not per-sample work):

* the raw read a user would write: npTDMS ``TdmsFile.read`` + every channel's array; h5py every ``data`` dataset;
* gvtlink's reader (``daq/studies/importing/{tdms,hdf5}.py``): that read, the file's SHA-256, the unit factor
  and the (n, ch) float64 table in SI units;
* the CSV reader on ``gvt log export``'s layout (fewer rows: text is ~20 x slower to parse, and the issue's goal
  is for the binary formats), beside ``np.loadtxt`` of the same file; and its peak memory (RSS) in a fresh
  process on a larger CSV against the file's size ("a 1 GB CSV must not need 10 GB": rows are streamed).

Prints a table and writes bench/results/bench_import_formats.json.

    .venv/bin/python bench/bench_import_formats.py [--channels 16] [--samples 2000000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from daq.studies.importing import csv, hdf5, tdms

RESULTS = Path(__file__).resolve().parent / "results"
GOAL = 50e6  # samples/s


def best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def write_tdms(path: Path, data: np.ndarray, fs: float) -> None:
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    props = {"wf_increment": 1 / fs, "unit_string": "g"}
    with TdmsWriter(path) as w:
        chans = [ChannelObject("g", f"a{k:02d}", d, properties=props) for k, d in enumerate(data)]
        w.write_segment([RootObject(), GroupObject("g"), *chans])


def write_h5(path: Path, data: np.ndarray, fs: float) -> None:
    import h5py

    with h5py.File(path, "w", track_order=True) as f:
        for k, d in enumerate(data):
            g = f.create_group(f"a{k:02d}")
            g["data"] = d
            g.attrs.update(unit_str="g", fs=fs)


def raw_tdms(path: Path) -> None:
    from nptdms import TdmsFile

    f = TdmsFile.read(path)
    [c[:] for g in f.groups() for c in g.channels()]


def raw_h5(path: Path) -> None:
    import h5py

    with h5py.File(path, "r") as f:
        [f[k]["data"][...] for k in f]


def write_csv(path: Path, data: np.ndarray, fs: float) -> None:
    n = data.shape[1]
    head = ",".join(["t [s] since 1970-01-01T00:00:00.000000000Z", "index", *(f"a{k:02d} [m/s^2]" for k in range(len(data)))])
    table = np.column_stack([np.arange(n) / fs, np.arange(n), data.T.astype(np.float64)])
    np.savetxt(path, table, fmt=["%.9f", "%d", *["%.9g"] * len(data)], delimiter=",", header=head, comments="")


_RSS = """import re, sys
from pathlib import Path
from daq.studies.importing import csv
def hwm():  # the process' peak RSS: /proc's VmHWM starts afresh at exec (ru_maxrss keeps the parent's peak)
    return int(re.search(r"VmHWM:\\s+(\\d+) kB", Path("/proc/self/status").read_text()).group(1)) * 1024
base = hwm()
x = csv.read(Path(sys.argv[1]))
print(base, hwm(), x.samples.nbytes)"""


def csv_memory(path: Path) -> dict:
    """Peak RSS of ``csv.read(path)`` in a fresh process, over the process' RSS before the read (bytes)."""
    base, peak, table = map(int, subprocess.run([sys.executable, "-c", _RSS, str(path)], check=True, capture_output=True,
                                                text=True, cwd=Path(__file__).resolve().parents[1]).stdout.split())  # fmt: skip
    size = path.stat().st_size
    return {"csv_bytes": size, "table_bytes": table, "peak_rss_over_base": peak - base, "ratio_to_file": (peak - base) / size}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channels", type=int, default=16)
    ap.add_argument("--samples", type=int, default=2_000_000)
    ap.add_argument("--csv-samples", type=int, default=100_000)
    ap.add_argument("--csv-memory-samples", type=int, default=500_000, help="rows of the CSV whose peak memory is measured")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dir", default=None)
    args = ap.parse_args()
    fs = 51200.0
    data = np.random.default_rng(0).standard_normal((args.channels, args.samples)).astype(np.float32)
    total = data.size
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir) as d:
        d = Path(d)
        td, h5, cv = d / "x.tdms", d / "x.h5", d / "x.csv"
        write_tdms(td, data, fs)
        write_h5(h5, data, fs)
        write_csv(cv, data[:, : args.csv_samples], fs)
        tdms.read(td)  # builds pint's registry once
        n_csv = args.channels * args.csv_samples
        cases = [
            ("tdms", "npTDMS TdmsFile.read + arrays", lambda: raw_tdms(td), total, td),
            ("tdms", "gvtlink tdms.read", lambda: tdms.read(td), total, td),
            ("hdf5-sep005", "h5py read of every data", lambda: raw_h5(h5), total, h5),
            ("hdf5-sep005", "gvtlink hdf5.read", lambda: hdf5.read(h5), total, h5),
            ("csv", "np.loadtxt (whole file)", lambda: np.loadtxt(cv, delimiter=",", skiprows=1), n_csv, cv),
            ("csv", "gvtlink csv.read (gvt log export)", lambda: csv.read(cv), n_csv, cv),
        ]  # fmt: skip
        for fmt, what, fn, n, path in cases:
            t = best(fn, args.repeats)
            rows.append({"format": fmt, "reader": what, "samples": n, "bytes": path.stat().st_size, "seconds": t,
                         "msamples_per_s": n / t / 1e6})  # fmt: skip
        big = d / "big.csv"
        write_csv(big, data[:, : args.csv_memory_samples], fs)
        mem = csv_memory(big)
    print(f"{'format':<12} {'reader':<36} {'samples':>11} {'MB':>7} {'s':>7} {'M samples/s':>12}")
    for r in rows:
        print(f"{r['format']:<12} {r['reader']:<36} {r['samples']:>11} {r['bytes'] / 1e6:>7.1f} {r['seconds']:>7.3f} "
              f"{r['msamples_per_s']:>12.1f}")  # fmt: skip
    ours = {r["format"]: r["msamples_per_s"] for r in rows if r["reader"].startswith("gvtlink")}
    for fmt in ("tdms", "hdf5-sep005"):
        print(f"{fmt}: {ours[fmt]:.1f} M samples/s, goal {GOAL / 1e6:.0f}: {'met' if ours[fmt] * 1e6 >= GOAL else 'NOT met'}")
    print(f"csv memory: {mem['csv_bytes'] / 1e6:.0f} MB CSV -> {mem['table_bytes'] / 1e6:.0f} MB table, peak RSS "
          f"+{mem['peak_rss_over_base'] / 1e6:.0f} MB ({mem['ratio_to_file']:.2f} x the file)")  # fmt: skip
    RESULTS.mkdir(exist_ok=True)
    out = {"channels": args.channels, "samples_per_channel": args.samples, "fs": fs, "goal_samples_per_s": GOAL, "rows": rows,
           "csv_memory": mem}  # fmt: skip
    (RESULTS / "bench_import_formats.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
