"""``gvt model update RIG --from LOG|MODES.json --out UPDATED.toml``: FE model updating (docs/model-updating.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, Progress, RigArg, check_output, err, fail, open_rig, out


def model_update(
    rig: RigArg,
    source: Annotated[
        Path,
        typer.Option("--from", help="Session log (.mcap) whose accepted hits give the modes, or `gvt modal --modes-out` JSON."),
    ],
    out_path: Annotated[
        Path, typer.Option("--out", help="Write the updated rig TOML here (the rig with new values + provenance).")
    ],
    params: Annotated[
        str | None, typer.Option("--params", help="Comma-separated parameter names (default: all the rig declares).")
    ] = None,
    objective: Annotated[
        str | None, typer.Option(help="eq45 (seed eq. 4.5) or eq45+mac (default: the rig's update table).")
    ] = None,
    modes: Annotated[
        int | None, typer.Option("--modes", min=1, max=50, help="Use the first N FE modes (default: the rig's update.modes, 6).")
    ] = None,
    optimiser: Annotated[str, typer.Option(help="de (differential evolution) or multistart (least_squares).")] = "de",
    band: Annotated[
        tuple[float, float] | None,
        typer.Option(help="Band of the modes from a log, Hz: LOW HIGH (default: 2 Hz to 1000 Hz or fs/2.56, as gvt modal)."),
    ] = None,
    level: Annotated[
        str | None,
        typer.Option(help="Force level of a log's hits: N (1 = lowest) or all (default: the lowest with 2 hits, as gvt frf)."),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Update the rig's parameters (Young's modulus, masses, springs) so its modes match the measured ones."""
    from analysis.model.rigs import resolve_rig_path
    from daq.outputs import atomic_output
    from daq.studies.update import run_update, summary, table_text

    rig_path = resolve_rig_path(rig)
    check_output(out_path, overwrite, "--out", inputs=[source, rig_path])
    names = [p.strip() for p in params.split(",") if p.strip()] if params is not None else None
    if params is not None and not names:
        fail("--params: give at least one parameter name (comma-separated)")
    if optimiser not in ("de", "multistart"):
        fail(f"--optimiser {optimiser}: use de or multistart")
    if objective is not None and objective not in ("eq45", "eq45+mac"):
        fail(f"--objective {objective}: use eq45 or eq45+mac")
    if level is not None and level != "all" and not (level.isdigit() and int(level) >= 1):
        fail(f"--level {level}: give a level number (1 = the lowest force) or all")
    r = open_rig(rig)
    with Progress(err if json_out else out) as report:
        run = run_update(r, rig_path, source, params=names, objective=objective, n_modes=modes, optimiser=optimiser,
                         band=band, level=level if level in (None, "all") else int(level), progress=report)  # fmt: skip
    with atomic_output(out_path) as tmp:
        tmp.write_text(run.text)
    if json_out:
        out.print_json(json.dumps({**summary(run), "out": str(out_path)}, default=float))
        return
    out.print(f"{rig_path}: {len(run.result.params)} parameter(s) updated against {len(run.result.pairs)} mode(s) of {source}",
              markup=False)  # fmt: skip
    out.print(table_text(run), markup=False)
    for n in run.notes:
        out.print(f"note: {n}", markup=False)
    for w in run.warnings:
        out.print(f"warning: {w}", markup=False)
    out.print(f"wrote {out_path}", markup=False)
