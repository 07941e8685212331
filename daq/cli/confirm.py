"""``gvt confirm``: WBEMD + slow-flow confirmation of IR events into a companion log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, Progress, check_output, err, open_rig, out


def confirm(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    event: Annotated[int | None, typer.Option("--event", help="Only the IR event with this id (see gvt analyze).")] = None,
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    out_path: Annotated[Path | None, typer.Option("--out", help="Where the results go (default: LOG.confirm.mcap).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the confirmation records as JSON.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Confirm IR events with WBEMD + slow-flow phase analysis (seed Ch. 3); results to a companion log."""
    import json

    from daq.outputs import atomic_output
    from daq.studies.confirm import companion_path, confirm_log, confirmations_table, write_companion

    dest = out_path or companion_path(log)
    check_output(dest, overwrite, inputs=[log])  # before minutes of work, not after
    r = open_rig(rig) if rig is not None else None
    console = err if json_out else out
    with Progress(console) as report:
        run = confirm_log(log, r, event, progress=lambda f: report("confirming", f))
    with atomic_output(dest) as tmp:
        write_companion(run, tmp)
    if json_out:
        slim = [{k: v for k, v in rec.items() if k != "trajectory"} for rec in run.records]
        out.print_json(json.dumps({"log": str(log), "stream": run.stream, "events_from": run.events_from, "out": str(dest),
                                   "seconds": run.wall_seconds, "confirmations": slim}, default=float))  # fmt: skip
    else:
        out.print(confirmations_table(run.records, f"confirmations ({run.stream}, events from the {run.events_from})"))
    console.print(f"wrote {len(run.records)} confirmation records to {dest} in {run.wall_seconds:.1f} s", markup=False)
