"""The energy axis of the RQ-FEP (seed §4.3.2, L1389; computational §4.2, L1251).

Experiment: "The total energy was estimated by fitting a shape-preserving, piecewise cubic Hermite
polynomial to the successive maximums of the kinetic energy, computed using the integrated velocities
and FE mass matrix" (L1389). So: ``KE(t) = ½ vᵀ M_m v`` with the filtered velocities at the sensors and
the Guyan mass at the sensor DOFs, its local maxima, a PCHIP through them, and the energy of window k
read at the window's start (Table 4.3 tags windows at their start, method-detection §1.6).

Computation: one energy per simulated impact, "the total energy induced by the forcing function"
(L1251) — the input work, which the simulator reports; :func:`input_work` recomputes it from a force and
the velocity at the hammer DOF when only signals are at hand.
"""

from __future__ import annotations

import numpy as np
import scipy.integrate
import scipy.interpolate
import scipy.signal

FloatArray = np.ndarray


def kinetic_energy(vel: FloatArray, M: FloatArray) -> FloatArray:
    """``½ vᵀ M v`` per sample (J) for velocities (N, n_dof) and the mass matrix at those DOFs."""
    v = np.asarray(vel, dtype=float)
    if v.ndim != 2 or M.shape != (v.shape[1], v.shape[1]):
        raise ValueError("vel must be (N, n_dof) and M (n_dof, n_dof)")
    return 0.5 * np.einsum("ni,ij,nj->n", v, M, v)


def ke_peaks(ke: FloatArray, min_separation: int = 1) -> np.ndarray:
    """Indices of the successive local maxima of the kinetic energy.

    ``min_separation`` (samples) = 1 keeps every local maximum, the seed's literal "successive maximums";
    a larger value (e.g. a quarter NNM1 period) ignores ripples from higher modes riding on a KE trough.
    """
    peaks, _ = scipy.signal.find_peaks(np.asarray(ke, dtype=float), distance=max(int(min_separation), 1))
    return peaks


def ke_envelope(ke: FloatArray, fs: float, min_separation: int = 1) -> tuple[np.ndarray, FloatArray]:
    """Peak indices and the PCHIP envelope through them, evaluated at every sample (J).

    Outside the first and last peak the envelope holds the end peak values: PCHIP extrapolation of a
    decaying sequence can undershoot, and before the first maximum there is no evidence of more energy.
    With fewer than two peaks the envelope is the record's maximum KE, constant.
    """
    ke = np.asarray(ke, dtype=float)
    peaks = ke_peaks(ke, min_separation)
    if peaks.size < 2:
        return peaks, np.full(ke.shape, float(ke.max()) if ke.size else 0.0)
    t = np.arange(ke.size) / fs
    interp = scipy.interpolate.PchipInterpolator(t[peaks], ke[peaks], extrapolate=False)
    env = interp(t)
    env[: peaks[0]] = ke[peaks[0]]
    env[peaks[-1] + 1 :] = ke[peaks[-1]]
    return peaks, env


def window_energy(envelope: FloatArray, bounds: np.ndarray) -> FloatArray:
    """Energy of each window = envelope at the window's first sample (Table 4.3, method-detection §1.6)."""
    return np.asarray(envelope, dtype=float)[np.asarray(bounds)[:, 0]]


def energy_percent(window_energies: FloatArray) -> FloatArray:
    """"Percent of initial total energy" of Table 4.3: relative to the first window (t = 0.0251 s)."""
    e = np.asarray(window_energies, dtype=float)
    return 100.0 * e / e[0]


def input_work(force: FloatArray, vel_at_force: FloatArray, fs: float) -> float:
    """``∫ F(t) ẇ_F(t) dt`` by the trapezoid rule (method-detection §1.8): the energy a single impulse puts in."""
    f = np.asarray(force, dtype=float)
    v = np.asarray(vel_at_force, dtype=float)
    return float(scipy.integrate.trapezoid(f * v, dx=1.0 / fs))
