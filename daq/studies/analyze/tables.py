"""Printing for ``gvt analyze``: a table of IR events, a summary of the RQ curves, or JSON."""

from __future__ import annotations

import json

import numpy as np
from rich.console import Console

from daq.log import layout
from daq.studies.analyze.batch import AnalysisRun
from daq.terminal import Col, FitTable


def summary(run: AnalysisRun) -> dict:
    rq = run.results.get(layout.RQ_TOPIC, [])
    f = np.array([r["rq_hz"] for r in rq]) if rq else np.zeros((0, 0))
    return {
        "stream": run.stream,
        "rig": run.rig,
        "seconds_of_data": run.seconds_of_data,
        "wall_seconds": run.wall_seconds,
        "speed_x_real_time": run.speed,
        "rq_windows": len(rq),
        "modal_windows": len(run.results.get(layout.MODAL_TOPIC, [])),
        "seed_spikes": int(sum(r["seed_spike"] for r in rq)),
        "rq_spikes": run.results.get(layout.RQ_SPIKES_TOPIC, []),
        "rq_median_hz": np.median(f, axis=0).tolist() if f.size else [],
        "events": run.events,
        "warnings": run.results.get(layout.WARNINGS_TOPIC, []),
    }


def document(run: AnalysisRun, full: bool = False) -> dict:
    """The ``--json`` document: the summary; ``full`` (``--windows``): also every window's RQ and modal result."""
    obj = summary(run)
    if full:
        obj["windows"] = {k: v for k, v in run.results.items() if k in (layout.RQ_TOPIC, layout.MODAL_TOPIC)}
    return obj


def print_json(console: Console, run: AnalysisRun, full: bool = False) -> None:
    console.print_json(json.dumps(document(run, full)))


def _event_note(e: dict) -> str | None:
    """The free text of an event (its evidence, reason or message; a source other than the modal exchange)."""
    parts = [str(e[k]) for k in ("evidence", "reason", "message") if e.get(k)]
    if e.get("source") not in (None, "modal-exchange"):
        parts.insert(0, f"source {e['source']}")
    return "; ".join(parts) or None


def events_table(events: list[dict], title: str = "internal-resonance events", width: int | None = None) -> FitTable:
    """IR events (``IREvent.as_dict()`` or the log's ``/analysis/events``) as a table that fits ``width``
    (default: the console's), any free text (evidence, reason) numbered below it."""
    notes = [_event_note(e) for e in events]
    cols = [
        Col("#", "right", key=True), Col("t [s]", "right", key=True), Col("m:n"), Col("modes"),
        Col("f [Hz]", "right"), Col("gain", "right"), Col("confidence (gain/lock/exch/rq)", "right"),
    ]  # fmt: skip
    if any(notes):
        cols.append(Col("note", note=True, inline_max=12))
    table = FitTable(f"{title}: {len(events)}", cols, width=width)
    for k, (e, note) in enumerate(zip(events, notes, strict=True)):
        sc = e.get("scores", {})
        scores = "/".join(f"{sc[s]:.2f}" if s in sc else "–" for s in ("gain", "lock", "exchange", "rq"))
        row = [
            e.get("id", k), f"{e['start_s']:.2f}–{e['end_s']:.2f}", e["ratio"], f"{e['modes'][0]}→{e['modes'][1]}",
            f"{e['f_give_hz']:.1f} / {e['f_recv_hz']:.1f}", f"{e['gain']:.1f}", f"{e['confidence']:.2f} ({scores})",
        ]  # fmt: skip
        table.add_row(*row, *([note] if any(notes) else []))
    return table


def print_report(console: Console, run: AnalysisRun) -> None:
    s = summary(run)
    console.print(
        f"{run.rig} · stream {run.stream}: {s['seconds_of_data']:.2f} s of data analysed in {s['wall_seconds']:.2f} s "
        f"({s['speed_x_real_time']:.0f}× real time); {s['rq_windows']} RQ windows, {s['seed_spikes']} seed-rule spikes, "
        f"{len(s['rq_spikes'])} window-robust RQ spikes",
        markup=False,
    )
    for w in s["warnings"]:
        console.print(f"warning: {w['message']}", markup=False)
    console.print(events_table(run.events))
