"""``gvt sweep``: the seed's force sweep on Dask."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import Progress, RigArg, err, fail, open_rig, out


def sweep(
    rig: RigArg,
    pmin: Annotated[float, typer.Option(help="Smallest peak force P, N (seed: 10).")] = 1e1,
    pmax: Annotated[float, typer.Option(help="Largest peak force P, N (seed: 1e12).")] = 1e12,
    n: Annotated[int, typer.Option(help="Runs, P = logspace(pmin, pmax, n) (seed: 1000).")] = 200,
    duration: Annotated[float, typer.Option(help="Seconds per run (seed: 1).")] = 1.0,
    outputs: Annotated[str, typer.Option(help="translational: every transverse DOF; sensors: the sensor DOFs.")] = (
        "translational"
    ),
    order: Annotated[int | None, typer.Option(help="Integrator order 2 or 4 (default: the rig's).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address (default: a local cluster).")] = None,
    workers: Annotated[int, typer.Option(help="Workers of the local cluster.")] = 2,
    out_dir: Annotated[Path, typer.Option("--out", help="Directory for rqfep.csv, rqfep.png, sweep.json.")] = Path("sweep"),
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON summary instead of tables.")] = False,
) -> None:
    """The seed's computational study: a force sweep, POD + RQ per run, the RQ-FEP and flagged interactions."""
    from daq.studies.sweep import SweepSpec, asymptote_warnings, print_report, run_sweep, summary_json, write_outputs

    spec = SweepSpec(
        pmin=pmin, pmax=pmax, n=n, duration=duration, outputs=outputs, order=order, scheduler=scheduler, workers=workers
    )
    try:
        spec.validate()
    except ValueError as exc:
        fail(str(exc))
    if out_dir.exists() and not out_dir.is_dir():
        fail(f"--out {out_dir}: exists and is not a directory")
    r = open_rig(rig)
    try:
        with Progress(err if json_out else out) as report:
            rep = run_sweep(r, spec, progress=report)
    except ValueError as exc:
        fail(str(exc))
    paths = write_outputs(rep, out_dir)
    if json_out:
        out.print_json(summary_json(rep))
    else:
        print_report(out, rep, paths)
    for line in asymptote_warnings(rep.asymptotes):  # the asymptotes whose edge runs disagree: one line each
        err.print(f"gvt: warning: {line}", markup=False, soft_wrap=True)
