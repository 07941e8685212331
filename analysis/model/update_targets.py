"""What an update may change: the rig values a ``[[update.parameters]]`` entry may target, and reading and setting them.

A target is a path into a rig config's data, ``structure.youngs_modulus`` or ``springs[0].k`` (docs/model-updating.md);
:data:`TARGETS` lists the ones that change the rig's linear M and K and nothing else (the values of the seed's eq. 4.5
updating, L1359-L1367).

Why a module of its own: the rig schema (analysis/model/config.py) checks a rig's declared parameters with
:func:`check_parameters` as it loads it, and the updater (analysis/model/updating.py) reads and sets the same paths
while it searches, so the grammar sits below both (issue 28: the schema imports nothing that imports it back).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from analysis.model.loader import ConfigFieldError

if TYPE_CHECKING:
    from pydantic import BaseModel

#: The values a parameter may set: what changes the rig's linear M and K and nothing else (the nonlinear
#: spring is not seen by linear modes; positions would move the mesh's nodes).
TARGETS = {
    r"structure\.youngs_modulus": "Young's modulus of the beam (Pa)",
    r"structure\.density": "density of the beam (kg/m^3)",
    r"structure\.height": "thickness of the beam (m)",
    r"structure\.width": "width of the beam (m)",
    r"structure\.masses\[\d+\]": "a lumped mass (kg)",
    r"structure\.springs\[\d+\]\.k": "a lumped spring (N/m)",
    r"point_masses\[\d+\]\.mass": "a point mass (kg)",
    r"springs\[\d+\]\.k": "a grounded linear spring (N/m): an attachment or a boundary spring",
    r"structure\.stiffness_parts\[\d+\]\.scale": "an imported rig's substructure stiffness scale p_i (K = sum p_i K_i)",
}
_TARGET_RE = re.compile("^(?:" + "|".join(TARGETS) + ")$")
_STEP = re.compile(r"^([a-z_]+)((?:\[\d+\])*)$")


class Parameter(Protocol):
    """What :func:`check_parameters` reads of an ``UpdateParameter`` (analysis/model/config.py): typed by its shape,
    so that this module, which the schema imports, does not import the schema back."""

    @property
    def name(self) -> str: ...

    @property
    def target(self) -> str: ...

    @property
    def bounds(self) -> tuple[float, float]: ...


def _steps(target: str) -> list[str | int]:
    out: list[str | int] = []
    for part in target.split("."):
        m = _STEP.match(part)
        if m is None:
            raise KeyError(target)
        out.append(m.group(1))
        out.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return out


def get_target(data: Any, target: str) -> float:
    """The value at ``target`` in a config's data (a dict from ``model_dump``, or a tomlkit document)."""
    node = data
    for s in _steps(target):
        node = node[s]
    return float(node)


def set_target(data: Any, target: str, value: float) -> None:
    *path, last = _steps(target)
    node = data
    for s in path:
        node = node[s]
    node[last] = value


def check_parameters(cfg: BaseModel, params: Sequence[Parameter], where: str = "update.parameters") -> None:
    """Each parameter names a value the rig ``cfg`` (a ``RigConfig``) has (:data:`TARGETS`), once, with its nominal
    value in its bounds; a problem is a :class:`ConfigFieldError` at the parameter's field."""
    data = cfg.model_dump()
    names: set[str] = set()
    targets: set[str] = set()
    for i, p in enumerate(params):
        at = f"{where}[{i}]"
        if p.name in names:
            raise ConfigFieldError(f"{at}.name", f"parameter name {p.name!r} is used twice")
        if not _TARGET_RE.match(p.target):
            raise ConfigFieldError(
                f"{at}.target", f"{p.target!r} is not an updatable value; use one of: " + ", ".join(_pretty_targets())
            )
        if p.target in targets:
            raise ConfigFieldError(f"{at}.target", f"{p.target!r} is updated by two parameters")
        try:
            v = get_target(data, p.target)
        except (KeyError, IndexError, TypeError):
            raise ConfigFieldError(f"{at}.target", f"this rig has no {p.target!r}") from None
        lo, hi = p.bounds
        if not lo <= v <= hi:
            raise ConfigFieldError(
                f"{at}.bounds", f"the rig's value of {p.target} ({v:g}) is outside the bounds [{lo:g}, {hi:g}]"
            )
        names.add(p.name)
        targets.add(p.target)


def _pretty_targets() -> list[str]:
    return [t.replace("\\", "").replace("[d+]", "[i]") for t in TARGETS]


__all__ = ["TARGETS", "Parameter", "check_parameters", "get_target", "set_target"]
