"""Event scoring against the simulator's major exchanges (issue 6: precision, recall, m:n label accuracy).

Matching rule (``docs/evaluation.md`` §4): an event ``[start, end]`` *can match* a truth interval
``[a, b]`` when it overlaps ``[a, b + lag]`` with ``lag`` = one window (closed intervals, touching
counts) — a windowed detector sees an exchange at the earliest when its window reaches it, and reports
it up to one window later. Within each case the events and truths are matched **one-to-one** with the
maximum number of matched pairs (ties broken towards larger overlap, never towards the right label):
an event matches at most one truth interval and a truth interval is matched by at most one event, so a
second event on the same exchange is a false positive. Unmatched events are false positives, unmatched
truths false negatives. A matched event's label is right when its ``(m, n)`` equals the truth's
(an event without a label counts as wrong).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from analysis.evaluation.truth import Exchange


@dataclass(frozen=True)
class DetectedEvent:
    """What a detector reports: an interval (s, record time), its m:n label (0:0 = none) and a confidence."""

    start_s: float
    end_s: float
    m: int = 0
    n: int = 0
    confidence: float = 1.0

    @property
    def label(self) -> str:
        return f"{self.m}:{self.n}" if self.m and self.n else "-"


class EventLike(Protocol):
    start_s: float
    end_s: float


@dataclass(frozen=True)
class CaseScore:
    name: str
    n_truth: int
    n_events: int
    tp: int
    fp: int
    fn: int
    labels_right: int
    matches: tuple[tuple[int, int], ...]  # (event index, truth index)


@dataclass(frozen=True)
class Score:
    tp: int
    fp: int
    fn: int
    precision: float  # tp / (tp + fp); NaN when there are no events
    recall: float  # tp / (tp + fn); NaN when there are no truths
    label_accuracy: float  # right labels / tp; NaN when tp = 0
    rows: tuple[CaseScore, ...]

    @property
    def n_events(self) -> int:
        return self.tp + self.fp

    def as_dict(self) -> dict:
        def num(x: float) -> float | None:
            return None if not np.isfinite(x) else float(x)

        return {
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "precision": num(self.precision),
            "recall": num(self.recall),
            "label_accuracy": num(self.label_accuracy),
            "cases": [
                {k: (list(map(list, v)) if k == "matches" else v) for k, v in r.__dict__.items()} for r in self.rows
            ],
        }


def can_match(event: EventLike, truth: Exchange, lag_s: float) -> bool:
    """Overlap of ``[event.start, event.end]`` with ``[truth.start, truth.end + lag]`` (closed)."""
    return float(event.start_s) <= truth.end_s + lag_s and float(event.end_s) >= truth.start_s


def _label(e: EventLike) -> tuple[int, int]:
    return int(getattr(e, "m", 0) or 0), int(getattr(e, "n", 0) or 0)


def match_case(events: Sequence[EventLike], truths: Sequence[Exchange], lag_s: float) -> list[tuple[int, int]]:
    """Maximum one-to-one matching of events to truths in one record; returns (event, truth) index pairs."""
    if not events or not truths:
        return []
    ok = np.zeros((len(events), len(truths)), dtype=bool)
    overlap = np.zeros(ok.shape)
    for i, e in enumerate(events):
        for j, tr in enumerate(truths):
            if can_match(e, tr, lag_s):
                ok[i, j] = True
                lo, hi = max(float(e.start_s), tr.start_s), min(float(e.end_s), tr.end_s + lag_s)
                overlap[i, j] = max(hi - lo, 0.0) / max(tr.end_s + lag_s - tr.start_s, 1e-12)
    # Each compatible pair is worth 1 (+ < 1e-3 for overlap), so maximum weight = maximum cardinality first.
    rows, cols = linear_sum_assignment(-(ok * (1.0 + 1e-3 * overlap)))
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if ok[i, j]]


def score_events(
    events_per_case: Sequence[Sequence[EventLike]],
    truths_per_case: Sequence[Sequence[Exchange]],
    window_s: float,
    case_names: Sequence[str] | None = None,
) -> Score:
    """Score a detector over cases; ``window_s`` is the allowed lag (one detector window)."""
    if len(events_per_case) != len(truths_per_case):
        raise ValueError("one list of events per case, one list of truths per case")
    names = list(case_names) if case_names is not None else [str(i) for i in range(len(truths_per_case))]
    rows = []
    for name, ev, tr in zip(names, events_per_case, truths_per_case, strict=True):
        ev, tr = list(ev), list(tr)
        pairs = match_case(ev, tr, window_s)
        right = sum(_label(ev[i]) == (tr[j].ratio_m, tr[j].ratio_n) for i, j in pairs)
        tp = len(pairs)
        rows.append(CaseScore(name, len(tr), len(ev), tp, len(ev) - tp, len(tr) - tp, right, tuple(pairs)))
    tp = sum(r.tp for r in rows)
    fp = sum(r.fp for r in rows)
    fn = sum(r.fn for r in rows)
    right = sum(r.labels_right for r in rows)
    nan = float("nan")
    return Score(
        tp=tp,
        fp=fp,
        fn=fn,
        precision=tp / (tp + fp) if tp + fp else nan,
        recall=tp / (tp + fn) if tp + fn else nan,
        label_accuracy=right / tp if tp else nan,
        rows=tuple(rows),
    )


def _f(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{x:.2f}"


SUMMARY_HEADER = ("detector", "events", "TP", "FP", "FN", "precision", "recall", "label acc.")


def summary_rows(scores: dict[str, Score]) -> list[tuple[str, ...]]:
    return [
        (name, str(s.n_events), str(s.tp), str(s.fp), str(s.fn), _f(s.precision), _f(s.recall), _f(s.label_accuracy))
        for name, s in scores.items()
    ]


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def format_markdown(scores: dict[str, Score]) -> str:
    """One row per detector: events, TP/FP/FN, precision, recall, label accuracy ('-' = undefined)."""
    return markdown_table(SUMMARY_HEADER, summary_rows(scores))


def format_rich(scores: dict[str, Score], title: str = "Detection scores"):
    """The same table as a :class:`rich.table.Table` for the terminal."""
    from rich.table import Table

    table = Table(title=title)
    for h in SUMMARY_HEADER:
        table.add_column(h, justify="left" if h == "detector" else "right")
    for r in summary_rows(scores):
        table.add_row(*r)
    return table


def constant_label_accuracy(score: Score, truths_per_case: Sequence[Sequence[Exchange]]) -> tuple[str, float]:
    """The baseline a label accuracy must beat: every matched event given the one label most common among the truths it
    matched (the best constant). Returns that label and its accuracy over the score's matches; ("-", nan) with none."""
    labels = [truths_per_case[i][t].label for i, row in enumerate(score.rows) for _, t in row.matches]
    if not labels:
        return "-", float("nan")
    best = max(set(labels), key=labels.count)
    return best, labels.count(best) / len(labels)
