"""Modal filter: project the sensor field onto the rig's linear modes, causally, block by block.

The seed's method already needs a linear model reduced to the sensor DOFs (assumptions 5–7, L63–L65;
Guyan reduction, eqs. 2.19–2.22). Its mass-normalised modes ``Φ`` (``Φᵀ M_m Φ = I``,
``Φᵀ K_m Φ = diag(ω²)``) give a modal filter for free: ``q = Φᵀ M_m x`` is exact on the reduced model,
so the linear modal energies ``E_j = (q̇_j² + ω_j² q_j²) / 2`` — the simulator's own ground truth — can
be estimated from the sensors, window by window. gvtlink uses them as the evidence of energy exchange
between modes that the RQ curves alone cannot give (detection-findings.md; docs/detection.md).

Accelerations are filtered *after* the (linear, spatial) projection: a temporal filter commutes with a
constant spatial matrix, so integrating each modal acceleration is the same as integrating each channel
and projecting, at a fraction of the cost (r modes instead of n channels), and the high-pass corner can
sit well below NNM1 (5 Hz by default) instead of the seed's 18 Hz, which keeps ~72 % of a 21 Hz mode
(detection-findings.md). The integration is the seed's §4.3 chain itself (analysis/preprocess.py's
causal preprocessor) with those corners. Everything here is causal: state carries across blocks, so a
batch run is the streaming one fed a single block, and live and replay agree.

The instantaneous phase of mode j is ``θ_j = atan2(−q̇_j / ω_j, q_j)`` — the angle of the modal state in
its own phase plane (for ``q = a cos(ωt + φ)`` it is exactly ``ωt + φ``), causal and without a Hilbert
transform; its advance over a window gives the mode's mean frequency there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np

from analysis.modal_basis import FloatArray, ModalBasis, modal_basis  # noqa: F401 (modal_basis: part of this module's API)
from analysis.preprocess import CausalPreprocessor, PreprocessSettings


@dataclass(frozen=True)
class ModalFilterSettings:
    """How sensor data become modal states. Every number is a named, documented default."""

    quantity: Literal["acceleration", "displacement"] = "acceleration"
    #: high-pass corner (Hz) after each integration of a modal acceleration: removes the drift that
    #: integrated sensor noise and offsets produce. 5 Hz keeps > 99 % of a 21 Hz mode's amplitude.
    highpass_hz: float = 5.0
    order: int = 3  # Butterworth order of each high-pass (the seed's §4.3 uses 3)

    def __post_init__(self) -> None:
        if self.highpass_hz <= 0 or self.order < 1:
            raise ValueError("modal filter: highpass_hz must be > 0 and order >= 1")


class ModalStateTracker:
    """Causal, streaming modal states ``(q, q̇)`` from sensor blocks ``(n_samples, n_dof)``.

    Acceleration input: project, then trapezoidal integration and a causal Butterworth high-pass after
    each integration (the seed's §4.3 chain, on r modal signals instead of n channels). Displacement
    input: project, then the midpoint pair ``q = (q_i + q_{i-1})/2``, ``q̇ = (q_i − q_{i-1}) fs`` —
    second-order and causal (both at ``t_{i−½}``).
    """

    def __init__(self, basis: ModalBasis, sample_rate: float, settings: ModalFilterSettings | None = None) -> None:
        self.basis = basis
        self.fs = float(sample_rate)
        self.s = settings or ModalFilterSettings()
        if self.s.highpass_hz >= 0.5 * self.fs:
            raise ValueError("modal filter: highpass_hz must be below the Nyquist frequency")
        # the §4.3 chain itself (analysis/preprocess.py), run on the r modal accelerations
        chain = PreprocessSettings(vel_corner_hz=self.s.highpass_hz, disp_corner_hz=self.s.highpass_hz, order=self.s.order,
                                   mode="causal")  # fmt: skip
        self._integrate = CausalPreprocessor(self.fs, basis.n_modes, chain)
        self._prev: FloatArray | None = None  # displacement input: last projected sample

    def set_basis(self, basis: ModalBasis) -> None:
        """Swap the projection (a sensor left the filter: analysis/sensor_health.py), keeping the filter state.

        The integrators and high-passes are the same linear filter on every modal coordinate, and the new
        basis's modes are the old ones (same count, signs aligned) at fewer sensors, so their state carries
        over: what changes is only the old projection's leakage, a small step that the filters carry off
        like any input (restarting them instead would cost a settling time inside a hit's decay)."""
        if basis.n_modes != self.basis.n_modes:
            raise ValueError("modal filter: a new basis must keep the number of modes")
        self.basis = basis

    def feed(self, block: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Modal displacement and velocity (each ``(n_samples, r)``) for the block's samples."""
        y = np.asarray(block, dtype=np.float64) @ self.basis.projector.T
        if y.shape[0] == 0:
            return y, y
        if self.s.quantity == "displacement":
            prev = y[:1] if self._prev is None else self._prev[None, :]
            full = np.concatenate([prev, y])
            self._prev = y[-1].copy()
            return 0.5 * (full[1:] + full[:-1]), (full[1:] - full[:-1]) * self.fs
        v, x = self._integrate.feed(y)
        return x, v


def modal_energy(q: FloatArray, qdot: FloatArray, omega: FloatArray) -> FloatArray:
    """Linear modal energies ``(q̇² + ω² q²) / 2`` (J with mass-normalised modes).

    Blocks of states ``(n, r)`` go through one compiled pass (the same products in the same order as the
    numpy expression, so the same numbers; five array passes → one, the modal lane's per-sample hot path).
    """
    q, qdot, omega = np.asarray(q), np.asarray(qdot), np.asarray(omega)
    if (q.ndim == 2 and q.shape == qdot.shape and omega.shape == (q.shape[1],)
            and q.dtype == qdot.dtype == omega.dtype == np.float64):  # fmt: skip
        return _modal_energy(q, qdot, omega)
    return 0.5 * (qdot**2 + omega**2 * q**2)


@numba.njit(cache=True, nogil=True)
def _modal_energy(q, qdot, omega):  # pragma: no cover - compiled
    out = np.empty(q.shape)
    w2 = omega * omega
    for k in range(q.shape[0]):
        for j in range(q.shape[1]):
            out[k, j] = 0.5 * (qdot[k, j] * qdot[k, j] + w2[j] * (q[k, j] * q[k, j]))
    return out


def modal_phase(q: FloatArray, qdot: FloatArray, omega: FloatArray) -> FloatArray:
    """Instantaneous phase ``θ = atan2(−q̇/ω, q)`` (rad, wrapped to (−π, π])."""
    return np.arctan2(-qdot / omega, q)
