"""Hammer force histories: the seed's half-sine pulse (eq. 4.1, L1211) or any sampled series.

The integrator needs the *mean* force over each integration step (so that the impulse, and hence the
input energy, is exact however the step falls on the pulse edges) and the force at the output
instants (for accelerations). Both are per unit amplitude; a batch scales them by its amplitudes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.model.beam import FloatArray


@dataclass(frozen=True)
class HalfSine:
    """``F(t) = peak * sin(pi (t - start) / duration)`` on ``[start, start + duration]``, else 0.

    Eq. 4.1 with ``H(0) = 1/2`` (eq. 3.16) — the value at the two edges is 0 either way.
    """

    peak: float
    duration: float
    start: float = 0.0

    def shape_at(self, t: FloatArray) -> FloatArray:
        """Force per unit peak at the instants ``t``."""
        tau = (np.asarray(t, dtype=float) - self.start) / self.duration
        inside = (tau >= 0.0) & (tau <= 1.0)
        return np.where(inside, np.sin(np.pi * np.clip(tau, 0.0, 1.0)), 0.0)

    def antiderivative(self, t: FloatArray) -> FloatArray:
        """Integral of the unit-peak pulse from -inf to ``t``."""
        T = self.duration
        a = np.clip(np.asarray(t, dtype=float), self.start, self.start + T)
        return (T / np.pi) * (1.0 - np.cos(np.pi * (a - self.start) / T))

    def shape_step_means(self, dt: float, n_steps: int) -> FloatArray:
        """Exact mean of the unit-peak pulse over each step ``[k dt, (k+1) dt]``."""
        return interval_means(self, np.arange(n_steps) * dt, np.arange(1, n_steps + 1) * dt)

    @property
    def end(self) -> float:
        return self.start + self.duration


@dataclass(frozen=True)
class ForceSeries:
    """A sampled force history (N), linearly interpolated; zero outside ``[t[0], t[-1]]``."""

    t: FloatArray
    force: FloatArray
    peak: float = 1.0

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError("force series time must be 1-D, increasing, with at least two samples")
        if np.asarray(self.force).shape != t.shape:
            raise ValueError("force series: time and force must have the same length")

    def shape_at(self, t: FloatArray) -> FloatArray:
        return np.interp(np.asarray(t, dtype=float), self.t, np.asarray(self.force, dtype=float), left=0.0, right=0.0)

    def antiderivative(self, t: FloatArray) -> FloatArray:
        """Exact integral of the piecewise-linear interpolant from ``t[0]`` to ``t``."""
        tt = np.asarray(self.t, dtype=float)
        ff = np.asarray(self.force, dtype=float)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (ff[1:] + ff[:-1]) * np.diff(tt))])
        x = np.clip(np.asarray(t, dtype=float), tt[0], tt[-1])
        i = np.clip(np.searchsorted(tt, x, side="right") - 1, 0, len(tt) - 2)
        frac = x - tt[i]
        slope = (ff[i + 1] - ff[i]) / (tt[i + 1] - tt[i])
        return cum[i] + ff[i] * frac + 0.5 * slope * frac**2

    def shape_step_means(self, dt: float, n_steps: int) -> FloatArray:
        """Exact mean of the interpolant over each step ``[k dt, (k+1) dt]``."""
        return interval_means(self, np.arange(n_steps) * dt, np.arange(1, n_steps + 1) * dt)

    @property
    def end(self) -> float:
        return float(self.t[-1])


Force = HalfSine | ForceSeries


def interval_means(force: Force, a: FloatArray, b: FloatArray) -> FloatArray:
    """Mean unit force over each interval from ``a`` to ``b`` (``b < a`` allowed: a backward stage).

    Exact for both force kinds (analytic / piecewise-linear antiderivative), so impulses and the
    input work do not depend on where integration stages fall on the pulse.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return (force.antiderivative(b) - force.antiderivative(a)) / (b - a)


#: samples of each half-sine in a pulse train: interpolation error ~ (pi/256)^2/8 = 2e-5
PULSE_POINTS = 257


def pulse_train(times: Sequence[float], peaks: Sequence[float], duration: float) -> ForceSeries:
    """Half-sine hammer pulses of ``duration`` at ``times`` with ``peaks`` (N), as one force series — a
    session's hits on one continuous simulation, so each starts from the previous one's tail."""
    ts, fs = [], []
    for t0, p in zip(times, peaks, strict=True):
        tau = np.linspace(0.0, duration, PULSE_POINTS)
        ts.append(t0 + tau)
        fs.append(p * np.sin(np.pi * tau / duration))
    t = np.concatenate(ts)
    f = np.concatenate(fs)
    keep = np.concatenate([[True], np.diff(t) > 0])  # pulses never overlap; guard exact duplicates
    return ForceSeries(t=t[keep], force=f[keep], peak=1.0)
