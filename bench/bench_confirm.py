"""Issue 21, item 6: one event's confirmation (WBEMD + slow flow), today's path against the one before, same run.

The events are bench/eval_confirm.py's: gvtlink's detector on issue 6's 24 nonlinear beam_ch4_exp hits
(1 % noise, acceleration path), every event labelled 3:1 or 5:2, each cut exactly as the lane cuts it
(``ConfirmContext.span_s``). Every event is confirmed twice in one process, one core, alternating the order
so that load drifts fall on both paths alike:

* ``before``: ``ConfirmSettings(fast=False)`` — the full-CWT peak pick and the zoom MWT of the bound test,
  the code path before issue 21;
* ``now``: ``ConfirmSettings()`` — banded MWTs (analysis/wbemd.py ``_BandedMwt``).

Reported: CPU seconds per confirmation (process time, so other jobs on the machine do not count) and wall
seconds, median / p90 / max; how many events got a different status or ratio. Prints a table, writes
bench/results/bench_confirm.json.

The session check (``--sessions`` / ``--sessions-only``): 30 s ``gvt record`` sessions (paced serial device, real
time) on both paths, with 0 and 2 CPU hogs alongside (``--load``), counting the lane's ``skipped`` records. ~5 min.

    python bench/bench_confirm.py [--limit N] [--workers 2] [--sessions | --sessions-only] [--load 0 2]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import argparse
import dataclasses
import json
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from analysis.confirm import ConfirmSettings, confirm_segment  # noqa: E402
from analysis.evaluation.detectors import modal_exchange_acc  # noqa: E402
from analysis.evaluation.grid import default_grid, simulate_cases  # noqa: E402
from bench.eval_confirm import _context  # noqa: E402

PATHS = {"before": ConfirmSettings(fast=False), "now": ConfirmSettings()}


def _timed(seg, fs, t0, ev, ctx) -> tuple[dict, float, float]:
    c0, w0 = time.process_time(), time.perf_counter()
    rec = confirm_segment(seg, fs, t0, ev, ctx)
    return rec, time.process_time() - c0, time.perf_counter() - w0


def _case(index: int, ratios: tuple[str, ...]) -> list[dict]:
    nl = [c for c in default_grid() if c.cubic][index]
    (case,) = simulate_cases([nl])
    events = [{"id": i, **e.as_dict()} for i, e in enumerate(modal_exchange_acc(case))]
    base = _context(case)
    rows = []
    for k, ev in enumerate(e for e in events if e["ratio"] in ratios):
        lo, hi = base.span_s(ev)
        a, b = int(np.floor(lo * case.fs)), min(case.acc.shape[0], int(np.ceil(hi * case.fs)))
        row: dict = {"case": nl.name, "event": ev["id"], "ratio": ev["ratio"], "segment_s": (b - a) / case.fs}
        order = ("before", "now") if k % 2 == 0 else ("now", "before")
        for name in order:
            rec, cpu, wall = _timed(case.acc[a:b], case.fs, a / case.fs, ev, dataclasses.replace(base, settings=PATHS[name]))
            row[name] = {"status": rec["status"], "ratio": rec.get("ratio"), "cpu_s": cpu, "wall_s": wall,
                         "imf_freqs_hz": rec.get("imf_freqs_hz")}  # fmt: skip
        rows.append(row)
    return rows


def _stats(v: list[float]) -> dict:
    a = np.asarray(v)
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "max": float(a.max()), "n": int(a.size)}


SESSIONS = {
    # the repo's 20-hit serial session (hits every 0.5 s for 10 s, overloads, double hits), run for 30 s
    "sim_serial_20hits": ROOT / "configs" / "sessions" / "sim_serial_20hits.toml",
    # issue 21's "hits every 2–4 s": ten 800–1800 N hits, one every 3 s, 30 s, same device and trigger
    "hits_every_3s": {
        "name": "confirm-30s", "rig": "beam_ch4_exp", "output": "confirm-30s.mcap", "duration": 30.0,
        "device": {"name": "dev0", "driver": "serial", "simulate": {
            "forces": [800, 1200, 1600, 1000, 1400, 1800, 900, 1300, 1700, 1100], "period": 3.0, "seed": 7}},
        "trigger": {"channel": "hammer", "level": 20.0, "pre_trigger": 0.01, "record_length": 0.3,
                    "force_range": [100.0, 2000.0], "driving_point": "a13"},
    },
}  # fmt: skip


def _burn() -> None:  # a CPU hog standing in for other work on the machine (--load)
    while True:
        pass


def _session(name: str, path: str, out_dir: Path) -> dict:
    """One 30 s ``gvt record`` session (paced, real time) with the confirmation lane on ``path``'s settings."""
    import functools

    import daq.lanes.confirm as lane_mod
    from analysis.model.loader import parse_toml, validate
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import run_session

    src = SESSIONS[name]
    data = parse_toml(src) if isinstance(src, Path) else json.loads(json.dumps(src))
    data["duration"] = 30.0
    cfg = validate(SessionConfig, data, str(src) if isinstance(src, Path) else name)
    original = lane_mod.start_confirm_lane
    lane_mod.start_confirm_lane = functools.partial(original, confirm_settings=PATHS[path])
    try:
        t0 = time.perf_counter()
        res = run_session(cfg, open_rig(cfg.rig), out_dir / f"{name}_{path}.mcap", overwrite=True)
        wall = time.perf_counter() - t0
    finally:
        lane_mod.start_confirm_lane = original
    recs = res.confirmations
    statuses: dict[str, int] = {}
    for r in recs:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    el = [float(r["elapsed_s"]) for r in recs if r.get("elapsed_s") is not None]
    return {"session": name, "path": path, "events": len(res.analysis_events), "records": len(recs), "statuses": statuses,
            "skipped": statuses.get("skipped", 0), "elapsed_s": _stats(el) if el else None, "wall_s": wall,
            "skip_reasons": sorted({r["reason"] for r in recs if r["status"] == "skipped"})}  # fmt: skip


