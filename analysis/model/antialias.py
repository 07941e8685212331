"""The simulated DAQ's anti-alias filter: what a sigma-delta ADC does before a sample reaches the log.

Why: a real DAQ never samples the analog signal directly. A sigma-delta ADC samples it at a high modulator
rate and a linear-phase FIR decimation filter brings it down to ``fs``, flat to ~0.45 fs and 90-110 dB down
from ~0.55 fs (DSA data sheets, e.g. NI 4472: alias-free band 0.4535 fs, 110 dB; DewesoftX SIRIUS: 0.45 fs).
So a mode above Nyquist never folds into the band, and a pulse shorter than the band allows is smoothed, not
missed between samples. A simulated device that samples the simulator's output directly does both wrong: at
2048 Hz beam_ch4_exp's 1339 Hz mode folds to 709 Hz, inside fs/2.56, and a 1 ms hammer pulse reads what the
sample grid happens to hit (1257 N of 1500 N).

The filter (one definition, :class:`AntiAliasFilter`): a Kaiser-windowed sinc, cut at 0.5 fs, half-length
``m / fs`` (m whole output samples, from Kaiser's length formula for a 0.45-0.55 fs transition at 100 dB), so
passband ripple +-1e-4 dB to 0.45 fs and >= 100 dB from 0.55 fs. Linear phase: its group delay is m samples,
and the device *compensates* it (as DewesoftX and NI-DAQmx do by default): sample k is the filtered signal at
k / fs, so channels, hit times and devices that do not filter line up.

How it is applied, exactly where it matters and cheaply elsewhere. A simulated channel is the sum of
(i) the hammer force times a constant: the force itself on the hammer channel, and on an accelerometer the
force's instantaneous share ``c F(t)`` (every mode's acceleration holds ``phi_F F``; the rest, stiffness and
damping forces, is an integral of the force), and (ii) a smooth remainder made of the simulated modes (up to
the simulator's top basis frequency ``f_top``). The force is known in closed form (a piecewise-linear
series), so (i) is filtered *exactly* (:func:`filtered_force`: the continuous convolution, by quadrature over
each pulse): the pulse's broadband tail, the one content of a simulation with no upper frequency, never
folds. (ii) is simulated at the modulator rate ``R fs`` and filtered by the same kernel sampled there;
``R`` (:func:`oversampling_for`) is the smallest for which no simulated mode folds below 0.55 fs: ``R = 1``
when ``f_top <= fs / 2`` (nothing folds; the smooth part is left unfiltered, its content between 0.45 fs
and Nyquist being modes above every analysis band), else ``R fs - f_top >= 0.55 fs``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.signal
import scipy.special

PASSBAND = 0.45  # x fs: the passband edge (flat to +-1e-4 dB)
STOPBAND = 0.55  # x fs: the stopband edge (ATTENUATION_DB down from here)
ATTENUATION_DB = 100.0  # stopband attenuation; Kaiser's one delta also bounds the passband ripple: 1e-5
MAX_OVERSAMPLING = 64
_GAUSS = np.polynomial.legendre.leggauss(3)  # nodes per force-series interval (the integrand is smooth on it)


def oversampling_for(fs: float, top_hz: float) -> int:
    """The smallest modulator ratio R at which no simulated mode (up to ``top_hz``) folds below 0.55 fs: 1 when
    nothing lies above Nyquist, else ``R fs - top_hz >= 0.55 fs`` (a mode at f folds to ``R fs - f``)."""
    if top_hz <= 0.5 * fs:
        return 1
    return int(min(MAX_OVERSAMPLING, math.ceil((top_hz + STOPBAND * fs) / fs - 1e-9)))


@dataclass(frozen=True)
class AntiAliasFilter:
    """The decimation filter of a simulated DAQ at output rate ``fs`` (module docstring): a Kaiser-windowed
    sinc of half-length ``half_samples / fs``, applied at the modulator rate ``oversampling * fs``."""

    fs: float
    oversampling: int
    half_samples: int  # the group delay, in output samples (compensated)
    beta: float  # Kaiser window shape

    @property
    def modulator_rate(self) -> float:
        return self.fs * self.oversampling

    @property
    def delay_s(self) -> float:
        return self.half_samples / self.fs

    def kernel(self, tau: np.ndarray) -> np.ndarray:
        """The continuous impulse response (1/s) at lags ``tau`` (s): zero beyond the half-length."""
        tau = np.asarray(tau, dtype=float)
        u = tau / self.delay_s
        w = scipy.special.i0(self.beta * np.sqrt(np.clip(1.0 - u * u, 0.0, None))) / scipy.special.i0(self.beta)
        return np.where(np.abs(u) <= 1.0, w * self.fs * np.sinc(self.fs * tau), 0.0) / self._gain

    @cached_property
    def _gain(self) -> float:
        """The unnormalised kernel's integral (unit DC gain after dividing by it; ~1)."""
        u = np.linspace(-1.0, 1.0, 20001)
        w = scipy.special.i0(self.beta * np.sqrt(1.0 - u * u)) / scipy.special.i0(self.beta)
        return float(np.trapezoid(w * self.fs * np.sinc(self.fs * u * self.delay_s), u * self.delay_s))

    @cached_property
    def taps(self) -> np.ndarray:
        """The kernel sampled at the modulator rate (2 R m + 1 taps, unit DC gain): the FIR :meth:`apply` runs."""
        r = self.oversampling
        h = self.kernel(np.arange(-r * self.half_samples, r * self.half_samples + 1) / self.modulator_rate)
        return h / h.sum()

    def apply(self, x: np.ndarray, n: int) -> np.ndarray:
        """``n`` output samples from ``x`` ``(m, channels)`` sampled at the modulator rate from t = 0 (zero
        before: a structure at rest), delay compensated: output k is the filtered signal at t = k / fs. ``x``
        should hold ``(n + half_samples) * oversampling`` rows (zeros are taken after its end). With
        ``oversampling == 1`` the samples pass as they are (nothing folds: module docstring)."""
        x = np.asarray(x, dtype=float)
        if self.oversampling == 1:
            return x[:n].copy()
        d, r = self.half_samples, self.oversampling
        need = (n + d) * r
        if x.shape[0] < need:
            x = np.concatenate([x, np.zeros((need - x.shape[0], *x.shape[1:]))])
        return scipy.signal.upfirdn(self.taps, x[:need], up=1, down=r, axis=0)[d : d + n]

    def response_db(self, freq_hz: np.ndarray) -> np.ndarray:
        """The gain (dB) of the FIR at the modulator rate, or of the continuous kernel when R is 1."""
        f = np.asarray(freq_hz, dtype=float)
        if self.oversampling > 1:
            _, h = scipy.signal.freqz(self.taps, worN=f, fs=self.modulator_rate)
        else:
            tau = np.linspace(-self.delay_s, self.delay_s, 2 * self.half_samples * 64 + 1)  # 64 points a sample
            k = self.kernel(tau)
            h = np.concatenate([np.trapezoid(k[None, :] * np.cos(2 * np.pi * fb[:, None] * tau[None, :]), tau, axis=1)
                                for fb in np.array_split(f, max(1, f.size // 256))])  # fmt: skip
        return 20.0 * np.log10(np.maximum(np.abs(h), 1e-300))

    def facts(self) -> dict[str, str]:
        """What a test report states about the DAQ's filter (strings, for a log's metadata)."""
        return {
            "kind": "linear-phase FIR (Kaiser-windowed sinc), sigma-delta decimation",
            "passband_hz": f"{PASSBAND * self.fs:g}",
            "stopband_hz": f"{STOPBAND * self.fs:g}",
            "attenuation_db": f"{ATTENUATION_DB:g}",
            "modulator_rate_hz": f"{self.modulator_rate:g}",
            "group_delay_s": f"{self.delay_s:g}",
            "group_delay_compensated": "true",
        }


def design(fs: float, top_hz: float) -> AntiAliasFilter:
    """The filter for output rate ``fs`` of a simulation whose basis reaches ``top_hz``.

    Kaiser's formulas (scipy.signal.kaiserord) give the length and shape for a 0.1 fs transition at 100 dB; the
    half-length is rounded up to whole output samples (so compensating the delay moves no sample) and checked
    against the spec on a fine-rate FIR, lengthened by a sample until it holds."""
    fine = 16 * fs  # a rate at which the FIR is the continuous kernel to well below the stopband
    n_taps, beta = scipy.signal.kaiserord(ATTENUATION_DB, (STOPBAND - PASSBAND) * fs / (fine / 2.0))
    m = math.ceil((n_taps - 1) / 32)
    probe = np.linspace(STOPBAND * fs, fine / 2.0, 4096)
    while True:
        trial = AntiAliasFilter(float(fs), 16, m, float(beta))
        if trial.response_db(probe).max() <= -ATTENUATION_DB:
            return AntiAliasFilter(float(fs), oversampling_for(fs, top_hz), m, float(beta))
        m += 1


def filtered_force(aaf: AntiAliasFilter, t: np.ndarray, force: np.ndarray, n: int, t0: float = 0.0) -> np.ndarray:
    """The piecewise-linear force series (``t``, ``force``; zero outside) through the filter, at ``t0 + k / fs``
    for k < n: the convolution integral itself, by Gauss quadrature (3 nodes a piece, pieces no longer than
    1 / (8 fs): the kernel varies on 1 / fs) over every interval where the force is not zero."""
    t, f = np.asarray(t, dtype=float), np.asarray(force, dtype=float)
    f = np.where(np.abs(f) > 1e-12 * max(np.abs(f).max(initial=0.0), 1e-300), f, 0.0)  # sin(pi) is 1e-16, not 0
    out = np.zeros(n)
    live = np.flatnonzero((f[:-1] != 0.0) | (f[1:] != 0.0))
    if live.size == 0:
        return out
    x, w = _GAUSS
    for run in np.split(live, np.flatnonzero(np.diff(live) > 1) + 1):  # a run: one pulse
        a, b, fa, fb = t[run], t[run + 1], f[run], f[run + 1]
        pieces = np.maximum(1, np.ceil((b - a) * 8 * aaf.fs)).astype(int)
        j = np.repeat(np.arange(run.size), pieces)
        k = np.arange(j.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        lo = a[j] + (b - a)[j] * k / pieces[j]
        h = (b - a)[j] / pieces[j]
        s = lo[:, None] + h[:, None] * 0.5 * (x[None, :] + 1.0)  # the nodes of each piece
        fs_nodes = fa[j][:, None] + (fb - fa)[j][:, None] * (s - a[j][:, None]) / (b - a)[j][:, None]
        weights = (0.5 * h[:, None] * w[None, :] * fs_nodes).ravel()
        s = s.ravel()
        k0 = max(0, math.floor((s.min() - aaf.delay_s - t0) * aaf.fs))
        k1 = min(n, math.ceil((s.max() + aaf.delay_s - t0) * aaf.fs) + 1)
        if k1 > k0:
            tk = t0 + np.arange(k0, k1) / aaf.fs
            out[k0:k1] += aaf.kernel(tk[:, None] - s[None, :]) @ weights
    return out
