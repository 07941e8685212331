"""The FRF section of ``gvt report``: FRFs, coherence, hammer spectra, averages, refused hits and modes.

What an impact test exists to produce (issue 20, item 3), from the same code as ``gvt frf`` and ``gvt modal``
(:func:`daq.studies.frf.frf_from_log`, :func:`daq.studies.modal.modal_from_frf`), so the report and the verbs agree:

- FRF magnitude and phase of the driving point (the response at the hammer's DOF) and one chosen response,
- their coherence (a dip below 1 at a peak means noise or nonlinearity there; Ewins, *Modal Testing*, 2000, §4.3),
- the force spectrum of every checked hit with its −10 dB point against the band of interest (a hit whose
  −10 dB point is below the band does not excite it enough: Ewins §3.9, Avitabile, *Modal Testing*, 2017, ch. 4),
- the averages count, the hits refused for the FRFs with their reasons, and the identified modes paired by
  MAC with the rig's FE modes (Allemang, *The Modal Assurance Criterion*, 2003).

Without a rig, without hits, or without an accepted hit the section says why it is absent: a report never
fails for it. Figures are returned as ``(title, Figure)``; the caller renders each exactly once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import BadInput

TITLE = "FRFs, coherence and modal parameters"
MODAL_F_LO = 2.0  # Hz: below it a free-free beam's rigid-body motion, not its modes (gvt modal's default)


@dataclass
class FRFSection:
    """Tables (HTML), figures ``(title, Figure)`` and, when the FRFs are absent, why."""

    tables: list[str] = field(default_factory=list)
    figures: list[tuple[str, object]] = field(default_factory=list)
    absent: str | None = None


def frf_section(log: str | Path, rig, table, *, channel: str | None = None, band_hz: float | None = None,
                rig_note: str | None = None) -> FRFSection:  # fmt: skip
    """The section for ``log``; ``table(title, cols, rows, empty)`` renders HTML tables (report's ``_table``)."""
    if rig is None:
        return _absent(table, f"no rig ({rig_note or 'the log carries no rig attachment'}); give one with --rig")
    from daq.studies.frf import frf_from_log

    try:
        run = frf_from_log(log, rig, band_hz=band_hz)
    except BadInput as exc:
        return _absent(table, str(exc))
    sec = FRFSection()
    sec.tables.append(table("FRF averages", AVG_COLS, _avg_rows(run)))
    refused = [[h["hit"], _num(h["t_s"]), _num(h["peak_force_N"], ".0f"), h["reason"]] for h in run.hits
               if h["verdict"] != "accepted"]  # fmt: skip
    sec.tables.append(table("hits refused for the FRFs", REFUSED_COLS, refused, "none: every hit accepted"))
    if run.frf is None:
        sec.absent = f"no hit was accepted for the FRFs ({len(run.hits)} refused)"
        sec.tables.append(table(TITLE, [], [], f"absent: {sec.absent}"))
    else:
        shown = shown_outputs(run.frf.outputs, run.driving.get(run.frf.references[0]), channel)
        sec.figures += [("FRF magnitude and phase", frf_figure(run, shown)), ("coherence", coherence_figure(run, shown))]
        sec.tables.append(_modal_table(run.frf, rig, run.band_hz, table, run.driving))
    if run.spectra:
        sec.figures.append(("hammer spectra", spectra_figure(run)))
    return sec


def _absent(table, why: str) -> FRFSection:
    return FRFSection(tables=[table(TITLE, [], [], f"absent: {why}")], absent=why)


REFUSED_COLS = ["#", "t [s]", "peak [N]", "reason"]
AVG_COLS = ["reference", "estimator", "units", "averages", "hits refused", "record [s]", "Δf [Hz]", "exp. window τ [s]"]
MODE_COLS = ["mode", "f [Hz]", "ζ [%]", "MPC", "MPD [°]", "FE mode", "f_FE [Hz]", "Δf [%]", "ζ_FE [%]", "MAC"]


def _num(x, fmt: str = ".3f") -> str:
    return "—" if x is None or not np.isfinite(float(x)) else format(float(x), fmt)


def _avg_rows(run) -> list[list]:
    """One row per reference (the hammer, or each hit point of a roving-hammer plan); the refused hits on the first."""
    f = run.frf
    n_ref = sum(h["verdict"] != "accepted" for h in run.hits)
    tail = [_num(run.record_s), _num(1.0 / run.record_s, ".4f"), _num(run.tau_s) if run.tau_s else "none"]
    if f is None:
        return [["—", "—", "—", 0, n_ref, *tail]]
    return [[r, f.kind, f.units, int(c), n_ref if k == 0 else "", *tail]
            for k, (r, c) in enumerate(zip(f.references, f.n_averages, strict=True))]  # fmt: skip


def shown_outputs(outputs: list[str], driving: str | None, channel: str | None) -> list[str]:
    """The driving point (or the first response if the hammer's DOF has no sensor) and ``channel``
    (default: the last response, on a beam the end farthest from the first sensor); no duplicates."""
    if channel is not None and channel not in outputs:
        raise BadInput(f"--frf-channel {channel!r}: not a response of the FRFs; they are {', '.join(outputs)}")
    first = driving or outputs[0]
    other = channel or next((o for o in reversed(outputs) if o != first), first)
    return list(dict.fromkeys([first, other]))


def _modal_table(frf, rig, band_hz: float, table, driving: dict[str, str] | None = None) -> str:
    from daq.studies.modal import modal_from_frf

    title = "identified modes (pLSCF + LSFD, window damping removed) against the FE modes"
    try:
        run = modal_from_frf(frf, rig, MODAL_F_LO, min(band_hz, float(frf.freq[-1])), source="report", driving=driving)
    except (BadInput, np.linalg.LinAlgError) as exc:
        return table(title, MODE_COLS, [], f"none: {exc}")
    rows = [[r["mode"], _num(r["freq_hz"]), _num(100 * r["zeta"]), _num(r["mpc"]), _num(r["mpd_deg"], ".2f"),
             r.get("fe_mode") or "—", _num(r.get("fe_freq_hz")),
             _num(100 * r["freq_error"], "+.3f") if "freq_error" in r else "—",
             _num(100 * r["fe_zeta"]) if "fe_zeta" in r else "—", _num(r.get("mac"))] for r in run.rows]  # fmt: skip
    return table(title, MODE_COLS, rows, "none: no stable pole in the band")


def frf_figure(run, shown: list[str]):
    """|H| (log) and phase of the ``shown`` responses against frequency, one figure of two axes."""
    import matplotlib.pyplot as plt

    f = run.frf
    fig, (a_mag, a_ph) = plt.subplots(2, 1, figsize=(11, 6), sharex=True, layout="constrained")
    for name in shown:
        h = f.H[f.outputs.index(name), 0]
        a_mag.semilogy(f.freq, np.abs(h), lw=0.9, label=name)
        a_ph.plot(f.freq, np.degrees(np.angle(h)), lw=0.9, label=name)
    a_mag.set_ylabel(f"|{f.kind}| [{f.units}]")
    a_mag.set_title(f"{f.kind} {f.quantity}, reference {f.references[0]}, {int(f.n_averages[0])} averages (first: driving point)")
    a_mag.legend(fontsize=8)
    a_ph.set_ylabel("phase [°]")
    a_ph.set_xlabel("frequency [Hz]")
    return fig


def coherence_figure(run, shown: list[str]):
    import matplotlib.pyplot as plt

    f = run.frf
    fig, ax = plt.subplots(figsize=(11, 3), layout="constrained")
    for name in shown:
        ax.plot(f.freq, f.coherence[f.outputs.index(name), 0], lw=0.9, label=name)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("coherence γ²")
    ax.set_xlabel("frequency [Hz]")
    ax.set_title(f"ordinary coherence over {int(f.n_averages[0])} averages (1 with one average: no information)")
    ax.legend(fontsize=8)
    return fig


def spectra_figure(run):
    """Each checked hit's force spectrum (dB re DC) with its −10 dB point marked, the band as a dashed line."""
    import matplotlib.pyplot as plt

    from analysis.hammer import level_db

    bw = {h["hit"]: (h.get("checks") or {}).get("bw10_hz") for h in run.hits}
    fig, ax = plt.subplots(figsize=(11, 4), layout="constrained")
    for hit, fr, mag in run.spectra:
        (line,) = ax.plot(fr, level_db(mag), lw=0.8, label=f"hit {hit}: −10 dB at {_num(bw.get(hit), '.0f')} Hz")
        if bw.get(hit) is not None:
            ax.plot([bw[hit]], [-10.0], "o", ms=4, color=line.get_color())
    ax.axvline(run.band_hz, color="k", ls="--", lw=0.8, label=f"band {run.band_hz:g} Hz")
    ax.axhline(-10, color="grey", ls=":", lw=0.8)
    ax.set_ylim(-40, 5)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("force spectrum [dB re DC]")
    ax.set_title("hammer spectra: a hit's −10 dB point must lie beyond the band")
    ax.legend(fontsize=6, ncol=3, loc="lower left")
    return fig


__all__ = ["FRFSection", "coherence_figure", "frf_figure", "frf_section", "shown_outputs", "spectra_figure"]
