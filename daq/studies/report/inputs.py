"""What ``gvt report`` reads before it draws anything: the log, its rig, its analysis results and hits.

Read once, here, and handed to each section: the sections draw, they do not open the log again (only the
figures that need samples read the stretch they show, through the same reader).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daq.log import layout
from daq.log.reader import LogReader, LogReadError
from daq.log.tools import log_info

if TYPE_CHECKING:
    from analysis.model.rig import Rig
    from daq.view.setup import ViewSetup


@dataclass
class ReportInputs:
    """The log's reader, ``log_info`` (health, streams, events), the rig (or why not: ``rig_note``), the
    ``/analysis/*`` results and where they came from, the hits, the streams and the view's setup of the rig."""

    reader: LogReader
    info: dict[str, Any]
    rig: Rig | None
    rig_note: str | None
    results: dict[str, list[dict]]
    source: str
    hits: list[dict]
    streams: dict[str, Any]
    fs: float
    setup: ViewSetup | None  # None without a rig


def read_inputs(log: str | Path, rig: Rig | None = None) -> ReportInputs:
    """Everything the sections need from ``log``; ``rig`` defaults to the log's attachment, and a log without a
    usable one is drawn without it (``rig_note`` says why) rather than refused."""
    from daq.log.rig import AnalyzeError, rig_from_log
    from daq.studies.analyze.rrd import log_results
    from daq.view.setup import ViewSetup

    reader = LogReader(log)
    reader.require_log()  # an MCAP file of another tool is one line, not an empty report (issue 30)
    hits = reader.json_messages(layout.HITS_TOPIC)
    check_hits(log, hits)  # before any analysis is read or drawn
    info = log_info(log)
    rig_note = None
    if rig is None:
        try:
            rig = rig_from_log(reader)
        except AnalyzeError as exc:
            rig, rig_note = None, str(exc)
    res, source = log_results(reader, rig)
    streams = reader.streams()
    fs = next(iter(streams.values())).sample_rate if streams else 1.0
    setup = ViewSetup.from_rig(rig, {n: tuple(i.channels) for n, i in streams.items()}, fs) if rig is not None else None
    return ReportInputs(reader, info, rig, rig_note, res, source, hits, streams, fs, setup)


def stream_with(streams: dict[str, Any], channel: str | None) -> str | None:
    """The first stream that records ``channel`` (None: no stream does, or no channel was asked for)."""
    return next((n for n, i in streams.items() if channel in i.channels), None)


_JSON_TYPES = {"integer": (int,), "number": (int, float), "string": (str,)}


def check_hits(log: str | Path, hits: list[dict]) -> None:
    """Every ``/daq/hits`` record has the fields its schema requires, of the right type (analysis/records.py,
    ``Hit.SCHEMA``); else one line naming the record and the field (:class:`LogReadError`, exit 2). A record
    without ``peak_force_N`` ended as "internal error: TypeError: Hit.__init__()" deep in the FRF section
    (issue 30)."""
    from analysis.records import Hit

    props, required = Hit.SCHEMA["properties"], Hit.SCHEMA["required"]
    for k, h in enumerate(hits):
        for name in required:
            kind = props[name]["type"]
            kinds = kind if isinstance(kind, list) else [kind]
            present = isinstance(h, dict) and name in h
            v = h.get(name) if present else None
            typed = (v is None and "null" in kinds) or any(
                isinstance(v, _JSON_TYPES.get(t, ())) and not isinstance(v, bool) for t in kinds
            )
            ok = present and typed
            if not ok:
                what = "lacks" if not present else f"has a {type(v).__name__} for"
                raise LogReadError(f"{log}: hit record {k} on {layout.HITS_TOPIC} {what} {name!r} ({' or '.join(kinds)}); "
                                   "the log is damaged or was not written by gvtlink")  # fmt: skip
