"""``gvt report LOG --out report.html``: a static, self-contained session report readable without rerun.

One HTML file, PNG plots embedded as base64 data URIs (matplotlib, Agg backend — no display, no network,
no external assets), and tables of what a test engineer signs off. Each section is a module of this package,
and :func:`build_report` assembles them in page order:

- ``loss.py``: streams and loss counters (gaps, writer overruns, undecodable blocks), driver events by kind;
- ``hits.py``: hits and verdicts;
- ``frf.py``: the FRF section — FRF magnitude and phase, coherence, hammer spectra with their −10 dB points,
  averages, refused hits and the modes against the FE modes;
- ``identify.py``: the identification (``gvt identify --json`` summaries), when given;
- ``events.py``: the near-live analysis — each detector's measured precision (``daq/view/scores.py``), IR
  events, window-robust RQ spikes as supporting evidence, warnings;
- ``confirmations.py``: confirmations of the background lane (``/analysis/confirmations``, or "none") and
  their slow-flow phase trajectories;
- the plots: ``signals.py`` hammer force with hits and the driving-point response, ``rq.py`` RQ per NNM against
  time with IR events, modal energies and the RQ-FEP (RQ frequency against windowed modal energy, seed Ch. 4),
  ``wavelet.py`` a Morlet wavelet spectrum of a hit record (eq. 3.2, amplitude normalisation), ``pom.py`` POM
  shapes of IR events;
- ``shell.py`` the page around them; ``page.py`` what they all draw with (each figure is drawn once:
  :func:`daq.studies.report.page.png`); ``inputs.py`` what they read from the log.

Results come from the log's ``/analysis/*`` topics, or from a batch run of the same kernels when the
session did not run the analysis (:func:`daq.studies.analyze.rrd.log_results`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from daq.log import layout
from daq.studies.report.confirmations import confirmations_table, session_confirmations, slow_flow_figure
from daq.studies.report.events import detection_tables, warnings_table
from daq.studies.report.frf import frf_section
from daq.studies.report.hits import hits_table
from daq.studies.report.identify import identify_section
from daq.studies.report.inputs import ReportInputs, read_inputs
from daq.studies.report.loss import loss_tables
from daq.studies.report.page import png, table
from daq.studies.report.pom import pom_figure
from daq.studies.report.rq import rq_figure, rqfep_figure
from daq.studies.report.shell import document, header
from daq.studies.report.signals import signals_figure
from daq.studies.report.wavelet import wavelet_figure


@dataclass
class ReportSummary:
    """What ``gvt report`` says after writing the page: the figures and tables it holds, and what it lacks and why."""

    path: Path
    figures: list[str] = field(default_factory=list)
    tables: list[str] = field(default_factory=list)
    results_from: str = "log"
    rig_note: str | None = None  # why the log's attached rig was not used (the report is drawn without it)
    frf_absent: str | None = None  # why the report has no FRFs (no rig, no hits, no accepted hit); None: it has them


def build_report(
    log: str | Path,
    out: str | Path,
    rig=None,
    frf_channel: str | None = None,
    band_hz: float | None = None,
    identification: list | None = None,
) -> ReportSummary:
    """Write the report for ``log`` to ``out`` (.html); ``rig`` defaults to the one attached to the log.

    ``frf_channel``: the response drawn beside the driving point in the FRF figures (default: the last);
    ``band_hz``: the band of interest of the FRFs and the hammer check (``gvt frf --band``);
    ``identification``: ``gvt identify --json`` summaries (``daq.studies.report.identify.load_summaries``) for the
    "Identification" section."""
    import matplotlib

    matplotlib.use("Agg")  # before any section imports pyplot: no display, ever
    src = read_inputs(log, rig)
    confs = session_confirmations(src.results, log)
    figs = _figures(src, confs)
    parts = [*loss_tables(src.info), hits_table(src.hits)]
    frf = frf_section(log, src.rig, table, channel=frf_channel, band_hz=band_hz, rig_note=src.rig_note)
    parts += frf.tables
    figs += [(name, png(fig)) for name, fig in frf.figures]
    id_parts, id_figs = _identification(identification)
    parts += [*id_parts, *detection_tables(src.results, src.source), confirmations_table(confs), warnings_table(src.results)]
    session = src.reader.metadata().get("gvtlink.session", {})
    head = header(log, src.info["health"], session, src.rig.name if src.rig else "unknown", src.source)
    Path(out).write_text(document(head, parts, figs), encoding="utf-8")
    return ReportSummary(Path(out), figures=[name for name, _ in figs] + id_figs, tables=_titles(parts),
                         results_from=src.source, rig_note=src.rig_note, frf_absent=frf.absent)  # fmt: skip


def _figures(src: ReportInputs, confs: list[dict]) -> list[tuple[str, str]]:
    """The session's figures in page order, each ``(title, PNG data URI)`` drawn once; a figure with nothing to
    show is left out (the FRF figures follow, from their section)."""
    rq = src.results.get(layout.RQ_TOPIC, [])
    modal = src.results.get(layout.MODAL_TOPIC, [])
    ir = src.results.get(layout.IR_EVENTS_TOPIC, [])
    drawn = [
        signals_figure(src.reader, src.streams, src.setup, src.hits),
        rq_figure(rq, modal, ir),
        rqfep_figure(rq, modal),
        wavelet_figure(src.reader, src.streams, src.setup, src.hits, src.fs),
        pom_figure(src.reader, src.streams, src.setup, ir),
        slow_flow_figure(confs),
    ]
    return [f for f in drawn if f is not None]


def _identification(identification: list | None) -> tuple[list[str], list[str]]:
    """The "Identification" section's parts (heading first) and figure names; nothing without summaries."""
    if not identification:
        return [], []
    id_parts, id_figs = identify_section(identification, table)
    return ["<h2>Identification</h2>", *id_parts], id_figs


def _titles(parts: list[str]) -> list[str]:
    """The title of every part that opens with a heading: the tables ``gvt report`` counts."""
    return [p.split("</h2>")[0][4:] for p in parts if p.startswith("<h2>")]
