"""Issue 6 evaluation: detectors against the simulator's major exchanges over the force x damping grid.

Runs the grid of ``analysis.evaluation.grid.default_grid`` (beam_ch4_exp hits; nonlinear cases and
their linear twins), prints the truth table (per case: force, damping, input energy, the major
exchanges with interval, m:n label, f2/f1 and E2 gain), scores every detector on the nonlinear grid
(precision, recall, label accuracy; one-window lag, one-to-one matching) and counts its events on the
linear grid (which must be zero), and writes ``bench/results/eval_detection.json``.

A detector is any callable ``CaseData -> iterable of events`` (objects with ``start_s``, ``end_s``,
``m``, ``n``, ``confidence``, e.g. :class:`analysis.evaluation.score.DetectedEvent`). It chooses its
own path: ``case.acc`` (noisy accelerations, the measured path) or ``case.disp_true`` (simulated
displacements). Plug detectors in from Python (``run(detectors={...})``) or on the command line:

    python bench/eval_detection.py [--detector NAME=package.module:function ...] [--window 0.0216]
                                   [--self-check] [--no-cache] [--json PATH]

``--self-check`` scores the truth itself as a detector (must give precision = recall = label = 1 and
no linear events): a check of the harness, not a result.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from analysis.evaluation.grid import (  # noqa: E402
    DEFAULT_CACHE_DIR,
    CaseData,
    GridCase,
    case_dict,
    default_grid,
    simulate_cases,
)
from analysis.evaluation.score import DetectedEvent, EventLike, Score, format_markdown, format_rich, score_events  # noqa: E402
from analysis.evaluation.truth import DEFAULT_WINDOW_S, Exchange  # noqa: E402

RESULTS = ROOT / "bench" / "results"
Detector = Callable[[CaseData], Iterable[EventLike]]


def truth_detector(case: CaseData) -> list[DetectedEvent]:
    """The truth reported as events (harness self-check)."""
    return [DetectedEvent(e.start_s, e.end_s, e.ratio_m, e.ratio_n, 1.0) for e in case.exchanges]


def load_detector(spec: str) -> tuple[str, Detector]:
    """``NAME=module:function`` (or ``module:function``, named after the function)."""
    name, _, target = spec.rpartition("=")
    mod, _, fn = target.partition(":")
    if not mod or not fn:
        raise SystemExit(f"eval_detection: bad --detector {spec!r} (want NAME=package.module:function)")
    return (name or fn), getattr(importlib.import_module(mod), fn)


def exchange_dict(e: Exchange) -> dict:
    return {
        "start_s": e.start_s,
        "end_s": e.end_s,
        "gain": e.gain,
        "label": e.label,
        "f1_hz": e.f1_hz,
        "f2_hz": e.f2_hz,
        "ratio": e.ratio,
        "e2_end_rel": e.e2_end_rel,
        "e2_over_e1": e.e2_over_e1,
    }


def truth_table(data: Sequence[CaseData], window_s: float) -> Table:
    table = Table(title=f"Major exchanges (mode-2 energy x>=2 after the pulse; window {window_s * 1e3:.1f} ms)")
    for h in ("case", "F (N)", "zeta", "W_in (J)", "n", "intervals (s), label, f2/f1, gain, E2/E1 at end", "sim (s)"):
        table.add_column(h, justify="left" if h in ("case", "intervals (s), label, f2/f1, gain, E2/E1 at end") else "right")
    for d in data:
        parts = [
            f"{e.start_s:.3f}-{e.end_s:.3f} {e.label} ({e.ratio:.2f}) x{e.gain:.1f} {e.e2_over_e1:.0e}" for e in d.exchanges
        ]
        sim = "cache" if d.from_cache else f"{d.sim_seconds:.2f}"
        c = d.case
        cells = (c.name, f"{c.force_n:g}", f"{c.zeta:g}", f"{d.input_work:.3f}", str(len(d.exchanges)))
        table.add_row(*cells, "\n".join(parts) or "-", sim)
    return table


def run(
    detectors: Mapping[str, Detector] | None = None,
    grid: Sequence[GridCase] | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    cache_dir: Path | None = DEFAULT_CACHE_DIR,
    console: Console | None = None,
) -> dict:
    """Simulate (or load) the grid, print the truth table and the scores; return the JSON-able results."""
    console = console or Console()
    grid = list(default_grid() if grid is None else grid)
    t0 = time.perf_counter()
    data = simulate_cases(grid, window_s=window_s, cache_dir=cache_dir)
    t_grid = time.perf_counter() - t0
    nl = [d for d in data if d.case.cubic]
    lin = [d for d in data if not d.case.cubic]
    console.print(truth_table(data, window_s))
    labels = Counter(e.label for d in nl for e in d.exchanges)
    n_ex = sum(len(d.exchanges) for d in nl)
    sim_times = [d.sim_seconds for d in data if not d.from_cache]
    console.print(
        f"nonlinear: {len(nl)} cases, {n_ex} major exchanges in {sum(bool(d.exchanges) for d in nl)} cases, labels "
        f"{dict(sorted(labels.items()))}; linear: {len(lin)} cases, {sum(len(d.exchanges) for d in lin)} exchanges. "
        f"Grid {t_grid:.1f} s ({len(sim_times)} simulated)."
    )
    scores: dict[str, Score] = {}
    results: dict[str, dict] = {}
    for name, det in (detectors or {}).items():
        t1 = time.perf_counter()
        ev_nl = [list(det(d)) for d in nl]
        ev_lin = [list(det(d)) for d in lin]
        dt = (time.perf_counter() - t1) / max(len(data), 1)
        s = score_events(ev_nl, [d.exchanges for d in nl], window_s, [d.case.name for d in nl])
        scores[name] = s
        results[name] = {
            "nonlinear": s.as_dict(),
            "linear_events": sum(len(e) for e in ev_lin),
            "linear_events_per_case": {d.case.name: len(e) for d, e in zip(lin, ev_lin, strict=True)},
            "seconds_per_case": dt,
        }
    if scores:
        console.print(format_rich(scores, title="Nonlinear grid"))
        for name, r in results.items():
            console.print(f"{name}: {r['linear_events']} events on the linear grid (must be 0)")
    return {
        "benchmark": "eval_detection",
        "python": platform.python_version(),
        "machine": platform.machine(),
        "window_s": window_s,
        "grid_seconds": t_grid,
        "sim_seconds_per_case": {d.case.name: d.sim_seconds for d in data if not d.from_cache},
        "truth_summary": {
            "nonlinear_cases": len(nl),
            "nonlinear_exchanges": n_ex,
            "labels": dict(labels),
            "linear_cases": len(lin),
            "linear_exchanges": sum(len(d.exchanges) for d in lin),
        },
        "cases": [
            {**case_dict(d.case), "input_work_j": d.input_work, "exchanges": [exchange_dict(e) for e in d.exchanges]}
            for d in data
        ],
        "detectors": results,
        "markdown": format_markdown(scores) if scores else "",
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--detector", action="append", default=[], help="NAME=package.module:function (repeatable)")
    ap.add_argument("--window", type=float, default=DEFAULT_WINDOW_S, help="truth smoothing window and allowed lag, s")
    ap.add_argument("--self-check", action="store_true", help="also score the truth itself as a detector")
    ap.add_argument("--no-cache", action="store_true", help="simulate every case (ignore .cache/evaluation)")
    ap.add_argument("--json", type=Path, default=RESULTS / "eval_detection.json")
    args = ap.parse_args(argv)
    detectors: dict[str, Detector] = dict(load_detector(s) for s in args.detector)
    if not detectors:  # default: the seed's literal detector (the baseline) and gvtlink's, both paths
        from analysis.evaluation.detectors import DETECTORS

        detectors = dict(DETECTORS)
    if args.self_check:
        detectors["truth (self-check)"] = truth_detector
    out = run(detectors, window_s=args.window, cache_dir=None if args.no_cache else DEFAULT_CACHE_DIR)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2, default=float))
    Console().print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
