"""Euler–Bernoulli beam finite elements (Hermite cubic shape functions, consistent mass).

The seed (L1207) uses "Euler-Bernoulli beam elements, where each element consisted of two nodes,
each with a translational and rotational degree of freedom" but prints no element matrices; the
standard Hermite-cubic stiffness and consistent mass reproduce its Table 3.1 to four significant
figures (method-detection.md §2.3), so those are what we assemble.

DOF order of the assembled (unconstrained) matrices: ``[w_0, theta_0, w_1, theta_1, ..., w_n,
theta_n]`` for nodes 0..n along the beam. Boundary conditions are applied by removing DOFs
(see :mod:`analysis.model.structure`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def element_stiffness(EI: float, le: float) -> FloatArray:
    """Hermite-cubic bending stiffness of one element, DOFs (w1, th1, w2, th2)."""
    l = le
    return (EI / l**3) * np.array(
        [
            [12.0, 6 * l, -12.0, 6 * l],
            [6 * l, 4 * l * l, -6 * l, 2 * l * l],
            [-12.0, -6 * l, 12.0, -6 * l],
            [6 * l, 2 * l * l, -6 * l, 4 * l * l],
        ]
    )


def element_mass(rhoA: float, le: float) -> FloatArray:
    """Consistent (not lumped) translational mass of one element, DOFs (w1, th1, w2, th2)."""
    l = le
    return (rhoA * l / 420.0) * np.array(
        [
            [156.0, 22 * l, 54.0, -13 * l],
            [22 * l, 4 * l * l, 13 * l, -3 * l * l],
            [54.0, 13 * l, 156.0, -22 * l],
            [-13 * l, -3 * l * l, -22 * l, 4 * l * l],
        ]
    )


@dataclass(frozen=True)
class BeamMesh:
    """A uniform mesh of ``n_elements`` equal elements along ``[0, length]``."""

    length: float
    n_elements: int

    @property
    def element_length(self) -> float:
        return self.length / self.n_elements

    @property
    def node_x(self) -> FloatArray:
        return np.linspace(0.0, self.length, self.n_elements + 1)

    def snap(self, x: float) -> tuple[int, float]:
        """Node index nearest to ``x`` and the distance to it.

        Raises ``ValueError`` when ``x`` lies more than half an element off the mesh, i.e. the
        position cannot be a point of this beam.
        """
        le = self.element_length
        if x < -0.5 * le or x > self.length + 0.5 * le:
            raise ValueError(
                f"position {x:g} m is off the beam [0, {self.length:g}] m by more than half an element ({0.5 * le:g} m)"
            )
        node = int(np.clip(round(x / le), 0, self.n_elements))
        return node, abs(x - node * le)


def assemble_beam(E: float, rho: float, width: float, height: float, mesh: BeamMesh) -> tuple[FloatArray, FloatArray]:
    """Global (unconstrained) mass and stiffness of a uniform rectangular beam.

    Returns ``(M, K)`` of size ``2 (n_elements + 1)``.
    """
    area = width * height
    inertia = width * height**3 / 12.0
    le = mesh.element_length
    ke = element_stiffness(E * inertia, le)
    me = element_mass(rho * area, le)
    n = 2 * (mesh.n_elements + 1)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    for e in range(mesh.n_elements):
        s = slice(2 * e, 2 * e + 4)
        K[s, s] += ke
        M[s, s] += me
    return M, K
