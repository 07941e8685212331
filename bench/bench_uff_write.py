"""`write_uff` against plain pyuff, in the same run: the same sets, the same bytes, the time.

pyuff's ``UFF.write_sets`` re-reads the whole file after every set it appends (``UFF.refresh``: the index its reader
uses), so writing n sets reads O(n^2) bytes; gvtlink's ``write_uff`` (daq/studies/uff/datasets.py) writes through
the same pyuff writer without that re-read. Sets: dataset 164 (units) and ``--frfs`` FRFs with their coherences as
datasets 58 (binary 58b and ASCII), each ``--lines`` lines, as ``gvt export`` writes a roving test's FRF matrix. Best of
``--repeats`` for each writer, alternating; the two files must be byte for byte equal.

Prints a table and writes bench/results/bench_uff_write.json.

    .venv/bin/python bench/bench_uff_write.py [--frfs 100,400] [--lines 2049] [--repeats 3]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from analysis.model.channels import Channel
from daq.studies.uff.datasets import frf_sets, units_set, write_uff

RESULTS = Path(__file__).resolve().parent / "results"


def sets(n: int, lines: int, binary: bool) -> list[dict]:
    """Units, then n FRFs with their coherences (2n datasets 58), as frf_sets writes a roving test's matrix."""
    rng = np.random.default_rng(1)
    f = np.linspace(0.0, 2048.0, lines)
    ref = Channel("hammer", "force", 1, (0.0, 0.0, 0.0), 3)
    outs = [Channel(f"a{k:03d}", "acceleration", 2 + k, (0.1 * k, 0.0, 0.0), 3) for k in range(n)]
    h = rng.normal(size=(n, 1, lines)) + 1j * rng.normal(size=(n, 1, lines))
    coh = rng.uniform(0.5, 1.0, size=(n, 1, lines))
    return [units_set(), *frf_sets(f, h, outs, [ref], coherence=coh, binary=binary)]


def timed(write, path: Path, data: list[dict]) -> float:
    t0 = time.perf_counter()
    write(path, copy.deepcopy(data))
    return time.perf_counter() - t0


def plain(path: Path, data: list[dict]) -> None:
    import pyuff

    pyuff.UFF(str(path)).write_sets(data, mode="overwrite")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frfs", default="100,400")
    ap.add_argument("--lines", type=int, default=2049)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for n in (int(x) for x in args.frfs.split(",")):
            for binary in (True, False):
                data = sets(n, args.lines, binary)
                ours, theirs = [], []
                for _ in range(args.repeats):  # alternating: the machine's drift falls on both
                    theirs.append(timed(plain, d / "plain.uff", data))
                    ours.append(timed(write_uff, d / "ours.uff", data))
                same = (d / "plain.uff").read_bytes() == (d / "ours.uff").read_bytes()
                rows.append({"frfs": n, "lines": args.lines, "format": "58b" if binary else "58", "bytes":
                             (d / "ours.uff").stat().st_size, "pyuff_s": min(theirs), "write_uff_s": min(ours),
                             "speedup": min(theirs) / min(ours), "same_bytes": same})  # fmt: skip
    print(f"{'FRFs':>5} {'fmt':>4} {'MB':>7} {'pyuff s':>9} {'write_uff s':>12} {'x':>6}  same bytes")
    for r in rows:
        print(f"{r['frfs']:>5} {r['format']:>4} {r['bytes'] / 1e6:>7.1f} {r['pyuff_s']:>9.2f} {r['write_uff_s']:>12.2f} "
              f"{r['speedup']:>6.1f}  {r['same_bytes']}")  # fmt: skip
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bench_uff_write.json").write_text(json.dumps({"rows": rows}, indent=1))
    if not all(r["same_bytes"] for r in rows):
        print("write_uff wrote different bytes from plain pyuff", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
