"""The rig's linear modes at the sensor DOFs, mass-normalised (eq. 2.15 of the seed on the Guyan-reduced model,
eqs. 2.19-2.22): the basis of the modal filter (analysis/modal_filter.py) and of the view's wavelet band.

Apart from the modal filter because it needs only numpy and scipy.linalg: ``gvt report`` sets up its figures from
the rig's first mode without loading the filter's JIT kernels and scipy.signal (docs/decisions.md D108).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

FloatArray = np.ndarray


@dataclass(frozen=True)
class ModalBasis:
    """Mass-normalised modes of a reduced model at the sensor DOFs."""

    omega: FloatArray  # (r,) rad/s
    shapes: FloatArray  # (n_dof, r), Φᵀ M Φ = I
    projector: FloatArray  # (r, n_dof) = Φᵀ M: q = projector @ x

    @property
    def freqs_hz(self) -> FloatArray:
        return self.omega / (2.0 * np.pi)

    @property
    def n_modes(self) -> int:
        return int(self.omega.size)


def modal_basis(M: FloatArray, K: FloatArray, n_modes: int | None = None) -> ModalBasis:
    """The lowest ``n_modes`` modes of ``(K, M)`` (eq. 2.15), mass-normalised, with their modal filter."""
    w2, phi = scipy.linalg.eigh(K, M)
    r = w2.size if n_modes is None else int(n_modes)
    if not 1 <= r <= w2.size:
        raise ValueError(f"n_modes must lie in [1, {w2.size}]")
    if w2[0] <= 0:
        raise ValueError("the reduced model has a rigid-body or unstable mode: a modal filter needs K > 0")
    phi = phi[:, :r]
    return ModalBasis(omega=np.sqrt(w2[:r]), shapes=phi, projector=phi.T @ M)
