"""Issue 21, item 4: calibrate the exchange detector's confidence on the realistic grid, and measure its reliability.

Every event gvtlink's detector reports on every class of ``bench/eval_realistic.py`` (nonlinear cases and their
linear twins, the acceleration path, the model each class hands the detector) is collected with its evidence
scores (gain, lock, exchange) and two outcomes from §4's one-to-one matching (``analysis.evaluation.score.
match_case``): its interval matches a true major exchange, and it does so with the truth's m:n. Two logistic maps
with non-negative slopes (``analysis.exchange.Calibration``) are fitted by maximum likelihood (L2 1e-2 on the
slopes) on the **fit half** of the cases — ``crc32(case name)`` even: the same physical hit lands in the same half
in every class, so a hit's events in 27 error classes do not leak from fit to test; a split by seed parity would
be a split by force (the grid enumerates 6 forces per damping), and put every false event on one side. The
reliability tables are measured on the **held-out half** only.

It prints the fitted coefficients (to be pasted into ``analysis/exchange.py``: INTERVAL_CALIBRATION,
LABEL_CALIBRATION), the reliability tables for the coefficients in the code, the precision and recall at each
``min_confidence`` level, and the detector's pooled scores over the grid (for ``daq/detector_scores.py``); JSON
with the held-out events (raw scores and outcomes: tests/test_confidence.py replays them) to
``bench/results/calibrate_confidence.json``. The detector runs with ``min_confidence = 0`` here (every event).

    python bench/calibrate_confidence.py [--only SUBSTRING ...] [--json PATH]
"""

from __future__ import annotations

import argparse
import datetime
import functools
import itertools
import json
import subprocess
import sys
import time
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "bench"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from eval_realistic import class_data, classes, model_for  # noqa: E402
from rich.console import Console  # noqa: E402

import analysis.evaluation.detectors as detectors  # noqa: E402
from analysis.evaluation.grid import DEFAULT_CACHE_DIR  # noqa: E402
from analysis.evaluation.score import markdown_table, match_case  # noqa: E402
from analysis.evaluation.truth import DEFAULT_WINDOW_S  # noqa: E402
from analysis.exchange import INTERVAL_CALIBRATION, LABEL_CALIBRATION, Calibration, ExchangeSettings, evidence  # noqa: E402

RESULTS = ROOT / "bench" / "results"
FIXTURE = ROOT / "tests" / "data" / "confidence_held_out.json"  # what tests/test_confidence.py replays
KEYS = ("gain", "lock", "exchange")
BINS = (0.0, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0 + 1e-9)
LEVELS = (0.0, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9)


def fit_half(case_name: str) -> bool:
    """The case is in the fit half (else held out): crc32 of its name, which every error class shares."""
    return zlib.crc32(case_name.encode()) % 2 == 0


def collect(only: Sequence[str] = ()) -> tuple[list[dict], list[dict]]:
    """(events, cases): every event with its scores and outcomes; every case with its truths and matches."""
    # every event, whatever its confidence: the detectors build ExchangeSettings(window_s=...) with the default
    # min_confidence, which this bench is choosing
    detectors.ExchangeSettings = functools.partial(ExchangeSettings, min_confidence=0.0)
    events, cases = [], []
    console = Console()
    for c in classes():
        if only and not any(s in c.name for s in only):
            continue
        t0 = time.perf_counter()
        for d in (c.measured(d) for d in class_data(c, DEFAULT_CACHE_DIR)):
            ev = list(detectors.modal_exchange_acc(d, model_rig=model_for(c, d)))
            tr = list(d.exchanges)
            pairs = dict(match_case(ev, tr, DEFAULT_WINDOW_S))
            half = "fit" if fit_half(d.case.name) else "held-out"
            cases.append({"class": c.name, "case": d.case.name, "half": half, "cubic": bool(d.case.cubic),
                          "hits": len(d.hit_times_s), "truths": len(tr)})  # fmt: skip
            for i, e in enumerate(ev):
                j = pairs.get(i)
                events.append({
                    "class": c.name, "case": d.case.name, "half": half, "cubic": bool(d.case.cubic),
                    "start_s": float(e.start_s), "end_s": float(e.end_s), "ratio": f"{e.m}:{e.n}",
                    "f_ratio": float(e.f_recv_hz / e.f_give_hz) if e.f_give_hz > 0 else None, "gain": float(e.gain),
                    "scores": {k: float(e.scores[k]) for k in KEYS}, "matched": j is not None,
                    "label_right": j is not None and (e.m, e.n) == (tr[j].ratio_m, tr[j].ratio_n),
                    "truth_ratio": None if j is None else tr[j].label,
                })  # fmt: skip
        console.print(f"{c.name}: {len(events)} events so far ({time.perf_counter() - t0:.1f} s)")
    return events, cases


