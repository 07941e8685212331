"""``gvt confirm LOG [--event ID]``: confirm a log's IR events with WBEMD + slow flow, in batch.

The events are the log's own ``/analysis/events`` (written live by ``gvt record``); a log recorded
without the analysis is analysed first (``gvt analyze``'s kernels). Each event is confirmed on the same
stretch of data the background lane uses (analysis/confirm.py), read straight from the log.

Results go to a small companion log, ``LOG.confirm.mcap`` by default (topic ``/analysis/confirmations``,
metadata naming the source log), not into the session log itself: an MCAP log is a finished file
(footer and summary), so adding to it means rewriting it — a multi-GB copy of the one record of a test
that must never be put at risk for a few kB of results (docs/decisions.md D22). ``gvt report`` and
``gvt confirm`` itself read the companion next to the log.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from analysis.records import confirmation_status
from daq.lanes.confirm import CONFIRM_TOPIC, skipped
from daq.log import layout
from daq.log.reader import LogReader

if TYPE_CHECKING:
    from analysis.confirm import ConfirmSettings
    from analysis.model.rig import Rig

META_CONFIRM = "gvtlink.confirm"


def companion_path(log: str | Path) -> Path:
    """Where the confirmations of ``log`` go: ``session.mcap`` → ``session.confirm.mcap``."""
    p = Path(log)
    return p.with_name(p.stem + ".confirm.mcap")


@dataclass
class ConfirmRun:
    log: str
    stream: str
    rig: str
    events_from: str  # "log" or "analysis"
    records: list[dict] = field(default_factory=list)
    wall_seconds: float = 0.0


def read_confirmations(log: str | Path, include_log: bool = True) -> list[dict]:
    """Confirmation records of a log: its own topic (written live, unless ``include_log=False``) then its
    companion file, if any. An unreadable file raises :class:`LogReadError` (one line) — never a silent "none"."""
    out: list[dict] = LogReader(log).json_messages(CONFIRM_TOPIC) if include_log else []
    side = companion_path(log)
    if side.exists():
        out.extend(LogReader(side).json_messages(CONFIRM_TOPIC))
    return out


def confirm_log(
    path: str | Path, rig: Rig | None = None, event_id: int | None = None, settings: ConfirmSettings | None = None,
    progress: Callable[[float], None] | None = None,
) -> ConfirmRun:  # fmt: skip
    """Confirm every IR event of the log (or the one with ``event_id``). The confirmation kernels (scipy.signal,
    numba) and the batch analysis load here, not with the module: ``gvt replay`` and ``gvt report`` import this
    module for the companion's path, table and reader only (docs/decisions.md D108)."""
    import numpy as np

    from analysis.confirm import ConfirmContext, ConfirmSettings, confirm_segment
    from daq.studies.analyze.batch import AnalyzeError, analyze_log, open_for_analysis

    settings = settings if settings is not None else ConfirmSettings()
    reader, rig, model, stream = open_for_analysis(path, rig, None)
    events = reader.json_messages(layout.IR_EVENTS_TOPIC)
    source = "log"
    if not events:
        events = analyze_log(path, rig).events
        source = "analysis"
    if event_id is not None:
        chosen = [e for e in events if e.get("id") == event_id]
        if not chosen:
            ids = [e.get("id") for e in events]
            raise AnalyzeError(f"{path}: no IR event with id {event_id}; the log's events are {ids or 'none'} (see gvt analyze)")
        events = chosen
    ctx = ConfirmContext.from_model(model, settings)
    info = reader.streams()[stream]
    fs = info.sample_rate
    run = ConfirmRun(log=str(path), stream=stream, rig=rig.name, events_from=source)
    t0 = time.perf_counter()
    for i, ev in enumerate(events):
        a, b = ctx.span_s(ev)
        data = reader.read_stream(stream, list(model.sensors), a, b)
        if data.gaps or data.data.shape[0] < 16:
            rec = skipped(ev, f"the log has a gap or no data in {a:.3f}–{b:.3f} s")
        else:
            try:
                rec = confirm_segment(np.asarray(data.data, np.float64), fs, float(data.index[0]) / fs, ev, ctx)
            except ValueError as exc:
                rec = skipped(ev, str(exc), status="error")
        run.records.append(rec)
        if progress is not None:
            progress((i + 1) / len(events))
    run.wall_seconds = time.perf_counter() - t0
    return run


