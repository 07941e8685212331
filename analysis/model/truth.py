"""Ground-truth readings of simulator output (not estimators for measured data).

The NNM1 frequency along a free decay is read from the zero crossings of the first linear modal
coordinate, which the simulator knows exactly; the analysis stage must estimate it from sensors.
"""

from __future__ import annotations

import numpy as np

from analysis.model.beam import FloatArray


def zero_crossing_frequency(signal: FloatArray, t: FloatArray, centres: FloatArray, half_width: float) -> FloatArray:
    """Mean frequency (Hz) from zero-crossing intervals within ``centre ± half_width``; NaN where none.

    Crossing times are linearly interpolated between samples, so the estimate is not quantised to the
    sample period.
    """
    s = np.asarray(signal, dtype=float)
    t = np.asarray(t, dtype=float)
    i = np.nonzero(np.signbit(s[:-1]) != np.signbit(s[1:]))[0]
    denom = s[i] - s[i + 1]
    tz = t[i] + (t[i + 1] - t[i]) * np.where(denom != 0, s[i] / np.where(denom != 0, denom, 1.0), 0.0)
    if tz.size < 2:
        return np.full(len(np.atleast_1d(centres)), np.nan)
    mid = 0.5 * (tz[1:] + tz[:-1])
    f = 0.5 / np.diff(tz)
    out = []
    for c in np.atleast_1d(centres):
        m = np.abs(mid - c) <= half_width
        out.append(float(np.mean(f[m])) if np.any(m) else np.nan)
    return np.asarray(out)
