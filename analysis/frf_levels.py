"""Force levels of impact hits and the linearity check between them (issue 29, item 1).

Why: on a structure with a local nonlinearity (the rigs' cubic springs) the FRF depends on the force. Hits of
150 N and 1583 N averaged together give an FRF of neither level, and the coherence at the modes falls (0.16-0.24
at mode 1 of the demo log) without saying why. A GVT therefore checks linearity the way Ewins (*Modal Testing*,
2nd ed., §3.11, "Tests for linearity") and the GVT practice of Göge et al. (*Detection and description of
non-linear phenomena in experimental modal analysis via linearity plots*, IJNLM 40(1), 2005) describe: FRFs
measured at two or more force levels are overlaid; a linear structure gives the same FRF at every level, a
nonlinear one shifts its peaks (a hardening spring: up in frequency) and changes their height.

Two pure functions serve the FRF study, the live lane and model updating alike:

* :func:`level_groups`: hits grouped by peak force into levels, each spanning at most ``ratio`` (2 = 6 dB)
  from its weakest to its strongest hit, split first where the forces leave the largest gap (a test engineer's
  "20 N hits" and "200 N hits" are two levels however many hits each has).
* :func:`linearity_check`: the FRFs of two levels compared at each mode (peak shift %, amplitude ratio dB)
  against stated bounds, with a one-line reason.

:func:`choose_level` says which level the FRF averages by default (the rule is in its docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.errors import BadInput

#: strongest / weakest peak force inside one level group (2 = 6 dB: a hand-held hammer's scatter around one
#: intended level stays inside it, 20 N and 200 N hits do not)
LEVEL_RATIO = 2.0
#: hits a level needs to be the one averaged by default (choose_level): with fewer the coherence says nothing
MIN_LEVEL_HITS = 2
#: linearity bounds per mode between two levels: peak frequency shift (%) and peak amplitude ratio (dB).
#: Ours, stated: 1 % is about a tenth of a mode's half-power bandwidth at the rigs' 0.5-2 % damping plus the
#: exponential window, 1 dB (12 %) is twice the scatter of single-hit peak heights at 1 % noise (tests).
MAX_SHIFT_PCT = 1.0
MAX_RATIO_DB = 1.0


def level_groups(peak_forces: np.ndarray, ratio: float = LEVEL_RATIO) -> list[np.ndarray]:
    """Indices into ``peak_forces`` (N, > 0) per force level, levels in ascending force, indices ascending.

    Rule: sort the forces; while a group's strongest / weakest hit exceeds ``ratio``, split it at its largest
    step in log force (a natural gap between intended levels first, a ramp of forces into pieces of at most
    ``ratio``). Deterministic, independent of the hits' order.
    """
    f = np.asarray(peak_forces, dtype=float).ravel()
    if ratio <= 1.0:
        raise BadInput(f"force levels: ratio must be above 1, got {ratio:g}")
    if f.size == 0:
        return []
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise BadInput("force levels: every hit's peak force must be a positive number of N")
    order = np.argsort(f, kind="stable")
    logf = np.log(f[order])
    spans = [(0, f.size)]  # [start, end) into order, split until each is within ratio
    done: list[tuple[int, int]] = []
    while spans:
        a, b = spans.pop()
        if logf[b - 1] - logf[a] <= np.log(ratio) + 1e-12:
            done.append((a, b))
            continue
        cut = a + 1 + int(np.argmax(np.diff(logf[a:b])))
        spans += [(a, cut), (cut, b)]
    return [np.sort(order[a:b]) for a, b in sorted(done)]


def choose_level(groups: list[np.ndarray], min_hits: int = MIN_LEVEL_HITS) -> int:
    """The level averaged by default: the lowest with at least ``min_hits`` hits; if none has that many, the
    one with the most hits (the lowest of a tie); -1 when there is no group.

    Why the lowest: it is the nearest to the linear structure a model is built for (the nonlinearity grows with
    amplitude), and it is a GVT's reference level. Why ``min_hits``: one hit's H1 has coherence 1 at every line,
    so a single weak hit would hide both noise and nonlinearity."""
    if not groups:
        return -1
    sizes = np.array([g.size for g in groups])
    enough = np.flatnonzero(sizes >= min_hits)
    return int(enough[0]) if enough.size else int(np.argmax(sizes))


@dataclass(frozen=True)
class LinearityCheck:
    """Two force levels' FRFs compared at each mode.

    ``freq_hz`` the modes' peak frequencies at the low level; ``shift_pct`` the high level's peak frequency
    re. the low one's, %; ``ratio_db`` the high level's peak height over the low one's, dB (a mode indicator:
    ``sum |H|`` over the pairs); ``linear`` every mode within ``max_shift_pct`` and ``max_ratio_db``;
    ``reason`` one line (the worst mode when not linear)."""

    freq_hz: np.ndarray
    shift_pct: np.ndarray
    ratio_db: np.ndarray
    max_shift_pct: float
    max_ratio_db: float
    linear: bool
    reason: str

    def as_dict(self) -> dict:
        """JSON-ready (lists of floats, NaN as None)."""
        def clean(a: np.ndarray) -> list:
            return [None if not np.isfinite(x) else float(x) for x in np.asarray(a, dtype=float)]

        return {"freq_hz": clean(self.freq_hz), "shift_pct": clean(self.shift_pct), "ratio_db": clean(self.ratio_db),
                "max_shift_pct": self.max_shift_pct, "max_ratio_db": self.max_ratio_db, "linear": self.linear,
                "reason": self.reason}  # fmt: skip


def mode_indicator(H: np.ndarray) -> np.ndarray:
    """``sum |H|`` over every axis but the last (frequency), NaN pairs (an output no hit was good on) skipped."""
    a = np.abs(np.asarray(H))
    return np.nansum(a.reshape(-1, a.shape[-1]), axis=0)


def peak_in(freqs: np.ndarray, mif: np.ndarray, lo: int, hi: int) -> tuple[float, float]:
    """Frequency (Hz) and height of the largest value of ``mif[lo:hi]``, refined by a parabola through the
    log-magnitudes of the three lines around it (Grandke's interpolation; on a peak sampled at df it takes the
    bin error from df/2 to a few % of df)."""
    k = lo + int(np.argmax(mif[lo:hi]))
    if k <= 0 or k >= mif.size - 1 or min(mif[k - 1], mif[k + 1]) <= 0:
        return float(freqs[k]), float(mif[k])
    y0, y1, y2 = np.log(mif[k - 1 : k + 2])
    den = y0 - 2.0 * y1 + y2
    d = 0.0 if den >= 0 else float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
    df = float(freqs[1] - freqs[0])
    return float(freqs[k] + d * df), float(np.exp(y1 - 0.25 * (y0 - y2) * d))


def linearity_check(freqs: np.ndarray, H_low: np.ndarray, H_high: np.ndarray, peaks_hz: np.ndarray | None = None, *,
                    band: tuple[float, float] | None = None, n_peaks: int = 6, max_shift_pct: float = MAX_SHIFT_PCT,
                    max_ratio_db: float = MAX_RATIO_DB) -> LinearityCheck:  # fmt: skip
    """Compare the FRFs of a low and a high force level (``H_*``: (..., n_f) complex on ``freqs``, Hz) at each mode.

    The modes are ``peaks_hz`` (Hz, e.g. the low level's peaks or the FE modes), or else the ``n_peaks`` most
    prominent peaks of the low level's mode indicator inside ``band`` (default: the whole grid above 1 Hz).
    Each mode's low-level peak is looked for within half the distance to its neighbours, and so is the high
    level's: a hardening spring can move a peak by tens of % (mode 1 of the demo log), which a fixed ±few %
    search would miss; between neighbours it is still that mode's peak."""
    f = np.asarray(freqs, dtype=float)
    lo_m, hi_m = mode_indicator(H_low), mode_indicator(H_high)
    if lo_m.shape != f.shape or hi_m.shape != f.shape:
        raise BadInput(f"linearity check: FRFs of {np.shape(H_low)} / {np.shape(H_high)} on {f.size} frequencies")
    pk = _modes(f, lo_m, peaks_hz, band, n_peaks)
    if pk.size == 0:
        return LinearityCheck(pk, pk.copy(), pk.copy(), max_shift_pct, max_ratio_db, True, "no mode in the band to compare")
    edges = np.concatenate([[f[0]], 0.5 * (pk[1:] + pk[:-1]), [f[-1]]])
    f_lo, shift, ratio = np.empty(pk.size), np.empty(pk.size), np.empty(pk.size)
    for m in range(pk.size):
        a = max(int(np.searchsorted(f, edges[m])), 1)
        b = max(int(np.searchsorted(f, edges[m + 1], side="right")), a + 1)
        fl, al = peak_in(f, lo_m, a, b)
        fh, ah = peak_in(f, hi_m, a, b)
        f_lo[m], shift[m] = fl, 100.0 * (fh - fl) / fl
        ratio[m] = 20.0 * np.log10(ah / al) if al > 0 and ah > 0 else np.nan
    bad = (np.abs(shift) > max_shift_pct) | ~(np.abs(ratio) <= max_ratio_db)
    if not bad.any():
        reason = (f"linear: {pk.size} modes within {max_shift_pct:g} % and {max_ratio_db:g} dB (largest shift "
                  f"{np.max(np.abs(shift)):.2f} %, largest ratio {np.nanmax(np.abs(ratio)):.2f} dB)")  # fmt: skip
        return LinearityCheck(f_lo, shift, ratio, max_shift_pct, max_ratio_db, True, reason)
    score = np.where(bad, np.abs(shift) / max_shift_pct + np.nan_to_num(np.abs(ratio), nan=99.0) / max_ratio_db, -1.0)
    w = int(np.argmax(score))
    reason = (f"not linear: {int(bad.sum())} of {pk.size} modes differ between levels, worst at {f_lo[w]:.1f} Hz: peak "
              f"moves {shift[w]:+.1f} % and {ratio[w]:+.1f} dB (bounds {max_shift_pct:g} %, {max_ratio_db:g} dB)")  # fmt: skip
    return LinearityCheck(f_lo, shift, ratio, max_shift_pct, max_ratio_db, False, reason)


def _modes(f: np.ndarray, mif: np.ndarray, peaks_hz: np.ndarray | None, band: tuple[float, float] | None,
           n_peaks: int) -> np.ndarray:  # fmt: skip
    """The modes' frequencies, ascending: given, or the most prominent peaks of ``mif`` in ``band``."""
    if peaks_hz is not None:
        p = np.sort(np.asarray(peaks_hz, dtype=float).ravel())
        return p[(p > f[0]) & (p < f[-1])]
    lo, hi = band if band is not None else (1.0, float(f[-1]))
    idx, prom = prominent_peaks(np.where((f >= lo) & (f <= hi), mif, 0.0), top=n_peaks)
    keep = idx[np.argsort(prom, kind="stable")[::-1][:n_peaks]]
    return np.sort(f[keep])


def prominent_peaks(y: np.ndarray, top: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of ``y`` (above both neighbours; a flat top counts once, at its middle) and their topographic
    prominence, ascending in index: what ``scipy.signal.find_peaks(y, prominence=0)`` gives (tests/test_frf_levels.py
    compares the two). With ``top``, only maxima that can be among the ``top`` most prominent are measured, and
    those are exact: a maximum's prominence is at most its height above ``min(y)``, so once the next-highest
    maximum stands lower than the ``top``-th prominence found, no maximum left can enter.

    Why not scipy: importing scipy.signal costs ~0.5-1.3 s of CPU here, more than the whole identification of
    `gvt modal` that calls this once per level pair (bench/bench_quality.py). Each maximum measured takes two
    passes over ``y``; with ``top`` a mode indicator stops after its modes and the ripple next to them."""
    y = np.asarray(y, dtype=float)
    if y.size < 3:
        return np.empty(0, int), np.empty(0)
    start = np.flatnonzero(np.r_[True, y[1:] != y[:-1]])  # runs of equal values (plateaus) as one sample each
    end = np.r_[start[1:], y.size] - 1
    v = y[start]
    k = 1 + np.flatnonzero((v[1:-1] > v[:-2]) & (v[1:-1] > v[2:]))
    i = (start[k] + end[k]) // 2  # a plateau's peak is its middle sample, as scipy's
    i = i[np.argsort(y[i], kind="stable")[::-1]]  # highest first
    floor = float(y.min())
    prom = np.empty(i.size)
    best: list[float] = []  # the ``top`` largest prominences so far, ascending
    n = 0
    for p in i:
        if top is not None and len(best) >= top and y[p] - floor < best[0]:
            break
        left = np.flatnonzero(y[:p] > y[p])
        right = np.flatnonzero(y[p + 1 :] > y[p])
        a = left[-1] + 1 if left.size else 0
        b = p + 1 + right[0] if right.size else y.size
        prom[n] = y[p] - max(y[a : p + 1].min(), y[p:b].min())
        if top is not None:
            best = sorted([*best, prom[n]])[-top:]
        n += 1
    i, prom = i[:n], prom[:n]
    order = np.argsort(i)
    return i[order], prom[order]


__all__ = ["LEVEL_RATIO", "MAX_RATIO_DB", "MAX_SHIFT_PCT", "MIN_LEVEL_HITS", "LinearityCheck", "choose_level",
           "level_groups", "linearity_check", "mode_indicator", "peak_in", "prominent_peaks"]  # fmt: skip
