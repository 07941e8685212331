"""Test geometry as data: the measured points (nodes with 3-D coordinates) and the trace lines drawn between them.

Why a geometry apart from the FE model: a test engineer draws and animates mode shapes on the points that were
measured, and exchanges them as UFF datasets 15 (nodes) and 82 (trace lines) (I-DEAS universal file format,
https://www.ceas3.uc.edu/sdrluff/). Node ids are the UFF node numbers: integers >= 1 (0 means "pen up" in a UFF 82
trace line).

Why a module of its own: the rig schema (analysis/model/config.py) checks a ``[geometry]`` table with
:func:`geometry_problem` as it validates it, and analysis/model/geometry.py derives a rig's geometry from the built
rig, so the data and its check sit below both (issue 28: the schema imports nothing that imports it back).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

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


__all__ = ["MAX_NODE_ID", "Geometry", "chain_lines", "geometry_problem", "make_geometry"]