def fit_logistic(X: np.ndarray, y: np.ndarray, lam: float = 1e-2) -> Calibration:
    """Maximum likelihood logistic regression, slopes >= 0 (monotone), L2 ``lam`` on the slopes only."""

    def loss(b: np.ndarray) -> tuple[float, np.ndarray]:
        z = b[0] + X @ b[1:]
        p = 0.5 * (1 + np.tanh(0.5 * z))
        eps = 1e-12
        ll = -np.sum(y * np.log(p + eps) + (1 - y) * np.log(1 - p + eps)) + lam * np.sum(b[1:] ** 2)
        g = p - y
        return float(ll), np.concatenate([[g.sum()], X.T @ g + 2 * lam * b[1:]])

    bounds = [(None, None)] + [(0.0, None)] * X.shape[1]
    res = minimize(loss, np.zeros(X.shape[1] + 1), jac=True, method="L-BFGS-B", bounds=bounds)
    b = np.round(res.x, 3)
    return Calibration(float(b[0]), tuple(float(max(v, 0.0)) for v in b[1:]), KEYS)


def reliability(p: np.ndarray, y: np.ndarray) -> list[dict]:
    """Per confidence bin: events, mean confidence, fraction right."""
    out = []
    for lo, hi in itertools.pairwise(BINS):
        s = (p >= lo) & (p < hi)
        if s.any():
            out.append({"bin": [lo, min(hi, 1.0)], "n": int(s.sum()), "mean_confidence": float(p[s].mean()),
                        "right": float(y[s].mean()), "n_right": int(y[s].sum())})  # fmt: skip
    return out


def levels(p: np.ndarray, y: np.ndarray, lab: np.ndarray, n_truth: int) -> list[dict]:
    """At each ``min_confidence``: events kept, precision, recall (against every held-out truth), label accuracy."""
    out = []
    for c in LEVELS:
        k = p >= c
        tp = int(y[k].sum())
        out.append({"min_confidence": c, "events": int(k.sum()), "tp": tp, "precision": tp / max(int(k.sum()), 1),
                    "recall": tp / max(n_truth, 1), "label_accuracy": float(lab[k].sum()) / max(tp, 1)})  # fmt: skip
    return out


