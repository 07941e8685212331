"""Issue 21, item 7: the realistic evaluation grid — the seed's literal rule and gvtlink's detector under lab errors.

Each *class* is one kind of error a real test has, applied to the issue-6 grid (24 nonlinear
beam_ch4_exp hits, 400-2000 N x zeta 0.002-0.015, and their 24 linear twins; the full grid in every
class: a class costs 5-20 s, so no subset is needed) or to sessions and the second structure
(``configs/rigs/beam_al_mid.toml``): sensor noise 1-5 %, sensitivity errors ±3/±5 %, a dead channel
(away from the attachment, and the attachment's), sensor positions off by up to 5 mm, FE model errors,
records of 2, 4 and 8 s, sessions of 5 hits every 2-6 s. How each is made: ``analysis/evaluation/
errors.py`` and ``sessions.py``; the results table: ``docs/evaluation.md`` ("Realistic grid").

Per class and detector it prints precision, recall and label accuracy on the nonlinear cases (scored
by ``analysis.evaluation.score``, one window of lag, one-to-one), and on the linear twins (where every
event is false) the false events per hit, the hits with at least one false event, and how long after
its hit each false event starts. Both detectors read ``acc`` (the measured path). JSON to
``bench/results/eval_realistic.json``.

    python bench/eval_realistic.py [--only SUBSTRING ...] [--no-cache] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from analysis.evaluation.detectors import modal_exchange_acc, seed_literal_acc  # noqa: E402
from analysis.evaluation.errors import (  # noqa: E402
    Measured,
    ModelError,
    model_error_rig,
    position_offsets,
    simulate_offset_cases,
)
from analysis.evaluation.grid import DEFAULT_CACHE_DIR, CaseData, case_rig, default_grid, simulate_cases  # noqa: E402
from analysis.evaluation.score import markdown_table, score_events  # noqa: E402
from analysis.evaluation.sessions import hit_of, per_hit, session_grid, simulate_sessions  # noqa: E402
from analysis.evaluation.truth import DEFAULT_WINDOW_S, Exchange  # noqa: E402

RESULTS = ROOT / "bench" / "results"
SECOND = "beam_al_mid"


@dataclass(frozen=True)
class ErrorClass:
    """One row group of the realistic grid: which cases, how they are measured, which model the detector gets."""

    name: str
    rig: str = ""
    duration: float = 2.0
    measured: Measured = field(default_factory=Measured)
    offsets_mm: float = 0.0  # sensors moved by up to this (uniform, seeded, one set for the campaign)
    model: ModelError | None = None  # fixed model error for every case
    model_pct: float = 0.0  # or: E, k, m each off by U(-pct, pct) %, a new draw per case
    sessions: tuple[float, float] | None = None  # gap range (s): 5-hit sessions instead of single hits


def classes() -> list[ErrorClass]:
    M = Measured
    return [
        ErrorClass("baseline: 1 % noise, 2 s"),
        ErrorClass("noise 2 %", measured=M(0.02)),
        ErrorClass("noise 3 %", measured=M(0.03)),
        ErrorClass("noise 5 %", measured=M(0.05)),
        ErrorClass("record 4 s", duration=4.0),
        ErrorClass("record 8 s", duration=8.0),
        ErrorClass("record 4 s, noise 3 %", duration=4.0, measured=M(0.03)),
        ErrorClass("record 8 s, noise 3 %", duration=8.0, measured=M(0.03)),
        ErrorClass("record 4 s, noise 3 % of the 4 s RMS (grid rule)", duration=4.0, measured=M(0.03, noise_ref_s=None)),
        ErrorClass("sensitivities ±3 %", measured=M(0.01, 3.0)),
        ErrorClass("sensitivities ±5 %", measured=M(0.01, 5.0)),
        ErrorClass("dead a07 (0.378 m)", measured=M(0.01, dead=("a07",))),
        ErrorClass("dead a13 (attachment)", measured=M(0.01, dead=("a13",))),
        ErrorClass("±3 % sens. + 3 % noise + dead a07", measured=M(0.03, 3.0, ("a07",))),
        ErrorClass("positions ±2 mm", offsets_mm=2.0),
        ErrorClass("positions ±5 mm", offsets_mm=5.0),
        ErrorClass("model E +3 %", model=ModelError(E=0.03)),
        ErrorClass("model k_att +5 %, m_att -5 %", model=ModelError(k=0.05, m=-0.05)),
        ErrorClass("model E, k_att, m_att ±5 % (per case)", model_pct=5.0),
        ErrorClass("sessions, hits every 2-6 s", sessions=(2.0, 6.0)),
        ErrorClass("sessions, hits every 2-4 s, noise 3 %", measured=M(0.03), sessions=(2.0, 4.0)),
        ErrorClass(f"{SECOND}: 1 % noise, 2 s", rig=SECOND),
        ErrorClass(f"{SECOND}: noise 3 %", rig=SECOND, measured=M(0.03)),
        ErrorClass(f"{SECOND}: record 8 s", rig=SECOND, duration=8.0),
        ErrorClass(f"{SECOND}: dead s06 (attachment)", rig=SECOND, measured=M(0.01, dead=("s06",))),
        ErrorClass(f"{SECOND}: ±3 % sens. + 3 % noise + dead s03", rig=SECOND, measured=M(0.03, 3.0, ("s03",))),
        ErrorClass(f"{SECOND}: model E, k_att, m_att ±5 % (per case)", rig=SECOND, model_pct=5.0),
    ]


Detector = Callable[..., list]
DETECTORS: dict[str, Detector] = {"seed literal (acc)": seed_literal_acc, "gvtlink modal exchange (acc)": modal_exchange_acc}


def class_data(c: ErrorClass, cache_dir: Path | None) -> list[CaseData]:
    """The class's cases (nonlinear then linear), clean, from the simulator or the cache."""
    if c.sessions is not None:
        return simulate_sessions(session_grid(gap_s=c.sessions, rig=c.rig), cache_dir=cache_dir)
    grid = default_grid(rig=c.rig)
    if c.offsets_mm:
        off = position_offsets(case_rig(grid[0]), c.offsets_mm, seed=0)
        return simulate_offset_cases(grid, off, c.duration, cache_dir=cache_dir)
    return simulate_cases(grid, c.duration, cache_dir=cache_dir)