def write_companion(run: ConfirmRun, out: str | Path, overwrite: bool = True) -> Path:
    """The confirmation records as a small MCAP log (topic ``/analysis/confirmations``). The verbs check
    ``--overwrite`` before their work starts; ``overwrite=False`` refuses an existing file here too."""
    from daq.log.writer import LogWriter

    out = Path(out)
    meta = {"source_log": Path(run.log).name, "stream": run.stream, "rig": run.rig, "events_from": run.events_from}
    origin = _stream_t0_ns(run.log, run.stream)  # on the source log's timeline: its event times are the stream's
    with LogWriter(out, fsync=True, session_metadata={"kind": "confirmations"}, overwrite=overwrite, origin_ns=origin) as w:
        w.add_metadata(META_CONFIRM, meta)
        for rec in run.records:
            t = rec.get("event", {}).get("end_s")
            w.write_json(CONFIRM_TOPIC, rec, None if t is None else round(float(t) * 1e9))
    return out


def _stream_t0_ns(log: str | Path, stream: str | None) -> int:
    """log_time of ``stream``'s sample 0 in the source log (docs/log-format.md, "Time base"); 0 when it cannot be read."""
    from daq.log.export import time_base
    from daq.log.reader import LogReader, LogReadError

    try:
        return time_base(LogReader(log)).stream_t0_ns(stream or "")
    except (LogReadError, OSError, ValueError, KeyError):
        return 0


def _confirmation_note(rec: dict) -> str | None:
    """The free text of a confirmation: which sensor, the orthogonality index, the time taken, and why."""
    facts = []
    if rec.get("sensor"):
        facts.append(f"sensor {rec['sensor']}")
    if rec.get("orthogonality_index") is not None:
        facts.append(f"IO {rec['orthogonality_index']:.3f}")
    if rec.get("elapsed_s") is not None:
        facts.append(f"{rec['elapsed_s']:.1f} s")
    why = rec.get("reason") or ""
    text = ", ".join(facts) + (": " if facts and why else "") + why
    return text or None


def confirmations_table(records: list[dict], title: str, width: int | None = None):
    """One row per event — its id, label, modes and span, the status, the m:n found, interval and evidence —
    fitting ``width`` (default: the console's); the sensor, orthogonality index (IO), time taken and the reason
    are numbered notes below the table (``gvt confirm --json`` and the report carry them too). The status is
    :func:`analysis.records.confirmation_status`: a resonance at another m:n than the event's is ``other_ratio``,
    also in a log written before that status existed."""
    from daq.terminal import Col, FitTable

    t = FitTable(
        title,
        [
            Col("id", "right", key=True), Col("m:n"), Col("modes"), Col("event [s]", "right"), Col("status"),
            Col("m:n found"), Col("interval [s]", "right"), Col("evidence"), Col("why", note=True, inline_max=3),
        ],
        empty="no IR events",
        width=width,
    )  # fmt: skip
    for rec in records:
        ev = rec.get("event", {})
        span = f"{rec['start_s']:.2f}–{rec['end_s']:.2f}" if rec.get("start_s") is not None else None
        t.add_row(
            rec.get("event_id"), ev.get("ratio", "?"), "→".join(str(m) for m in ev.get("modes", [])) or None,
            f"{ev.get('start_s', float('nan')):.2f}–{ev.get('end_s', float('nan')):.2f}", confirmation_status(rec),
            rec.get("ratio"), span, rec.get("evidence"), _confirmation_note(rec),
        )  # fmt: skip
    return t
