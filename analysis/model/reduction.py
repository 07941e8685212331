"""Modal truncation with residual-flexibility vectors: the basis the transient simulator runs in.

The full FE model is stiff (highest eigenfrequency 648 kHz for the seed's 100-element beam, 2.2 MHz
for the experimental rig), so the simulator does not integrate it directly. It keeps the modes below
a stated cutoff and adds, for each DOF where a force acts (the hammer and every nonlinear spring), the
*residual flexibility* of the discarded modes at that DOF,
``r = sum_{h > cutoff} phi_h phi_h^T e / omega_h^2`` (modal truncation augmentation). That vector is
the part of the exact static deflection under a point load that the kept modes miss; without it a
truncated basis cannot represent a stiff spring pinning its DOF (the seed's high-energy limit,
L1244), and the pinned-limit frequencies converge slowly. The residual vectors are M-orthogonal and
K-orthogonal to the kept modes by construction, so after a small eigen-solve among themselves the whole
basis is mass-normalised with diagonal stiffness, and the linear part of the equations of motion stays
diagonal.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from analysis.model.beam import FloatArray
from analysis.model.modal import Modes, structure_modes
from analysis.model.nonlinear import Damper, NonlinearSpring
from analysis.model.structure import Structure


@dataclass(frozen=True)
class ReducedModel:
    """A mass-normalised basis with diagonal stiffness and damping.

    ``basis[:, :n_modes]`` are exact modes of the linear structure, the rest residual vectors.
    Physical displacement ``x = basis @ q``.
    """

    basis: FloatArray  # (n_dof, n_r)
    omega: FloatArray  # (n_r,) rad/s
    damping: FloatArray  # (n_r,) modal damping coefficients c_r (1/s)
    n_modes: int
    cutoff_hz: float
    nonlinear: tuple[NonlinearSpring, ...]
    dampers: tuple[Damper, ...] = ()

    @property
    def n_basis(self) -> int:
        return self.basis.shape[1]

    def rows(self, dofs: Sequence[int]) -> FloatArray:
        return self.basis[np.asarray(list(dofs), dtype=int), :]


def reduce_for_simulation(
    structure: Structure,
    cutoff_hz: float,
    load_dofs: Sequence[int] = (),
    *,
    residual_vectors: bool = True,
    modes: Modes | None = None,
) -> ReducedModel:
    """Keep modes up to ``cutoff_hz`` (at least one) and add residual vectors at the load and spring DOFs."""
    if cutoff_hz <= 0:
        raise ValueError("modal cutoff must be positive")
    if modes is None:
        modes = structure_modes(structure)
    f = modes.frequencies_hz
    n_keep = max(1, int(np.searchsorted(f, cutoff_hz, side="right")))
    n_keep = min(n_keep, len(f))
    coeff_all = structure.damping.modal_coefficients(modes.omega)
    Phi_k = modes.shapes[:, :n_keep]
    omega = [modes.omega[:n_keep]]
    damp = [coeff_all[:n_keep]]
    basis = [Phi_k]
    local = (*structure.nonlinear, *structure.dampers)
    ends = [d for s in local for d in (s.dof, s.ref) if d is not None]  # both ends of a relative spring or damper
    dofs = list(dict.fromkeys([*load_dofs, *ends]))
    if residual_vectors and dofs and n_keep < len(f):
        Phi_h = modes.shapes[:, n_keep:]
        om_h = modes.omega[n_keep:]
        R = Phi_h[dofs, :].T / om_h[:, None] ** 2  # modal coordinates (higher modes) of each residual vector
        # Eigen-solve among the residual vectors: in higher-mode coordinates M = I, K = diag(om_h^2).
        Mr = R.T @ R
        Kr = R.T @ (om_h[:, None] ** 2 * R)
        lam, Y = scipy.linalg.eigh(Kr, Mr)
        Z = R @ Y  # higher-mode coordinates of the orthonormal residual vectors
        basis.append(Phi_h @ Z)
        omega.append(np.sqrt(np.maximum(lam, 0.0)))
        damp.append(np.einsum("hj,h,hj->j", Z, coeff_all[n_keep:], Z))  # diagonal of Z^T C_h Z
    return ReducedModel(
        basis=np.hstack(basis),
        omega=np.concatenate(omega),
        damping=np.concatenate(damp),
        n_modes=n_keep,
        cutoff_hz=float(cutoff_hz),
        nonlinear=structure.nonlinear,
        dampers=structure.dampers,
    )
