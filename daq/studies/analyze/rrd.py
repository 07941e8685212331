"""Offline rerun recording of a session log (``gvt analyze LOG --rrd OUT.rrd``, ``gvt demo``).

The log's blocks go through the same :class:`~daq.view.logger.ViewLogger` the live lane uses, in time
order, and every result (hits, driver events, ``/analysis/*``, ``/analysis/confirmations``) is handed
to it as soon as the blocks up to its time have been drawn — so POM shapes of events and the wavelet
spectrum of hits come from the same bounded history as live. Results come from the log when the
session ran the near-live analysis, or from :func:`daq.studies.analyze.batch.analyze_log` (same kernels) otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from daq.log import layout
from daq.log.reader import LogReader

if TYPE_CHECKING:
    from daq.view.logger import ViewLogger

RESULT_TOPICS = layout.RESULT_TOPICS


@dataclass
class BuildSummary:
    path: Path
    blocks: int = 0
    results_from: str = "log"  # "log": the session's own near-live results; "analyze": computed now
    counts: dict[str, int] = field(default_factory=dict)


def _time_of(topic: str, obj: dict) -> float:
    if topic == layout.HITS_TOPIC:
        return float(obj.get("t_s", 0.0)) + 0.5  # the record is complete half a second after the hit at most
    if topic == layout.CONFIRMATIONS_TOPIC:
        ev = obj.get("event") or {}
        return float(obj.get("end_s") or ev.get("end_s") or 0.0)
    for k in ("t_end_s", "end_s", "t_s"):
        if k in obj:
            return float(obj[k])
    return float("inf")  # no time: after the last block


def log_results(reader: LogReader, rig=None, results: dict[str, list[dict]] | None = None) -> tuple[dict[str, list[dict]], str]:
    """The log's ``/analysis/*`` results, or a fresh batch analysis when the log has none."""
    if results is not None:  # computed now; confirmations only ever come from the log (or the confirmation lane)
        out = dict(results)
        out.setdefault(layout.CONFIRMATIONS_TOPIC, reader.json_messages(layout.CONFIRMATIONS_TOPIC))
        return out, "analyze"
    got = {t: reader.json_messages(t) for t in RESULT_TOPICS}
    if got[layout.RQ_TOPIC] or got[layout.MODAL_TOPIC]:
        return got, "log"
    from daq.studies.analyze.batch import AnalyzeError, analyze_log

    try:
        run = analyze_log(reader.path, rig)
    except AnalyzeError:
        return got, "none"
    out = dict(run.results)
    out[layout.CONFIRMATIONS_TOPIC] = got[layout.CONFIRMATIONS_TOPIC]
    return out, "analyze"


def build_rrd(
    log: str | Path, out: str | Path, rig=None, results: dict[str, list[dict]] | None = None, wavelet_channel: str | None = None,
) -> BuildSummary:  # fmt: skip
    """Write ``out`` (.rrd, blueprint included) from the session log ``log``; ``rig`` defaults to the log's.
    rerun and the view load here, not with the module: ``gvt report`` imports it for :func:`log_results` only."""
    from daq.log.rig import AnalyzeError, rig_from_log
    from daq.replay import iter_log_blocks
    from daq.view import recording as R
    from daq.view.logger import ViewLogger, ViewSetup

    reader = LogReader(log)
    infos = reader.streams()
    streams = {n: tuple(i.channels) for n, i in infos.items()}
    fs = next(iter(infos.values())).sample_rate if infos else 1.0
    if rig is None:
        try:
            rig = rig_from_log(reader)
        except AnalyzeError:
            rig = None
    setup = ViewSetup.from_rig(rig, streams, fs, wavelet_channel) if rig is not None else ViewSetup(streams, fs)
    res, source = log_results(reader, rig, results)
    items: list[tuple[float, int, str, dict]] = []
    for topic in (layout.HITS_TOPIC, layout.EVENTS_TOPIC, *RESULT_TOPICS):
        objs = reader.json_messages(topic) if topic.startswith(layout.DAQ_PREFIX) else res.get(topic, [])
        items += [(_time_of(topic, o), len(items) + i, topic, o) for i, o in enumerate(objs)]
    items.sort(key=lambda x: x[:2])
    rec = R.new_recording()
    rec.save(str(out), default_blueprint=R.blueprint())
    summary = BuildSummary(Path(out), results_from=source)
    try:
        view = ViewLogger(rec, setup, flush_s=1.0)
        k = 0
        bad: list[str] = []
        for blk in iter_log_blocks(reader, bad=bad):
            view.block(blk)
            summary.blocks += 1
            t = blk.end_index / blk.sample_rate
            j = k
            while j < len(items) and items[j][0] <= t:
                j += 1
            _batched(view, items[k:j])
            k = j
        _batched(view, items[k:])
        if bad:
            R.log_text(rec, R.LOG_DAQ, view.t_now, f"{len(bad)} undecodable sample block(s) skipped; first: {bad[0]}", "WARN")
        if not res.get(layout.CONFIRMATIONS_TOPIC):
            R.log_text(rec, R.LOG_ANALYSIS, view.t_now, "confirmations: none in this log", "INFO")
        view.finish()
        summary.counts = dict(view.counts)
    finally:
        rec.flush()
        rec.disconnect()
    return summary


def _batched(view: ViewLogger, items: list[tuple[float, int, str, dict]]) -> None:
    """Hand results over per topic in time order (one send_columns per topic and batch, not per row)."""
    by: dict[str, list[dict]] = {}
    for _t, _i, topic, obj in items:
        by.setdefault(topic, []).append(obj)
    for topic in (layout.MODAL_TOPIC, *[t for t in by if t != layout.MODAL_TOPIC]):  # energies before the RQ-FEP pairs
        view.results(topic, by.get(topic, []))
