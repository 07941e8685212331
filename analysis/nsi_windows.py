"""Experimental-style NSI (seed Ch. 5 §5.3.4–5.3.5, L1704–L1750): windowed δ̄ and POMs from measured hits.

The computational studies reduce each whole simulated run to one (δ̄, f) pair (``analysis/nsi.py``); the seed's
experiment instead cuts each measured impact into non-overlapping windows and gets one pair per window
(digest method-nsi.md §2.2, §1.7–1.8, §1.16):

1. **Displacement from acceleration** by the Ch. 5 chain (L1646, L1664): integrate, 3rd-order Butterworth
   high-pass, integrate, the same high-pass, the temporal mean removed around each step, zero phase
   (``analysis.preprocess.acc_to_disp``; the seed states neither the scheme nor the phase, method-nsi §1.11).
   The seed's corner was 2 Hz for its 8.36 Hz NES, 0.24 of it; the default here keeps that ratio to the
   attachment's linear frequency (:func:`default_settings`) so the filter does not bend the curve it measures.
2. **δ** across the attachment (eq. 5.13) with the Ch. 5 extra 3rd-order high-pass (6 Hz there, L1747: it
   removed 1B, which never engages the NES); here only when a lower mode than the attachment's exists (the
   geometric mean of the two frequencies: the seed's 6 Hz sat between 2.77 and 8.36 Hz) or the rig's
   ``[nsi] delta_highpass_hz`` says so.
3. **Windows**: non-overlapping, ~T/2 of the fundamental (0.174 s for the 2.77 Hz wing, L1704); the forced part
   and what follows the impact are dropped at the start (0.09 s, the load ending at 0.0825 s) and the tail at
   the end (0.471 s, "only NNM1 remains"). Here the start drop is the pulse plus one window (the impulse's
   high modes and the zero-phase filters' start-up), the tail one window (their end effect); both stated.
4. **Per window**: POD (eqs. 2.12–2.13), the attachment's POM by MAC (eq. 5.6), two POMs resembling its mode
   flagged as 1:1 capture and left out (L1747), its RQ frequency (eq. 2.18) or, as ``analysis/nsi.py`` offers,
   the frequency of its temporal coefficient, and δ̄ (eq. 5.2) of the window.

All windows of all hits then form one RQ-FDP and are fitted exactly like a sweep's runs
(``analysis.nsi.rq_fdp`` / ``fit_power_law``). Pure numpy/scipy; one hit's record at a time.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from analysis import nsi
from analysis.errors import BadInput

FloatArray = np.ndarray

#: The seed's integration corner over its NES's linear frequency: 2 Hz / 8.36 Hz (L1646, Table 5.2).
SEED_INTEGRATION_RATIO = 2.0 / 8.362
#: The Ch. 5 filter order everywhere (L1646, L1747).
SEED_ORDER = 3
#: Seed window over the fundamental's period: 0.174 s × 2.769 Hz (L1704, Table 5.2).
SEED_WINDOW_PERIODS = 0.174 * 2.769


@dataclass(frozen=True)
class WindowSettings:
    """How each hit is cut and processed (seconds from the pulse start; corners in Hz, ``None``: no filter).

    The ``pom`` frequency Hilbert-transforms a window's POM temporal coefficient over the whole hit record and
    reads its phase slope inside the window only: the transform's end effects then fall outside it (measured on
    beam_ch4_sim: with one window of padding each side the linear 3.81 Hz read 3.38 Hz)."""

    window_s: float
    skip_s: float
    tail_s: float
    integration_corner_hz: float | None
    delta_corner_hz: float | None
    order: int = SEED_ORDER
    snap: bool = True  # windows of whole half-cycles of δ (half_cycle_windows); False: the seed's fixed length
    similar_mac: float = nsi.SIMILAR_MAC

    def validate(self, fs: float) -> None:
        if not self.window_s > 0 or self.window_s * fs < 8:
            raise BadInput(f"window {self.window_s:g} s holds fewer than 8 samples at {fs:g} Hz")
        if self.skip_s < 0 or self.tail_s < 0:
            raise BadInput("window skip and tail must be >= 0")
        for name in ("integration_corner_hz", "delta_corner_hz"):
            fc = getattr(self, name)
            if fc is not None and not 0 < fc < fs / 2:
                raise BadInput(f"{name.replace('_', ' ')} {fc:g} must lie in (0, fs/2 = {fs / 2:g} Hz)")

    def to_dict(self) -> dict:
        return asdict(self)


def default_settings(
    f_modes_hz: FloatArray, attachment_mode: int, pulse_s: float, delta_corner_hz: float | None = None
) -> WindowSettings:
    """The seed's Ch. 5 choices scaled to this rig's linear modes (``f_modes_hz`` ascending, the low-energy
    linear frequencies at the outputs; ``attachment_mode`` 0-based):

    * window: the seed's 0.174 s is 0.48 of its fundamental's period (2.77 Hz, L1704); the same fraction of the
      lowest mode's period here ("~T/2 of the fundamental");
    * integration high-pass: 0.24 × the attachment's linear frequency (the seed's 2 Hz for 8.36 Hz);
    * δ high-pass: the rig's ``[nsi] delta_highpass_hz`` if given, else the geometric mean of the attachment's
      frequency and the next lower mode's when one exists (the seed's 6 Hz between 2.77 and 8.36 Hz), else none;
    * start drop: the pulse plus one window; tail: one window (module docstring, step 3)."""
    f = np.asarray(f_modes_hz, float)
    if f.size == 0 or not 0 <= attachment_mode < f.size or not np.all(f > 0):
        raise BadInput("window defaults need the positive linear frequencies and the attachment's mode among them")
    win = SEED_WINDOW_PERIODS / float(f[0])
    fa = float(f[attachment_mode])
    if delta_corner_hz is None and attachment_mode > 0:
        delta_corner_hz = math.sqrt(fa * float(f[attachment_mode - 1]))
    return WindowSettings(
        window_s=win,
        skip_s=float(pulse_s) + win,
        tail_s=win,
        integration_corner_hz=SEED_INTEGRATION_RATIO * fa,
        delta_corner_hz=delta_corner_hz,
    )


def to_displacement(record: FloatArray, fs: float, quantity: tuple[str, ...], settings: WindowSettings) -> FloatArray:
    """Displacement (n, c) of a hit's record per its channels' quantities: acceleration by the Ch. 5 chain
    (``acc_to_disp``: ∫, high-pass, ∫, high-pass, means removed, zero phase), velocity by its second half,
    displacement with its mean removed (a simulated or laser channel needs no integration)."""
    import scipy.integrate
    import scipy.signal

    from analysis.preprocess import PreprocessSettings, acc_to_disp, highpass_sos

    x = np.asarray(record, float)
    if x.ndim != 2 or x.shape[1] != len(quantity):
        raise BadInput(f"record {x.shape} does not match its {len(quantity)} channel quantities")
    fc = settings.integration_corner_hz
    out = np.empty_like(x)
    q = np.asarray(quantity)
    acc = np.flatnonzero(q == "acceleration")
    if acc.size:
        ps = PreprocessSettings(vel_corner_hz=fc, disp_corner_hz=fc, order=settings.order, mode="zero_phase")
        out[:, acc] = acc_to_disp(x[:, acc], fs, ps)[1]
    vel = np.flatnonzero(q == "velocity")
    if vel.size:
        v = x[:, vel] - x[:, vel].mean(axis=0)
        d = scipy.integrate.cumulative_trapezoid(v, dx=1.0 / fs, axis=0, initial=0.0)
        d -= d.mean(axis=0)
        sos = highpass_sos(fc, fs, settings.order)
        if sos is not None:
            d = scipy.signal.sosfiltfilt(sos, d, axis=0)
        out[:, vel] = d - d.mean(axis=0)
    dis = np.flatnonzero(q == "displacement")
    if dis.size:
        out[:, dis] = x[:, dis] - x[:, dis].mean(axis=0)
    bad = sorted(set(quantity) - {"acceleration", "velocity", "displacement"})
    if bad:
        raise BadInput(f"channels of quantity {bad} cannot give a displacement")
    return out


def hit_region(n_samples: int, fs: float, pulse_index: int, settings: WindowSettings) -> tuple[int, int]:
    """The part of a hit's record that is windowed, ``[start, stop)`` samples: from ``skip_s`` after the pulse
    start to ``tail_s`` before the record's end (empty when nothing is left)."""
    start = pulse_index + round(settings.skip_s * fs)
    stop = n_samples - round(settings.tail_s * fs)
    return start, max(start, stop)


