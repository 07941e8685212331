"""Hit gate benchmark (issue 30, item 5): the hit detector against pyTrigger, and against the base commit.

The same 15 channels (hammer + the 14 accelerometers of beam_ch4_exp at 16384 Hz, a hit every 2 s at rising
force, 1 % noise: bench/bench_analysis.py's data) are fed in blocks of 256 and 8192 samples to

* gvtlink's :class:`daq.hits.HitDetector` — trigger, pre-trigger ring, hysteresis re-arm, per-hit record and the
  whole quality gate (every channel judged on every hit: :func:`daq.hits.judge_channels`);
* the same detector with the channel judgment timed apart (``judge_channels`` alone, per hit);
* pyTrigger (ladisk/pyTrigger, the reference of docs/landscape.md §2.2) as it is used for a hit sequence: one
  instance per hit, a new one armed when the last finished (it has no re-arm of its own), the same level,
  pre-trigger and record length. Skipped, with a line, when pyTrigger is not importable.

CPU ms per second of data (median of ``--repeat``), the hits found by each, and the ratio pyTrigger / gvtlink
(> 1: gvtlink is faster). ``--base REV`` (default: the commit before issue 30's speed work) measures the
detector of that commit in the same run, in a subprocess importing a ``git archive`` of it.

    python bench/bench_hits.py [--seconds 20] [--repeat 5] [--base 7531466 | --base none]

Prints a table; writes bench/results/bench_hits.json.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_analysis import BASE_DEFAULT, base_tree  # noqa: E402  (the sibling script, by path)

LEVEL, PRE_S, RECORD_S = 20.0, 0.01, 1.0


def _data(seconds: float) -> tuple[np.ndarray, tuple[str, ...], float]:
    from bench_analysis import _data as data

    return data("beam_ch4_exp", seconds)


def _cpu(fn, repeat: int) -> tuple[float, object]:
    """Median CPU seconds of ``fn()`` over ``repeat`` runs after one warm-up, and the last result."""
    res = fn()
    times = []
    for _ in range(repeat):
        c0 = time.process_time()
        res = fn()
        times.append(time.process_time() - c0)
    return statistics.median(times), res


def gvt_hits(data: np.ndarray, chans, fs: float, block: int) -> list:
    from daq.hits import HitDetector, TriggerSettings
    from drivers.blocks import SampleBlock

    det = HitDetector(TriggerSettings(level=LEVEL, channel=chans[0], pre_trigger=PRE_S, record_length=RECORD_S), chans, fs,
                      ranges={c: 4905.0 for c in chans[1:]})  # fmt: skip
    out = []
    for s in range(0, data.shape[0], block):
        out += det.feed(SampleBlock("dev0", s, fs, chans, data[s : s + block]))
    return out + det.finish()


def pytrigger_hits(data: np.ndarray, fs: float, block: int) -> list[np.ndarray]:
    """pyTrigger over a hit sequence: a new instance per hit, armed once the force fell below the level again."""
    from pyTrigger import pyTrigger

    pre, rows = round(PRE_S * fs), round(PRE_S * fs) + round(RECORD_S * fs)
    out: list[np.ndarray] = []
    trig = pyTrigger(rows=rows, channels=data.shape[1], trigger_channel=0, trigger_level=LEVEL, presamples=pre)
    wait_below = False
    for s in range(0, data.shape[0], block):
        b = data[s : s + block]
        if wait_below:  # after a record: the pulse must end before a new trigger is armed (no re-arm in pyTrigger)
            low = np.flatnonzero(b[:, 0] < LEVEL)
            if low.size == 0:
                continue
            b, wait_below = b[low[0] :], False
        if trig.add_data(b):
            out.append(trig.get_data())
            trig = pyTrigger(rows=rows, channels=data.shape[1], trigger_channel=0, trigger_level=LEVEL, presamples=pre)
            wait_below = True
    return out


def measure(seconds: float, repeat: int) -> dict:
    """This interpreter's tree: ms CPU per data-second of the detector, and of ``judge_channels`` alone."""
    from daq.hits import judge_channels

    data, chans, fs = _data(seconds)
    secs = data.shape[0] / fs
    out: dict = {}
    for block in (256, 8192):
        cpu, hits = _cpu(lambda b=block: gvt_hits(data, chans, fs, b), repeat)
        out[f"gvt_{block}"] = {"ms_per_data_s": 1e3 * cpu / secs, "hits": len(hits)}
    hits = gvt_hits(data, chans, fs, 8192)
    ranges = np.array([np.inf, *([4905.0] * (len(chans) - 1))])
    pre = round(PRE_S * fs)

    def judge_all():
        return [judge_channels(h.data, chans, ranges, 0, pre, fs) for h in hits]

    cpu, _ = _cpu(judge_all, repeat)
    out["judge_channels"] = {"ms_per_data_s": 1e3 * cpu / secs, "ms_per_hit": 1e3 * cpu / max(len(hits), 1)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--base", default=BASE_DEFAULT, help="git revision to compare with in the same run ('none': skip)")
    ap.add_argument("--measure-only", action="store_true", help=argparse.SUPPRESS)  # the base tree's subprocess
    args = ap.parse_args()
    if args.measure_only:
        print(json.dumps(measure(args.seconds, args.repeat)))
        return
    res: dict = {"benchmark": "bench_hits", "python": platform.python_version(), "machine": platform.machine(),
                 "seconds": args.seconds, "channels": 15, "this_tree": measure(args.seconds, args.repeat)}  # fmt: skip
    if args.base != "none":
        tree = base_tree(args.base)
        env = {**os.environ, "PYTHONPATH": str(tree)}
        p = subprocess.run([sys.executable, __file__, "--measure-only", "--seconds", str(args.seconds), "--repeat",
                            str(args.repeat)], env=env, cwd=tree, capture_output=True, text=True)  # fmt: skip
        if p.returncode:
            print(f"base {args.base}: not measured ({p.stderr.strip().splitlines()[-1] if p.stderr.strip() else p.returncode})")
        else:
            res["base"] = {"rev": args.base, **json.loads(p.stdout.strip().splitlines()[-1])}
    data, _chans, fs = _data(args.seconds)
    secs = data.shape[0] / fs
    try:
        import pyTrigger  # noqa: F401
    except ImportError:
        print("pyTrigger not importable (pip install pytrigger): its column is empty")
    else:
        for block in (256, 8192):
            cpu, recs = _cpu(lambda b=block: pytrigger_hits(data, fs, b), args.repeat)
            res.setdefault("pytrigger", {})[f"pt_{block}"] = {"ms_per_data_s": 1e3 * cpu / secs, "hits": len(recs)}
    res["load_avg_1_5_15"] = list(os.getloadavg())
    print(f"{'15 ch x 16384 Hz':22s} {'block':>6s} {'ms CPU/data-s':>14s} {'hits':>5s} {'pyTrigger/this':>15s}")
    for block in (256, 8192):
        pt = res.get("pytrigger", {}).get(f"pt_{block}")
        for who in ("this_tree", "base"):
            if who not in res:
                continue
            r = res[who][f"gvt_{block}"]
            ratio = f"{pt['ms_per_data_s'] / r['ms_per_data_s']:.2f}x" if pt else "-"
            name = "hit detector" + (f" @{args.base}" if who == "base" else "")
            print(f"{name:22s} {block:6d} {r['ms_per_data_s']:14.2f} {r['hits']:5d} {ratio:>15s}")
        if pt:
            print(f"{'pyTrigger':22s} {block:6d} {pt['ms_per_data_s']:14.2f} {pt['hits']:5d}")
    for who in ("this_tree", "base"):
        if who in res:
            j = res[who]["judge_channels"]
            tag = "" if who == "this_tree" else f" @{args.base}"
            print(f"judge_channels{tag}: {j['ms_per_hit']:.3f} ms a hit ({j['ms_per_data_s']:.2f} ms per data-s)")
    print(f"(load average {res['load_avg_1_5_15'][0]:.2f})")
    dest = ROOT / "bench" / "results" / "bench_hits.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(res, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
