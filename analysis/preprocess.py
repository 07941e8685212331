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

import functools
from dataclasses import dataclass
from typing import Literal

import numba
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
    return butter_sos(order, corner_hz, "highpass", fs)


def butter_sos(order: int, corners_hz: float | tuple[float, float], btype: str, fs: float) -> FloatArray:
    """``scipy.signal.butter(order, corners_hz, btype, fs=fs, output="sos")``, designed once per arguments in a process
    (a copy each call). An operator's start designs ~14 such filters (the chain's high-passes, the modes' band-passes,
    the noise prior's): 16 ms of a 20 s replay's ~0.25 s on its critical path (issue 30 item 5)."""
    key = tuple(float(c) for c in corners_hz) if np.ndim(corners_hz) else float(corners_hz)
    return _butter(int(order), key, str(btype), float(fs)).copy()


@functools.lru_cache(maxsize=512)
def _butter(order: int, corners_hz: float | tuple[float, ...], btype: str, fs: float) -> FloatArray:
    return scipy.signal.butter(order, corners_hz, btype=btype, fs=fs, output="sos")


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


@numba.njit(cache=True, nogil=True)
def _causal_chain(a, offset, h, first, z_iv, sos_v, z_v, z_id, sos_d, z_d, keep_v, v_out, d_out):  # pragma: no cover - compiled
    """The whole causal §4.3 chain in one pass over ``a`` (n, c): states ``z_*`` are updated in place.

    Per sample and channel: baseline removal, trapezoid ``y[k] = y[k-1] + h (x[k-1] + x[k])`` (h = dt/2),
    the velocity high-pass sections, trapezoid again, the displacement high-pass sections. Each step is
    the arithmetic of the library filters it replaces, operation for operation, so the output is
    bit-identical to ``scipy.signal.lfilter([h, h], [1, -1])`` (transposed direct form II:
    ``y = z + h·x``, ``z ← h·x − (−1)·y``) and ``scipy.signal.sosfilt`` (``scipy/signal/_sosfilt.pyx``)
    applied stage after stage with carried ``zi`` (tests/test_preprocess.py checks it). ``first``:
    the integrators start at y[0] = 0 (their state becomes ``−h·x[0]``). One pass with the channels
    innermost instead of four library calls each copying the block to channel-major order: ~6× faster
    (docs/preprocessing.md, bench/bench_analysis.py). ``keep_v`` False: the velocity is not stored (``v_out`` is not
    touched), for a caller that uses the displacement alone (the seed lane: a block-sized array less to write).
    """
    n, c = a.shape
    x = np.empty(c)  # the current sample of every channel, through the stages in turn
    for k in range(n):
        for j in range(c):
            x[j] = a[k, j] - offset[j]
        _trapezoid(x, z_iv, h, first and k == 0)
        _sections(x, sos_v, z_v)
        if keep_v:
            for j in range(c):
                v_out[k, j] = x[j]
        _trapezoid(x, z_id, h, first and k == 0)
        _sections(x, sos_d, z_d)
        for j in range(c):
            d_out[k, j] = x[j]


@numba.njit(cache=True, nogil=True, inline="always")
def _trapezoid(x, z, h, first):  # pragma: no cover - compiled
    """One sample of ``lfilter([h, h], [1, -1])`` on every channel, in place (``first``: start at y = 0)."""
    if first:
        for j in range(x.shape[0]):
            z[j] = -(h * x[j])
    for j in range(x.shape[0]):
        y = z[j] + h * x[j]
        z[j] = h * x[j] + y
        x[j] = y


@numba.njit(cache=True, nogil=True, inline="always")
def _sections(x, sos, z):  # pragma: no cover - compiled
    """One sample of ``sosfilt`` on every channel, in place; the channel loop innermost (vectorised)."""
    for s in range(sos.shape[0]):
        b0, b1, b2, a1, a2 = sos[s, 0], sos[s, 1], sos[s, 2], sos[s, 4], sos[s, 5]
        for j in range(x.shape[0]):
            y = b0 * x[j] + z[s, 0, j]
            z[s, 0, j] = b1 * x[j] - a1 * y + z[s, 1, j]
            z[s, 1, j] = b2 * x[j] - a2 * y
            x[j] = y


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
        self._h = 0.5 * (1.0 / fs)  # the trapezoid's dt/2, as lfilter's b = [dt/2, dt/2]
        sos_v = highpass_sos(settings.vel_corner_hz, fs, settings.order)
        sos_d = highpass_sos(settings.disp_corner_hz, fs, settings.order)
        self._sos_v = np.zeros((0, 6)) if sos_v is None else np.ascontiguousarray(sos_v)  # no sections: no filter
        self._sos_d = np.zeros((0, 6)) if sos_d is None else np.ascontiguousarray(sos_d)
        # carried states: the integrators' single delay (set from the first sample) and the sections' two
        # delays each, started from rest (sosfilt's zi layout, channels last)
        self._z_iv, self._z_id = np.zeros(n_channels), np.zeros(n_channels)
        self._z_v = np.zeros((self._sos_v.shape[0], 2, n_channels))
        self._z_d = np.zeros((self._sos_d.shape[0], 2, n_channels))
        self._started = False
        self._n_base = round(settings.causal_baseline_s * fs)
        self._buf: list[FloatArray] = []
        self._n_buf = 0
        self.offset: FloatArray | None = None if self._n_base > 0 else np.zeros(n_channels)

    @property
    def pending(self) -> int:
        """Samples held back while the baseline is incomplete."""
        return self._n_buf

    def _run(self, a: FloatArray, head: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        assert self.offset is not None
        a = np.ascontiguousarray(a, dtype=np.float64)
        v = np.empty_like(a) if head is None else np.empty((0, a.shape[1]))
        at = 0 if head is None else head.shape[0]
        d = np.empty((at + a.shape[0], a.shape[1]))
        if head is not None:
            d[:at] = head
        if a.shape[0]:
            _causal_chain(a, np.ascontiguousarray(self.offset, dtype=np.float64), self._h, not self._started, self._z_iv,
                          self._sos_v, self._z_v, self._z_id, self._sos_d, self._z_d, head is None, v, d[at:])  # fmt: skip
            self._started = True
        return v, d

    def feed_after(self, head: FloatArray, acc_block: FloatArray) -> tuple[FloatArray, int]:
        """The displacement of ``acc_block`` written after ``head`` (earlier displacement the caller keeps) in one new
        array, and how many rows are new; the velocity is not stored. For the seed lane, which keeps a tail of
        displacement for its windows and uses no velocity: the chain writes into the joined buffer, where ``feed`` and a
        concatenation wrote a block twice and a velocity nobody read (issue 30). The same numbers as ``feed``."""
        a = _as_2d(acc_block)
        if self.offset is None or a.shape[1] != self.n_channels:  # holding a baseline, or a bad block: feed's path
            d = self.feed(a)[1]
            return (np.concatenate([head, d]) if head.size else d), d.shape[0]
        return self._run(a, np.asarray(head, dtype=np.float64))[1], a.shape[0]

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
