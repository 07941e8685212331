"""``gvt model export RIG --out DIR``: the rig's linear model as matrix files an FE workflow reads back.

Writes M and K (or the named stiffness parts, and C when the rig has a damping matrix) at the rig's DOFs without
its attachments, the DOF map (``node,direction,x,y,z``) and a ``kind = "matrices"`` rig TOML that references them
with the attachments, sensors and hammer placed at ``"<node>:<direction>"`` DOFs (analysis/model/fe_export.py).
Loaded back it is the same rig: same modes, same simulated response (tests/test_fe_import.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, RigArg, check_output, fail, open_rig, out

FORMATS = ("matrixmarket", "matlab", "harwell-boeing")


def model_export(
    rig: RigArg,
    out_dir: Annotated[Path, typer.Option("--out", help="Directory to write into (created if its parent exists).")],
    fmt: Annotated[
        str, typer.Option("--format", help="matrixmarket (.mtx), matlab (.mat) or harwell-boeing (.rua).")
    ] = "matrixmarket",
    name: Annotated[str | None, typer.Option(help="File name stem (default: the rig's name).")] = None,
    overwrite: OverwriteOpt = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print the written files as JSON.")] = False,
) -> None:
    """Export the rig's M, K (C) at its DOFs, the DOF map and a rig TOML that reads them back."""
    from analysis.model.fe_export import export_plan, write_matrix
    from daq.outputs import atomic_output

    if fmt not in FORMATS:
        hint = " (Nastran OUTPUT4 needs pyNastran, which requires numpy < 2; see docs/fe-import.md)" if fmt == "op4" else ""
        fail(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}{hint}")
    r = open_rig(rig)
    if out_dir.exists() and not out_dir.is_dir():
        fail(f"--out {out_dir}: is a file; give a directory")
    if not out_dir.exists():
        if not out_dir.parent.exists():
            fail(f"--out {out_dir}: directory {out_dir.parent} does not exist (create it first)")
        out_dir.mkdir()
    plan = export_plan(r, fmt, name)
    stem = name or r.name
    targets = [out_dir / f for f in plan.matrices] + [out_dir / f"{stem}_dofs.csv", out_dir / f"{stem}.toml"]
    for t in targets:
        check_output(t, overwrite, "--out", inputs=[Path(r.path)] if r.path != "<config>" else [])
    for fname, a in plan.matrices.items():
        with atomic_output(out_dir / fname) as tmp:
            write_matrix(tmp, a, fmt)
    with atomic_output(out_dir / f"{stem}_dofs.csv") as tmp:
        tmp.write_text(plan.dof_map.to_csv(), encoding="utf-8")
    with atomic_output(out_dir / f"{stem}.toml") as tmp:
        tmp.write_text(plan.toml, encoding="utf-8")
    report = {"rig": r.name, "format": fmt, "n_dof": len(plan.dof_map), "files": [str(t) for t in targets]}
    if json_out:
        out.print_json(json.dumps(report))
    else:
        out.print(f"{r.name}: {len(plan.dof_map)} DOFs as {fmt} -> {out_dir / f'{stem}.toml'} (+ {len(targets) - 1} files)")