def model_for(c: ErrorClass, d: CaseData):
    if c.model is not None:
        return model_error_rig(d.case, c.model)
    if c.model_pct:
        return model_error_rig(d.case, ModelError.draw(c.model_pct, d.case.seed))
    return None


def run_class(c: ErrorClass, cache_dir: Path | None, window_s: float = DEFAULT_WINDOW_S) -> dict:
    t0 = time.perf_counter()
    data = [c.measured(d) for d in class_data(c, cache_dir)]
    t_sim = time.perf_counter() - t0
    nl = [d for d in data if d.case.cubic]
    lin = [d for d in data if not d.case.cubic]
    hits_lin = sum(len(d.hit_times_s) for d in lin)
    out: dict = {
        "class": asdict(c),
        "nonlinear_cases": len(nl),
        "linear_cases": len(lin),
        "hits_per_twin_grid": hits_lin,
        "truth_exchanges": sum(len(d.exchanges) for d in nl),
        "linear_truth_exchanges": sum(len(d.exchanges) for d in lin),
        "data_seconds": t_sim,
        "detectors": {},
    }
    for name, det in DETECTORS.items():
        if c.sessions is not None and det is seed_literal_acc:
            det = per_hit(det)  # the seed analysed one record per hit (L1320)
        t1 = time.perf_counter()
        ev_nl = [list(det(d, model_rig=model_for(c, d))) for d in nl]
        ev_lin = [list(det(d, model_rig=model_for(c, d))) for d in lin]
        s = score_events(ev_nl, [d.exchanges for d in nl], window_s, [d.case.name for d in nl])
        s_zc = score_events(ev_nl, [zc_truth(d.exchanges) for d in nl], window_s, [d.case.name for d in nl])
        delays = [
            float(e.start_s) - d.hit_times_s[max(hit_of(d, float(e.start_s)), 0)]
            for d, ev in zip(lin, ev_lin, strict=True)
            for e in ev
        ]
        hits_hit = sum(len({max(hit_of(d, float(e.start_s)), 0) for e in ev}) for d, ev in zip(lin, ev_lin, strict=True))
        n_false = sum(len(e) for e in ev_lin)
        out["detectors"][name] = {
            "tp": s.tp, "fp": s.fp, "fn": s.fn,
            "precision": _num(s.precision), "recall": _num(s.recall), "label_accuracy": _num(s.label_accuracy),
            "label_accuracy_zero_crossing_truth": _num(s_zc.label_accuracy),
            "linear_false_events": n_false,
            "linear_false_per_hit": n_false / max(hits_lin, 1),
            "linear_hits_with_false_event": hits_hit,
            "linear_false_delay_s": _quantiles(delays),
            "nonlinear_fp_delay_s": _quantiles(_fp_delays(nl, ev_nl, s)),
            "seconds": time.perf_counter() - t1,
        }  # fmt: skip
    return out


