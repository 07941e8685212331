"""The attachment an NSI identifies: its DOF at the simulator's outputs, what it moves relative to, its model.

From the rig's ``[nsi]`` table (or, without one, its first nonlinear spring, grounded). The sweep records the
NSI columns for it and ``gvt identify`` fits them, so both resolve it here, below both (seed §5.1, eq. 5.6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis import nsi
from analysis.errors import BadInput
from analysis.model.rig import Rig


@dataclass(frozen=True)
class Target:
    """The attachment at the simulator's outputs: its column, its connection points' columns, and the model."""

    attachment: int
    relative_to: tuple[int, ...]
    model: nsi.AttachmentModel
    description: str


def _dof_of(rig: Rig, where: float | str, field: str) -> int:
    s = rig.structure
    if isinstance(where, str):
        try:
            return s.dof_index(where)
        except KeyError:
            raise BadInput(f"{rig.path}: {field}: unknown DOF {where!r}") from None
    if s.mesh is None:
        raise BadInput(f"{rig.path}: {field}: a position (m) needs a beam rig; give a DOF name")
    node, _ = s.mesh.snap(float(where))
    try:
        return s.dof_index(f"w{node}")
    except KeyError:
        raise BadInput(f"{rig.path}: {field}: x = {where:g} m sits on a support") from None


def resolve_target(rig: Rig, output_dofs: list[int], M: np.ndarray, K: np.ndarray) -> Target:
    """The rig's ``[nsi]`` attachment, or (without one) the DOF of its first nonlinear spring, grounded."""
    spec = rig.config.nsi
    if spec is not None:
        att = _dof_of(rig, spec.x if spec.x is not None else spec.dof, "nsi")  # type: ignore[arg-type]
        refs = [_dof_of(rig, r, f"nsi.relative_to[{i}]") for i, r in enumerate(spec.relative_to)]
        mode = None if spec.mode is None else spec.mode - 1
        mass, rot = spec.mass, {"inertia": spec.inertia, "arm": spec.arm}
    elif rig.structure.nonlinear:
        att, refs, mode, mass, rot = rig.structure.nonlinear[0].dof, [], None, None, {}
    else:
        raise BadInput(f"{rig.name}: no [nsi] table and no nonlinear spring; say where the attachment is ([nsi] x or dof)")
    pos = {d: i for i, d in enumerate(output_dofs)}
    missing = [rig.structure.dofs[d].name for d in [att, *refs] if d not in pos]
    if missing:
        raise BadInput(f"{rig.name}: the attachment's DOFs {missing} are not among the outputs; use --outputs translational")
    ref_cols = tuple(pos[d] for d in refs)
    model = nsi.attachment_model(M, K, pos[att], ref_cols, mode, mass, **rot)
    names = [rig.structure.dofs[d].name for d in refs]
    desc = rig.structure.dofs[att].name + (f" - mean({', '.join(names)})" if names else " (grounded)")
    return Target(pos[att], ref_cols, model, desc)
