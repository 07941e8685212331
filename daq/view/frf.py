"""Live FRFs in the rerun view: the curves the FRF lane (daq/lanes/frf.py) sends after each accepted hit.

rerun has no x-y plot archetype for a curve over frequency, so each curve is a ``LineStrips2D`` in a 2-D
view, x = frequency in Hz and y downwards (rerun's 2-D y points down, as the RQ-FEP and POM views here):

| entity | y | content |
|---|---|---|
| ``/frf/magnitude/<channel>`` | −10 × dB re 1 unit | \\|H\\| of the driving point and the shown response |
| ``/frf/phase/<channel>`` | −phase / deg | phase of the same |
| ``/frf/coherence/<channel>`` | −1000 × γ² | ordinary coherence (0…1 → 0…−1000: the same span as 100 dB) |
| ``/frf/hammer`` | −10 × dB re DC | the hit's force spectrum up to twice the band, a mark at the band |
| ``/frf/averages`` | Scalars on the time line | hits averaged after each update |

Each update replaces the curves at the hit's time, so the view shows the latest average at the cursor.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from daq.view.recording import TIMELINE, color

FRF = "/frf"
MAGNITUDE = FRF + "/magnitude"
PHASE = FRF + "/phase"
COHERENCE = FRF + "/coherence"
HAMMER = FRF + "/hammer"
AVERAGES = FRF + "/averages"
Y_PER_DB = 10.0  # display units per dB
Y_PER_COHERENCE = 1000.0


def _strip(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    ok = np.isfinite(y)
    return np.stack([np.asarray(x, float)[ok], -np.asarray(y, float)[ok]], axis=1)


def _db(v: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.maximum(np.abs(v), 1e-300))


def log_frf(rec: rr.RecordingStream, c: dict) -> list[str]:
    """Draw one update ``c`` (daq.lanes.frf.view_curves); returns the entity paths it logged."""
    rec.set_time(TIMELINE, duration=float(c["t_s"]))
    f = np.asarray(c["freq"], float)
    paths = []
    for k, (name, cv) in enumerate(c["curves"].items()):
        what = "driving point " if name == c.get("driving_point") else ""
        label = f"{what}{name}, {c['averages']} averages"
        for path, y, unit in ((f"{MAGNITUDE}/{name}", Y_PER_DB * _db(cv["mag"]), f"y: -{Y_PER_DB:g}/dB re 1 {c['units']}"),
                              (f"{PHASE}/{name}", np.asarray(cv["phase_deg"], float), "y: -deg"),
                              (f"{COHERENCE}/{name}", Y_PER_COHERENCE * np.asarray(cv["coherence"], float),
                               f"y: -{Y_PER_COHERENCE:g} x coherence")):  # fmt: skip
            rec.log(path, rr.LineStrips2D([_strip(f, y)], colors=[color(k)], labels=[f"{label} ({unit}; x: Hz)"], radii=[0.8]))
            paths.append(path)
    ff, db = np.asarray(c["force_freq"], float), np.asarray(c["force_db"], float)
    band = float(c["band_hz"])
    mark = np.array([[band, 0.0], [band, Y_PER_DB * 40.0]])
    rec.log(HAMMER, rr.LineStrips2D([_strip(ff, Y_PER_DB * db), mark], colors=[(30, 30, 30), (200, 0, 0)],
                                    labels=[f"force spectrum (y: -{Y_PER_DB:g}/dB re DC; x: Hz)", f"band {band:g} Hz"],
                                    radii=[0.8, 0.5]))  # fmt: skip
    rec.log(AVERAGES, rr.Scalars([float(c["averages"])]))
    return [*paths, HAMMER, AVERAGES]
