"""Confirm a flagged internal resonance: WBEMD of one sensor's displacement, then the slow flow (seed Ch. 3–4).

The near-live detector (analysis/exchange.py) flags "mode r gave energy to mode s at about m:n". The seed
proves such a flag by decomposing the response into well-separated components (WBEMD, eqs. 3.4–3.11)
and showing that the slow phase Φ_{m:n} = mθ̂_low − nθ̂_high of the two components stops drifting
(non-time-like loops, L986, L1298). This module does that for one event's stretch of data:

1. accelerations → displacements by the seed's §4.3 chain, zero-phase (batch data), with the high-pass
   corners lowered to half the giving mode's frequency when the seed's 18/10 Hz would eat it
   (docs/preprocessing.md: the 18 Hz filter keeps 0.71 of a 21 Hz mode);
2. the sensor: the one where both modes of the event are most visible (largest min over the two modes of
   |φ_k(s)| / max|φ_k|, mode shapes of the rig's Guyan model at the sensors);
3. characteristic frequencies: the MWT peaks of that displacement (L769, L478), with the event's two
   frequencies put in when no peak lies within ``match_rel`` of them; WBEMD into those components;
4. the two IMFs nearest the event's frequencies go to :func:`analysis.slowflow.test_ratios`, which scans
   (m−2 … m+2):n and applies the bracketing rule (L1296–L1298).

The record (a plain dict, the ``/analysis/confirmations`` message) carries the confirmed ratio and interval,
"other_ratio" (a resonance at another m:n than the event's: not a confirmation of the event) or
"not_confirmed", the candidates, the (Φ, Φ̇) trajectory decimated for display, the IMF frequencies and the
orthogonality index.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.linalg
import scipy.signal
from numpy.typing import NDArray

from analysis.preprocess import PreprocessSettings, acc_to_disp
from analysis.records import OTHER_RATIO, Confirmation
from analysis.slowflow import Component, DetectorParams, candidate_ratios, mean_frequency_hz, memo, test_ratios, trajectory
from analysis.wavelet import AnalyticMemo

if TYPE_CHECKING:  # the decomposition (PyEMD, ~30 MB) is imported where it runs: in the confirmation worker
    from analysis.wbemd import WbemdParams


@dataclass(frozen=True)
class ConfirmSettings:
    n_imfs: int = 4  # components WBEMD extracts (the seed's experiment: 4 IMFs, L1316–L1445)
    pre_s: float = 0.5  # data before the event's start given to the decomposition (>= the slow-flow end guard, 0.3 s)
    post_s: float = 0.5  # data after the event's end (seed L1426: a loop needs >= 0.3 s of signal after escape)
    match_rel: float = 0.3  # an MWT peak within this fraction of an event frequency stands for it (a hardening
    # mode sweeps ~20 % within one segment; the two modes of an event are >= 2x apart)
    f_max_factor: float = 4.0  # MWT peak search up to this × the higher event frequency
    vel_corner_hz: float = 18.0  # seed §4.3 (L1322–L1323), lowered to half the giving mode when above it
    disp_corner_hz: float = 10.0
    lowpass_hz: float | None = None  # instantaneous-frequency low-pass (None: slowflow's default for the data)
    span: int = 2  # candidates (m−span … m+span):n (L1296)
    min_gain: float = 1.5  # receiving IMF's energy (amplitude²) end / start of the event, slow-angle test
    max_turn: float = 2.0 * math.pi  # largest Φ range over the event for a slow angle (one turn)
    overlap_s: float = 0.1  # captured loops must overlap the event interval widened by this much
    wbemd: WbemdParams | None = None  # None: WbemdParams() — the text's values
    detector: DetectorParams | None = None  # None: DetectorParams() — docs/slowflow.md
    fast: bool = True  # issue 21: banded MWTs for the peak pick and the bound test (docs/confirmation.md "Speed");
    # False: the path before it (full-CWT peak pick, zoom MWT), kept so bench/bench_confirm.py times both in one run


@dataclass(frozen=True)
class ConfirmContext:
    """What a confirmation needs of the rig (small and picklable: it travels to the worker process)."""

    sensors: tuple[str, ...]
    shapes: NDArray[np.float64]  # (n_sensors, n_modes) Guyan mode shapes at the sensors, ascending frequency
    settings: ConfirmSettings = ConfirmSettings()

    def span_s(self, event: Mapping[str, Any]) -> tuple[float, float]:
        """The stretch of data one event's confirmation uses: ``pre_s`` before its start to ``post_s`` after its
        end (never before the stream's start). The lane, ``gvt confirm`` and the evaluation all cut this."""
        s = self.settings
        return max(0.0, float(event["start_s"]) - s.pre_s), float(event["end_s"]) + s.post_s

    @classmethod
    def from_model(cls, model, settings: ConfirmSettings = ConfirmSettings()) -> ConfirmContext:
        """From an :class:`analysis.operator.RigModel` (Guyan M, K at the sensors, sensors in model order)."""
        _w2, phi = scipy.linalg.eigh(model.K, model.M)
        return cls(sensors=tuple(model.sensors), shapes=np.asarray(phi), settings=settings)


def pick_sensor(shapes: NDArray[np.float64], modes: tuple[int, int]) -> int:
    """Index of the sensor where both (1-based) modes are most visible: max over s of min_k |φ_k(s)|/max|φ_k|."""
    cols = [k - 1 for k in modes]
    if min(cols) < 0 or max(cols) >= shapes.shape[1]:
        raise ValueError(f"modes {modes} outside the model's {shapes.shape[1]} modes")
    a = np.abs(shapes[:, cols])
    return int(np.argmax(np.min(a / a.max(axis=0), axis=1)))


def _frequencies(x: NDArray[np.float64], fs: float, f_a: float, f_b: float, s: ConfirmSettings) -> NDArray[np.float64]:
    from analysis.wbemd import characteristic_frequencies

    lo, hi = min(f_a, f_b), max(f_a, f_b)
    f_max = min(s.f_max_factor * hi, 0.4 * fs)
    engine = "banded" if s.fast else "cwt"
    peaks = list(characteristic_frequencies(x, fs, s.n_imfs, 0.5 * lo, f_max, at_most=True, engine=engine))
    for f in (f_a, f_b):
        near = [p for p in peaks if abs(p - f) <= s.match_rel * f]
        if near:
            peaks.remove(min(near, key=lambda p: abs(p - f)))
        elif len(peaks) >= s.n_imfs:
            peaks.remove(min((p for p in peaks if all(abs(p - g) > s.match_rel * g for g in (f_a, f_b))),
                             key=lambda p: abs(np.log(p / f)), default=peaks[-1]))  # fmt: skip
        peaks.append(f)
    out = np.sort(np.asarray(peaks, dtype=np.float64))
    keep = np.concatenate([[True], np.diff(out) > 0.05 * out[1:]])  # distinct components only
    return out[keep]


@dataclass(frozen=True)
class SlowAngle:
    """The slow-angle test of one event (seed L574: near resonance Φ_{k:l} is a slow angle; finding one
    shows the resonance). ``phase_range`` per candidate is the range of Φ_{m:n} over the event interval."""

    ratio: tuple[int, int]  # the candidate whose Φ moves least over the event
    phase_range: dict[tuple[int, int], float]
    gain: float  # energy gain of the higher-frequency IMF over the event (amplitude² end / start)
    passed: bool


def slow_angle_test(low: Component, high: Component, fs: float, t0_s: float, start_s: float, end_s: float, m: int, n: int,
                    s: ConfirmSettings) -> SlowAngle:  # fmt: skip
    """Is Φ_{m:n} a slow angle while the higher component gains energy (the exchange the detector flagged)?

    Three conditions, all physical: (1) the higher IMF's energy grows by ``min_gain`` over the event — an
    exchange seen in one sensor's WBEMD component, independent of the detector's modal filter; (2) of the
    candidates (m−2 … m+2):n the slowest angle over the event is the confirmed ratio — the bracketing rule
    (L1298) in its integral form: the neighbours drift faster on either side; (3) that angle moves less
    than ``max_turn`` over the event (the averaged energy flow ∝ sin Φ keeps its direction for a half
    turn; one turn allows for the ramp in and out). Captured loops (non-time-like, :mod:`analysis.slowflow`)
    are the stronger evidence and reported separately. ``low``/``high`` may be the caller's
    :class:`~analysis.wavelet.AnalyticMemo` of the two IMFs (shared with :func:`analysis.slowflow.test_ratios`).
    """
    low, high = memo(low, fs), memo(high, fs)
    lp = 0.25 * mean_frequency_hz(low, fs)
    t = t0_s + np.arange(low.c.size) / fs
    sel = (t >= start_s) & (t <= end_s)
    if sel.sum() < 4:
        raise ValueError(f"event {start_s:.3f}–{end_s:.3f} s has fewer than 4 samples in its segment")
    ranges = {}
    for r in candidate_ratios(m, n, s.span):
        tr = trajectory(low, high, fs, r[0], r[1], lowpass_hz=lp, t0=t0_s)
        ranges[r] = float(np.ptp(tr.phi[sel]))
    best = min(ranges, key=ranges.get)
    amp = high(None).amplitude
    sos = scipy.signal.butter(3, min(0.25 * mean_frequency_hz(high, fs), 0.4 * fs), fs=fs, output="sos")
    amp = scipy.signal.sosfiltfilt(sos, amp)
    a = amp[sel]
    gain = float((a[-1] / a[0]) ** 2) if a[0] > 0 else float("inf")
    return SlowAngle(best, ranges, gain, bool(gain >= s.min_gain and ranges[best] < s.max_turn))


def _against_the_event(status: str, found: tuple, event: tuple[int, int], reason: str) -> tuple[str, str]:
    """A resonance found at another m:n than the event's does not confirm the event (issue 29): the demo's 3:1
    event whose slowest angle was Φ_2:1 read ``confirmed`` with "found 2:1". It is ``other_ratio``, its own
    status, with the ratio found kept in the record and said first in the reason; a test engineer then knows the
    detector's label is in question, not the exchange."""
    if status != "confirmed" or tuple(found) == tuple(event):
        return status, reason
    return OTHER_RATIO, f"found {found[0]}:{found[1]}, not the event's {event[0]}:{event[1]}: {reason}"


def confirm_segment(seg: NDArray, fs: float, t0_s: float, event: Mapping[str, Any], context: ConfirmContext) -> dict:
    """Confirm one IR event on its stretch of sensor accelerations ``seg`` (n, sensors in context order).

    ``t0_s`` is the time of ``seg[0]`` on the stream's clock; times in the record are on that clock too.
    """
    from analysis.wbemd import WbemdParams, wbemd

    t_start = time.perf_counter()
    s = context.settings
    modes = tuple(int(k) for k in event["modes"])
    f_give, f_recv = float(event["f_give_hz"]), float(event["f_recv_hz"])
    m, n = int(event["m"]), int(event["n"])
    # analysis.exchange.LEAK_RATIO (not imported here: that module compiles numba kernels the worker does not need):
    # f_recv near f_give is a leak of the giving mode, not an m:n IR to look for (issue 21)
    if (m, n) == (1, 1):
        return Confirmation.skipped(event, "1:1 event (receiving frequency near the giving mode's): a leak, not an m:n "
                                           "internal resonance; not confirmed").to_json()  # fmt: skip
    if not (math.isfinite(f_give) and math.isfinite(f_recv) and f_give > 0 and f_recv > 0):
        raise ValueError(f"event {event.get('id')}: frequencies {f_give}, {f_recv} Hz are not usable")
    acc = np.asarray(seg, dtype=np.float64)
    if acc.ndim != 2 or acc.shape[1] != len(context.sensors):
        raise ValueError(f"segment of shape {acc.shape} for {len(context.sensors)} sensors")
    f_low = min(f_give, f_recv)
    pre = PreprocessSettings(vel_corner_hz=min(s.vel_corner_hz, 0.5 * f_low), disp_corner_hz=min(s.disp_corner_hz, 0.5 * f_low))
    k = pick_sensor(context.shapes, modes)
    _v, disp = acc_to_disp(acc[:, [k]], fs, pre)
    x = disp[:, 0]
    freqs = _frequencies(x, fs, f_give, f_recv, s)
    params = s.wbemd or WbemdParams()
    dec = wbemd(x, fs, freqs, params=params if s.fast else dataclasses.replace(params, mwt="zoom"))
    i_lo = int(np.argmin(np.abs(dec.char_freqs_hz - f_low)))
    i_hi = int(np.argmin(np.abs(dec.char_freqs_hz - max(f_give, f_recv))))
    examined = {  # the keys of every record whose segment was decomposed (records.Confirmation)
        "event_id": event.get("id"), "event": dict(event), "sensor": context.sensors[k],
        "imf_freqs_hz": dec.char_freqs_hz.tolist(), "orthogonality_index": float(dec.orthogonality_index),
        "segment_s": [t0_s, t0_s + acc.shape[0] / fs],
    }  # fmt: skip
    if i_lo == i_hi:
        return Confirmation(**examined, status="not_confirmed", reason="the two event frequencies fell on one IMF",
                            elapsed_s=time.perf_counter() - t_start).to_json()  # fmt: skip
    # one Hilbert transform of each IMF for the ten slow-flow trajectories and the slow-angle test (AnalyticMemo)
    lo_imf, hi_imf = AnalyticMemo(dec.imfs[i_lo], fs), AnalyticMemo(dec.imfs[i_hi], fs)
    params = s.detector or DetectorParams()
    c = test_ratios(lo_imf, hi_imf, fs, m, n, span=s.span, lowpass_hz=s.lowpass_hz, params=params, t0=t0_s)
    sa = slow_angle_test(lo_imf, hi_imf, fs, t0_s, float(event["start_s"]), float(event["end_s"]), m, n, s)
    ev_lo, ev_hi = float(event["start_s"]) - s.overlap_s, float(event["end_s"]) + s.overlap_s
    captured = c.status == "confirmed" and c.start_s <= ev_hi and c.end_s >= ev_lo and sa.gain >= s.min_gain
    if captured:
        status, evidence, (cm, cn), span = "confirmed", "captured", (c.m, c.n), (c.start_s, c.end_s)
        reason = f"{c.reason}; the {dec.char_freqs_hz[i_hi]:.1f} Hz component gained ×{sa.gain:.2f} in energy"
    elif sa.passed:
        status, evidence, (cm, cn) = "confirmed", "slow_angle", sa.ratio
        span = (float(event["start_s"]), float(event["end_s"]))
        reason = (f"Φ_{cm}:{cn} moved {sa.phase_range[sa.ratio]:.2f} rad (slowest of the candidates) while the "
                  f"{dec.char_freqs_hz[i_hi]:.1f} Hz component gained ×{sa.gain:.2f} in energy")  # fmt: skip
    else:
        status, evidence, (cm, cn), span = "not_confirmed", None, (None, None), (None, None)
        loops = c.reason if c.status != "confirmed" else (
            f"loops at {c.start_s:.3f}–{c.end_s:.3f} s do not overlap the event or come without an energy gain")  # fmt: skip
        reason = (f"no captured loops ({loops}); slow-angle test: gain ×{sa.gain:.2f} (needs {s.min_gain}), "
                  f"slowest Φ_{sa.ratio[0]}:{sa.ratio[1]} moved {sa.phase_range[sa.ratio]:.2f} rad "
                  f"(needs < {s.max_turn:.2f})")  # fmt: skip
    status, reason = _against_the_event(status, (cm, cn), (m, n), reason)
    return Confirmation(
        **examined, status=status, evidence=evidence, reason=reason,
        ratio=f"{cm}:{cn}" if cm is not None else None, m=cm, n=cn,
        label_agrees=status == "confirmed" and (cm, cn) == (m, n),
        start_s=span[0], end_s=span[1], bracketed=bool(c.bracketed),
        slow_angle={"gain": sa.gain, "phase_range": {f"{k[0]}:{k[1]}": v for k, v in sa.phase_range.items()},
                    "slowest": f"{sa.ratio[0]}:{sa.ratio[1]}"},
        candidates=[{"ratio": f"{rt.m}:{rt.n}", "captured_fraction": float(rt.captured_fraction),
                     "intervals": [[iv.start_s, iv.end_s] for iv in rt.intervals if not iv.end_effect],
                     "end_effect_intervals": [[iv.start_s, iv.end_s] for iv in rt.intervals if iv.end_effect],
                     "drift_sign": int(rt.drift_sign)} for rt in c.candidates],
        trajectory={"t": np.asarray(c.t).tolist(), "phi": np.asarray(c.phi).tolist(),
                    "phi_dot": np.asarray(c.phi_dot).tolist()},
        elapsed_s=time.perf_counter() - t_start,
    ).to_json()  # fmt: skip
