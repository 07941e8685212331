"""A linear structure (mass, stiffness, named DOFs) with grounded nonlinear springs and modal damping.

The model layer is not beam-only: :func:`build_beam` assembles Euler–Bernoulli beams with point
masses and grounded springs, :func:`build_lumped` spring–mass chains such as the seed's 2-DOF system
(eq. 2.1, L131–L134). Both produce a :class:`Structure`, which is what modal analysis, Guyan
reduction and the transient simulator consume.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from analysis.model.beam import BeamMesh, FloatArray, assemble_beam
from analysis.model.nonlinear import Damper, NonlinearSpring

EndCondition = Literal["clamped", "pinned", "free"]


@dataclass(frozen=True)
class Dof:
    """One degree of freedom of a structure.

    ``kind`` is ``"w"`` (transverse displacement) or ``"theta"`` (rotation) for beams and ``"x"``
    for lumped masses; ``x`` is the position along the beam in metres (None for lumped DOFs).
    """

    name: str
    kind: str
    node: int | None = None
    x: float | None = None

    @property
    def translational(self) -> bool:
        return self.kind in ("w", "x")


@dataclass(frozen=True)
class ModalDamping:
    """Per-mode viscous damping ratios.

    ``zeta[r]`` applies to mode r+1 and ``zeta_rest`` to all higher modes (the seed's Table 4.1
    plus "0.001 for higher modes", L1207). ``factor2=True`` is the standard ``2 zeta omega``
    modal damping; ``False`` reproduces the seed's printed eq. 3.14 (L885–L892), which drops the 2.
    """

    zeta: tuple[float, ...] = ()
    zeta_rest: float = 0.0
    factor2: bool = True

    def ratios(self, n_modes: int) -> FloatArray:
        z = np.full(n_modes, self.zeta_rest, dtype=float)
        k = min(n_modes, len(self.zeta))
        z[:k] = self.zeta[:k]
        return z

    def modal_coefficients(self, omega: FloatArray) -> FloatArray:
        """Diagonal of the modal damping matrix for mass-normalised modes: ``2 zeta_r omega_r``."""
        return (2.0 if self.factor2 else 1.0) * self.ratios(len(omega)) * omega


@dataclass(frozen=True)
class StiffnessPart:
    """A named substructure stiffness of an imported model, ``K = sum_i scale_i matrix_i + attachments``.

    Kept beside ``K`` so that updating can scale a part (the issue's ``K = sum p_i K_i`` when the FE model has
    no physical parameters); ``matrix`` is unscaled, over the same DOFs as ``K``."""

    name: str
    matrix: FloatArray
    scale: float = 1.0


@dataclass(frozen=True)
class Structure:
    """Mass and stiffness over the free (unconstrained) DOFs, plus nonlinear springs and damping."""

    M: FloatArray
    K: FloatArray
    dofs: tuple[Dof, ...]
    nonlinear: tuple[NonlinearSpring, ...] = ()
    damping: ModalDamping = field(default_factory=ModalDamping)
    mesh: BeamMesh | None = None
    K_parts: tuple[StiffnessPart, ...] = ()
    dampers: tuple[Damper, ...] = ()  # local viscous + Coulomb forces (rig ``[[dampers]]``, eq. 5.11)

    @property
    def n_dof(self) -> int:
        return len(self.dofs)

    def dof_index(self, name: str) -> int:
        for i, d in enumerate(self.dofs):
            if d.name == name:
                return i
        raise KeyError(f"no DOF named {name!r}; this structure has e.g. {[d.name for d in self.dofs[:4]]}")

    def translational_dofs(self) -> list[int]:
        return [i for i, d in enumerate(self.dofs) if d.translational]

    def without_dofs(self, removed: Sequence[int]) -> Structure:
        """The structure with the given DOFs held at zero (pinned) and removed.

        Nonlinear springs on removed DOFs disappear (a pinned point carries no spring force); a spring between
        two DOFs whose other end is removed becomes grounded (that end is pinned).
        """
        removed_set = set(int(i) for i in removed)
        keep = [i for i in range(self.n_dof) if i not in removed_set]
        new_index = {old: new for new, old in enumerate(keep)}
        springs = tuple(
            s.moved_to(new_index[s.dof], None if s.ref is None else new_index.get(s.ref))
            for s in self.nonlinear
            if s.dof in new_index
        )
        dampers = tuple(
            d.moved_to(new_index[d.dof], None if d.ref is None else new_index.get(d.ref))
            for d in self.dampers
            if d.dof in new_index
        )
        return replace(
            self,
            M=self.M[np.ix_(keep, keep)],
            K=self.K[np.ix_(keep, keep)],
            dofs=tuple(self.dofs[i] for i in keep),
            nonlinear=springs,
            dampers=dampers,
            K_parts=tuple(replace(p, matrix=p.matrix[np.ix_(keep, keep)]) for p in self.K_parts),
        )

    def high_energy_limit(self) -> Structure:
        """The seed's high-energy linear limit: every nonlinear spring replaced by a pin (L1244)."""
        return self.without_dofs([s.dof for s in self.nonlinear])

    def linear(self) -> Structure:
        """The underlying linear structure (nonlinear springs removed: the low-energy limit)."""
        return replace(self, nonlinear=())


def _end_dofs(condition: EndCondition, node: int) -> list[int]:
    if condition == "clamped":
        return [2 * node, 2 * node + 1]
    if condition == "pinned":
        return [2 * node]
    return []


