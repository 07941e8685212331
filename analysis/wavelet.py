"""Morlet continuous wavelet transform (seed eq. 3.2), maximum wavelet transform (eq. 3.3) and the
analytic signal with instantaneous amplitude, phase and frequency (eqs. 2.30–2.33, 3.17–3.18).

Why FFT-based: the seed computes every CWT as the inverse FFT of the signal's spectrum times the
Morlet's analytic spectrum (eq. 2.29, L400–L415). For the frequency form of eq. 3.2,
ψ_{ω,t}(τ) = π^{-1/4} exp[jω(τ−t)] exp[−½(ω(τ−t)/ω0)²], the kernel in the frequency domain is a
Gaussian centred on the analysing frequency ω with standard deviation ω/ω0 (rad/s)
(method-wbemd-slowflow.md §1.1, [DERIVED]). One forward FFT of the (zero-padded) signal is shared by
all frequencies; the inverse FFTs are done for a block of rows at once.

Normalisations (``normalization=``):

- ``"amplitude"`` (default): G_ω(λ) = 2·exp[−½(ω0/ω)²(λ−ω)²], so a sinusoid A·cos(Ωt) gives |Z(Ω,t)| = A.
  The seed's WT figures are shaded in signal-amplitude units (Fig. 3.17, L1067), and WBEMD's bounding
  test compares MWT amplitudes across frequencies, which a frequency-dependent gain would distort.
- ``"literal"``: eq. 3.2 as printed (no weight): G = π^{-1/4}·√(2π)·(ω0/ω)·exp[…]; a sinusoid gives
  |Z| ≈ 0.9414·A·ω0/Ω.
- ``"l2"``: the 1/√a weight of eq. 2.25 with scale a = ω0/ω applied to the literal form.

Edge effects: the signal is zero-padded (not wrapped) to at least N + 9 Gaussian standard deviations
of the lowest analysing frequency, so the transform is the linear (non-circular) convolution of the
finite record with the wavelet, like PyWavelets' ``method="fft"``; the first and last few wavelet
lengths still show the record's ends (seed pitfall 15, L1314) — ``mwt(trim_s=...)`` can skip them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

Normalization = Literal["amplitude", "literal", "l2"]

OMEGA0_DEFAULT = 2.0 * np.pi
"""ω0 of the Morlet wavelet: the only value the seed gives (Fig. 2.3, L398/L411)."""

_PAD_SIGMAS = 9.0
"""Zero padding, in time-domain Gaussian standard deviations (ω0/ω s) of the lowest frequency: the
wavelet is below exp(−40) of its peak there, so no wrapped sample reaches the result (tested against the
direct integral to 1e-9)."""


def _kernel_gain(omega: NDArray[np.float64], omega0: float, normalization: Normalization) -> NDArray[np.float64]:
    """The peak value of the frequency-domain kernel per analysing frequency (rows)."""
    if normalization == "amplitude":
        return np.full_like(omega, 2.0)
    literal = np.pi ** -0.25 * np.sqrt(2.0 * np.pi) * (omega0 / omega)
    if normalization == "literal":
        return literal
    if normalization == "l2":
        return literal * np.sqrt(omega / omega0)
    raise ValueError(f"normalization must be 'amplitude', 'literal' or 'l2', not {normalization!r}")


def padded_length(n: int, fs: float, f_min_hz: float, omega0: float = OMEGA0_DEFAULT, pad_sigmas: float = _PAD_SIGMAS) -> int:
    """FFT length for a record of ``n`` samples: linear convolution down to ``f_min_hz`` (``pad_sigmas``
    Gaussian standard deviations of the lowest row's wavelet of zeros after the record)."""
    sigma_samples = omega0 / (2.0 * np.pi * f_min_hz) * fs
    return int(scipy.fft.next_fast_len(n + int(np.ceil(pad_sigmas * sigma_samples)), real=False))


def morlet_cwt(
    x: ArrayLike,
    fs: float,
    freqs_hz: ArrayLike,
    *,
    omega0: float = OMEGA0_DEFAULT,
    normalization: Normalization = "amplitude",
    dtype: type = np.complex128,
    workers: int | None = None,
    block_rows: int = 16,
    pad_sigmas: float = _PAD_SIGMAS,
) -> NDArray[np.complexfloating]:
    """CWT Z(ω, t) of ``x`` with the Morlet wavelet of eq. 3.2, rows = ``freqs_hz``, columns = samples.

    ``dtype=np.complex64`` halves memory and time at single precision (errors of order 1e-5 of the largest
    coefficient: for display, not for the WBEMD bounding test). ``workers`` is passed to
    ``scipy.fft`` (default: one thread, like the rest of gvtlink's analysis — docs/decisions.md D19).
    ``pad_sigmas`` below the default 9 trades exactness near the record's ends for speed: at 4 the wrapped
    tail of the lowest row is below exp(−8) of its peak (a display: the live view's hit spectra; measured
    2e-5 of the largest coefficient apart, 1.3 → 0.95 ms for 48 rows of 10–2000 Hz × 2731 samples, and
    7.7 → 1.5 ms when the rows go down to 4 Hz).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"morlet_cwt: x must be one channel (1-D), got shape {x.shape}")
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=np.float64))
    if f.size == 0 or np.any(~np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("morlet_cwt: frequencies must be finite and > 0 Hz")
    if fs <= 0:
        raise ValueError(f"morlet_cwt: fs must be > 0, got {fs}")
    n = x.size
    nfft = padded_length(n, fs, float(f.min()), omega0, pad_sigmas)
    real_dtype = np.float32 if np.dtype(dtype) == np.complex64 else np.float64
    spectrum = scipy.fft.fft(x, n=nfft, workers=workers).astype(dtype, copy=False)
    lam = (2.0 * np.pi * scipy.fft.fftfreq(nfft, d=1.0 / fs)).astype(real_dtype)
    omega = 2.0 * np.pi * f
    gain = _kernel_gain(omega, omega0, normalization)
    out = np.empty((f.size, n), dtype=dtype)
    for start in range(0, f.size, block_rows):
        rows = slice(start, min(start + block_rows, f.size))
        w = omega[rows, None].astype(real_dtype)
        width = (omega0 / w) ** 2
        kernel = gain[rows, None].astype(real_dtype) * np.exp(-0.5 * width * (lam[None, :] - w) ** 2)
        out[rows] = scipy.fft.ifft(spectrum[None, :] * kernel, axis=1, workers=workers)[:, :n]
    return out


def mwt(z: NDArray[np.complexfloating], fs: float | None = None, trim_s: float = 0.0) -> NDArray[np.float64]:
    """Maximum wavelet transform Z̃(ω) = max_t |Z(ω, t)| (eq. 3.3 with the modulus the print omits).

    ``trim_s`` skips that many seconds at each end before the maximum (wavelet end effects); the
    default 0 matches the text.
    """
    mag = np.abs(z)
    if trim_s > 0:
        if fs is None:
            raise ValueError("mwt: trim_s needs fs")
        k = round(trim_s * fs)
        if 2 * k >= mag.shape[-1]:
            raise ValueError(f"mwt: trim of {trim_s} s at each end leaves no samples")
        mag = mag[..., k: mag.shape[-1] - k]
    return mag.max(axis=-1).astype(np.float64)


@dataclass(frozen=True)
class Instantaneous:
    """Instantaneous attributes of one component (eqs. 2.32–2.33, 3.18, 3.24–3.27).

    ``phase`` is the four-quadrant, unwrapped θ̂ (rad) — eq. 3.17 prints d/dt[HT{c}/c] without the
    arctan (erratum); ``frequency_hz`` is (1/2π)·dθ̂/dt, low-passed when a cut-off was given.
    """

    amplitude: NDArray[np.float64]
    phase: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]


def analytic(c: ArrayLike, fs: float, lowpass_hz: float | None = 1.0, order: int = 3) -> Instantaneous:
    """Analytic signal c + j·HT{c} (eq. 2.31) and its amplitude, unwrapped phase and frequency.

    The FFT Hilbert transform adds high-frequency ripple to phase and amplitude, so the seed low-passes
    the instantaneous frequency (L451–L452; 1 Hz in the beam case, L961–L962). The filter type is not
    stated: this uses a zero-phase Butterworth (``order``, default 3) on the frequency only; the phase
    stays unfiltered so that phase variables Φ = mθ̂_a − nθ̂_b keep their slow content exactly.
    ``lowpass_hz=None`` skips the filter. :class:`AnalyticMemo` gives the same at several cut-offs.
    """
    return AnalyticMemo(c, fs)(lowpass_hz, order)


def _frozen(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a.flags.writeable = False
    return a


class AnalyticMemo:
    """:func:`analytic` of one component, asked for again and again: the Hilbert transform, amplitude, unwrapped
    phase and raw frequency are computed once, the low-passed frequency once per (cut-off, order).

    Why: one confirmation reads the same two IMFs' analytic signals 24 times (each of the ten slow-flow
    trajectories of :func:`analysis.slowflow.test_ratios` and the slow-angle test, and the mean frequencies),
    although only the frequency's low-pass differs between them (issue 30, item 5). The numbers are those of
    :func:`analytic`, which is this class asked once. The arrays handed out are shared between callers, so they
    are read-only: a caller that wrote into one would change every later answer (numpy raises instead).
    """

    def __init__(self, c: ArrayLike, fs: float) -> None:
        c = np.asarray(c, dtype=np.float64)
        if c.ndim != 1 or c.size < 4:
            raise ValueError(f"analytic: need a 1-D component of at least 4 samples, got shape {c.shape}")
        self.c, self.fs = c, fs
        self._raw: Instantaneous | None = None
        self._low: dict[tuple[float, int], NDArray[np.float64]] = {}

    def __call__(self, lowpass_hz: float | None = 1.0, order: int = 3) -> Instantaneous:
        from scipy import signal  # here, not with the module: the CWT alone (gvt report, the view) needs no scipy.signal (D108)

        fs = self.fs
        if self._raw is None:
            z = signal.hilbert(self.c)
            phase = np.unwrap(np.angle(z))
            self._raw = Instantaneous(amplitude=_frozen(np.abs(z)), phase=_frozen(phase),
                                      frequency_hz=_frozen(np.gradient(phase) * fs / (2.0 * np.pi)))  # fmt: skip
        raw = self._raw
        if lowpass_hz is None:
            return raw
        if not 0 < lowpass_hz < fs / 2:
            raise ValueError(f"analytic: lowpass_hz must lie in (0, fs/2 = {fs / 2}), got {lowpass_hz}")
        key = (float(lowpass_hz), int(order))
        if key not in self._low:
            sos = signal.butter(order, lowpass_hz, btype="low", fs=fs, output="sos")
            padlen = min(self.c.size - 1, 3 * (2 * sos.shape[0] + 1))
            self._low[key] = _frozen(signal.sosfiltfilt(sos, raw.frequency_hz, padlen=padlen))
        return Instantaneous(amplitude=raw.amplitude, phase=raw.phase, frequency_hz=self._low[key])
