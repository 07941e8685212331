"""Slow-flow phase analysis that confirms an internal resonance (IR) between two IMFs.

An m:n IR between two components is the failure of averaging over the slow angle
Φ_{m:n} = m·θ̂_a − n·θ̂_b (eqs. 2.41, 2.56–2.58): while the fast phases satisfy m·ω_a ≈ n·ω_b, Φ stops
drifting and its trajectory (Φ, Φ̇) becomes *non-time-like* — small loops about Φ̇ = 0 over a small phase
range (eqs. 3.19, 3.28, 4.2, 4.4; L978–L986, L1275, L1298). The seed reads these loops off plots; this
module turns that reading into a detector with named thresholds (method-wbemd-slowflow §5 step 5 and its CHOICE).

Label convention (method-wbemd-slowflow §4.3 DERIVED): ``Φ_{m:n} = m θ̂_low − n θ̂_high`` with the lower-frequency component
first, so an m:n label means ω_high ≈ (m/n)·ω_low (Φ_{3:1} = 3θ̂_1 − θ̂_2: ω_2 ≈ 3ω_1).

Choices (the seed leaves them open; ``docs/slowflow.md`` says how they were calibrated):

* θ̂ is the unwrapped four-quadrant Hilbert phase and ω̂ its derivative, low-passed with a zero-phase
  Butterworth (:func:`analysis.wavelet.analytic`; 1 Hz in the beam case, L961). Φ̇ is built from the
  *filtered* frequencies (method-wbemd-slowflow §5 step 3) and Φ is low-passed with the same filter before the range test,
  so the Hilbert ripple (L451–L452) neither adds spurious sign changes nor inflates the phase range.
* Non-time-like = a chain of at least ``min_sign_changes`` reversals of Φ (sign changes of Φ̇ outside a
  dead band) whose successive Φ excursions stay under ``max_phase_range`` (loops, not a drift); [T1, T2]
  runs from the first to the last reversal of the chain. A first version used a fixed sliding window
  (method-wbemd-slowflow §5 CHOICE); it missed the beam's ~1 s capture because any window long enough to hold two loops of
  the slower synthetic wobble also reached into the drift on both sides (docs/slowflow.md).
* Net drift: a drift Φ = Dt + A·sin(ωt) with A·ω > D reverses every wobble period, and its short
  backward swings form chains, yet Φ advances every period; a captured Φ librates about a centre
  (eq. 4.2, L1275). Chains whose loops advance on balance by more than ``max_net_drift`` of their Φ path
  are dropped (:func:`net_drift`).
* Reversals closer than ``end_guard`` to either end of the record are not trusted: the seed distrusts
  loops near the signal ends (L1314) and accepts one only with ≥ 0.3 s of signal after the escape
  (L1426). A chain reaching into the guard is kept whole but marked ``end_effect`` (never confirms), and
  its reversals outside the guard form a trusted interval if at least ``min_sign_changes`` remain. A
  record no longer than two guards cannot be tested, and the Confirmation's reason says so.
* Ratio test (L1296–L1298): for an m:n label the candidates (m−2 … m+2):n (reduced fractions only) are
  scanned; the best candidate must have a captured interval, and the bracketing rule must hold inside it:
  the drift of (m−1):n and (m+1):n runs in opposite directions (Φ̇ < 0 below, > 0 above the true ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from analysis.runs import true_runs
from analysis.wavelet import AnalyticMemo

FloatArray = NDArray[np.float64]

#: default cut-off of the instantaneous-frequency low-pass, as a fraction of the lower component's mean
#: frequency. 0.2 × ~5 Hz ≈ 1 Hz reproduces the seed's beam choice (L961) and scales with faster signals.
LOWPASS_FRACTION = 0.2
#: stored trajectories are decimated to at most this many points.
MAX_TRAJECTORY_POINTS = 2000


@dataclass(frozen=True)
class DetectorParams:
    """Thresholds of the non-time-like detector (method-wbemd-slowflow §5 step 5 CHOICE); calibration in docs/slowflow.md.

    ``max_phase_range``: largest Φ excursion (rad) between two successive reversals of Φ that still
    counts as one loop — a captured slow angle stays within one turn.
    ``min_sign_changes``: Φ̇ reversals needed in a chain, ≥ 2 (two = one loop; one is a mere passage).
    ``max_gap_cycles``: successive reversals further apart than this many cut-off periods are not chained
    (a loop's reversals come every few slow periods; without this bound a loose ``max_phase_range`` let
    the filter's start-up transient chain onto a capture seconds later and drag it into the end guard).
    ``dead_band_rel``: Φ̇ must leave ±dead_band_rel·m·mean(ω_a) for a sign change to count (rejects
    rounding chatter about zero, e.g. a linear 1:1 pair whose Φ̇ is identically ~0).
    ``end_guard_s``: reversals this close to the record ends are not trusted; a chain reaching into the
    guard is reported whole as ``end_effect`` and, trimmed to its reversals outside the guard, as a trusted
    interval when enough reversals remain. ``None`` means max(``end_guard_min_s``, 1/cut-off) — the seed's
    0.3 s (L1426) or the filter's own end transient, whichever is longer.
    ``max_net_drift``: a chain whose loops advance Φ on balance by more than this fraction of their Φ
    path is a drift with a wobble, not a capture (:func:`net_drift`; a chain of two reversals is judged
    with its neighbouring reversals, a single loop of three is not judged). A captured slow angle
    librates about a fixed or slowly moving centre, so its loops close (L986; eq. 4.2, L1275:
    mθ̂_1 − nθ̂_2 ≈ const), while a time-like drift Φ = Dt + A·sin(ωt) with A·ω > D reverses every wobble
    period yet advances a = 2πD/ω per loop. With b its backward swing the fraction is a/(2b + a), and
    1/3 ⇔ a = b ⇔ successive loops overlap by half their Φ range: a capture's loops must overlap by more.
    Calibration in docs/slowflow.md.
    """

    max_phase_range: float = 2.0 * math.pi
    min_sign_changes: int = 2
    max_gap_cycles: float = 3.0
    dead_band_rel: float = 0.002
    end_guard_s: float | None = None
    end_guard_min_s: float = 0.3
    max_net_drift: float = 1.0 / 3.0

    def __post_init__(self) -> None:
        if self.max_gap_cycles <= 0 or self.max_phase_range <= 0 or self.min_sign_changes < 2:
            raise ValueError("DetectorParams: max_gap_cycles and max_phase_range must be > 0, min_sign_changes >= 2")
        if not 0 < self.max_net_drift <= 1:
            raise ValueError("DetectorParams: max_net_drift must lie in (0, 1]")
        if self.dead_band_rel < 0 or self.end_guard_min_s < 0:
            raise ValueError("DetectorParams: dead_band_rel and end_guard_min_s must be >= 0")


@dataclass(frozen=True)
class Trajectory:
    """Phase trajectory of one m:n pairing: Φ (low-passed, rad) and Φ̇ (rad/s) at times ``t`` (s)."""

    m: int
    n: int
    t: FloatArray
    phi: FloatArray
    phi_dot: FloatArray
    lowpass_hz: float
    dead_band: float  # rad/s

    def decimated(self, max_points: int = MAX_TRAJECTORY_POINTS) -> Trajectory:
        """Every k-th sample so that at most ``max_points`` remain (for storage/plots only)."""
        k = max(1, math.ceil(self.t.size / max_points))
        return Trajectory(self.m, self.n, self.t[::k], self.phi[::k], self.phi_dot[::k], self.lowpass_hz, self.dead_band)


@dataclass(frozen=True)
class Interval:
    """A non-time-like interval [start_s, end_s] of one phase variable."""

    start_s: float
    end_s: float
    strength: float  # reversals × (1 − median Φ excursion between reversals / max_phase_range)
    sign_changes: int  # Φ̇ reversals inside [start_s, end_s]
    phase_range: float  # rad, range of Φ inside [start_s, end_s]
    end_effect: bool  # reaches into the end guard, never trusted (L1314, L1426)
    net_drift: float = math.nan  # net advance / Φ path over its loops (:func:`net_drift`); nan: not judged


@dataclass(frozen=True)
class RatioTest:
    """One candidate m:n: its non-time-like intervals, drift direction and captured fraction."""

    m: int
    n: int
    intervals: tuple[Interval, ...]
    drift_sign: int  # sign of the median Φ̇ over the time-like (not captured, not end-guarded) samples
    captured_fraction: float  # fraction of the record inside intervals that are not end effects
    strength: float  # sum of the strengths of the intervals that are not end effects

    @property
    def trusted(self) -> tuple[Interval, ...]:
        return tuple(iv for iv in self.intervals if not iv.end_effect)


@dataclass(frozen=True)
class Confirmation:
    """Outcome of :func:`test_ratios` for the best candidate (``m``, ``n``)."""

    status: Literal["confirmed", "not_confirmed"]
    m: int
    n: int
    start_s: float  # nan when nothing was captured
    end_s: float
    candidates: tuple[RatioTest, ...]
    bracketed: bool  # (m−1):n and (m+1):n drift in opposite directions inside [start_s, end_s]
    reason: str
    t: FloatArray = field(repr=False)  # trajectory of the best candidate, decimated to ≤ 2000 points
    phi: FloatArray = field(repr=False)
    phi_dot: FloatArray = field(repr=False)

    @property
    def confirmed(self) -> bool:
        return self.status == "confirmed"


def phase_variable(
    theta_a: ArrayLike,
    theta_b: ArrayLike,
    m: int,
    n: int,
    omega_a: ArrayLike | None = None,
    omega_b: ArrayLike | None = None,
    fs: float | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Φ = m·θ̂_a − n·θ̂_b and Φ̇ = m·ω̂_a − n·ω̂_b (eqs. 2.57–2.58, 3.19, 3.28, 4.4).

    ``theta_*`` are unwrapped phases (rad) of the lower (a) and higher (b) component. Φ̇ comes from the
    low-passed instantaneous angular frequencies ``omega_*`` (rad/s) when given — the seed's choice, since
    a raw phase derivative carries the Hilbert ripple (L451, L961) — otherwise from dΦ/dt (needs ``fs``).
    """
    _check_ratio(m, n, "phase_variable")
    ta = np.asarray(theta_a, dtype=np.float64)
    tb = np.asarray(theta_b, dtype=np.float64)
    if ta.shape != tb.shape or ta.ndim != 1:
        raise ValueError(f"phase_variable: theta_a and theta_b must be 1-D of equal length, got {ta.shape} and {tb.shape}")
    phi = m * ta - n * tb
    if omega_a is not None and omega_b is not None:
        wa = np.asarray(omega_a, dtype=np.float64)
        wb = np.asarray(omega_b, dtype=np.float64)
        if wa.shape != ta.shape or wb.shape != ta.shape:
            raise ValueError("phase_variable: omega_a/omega_b must have the shape of the phases")
        return phi, m * wa - n * wb
    if fs is None:
        raise ValueError("phase_variable: give omega_a and omega_b, or fs to differentiate Φ")
    return phi, np.gradient(phi) * fs


Component = ArrayLike | AnalyticMemo
"""A component as an array, or as its :class:`~analysis.wavelet.AnalyticMemo` (the caller asks for it again)."""


def memo(c: Component, fs: float) -> AnalyticMemo:
    """``c``'s analytic-signal memo: ``c`` itself when it is one (at the same ``fs``), else a new one."""
    if isinstance(c, AnalyticMemo):
        if c.fs != fs:
            raise ValueError(f"slowflow: a component analysed at fs = {c.fs} Hz was given with fs = {fs} Hz")
        return c
    return AnalyticMemo(c, fs)


def mean_frequency_hz(c: Component, fs: float) -> float:
    """Mean frequency of a component: the slope of its unwrapped Hilbert phase over the record."""
    ph = memo(c, fs)(None).phase
    return abs(ph[-1] - ph[0]) / (2.0 * math.pi) * fs / max(ph.size - 1, 1)


def default_lowpass_hz(comp_low: Component, fs: float) -> float:
    """``LOWPASS_FRACTION`` × the mean frequency of the lower component (unwrapped-phase slope)."""
    f_mean = mean_frequency_hz(comp_low, fs)
    if not f_mean > 0:
        raise ValueError("default_lowpass_hz: the lower component has no oscillation; pass lowpass_hz explicitly")
    return LOWPASS_FRACTION * f_mean


def trajectory(
    comp_low: Component,
    comp_high: Component,
    fs: float,
    m: int,
    n: int,
    lowpass_hz: float | None = None,
    params: DetectorParams = DetectorParams(),
    t0: float = 0.0,
) -> Trajectory:
    """Phase trajectory (Φ, Φ̇) of Φ_{m:n} between two components sampled at ``fs`` (method-wbemd-slowflow §5 steps 3–5).

    The components may be given as :class:`~analysis.wavelet.AnalyticMemo` (several trajectories of the same
    two: their Hilbert transforms are computed once; the numbers are the same)."""
    _check_ratio(m, n, "trajectory")
    a, b = (c.c if isinstance(c, AnalyticMemo) else np.asarray(c, dtype=np.float64) for c in (comp_low, comp_high))
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"trajectory: components must be 1-D of equal length, got {a.shape} and {b.shape}")
    ma, mb = memo(comp_low, fs), memo(comp_high, fs)
    lp = default_lowpass_hz(ma, fs) if lowpass_hz is None else float(lowpass_hz)
    ia = ma(lp)
    ib = mb(lp)
    two_pi = 2.0 * math.pi
    phi, phi_dot = phase_variable(ia.phase, ib.phase, m, n, two_pi * ia.frequency_hz, two_pi * ib.frequency_hz)
    sos = signal.butter(3, lp, btype="low", fs=fs, output="sos")
    phi = signal.sosfiltfilt(sos, phi, padlen=min(phi.size - 1, 3 * (2 * sos.shape[0] + 1)))
    dead_band = params.dead_band_rel * m * two_pi * float(np.mean(np.abs(ia.frequency_hz)))
    t = t0 + np.arange(a.size) / fs
    return Trajectory(m, n, t, phi, phi_dot, lp, dead_band)


