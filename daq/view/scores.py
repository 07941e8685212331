"""What each of the analysis's outputs is worth: measured precision and recall, shown by the report and the viewer.

Issue 21: the report listed "window-robust RQ spikes" beside the IR events as if both were detectors, while
the project's own evaluation scores the spikes 0 TP / 12 FP. Each output now carries its role and its score,
copied here from the bench runs that measured them (date and commit with each row); rerun those benches and update
the constants when a detector changes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DetectorScore:
    """One analysis output's measured score against the simulator's major exchanges (docs/evaluation.md §4)."""

    name: str  # as the report's section calls it
    role: str  # "detector" or "supporting evidence, not a detector"
    tp: int
    fp: int
    fn: int
    label_accuracy: float | None
    measured_on: str  # which grid, with the bench, date and commit

    @property
    def precision(self) -> float | None:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else None

    @property
    def recall(self) -> float | None:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else None


# bench/eval_realistic.py ("gvtlink modal exchange (acc)" summed over its 27 classes, nonlinear cases, at the default
# min_confidence; bench/results/eval_realistic.json), 2026-11-26, after the sensors' noise prior (docs/detection.md §9)
MODAL_EXCHANGE = DetectorScore(
    "internal-resonance events (modal exchange)", "detector", 2431, 33, 340, 0.99,
    "realistic grid, 27 error classes (bench/eval_realistic.py, 2026-11-26, with the sensors' noise prior)",
)  # fmt: skip
# docs/detection.md §4 (bench/eval_detection.py): the spikes alone on the issue-6 grid, 24 nonlinear hits, 63 exchanges
ROBUST_RQ_SPIKES = DetectorScore(
    "window-robust RQ spikes", "supporting evidence, not a detector", 0, 12, 63, None,
    "issue-6 grid, 24 hits (bench/eval_detection.py, docs/detection.md §4)",
)  # fmt: skip
# bench/eval_realistic.py ("seed literal (acc)" summed over its 27 classes; bench/results/eval_realistic.json),
# 2026-11-26, commit c397a79: the seed's spike rule, flagged per window as `seed_spike` in /analysis/rq
SEED_SPIKE = DetectorScore(
    "seed's literal RQ spike rule (seed_spike)", "the seed's method, for reference", 437, 3950, 2334, 0.15,
    "realistic grid, 27 error classes (bench/eval_realistic.py, 2026-11-26, c397a79)",
)  # fmt: skip

DETECTOR_SCORES: tuple[DetectorScore, ...] = (MODAL_EXCHANGE, ROBUST_RQ_SPIKES, SEED_SPIKE)


def _f(x: float | None) -> str:
    return "—" if x is None else f"{x:.2f}"


def score_note(s: DetectorScore) -> str:
    """One line: role, TP/FP, precision and recall, where measured."""
    return (f"{s.role}: {s.tp} TP / {s.fp} FP, precision {_f(s.precision)}, recall {_f(s.recall)} "
            f"({s.measured_on})")  # fmt: skip


SCORE_COLS = ["output", "role", "TP", "FP", "FN", "precision", "recall", "label acc.", "measured on"]


def score_rows() -> list[list[str]]:
    """The report's table: one row per analysis output."""
    return [[s.name, s.role, str(s.tp), str(s.fp), str(s.fn), _f(s.precision), _f(s.recall), _f(s.label_accuracy),
             s.measured_on] for s in DETECTOR_SCORES]  # fmt: skip
