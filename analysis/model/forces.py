"""Hammer force histories: the seed's half-sine pulse (eq. 4.1, L1211) or any sampled series.

The integrator needs the *mean* force over each integration step (so that the impulse, and hence the
input energy, is exact however the step falls on the pulse edges) and the force at the output
instants (for accelerations). Both are per unit amplitude; a batch scales them by its amplitudes.
"""

from __future__ import annotations

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

    def shape_step_means(self, dt: float, n_steps: int) -> FloatArray:
        """Exact mean of the unit-peak pulse over each step ``[k dt, (k+1) dt]``."""
        t0 = np.arange(n_steps) * dt
        t1 = t0 + dt
        a = np.clip(t0, self.start, self.start + self.duration)
        b = np.clip(t1, self.start, self.start + self.duration)
        T = self.duration
        # integral of sin(pi (t - start)/T) from a to b
        integ = (T / np.pi) * (np.cos(np.pi * (a - self.start) / T) - np.cos(np.pi * (b - self.start) / T))
        return integ / dt

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

    def shape_step_means(self, dt: float, n_steps: int) -> FloatArray:
        # Exact mean of the piecewise-linear interpolant over each step: integrate the cumulative
        # trapezoid of the series evaluated at the step edges.
        tt = np.asarray(self.t, dtype=float)
        ff = np.asarray(self.force, dtype=float)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (ff[1:] + ff[:-1]) * np.diff(tt))])

        def integral_to(x: FloatArray) -> FloatArray:
            x = np.clip(x, tt[0], tt[-1])
            i = np.clip(np.searchsorted(tt, x, side="right") - 1, 0, len(tt) - 2)
            frac = x - tt[i]
            slope = (ff[i + 1] - ff[i]) / (tt[i + 1] - tt[i])
            return cum[i] + ff[i] * frac + 0.5 * slope * frac**2

        edges = np.arange(n_steps + 1) * dt
        return np.diff(integral_to(edges)) / dt

    @property
    def end(self) -> float:
        return float(self.t[-1])


Force = HalfSine | ForceSeries
