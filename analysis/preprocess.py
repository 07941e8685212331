"""Acceleration → velocity → displacement, as the seed did it for its experiment (§4.3, L1322–L1323).

The seed: "the accelerations were numerically integrated, and the resulting velocities were passed
through a third-order, high-pass Butterworth filter with a cutoff frequency of 18 Hz. The filtered
velocities were then numerically integrated and passed through the same filter, except with a cutoff
frequency of 10 Hz. The temporal mean was also subtracted before and after each integration."

Two modes, both configurable through :class:`PreprocessSettings`:

* ``"zero_phase"`` (batch, the default; the seed does not say which, method-detection §1.9/§5.9):
  mean removal around each step, cumulative trapezoid, ``sosfiltfilt``. Magnitude is ``|H|²`` and the
  phase is zero, but every output sample depends on the whole record, so it cannot stream.
* ``"causal"`` (streaming): trapezoid integrator and ``sosfilt`` started from rest. A temporal mean
  is not causal, so this mode removes a **pre-trigger baseline** instead: the mean acceleration over the
  first ``causal_baseline_s`` seconds (the hit recorder's pre-trigger, before the impact) is
  subtracted from every sample; the DC offsets it targets (gravity, sensor orientation, L1323) are
  constant, so the pre-trigger measures them. Velocity and displacement get no mean removal: the
  3rd-order high-passes have three zeros at DC, so a residual constant or ramp left by integrating an
  imperfect baseline decays as a start-up transient instead of accumulating. ``causal_baseline_s = 0``
  relies on the high-passes alone. Measured amplitudes, phases and transients: ``docs/preprocessing.md``.

:class:`CausalPreprocessor` is the streaming form: it carries the integrator and filter states (and
buffers the baseline samples) across blocks, and its concatenated output is the batch causal output
sample for sample, whatever the block split — the batch causal function *is* one ``feed`` of the
whole record.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.integrate
import scipy.signal

FloatArray = np.ndarray


@dataclass(frozen=True)
class PreprocessSettings:
    """Seed defaults (L1322–L1323): 3rd-order Butterworth high-pass, 18 Hz on velocity, 10 Hz on displacement.

    ``vel_corner_hz`` / ``disp_corner_hz`` = ``None`` switches that high-pass off.
    """

    vel_corner_hz: float | None = 18.0
    disp_corner_hz: float | None = 10.0
    order: int = 3
    mode: Literal["zero_phase", "causal"] = "zero_phase"
    causal_baseline_s: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in ("zero_phase", "causal"):
            raise ValueError("mode must be 'zero_phase' or 'causal'")
        if self.order < 1:
            raise ValueError("filter order must be >= 1")
        for name in ("vel_corner_hz", "disp_corner_hz"):
            fc = getattr(self, name)
            if fc is not None and fc <= 0:
                raise ValueError(f"{name} must be positive (or None for no filter)")
        if self.causal_baseline_s < 0:
            raise ValueError("causal_baseline_s must be >= 0")


def highpass_sos(corner_hz: float | None, fs: float, order: int) -> FloatArray | None:
    """Butterworth high-pass in second-order sections, or ``None`` for no filter."""
    if corner_hz is None:
        return None
    if not 0 < corner_hz < fs / 2:
        raise ValueError(f"corner {corner_hz} Hz must lie in (0, fs/2 = {fs / 2} Hz)")
    return scipy.signal.butter(order, corner_hz, btype="highpass", fs=fs, output="sos")


def _as_2d(acc: FloatArray) -> FloatArray:
    a = np.asarray(acc, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError("acceleration must be (n_samples, n_channels)")
    return a


def _zero_phase(acc: FloatArray, fs: float, s: PreprocessSettings) -> tuple[FloatArray, FloatArray]:
    """Seed steps 1–9 of method-detection §1.9 with ``sosfiltfilt``."""
    dt = 1.0 / fs
    sos_v = highpass_sos(s.vel_corner_hz, fs, s.order)
    sos_d = highpass_sos(s.disp_corner_hz, fs, s.order)
    a = acc - acc.mean(axis=0)
    v = scipy.integrate.cumulative_trapezoid(a, dx=dt, axis=0, initial=0.0)
    v -= v.mean(axis=0)
    if sos_v is not None:
        v = scipy.signal.sosfiltfilt(sos_v, v, axis=0)
    v -= v.mean(axis=0)
    d = scipy.integrate.cumulative_trapezoid(v, dx=dt, axis=0, initial=0.0)
    d -= d.mean(axis=0)
    if sos_d is not None:
        d = scipy.signal.sosfiltfilt(sos_d, d, axis=0)
    d -= d.mean(axis=0)
    return v, d


def acc_to_disp(acc: FloatArray, fs: float, settings: PreprocessSettings = PreprocessSettings()) -> tuple[FloatArray, FloatArray]:
    """Velocity and displacement ``(n, c)`` from accelerations ``(n, c)`` sampled at ``fs``.

    The velocity returned is the filtered one the seed's kinetic energy uses (L1389).
    """
    a = _as_2d(acc)
    if settings.mode == "zero_phase":
        return _zero_phase(a, fs, settings)
    pre = CausalPreprocessor(fs, a.shape[1], settings)
    v, d = pre.feed(a)
    if pre.pending:  # record shorter than the baseline: use what there is
        v2, d2 = pre.flush()
        v, d = np.concatenate([v, v2]), np.concatenate([d, d2])
    return v, d


class _Trapezoid:
    """Causal trapezoid integrator ``y[k] = y[k-1] + dt (x[k-1] + x[k]) / 2`` with ``y[0] = 0``.

    As an ``lfilter`` with carried state, so a split record integrates sample for sample like a whole one.
    """

    def __init__(self, dt: float, n_channels: int) -> None:
        self.b = np.array([0.5 * dt, 0.5 * dt])
        self.a = np.array([1.0, -1.0])
        self.zi: FloatArray | None = None
        self.n = n_channels

    def __call__(self, x: FloatArray) -> FloatArray:
        if x.shape[0] == 0:
            return x.copy()
        if self.zi is None:  # y[0] = 0: the state that makes b0 x[0] + zi = 0
            self.zi = (-self.b[0] * x[0])[None, :]
        y, self.zi = scipy.signal.lfilter(self.b, self.a, x, axis=0, zi=self.zi)
        return y


class _SosStage:
    """``sosfilt`` from rest with the section states carried between blocks."""

    def __init__(self, sos: FloatArray | None, n_channels: int) -> None:
        self.sos = sos
        self.zi = None if sos is None else np.zeros((sos.shape[0], 2, n_channels))

    def __call__(self, x: FloatArray) -> FloatArray:
        if self.sos is None or x.shape[0] == 0:
            return x.copy()
        y, self.zi = scipy.signal.sosfilt(self.sos, x, axis=0, zi=self.zi)
        return y


class CausalPreprocessor:
    """Streaming acceleration → (velocity, displacement), the causal mode of :func:`acc_to_disp`.

    ``feed(block)`` returns the outputs for the samples it can finish. With a baseline
    (``settings.causal_baseline_s > 0``) the first ``round(causal_baseline_s * fs)`` samples are held
    until the baseline mean is known and then released together; afterwards every block comes back
    whole, so the latency is zero after the baseline.
    """

    def __init__(self, fs: float, n_channels: int, settings: PreprocessSettings = PreprocessSettings(mode="causal")) -> None:
        if fs <= 0:
            raise ValueError("fs must be positive")
        if n_channels < 1:
            raise ValueError("n_channels must be >= 1")
        self.fs = float(fs)
        self.n_channels = int(n_channels)
        self.settings = settings
        dt = 1.0 / fs
        self._int_v = _Trapezoid(dt, n_channels)
        self._int_d = _Trapezoid(dt, n_channels)
        self._hp_v = _SosStage(highpass_sos(settings.vel_corner_hz, fs, settings.order), n_channels)
        self._hp_d = _SosStage(highpass_sos(settings.disp_corner_hz, fs, settings.order), n_channels)
        self._n_base = round(settings.causal_baseline_s * fs)
        self._buf: list[FloatArray] = []
        self._n_buf = 0
        self.offset: FloatArray | None = None if self._n_base > 0 else np.zeros(n_channels)

    @property
    def pending(self) -> int:
        """Samples held back while the baseline is incomplete."""
        return self._n_buf

    def _run(self, a: FloatArray) -> tuple[FloatArray, FloatArray]:
        assert self.offset is not None
        v = self._hp_v(self._int_v(a - self.offset))
        d = self._hp_d(self._int_d(v))
        return v, d

    def feed(self, acc_block: FloatArray) -> tuple[FloatArray, FloatArray]:
        a = _as_2d(acc_block)
        if a.shape[1] != self.n_channels:
            raise ValueError(f"expected {self.n_channels} channels, got {a.shape[1]}")
        if self.offset is not None:
            return self._run(a)
        self._buf.append(a.copy())
        self._n_buf += a.shape[0]
        if self._n_buf < self._n_base:
            empty = np.empty((0, self.n_channels))
            return empty, empty.copy()
        return self.flush()

    def flush(self) -> tuple[FloatArray, FloatArray]:
        """Release held samples, fixing the baseline from what has arrived (all of it if short)."""
        if self.offset is not None and not self._buf:
            empty = np.empty((0, self.n_channels))
            return empty, empty.copy()
        held = np.concatenate(self._buf) if self._buf else np.empty((0, self.n_channels))
        self._buf, self._n_buf = [], 0
        if self.offset is None:
            base = held[: self._n_base]
            self.offset = base.mean(axis=0) if base.shape[0] else np.zeros(self.n_channels)
        return self._run(held)


def frequency_response(fs: float, freqs_hz: FloatArray, settings: PreprocessSettings) -> tuple[FloatArray, FloatArray]:
    """Gain and phase (rad) of the filtered displacement relative to the exact double integral.

    The integrations are exact for a sinusoid well below fs (trapezoid error ``(ωdt)²/12``), so the
    distortion is the two high-passes: ``H_v·H_d`` causal, ``|H_v|²·|H_d|²`` with zero phase when
    applied forward and backward.
    """
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    h = np.ones_like(f, dtype=complex)
    for fc in (settings.vel_corner_hz, settings.disp_corner_hz):
        sos = highpass_sos(fc, fs, settings.order)
        if sos is not None:
            h *= scipy.signal.sosfreqz(sos, worN=f, fs=fs)[1]
    if settings.mode == "zero_phase":
        h = np.abs(h) ** 2
    return np.abs(h), np.angle(h)
