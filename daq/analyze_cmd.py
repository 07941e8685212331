"""Printing for ``gvt analyze``: a table of IR events, a summary of the RQ curves, or JSON."""

from __future__ import annotations

import json

import numpy as np
from rich.console import Console
from rich.table import Table

from daq.analyze import AnalysisRun


def summary(run: AnalysisRun) -> dict:
    rq = run.results.get("/analysis/rq", [])
    f = np.array([r["rq_hz"] for r in rq]) if rq else np.zeros((0, 0))
    return {
        "stream": run.stream,
        "rig": run.rig,
        "seconds_of_data": run.seconds_of_data,
        "wall_seconds": run.wall_seconds,
        "speed_x_real_time": run.speed,
        "rq_windows": len(rq),
        "modal_windows": len(run.results.get("/analysis/modal", [])),
        "seed_spikes": int(sum(r["seed_spike"] for r in rq)),
        "rq_spikes": run.results.get("/analysis/rq_spikes", []),
        "rq_median_hz": np.median(f, axis=0).tolist() if f.size else [],
        "events": run.events,
        "warnings": run.results.get("/analysis/warnings", []),
    }


def print_json(console: Console, run: AnalysisRun, full: bool = False) -> None:
    obj = summary(run)
    if full:
        obj["windows"] = {k: v for k, v in run.results.items() if k in ("/analysis/rq", "/analysis/modal")}
    console.print_json(json.dumps(obj))


def events_table(events: list[dict], title: str = "internal-resonance events") -> Table:
    """IR events (``IREvent.as_dict()`` or the log's ``/analysis/events``) as a table."""
    table = Table(title=f"{title}: {len(events)}")
    for col in ("#", "start [s]", "end [s]", "modes", "m:n", "f [Hz]", "gain", "gain/lock/exch/rq", "confidence"):
        table.add_column(col)
    for k, e in enumerate(events):
        sc = e["scores"]
        table.add_row(
            str(e.get("id", k)), f"{e['start_s']:.3f}", f"{e['end_s']:.3f}", f"{e['modes'][0]}→{e['modes'][1]}", e["ratio"],
            f"{e['f_give_hz']:.1f} / {e['f_recv_hz']:.1f}", f"{e['gain']:.1f}",
            f"{sc['gain']:.2f}/{sc['lock']:.2f}/{sc['exchange']:.2f}/{sc['rq']:.2f}", f"{e['confidence']:.2f}",
        )  # fmt: skip
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
    table = events_table(run.events)
    console.print(table)
