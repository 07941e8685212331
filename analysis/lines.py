"""Stationary lines (mains hum) in sensor channels: synthesis, detection and removal, causally (issue 29).

Why: an IEPE accelerometer chain picks up the mains (50 or 60 Hz and its harmonics) through ground loops
and cable shields — the most common interference in a vibration lab. A line at 2 % of a channel's RMS sits
inside mode 2's band on both grid rigs (50, 100 Hz against 64-68 Hz), so late in a decay the modal filter's
mode-2 energy is the line beating against the structure's free decay: the exchange detector read those beats
as exchanges (issue 29: 5.5 false events a hit at 2 %, 84 % of them at confidence >= 0.9). The seed assumes
clean sensors (assumptions 5-7, L63-L65) and its §4.3 chain (18/10 Hz high-passes) removes nothing at 50 Hz.

What a line is, and what the structure is not: a line keeps its amplitude and phase against a clock at its
frequency for seconds; a structure's response at that frequency is a decaying transient, or the leakage of a
mode elsewhere, whose phasor against the clock turns and shrinks. So per channel and candidate frequency
(``mains_hz`` x 1 ... ``harmonics``) the complex amplitude is measured over consecutive spans of ``span_s``
(Hann-tapered: a mode 18 Hz away leaks < -40 dB into a 0.2 s span's line, where a plain sum leaks -21 dB) on
a lattice fixed to the stream's first sample; a line is **stationary** when the last ``n_spans`` phasors
agree: their scatter about the mean phasor is below ``max_scatter`` of its magnitude and their magnitudes
within ``max_amp_ratio`` (white noise alone passes the scatter test with p ~ 1e-6 per trial; a 50 Hz mode with
ζ = 0.002 halves in 1 s and fails the magnitude test). A stationary line is **removed**: its sinusoid, with the
amplitude and phase of the mean phasor and the frequency offset from the phasors' rotation (a grid runs at
50 +- 0.05 Hz), is subtracted from every following sample — the classic coherent line canceller (Widrow's
adaptive noise cancelling with a sinusoidal reference), here estimated on spans rather than sample by sample
so that the structure's transients do not move it. The estimate is refreshed whenever the last spans are
stationary again and kept through a hit (the hum goes on; the spans during a hit are not stationary). This
is a notch ~1/(n_spans span_s) = 1 Hz wide at a line only, applied only where a line is found.

Cost: per block, one (n, lines) table of complex exponentials (on a recurrence) and two small matrix products.
Live and replay give the same numbers: spans lie on the stream's own sample lattice, and an estimate takes
effect at a span boundary.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: the mains families looked for: Europe/Asia and the Americas
MAINS_HZ: tuple[float, ...] = (50.0, 60.0)


def hum_waveform(
    n: int, fs: float, f0: float, amplitudes: Sequence[float], phases: Sequence[float] | None = None,
    first_index: int = 0,
) -> np.ndarray:  # fmt: skip
    """``Σ_k a_k cos(2π k f0 t + φ_k)`` at ``t = (first_index + i) / fs``, i < n: a mains line and its harmonics
    (k = 1 ... len(amplitudes)). The phase runs on the stream's sample clock, so blocks produced apart join."""
    t = (int(first_index) + np.arange(int(n))) / float(fs)
    ph = np.zeros(len(amplitudes)) if phases is None else np.asarray(phases, float)
    out = np.zeros(int(n))
    for k, (a, p) in enumerate(zip(amplitudes, ph, strict=True), start=1):
        out += float(a) * np.cos(2 * np.pi * k * f0 * t + p)
    return out


@dataclass(frozen=True)
class LineSettings:
    """Named thresholds of the line canceller (the module docstring says why each)."""

    mains_hz: tuple[float, ...] = MAINS_HZ
    harmonics: int = 4  # the fundamental and 3 harmonics (issue 29's case); lines above ``max_fraction`` x fs skipped
    span_s: float = 0.2  # 10 / 12 cycles of 50 / 60 Hz: a 5 Hz resolution, 18 Hz from mode 2 is 3.6 bins
    n_spans: int = 5  # a line must hold for 1 s
    max_scatter: float = 0.2  # rms |P_k - P̄| / |P̄|
    max_amp_ratio: float = 1.3  # max |P_k| / min |P_k| over the spans
    max_fraction: float = 1 / 2.56  # the usable band (analysis/operator.py RESOLVABLE_FRACTION)
    #: a removed line is refreshed from spans whose scatter is at most twice its estimate's, or this (measured: the
    #: quiet pre-trigger gives 0.002-0.01 at 0.5-5 % hum, a decay's tail 0.03-0.2)
    refresh_scatter: float = 0.02
    #: a line's amplitude must reach this fraction of the channel's RMS over the spans (offset included): a frozen
    #: channel's constant leaks a perfectly stationary 1e-5 of itself into every line's span; real pickup at 0.5 % of
    #: a hit's RMS is >= 1e-3 of a 1 s span's RMS
    min_rel: float = 1e-4
    #: phasors from every D-th sample, D at most this: each halving of the samples raises a line's phasor noise by
    #: sqrt(2), and at 8 the weakest harmonic of 0.5 % hum failed the scatter test on strip_steel_ch8 (named on 0 of 24
    #: hits); 2 halves the cost of the demodulation and keeps them
    max_decimation: int = 2

    def __post_init__(self) -> None:
        if self.span_s <= 0 or self.n_spans < 2 or self.harmonics < 1 or not self.mains_hz:
            raise ValueError("lines: span_s > 0, n_spans >= 2, harmonics >= 1 and a mains frequency required")


