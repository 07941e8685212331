"""Ground truth for internal-resonance detection: *major exchanges* of energy into mode 2.

Issue 6 defines a major exchange as "an interval after the pulse in which mode-2 modal energy at least
doubles (modal energies from the simulator's exact modal coordinates, smoothed over one window); its
ratio is f2/f1 at that time rounded to the nearest of 2:1, 5:2, 3:1, 7:2, 4:1" — since issue 21 with 1:1 first
(:data:`analysis.exchange.LEAK_RATIO`, every ratio <= 1.5: a leak, not a resonance), the detector's rule. This module makes
that definition precise (``docs/evaluation.md`` §1):

* ``E2`` is the linear modal energy ``(q2'^2 + w2^2 q2^2)/2`` of the rig's *second linear mode* (the
  simulator's mass-normalised mode 2 of the underlying linear structure), smoothed by a centred moving
  average over one detector window. Only samples whose smoothing window lies entirely after the pulse
  end and inside the record are used: ``[pulse_end + W/2, t_end - W/2]``.
* The smoothed ``E2`` is split into alternating minima and maxima by a zig-zag with hysteresis: an
  extremum is confirmed only once the signal has moved away from it by the factor ``hysteresis``
  (1.25 by default). So a dip of less than 20 % inside a rise does not split the rise (merge rule),
  and ripple of the moving average never creates extrema. Each rise (a minimum to the following
  maximum) is one candidate; the first sample may be a minimum (E2 rising right after the pulse), the
  last sample may be a maximum (still rising at the end of the record).
* A rise is a major exchange when ``E2(max) / E2(min) >= factor`` (2) and ``E2(max) >= floor_rel *
  input_work`` (1e-6 by default): rises that end at the numerical floor are not exchanges. In a linear
  rig with modal damping each modal energy obeys ``dE/dt = -2 zeta w v^2 <= 0``, so smoothed E2 never
  rises and the linear grid has no exchange by construction — the tests check the simulator agrees.
* The label: ``f1``, ``f2`` are the zero-crossing frequencies of modal coordinates 1 and 2 over the
  interval (at least ``± window`` around its centre), and ``f2/f1`` is rounded to the nearest ratio in
  the list by absolute difference. The unrounded value is kept (``Exchange.ratio``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import scipy.signal
from scipy.ndimage import uniform_filter1d

from analysis.exchange import DEFAULT_RATIOS, lock_fit, nearest_ratio, phase_bands, slowest_phase_ratio
from analysis.model.beam import FloatArray
from analysis.model.truth import zero_crossing_frequency

DEFAULT_WINDOW_S = 354 / 16384.0  # the seed's 0.0216 s window (354 samples at 16384 Hz)
DEFAULT_FLOOR_REL = 1e-6
DEFAULT_HYSTERESIS = 1.25
#: the span of the phase-lock test around an exchange's centre: long enough that the giving mode's candidate harmonics
#: (0.5 f1 apart, ~10 Hz) and the free mode-2 oscillation (4-7 Hz from 3 f1 on both rigs) are resolved
DEFAULT_LOCK_SPAN_S = 0.3
#: the lock test's label needs its best candidate's model to leave at most 1 - this of the residual without it ...
LOCK_MIN_IMPROVEMENT = 0.2
#: ... and its locked component to explain at least this fraction of q2's energy over the span
LOCK_MIN_SHARE = 0.02


@dataclass(frozen=True)
class Exchange:
    """One major exchange: E2 rises by ``gain`` from ``start_s`` (a minimum) to ``end_s`` (a maximum)."""

    start_s: float
    end_s: float
    gain: float  # smoothed E2 at end / at start
    ratio_m: int
    ratio_n: int
    f1_hz: float
    f2_hz: float
    e2_end_rel: float = float("nan")  # smoothed E2 at the end / input work: how large the exchange is
    e2_over_e1: float = float("nan")  # smoothed E2 / E1 at the end: how visible mode 2 is then
    zc_label: str = ""  # issue 6's label, f2/f1 from zero crossings rounded (kept to compare; the label is the lock test's)

    @property
    def ratio(self) -> float:
        """Unrounded f2/f1 over the interval."""
        return self.f2_hz / self.f1_hz

    @property
    def label(self) -> str:
        return f"{self.ratio_m}:{self.ratio_n}"


def modal_energy_smoothed(E: FloatArray, fs: float, window_s: float) -> FloatArray:
    """Centred moving average of modal energies ``E`` (N, n_modes) over one window (``round(W fs)`` samples).

    The first and last ``W/2`` are biased by the edge (mode ``nearest``); ``major_exchanges`` does not
    use them.
    """
    E = np.asarray(E, dtype=float)
    nw = max(1, round(window_s * fs))
    return uniform_filter1d(E, nw, axis=0, mode="nearest")


def instantaneous_frequencies(modal_q: FloatArray, fs: float, t_centres: FloatArray, half_width: float = 0.05) -> FloatArray:
    """Zero-crossing frequency (Hz) of each modal coordinate around each centre, shape (n_centres, modes).

    Reuses :func:`analysis.model.truth.zero_crossing_frequency` (interpolated crossings); NaN where a
    coordinate has fewer than two crossings in ``centre ± half_width``.
    """
    q = np.asarray(modal_q, dtype=float)
    if q.ndim == 1:
        q = q[:, None]
    t = np.arange(q.shape[0]) / fs
    c = np.atleast_1d(np.asarray(t_centres, dtype=float))
    return np.stack([zero_crossing_frequency(q[:, r], t, c, half_width) for r in range(q.shape[1])], axis=1)


def giving_phase(q1: FloatArray) -> FloatArray:
    """Unwrapped phase (rad) of the giving mode's exact coordinate, from its analytic signal (non-causal: a truth)."""
    return np.unwrap(np.angle(scipy.signal.hilbert(np.asarray(q1, dtype=float))))


