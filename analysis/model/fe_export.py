"""``gvt model export``: a rig's linear model written as the matrix files and DOF map of a ``kind = "matrices"`` rig.

M and K (or the named stiffness parts, and C when the rig has a damping matrix) at the rig's DOFs without its
attachments, the DOF map (``node,direction,x,y,z``) and a rig TOML that references them with the attachments,
sensors and hammer at ``"<node>:<direction>"`` DOFs. Read back by analysis/model/matrices.py, it is the same rig
(docs/fe-import.md). It builds the rig without its attachments, so it sits above analysis/model/rig.py, which reads
such files through analysis/model/matrices.py (issue 28: no import circle).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.model.beam import FloatArray
from analysis.model.matrices import DofMap, dof_name, read_matrix
from analysis.model.structure import Dof, Structure

#: File suffixes written by :func:`write_matrix` per format.
SUFFIX = {"matrixmarket": ".mtx", "matlab": ".mat", "harwell-boeing": ".rua"}


def write_matrix(path: Path, a: FloatArray, fmt: str, name: str = "A") -> None:
    """Write ``a`` so that :func:`read_matrix` reads back the same floats: MatrixMarket coordinate, symmetric
    storage (scipy writes each value's shortest round-trip digits); .mat as variable ``name``; Harwell-Boeing RUA."""
    import scipy.io
    import scipy.sparse

    if fmt == "matrixmarket":
        sym = "symmetric" if np.array_equal(a, a.T) else "general"
        scipy.io.mmwrite(path, scipy.sparse.coo_matrix(a), symmetry=sym)
    elif fmt == "matlab":
        scipy.io.savemat(path, {name: a})
    elif fmt == "harwell-boeing":
        scipy.io.hb_write(path, scipy.sparse.csc_matrix(a))
    else:
        raise ValueError(f"unknown matrix format {fmt!r}")


def bare_rig_structure(rig) -> Structure:
    """The rig's linear structure without the TOML's attachments (point masses, springs, nonlinear springs):
    what an FE code would export, the attachments staying in the TOML where updating can reach them."""
    from analysis.model.rig import build_rig

    bare = rig.config.model_copy(update={"point_masses": [], "springs": [], "nonlinear_springs": []})
    return build_rig(bare, rig.path).structure


def _export_dof(d: Dof, index: int) -> tuple[int, str]:
    """Node id and direction of a native DOF: a beam's node n is id n+1 (``w`` is Z, ``theta`` RY), a lumped
    chain's DOF k is node k+1 along X, an imported DOF keeps its own."""
    if ":" in d.name:
        n, _, dr = d.name.partition(":")
        return int(n), dr
    if d.kind in ("w", "theta") and d.node is not None:
        return d.node + 1, "Z" if d.kind == "w" else "RY"
    return index + 1, "X"


@dataclass(frozen=True)
class ExportPlan:
    """What ``gvt model export`` writes: matrix files (name -> array), the DOF map and the rig TOML's text."""

    matrices: dict[str, FloatArray]
    dof_map: DofMap
    toml: str
    fmt: str


def export_plan(rig, fmt: str = "matrixmarket", stem: str | None = None) -> ExportPlan:
    """M, K (or the named parts) and C of ``rig`` at its DOFs without the attachments, the DOF map, and a rig TOML
    of ``kind = "matrices"`` referencing them with the attachments, sensors and hammer at ``"<node>:<dir>"`` DOFs.
    Read back, it is the same rig: the same floats in M and K (exact round trips), the same modes and response."""
    import tomlkit

    from analysis.model.config import BeamSpec, MatricesSpec

    cfg = rig.config
    bare = bare_rig_structure(rig)
    ids = [_export_dof(d, i) for i, d in enumerate(bare.dofs)]
    xs = [d.x for d in bare.dofs]
    xyz = None if any(x is None for x in xs) else np.array([[x, 0.0, 0.0] for x in xs], dtype=float)
    dmap = DofMap(tuple(n for n, _ in ids), tuple(dr for _, dr in ids), xyz)
    new_name = {d.name: dof_name(*ids[i]) for i, d in enumerate(bare.dofs)}
    sfx = SUFFIX[fmt]
    stem = stem or cfg.name
    ref = (lambda f, var: f"{f}#{var}") if fmt == "matlab" else (lambda f, var: f)
    mats: dict[str, FloatArray] = {f"{stem}_M{sfx}": bare.M}
    structure: dict = {"kind": "matrices", "format": fmt, "dofs": f"{stem}_dofs.csv", "mass": ref(f"{stem}_M{sfx}", "A")}
    if bare.K_parts:
        structure["stiffness_parts"] = []
        for p in bare.K_parts:
            fname = f"{stem}_K_{p.name}{sfx}"
            mats[fname] = p.matrix
            structure["stiffness_parts"].append({"name": p.name, "file": ref(fname, "A"), "scale": p.scale})
    else:
        mats[f"{stem}_K{sfx}"] = bare.K
        structure["stiffness"] = ref(f"{stem}_K{sfx}", "A")
    data = cfg.model_dump(mode="json", exclude_unset=True, exclude_none=True)
    spec = cfg.structure
    if isinstance(spec, MatricesSpec) and spec.damping is not None:
        base = Path(rig.path).parent if rig.path != "<config>" else Path.cwd()
        mats[f"{stem}_C{sfx}"] = read_matrix(base, spec.damping, spec.format, "structure.damping")
        structure["damping"] = ref(f"{stem}_C{sfx}", "A")
        data.pop("damping", None)
    data["structure"] = structure
    data.pop("update", None)  # its targets may name the beam's parameters; declare the parts to update anew
    data.pop("sensor_arrays", None)
    placed = {p.name: p for p in (*rig.sensors, rig.hammer)}
    default_dir = "+Z" if isinstance(spec, BeamSpec) else "+X"  # as rig_channels defaults them (channels.py)
    sensors = []
    for sn in cfg.all_sensors:
        d = sn.model_dump(mode="json", exclude_unset=True, exclude_none=True)
        d.pop("x", None)
        d.pop("dof", None)
        d.setdefault("direction", default_dir)
        sensors.append({"name": d.pop("name"), "dof": new_name[placed[sn.name].dof_name], **d})
    data["sensors"] = sensors
    data["hammer"].pop("x", None)
    data["hammer"].pop("dof", None)
    data["hammer"].setdefault("direction", default_dir)
    data["hammer"] = {"dof": new_name[rig.hammer.dof_name], **data["hammer"]}
    for key in ("point_masses", "springs", "nonlinear_springs"):
        items = []
        for item in getattr(cfg, key):
            d = item.model_dump(mode="json", exclude_unset=True, exclude_none=True)
            d.pop("x", None)
            d["dof"] = new_name[_attachment_dof(bare, cfg, item)]
            items.append(d)
        if items:
            data[key] = items
    doc = tomlkit.document()
    doc.add(tomlkit.comment(f"Exported by 'gvt model export' from {rig.path}: {fmt} matrices at the rig's {len(dmap)} DOFs,"))
    doc.add(tomlkit.comment("the attachments below added on top (docs/fe-import.md)."))
    for k, v in data.items():
        doc.add(k, _toml_item(v))
    return ExportPlan(mats, dmap, tomlkit.dumps(doc), fmt)


def _attachment_dof(bare: Structure, cfg, item) -> str:
    """The native DOF name an attachment sits on (a beam snaps ``x`` to the nearest node's deflection)."""
    if item.dof is not None:
        return item.dof
    assert bare.mesh is not None
    node, _ = bare.mesh.snap(item.x)
    return f"w{node}"


def _toml_item(v):
    """Lists of tables as ``[[arrays of tables]]`` (as the shipped rigs are written), the rest as tomlkit infers."""
    import tomlkit

    if isinstance(v, list) and v and all(isinstance(e, dict) for e in v):
        aot = tomlkit.aot()
        for e in v:
            t = tomlkit.table()
            for k, x in e.items():
                t.add(k, _toml_item(x))
            aot.append(t)
        return aot
    if isinstance(v, dict):
        t = tomlkit.table()
        for k, x in v.items():
            t.add(k, _toml_item(x))
        return t
    return v


__all__ = ["SUFFIX", "ExportPlan", "bare_rig_structure", "export_plan", "write_matrix"]
