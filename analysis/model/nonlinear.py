"""Grounded nonlinear springs: force laws, potentials and their codes for the compiled simulator.

Two laws, both odd and hardening for positive coefficients:

* ``cubic``: ``f(w) = k3 * w**3`` — the seed's local nonlinearity (eq. 3.13, L875; L1207).
* ``power``: ``f(w) = alpha * |w|**beta * sign(w)`` — the general power law the model layer
  offers for attachments that are not purely cubic (the seed's experimental wires, L1336).

The potential is ``V(w) = alpha |w|^(beta+1) / (beta+1)`` (``k3 w^4 / 4`` for the cubic).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

LAW_CODES = {"cubic": 0, "power": 1}


@dataclass(frozen=True)
class NonlinearSpring:
    """A grounded nonlinear spring acting on one translational DOF of a structure."""

    dof: int
    law: Literal["cubic", "power"]
    coefficient: float
    exponent: float = 3.0

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

    def moved_to(self, dof: int) -> NonlinearSpring:
        return NonlinearSpring(dof=dof, law=self.law, coefficient=self.coefficient, exponent=self.exponent)