def locked_ratio(
    q2: FloatArray,
    theta1: FloatArray,
    fs: float,
    centre_s: float,
    f1_hz: float,
    ratios: Sequence[tuple[int, int]] = DEFAULT_RATIOS,
    span_s: float = DEFAULT_LOCK_SPAN_S,
    bounds_s: tuple[float, float] | None = None,
    step_hz: float = 0.25,
) -> tuple[int, int] | None:
    """The m:n whose component of mode 2 is **phase-locked** to mode 1 around ``centre_s``; None if none stands out.

    Why (docs/evaluation.md §8): an internal resonance is the slow phase ``m θ1 − n θ2`` staying constant (the seed's
    eq. 4.2, L1275). Measured on both grid rigs, the exact q2 during an exchange holds two oscillations: the response the
    cubic spring drives at exactly 3 f1 (locked to θ1) and mode 2's free oscillation at its own, amplitude-shifted
    frequency f2' (3.1-3.4 f1); E2 rises where they come into phase (the exchanges recur at 1/|f2' − 3 f1|). Issue 6's
    f2/f1 reads a mixture of the two, which straddles the 3.25 rounding boundary. Here each candidate ``ρ = m/n`` is
    tried as ``q2 ≈ a cos(ρ θ1) + b sin(ρ θ1) + c cos(2π f t) + d sin(2π f t)`` (least squares over ``centre ± span/2``,
    the free frequency ``f`` searched in ``[1.25, 4.75] f1`` on a ``step_hz`` grid), always with a component locked at
    θ1 itself as a nuisance (the cubic force's f1 part drives mode 2 off resonance, far below it: not an m:n resonance,
    and 1:1 is not a candidate); the candidate with the smallest residual wins, provided it leaves at most
    ``1 − LOCK_MIN_IMPROVEMENT`` of the residual without it (f1 component + one free sinusoid) and explains at least
    ``LOCK_MIN_SHARE`` of q2's energy (else nothing is locked that a free oscillation does not explain: None). ``theta1`` is
    :func:`giving_phase` of q1 over the same samples as ``q2``; ``bounds_s`` clips the span (pulse end, record end).
    """
    q2 = np.asarray(q2, dtype=float)
    lo, hi = centre_s - 0.5 * span_s, centre_s + 0.5 * span_s
    if bounds_s is not None:
        lo, hi = max(lo, bounds_s[0]), min(hi, bounds_s[1])
    stride = max(1, int(fs // 1024))  # q2's content here is below ~5 f1 < 200 Hz: 1 kHz samples resolve it
    idx = np.arange(max(0, int(np.ceil(lo * fs))), min(q2.size, int(np.floor(hi * fs)) + 1), stride)
    th = np.asarray(theta1, dtype=float)[idx]
    return lock_fit(idx / fs, q2[idx], th, f1_hz, ratios, LOCK_MIN_IMPROVEMENT, LOCK_MIN_SHARE, step_hz)


def slow_phase_label(
    modal_q: FloatArray, fs: float, freqs_hz: Sequence[float], t0: float, t1: float,
    ratios: Sequence[tuple[int, int]] = DEFAULT_RATIOS,
) -> tuple[tuple[int, int], float] | None:  # fmt: skip
    """The m:n whose slow phase ``m θ1 − n θ2`` turns slowest over ``[t0, t1]`` — the seed's definition of an internal
    resonance (eq. 4.2, L1275) read on the simulator's exact modal coordinates — and the ratio of the phases' advances.

    Independent of the detector (issue 29): no fit and no sensor; θ1, θ2 are the analytic phases (Hilbert, zero-phase)
    of exact q1 and q2, each band-passed to its mode's band (:func:`analysis.exchange.phase_bands` of the linear
    frequencies ``freqs_hz``, so that the little of mode 1 in q2 does not set q2's phase), their advances over the span
    give ``r = Δθ2 / Δθ1``, and the label minimises the slow phase's advance ``n |r − m/n| Δθ1``
    (:func:`analysis.exchange.slowest_phase_ratio`). The detector labels by a least-squares phase-lock fit of its own
    band-passed states (:func:`analysis.exchange.lock_fit`); the lock truth of §8 used that same fit on exact data."""
    q = np.asarray(modal_q, dtype=float)
    if q.shape[0] < 16 or not t1 > t0:
        return None
    bands = phase_bands(np.asarray(freqs_hz, float)[:3], fs)
    th = []
    for j in (0, 1):
        sos = scipy.signal.butter(2, bands[j], "bandpass", fs=fs, output="sos")
        th.append(np.unwrap(np.angle(scipy.signal.hilbert(scipy.signal.sosfiltfilt(sos, q[:, j])))))
    a, b = max(0, round(t0 * fs)), min(q.shape[0] - 1, round(t1 * fs))
    d1, d2 = th[0][b] - th[0][a], th[1][b] - th[1][a]
    if b <= a or not d1 > 0:
        return None
    r = float(d2 / d1)
    return slowest_phase_ratio(r, ratios), r


def zigzag(x: FloatArray, hysteresis: float = DEFAULT_HYSTERESIS) -> list[tuple[int, int]]:
    """Alternating extrema ``(index, +1 max | -1 min)`` of a positive signal, each confirmed by a move of ``hysteresis``.

    A minimum is confirmed when the signal later exceeds it by the factor ``hysteresis`` (before going
    lower), a maximum when the signal later falls below it by that factor. The pending extremum at
    the end of the record is appended unconfirmed, so a rise still under way at the end is kept.
    """
    if hysteresis <= 1.0:
        raise ValueError("hysteresis must be > 1")
    x = np.asarray(x, dtype=float)
    out: list[tuple[int, int]] = []
    if x.size == 0:
        return out
    trend = 0
    imin = imax = 0
    for i in range(1, x.size):
        xi = x[i]
        if trend == 0:
            if xi < x[imin]:
                imin = i
            if xi > x[imax]:
                imax = i
            if xi >= hysteresis * x[imin]:
                out.append((imin, -1))
                trend, imax = 1, i
            elif xi * hysteresis <= x[imax]:
                out.append((imax, 1))
                trend, imin = -1, i
        elif trend == 1:
            if xi > x[imax]:
                imax = i
            elif xi * hysteresis <= x[imax]:
                out.append((imax, 1))
                trend, imin = -1, i
        else:
            if xi < x[imin]:
                imin = i
            elif xi >= hysteresis * x[imin]:
                out.append((imin, -1))
                trend, imax = 1, i
    if trend == 1:
        out.append((imax, 1))
    elif trend == -1:
        out.append((imin, -1))
    return out


def major_exchanges(
    modal_q: FloatArray,
    modal_energy: FloatArray,
    fs: float,
    pulse_end_s: float,
    window_s: float = DEFAULT_WINDOW_S,
    ratios: Sequence[tuple[int, int]] = DEFAULT_RATIOS,
    factor: float = 2.0,
    *,
    input_work: float | None = None,
    floor_rel: float = DEFAULT_FLOOR_REL,
    hysteresis: float = DEFAULT_HYSTERESIS,
    label_rule: str = "lock",
    freqs_hz: Sequence[float] | None = None,
) -> list[Exchange]:
    """Major exchanges into mode 2 (column 1) of one record; see the module docstring for the rules.

    ``modal_q`` (N, >= 2) and ``modal_energy`` (N, >= 2) are the simulator's linear modal coordinates
    and energies (``SimulationResult.modal_q[b]``, ``.modal_energy[b]``). ``input_work`` (J) sets the
    floor; when omitted, the total modal energy at the first usable sample stands in for it. ``label_rule``
    "lock" (default since issue 21): m:n from :func:`locked_ratio`, falling back to the rounded zero-crossing f2/f1
    where no candidate is locked; "zero_crossing": issue 6's rounded f2/f1 only (``Exchange.zc_label`` either way);
    "phase": :func:`slow_phase_label` over the interval widened to +-W, the definition independent of the detector
    (issue 29, docs/evaluation.md §11; needs ``freqs_hz``, the linear modes' frequencies).
    """
    if label_rule == "phase" and freqs_hz is None:
        raise ValueError("label_rule 'phase' needs the linear modes' frequencies (freqs_hz)")
    if label_rule not in ("lock", "zero_crossing", "phase"):
        raise ValueError("label_rule must be 'lock', 'zero_crossing' or 'phase'")
    q = np.asarray(modal_q, dtype=float)
    E = np.asarray(modal_energy, dtype=float)
    if q.ndim != 2 or q.shape[1] < 2 or E.shape[0] != q.shape[0] or E.shape[1] < 2:
        raise ValueError("modal_q and modal_energy must be (N, >= 2) with the same N")
    if factor <= 1.0:
        raise ValueError("factor must be > 1")
    n = q.shape[0]
    half = 0.5 * window_s
    i0 = int(np.ceil((pulse_end_s + half) * fs))
    i1 = int(np.floor((n - 1) - half * fs))
    if i1 - i0 < 2:
        return []
    Es = modal_energy_smoothed(E, fs, window_s)
    e2 = Es[i0 : i1 + 1, 1]
    e1 = Es[i0 : i1 + 1, 0]
    work = float(np.sum(Es[i0])) if input_work is None else float(input_work)
    floor = floor_rel * work
    ext = zigzag(np.maximum(e2, np.finfo(float).tiny), hysteresis)
    out: list[Exchange] = []
    theta1: FloatArray | None = None
    for (ia, ka), (ib, kb) in pairwise(ext):
        if ka != -1 or kb != 1:
            continue
        gain = e2[ib] / max(e2[ia], np.finfo(float).tiny)
        if gain < factor or e2[ib] < floor:
            continue
        ts, te = (i0 + ia) / fs, (i0 + ib) / fs
        centre = 0.5 * (ts + te)
        hw = max(0.5 * (te - ts), window_s)
        f = instantaneous_frequencies(q[:, :2], fs, [centre], hw)[0]
        f1, f2 = float(f[0]), float(f[1])
        m, nn = nearest_ratio(f2 / f1, ratios) if np.isfinite(f1) and np.isfinite(f2) and f1 > 0 else (0, 0)
        zc = f"{m}:{nn}"
        if label_rule == "lock":
            theta1 = giving_phase(q[:, 0]) if theta1 is None else theta1
            locked = locked_ratio(q[:, 1], theta1, fs, centre, f1, ratios, bounds_s=(pulse_end_s, (n - 1) / fs))
            m, nn = locked if locked is not None else (m, nn)
        elif label_rule == "phase":
            lab = slow_phase_label(q, fs, freqs_hz, max(centre - hw, pulse_end_s), min(centre + hw, (n - 1) / fs), ratios)
            m, nn = lab[0] if lab is not None else (m, nn)
        rel = float(e2[ib] / work) if work > 0 else float("nan")
        out.append(Exchange(ts, te, float(gain), m, nn, f1, f2, rel, float(e2[ib] / e1[ib]) if e1[ib] > 0 else float("inf"), zc))
    return out