def _commit() -> str:
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "analysis"], capture_output=True, text=True)
        return out.stdout.strip() + ("+" if dirty.stdout.strip() else "")
    except OSError:
        return "unknown"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", action="append", default=[], help="classes whose name contains this (repeatable)")
    ap.add_argument("--json", type=Path, default=RESULTS / "calibrate_confidence.json")
    args = ap.parse_args(argv)
    console = Console(width=max(Console().width, 160))
    t0 = time.perf_counter()
    events, cases = collect(args.only)
    X = np.array([[e["scores"][k] for k in KEYS] for e in events], float).reshape(-1, len(KEYS))
    y = np.array([e["matched"] for e in events], float)
    lab = np.array([e["label_right"] for e in events], float)
    fit = np.array([e["half"] == "fit" for e in events])
    fitted = {"interval": fit_logistic(X[fit], y[fit]), "label": fit_logistic(X[fit], lab[fit])}
    code = {"interval": INTERVAL_CALIBRATION, "label": LABEL_CALIBRATION}
    for name, cal in fitted.items():
        console.print(f"fitted {name}: Calibration({cal.intercept}, {cal.coef})  (in the code: "
                      f"Calibration({code[name].intercept}, {code[name].coef}))")  # fmt: skip
    held = ~fit
    n_truth_held = sum(c["truths"] for c in cases if c["half"] == "held-out")
    p_int = np.array([INTERVAL_CALIBRATION(e["scores"]) for e in events])
    p_lab = np.array([LABEL_CALIBRATION(e["scores"]) for e in events])
    old = np.array([evidence({**e["scores"], "rq": 0.0}, ExchangeSettings().weights) for e in events])
    tables = {
        "interval": reliability(p_int[held], y[held]),
        "label": reliability(p_lab[held], lab[held]),
        "old_weighted_mean_interval": reliability(old[held], y[held]),
    }
    lv = levels(p_int[held], y[held], lab[held], n_truth_held)
    for name, t in tables.items():
        console.print(f"\nheld-out reliability, {name}:")
        console.print(markdown_table(("confidence", "events", "mean confidence", "right"),
                                     [(f"{r['bin'][0]:.2f}–{r['bin'][1]:.2f}", str(r["n"]), f"{r['mean_confidence']:.3f}",
                                       f"{r['right']:.3f} ({r['n_right']}/{r['n']})") for r in t]))  # fmt: skip
    console.print("\nheld-out, by min_confidence (recall against every held-out truth):")
    console.print(markdown_table(("min_confidence", "events", "TP", "precision", "recall", "label acc."),
                                 [(f"{r['min_confidence']:.1f}", str(r["events"]), str(r["tp"]), f"{r['precision']:.3f}",
                                   f"{r['recall']:.3f}", f"{r['label_accuracy']:.3f}") for r in lv]))  # fmt: skip
    # pooled over the whole grid, at the default min_confidence (what a session reports)
    keep = p_int >= ExchangeSettings().min_confidence
    tp = int(y[keep].sum())
    n_ev = int(keep.sum())
    n_truth = sum(c["truths"] for c in cases if c["cubic"])
    lin_hits = sum(c["hits"] for c in cases if not c["cubic"])
    lin_ev = int(sum(1 for e, k in zip(events, keep, strict=True) if k and not e["cubic"]))
    pooled = {"events": n_ev, "tp": tp, "fp": n_ev - tp, "fn": n_truth - tp, "precision": tp / max(n_ev, 1),
              "recall": tp / max(n_truth, 1), "label_accuracy": float(lab[keep].sum()) / max(tp, 1),
              "linear_false_per_hit": lin_ev / max(lin_hits, 1), "classes": len({c["class"] for c in cases})}  # fmt: skip
    med = {"tp": float(np.median(old[y == 1])) if (y == 1).any() else None,
           "fp": float(np.median(old[y == 0])) if (y == 0).any() else None}  # fmt: skip
    console.print(f"\npooled over the grid at min_confidence {ExchangeSettings().min_confidence}: {pooled}")
    console.print(f"old weighted-mean confidence, medians: true {med['tp']}, false {med['fp']}")
    out = {
        "benchmark": "calibrate_confidence",
        "date": datetime.date.today().isoformat(),
        "commit": _commit(),
        "split": "crc32(case name) % 2 == 0: fit; else held-out",
        "fitted": {k: {"intercept": v.intercept, "coef": list(v.coef), "keys": list(v.keys)} for k, v in fitted.items()},
        "in_code": {k: {"intercept": v.intercept, "coef": list(v.coef), "keys": list(v.keys)} for k, v in code.items()},
        "n_events": len(events), "n_fit": int(fit.sum()), "n_held_out": int(held.sum()),
        "n_truth_held_out": n_truth_held,
        "reliability": tables, "levels": lv, "pooled": pooled, "old_confidence_medians": med,
        "held_out_events": [e for e, h in zip(events, held, strict=True) if h],
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1, default=float))
    # bench/results is not in git: the held-out events' scores and outcomes, and the pooled score, for the test
    fixture = {"source": "bench/calibrate_confidence.py", "date": out["date"], "commit": out["commit"], "keys": list(KEYS),
               "columns": [*KEYS, "matched", "label_right"], "pooled": pooled,
               "held_out": [[round(e["scores"][k], 4) for k in KEYS] + [int(e["matched"]), int(e["label_right"])]
                            for e in out["held_out_events"]]}  # fmt: skip
    FIXTURE.parent.mkdir(parents=True, exist_ok=True)
    FIXTURE.write_text(json.dumps(fixture, separators=(",", ":")))
    console.print(f"wrote {args.json} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
