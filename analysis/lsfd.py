"""Residues and mode shapes from known poles: least-squares frequency-domain fit (LSFD), and the modal FRF.

Model (Ewins, *Modal Testing*, 2nd ed., §4.3-4.4; Peeters et al. 2004, eq. 9), written in receptance and
multiplied by ``(jw)^k`` for mobility (k = 1) or accelerance (k = 2):

``H_oi(w) = (jw)^k [ sum_r ( R_roi / (jw - s_r) + conj(R_roi) / (jw - conj(s_r)) ) + LR_oi / (jw)^2 + UR_oi ]``

``LR`` (lower residual, a mass-line for modes below the band) and ``UR`` (upper residual, the static
flexibility of modes above it) are real. With the poles fixed the model is linear in ``Re R``, ``Im R``,
``LR`` and ``UR``: one real least-squares problem whose matrix is shared by every FRF, so all
``n_out x n_ref`` FRFs are fitted by one ``lstsq`` with many right-hand sides. Conjugate pairs are built
in, so the fitted FRF is that of a real structure.

For mass-normalised real modes ``phi`` (``H = sum phi_o phi_i / (w_r^2 - w^2 + 2j zeta_r w_r w)``) the
residue is ``R_roi = phi_o phi_i / (2j w_dr)``: the *modal constant* ``A_roi = 2j Im(s_r) R_roi`` is
``phi_o phi_i``, which gives mass-normalised shapes from a driving point (``phi_o = A_oi / sqrt(A_ii)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POWER = {"receptance": 0, "mobility": 1, "accelerance": 2}


def _power(quantity: str) -> int:
    if quantity not in POWER:
        raise ValueError(f"quantity must be one of {sorted(POWER)}, got {quantity!r}")
    return POWER[quantity]


def modal_frf(
    freq: np.ndarray, omega: np.ndarray, zeta: np.ndarray, phi_out: np.ndarray, phi_in: np.ndarray, quantity: str = "receptance"
) -> np.ndarray:
    """Analytic FRF ``(n_out, n_in, n_f)`` of a structure with mass-normalised real modes and modal damping.

    ``sum_r phi_or phi_ir / (w_r^2 - w^2 + 2j zeta_r w_r w)`` (Ewins eq. 2.79 with viscous modal damping),
    times ``(jw)^k`` for mobility / accelerance. ``phi_out (n_out, n_modes)``, ``phi_in (n_in, n_modes)``."""
    w = 2 * np.pi * np.asarray(freq, dtype=float)
    den = omega[:, None] ** 2 - w[None, :] ** 2 + 2j * (zeta * omega)[:, None] * w[None, :]  # (n_modes, n_f)
    H = np.einsum("or,ir,rk->oik", phi_out, phi_in, 1.0 / den)
    return H * (1j * w) ** _power(quantity)


@dataclass(frozen=True)
class LSFDResult:
    """Residues ``R (n_out, n_ref, n_modes)`` of the receptance form, residuals, and the fitted FRFs."""

    s: np.ndarray
    residues: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    H_fit: np.ndarray
    band: np.ndarray  # indices of the fitted frequency lines

    @property
    def modal_constants(self) -> np.ndarray:
        """``A = 2j Im(s) R``: ``phi_o phi_i`` for mass-normalised modes."""
        return self.residues * (2j * self.s.imag)


def lsfd_basis(freq: np.ndarray, s: np.ndarray, quantity: str, lower: bool = True, upper: bool = True) -> np.ndarray:
    """Complex basis ``(n_f, 2 n_modes + residuals)``: columns for Re R, Im R of each mode, then LR, UR."""
    jw = 2j * np.pi * np.asarray(freq, dtype=float)[:, None]
    a = 1.0 / (jw - s[None, :])
    b = 1.0 / (jw - s.conj()[None, :])
    cols = [a + b, 1j * (a - b)]
    if lower:
        cols.append(1.0 / jw**2)
    if upper:
        cols.append(np.ones_like(jw))
    return np.hstack(cols) * jw ** _power(quantity)


def lsfd(
    freq: np.ndarray, H: np.ndarray, s: np.ndarray, quantity: str, f_lo: float, f_hi: float,
    lower: bool = True, upper: bool = True,
) -> LSFDResult:
    """Fit residues (and lower/upper residuals) of every FRF in ``[f_lo, f_hi]`` to the poles ``s`` (Im > 0)."""
    freq = np.asarray(freq, dtype=float)
    s = np.asarray(s, dtype=complex)
    n_out, n_ref, _ = H.shape
    idx = np.flatnonzero((freq >= f_lo) & (freq <= f_hi) & (freq > 0))
    if idx.size < 2 * s.size + 2:
        raise ValueError(f"{idx.size} frequency lines cannot fit {s.size} modes; widen the band")
    B = lsfd_basis(freq[idx], s, quantity, lower, upper)
    A = np.vstack([B.real, B.imag])
    scale = np.linalg.norm(A, axis=0)
    Y = H[:, :, idx].reshape(n_out * n_ref, -1).T
    theta, *_ = np.linalg.lstsq(A / scale, np.vstack([Y.real, Y.imag]), rcond=None)
    theta = (theta / scale[:, None]).T.reshape(n_out, n_ref, -1)
    n = s.size
    residues = theta[..., :n] + 1j * theta[..., n : 2 * n]
    k = 2 * n
    lr = theta[..., k] if lower else np.zeros((n_out, n_ref))
    ur = theta[..., k + int(lower)] if upper else np.zeros((n_out, n_ref))
    pos = freq > 0  # the DC line has no value for a lower residual (1/(jw)^2): left at 0 in the fit
    H_fit = np.zeros(H.shape, dtype=complex)
    basis = lsfd_basis(freq[pos], s, quantity, lower, upper)  # (n_f, c); one matmul (einsum took 16 ms on 14 x 5 FRFs)
    H_fit[:, :, pos] = (theta.reshape(n_out * n_ref, -1) @ basis.T).reshape(n_out, n_ref, -1)
    return LSFDResult(s=s, residues=residues, lower=lr, upper=ur, H_fit=H_fit, band=idx)


def shapes_from_constants(A: np.ndarray, driving: list[int | None] | None = None) -> np.ndarray:
    """Mode shapes ``(n_out, n_modes)`` from modal constants ``A (n_out, n_ref, n_modes)``.

    ``driving[i]`` is the output index measured at reference ``i`` (a driving point) or None. With a driving
    point the shape is mass-normalised from the reference that excites the mode best (largest ``|A_ii|``),
    ``phi = A[:, i] / sqrt(A[d_i, i])``; without one it is the dominant left singular vector of ``A_r``
    (rank one in theory: ``A_r = phi_r L_r^T``) scaled to unit norm."""
    n_out, _n_ref, n = A.shape
    shapes = np.empty((n_out, n), dtype=complex)
    drive = [] if driving is None else [(i, d) for i, d in enumerate(driving) if d is not None]
    for r in range(n):
        if drive:
            i, d = max(drive, key=lambda t: abs(A[t[1], t[0], r]))
            shapes[:, r] = A[:, i, r] / np.sqrt(A[d, i, r])
        else:
            u, _sv, _ = np.linalg.svd(A[:, :, r], full_matrices=False)
            shapes[:, r] = u[:, 0]
    return shapes


__all__ = ["LSFDResult", "lsfd", "lsfd_basis", "modal_frf", "shapes_from_constants"]
