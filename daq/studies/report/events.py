"""The near-live analysis in tables: what each detector is worth, the IR events, the window-robust RQ spikes,
and the analysis warnings.

The detectors' measured scores come first (issue 21): a reader weighs each output by its measured precision
before reading the outputs themselves (``daq/view/scores.py``, docs/evaluation.md).
"""

from __future__ import annotations

import html

from daq.log import layout
from daq.studies.report.page import num, table

IR_COLS = ["#", "start [s]", "end [s]", "modes", "m:n", "f give/recv [Hz]", "gain", "confidence", "label conf.", "source"]


def detection_tables(results: dict[str, list[dict]], source: str) -> list[str]:
    """The scores table, the IR events with their note, the RQ spikes with theirs; ``source``: where the results
    came from (the log, or a batch run of the same kernels)."""
    from daq.view.scores import MODAL_EXCHANGE, ROBUST_RQ_SPIKES, SCORE_COLS, score_note, score_rows

    ir = [_ir_row(k, e) for k, e in enumerate(results.get(layout.IR_EVENTS_TOPIC, []))]
    spikes = [[num(s["start_s"]), num(s["end_s"]), num(s.get("agreement"), ".2f")]
              for s in results.get(layout.RQ_SPIKES_TOPIC, [])]  # fmt: skip
    ir_note = (f"<p class='note'>{html.escape(score_note(MODAL_EXCHANGE))}. Confidence: calibrated probability that "
               "the event is a true major exchange; label conf.: that it is one with this m:n (docs/evaluation.md §6); "
               "1:1 = receiving frequency near the giving mode's, a leak, not an m:n resonance.</p>")  # fmt: skip
    return [
        table("detectors and their measured scores", SCORE_COLS, score_rows()),
        table(f"internal-resonance events (near-live analysis, results from {source})", IR_COLS, ir),
        ir_note,
        table("window-robust RQ spikes (supporting evidence, not a detector)", ["start [s]", "end [s]", "agreement"], spikes),
        f"<p class='note'>{html.escape(score_note(ROBUST_RQ_SPIKES))}.</p>",
    ]


def warnings_table(results: dict[str, list[dict]]) -> str:
    """The analysis' warnings (a lost nonlinearity sensor, a channel dropped from the modal filter ...)."""
    warns = [[w.get("kind"), w.get("message")] for w in results.get(layout.WARNINGS_TOPIC, [])]
    return table("analysis warnings", ["kind", "message"], warns)


def _ir_row(k: int, e: dict) -> list:
    return [e.get("id", k), num(e["start_s"]), num(e["end_s"]), "→".join(str(m) for m in e.get("modes", [])), e.get("ratio"),
            f"{num(e.get('f_give_hz'), '.1f')} / {num(e.get('f_recv_hz'), '.1f')}", num(e.get("gain"), ".1f"),
            num(e.get("confidence"), ".2f"), num(e.get("label_confidence"), ".2f"), e.get("source", "")]  # fmt: skip
