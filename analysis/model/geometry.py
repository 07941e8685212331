"""A rig's test geometry: the measured points (nodes with 3-D coordinates) and the trace lines drawn between them.

Why a geometry apart from the FE model: a test engineer draws and animates mode shapes on the points that were
measured, and exchanges them as UFF datasets 15 (nodes) and 82 (trace lines) (I-DEAS universal file format,
https://www.ceas3.uc.edu/sdrluff/; the data and its checks: analysis/model/wireframe.py). The FE model can be a
beam while the structure is not straight (a frame, a wing with a pylon), so the rig's ``[geometry]`` table may
describe the test points freely; without one a beam rig gets a node at each distinct sensor (and hammer) position
along x and a line between neighbours, and a lumped rig a schematic chain, one node per DOF 1 m apart.

Node ids are the UFF node numbers: integers >= 1 (0 means "pen up" in a UFF 82 trace line).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from analysis.model.wireframe import Geometry, chain_lines, make_geometry

if TYPE_CHECKING:
    from analysis.model.rig import PlacedChannel, Rig


def _position(ch: PlacedChannel, lumped_names: Sequence[str]) -> tuple[float, float, float]:
    """Where a placed channel sits: a beam's model node at (x, 0, 0); a lumped DOF on a 1 m schematic chain."""
    if ch.x_model is not None:
        return (float(ch.x_model), 0.0, 0.0)
    return (float(lumped_names.index(ch.dof_name)), 0.0, 0.0)


def rig_nodes(rig: Rig) -> dict[str, int]:
    """The node id of the hammer and every sensor (by channel name): the id the rig gives (``node = N``), else
    one shared by every channel on the same model DOF, numbered 1, 2, ... along the structure (skipping ids the
    rig has taken). With a ``[geometry]`` table every channel must name its node (the config checks it)."""
    cfg = rig.config
    placed = [rig.hammer, *rig.sensors]
    given = {s.name: s.node for s in cfg.all_sensors if s.node is not None}
    if cfg.hammer.node is not None:
        given["hammer"] = cfg.hammer.node
    by_dof: dict[int, int] = {}
    for ch in placed:  # a DOF with a named node: every channel on it shares that node
        if ch.name in given:
            by_dof.setdefault(ch.dof, given[ch.name])
    taken = set(given.values())
    names = [d.name for d in rig.structure.dofs]
    next_id = 1
    for ch in sorted(placed, key=lambda c: _position(c, names)[0]):
        if ch.dof not in by_dof:
            while next_id in taken:
                next_id += 1
            by_dof[ch.dof] = next_id
            taken.add(next_id)
    return {ch.name: given.get(ch.name, by_dof[ch.dof]) for ch in placed}


def rig_geometry(rig: Rig) -> Geometry:
    """The rig's test geometry: its ``[geometry]`` table when it has one, else one node per distinct sensor or
    hammer position (a beam: at the model node's x, y = z = 0; a lumped rig: DOF k at x = k m) and lines between
    neighbours along the structure."""
    spec = rig.config.geometry
    if spec is not None:
        return make_geometry(((n.id, n.x, n.y, n.z) for n in spec.nodes), spec.lines)
    nodes = rig_nodes(rig)
    names = [d.name for d in rig.structure.dofs]
    pos: dict[int, tuple[float, float, float]] = {}
    for ch in (rig.hammer, *rig.sensors):
        pos.setdefault(nodes[ch.name], _position(ch, names))
    order = sorted(pos, key=lambda n: (pos[n][0], n))
    return make_geometry(((n, *pos[n]) for n in order), chain_lines(order))


__all__ = [
    "rig_geometry",
    "rig_nodes",
]
