"""RQ spikes that survive a change of window offset and length — the seed's picture without its artefact.

detection-findings.md: with windows about half an NNM1 period long, two modes are not orthogonal over a
window and the POMs rotate by an amount that depends on where the window falls in the cycle, so steady
*linear* motion with E2/E1 ≳ 0.3 already gives partnered "spikes" (beat period T_w / |2 f1 T_w − n|).
Such an artefact moves when the windows move; a real change of the NNM frequencies does not. So the same
causal spike rule runs on several window grids — ``offsets`` (fractions of a window) × ``lengths``
(multiples of the base window) — and a spike counts only where at least ``min_fraction`` of the grids
flag a window that covers the same instant.

The per-grid rule is the seed's, made causal: a window's RQ frequency is a spike candidate when it is
more than ``mad_factor`` MADs and more than ``min_relative`` from the median of the previous
``history`` windows of the same grid, and it needs a partner (the other curve of the pair spiking in the
same window) — the literal prototype's reading of seed L1255/L1389 (method-detection §5.7: the seed
gives no numbers).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

FloatArray = np.ndarray


@dataclass(frozen=True)
class RobustSpikeSettings:
    offsets: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75)  # window-grid offsets, fractions of the base window
    lengths: tuple[float, ...] = (1.0, 1.5)  # window lengths, multiples of the base window
    history: int = 15  # previous windows in the running median
    mad_factor: float = 4.0
    min_relative: float = 0.02
    min_fraction: float = 0.75  # of the grids that must agree
    curves: tuple[int, int] = (0, 1)  # the partnered pair (NNM1, NNM2), 0-based columns of the RQ frequencies

    def __post_init__(self) -> None:
        if not self.offsets or not self.lengths or self.history < 3 or not 0 < self.min_fraction <= 1:
            raise ValueError("robust spikes: need offsets, lengths, history >= 3 and 0 < min_fraction <= 1")


class CausalSpikeRule:
    """The seed's spike rule on one window grid, using only past windows."""

    def __init__(self, settings: RobustSpikeSettings) -> None:
        self.s = settings
        self._hist: deque[FloatArray] = deque(maxlen=settings.history)

    def feed(self, freqs: FloatArray) -> bool:
        """True when this window is a partnered spike on ``curves``."""
        f = np.asarray(freqs, float)[list(self.s.curves)]
        if not np.all(np.isfinite(f)):  # a window without a usable POM (silence): neither a spike nor history
            return False
        spike = False
        if len(self._hist) >= 3:
            h = np.array(self._hist)
            med = np.median(h, axis=0)
            mad = np.median(np.abs(h - med), axis=0)
            dev = np.abs(f - med)
            cand = (dev > self.s.mad_factor * mad) & (dev > self.s.min_relative * np.abs(med))
            spike = bool(cand.all())  # partnered: both curves at once
        self._hist.append(f)
        return spike

    def feed_many(self, freqs: FloatArray) -> np.ndarray:
        """:meth:`feed` for consecutive windows ``(k, n)`` at once (vectorised once the history is full)."""
        F = np.asarray(freqs, float)
        if not np.all(np.isfinite(F[:, list(self.s.curves)])):
            return np.array([self.feed(row) for row in F], bool)
        out = np.zeros(F.shape[0], bool)
        i = 0
        h = self.s.history
        while i < F.shape[0] and len(self._hist) < h:
            out[i] = self.feed(F[i])
            i += 1
        if i < F.shape[0]:
            f = F[i:][:, list(self.s.curves)]
            H = np.concatenate([np.array(self._hist), f])
            win = np.lib.stride_tricks.sliding_window_view(H[:-1], h, axis=0)  # (m, n_curves, h): the h rows before each
            med = np.median(win, axis=-1)
            mad = np.median(np.abs(win - med[..., None]), axis=-1)
            dev = np.abs(f - med)
            out[i:] = ((dev > self.s.mad_factor * mad) & (dev > self.s.min_relative * np.abs(med))).all(axis=1)
            self._hist.extend(H[-h:])
        return out


def robust_spike_intervals(
    flagged: list[list[tuple[float, float]]], min_fraction: float, resolution_s: float
) -> list[tuple[float, float, float]]:
    """Merge per-grid flagged windows ``[(t0, t1), …]`` into intervals where ≥ ``min_fraction`` agree.

    Returns ``(start, end, fraction)``: time is sampled at multiples of ``resolution_s`` and each grid counts once
    at an instant if any of its flagged windows covers it.
    """
    if not flagged or not any(flagged):
        return []
    t_end = max(t1 for grid in flagged for _, t1 in grid)
    t_start = min(t0 for grid in flagged for t0, _ in grid)
    # a global lattice k·resolution (not anchored at the first flagged window), so that the same flags give
    # the same intervals whichever subset of windows a call sees
    ts = np.arange(np.ceil(t_start / resolution_s), np.floor(t_end / resolution_s) + 1) * resolution_s
    votes = np.zeros(ts.size)
    for grid in flagged:
        cover = np.zeros(ts.size, bool)
        for t0, t1 in grid:
            cover |= (ts >= t0) & (ts <= t1)
        votes += cover
    frac = votes / len(flagged)
    ok = frac >= min_fraction
    out = []
    k = 0
    while k < ts.size:
        if ok[k]:
            j = k
            while j + 1 < ts.size and ok[j + 1]:
                j += 1
            out.append((float(ts[k]), float(ts[j]), float(frac[k : j + 1].max())))
            k = j + 1
        else:
            k += 1
    return out