def _sign_flips(x: FloatArray, dead_band: float) -> NDArray[np.bool_]:
    """flips[i] is True when the hysteresis sign of x changes between samples i and i+1."""
    s = np.where(x > dead_band, 1, np.where(x < -dead_band, -1, 0))
    idx = np.where(s != 0, np.arange(s.size), 0)
    np.maximum.accumulate(idx, out=idx)
    held = s[idx]  # forward-filled sign; 0 only before the first excursion
    return (held[1:] != held[:-1]) & (held[:-1] != 0)


def end_guard_s(lowpass_hz: float, params: DetectorParams) -> float:
    """Time (s) at each record end in which reversals are not trusted (L1314, L1426; ``DetectorParams``).

    1/cut-off stays the filter term. Measured from the impulse response of the zero-phase 3rd-order
    Butterworth (what ``sosfiltfilt`` leaves at an end), |response| stays above 5 % of its peak until
    0.88/cut-off, above 2 % until 0.97/cut-off and above 1 % until 1.43/cut-off: a settling time taken
    from it at the usual 2–5 % levels is 1/cut-off within 12 %, so it would not shorten the guard.
    """
    if params.end_guard_s is not None:
        return params.end_guard_s
    return max(params.end_guard_min_s, 1.0 / lowpass_hz)


