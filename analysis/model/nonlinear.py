"""Nonlinear springs (grounded, or between two DOFs): force laws, potentials and their codes for the simulator.

Two laws, both odd and hardening for positive coefficients:

* ``cubic``: ``f(w) = k3 * w**3`` — the seed's local nonlinearity (eq. 3.13, L875; L1207).
* ``power``: ``f(w) = alpha * |w|**beta * sign(w)`` — the general power law the model layer
  offers for attachments that are not purely cubic (the seed's experimental wires, L1336).

The potential is ``V(w) = alpha |w|^(beta+1) / (beta+1)`` (``k3 w^4 / 4`` for the cubic).

``w`` is the spring's stretch: the DOF's displacement for a grounded spring, ``x[dof] - x[ref]`` for one
between two DOFs (the seed's NES coupling, eq. 5.7, and its LO–store flexure, eq. 6.4). The simulator only
ever sees the incidence row ``e_dof - e_ref`` (:func:`incidence`), so both kinds share one code path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

LAW_CODES = {"cubic": 0, "power": 1}


@dataclass(frozen=True)
class NonlinearSpring:
    """A nonlinear spring on translational DOF ``dof``, to ground (``ref`` None) or to DOF ``ref``."""

    dof: int
    law: Literal["cubic", "power"]
    coefficient: float
    exponent: float = 3.0
    ref: int | None = None

    @property
    def code(self) -> int:
        return LAW_CODES[self.law]

    def force(self, w: np.ndarray | float) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        if self.law == "cubic":
            return self.coefficient * w**3
        return self.coefficient * np.abs(w) ** self.exponent * np.sign(w)

    def potential(self, w: np.ndarray | float) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        if self.law == "cubic":
            return 0.25 * self.coefficient * w**4
        return self.coefficient * np.abs(w) ** (self.exponent + 1.0) / (self.exponent + 1.0)

    def tangent_stiffness(self, w: np.ndarray | float) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        if self.law == "cubic":
            return 3.0 * self.coefficient * w**2
        return self.coefficient * self.exponent * np.abs(w) ** (self.exponent - 1.0)

    def moved_to(self, dof: int, ref: int | None = None) -> NonlinearSpring:
        return NonlinearSpring(dof=dof, law=self.law, coefficient=self.coefficient, exponent=self.exponent, ref=ref)


def incidence(springs: tuple[NonlinearSpring, ...] | list[NonlinearSpring], n_dof: int) -> np.ndarray:
    """(n_springs, n_dof) map from displacements to stretches, ``w = E x``: +1 at ``dof``, -1 at ``ref``.

    The generalised force of the springs is ``-E^T f(w)`` (equal and opposite on the two ends)."""
    E = np.zeros((len(springs), n_dof))
    for i, s in enumerate(springs):
        E[i, s.dof] += 1.0
        if s.ref is not None:
            E[i, s.ref] -= 1.0
    return E