def sessions(load: int) -> list[dict]:
    """Each session of :data:`SESSIONS` on both paths, with ``load`` CPU hogs running alongside."""
    import multiprocessing
    import tempfile

    hogs = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(load)]
    for h in hogs:
        h.start()
    try:
        with tempfile.TemporaryDirectory() as d:
            rows = [_session(name, path, Path(d)) | {"load_hogs": load} for name in SESSIONS for path in PATHS]
    finally:
        for h in hogs:
            h.terminate()
            h.join()
    print(f"\n30 s sessions (gvt record, paced serial device), {load} CPU hogs alongside:")
    print(
        f"{'session':<18} {'path':<7} {'events':>6} {'skipped':>7} {'confirmed':>9} {'median s':>8} {'p90':>6} {'max':>6} "
        f"{'wall s':>6}"
    )
    for r in rows:
        e = r["elapsed_s"] or {"median": float("nan"), "p90": float("nan"), "max": float("nan")}
        print(f"{r['session']:<18} {r['path']:<7} {r['events']:6d} {r['skipped']:7d} {r['statuses'].get('confirmed', 0):9d} "
              f"{e['median']:8.2f} {e['p90']:6.2f} {e['max']:6.2f} {r['wall_s']:6.1f}")  # fmt: skip
        for why in r["skip_reasons"]:
            print(f"    skipped: {why}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2, help="processes, one case each (each times both paths itself)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N nonlinear cases (smoke runs)")
    ap.add_argument("--ratios", default="3:1,5:2")
    ap.add_argument("--sessions", action="store_true", help="also the 30 s sessions (issue 21: no event skipped), both paths")
    ap.add_argument("--sessions-only", action="store_true", help="only the 30 s sessions")
    ap.add_argument("--load", type=int, nargs="*", default=[0, 2], help="CPU hogs alongside the sessions (one run per value)")
    args = ap.parse_args()
    out = ROOT / "bench" / "results" / "bench_confirm.json"
    if args.sessions_only:
        rows = [r for n in args.load for r in sessions(n)]
        old = json.loads(out.read_text()) if out.exists() else {}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(old | {"sessions": rows}, indent=1))
        print(f"wrote {out.relative_to(ROOT)}")
        return
    ratios = tuple(args.ratios.split(","))
    n_cases = sum(c.cubic for c in default_grid())
    idx = list(range(n_cases if args.limit is None else min(args.limit, n_cases)))
    simulate_cases([c for c in default_grid() if c.cubic])  # fill the cache once, in this process
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        rows = [r for part in pool.map(_case, idx, [ratios] * len(idx)) for r in part]
    wall = time.perf_counter() - t0
    summary = {name: {"cpu_s": _stats([r[name]["cpu_s"] for r in rows]), "wall_s": _stats([r[name]["wall_s"] for r in rows]),
                      "confirmed": sum(r[name]["status"] == "confirmed" for r in rows)} for name in PATHS}  # fmt: skip
    differ = [r for r in rows if (r["before"]["status"], r["before"]["ratio"]) != (r["now"]["status"], r["now"]["ratio"])]
    speedup = [r["before"]["cpu_s"] / r["now"]["cpu_s"] for r in rows]
    print(f"{len(rows)} events (labelled {', '.join(ratios)}) of {len(idx)} cases; {args.workers} workers; "
          f"load {load0[0]:.1f} → {os.getloadavg()[0]:.1f}; wall {wall:.0f} s")  # fmt: skip
    print(f"{'path':<8} {'CPU median':>10} {'p90':>6} {'max':>6} {'wall median':>11} {'p90':>6} {'max':>6} {'confirmed':>9}")
    for name in PATHS:
        c, w = summary[name]["cpu_s"], summary[name]["wall_s"]
        print(f"{name:<8} {c['median']:10.3f} {c['p90']:6.3f} {c['max']:6.3f} {w['median']:11.3f} {w['p90']:6.3f} "
              f"{w['max']:6.3f} {summary[name]['confirmed']:9d}")  # fmt: skip
    print(f"CPU speed-up per event: median ×{np.median(speedup):.2f} (min ×{min(speedup):.2f}, max ×{max(speedup):.2f}); "
          f"status or ratio differs on {len(differ)} of {len(rows)} events")  # fmt: skip
    for r in differ:
        print(f"  {r['case']} event {r['event']} ({r['ratio']}): before {r['before']['status']} {r['before']['ratio']}, "
              f"now {r['now']['status']} {r['now']['ratio']}")  # fmt: skip
    sess = [r for n in args.load for r in sessions(n)] if args.sessions else None
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"workers": args.workers, "cases": len(idx), "wall_s": wall, "loadavg_start": load0, "loadavg_end": os.getloadavg(),
            "python": platform.python_version(), "cpu_count": os.cpu_count()}  # fmt: skip
    out.write_text(json.dumps({"meta": meta, "summary": summary, "speedup_median": float(np.median(speedup)),
                               "differ": len(differ), "events": rows} | ({"sessions": sess} if sess else {}),
                              indent=1))  # fmt: skip
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
