"""Issue 29, item 6: label accuracy against a truth independent of the detector, beside the constant-label baseline.

Truth labels by the slow phase (``analysis.evaluation.truth.slow_phase_label``: the m:n whose ``m θ1 − n θ2`` turns
slowest over the exchange, from the simulator's exact modal coordinates; the seed's eq. 4.2), not by the phase-lock fit
the detector itself runs. Grids: beam_ch4_sim (the seed's computational rig, §4.2: a 4:1 internal resonance at low
energy, 3:1 above; hits of 145, 300 and 1000 N at zeta 0.002 and 0.005, 2 s, displacement channels with 1 % noise,
the detector on its displacement path: mode 1 at 3.8 Hz is under the acceleration path's 5 Hz high-pass) and
beam_ch4_exp's 24 nonlinear hits (1 % noise, acceleration path). Per grid: the truth's label counts, the detector's
precision / recall, its label accuracy against the slow-phase truth and against the lock truth (docs/evaluation.md
§8), and the best constant label's accuracy over the same matches (a detector that always says "3:1").

    python bench/eval_labels.py [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from analysis.evaluation.detectors import modal_exchange_health  # noqa: E402
from analysis.evaluation.grid import CaseData, GridCase, default_grid, simulate_cases  # noqa: E402
from analysis.evaluation.score import constant_label_accuracy, markdown_table, score_events  # noqa: E402
from analysis.evaluation.truth import DEFAULT_WINDOW_S  # noqa: E402

RESULTS = ROOT / "bench" / "results"
SIM_FORCES = (145.0, 300.0, 1000.0)
SIM_ZETAS = (0.002, 0.005)


def sim_grid() -> list[GridCase]:
    return [GridCase(f, z, True, i, "beam_ch4_sim") for i, (z, f) in enumerate((z, f) for z in SIM_ZETAS for f in SIM_FORCES)]


def noisy_displacement(d: CaseData, level: float = 0.01) -> CaseData:
    """The displacement channels as a DAQ reads them: 1 % Gaussian noise of each channel's RMS (the grid's rule)."""
    x = d.disp_true.astype(float)
    std = level * np.sqrt(np.mean(x**2, axis=0))
    rng = np.random.default_rng([d.case.seed, 7])
    return replace(d, disp_true=(x + rng.standard_normal(x.shape) * std).astype(np.float32))


def grid_row(name: str, data: list[CaseData], quantity: str) -> dict:
    t0 = time.perf_counter()
    phase = [d.truth(label_rule="phase") for d in data]
    lock = [d.exchanges for d in data]
    events = [modal_exchange_health(d, quantity=quantity)[0] for d in data]
    s = score_events(events, phase, DEFAULT_WINDOW_S)
    s_lock = score_events(events, lock, DEFAULT_WINDOW_S)
    const, const_acc = constant_label_accuracy(s, phase)
    _, const_lock = constant_label_accuracy(s_lock, lock)
    return {
        "grid": name, "cases": len(data), "truth_labels": dict(Counter(e.label for t in phase for e in t)),
        "lock_truth_labels": dict(Counter(e.label for t in lock for e in t)),
        "tp": s.tp, "fp": s.fp, "fn": s.fn, "precision": s.precision, "recall": s.recall,
        "label_accuracy": s.label_accuracy, "constant_label": const, "constant_label_accuracy": const_acc,
        "label_accuracy_lock_truth": s_lock.label_accuracy, "constant_label_accuracy_lock_truth": const_lock,
        "detector_labels": dict(Counter(f"{e.m}:{e.n}" for ev in events for e in ev)),
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, default=RESULTS / "eval_labels.json")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = [
        grid_row("beam_ch4_sim 145-1000 N (displacement)", [noisy_displacement(d) for d in simulate_cases(sim_grid())],
                 "displacement"),
        grid_row("beam_ch4_exp 24 nonlinear hits (acceleration)", simulate_cases(default_grid()[:24]), "acceleration"),
    ]  # fmt: skip
    header = ("grid", "truth labels (slow phase)", "P", "R", "label acc.", "best constant", "label acc. (lock truth)",
              "constant (lock truth)")  # fmt: skip
    table = [
        (r["grid"], ", ".join(f"{k} x{v}" for k, v in sorted(r["truth_labels"].items())), f"{r['precision']:.2f}",
         f"{r['recall']:.2f}", f"{r['label_accuracy']:.2f}", f"{r['constant_label']} {r['constant_label_accuracy']:.2f}",
         f"{r['label_accuracy_lock_truth']:.2f}", f"{r['constant_label_accuracy_lock_truth']:.2f}")
        for r in rows
    ]  # fmt: skip
    md = markdown_table(header, table)
    print(md)
    out = {"benchmark": "eval_labels", "seconds": time.perf_counter() - t0, "rows": rows, "markdown": md}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2, default=float))
    print(f"wrote {args.json} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
