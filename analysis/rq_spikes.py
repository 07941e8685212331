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

from dataclasses import dataclass

import numba
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
        self._curves = list(settings.curves)
        self._hist = np.empty((0, len(settings.curves)))  # the last ``history`` finite windows, oldest first

    def feed(self, freqs: FloatArray) -> bool:
        """True when this window is a partnered spike on ``curves``."""
        f = np.asarray(freqs, float)[self._curves]
        if not np.all(np.isfinite(f)):  # a window without a usable POM (silence): neither a spike nor history
            return False
        spike = False
        if len(self._hist) >= 3:
            h = self._hist
            med = np.median(h, axis=0)
            mad = np.median(np.abs(h - med), axis=0)
            dev = np.abs(f - med)
            cand = (dev > self.s.mad_factor * mad) & (dev > self.s.min_relative * np.abs(med))
            spike = bool(cand.all())  # partnered: both curves at once
        self._hist = np.concatenate([self._hist, f[None, :]])[-self.s.history :]
        return spike

    def feed_many(self, freqs: FloatArray) -> np.ndarray:
        """:meth:`feed` for consecutive windows ``(k, n)`` at once: the same decisions, in one compiled pass.

        Windows without finite frequencies on ``curves`` are skipped as :meth:`feed` skips them; the others
        are judged against the (up to ``history``) finite windows before them — the median and MAD of an odd
        count are a middle element and of an even count the mean of the two, exactly as ``np.median``.
        """
        f = np.asarray(freqs, float)[:, self._curves]
        ok = np.isfinite(f).all(axis=1)
        if not ok.all():
            out = np.zeros(f.shape[0], bool)
            if ok.any():
                out[ok] = self.feed_many(np.asarray(freqs, float)[ok])  # the skipped windows leave no trace
            return out
        n_hist = self._hist.shape[0]
        H = np.concatenate([self._hist, f])
        self._hist = H[-self.s.history :]
        return _spike_flags(H, n_hist, self.s.history, self.s.mad_factor, self.s.min_relative)


@numba.njit(cache=True, nogil=True)
def _median_sorted(b, m):  # pragma: no cover - compiled
    """Median of the first ``m`` entries of ``b`` (sorted in place: insertion sort, m <= history is
    small), as ``np.median`` computes it: the middle element, or the mean of the two middle ones."""
    for i in range(1, m):
        v = b[i]
        k = i - 1
        while k >= 0 and b[k] > v:
            b[k + 1] = b[k]
            k -= 1
        b[k + 1] = v
    if m % 2:
        return b[m // 2]
    return (b[m // 2 - 1] + b[m // 2]) / 2.0


@numba.njit(cache=True, nogil=True)
def _spike_flags(H, start, history, mad_factor, min_relative):  # pragma: no cover - compiled
    """:meth:`CausalSpikeRule.feed` for rows ``start:`` of ``H`` (finite frequencies, one column per curve),
    each judged against the up to ``history`` rows before it (no decision with fewer than 3)."""
    n, nc = H.shape
    out = np.zeros(n - start, np.bool_)
    col = np.empty(history)
    for t in range(start, n):
        lo = max(0, t - history)
        m = t - lo
        if m < 3:
            continue
        spike = True
        for c in range(nc):
            for i in range(m):
                col[i] = H[lo + i, c]
            med = _median_sorted(col, m)
            for i in range(m):
                col[i] = abs(H[lo + i, c] - med)
            mad = _median_sorted(col, m)
            dev = abs(H[t, c] - med)
            if not (dev > mad_factor * mad and dev > min_relative * abs(med)):
                spike = False
        out[t - start] = spike
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
    for grid in flagged:  # ts[k] is covered where t0 <= ts[k] <= t1 for one of the grid's windows: index ranges on the
        if not grid:  # sorted lattice, marked by a running count (was one full-lattice comparison per window)
            continue
        t01 = np.asarray(grid, float)
        mark = np.zeros(ts.size + 1, np.int64)
        np.add.at(mark, np.searchsorted(ts, t01[:, 0], side="left"), 1)
        np.add.at(mark, np.searchsorted(ts, t01[:, 1], side="right"), -1)
        votes += np.cumsum(mark[:-1]) > 0
    frac = votes / len(flagged)
    ok = np.concatenate([[False], frac >= min_fraction, [False]])
    edges = np.flatnonzero(ok[1:] != ok[:-1])  # runs of agreement: [start, stop) pairs
    starts, stops = edges[::2], edges[1::2]
    if starts.size == 0:
        return []
    # each run's largest fraction: the maximum from its start to the next run's start is the run's own, the samples
    # between two runs being below min_fraction
    peak = np.maximum.reduceat(frac, starts)
    return [(float(ts[a]), float(ts[b - 1]), float(m)) for a, b, m in zip(starts, stops, peak, strict=True)]
