"""Guyan (static) reduction to named master DOFs, seed eqs. 2.19–2.23 (L300–L354).

The seed condenses the rotational DOFs out so that the Rayleigh quotient works on the observable
translational DOFs (L302–L303): ``x_s = -K_ss^{-1} K_sm x_m`` (eq. 2.20), ``T = [I; -K_ss^{-1}
K_sm]`` (eq. 2.21, rows scattered back to the original DOF order here), and ``M_m = T^T M T`` etc.
(eq. 2.22).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from analysis.model.beam import FloatArray


@dataclass(frozen=True)
class GuyanModel:
    masters: tuple[int, ...]
    T: FloatArray  # (n_full, n_masters), original DOF order
    M: FloatArray
    K: FloatArray
    D: FloatArray | None = None


def guyan_reduce(M: FloatArray, K: FloatArray, masters: Sequence[int], D: FloatArray | None = None) -> GuyanModel:
    """Reduce ``(M, K[, D])`` to the master DOFs (indices into the full DOF list, kept in that order)."""
    n = M.shape[0]
    m = np.asarray(list(masters), dtype=int)
    if len(set(m.tolist())) != len(m):
        raise ValueError("master DOFs must be distinct")
    if m.size == 0 or m.min() < 0 or m.max() >= n:
        raise ValueError(f"master DOF indices must lie in [0, {n})")
    s = np.setdiff1d(np.arange(n), m)
    T = np.zeros((n, m.size))
    T[m, np.arange(m.size)] = 1.0
    if s.size:
        Kss = K[np.ix_(s, s)]
        Ksm = K[np.ix_(s, m)]
        T[s, :] = -scipy.linalg.solve(Kss, Ksm, assume_a="pos")
    Mm = T.T @ M @ T
    Km = T.T @ K @ T
    Dm = None if D is None else T.T @ D @ T
    # Symmetrise away rounding so downstream eigh/cholesky see exactly symmetric matrices.
    return GuyanModel(
        masters=tuple(int(i) for i in m),
        T=T,
        M=0.5 * (Mm + Mm.T),
        K=0.5 * (Km + Km.T),
        D=None if Dm is None else 0.5 * (Dm + Dm.T),
    )


def guyan_reduce_named(structure, masters: Sequence[str | int], with_damping: bool = False) -> GuyanModel:
    """Guyan-reduce a :class:`~analysis.model.structure.Structure` to master DOFs given by name or index.

    ``with_damping`` also reduces the modal damping matrix (eq. 2.22's ``D_m``).
    """
    idx = [m if isinstance(m, int) else structure.dof_index(m) for m in masters]
    D = None
    if with_damping:
        from analysis.model.modal import modal_damping_matrix, structure_modes

        D = modal_damping_matrix(structure.M, structure_modes(structure), structure.damping)
    return guyan_reduce(structure.M, structure.K, idx, D)