def detect_non_time_like(traj: Trajectory, params: DetectorParams = DetectorParams()) -> tuple[Interval, ...]:
    """Non-time-like intervals of a phase trajectory (method-wbemd-slowflow §5 step 5).

    Why this rule: a time-like Φ drifts monotonically (Φ̇ of one sign, no reversal); a passage through
    the ratio without capture reverses Φ once; a capture makes Φ̇ oscillate about zero while Φ stays
    within a loop (L986, L1275, L1298). So: find the reversals of Φ (hysteresis sign changes of Φ̇),
    chain successive reversals whose Φ excursion is under ``max_phase_range`` and whose spacing is under
    ``max_gap_cycles`` cut-off periods, and report chains of at least ``min_sign_changes`` reversals as
    [first reversal, last reversal]. The loop period is a property of the data, so no fixed window is used.

    Two further rules (docs/slowflow.md): a chain whose loops advance Φ on balance by more than
    ``max_net_drift`` of their path is a wobbling drift and is dropped (:func:`net_drift`); a chain
    reaching into the end guard (L1314, L1426) is reported whole as ``end_effect`` and, trimmed to its
    reversals outside the guard, as a trusted interval if at least ``min_sign_changes`` of them remain.
    """
    t, phi, phi_dot = traj.t, traj.phi, traj.phi_dot
    if t.size < 8:
        return ()
    flips = np.flatnonzero(_sign_flips(phi_dot, traj.dead_band))  # reversal between f and f+1
    if flips.size < params.min_sign_changes:
        return ()
    fs = (t.size - 1) / (t[-1] - t[0])
    near = np.diff(flips) <= params.max_gap_cycles / traj.lowpass_hz * fs  # successive reversals close in time
    exc = np.abs(np.diff(phi[flips]))
    link = (exc < params.max_phase_range) & near
    guard = end_guard_s(traj.lowpass_hz, params)
    ok = (t[flips] - t[0] >= guard) & (t[-1] - t[np.minimum(flips + 1, t.size - 1)] >= guard)  # reversal outside the guard
    out: list[Interval] = []
    for s, e in true_runs(link):  # links s..e join reversals s..e+1
        idx = np.arange(s, e + 2)
        if idx.size < params.min_sign_changes:
            continue
        kept = idx[ok[idx]]  # ok is True on one contiguous block of reversals
        drift = _chain_drift(phi, flips, kept, near) if kept.size else math.nan
        if drift > params.max_net_drift:  # the trustworthy part is a wobbling drift: nothing to show
            continue
        if not (ok[idx[0]] and ok[idx[-1]]):  # reaches into the guard: shown whole, never trusted
            whole = _chain_drift(phi, flips, idx, near)
            if not whole > params.max_net_drift:
                out.append(_interval(traj, flips, idx, exc, params, True, whole))
        if kept.size >= params.min_sign_changes:
            out.append(_interval(traj, flips, kept, exc, params, False, drift))
    return tuple(sorted(out, key=lambda iv: (iv.start_s, iv.end_effect)))