def half_cycle_windows(delta: FloatArray, fs: float, start: int, stop: int, window_s: float) -> np.ndarray:
    """Non-overlapping windows (k, 2) over ``[start, stop)`` that begin and end at zero crossings of δ, each the
    fewest whole half-cycles lasting at least ``window_s``.

    Why: eq. 5.2's mean |δ| over a window is 2A/π of a sinusoid only over whole half-cycles. The seed's
    0.174 s (T/2 of the fundamental, L1704) was that for the mode it windowed; a hardening attachment runs up to
    several times faster than its linear frequency, and a fixed window then holds a fraction of a cycle more or
    less, whose phase moves δ̄ by up to ±1/(2·half-cycles): on beam_ch4_sim's tip spring ±25 % at 6 Hz, where
    the law's Δf² ∝ δ̄^β doubles it. Crossings closer than a quarter of ``window_s`` are chatter (noise, a
    higher mode) and skipped."""
    y = np.asarray(delta, float)[start:stop]
    if y.size < 2:
        return np.zeros((0, 2), np.int64)
    z = np.flatnonzero(np.signbit(y[:-1]) != np.signbit(y[1:])) + 1 + start
    min_gap, need = 0.25 * window_s * fs, window_s * fs
    keep: list[int] = []
    for i in z:
        if not keep or i - keep[-1] >= min_gap:
            keep.append(int(i))
    out, i = [], 0
    for j in range(1, len(keep)):
        if keep[j] - keep[i] >= need - 0.5:
            out.append((keep[i], keep[j]))
            i = j
    return np.asarray(out, np.int64).reshape(-1, 2)


