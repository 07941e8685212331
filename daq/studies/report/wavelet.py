"""The Morlet wavelet spectrum (seed eq. 3.2, amplitude normalisation) of the strongest accepted hit at the
driving point: half a second from 20 ms before the hit, where a nonlinear structure's frequencies move most."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from daq.studies.report.inputs import stream_with
from daq.studies.report.page import png

if TYPE_CHECKING:
    from daq.log.reader import LogReader
    from daq.view.setup import ViewSetup

TITLE = "wavelet spectrum"


def wavelet_figure(
    reader: LogReader, streams: dict, setup: ViewSetup | None, hits: list[dict], fs: float
) -> tuple[str, str] | None:
    """``(title, PNG)``, or None without hits, a rig, the driving point on record or 64 samples of it."""
    good = [h for h in hits if h.get("verdict") == "accepted"] or hits
    dp = setup.wavelet_channel if setup else None
    dp_stream = stream_with(streams, dp)
    if not (good and dp_stream and setup is not None):
        return None
    h = max(good, key=lambda h: h.get("peak_force_N", 0.0))
    t0 = max(0.0, h["t_s"] - 0.02)
    d = reader.read_stream(dp_stream, [dp], start=t0, end=t0 + 0.5)
    if d.data.shape[0] <= 64:
        return None
    import matplotlib.pyplot as plt

    from analysis.wavelet import morlet_cwt

    freqs = np.geomspace(setup.f_min_hz, setup.f_max_hz, 96)
    z = np.abs(morlet_cwt(d.data[:, 0].astype(float), fs, freqs, normalization="amplitude"))
    step = max(1, z.shape[1] // 800)
    fig, ax = plt.subplots(figsize=(11, 4))
    ax.pcolormesh(d.t[::step], freqs, z[:, ::step], shading="auto", cmap="viridis")
    ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title(f"Morlet |Z| (amplitude normalisation) of {dp}, hit {h.get('hit', '')} ({h.get('peak_force_N', 0):.0f} N)")
    return TITLE, png(fig)
