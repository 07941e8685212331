"""``gvt model modes``: the rig's natural frequencies."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from daq.cli.common import RigArg, fail, open_rig, out

model_app = typer.Typer(no_args_is_help=True, help="Structural model of a rig: modes, limits.")


@model_app.command("modes")
def model_modes(
    rig: RigArg,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    limit: Annotated[str, typer.Option(help="low: the linear structure; high: nonlinear springs pinned (seed L1244).")] = "low",
    count: Annotated[int, typer.Option(min=1, help="How many modes to list.")] = 10,
) -> None:
    """List the rig's natural frequencies (FE, and Guyan-reduced to the sensor DOFs)."""
    from daq.studies.modes import modes_report, print_modes

    if limit not in ("low", "high"):
        fail(f"--limit must be 'low' or 'high', got {limit!r}")
    r = open_rig(rig)
    report = modes_report(r, limit=limit, count=count)
    if json_out:
        out.print_json(json.dumps(report))
    else:
        print_modes(out, report)
