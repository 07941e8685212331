"""Roving-hammer test plans (issue 20, item 7): hit points resolved on the rig, the operator's progress, the prompt.

A roving-hammer test keeps the accelerometers in place and moves the hammer over a list of hit points, averaging a
few hits at each: every point is one reference (one column of the FRF matrix H[output, reference]; Ewins, *Modal
Testing*, 2nd ed., sec. 3.12: by reciprocity the columns also give rows). The plan (``[plan]`` of a session,
:class:`daq.config.session.PlanSpec`) names each point by a sensor, a test node or a model DOF; here it becomes a
:class:`HitPoint` (model DOF for the simulator, UFF node and direction for the export), :class:`PlanTracker` counts
the accepted averages and moves on, and :func:`hit_dofs` tells a simulated device where its scheduled hits land
(the hits it expects refused — overloads, double hits — are repeated at the same point, as an operator would).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from analysis.model.loader import ConfigFieldError
from analysis.model.units import direction_label, parse_direction

if TYPE_CHECKING:
    from analysis.model.rig import Rig
    from daq.config.session import PlanSpec


@dataclass(frozen=True)
class HitPoint:
    """A resolved hit point: model DOF (index and name), UFF node and direction code, averages, the sensor there."""

    name: str
    dof: int
    dof_name: str
    node: int
    direction: int
    averages: int
    sensor: str | None = None

    @property
    def label(self) -> str:
        return f"{self.name} (node {self.node}, {direction_label(self.direction)})"

    def as_dict(self) -> dict:
        return {"name": self.name, "node": self.node, "direction": direction_label(self.direction), "dof": self.dof_name,
                "sensor": self.sensor, "averages": self.averages}  # fmt: skip


def resolve_plan(plan: PlanSpec, rig: Rig) -> tuple[HitPoint, ...]:
    """The plan's points on ``rig``; a point naming an unknown sensor, node or DOF is a :class:`ConfigFieldError`
    naming ``plan.points[k].<field>``."""
    from analysis.model.channels import rig_channels

    chans = {c.name: c for c in rig_channels(rig)}
    placed = {p.name: p for p in (rig.hammer, *rig.sensors)}
    by_node = {c.node: c for c in reversed(chans.values())}  # the first channel on a node wins
    dof_names = [d.name for d in rig.structure.dofs]
    out = []
    for k, p in enumerate(plan.points):
        where = f"plan.points[{k}]"
        if p.sensor is not None:
            if p.sensor not in chans:
                raise ConfigFieldError(f"{where}.sensor", f"rig {rig.name} has no channel {p.sensor!r}")
            ch = chans[p.sensor]
        elif p.dof is None:
            if p.node not in by_node:
                raise ConfigFieldError(f"{where}.node", f"no channel of rig {rig.name} is on node {p.node} "
                                                        f"(nodes {sorted(by_node)}); give dof too")  # fmt: skip
            ch = by_node[p.node]
        else:
            if p.dof not in dof_names:
                raise ConfigFieldError(f"{where}.dof", f"rig {rig.name} has no model DOF {p.dof!r} (e.g. {dof_names[0]!r})")
            ch = next((chans[n] for n, pc in placed.items() if pc.dof_name == p.dof), None)
            if ch is None and p.node is None:
                raise ConfigFieldError(f"{where}.node", f"no channel sits on DOF {p.dof}: give its test node")
        dof_name = placed[ch.name].dof_name if p.dof is None and ch is not None else p.dof
        assert dof_name is not None
        node = p.node if p.node is not None else ch.node  # type: ignore[union-attr]
        direction = parse_direction(p.direction) if p.direction is not None else (ch.direction if ch is not None else 3)
        sensor = next((x.name for x in rig.sensors if x.dof_name == dof_name), None)  # the driving point's response
        out.append(HitPoint(p.name or f"P{k + 1}", dof_names.index(dof_name), dof_name, int(node), direction,
                            p.averages or plan.averages, sensor))  # fmt: skip
    return tuple(out)


def hit_dofs(points: tuple[HitPoint, ...], n_hits: int, refused: set[int] = frozenset()) -> list[int]:  # type: ignore[assignment]
    """The point index each of ``n_hits`` scheduled hits lands on: the plan's order, each point until it has its
    averages; a hit in ``refused`` (the simulator knows it overloads or double-taps) is repeated at its point;
    hits beyond the plan stay at the last point."""
    out, k, done = [], 0, 0
    for i in range(n_hits):
        out.append(k)
        if i not in refused:
            done += 1
            if done >= points[k].averages and k < len(points) - 1:
                k, done = k + 1, 0
    return out


def scheduled_dofs(plan: PlanSpec, rig: Rig, forces: list[float], double_hits: list[int] = ()) -> tuple[int, ...]:  # type: ignore[assignment]
    """The model DOF of each scheduled hit of a simulated device following ``plan``: the hits it expects refused are
    its double hits and those above the hammer's range (an overload)."""
    points = resolve_plan(plan, rig)
    full = rig.hammer.props.range
    refused = set(double_hits) | {k for k, f in enumerate(forces) if full is not None and f >= full}
    return tuple(points[i].dof for i in hit_dofs(points, len(forces), refused))


class PlanTracker:
    """The operator's progress: the current point and each point's accepted averages."""

    def __init__(self, points: tuple[HitPoint, ...]) -> None:
        self.points = points
        self.done = [0] * len(points)
        self.current = 0

    @property
    def complete(self) -> bool:
        return all(d >= p.averages for d, p in zip(self.done, self.points, strict=True))

    @property
    def point(self) -> HitPoint:
        return self.points[self.current]

    def accept(self) -> bool:
        """Count an accepted hit at the current point; True when that completed the point (the prompt moves on)."""
        self.done[self.current] += 1
        if self.done[self.current] < self.point.averages:
            return False
        nxt = next((i for i in range(len(self.points)) if self.done[i] < self.points[i].averages), None)
        if nxt is not None:
            self.current = nxt
        return True

    def prompt(self) -> str:
        """``hit point P3 (node 7, +Z): 2 of 3 averages``, or that the plan is complete."""
        if self.complete:
            return f"plan complete: {len(self.points)} points, {sum(self.done)} averages"
        return f"hit point {self.point.label}: {self.done[self.current]} of {self.point.averages} averages"

    def missing(self) -> list[str]:
        return [p.name for d, p in zip(self.done, self.points, strict=True) if d < p.averages]


def plan_channels(points: list[dict], hammer) -> dict:
    """Channels (analysis/model/channels.py) for the FRF matrix's references, named by hit point, from a
    ``/daq/plan`` record's ``points``: the hammer's quantity and sensitivity at each point's node and direction."""
    from dataclasses import replace

    return {p["name"]: replace(hammer, name=p["name"], node=int(p["node"]), direction=parse_direction(p["direction"]))
            for p in points}  # fmt: skip


__all__ = ["HitPoint", "PlanTracker", "hit_dofs", "plan_channels", "resolve_plan", "scheduled_dofs"]
