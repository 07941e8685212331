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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

LAW_CODES = {"cubic": 0, "power": 1}
#: Row codes of the velocity-dependent forces the integrator steps beside the springs (:class:`Damper`).
VISCOUS_CODE = 2
COULOMB_CODE = 3
#: Default regularisation velocity of the Coulomb force, ``tanh(v / v_eps)`` (m/s): docs/rfs.md, tests/test_rfs.py.
DEFAULT_V_EPS = 1e-4


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


@dataclass(frozen=True)
class Damper:
    """A velocity-dependent force on DOF ``dof``, to ground (``ref`` None) or to DOF ``ref``: viscous plus Coulomb,
    ``f(z) = viscous z + coulomb tanh(z / v_eps)`` with ``z`` the stretch rate (the seed's NES on its rails, eq. 5.11:
    ``d_r x' + mu_r m g sgn(x')``; ``coulomb`` is the friction force mu m g, N).

    The sign is regularised by ``tanh(z / v_eps)``: the simulator's implicit midpoint step evaluates it at the step's
    mean rate, so the friction dissipates ``f(z) z dt >= 0`` each step and the energy budget closes; below ``v_eps``
    a stuck mass creeps towards ``|x| < coulomb / k`` instead of sticking (tests/test_rfs.py: the Coulomb
    oscillator's decrement ``4 F_c / k`` a cycle and its stop band)."""

    dof: int
    viscous: float = 0.0
    coulomb: float = 0.0
    v_eps: float = DEFAULT_V_EPS
    ref: int | None = None

    def force(self, z: np.ndarray | float) -> np.ndarray:
        """Force (N) at stretch rate ``z`` (m/s)."""
        z = np.asarray(z, dtype=float)
        return self.viscous * z + self.coulomb * np.tanh(z / self.v_eps)

    def rows(self) -> list[tuple[int, float, float]]:
        """The integrator's rows ``(code, coefficient, parameter)``: one viscous, one Coulomb (``v_eps``), each if non-zero."""
        out = []
        if self.viscous > 0:
            out.append((VISCOUS_CODE, self.viscous, 0.0))
        if self.coulomb > 0:
            out.append((COULOMB_CODE, self.coulomb, self.v_eps))
        return out

    def moved_to(self, dof: int, ref: int | None = None) -> Damper:
        return Damper(dof=dof, viscous=self.viscous, coulomb=self.coulomb, v_eps=self.v_eps, ref=ref)


def incidence(springs: Sequence[NonlinearSpring | Damper], n_dof: int) -> np.ndarray:
    """(n_springs, n_dof) map from displacements to stretches, ``w = E x``: +1 at ``dof``, -1 at ``ref`` (springs or
    dampers: anything with ``dof`` and ``ref``).

    The generalised force of the springs is ``-E^T f(w)`` (equal and opposite on the two ends)."""
    E = np.zeros((len(springs), n_dof))
    for i, s in enumerate(springs):
        E[i, s.dof] += 1.0
        if s.ref is not None:
            E[i, s.ref] -= 1.0
    return E