def _chain_drift(phi: FloatArray, flips: NDArray[np.intp], idx: NDArray[np.intp], near: NDArray[np.bool_]) -> float:
    """:func:`net_drift` of the chain of reversals ``idx`` (indices into ``flips``); nan when not judged.

    A chain of three reversals is one loop and is not judged: one loop's advance cannot tell a wobble
    period from a capture inside a passage, whose centre moves with the sweeping detuning (0.32 on the
    synthetic one-loop passage of tests/test_slowflow.py); what marks a drift is the same advance
    repeated, so a longer chain is judged on its own loops. A chain of two reversals is judged together
    with the reversals just before and after it when they are ``near`` (inside the end guard too: they
    only ever reject): a wobbling drift whose forward swings exceed ``max_phase_range`` breaks into such
    two-reversal chains, and only the neighbouring reversals show that it advances every period — the
    loop they form contains a swing beyond ``max_phase_range``, so it is never a capture's own loop.
    """
    lo, hi = int(idx[0]), int(idx[-1])
    if hi - lo == 2:
        return math.nan
    if hi - lo < 2:
        if lo > 0 and near[lo - 1]:
            lo -= 1
        if hi + 1 < flips.size and near[hi]:
            hi += 1
    return net_drift(phi[flips[lo: hi + 1]])


