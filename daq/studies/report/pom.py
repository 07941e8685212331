"""The shapes of the IR events: the POMs (seed eq. 2.13) of the acceleration over each event, along the structure.

An internal resonance is energy moving between modes; the POMs over the event show which shapes carry it and
their POVs how much. The first six events are drawn, one panel each.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from daq.studies.report.page import png

if TYPE_CHECKING:
    from daq.log.reader import LogReader
    from daq.view.setup import ViewSetup

TITLE = "POM shapes over IR events (acceleration POD)"
MAX_EVENTS = 6


def pom_figure(reader: LogReader, streams: dict, setup: ViewSetup | None, ir: list[dict]) -> tuple[str, str] | None:
    """``(title, PNG)``, or None without IR events, a rig, or one stream holding all its sensors."""
    sensor_stream = next(
        (n for n, i in streams.items() if setup and setup.sensors and all(c in i.channels for c in setup.sensors)), None
    )
    if not (ir and sensor_stream and setup is not None):
        return None
    import matplotlib.pyplot as plt

    shown = ir[:MAX_EVENTS]
    fig, axes = plt.subplots(1, len(shown), figsize=(3.2 * len(shown), 3), squeeze=False)
    for ax, e in zip(axes[0], shown, strict=True):
        _event_poms(ax, reader, sensor_stream, setup, e)
    return TITLE, png(fig)


def _event_poms(ax, reader: LogReader, stream: str, setup: ViewSetup, e: dict) -> None:
    """The POMs of the sensors over event ``e`` (at least 10 ms) against position, labelled with their POV share."""
    from analysis.pod import pod

    x = np.asarray(setup.sensor_x)
    order = np.argsort(x)
    d = reader.read_stream(stream, list(setup.sensors), start=e["start_s"], end=max(e["end_s"], e["start_s"] + 0.01))
    if d.data.shape[0] >= 2:
        poms, povs = pod(d.data.astype(float))
        for k in range(min(setup.n_nnm, poms.shape[1])):
            ax.plot(x[order], poms[order, k], "-o", ms=2, label=f"POM{k + 1} {100 * povs[k] / max(povs.sum(), 1e-300):.0f} %")
    ax.set_title(f"IR {e.get('id', '')} {e.get('ratio', '')} {e['start_s']:.2f}–{e['end_s']:.2f} s", fontsize=8)
    ax.set_xlabel("sensor position [m]")
    ax.legend(fontsize=6)
