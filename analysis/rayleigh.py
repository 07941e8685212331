"""Rayleigh quotient frequency estimate, seed eqs. 2.17–2.18 (L286, L294)."""

from __future__ import annotations

import numpy as np

from analysis.model.beam import FloatArray


def rayleigh_quotient_hz(v: FloatArray, K: FloatArray, M: FloatArray) -> FloatArray | float:
    """``f = sqrt(v^T K v / v^T M v) / (2 pi)`` for one trial vector or the columns of a matrix.

    ``K`` and ``M`` are the (Guyan-reduced) matrices at the DOFs the trial vectors live on; the
    vectors need not be mass-orthogonal (the seed uses POMs independently, L290).
    """
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:
        return float(np.sqrt(max(v @ K @ v, 0.0) / (v @ M @ v)) / (2.0 * np.pi))
    num = np.einsum("ij,ik,kj->j", v, K, v)
    den = np.einsum("ij,ik,kj->j", v, M, v)
    return np.sqrt(np.maximum(num, 0.0) / den) / (2.0 * np.pi)
