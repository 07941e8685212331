"""Modal analysis of a linear structure and the modal damping matrix (seed eq. 3.14, corrected)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from analysis.model.beam import FloatArray
from analysis.model.structure import ModalDamping, Structure


@dataclass(frozen=True)
class Modes:
    """Undamped modes ``K phi = omega^2 M phi`` (eq. 2.15), mass-normalised, ascending."""

    omega: FloatArray  # rad/s
    shapes: FloatArray  # (n_dof, n_modes), phi^T M phi = I

    @property
    def frequencies_hz(self) -> FloatArray:
        return self.omega / (2.0 * np.pi)

    def __len__(self) -> int:
        return len(self.omega)


def modal_analysis(M: FloatArray, K: FloatArray, n_modes: int | None = None) -> Modes:
    """Solve the generalised symmetric eigenproblem with LAPACK (scipy.linalg.eigh).

    Rigid-body modes (eigenvalues that round to slightly negative) are reported at 0 rad/s.
    """
    subset = None if n_modes is None else [0, min(n_modes, M.shape[0]) - 1]
    lam, phi = scipy.linalg.eigh(K, M, subset_by_index=subset)
    scale = max(float(np.max(np.abs(lam))), 1.0)
    lam = np.where(lam < 1e-12 * scale, 0.0, lam)
    return Modes(omega=np.sqrt(lam), shapes=phi)


def structure_modes(structure: Structure, n_modes: int | None = None) -> Modes:
    return modal_analysis(structure.M, structure.K, n_modes)


def modal_damping_matrix(M: FloatArray, modes: Modes, damping: ModalDamping) -> FloatArray:
    """Physical damping matrix ``D = M Phi diag(c_r) Phi^T M`` with ``c_r = 2 zeta_r omega_r``.

    This is eq. 3.14 (L885–L892) with the factor 2 of standard modal damping restored (the printed
    equation has ``zeta_r omega_r``; ``damping.factor2=False`` reproduces it). ``modes`` must be the
    complete set so that D is exact on every mode.
    """
    c = damping.modal_coefficients(modes.omega)
    MP = M @ modes.shapes
    return (MP * c) @ MP.T
