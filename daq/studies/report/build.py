"""``gvt report LOG --out report.html``: a static, self-contained session report readable without rerun.

One HTML file, PNG plots embedded as base64 data URIs (matplotlib, Agg backend — no display, no network,
no external assets), and tables of what a test engineer signs off: hits and verdicts, loss counters
(gaps, writer overruns, driver events by kind), the near-live analysis (IR events, window-robust RQ
spikes as supporting evidence, warnings; each output with its measured precision, ``daq/view/scores.py``),
confirmations of the background lane (``/analysis/confirmations``, or "none") and the
plots: hammer force with hits, driving-point response, RQ per NNM against time with IR events, modal
energies, the RQ-FEP (RQ frequency against windowed modal energy, seed Ch. 4), a Morlet wavelet
spectrum of a hit record (eq. 3.2, amplitude normalisation), POM shapes of IR events and slow-flow phase
trajectories of confirmations; and the FRF section (``daq/studies/report/frf.py``): FRF magnitude and phase, coherence,
hammer spectra with their −10 dB points, averages, refused hits and the modes against the FE modes. Each figure
is drawn once (:func:`daq.studies.report.page.png`).

Results come from the log's ``/analysis/*`` topics, or from a batch run of the same kernels when the
session did not run the analysis (:func:`daq.studies.analyze.rrd.log_results`).
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from daq.log import layout
from daq.log.reader import LogReader
from daq.log.tools import log_info
from daq.studies.report.page import num, png, table


@dataclass
class ReportSummary:
    path: Path
    figures: list[str] = field(default_factory=list)
    tables: list[str] = field(default_factory=list)
    results_from: str = "log"
    rig_note: str | None = None  # why the log's attached rig was not used (the report is drawn without it)
    frf_absent: str | None = None  # why the report has no FRFs (no rig, no hits, no accepted hit); None: it has them


def _envelope(t: np.ndarray, y: np.ndarray, n: int = 2000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = max(1, y.size // n)
    m = (y.size // b) * b
    yy = y[:m].reshape(-1, b)
    return t[:m].reshape(-1, b)[:, 0], yy.min(axis=1), yy.max(axis=1)


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

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from daq.log.rig import AnalyzeError, rig_from_log
    from daq.studies.analyze.rrd import log_results
    from daq.view.logger import ViewSetup

    reader = LogReader(log)
    info = log_info(log)
    rig_note = None
    if rig is None:
        try:
            rig = rig_from_log(reader)
        except AnalyzeError as exc:
            rig, rig_note = None, str(exc)
    res, source = log_results(reader, rig)
    summary = ReportSummary(Path(out), results_from=source, rig_note=rig_note)
    hits = reader.json_messages(layout.HITS_TOPIC)
    streams = reader.streams()
    fs = next(iter(streams.values())).sample_rate if streams else 1.0
    setup = ViewSetup.from_rig(rig, {n: tuple(i.channels) for n, i in streams.items()}, fs) if rig is not None else None
    parts: list[str] = []
    figs: list[tuple[str, str]] = []

    # --- signals: hammer with hits, driving point ---------------------------------------------------
    hammer = setup.hammer if setup else None
    dp = setup.wavelet_channel if setup else None
    ham_stream = next((n for n, i in streams.items() if hammer in i.channels), None)
    dp_stream = next((n for n, i in streams.items() if dp in i.channels), None)
    if ham_stream or dp_stream:
        fig, axes = plt.subplots(2, 1, figsize=(11, 5), sharex=True)
        for ax, stream, ch, unit in ((axes[0], ham_stream, hammer, "N"), (axes[1], dp_stream, dp, "m/s²")):
            if stream is None:
                ax.text(0.5, 0.5, "not recorded", ha="center", transform=ax.transAxes)
                continue
            d = reader.read_stream(stream, [ch])
            t, lo, hi = _envelope(d.t, d.data[:, 0].astype(float))
            ax.fill_between(t, lo, hi, color="0.3", lw=0)
            ax.set_ylabel(f"{ch} [{unit}]")
        colors = {"accepted": "tab:green", "overload": "tab:red", "double_hit": "tab:orange"}
        for h in hits:
            c = colors.get(h.get("verdict"), "tab:gray")
            axes[0].plot(h["t_s"], h.get("peak_force_N", 0.0), "o", color=c)
            axes[0].annotate(f"{h.get('hit', '')} {h.get('verdict', '')}", (h["t_s"], h.get("peak_force_N", 0.0)), fontsize=7)
        axes[1].set_xlabel("time [s]")
        axes[0].set_title("hammer force (min/max envelope) with hits by verdict; driving-point response")
        figs.append(("signals", png(fig)))

    # --- RQ per NNM with IR events, modal energies -------------------------------------------------
    rq = res.get(layout.RQ_TOPIC, [])
    modal = res.get(layout.MODAL_TOPIC, [])
    ir = res.get(layout.IR_EVENTS_TOPIC, [])
    if rq or modal:
        fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
        if rq:
            t = np.array([r["t_end_s"] for r in rq])
            f = np.array([r["rq_hz"] for r in rq], float)
            for k in range(f.shape[1]):
                axes[0].plot(t, f[:, k], ".", ms=2, label=f"NNM{k + 1}")
            axes[0].set_yscale("log")
            axes[0].legend(fontsize=7, loc="upper right")
        for e in ir:
            for ax in axes:
                ax.axvspan(e["start_s"], e["end_s"], color="tab:purple", alpha=0.15)
            axes[0].annotate(f"IR {e.get('id', '')} {e.get('ratio', '')}", (e["start_s"], e.get("f_recv_hz", 1.0)), fontsize=7)
        axes[0].set_ylabel("RQ frequency [Hz]")
        axes[0].set_title("RQ per NNM (base grid windows); IR events shaded")
        if modal:
            tm = np.array([m["t_end_s"] for m in modal])
            e = np.array([m["modal_energy_J"] for m in modal], float)
            for k in range(e.shape[1]):
                axes[1].semilogy(tm, np.where(e[:, k] > 0, e[:, k], np.nan), lw=0.8, label=f"mode {k + 1}")
            axes[1].legend(fontsize=7, loc="upper right")
        axes[1].set_ylabel("modal energy [J]")
        axes[1].set_xlabel("time [s]")
        figs.append(("RQ and modal energies", png(fig)))
    if rq and modal:
        from daq.view.recording import rqfep_points

        tm = np.array([m["t_end_s"] for m in modal])
        et = np.array([np.nansum(m["modal_energy_J"]) for m in modal])
        _t, le, f = rqfep_points(rq, tm, et)
        if f.size:
            fig, ax = plt.subplots(figsize=(7, 4.5))
            for k in range(f.shape[1]):
                ax.semilogx(10.0**le, f[:, k], ".", ms=3, label=f"NNM{k + 1}")
            ax.set_yscale("log")
            ax.set_xlabel("windowed total modal energy [J]")
            ax.set_ylabel("RQ frequency [Hz]")
            ax.set_title("RQ-FEP (RQ frequency against energy)")
            ax.legend(fontsize=7)
            figs.append(("RQ-FEP", png(fig)))

    # --- wavelet spectrum of the strongest accepted hit at the driving point --------------------------
    good = [h for h in hits if h.get("verdict") == "accepted"] or hits
    if good and dp_stream and setup is not None:
        from analysis.wavelet import morlet_cwt

        h = max(good, key=lambda h: h.get("peak_force_N", 0.0))
        t0 = max(0.0, h["t_s"] - 0.02)
        d = reader.read_stream(dp_stream, [dp], start=t0, end=t0 + 0.5)
        if d.data.shape[0] > 64:
            freqs = np.geomspace(setup.f_min_hz, setup.f_max_hz, 96)
            z = np.abs(morlet_cwt(d.data[:, 0].astype(float), fs, freqs, normalization="amplitude"))
            step = max(1, z.shape[1] // 800)
            fig, ax = plt.subplots(figsize=(11, 4))
            ax.pcolormesh(d.t[::step], freqs, z[:, ::step], shading="auto", cmap="viridis")
            ax.set_yscale("log")
            ax.set_xlabel("time [s]")
            ax.set_ylabel("frequency [Hz]")
            ax.set_title(
                f"Morlet |Z| (amplitude normalisation) of {dp}, hit {h.get('hit', '')} ({h.get('peak_force_N', 0):.0f} N)"
            )
            figs.append(("wavelet spectrum", png(fig)))

    # --- POM shapes of IR events, slow-flow trajectories ----------------------------------------------
    sensor_stream = next(
        (n for n, i in streams.items() if setup and setup.sensors and all(c in i.channels for c in setup.sensors)), None
    )
    if ir and sensor_stream and setup is not None:
        from analysis.pod import pod

        shown = ir[:6]
        fig, axes = plt.subplots(1, len(shown), figsize=(3.2 * len(shown), 3), squeeze=False)
        x = np.asarray(setup.sensor_x)
        order = np.argsort(x)
        for ax, e in zip(axes[0], shown, strict=True):
            d = reader.read_stream(
                sensor_stream, list(setup.sensors), start=e["start_s"], end=max(e["end_s"], e["start_s"] + 0.01)
            )
            if d.data.shape[0] >= 2:
                poms, povs = pod(d.data.astype(float))
                for k in range(min(setup.n_nnm, poms.shape[1])):
                    ax.plot(
                        x[order], poms[order, k], "-o", ms=2, label=f"POM{k + 1} {100 * povs[k] / max(povs.sum(), 1e-300):.0f} %"
                    )
            ax.set_title(f"IR {e.get('id', '')} {e.get('ratio', '')} {e['start_s']:.2f}–{e['end_s']:.2f} s", fontsize=8)
            ax.set_xlabel("sensor position [m]")
            ax.legend(fontsize=6)
        figs.append(("POM shapes over IR events (acceleration POD)", png(fig)))
    confs = res.get(layout.CONFIRMATIONS_TOPIC, [])
    if not confs:  # gvt confirm / gvt replay write theirs next to the log (docs/decisions.md D22)
        from daq.studies.confirm import read_confirmations

        confs = read_confirmations(log, include_log=False)
    with_traj = [c for c in confs if (c.get("trajectory") or {}).get("phi")]
    if with_traj:
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for c in with_traj:
            tr = c["trajectory"]
            ax.plot(tr["phi"], tr["phi_dot"], "-", label=f"event {c.get('event_id')} {c.get('ratio') or ''} {c.get('status')}")
        ax.set_xlabel("φ [rad]")
        ax.set_ylabel("φ̇ [rad/s]")
        ax.set_title("slow-flow phase trajectories of confirmations")
        ax.legend(fontsize=7)
        figs.append(("slow flow", png(fig)))

    # --- tables -----------------------------------------------------------------------------------------
    meta = reader.metadata()
    sess = meta.get("gvtlink.session", {})
    parts.append(table("streams and loss counters", STREAM_COLS, [_stream_row(s) for s in info["streams"]]))
    ev_rows = [[k, v] for k, v in sorted(info["events"].items())]
    parts.append(table("driver and session events by kind", ["kind", "count"], ev_rows, "no events (no gaps, CRC errors)"))
    parts.append(table("hits and verdicts", HIT_COLS, [_hit_row(h) for h in hits]))
    from daq.studies.report.frf import frf_section

    sec = frf_section(log, rig, table, channel=frf_channel, band_hz=band_hz, rig_note=rig_note)
    parts += sec.tables
    figs += [(name, png(fig)) for name, fig in sec.figures]
    summary.frf_absent = sec.absent
    if identification:
        from daq.studies.report.identify import identify_section

        id_parts, id_figs = identify_section(identification, table)
        parts += ["<h2>Identification</h2>", *id_parts]
        summary.figures += id_figs
    from daq.view.scores import MODAL_EXCHANGE, ROBUST_RQ_SPIKES, SCORE_COLS, score_note, score_rows

    # what each output is worth, measured on the simulator (issue 21): before the outputs themselves
    parts.append(table("detectors and their measured scores", SCORE_COLS, score_rows()))
    parts.append(table(f"internal-resonance events (near-live analysis, results from {source})", IR_COLS,
                        [_ir_row(k, e) for k, e in enumerate(ir)]))  # fmt: skip
    parts.append(f"<p class='note'>{html.escape(score_note(MODAL_EXCHANGE))}. Confidence: calibrated probability that "
                 "the event is a true major exchange; label conf.: that it is one with this m:n (docs/evaluation.md §6); "
                 "1:1 = receiving frequency near the giving mode's, a leak, not an m:n resonance.</p>")  # fmt: skip
    spikes = [[num(s["start_s"]), num(s["end_s"]), num(s.get("agreement"), ".2f")] for s in res.get(layout.RQ_SPIKES_TOPIC, [])]
    parts.append(table("window-robust RQ spikes (supporting evidence, not a detector)", ["start [s]", "end [s]", "agreement"],
                        spikes))  # fmt: skip
    parts.append(f"<p class='note'>{html.escape(score_note(ROBUST_RQ_SPIKES))}.</p>")
    parts.append(table("confirmations (WBEMD + slow flow)", CONF_COLS, [_conf_row(c) for c in confs],
                        "none (no /analysis/confirmations in this log)"))  # fmt: skip
    warns = [[w.get("kind"), w.get("message")] for w in res.get(layout.WARNINGS_TOPIC, [])]
    parts.append(table("analysis warnings", ["kind", "message"], warns))
    summary.tables = [p.split("</h2>")[0][4:] for p in parts if p.startswith("<h2>")]
    summary.figures = [name for name, _ in figs] + summary.figures
    header = (
        f"<h1>gvtlink session report</h1><p>log <code>{html.escape(str(log))}</code> · health: {html.escape(info['health'])} · "
        f"session {html.escape(json.dumps(sess.get('session', '')))} · rig {html.escape(rig.name if rig else 'unknown')} · "
        f"analysis results from {source}</p>"
    )
    fig_html = "".join(f"<h2>{html.escape(n)}</h2><img alt='{html.escape(n)}' src='{src}'>" for n, src in figs)
    doc = f"""<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>gvtlink report</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1200px}} table{{border-collapse:collapse;font-size:13px}}
