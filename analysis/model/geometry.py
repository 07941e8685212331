"""Test geometry: the measured points (nodes with 3-D coordinates) and the trace lines drawn between them.

Why a geometry apart from the FE model: a test engineer draws and animates mode shapes on the points that were
measured, and exchanges them as UFF datasets 15 (nodes) and 82 (trace lines) (I-DEAS universal file format,
https://www.ceas3.uc.edu/sdrluff/). The FE model can be a beam while the structure is not straight (a frame, a
wing with a pylon), so the rig's ``[geometry]`` table may describe the test points freely; without one a beam rig
gets a node at each distinct sensor (and hammer) position along x and a line between neighbours, and a lumped rig
a schematic chain, one node per DOF 1 m apart.

Node ids are the UFF node numbers: integers >= 1 (0 means "pen up" in a UFF 82 trace line).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from analysis.model.rig import PlacedChannel, Rig

#: The largest UFF node number: datasets 15, 55, 58 and 82 write node numbers as I10.
MAX_NODE_ID = 2_147_483_647


@dataclass(frozen=True)
class Geometry:
    """Nodes ``ids`` (n,) int, ``xyz`` (n, 3) m, and ``lines`` (m, 2) pairs of node ids."""

    ids: np.ndarray
    xyz: np.ndarray
    lines: np.ndarray

    def __post_init__(self) -> None:
        problem = geometry_problem(self.ids, self.xyz, self.lines)
        if problem:
            raise ValueError(problem)

    def coordinates(self, node: int) -> tuple[float, float, float]:
        """The (x, y, z) of ``node`` (m); KeyError for an unknown node."""
        hit = np.flatnonzero(self.ids == node)
        if not hit.size:
            raise KeyError(f"node {node} is not in the geometry (nodes {self.ids.tolist()})")
        x, y, z = self.xyz[hit[0]]
        return float(x), float(y), float(z)


def geometry_problem(ids: np.ndarray, xyz: np.ndarray, lines: np.ndarray) -> str | None:
    """Why ``(ids, xyz, lines)`` is not a geometry (None: it is): shapes, ids 1..MAX_NODE_ID and unique, finite
    coordinates, lines between two different known nodes."""
    if ids.ndim != 1 or xyz.shape != (ids.size, 3) or lines.ndim != 2 or lines.shape[1] != 2:
        return f"geometry shapes: ids {ids.shape}, xyz {xyz.shape} (want (n, 3)), lines {lines.shape} (want (m, 2))"
    if ids.size and (ids.min() < 1 or ids.max() > MAX_NODE_ID):
        return f"node ids must be 1..{MAX_NODE_ID} (0 means 'pen up' in a UFF trace line)"
    uniq, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        return f"node {int(uniq[counts > 1][0])} is defined twice; give each node one id"
    if not np.all(np.isfinite(xyz)):
        return "node coordinates must be finite numbers (m)"
    known = set(ids.tolist())
    for a, b in lines.tolist():
        if a not in known or b not in known:
            return f"line [{a}, {b}] names node {a if a not in known else b}, which is not among the nodes"
        if a == b:
            return f"line [{a}, {b}] joins a node to itself"
    return None


def make_geometry(nodes: Iterable[tuple[int, float, float, float]], lines: Iterable[Sequence[int]] = ()) -> Geometry:
    """A :class:`Geometry` from ``(id, x, y, z)`` rows and ``(a, b)`` pairs (ValueError with the reason)."""
    rows = list(nodes)
    ids = np.array([int(r[0]) for r in rows], dtype=np.int64)
    xyz = np.array([[float(v) for v in r[1:4]] for r in rows], dtype=float).reshape(len(rows), 3)
    pairs = np.array([[int(a), int(b)] for a, b in lines], dtype=np.int64).reshape(-1, 2)
    return Geometry(ids=ids, xyz=xyz, lines=pairs)


def chain_lines(ids: Sequence[int]) -> list[tuple[int, int]]:
    """Lines between consecutive nodes of ``ids`` (a beam's sensors in order along it)."""
    return [(int(a), int(b)) for a, b in itertools.pairwise(ids)]


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


__all__ = ["MAX_NODE_ID", "Geometry", "chain_lines", "geometry_problem", "make_geometry", "rig_geometry", "rig_nodes"]