def build_beam(
    *,
    length: float,
    width: float,
    height: float,
    E: float,
    rho: float,
    n_elements: int,
    left: EndCondition = "clamped",
    right: EndCondition = "free",
    point_masses: Sequence[tuple[float, float]] = (),
    springs: Sequence[tuple[float, float]] = (),
    nonlinear_springs: Sequence[tuple] = (),
    damping: ModalDamping | None = None,
    oscillators: Sequence[tuple[str, float, float, float]] = (),
) -> Structure:
    """Assemble a uniform Euler–Bernoulli beam with attachments.

    ``point_masses`` are ``(x, mass_kg)``; ``springs`` are grounded linear springs ``(x, k_N_per_m)``;
    ``nonlinear_springs`` are ``(at, law, coefficient, exponent[, to])``, ``at``/``to`` a position (m) or an
    oscillator's name, ``to`` omitted or None for a grounded spring. ``oscillators`` are ``(name, x, mass_kg,
    k_N_per_m)``: a mass with its own translational DOF (appended after the beam's), tied to the beam at ``x``
    by a linear spring — the seed's NES on its wing (Ch. 5, L1515). Every position is snapped to the nearest
    node (an error beyond half an element off the beam).
    """
    mesh = BeamMesh(length=length, n_elements=n_elements)
    try:
        M, K = assemble_beam(E, rho, width, height, mesh)
    except OverflowError:  # a float power past 1e308 (a height of 1e103 m): raised, not inf
        M = K = None
    if M is None or not (np.isfinite(M).all() and np.isfinite(K).all()):
        raise ValueError(f"the beam ({length:g} x {width:g} x {height:g} m, E {E:g} Pa, density {rho:g} kg/m^3) gives a "
                         "mass or stiffness beyond floating point: check the structure's dimensions and material")  # fmt: skip
    nb = M.shape[0]
    if oscillators:
        n_all = nb + len(oscillators)
        M = np.pad(M, ((0, n_all - nb), (0, n_all - nb)))
        K = np.pad(K, ((0, n_all - nb), (0, n_all - nb)))
        for o, (_name, x, m, k) in enumerate(oscillators):
            node, _ = mesh.snap(x)
            i, j = nb + o, 2 * node
            M[i, i] += m
            K[i, i] += k
            K[j, j] += k
            K[i, j] -= k
            K[j, i] -= k
    osc_index = {name: nb + o for o, (name, *_rest) in enumerate(oscillators)}

    def dof_at(where: float | str) -> int:
        if isinstance(where, str):
            return osc_index[where]
        node, _ = mesh.snap(where)
        return 2 * node

    for x, m in point_masses:
        node, _ = mesh.snap(x)
        M[2 * node, 2 * node] += m
    for x, k in springs:
        node, _ = mesh.snap(x)
        K[2 * node, 2 * node] += k
    xs = mesh.node_x
    dofs: list[Dof] = []
    for n in range(n_elements + 1):
        dofs.append(Dof(name=f"w{n}", kind="w", node=n, x=float(xs[n])))
        dofs.append(Dof(name=f"theta{n}", kind="theta", node=n, x=float(xs[n])))
    for name, *_rest in oscillators:
        dofs.append(Dof(name=name, kind="x"))  # not a beam point: no position
    nl = []
    for at, law, coef, expo, *to in nonlinear_springs:
        ref = None if not to or to[0] is None else dof_at(to[0])
        nl.append(NonlinearSpring(dof=dof_at(at), law=law, coefficient=coef, exponent=expo, ref=ref))  # type: ignore[arg-type]
    full = Structure(M=M, K=K, dofs=tuple(dofs), nonlinear=tuple(nl), damping=damping or ModalDamping(), mesh=mesh)
    removed = _end_dofs(left, 0) + _end_dofs(right, n_elements)
    for s in full.nonlinear:
        if s.dof in removed or s.ref in removed:
            raise ValueError(f"a nonlinear spring sits on a constrained DOF ({full.dofs[s.dof].name})")
    return full.without_dofs(removed)


def build_lumped(
    *,
    masses: Sequence[float],
    springs: Sequence[tuple[int, int | None, float]],
    nonlinear_springs: Sequence[tuple] = (),
    names: Sequence[str] | None = None,
    damping: ModalDamping | None = None,
) -> Structure:
    """A spring–mass system: ``springs`` are ``(i, j, k)`` between DOFs i and j, ``j=None`` to ground;
    ``nonlinear_springs`` are ``(i, law, coefficient, exponent[, j])``, between i and j (``j`` omitted or None:
    to ground)."""
    n = len(masses)
    names = list(names) if names is not None else [f"x{i + 1}" for i in range(n)]
    M = np.diag(np.asarray(masses, dtype=float))
    K = np.zeros((n, n))
    for i, j, k in springs:
        K[i, i] += k
        if j is not None:
            K[j, j] += k
            K[i, j] -= k
            K[j, i] -= k
    nl = tuple(
        NonlinearSpring(dof=i, law=law, coefficient=c, exponent=e, ref=j[0] if j else None)  # type: ignore[arg-type]
        for i, law, c, e, *j in nonlinear_springs
    )
    dofs = tuple(Dof(name=nm, kind="x") for nm in names)
    return Structure(M=M, K=K, dofs=dofs, nonlinear=nl, damping=damping or ModalDamping())
