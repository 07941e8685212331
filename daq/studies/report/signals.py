"""The report's first figure: the hammer force with every hit marked by its verdict, and the driving-point response.

Drawn as min/max envelopes: a 60 s log at 16 kHz is a million points a channel, more than a PNG of 11 inches
can show; the envelope keeps every peak (a clipped or double hit stays visible) at 2000 points.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from daq.studies.report.inputs import stream_with
from daq.studies.report.page import png

if TYPE_CHECKING:
    from daq.log.reader import LogReader
    from daq.view.setup import ViewSetup

TITLE = "signals"
VERDICT_COLORS = {"accepted": "tab:green", "overload": "tab:red", "double_hit": "tab:orange"}


def signals_figure(reader: LogReader, streams: dict, setup: ViewSetup | None, hits: list[dict]) -> tuple[str, str] | None:
    """``(title, PNG data URI)``, or None when the log records neither the hammer nor the driving point."""
    import matplotlib.pyplot as plt

    hammer = setup.hammer if setup else None
    dp = setup.wavelet_channel if setup else None
    ham_stream = stream_with(streams, hammer)
    dp_stream = stream_with(streams, dp)
    if not (ham_stream or dp_stream):
        return None
    fig, axes = plt.subplots(2, 1, figsize=(11, 5), sharex=True)
    for ax, stream, ch, unit in ((axes[0], ham_stream, hammer, "N"), (axes[1], dp_stream, dp, "m/s²")):
        _envelope_trace(ax, reader, stream, ch, unit)
    _mark_hits(axes[0], hits)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title("hammer force (min/max envelope) with hits by verdict; driving-point response")
    return TITLE, png(fig)


def _envelope_trace(ax, reader: LogReader, stream: str | None, ch: str | None, unit: str) -> None:
    """One channel's min/max envelope on ``ax``, or "not recorded" when no stream holds it."""
    if stream is None:
        ax.text(0.5, 0.5, "not recorded", ha="center", transform=ax.transAxes)
        return
    d = reader.read_stream(stream, [ch])
    t, lo, hi = _envelope(d.t, d.data[:, 0].astype(float))
    ax.fill_between(t, lo, hi, color="0.3", lw=0)
    ax.set_ylabel(f"{ch} [{unit}]")


def _mark_hits(ax, hits: list[dict]) -> None:
    """Each hit at its time and peak force, coloured and labelled by its verdict."""
    for h in hits:
        c = VERDICT_COLORS.get(h.get("verdict"), "tab:gray")
        ax.plot(h["t_s"], h.get("peak_force_N", 0.0), "o", color=c)
        ax.annotate(f"{h.get('hit', '')} {h.get('verdict', '')}", (h["t_s"], h.get("peak_force_N", 0.0)), fontsize=7)


def _envelope(t: np.ndarray, y: np.ndarray, n: int = 2000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About ``n`` bins of ``y``: each bin's first time, minimum and maximum."""
    b = max(1, y.size // n)
    m = (y.size // b) * b
    yy = y[:m].reshape(-1, b)
    return t[:m].reshape(-1, b)[:, 0], yy.min(axis=1), yy.max(axis=1)