def zc_truth(exchanges: Sequence[Exchange]) -> list[Exchange]:
    """The truths with issue 6's labels (rounded zero-crossing f2/f1) instead of the phase-lock test's
    (analysis/evaluation/truth.py, docs/evaluation.md §8): the label accuracy both ways."""
    out = []
    for e in exchanges:
        m, n = (int(x) for x in e.zc_label.split(":")) if e.zc_label else (e.ratio_m, e.ratio_n)
        out.append(replace(e, ratio_m=m, ratio_n=n))
    return out


def _fp_delays(nl: Sequence[CaseData], ev_nl: Sequence[list], s) -> list[float]:
    out = []
    for d, ev, row in zip(nl, ev_nl, s.rows, strict=True):
        matched = {i for i, _ in row.matches}
        out += [
            float(e.start_s) - d.hit_times_s[max(hit_of(d, float(e.start_s)), 0)] for i, e in enumerate(ev) if i not in matched
        ]
    return out


def _quantiles(x: Sequence[float]) -> dict | None:
    if not x:
        return None
    a = np.asarray(x)
    return {"n": int(a.size), "min": float(a.min()), "median": float(np.median(a)), "max": float(a.max())}


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "-" if x is None else format(x, fmt)


HEADER = (
    "class",
    "detector",
    "exch.",
    "TP",
    "FP",
    "FN",
    "precision",
    "recall",
    "label",
    "label (zc truth)",
    "lin. false/hit",
    "lin. hits w/ false",
    "false starts after hit (s)",
)


def rows(results: Sequence[dict]) -> list[tuple[str, ...]]:
    out = []
    for r in results:
        for name, d in r["detectors"].items():
            q = d["linear_false_delay_s"]
            delay = "-" if q is None else f"{q['min']:.2f}–{q['max']:.2f} (med {q['median']:.2f})"
            short = "seed" if name.startswith("seed") else "gvtlink"
            out.append((r["class"]["name"], short, str(r["truth_exchanges"]), str(d["tp"]), str(d["fp"]), str(d["fn"]),
                        _f(d["precision"]), _f(d["recall"]), _f(d["label_accuracy"]),
                        _f(d.get("label_accuracy_zero_crossing_truth")), f"{d['linear_false_per_hit']:.2f}",
                        f"{d['linear_hits_with_false_event']}/{r['hits_per_twin_grid']}", delay))  # fmt: skip
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", action="append", default=[], help="run the classes whose name contains this (repeatable)")
    ap.add_argument("--no-cache", action="store_true", help="simulate every case (ignore .cache/evaluation)")
    ap.add_argument("--json", type=Path, default=RESULTS / "eval_realistic.json")
    args = ap.parse_args(argv)
    console = Console(width=max(Console().width, 200))
    todo = [c for c in classes() if not args.only or any(s in c.name for s in args.only)]
    cache = None if args.no_cache else DEFAULT_CACHE_DIR
    results = []
    t0 = time.perf_counter()
    for i, c in enumerate(todo, 1):
        r = run_class(c, cache)
        results.append(r)
        g = r["detectors"]["gvtlink modal exchange (acc)"]
        console.print(f"[{i}/{len(todo)}] {c.name}: {r['truth_exchanges']} exchanges; gvtlink P {_f(g['precision'])} "
                      f"R {_f(g['recall'])} L {_f(g['label_accuracy'])}, {g['linear_false_per_hit']:.2f} false/hit "
                      f"({r['data_seconds']:.1f} s data)")  # fmt: skip
    table = Table(title="Realistic grid (nonlinear: scores against major exchanges; linear twins: every event false)")
    for h in HEADER:
        table.add_column(h, justify="left" if h in ("class", "detector", "false starts after hit (s)") else "right")
    for r in rows(results):
        table.add_row(*r)
    console.print(table)
    out = {
        "benchmark": "eval_realistic",
        "python": platform.python_version(),
        "machine": platform.machine(),
        "window_s": DEFAULT_WINDOW_S,
        "seconds": time.perf_counter() - t0,
        "classes": results,
        "markdown": markdown_table(HEADER, rows(results)),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2, default=float))
    console.print(f"wrote {args.json} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
