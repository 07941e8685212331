"""What the trust checks of issue 29 cost: `gvt frf`, `gvt modal` and `gvt analyze` against the commit before.

Issue 29's speed target: the quality checks (coherence per mode, linearity across levels, stabilisation and
one-to-one pairing, hum and polarity health) cost <= 5 % of the three verbs' CPU. Each verb runs on the same
logs from this tree and from a git worktree of the base commit (default c2752af, the last commit before the
issue), alternating A/B so the machine's drift hits both alike; CPU is user + sys of the verb's process from
``os.wait4``, and the ratio new/base is taken per pair (median and range over ``--pairs``). Both trees run
with the same venv and numba cache, after one warm-up run each.

Logs: the demo's session log (``gvt demo``, the seed's rig, 20 hits at 150-1583 N) and the roving log of
``configs/sessions/sim_roving.toml``, both written once by this tree.

Note what the ratio holds: the new verbs also do more than check. `gvt frf` averages one level group, not all
hits, so it can do less work; `gvt modal` clusters poles it used to list. A ratio above 1.05 is a fail
whatever its cause; below 1 is reported as it is.

    python bench/bench_quality.py [--pairs 5] [--base c2752af] [--quick]
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

from bench_session import worktree  # a detached worktree of the base commit, kept in the temp dir

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"


def gvt_cpu(tree: Path, *args: str) -> tuple[float, float, int]:
    """(CPU s, wall s, exit code) of one ``python -m daq.cli ARGS`` from ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "daq.cli", *args], cwd=tree, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    _, status, ru = os.wait4(proc.pid, 0)
    return ru.ru_utime + ru.ru_stime, time.perf_counter() - t0, os.waitstatus_to_exitcode(status)


def make_logs(tmp: Path) -> dict[str, Path]:
    """The demo's log and the roving log, written by this tree."""
    demo, roving = tmp / "demo.mcap", tmp / "roving.mcap"
    for args in (["demo", "--out", str(demo), "--overwrite"],
                 ["record", str(ROOT / "configs" / "sessions" / "sim_roving.toml"), "--out", str(roving)]):  # fmt: skip
        *_, rc = gvt_cpu(ROOT, *args)
        if rc not in (0, 3):
            raise SystemExit(f"bench_quality: `gvt {args[0]}` exited {rc}; run it by hand to see why")
    return {"demo": demo, "roving": roving}


def cases(logs: dict[str, Path], tmp: Path) -> list[tuple[str, list[str]]]:
    out = []
    for name, log in logs.items():
        out.append((f"frf {name}", ["frf", str(log), "--out", str(tmp / f"{name}.frf.npz"), "--overwrite"]))
        out.append((f"modal {name}", ["modal", str(log), "--modes-out", str(tmp / f"{name}.modes.json"), "--overwrite"]))
    out.append(("analyze demo", ["analyze", str(logs["demo"]), "--json"]))
    return out


def compare(base: Path, pairs: int, tmp: Path, logs: dict[str, Path]) -> list[dict]:
    rows = []
    for label, args in cases(logs, tmp):
        for tree in (base, ROOT):  # warm-up: numba cache, page cache
            gvt_cpu(tree, *args)
        b_cpu, n_cpu, codes = [], [], set()
        for _ in range(pairs):
            for tree, acc in ((base, b_cpu), (ROOT, n_cpu)):
                cpu, _, rc = gvt_cpu(tree, *args)
                acc.append(cpu)
                codes.add((tree == ROOT, rc))
        ratios = [n / b for n, b in zip(n_cpu, b_cpu, strict=True)]
        rows.append({"case": label, "base_cpu_s": b_cpu, "new_cpu_s": n_cpu, "ratio_median": statistics.median(ratios),
                     "ratio_min": min(ratios), "ratio_max": max(ratios), "exit_codes": sorted(codes)})  # fmt: skip
        print(f"  {label:16s} base {statistics.median(b_cpu):6.2f} s  new {statistics.median(n_cpu):6.2f} s  "
              f"new/base {statistics.median(ratios):5.3f}", flush=True)  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--base", default="c2752af")
    ap.add_argument("--quick", action="store_true", help="2 pairs")
    args = ap.parse_args()
    pairs = 2 if args.quick else args.pairs
    base = worktree(args.base)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        logs = make_logs(tmp)
        print(f"trust checks: this tree against {args.base}, {pairs} alternating pairs, CPU user + sys", flush=True)
        rows = compare(base, pairs, tmp, logs)
    print()
    print(f"{'verb and log':18s} {'base CPU s':>10s} {'new CPU s':>10s} {'new/base':>9s} {'range':>13s}  target <= 1.05")
    for r in rows:
        print(f"{r['case']:18s} {statistics.median(r['base_cpu_s']):10.2f} {statistics.median(r['new_cpu_s']):10.2f} "
              f"{r['ratio_median']:9.3f} {r['ratio_min']:6.3f}-{r['ratio_max']:.3f}  "
              f"{'ok' if r['ratio_median'] <= 1.05 else 'OVER'}")  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "bench_quality.json"
    out.write_text(json.dumps({"base": args.base, "pairs": pairs, "rows": rows}, indent=1))
    print(f"\nwrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