td,th{{border:1px solid #bbb;padding:2px 6px;text-align:right}} th{{background:#eee}} img{{max-width:100%}}
.none{{color:#666;font-style:italic}}</style></head><body>{header}{"".join(parts)}{fig_html}</body></html>"""
    Path(out).write_text(doc, encoding="utf-8")
    return summary


STREAM_COLS = ["stream", "channels", "fs [Hz]", "duration [s]", "samples", "gaps", "missing samples", "writer overruns",
               "undecodable blocks"]  # fmt: skip
HIT_COLS = ["#", "t [s]", "peak [N]", "width [ms]", "energy [J]", "verdict", "reason"]
IR_COLS = ["#", "start [s]", "end [s]", "modes", "m:n", "f give/recv [Hz]", "gain", "confidence", "label conf.", "source"]
CONF_COLS = ["event", "status", "evidence", "m:n", "start [s]", "end [s]", "orthogonality", "IMF freqs [Hz]",
             "candidates (captured)", "why"]


def _stream_row(s: dict) -> list:
    return [s["stream"], len(s["channels"]), num(s["sample_rate"], "g"), num(s["duration_s"]), s["samples"], len(s["gaps"]),
            s["missing_samples"], s["overrun_samples"], s["undecodable_blocks"]]  # fmt: skip


def _hit_row(h: dict) -> list:
    return [h.get("hit"), num(h.get("t_s")), num(h.get("peak_force_N"), ".0f"), num(1000 * h.get("pulse_width_s", 0), ".2f"),
            num(h.get("input_energy_J"), ".3g"), h.get("verdict"), h.get("reason", "")]  # fmt: skip


def _ir_row(k: int, e: dict) -> list:
    return [e.get("id", k), num(e["start_s"]), num(e["end_s"]), "→".join(str(m) for m in e.get("modes", [])), e.get("ratio"),
            f"{num(e.get('f_give_hz'), '.1f')} / {num(e.get('f_recv_hz'), '.1f')}", num(e.get("gain"), ".1f"),
            num(e.get("confidence"), ".2f"), num(e.get("label_confidence"), ".2f"), e.get("source", "")]  # fmt: skip


def _conf_row(c: dict) -> list:
    cands = "; ".join(f"{d.get('ratio')} {100 * d.get('captured_fraction', 0):.0f} %" for d in c.get("candidates") or [])
    freqs = ", ".join(num(f, ".1f") for f in c.get("imf_freqs_hz") or [])
    return [c.get("event_id"), c.get("status"), c.get("evidence") or "—", c.get("ratio") or "—", num(c.get("start_s")),
            num(c.get("end_s")), num(c.get("orthogonality_index"), ".3f"), freqs, cands, c.get("reason") or ""]  # fmt: skip