@dataclass(frozen=True)
class LineFound:
    """A stationary line found on a channel: which, where (Hz), how strong (SI amplitude), when (stream sample)."""

    channel: int
    freq_hz: float
    amplitude: float
    index: int


class LineCanceller:
    """Feed blocks ``(n, channels)`` in stream order; get them back with the stationary lines removed, and the lines
    newly found (:attr:`found`, cleared by the caller)."""

    def __init__(self, n_channels: int, sample_rate: float, settings: LineSettings | None = None) -> None:
        self.s = settings or LineSettings()
        self.fs = float(sample_rate)
        self.c = int(n_channels)
        f = [k * f0 for f0 in self.s.mains_hz for k in range(1, self.s.harmonics + 1)]
        self.freqs = np.array(sorted({x for x in f if x < self.s.max_fraction * self.fs}))
        self._w = 2 * np.pi * self.freqs / self.fs  # rad a sample
        self.L = max(8, round(self.s.span_s * self.fs))
        self._taper = np.hanning(self.L + 2)[1:-1]
        self._taper *= 2.0 / self._taper.sum()  # a cosine of amplitude a gives a phasor of magnitude a
        j = np.arange(self.L)
        #: the phasors are measured on every D-th stream sample (down to ~4 x the highest line's rate, at most
        #: ``max_decimation``): the lines need no more, and a block costs D times less; the broadband content aliased
        #: into a line's bin is no line (it turns against the line's clock), and the scatter test rejects it
        top = max(float(self.freqs.max()) if self.freqs.size else 1.0, 1.0)
        self.D = int(max(1, min(self.s.max_decimation, self.fs // (8 * top))))
        z = self.D * self._taper * np.exp(-1j * np.outer(self._w, j))  # (lines, L): tapered clocks from a span's start
        self._demod = np.stack([z.real, z.imag])
        self._index = 0
        self._acc = np.zeros((len(self.freqs), self.c), complex)  # the open span's tapered sums
        self._ss = np.zeros(self.c)  # ... and its sum of squares per channel
        self._ss_hist: list[np.ndarray] = []
        self._hist: list[np.ndarray] = []  # the last n_spans phasors (lines, channels), against each span's start
        self._est = np.zeros((len(self.freqs), self.c), complex)  # the line removed, phasor at the stream's sample 0
        self._dw = np.zeros(len(self.freqs))  # each line's frequency offset (rad a sample), shared by the channels
        self._on = np.zeros((len(self.freqs), self.c), bool)
        self._scatter = np.full((len(self.freqs), self.c), np.inf)  # the estimate's relative scatter
        self._clock = self._clocks()
        self.found: list[LineFound] = []

    def _clocks(self) -> np.ndarray:
        """(2, L, lines): the removed lines' clocks from a span's start at their measured frequencies, real and imaginary."""
        z = np.exp(1j * np.outer(np.arange(self.L), self._w + self._dw))
        return np.stack([z.real, z.imag])

    @property
    def active(self) -> bool:
        return bool(self._on.any())

    def feed(self, block: np.ndarray) -> np.ndarray:
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.c:
            raise ValueError(f"lines: blocks of (n, {self.c}) samples, got {x.shape}")
        if self.freqs.size == 0 or x.shape[0] == 0:
            self._index += x.shape[0]
            return x
        out = x.copy() if self._on.any() else x
        i = 0
        while i < x.shape[0]:
            pos = self._index % self.L
            take = min(x.shape[0] - i, self.L - pos)
            seg = x[i : i + take]
            start = self._index - pos  # the span's first sample: its clocks are tables times one phase each
            # real products of the tables (a complex product would copy the block to complex first: 3x the time)
            sel = slice((-self._index) % self.D, take, self.D)  # stream samples on the decimation lattice
            d = self._demod[:, :, pos : pos + take][:, :, sel]
            self._acc += (d[0] @ seg[sel] + 1j * (d[1] @ seg[sel])) * np.exp(-1j * self._w * start)[:, None]
            self._ss += np.einsum("ij,ij->j", seg[sel], seg[sel])
            if self._on.any():
                on = self._on.any(axis=1)  # only the lines found somewhere are subtracted, at every sample
                est = self._est[on] * np.exp(1j * (self._w[on] + self._dw[on]) * start)[:, None]
                c = self._clock[:, pos : pos + take][:, :, on]
                out[i : i + take] -= c[0] @ est.real - c[1] @ est.imag
            self._index += take
            i += take
            if self._index % self.L == 0:
                self._close_span()
        return out

    def restart(self) -> None:
        """A gap in the stream: the samples are counted without it, so the lines' phases are lost; start again."""
        self._acc[:] = 0.0
        self._ss[:] = 0.0
        self._hist.clear()
        self._ss_hist.clear()
        self._on[:] = False
        self._scatter[:] = np.inf
        self._index += (-self._index) % self.L  # the next span starts on the lattice

    def _close_span(self) -> None:
        self._hist.append(self._acc)  # the span's phasor on the stream's clock at each line's nominal frequency
        self._ss_hist.append(self._ss)
        self._acc = np.zeros_like(self._acc)
        self._ss = np.zeros(self.c)
        if len(self._hist) < self.s.n_spans:
            return
        P = np.stack(self._hist)  # (spans, lines, ch)
        ss = np.sum(self._ss_hist, axis=0)
        # judged at every span on the last n_spans (overlapping): judged once a second on non-overlapping groups instead,
        # a line that leakage hid at one test waited a second for the next, and beam_al_mid's linear twins took ~1 false
        # event a hit in that second at 1-5 % hum (bench/eval_hum.py); the test is ~25 small array operations
        self._hist.pop(0)
        self._ss_hist.pop(0)
        turn = np.sum(P[1:] * np.conj(P[:-1]), axis=0)  # a line off its nominal frequency by dw turns dw L a span
        rot = np.angle(turn)
        spans = np.arange(P.shape[0])[:, None, None]
        Pc = P * np.exp(-1j * rot[None] * spans)  # de-rotated onto the first span
        mean = Pc.mean(axis=0)
        mag = np.abs(mean)
        scatter = np.sqrt(np.mean(np.abs(Pc - mean) ** 2, axis=0))
        amp = np.abs(P)
        rms = np.sqrt(self.D * ss / (P.shape[0] * self.L))
        steady = amp.max(axis=0) <= self.s.max_amp_ratio * amp.min(axis=0)
        ok = (mag > self.s.min_rel * rms) & (scatter <= self.s.max_scatter * mag) & steady
        rel = np.where(mag > 0, scatter / np.where(mag > 0, mag, 1.0), np.inf)
        # a line already removed is re-estimated only from spans about as clean as those it was found on: during a hit's
        # decay the structure's leakage passes the test at a 0.1 scatter and would spoil an estimate made in the quiet
        ok &= ~self._on | (rel <= np.maximum(2 * self._scatter, self.s.refresh_scatter))
        if not ok.any():
            return
        # one frequency per line, from the channels that hold it (weighted by their power); the clocks' table is rebuilt
        # only when it would slip by more than 3e-3 rad over a span (the estimate is made with the frequency in use, so a
        # smaller slip costs at most ~0.5 % of the line until the next refresh)
        shared = np.angle(np.sum(np.where(ok, turn, 0.0), axis=1)) / self.L
        dw = np.where(ok.any(axis=1), shared, self._dw)
        if np.max(np.abs(dw - self._dw)) * self.L > 3e-3:
            self._dw = dw
            self._clock = self._clocks()
        dw = self._dw
        mid = self._index - P.shape[0] * self.L + 0.5 * (self.L - 1)  # the first span's centre
        Pc = P * np.exp(-1j * (dw * self.L)[None, :, None] * spans)
        est = Pc.mean(axis=0) * np.exp(-1j * dw * mid)[:, None]  # amplitude and phase at the stream's sample 0
        for li, ch in zip(*np.nonzero(ok & ~self._on), strict=True):
            self.found.append(LineFound(int(ch), float((self._w[li] + dw[li]) * self.fs / (2 * np.pi)),
                                        float(mag[li, ch]), self._index))  # fmt: skip
        self._est = np.where(ok, est, self._est)
        self._scatter = np.where(ok, rel, self._scatter)
        self._on |= ok