def fixed_windows(start: int, stop: int, fs: float, window_s: float) -> np.ndarray:
    """The seed's contiguous fixed-length windows over ``[start, stop)`` (``analysis.pod.window_bounds``)."""
    from analysis.pod import window_bounds

    if stop <= start:
        return np.zeros((0, 2), np.int64)
    return window_bounds(stop - start, fs, window_s).reshape(-1, 2) + start


@dataclass(frozen=True)
class WindowedHit:
    """Per window of one hit: its bounds (samples of the record), δ̄ (eq. 5.2), the attachment's POM (index, MAC,
    similar-POM capture flag), its RQ frequency (eq. 2.18) and the frequency of its temporal coefficient."""

    bounds: np.ndarray
    dbar: FloatArray
    f_rq: FloatArray
    f_pom: FloatArray
    mac: FloatArray
    capture: np.ndarray
    pom_index: np.ndarray


def window_phase_hz(a: FloatArray, fs: float, lo: int, hi: int) -> float:
    """Mean frequency over ``[lo, hi)`` of a temporal coefficient ``a`` (a longer stretch around it): the
    least-squares slope of the unwrapped phase of its analytic signal inside the window (``nsi.pom_frequency_hz``
    reads the same slope over a whole run)."""
    import scipy.signal

    ph = np.unwrap(np.angle(scipy.signal.hilbert(a - a.mean())))
    t = np.arange(lo, hi) / fs
    return float(abs(np.polyfit(t, ph[lo:hi], 1)[0]) / (2 * np.pi))


def analyse_hit(
    disp: FloatArray,
    fs: float,
    region: tuple[int, int],
    attachment: int,
    relative_to: tuple[int, ...],
    shape: FloatArray,
    M: FloatArray,
    K: FloatArray,
    settings: WindowSettings,
    record: tuple[int, int] | None = None,
) -> WindowedHit:
    """The windowed NSI quantities of one hit's displacement ``disp`` (n, c) at the output DOFs (columns of ``M``,
    ``K``, ``shape``): δ (eq. 5.13) with the optional Ch. 5 high-pass, windows over ``region`` (samples of
    ``disp``: :func:`hit_region`), δ̄ per window, and per window the POD, the
    attachment's POM by MAC to ``shape`` (its linear mode), RQ and temporal frequencies. ``record``: the hit's
    record ``[start, stop)`` within ``disp`` (default all of it), over which the temporal coefficients are
    Hilbert-transformed."""
    from analysis.pod import mac, pod, rq_hz

    x = np.asarray(disp, float)
    delta = nsi.highpass_delta(
        nsi.relative_displacement(x, attachment, relative_to), fs, settings.delta_corner_hz, settings.order
    )
    if settings.snap:
        b = half_cycle_windows(delta, fs, region[0], region[1], settings.window_s)
    else:
        b = fixed_windows(region[0], region[1], fs, settings.window_s)
    k = b.shape[0]
    dbar = nsi.characteristic_displacement(delta, b) if k else np.zeros(0)
    f_rq, f_pom, mc = np.full(k, np.nan), np.full(k, np.nan), np.zeros(k)
    cap, idx = np.zeros(k, bool), np.zeros(k, np.int64)
    lo, hi = record if record is not None else (0, x.shape[0])
    for w, (s, e) in enumerate(b):
        poms, _ = pod(x[s:e])
        row = mac(np.asarray(shape, float)[:, None], poms)[0]
        pick = nsi.pick_attachment_pom(row[None], settings.similar_mac)
        j = int(pick.index[0])
        psi = poms[:, j]
        idx[w], mc[w], cap[w] = j, float(pick.mac[0]), bool(pick.capture[0])
        f_rq[w] = float(rq_hz(psi[:, None], M, K)[0])
        seg = x[lo:hi]
        f_pom[w] = window_phase_hz((seg - x[s:e].mean(axis=0)) @ psi, fs, s - lo, e - lo)
    return WindowedHit(b, np.asarray(dbar, float), f_rq, f_pom, mc, cap, idx)


__all__ = [
    "SEED_INTEGRATION_RATIO",
    "SEED_WINDOW_PERIODS",
    "WindowSettings",
    "WindowedHit",
    "analyse_hit",
    "default_settings",
    "fixed_windows",
    "half_cycle_windows",
    "hit_region",
    "to_displacement",
    "window_phase_hz",
]