def _interval(
    traj: Trajectory, flips: NDArray[np.intp], idx: NDArray[np.intp], exc: FloatArray, params: DetectorParams,
    end_effect: bool, drift: float,
) -> Interval:  # fmt: skip
    """The interval from the first to the last reversal of the chain ``idx`` (indices into ``flips``)."""
    t, phi = traj.t, traj.phi
    i0, i1 = int(flips[idx[0]]), int(flips[idx[-1]]) + 1
    seg = phi[i0: i1 + 1]
    med = float(np.median(exc[idx[0]: idx[-1]]))
    k = int(idx.size)
    strength = k * max(0.0, 1.0 - med / params.max_phase_range)
    return Interval(float(t[i0]), float(t[i1]), strength, k, float(seg.max() - seg.min()), end_effect, drift)


def net_drift(phi_at_reversals: ArrayLike) -> float:
    """Net advance of Φ per loop as a fraction of the Φ path per loop, over successive reversals.

    Each loop — three successive reversals r_i, r_i+1, r_i+2 — advances Φ(r_i+2) − Φ(r_i) over a path
    |Φ(r_i+1) − Φ(r_i)| + |Φ(r_i+2) − Φ(r_i+1)|; the result is |Σ advances| / Σ paths, in [0, 1], nan for
    fewer than three reversals (no loop, no evidence of drift). A libration about a fixed or slowly moving
    centre gives ≈ 0 (eq. 4.2, L1275: mθ̂_1 − nθ̂_2 ≈ const); a drift Φ = Dt + A·sin(ωt) with A·ω > D gives
    a/(2b + a) with a = 2πD/ω its advance per period and b its backward swing. Summing before dividing
    keeps one irregular loop (a start-up wiggle, a noisy reversal) from hiding a drift over many loops.
    """
    p = np.asarray(phi_at_reversals, dtype=np.float64)
    if p.size < 3:
        return math.nan
    swing = np.abs(np.diff(p))
    path = float(np.sum(swing[:-1] + swing[1:]))
    adv = float(np.sum(p[2:] - p[:-2]))
    return abs(adv) / path if path > 0 else 0.0


