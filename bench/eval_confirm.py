"""Issue 7 evaluation: WBEMD + slow-flow confirmation of the detection stage's events on beam_ch4_exp hits.

For every nonlinear case of issue 6's grid (analysis/evaluation/grid.py: 24 hits, 400–2000 N x
ζ 0.002–0.015, 1 % noise, acceleration path), gvtlink's near-live detector gives its IR events; each
event labelled 3:1 or 5:2 is confirmed on its stretch of noisy accelerations exactly as the background
lane does it (``ConfirmContext.span_s``: event start − 0.5 s … end + 0.5 s). Scored against the simulator's
truth (major exchanges of mode 2, issue 6's definition):

* precision — of the events confirmed with their own label, the fraction that match a truth exchange
  with that ratio (overlap with one window of lag, one-to-one);
* recall — of the truth exchanges labelled 3:1 or 5:2, the fraction matched by an event confirmed with
  that ratio (and, separately, of those the detector found with that label).

Linear rig: the detector flags nothing there, so to test the confirmation itself each nonlinear case's
events are replayed on its linear twin (same force, damping, noise; cubic term zero) — nothing may be
confirmed. Prints tables, writes bench/results/eval_confirm.json.

    python bench/eval_confirm.py [--workers 2] [--ratios 3:1,5:2] [--before]

``--before``: the confirmation path before issue 21 (bench/results/eval_confirm_before.json), to score both paths
on the same events.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import argparse
import json
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import scipy.linalg

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from analysis.confirm import ConfirmContext, ConfirmSettings, confirm_segment  # noqa: E402
from analysis.evaluation.detectors import WINDOW_S, modal_exchange_acc  # noqa: E402
from analysis.evaluation.grid import case_rig, default_grid, simulate_cases  # noqa: E402
from analysis.evaluation.score import match_case  # noqa: E402


def _context(case, settings: ConfirmSettings | None = None) -> ConfirmContext:
    rig = case_rig(case.case)
    g = rig.guyan([s.dof for s in rig.sensors])
    _w, phi = scipy.linalg.eigh(g.K, g.M)
    return ConfirmContext(sensors=tuple(case.sensor_names), shapes=phi, settings=settings or ConfirmSettings())


def _confirm_all(case, events: list[dict], ctx: ConfirmContext) -> list[dict]:
    fs, out = case.fs, []
    for ev in events:
        lo, hi = ctx.span_s(ev)
        a, b = int(np.floor(lo * fs)), min(case.acc.shape[0], int(np.ceil(hi * fs)))
        try:
            out.append(confirm_segment(case.acc[a:b], fs, a / fs, ev, ctx))
        except Exception as exc:  # counted and shown, never hidden
            out.append({"event_id": ev["id"], "event": ev, "status": "error", "reason": f"{type(exc).__name__}: {exc}"})
    return out


def _one(pair_index: int, ratios: tuple[str, ...], before: bool = False) -> dict:
    grid = default_grid()
    nl = [c for c in grid if c.cubic][pair_index]
    lin = next(c for c in grid if not c.cubic and c.force_n == nl.force_n and c.zeta == nl.zeta)
    case_nl, case_lin = simulate_cases([nl, lin])
    raw = modal_exchange_acc(case_nl)
    events = [{"id": i, **e.as_dict()} for i, e in enumerate(raw)]
    picked = [e for e in events if e["ratio"] in ratios]
    t0 = time.perf_counter()
    settings = ConfirmSettings(fast=not before)
    conf_nl = _confirm_all(case_nl, picked, _context(case_nl, settings))
    conf_lin = _confirm_all(case_lin, picked, _context(case_lin, settings))
    truths = [tr for tr in case_nl.exchanges]
    return {
        "case": nl.name, "force_n": nl.force_n, "zeta": nl.zeta, "events": events, "picked": [e["id"] for e in picked],
        "confirm_nl": conf_nl, "confirm_lin": conf_lin, "seconds": time.perf_counter() - t0,
        "truths": [{"start_s": t.start_s, "end_s": t.end_s, "ratio": f"{t.ratio_m}:{t.ratio_n}"} for t in truths],
    }  # fmt: skip


def score(rows: list[dict], ratios: tuple[str, ...]) -> dict:
    tp = fp = 0
    truth_total = truth_detected = truth_confirmed = 0
    statuses: dict[str, int] = {}
    lin_confirmed = 0
    for r in rows:
        for c in r["confirm_nl"]:
            statuses[c["status"]] = statuses.get(c["status"], 0) + 1
        lin_confirmed += sum(c["status"] == "confirmed" for c in r["confirm_lin"])
        truths = [t for t in r["truths"] if t["ratio"] in ratios]
        truth_total += len(truths)
        ev_by_id = {e["id"]: e for e in r["events"]}
        # detected with the right label (the confirmation's denominator)
        labelled = [e for e in r["events"] if e["ratio"] in ratios]
        pairs = match_case([SimpleNamespace(**e) for e in labelled], [SimpleNamespace(**t) for t in truths], WINDOW_S)
        truth_detected += sum(labelled[i]["ratio"] == truths[j]["ratio"] for i, j in pairs)
        conf = [c for c in r["confirm_nl"] if c["status"] == "confirmed" and c.get("ratio") == ev_by_id[c["event_id"]]["ratio"]]
        cev = [ev_by_id[c["event_id"]] for c in conf]
        pairs = match_case([SimpleNamespace(**e) for e in cev], [SimpleNamespace(**t) for t in truths], WINDOW_S)
        good = sum(cev[i]["ratio"] == truths[j]["ratio"] for i, j in pairs)
        tp += good
        fp += len(cev) - good
        truth_confirmed += good
    return {
        "confirmed_with_label": tp + fp, "precision": tp / (tp + fp) if tp + fp else float("nan"),
        "recall_vs_truth": truth_confirmed / truth_total if truth_total else float("nan"),
        "recall_vs_detected": truth_confirmed / truth_detected if truth_detected else float("nan"),
        "truth_exchanges": truth_total, "detected_with_label": truth_detected, "statuses": statuses,
        "linear_confirmed": lin_confirmed,
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ratios", default="3:1,5:2")
    ap.add_argument("--limit", type=int, default=None, help="only the first N nonlinear cases (smoke runs)")
    ap.add_argument("--before", action="store_true", help="the confirmation path before issue 21 (ConfirmSettings(fast=False))")
    args = ap.parse_args()
    ratios = tuple(args.ratios.split(","))
    n_cases = sum(c.cubic for c in default_grid())
    idx = list(range(n_cases if args.limit is None else min(args.limit, n_cases)))
    simulate_cases(default_grid())  # fill the cache once, in this process
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        rows = list(pool.map(_one, idx, [ratios] * len(idx), [args.before] * len(idx)))
    wall = time.perf_counter() - t0
    s = score(rows, ratios)
    print(f"{'case':<22} {'events':>6} {'picked':>6} {'confirmed':>9} {'as label':>8} {'truth':>5} {'lin conf':>8} {'s':>6}")
    for r in rows:
        ev_by_id = {e["id"]: e for e in r["events"]}
        conf = [c for c in r["confirm_nl"] if c["status"] == "confirmed"]
        same = [c for c in conf if c.get("ratio") == ev_by_id[c["event_id"]]["ratio"]]
        n_truth = sum(t["ratio"] in ratios for t in r["truths"])
        n_lin = sum(c["status"] == "confirmed" for c in r["confirm_lin"])
        print(f"{r['case']:<22} {len(r['events']):6d} {len(r['picked']):6d} {len(conf):9d} {len(same):8d} "
              f"{n_truth:5d} {n_lin:8d} {r['seconds']:6.1f}")  # fmt: skip
    print(f"\nratios {', '.join(ratios)}: precision {s['precision']:.2f}, recall {s['recall_vs_truth']:.2f} of "
          f"{s['truth_exchanges']} truth exchanges ({s['recall_vs_detected']:.2f} of the {s['detected_with_label']} the detector "
          f"labelled right); statuses {s['statuses']}; confirmed on the linear twins: {s['linear_confirmed']}; "
          f"wall {wall:.0f} s")  # fmt: skip
    el = [c["elapsed_s"] for r in rows for c in r["confirm_nl"] + r["confirm_lin"] if c.get("elapsed_s") is not None]
    print(f"CPU per confirmation (elapsed_s): median {np.median(el):.2f} s, p90 {np.percentile(el, 90):.2f} s, "
          f"max {max(el):.2f} s ({'before issue 21' if args.before else 'now'})")  # fmt: skip
    out = ROOT / "bench" / "results" / ("eval_confirm_before.json" if args.before else "eval_confirm.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    slim = [{k: v for k, v in r.items() if k not in ("confirm_nl", "confirm_lin")} | {
        "confirm_nl": [{k: v for k, v in c.items() if k != "trajectory"} for c in r["confirm_nl"]],
        "confirm_lin": [{k: v for k, v in c.items() if k != "trajectory"} for c in r["confirm_lin"]]} for r in rows]  # fmt: skip
    meta = {"ratios": ratios, "workers": args.workers, "wall_s": wall, "python": platform.python_version(),
            "loadavg": os.getloadavg(), "path": "before" if args.before else "now"}  # fmt: skip
    out.write_text(json.dumps({"meta": meta, "score": s, "cases": slim}, indent=1, default=float))
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
