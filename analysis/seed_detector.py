"""The seed's spike rule as a named baseline detector, and its method assumptions as checks.

The seed gives no numeric spike definition (method-detection §1.10, §5.7): spikes are "non-smooth
perturbations" of the RQ curves (L1253), and an internal resonance needs a partner spike on the other
NNM's curve (L1393: the late NNM1 spikes "have no partner spikes", so they are not IRs). The literal
prototype of ``detection-findings.md`` made that concrete and this module reproduces it:

    a window is flagged on a curve when |RQ − running median| > k · σ and > δ · running median,
    σ = 1.4826 · MAD of the residual (global per curve), and it is a *spike window* when the other
    curve of the pair (NNM1/NNM2) is flagged in the same window.

Every threshold is a field of :class:`SeedSpikeSettings`. This is the baseline gvtlink's own detector
is scored against — detection-findings shows it is fooled by window phase, so it is kept as is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage

from analysis.runs import true_runs

FloatArray = np.ndarray


@dataclass(frozen=True)
class SeedSpikeSettings:
    """Thresholds of the literal prototype (method-detection §1.10 defaults).

    ``mad_scale`` = 1.4826 makes σ the normal-consistent MAD; 1.0 reads "4·MAD" literally.
    ``partner_tolerance`` = 0: the partner must be flagged in the same window.
    """

    median_window: int = 7
    mad_k: float = 4.0
    mad_scale: float = 1.4826
    rel_threshold: float = 0.02
    partner_tolerance: int = 0
    curves: tuple[int, int] = (0, 1)

    def __post_init__(self) -> None:
        if self.median_window < 3 or self.median_window % 2 == 0:
            raise ValueError("median_window must be odd and >= 3")
        if self.mad_k <= 0 or self.mad_scale <= 0 or self.rel_threshold < 0 or self.partner_tolerance < 0:
            raise ValueError("thresholds must be positive")


@dataclass(frozen=True)
class SpikeInterval:
    """A run of consecutive spike windows ``[start, end]`` (inclusive) and the curves flagged in it."""

    start: int
    end: int
    curves: tuple[int, ...]
    peak_window: int
    peak_rel: float  # largest |residual| / baseline over the run and its curves


@dataclass(frozen=True)
class SeedSpikeResult:
    baseline: FloatArray  # (k, n_curves) running median
    residual: FloatArray  # (k, n_curves) RQ − baseline
    sigma: FloatArray  # (n_curves,) robust scale per curve
    flagged: np.ndarray  # (k, n_curves) bool, each curve on its own
    spike_windows: np.ndarray  # (n,) window indices with a partnered flag
    intervals: tuple[SpikeInterval, ...]
    unpartnered_windows: np.ndarray  # flagged on one curve with no partner (the seed's "noise spikes", L1393)


def _flag(freqs: FloatArray, s: SeedSpikeSettings) -> tuple[FloatArray, FloatArray, FloatArray, np.ndarray]:
    base = scipy.ndimage.median_filter(freqs, size=(s.median_window, 1), mode="nearest")
    r = freqs - base
    mad = np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    sigma = s.mad_scale * mad
    flagged = (np.abs(r) > s.mad_k * sigma) & (np.abs(r) > s.rel_threshold * np.abs(base))
    return base, r, sigma, flagged


def seed_spikes(freqs: FloatArray, settings: SeedSpikeSettings = SeedSpikeSettings()) -> SeedSpikeResult:
    """Apply the seed's spike rule to RQ curves ``freqs`` (k windows, n_curves), ordered in time/energy."""
    f = np.asarray(freqs, dtype=float)
    if f.ndim != 2:
        raise ValueError("freqs must be (k, n_curves)")
    s = settings
    i, j = s.curves
    if max(i, j) >= f.shape[1] or i == j:
        raise ValueError("curves must name two distinct columns of freqs")
    base, r, sigma, flagged = _flag(f, s)
    tol = s.partner_tolerance
    # partner[k, c]: the other curve is flagged within ±tol windows of k.
    near = scipy.ndimage.binary_dilation(flagged, structure=np.ones((2 * tol + 1, 1), bool)) if tol else flagged
    pair_i = flagged[:, i] & near[:, j]
    pair_j = flagged[:, j] & near[:, i]
    spike = pair_i | pair_j
    spike_windows = np.flatnonzero(spike)
    rel = np.abs(r) / np.where(base == 0, np.inf, np.abs(base))
    intervals = []
    for a, b in true_runs(spike):
        curves = tuple(c for c in (i, j) if flagged[a : b + 1, c].any())
        sub = rel[a : b + 1][:, list(curves)]
        pk = int(np.unravel_index(np.argmax(sub), sub.shape)[0]) + a
        intervals.append(SpikeInterval(a, b, curves, pk, float(sub.max())))
    lone = (flagged[:, i] | flagged[:, j]) & ~spike
    return SeedSpikeResult(
        baseline=base,
        residual=r,
        sigma=sigma,
        flagged=flagged,
        spike_windows=spike_windows,
        intervals=tuple(intervals),
        unpartnered_windows=np.flatnonzero(lone),
    )


def check_assumptions(
    n_sensors: int,
    n_modes_of_interest: int,
    freqs: FloatArray,
    window_s: float,
    nonlinearity_measured: bool,
) -> list[str]:
    """Warnings for the seed's method assumptions (Sec 1.4, L59–L69) that data can check.

    * L61: sensors ≥ 2 × the modes of interest.
    * L68: an NNM's frequency changes < 10 % within one-half cycle of the fundamental — checked as the
      relative change between consecutive windows of each curve ``freqs`` (k, n_modes), which bounds the
      change within a window when windows are about half a cycle long.
    * L1371: a window spans at least half a cycle of the first NNM (the seed's own window rule).
    * L69: the nonlinearity's location is measured by a sensor.
    """
    out: list[str] = []
    if n_sensors < 2 * n_modes_of_interest:
        out.append(
            f"{n_sensors} sensors for {n_modes_of_interest} modes of interest: the method assumes at least "
            f"{2 * n_modes_of_interest} (twice the modes, seed L61)"
        )
    f = np.asarray(freqs, dtype=float)
    if f.ndim == 1:
        f = f[:, None]
    if f.shape[0] >= 2:
        rel = np.abs(np.diff(f, axis=0)) / np.abs(f[:-1])
        bad = np.argwhere(rel >= 0.10)
        if bad.size:
            k, c = bad[0]
            out.append(
                f"{len(bad)} window step(s) change an RQ frequency by >= 10 % (first: curve {c}, window {k} -> {k + 1}, "
                f"{100 * rel[k, c]:.0f} %); the method assumes < 10 % within half a cycle (seed L68)"
            )
    if f.size:
        f1 = float(np.nanmin(f[:, 0]))
        if f1 > 0 and window_s < 0.5 / f1:
            out.append(
                f"window {window_s:.4g} s is shorter than half a cycle of the lowest NNM ({0.5 / f1:.4g} s at "
                f"{f1:.3g} Hz); the seed requires at least one-half cycle (L1371)"
            )
    if not nonlinearity_measured:
        out.append("the nonlinearity's location is not measured by any sensor (seed assumption L69)")
    return out