def ratio_test(traj: Trajectory, params: DetectorParams = DetectorParams()) -> RatioTest:
    """Intervals, drift direction and captured fraction of one candidate's trajectory."""
    intervals = detect_non_time_like(traj, params)
    t = traj.t
    guard = end_guard_s(traj.lowpass_hz, params)
    free = (t - t[0] >= guard) & (t[-1] - t >= guard)
    captured = np.zeros(t.size, dtype=bool)
    for iv in intervals:
        inside = (t >= iv.start_s) & (t <= iv.end_s)
        free &= ~inside
        if not iv.end_effect:
            captured |= inside
    drift = int(np.sign(np.median(traj.phi_dot[free]))) if free.any() else 0
    trusted = [iv for iv in intervals if not iv.end_effect]
    return RatioTest(traj.m, traj.n, intervals, drift, float(captured.mean()), float(sum(iv.strength for iv in trusted)))


def candidate_ratios(m: int, n: int, span: int = 2) -> list[tuple[int, int]]:
    """(m−span … m+span):n, reduced fractions only (4:2 is the 2:1 resonance, L1296)."""
    _check_ratio(m, n, "candidate_ratios")
    return [(k, n) for k in range(max(1, m - span), m + span + 1) if math.gcd(k, n) == 1]


def test_ratios(
    comp_low: Component,
    comp_high: Component,
    fs: float,
    m: int,
    n: int,
    span: int = 2,
    lowpass_hz: float | None = None,
    params: DetectorParams = DetectorParams(),
    t0: float = 0.0,
    trajectories: dict[tuple[int, int], Trajectory] | None = None,
) -> Confirmation:
    """Test a suspected m:n IR between two IMFs (lower-frequency first) against its neighbours.

    Follows L1296–L1298: scan (m−2 … m+2):n, keep the candidate with the strongest trusted non-time-like
    behaviour, and require the bracketing rule inside its interval — (m*−1):n drifts with Φ̇ < 0 and
    (m*+1):n with Φ̇ > 0, i.e. the ratio really sits between them. Returns a :class:`Confirmation` whose
    trajectory arrays are those of the best candidate (or of the label when nothing was captured).
    ``trajectories``: k:n → :func:`trajectory` of these same inputs, already computed by the caller (who also
    reads them); any candidate missing from it is computed here, all on one Hilbert transform of each component
    (:class:`~analysis.wavelet.AnalyticMemo`; pass memos to share them with the caller).
    """
    comp_low, comp_high = memo(comp_low, fs), memo(comp_high, fs)
    lp = default_lowpass_hz(comp_low, fs) if lowpass_hz is None else float(lowpass_hz)
    given = trajectories or {}
    trajs = {
        r: given.get(r) or trajectory(comp_low, comp_high, fs, r[0], r[1], lp, params, t0) for r in candidate_ratios(m, n, span)
    }
    tests = tuple(ratio_test(tr, params) for tr in trajs.values())
    live = [rt for rt in tests if rt.trusted]
    if not live:
        tr = trajs.get((m, n)) or trajectory(comp_low, comp_high, fs, m, n, lp, params, t0)
        guard, span_s = end_guard_s(lp, params), float(tr.t[-1] - tr.t[0])
        if span_s <= 2.0 * guard:  # no reversal can lie outside both guards: say so instead of a bare "no"
            why = f"record too short for the slow-flow test: needs > 2×guard = {2.0 * guard:.2f} s, got {span_s:.2f} s"
            if params.end_guard_s is None:
                why += f" (guard = max({params.end_guard_min_s:g} s, 1/cut-off = 1/{lp:.2f} Hz))"
        else:
            why = "no candidate has a non-time-like interval away from the record ends"
        return _confirmation("not_confirmed", m, n, math.nan, math.nan, tests, False, why, tr)
    best = max(live, key=lambda rt: rt.strength)
    iv = max(best.trusted, key=lambda x: x.strength)
    signs = []
    for k in (best.m - 1, best.m + 1):
        if k < 1:
            continue
        tr = trajs.get((k, best.n)) or trajectory(comp_low, comp_high, fs, k, best.n, lp, params, t0)
        inside = (tr.t >= iv.start_s) & (tr.t <= iv.end_s)
        signs.append((k, int(np.sign(np.mean(tr.phi_dot[inside])))))
    bracketed = all(s == (-1 if k < best.m else 1) for k, s in signs)
    status: Literal["confirmed", "not_confirmed"] = "confirmed" if bracketed else "not_confirmed"
    reason = (f"{best.m}:{best.n} non-time-like over {iv.start_s:.2f}–{iv.end_s:.2f} s, "
              f"neighbour drift signs {signs}{'' if bracketed else ' do not bracket the ratio'}")  # fmt: skip
    return _confirmation(status, best.m, best.n, iv.start_s, iv.end_s, tests, bracketed, reason, trajs[(best.m, best.n)])


test_ratios.__test__ = False  # type: ignore[attr-defined]  # not a pytest test despite its (spec-given) name


def _confirmation(status, m, n, start, end, tests, bracketed, reason, tr: Trajectory) -> Confirmation:
    d = tr.decimated()
    return Confirmation(status, m, n, float(start), float(end), tests, bool(bracketed), reason, d.t, d.phi, d.phi_dot)


def _check_ratio(m: int, n: int, where: str) -> None:
    if int(m) != m or int(n) != n or m < 1 or n < 1:
        raise ValueError(f"{where}: m and n must be positive integers, got {m}:{n}")
