"""``gvt identify``: the seed's NSI of a rig's nonlinear attachment (eq. 5.8 fit on the RQ-FDP)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, Progress, check_output, err, fail, open_rig, out


def identify(
    source: Annotated[Path, typer.Argument(help="A 'gvt sweep' output directory, or a session LOG (.mcap) with hits.")],
    rig: Annotated[str, typer.Option("--rig", help="Rig TOML file or name in configs/rigs (the sweep's rig).")],
    frequency: Annotated[str, typer.Option(help="rq: the POM's RQ (seed eq. 2.18); pom: its temporal frequency.")] = "rq",
    law: Annotated[
        str, typer.Option(help="seed: eq. 5.8 as printed; hb: harmonic-balance factor; exact: the one-mass backbone.")
    ] = "seed",
    max_ratio: Annotated[float | None, typer.Option(help="Fit only points with f <= ratio x f_n (default: all).")] = None,
    smooth: Annotated[int, typer.Option(help="Running-median window (points, odd) of the RQ-FDP.")] = 5,
    boot: Annotated[int, typer.Option(help="Bootstrap replicates for the uncertainty (0: none).")] = 200,
    no_intersection: Annotated[bool, typer.Option("--no-intersection", help="Fit α and β together (no eq. 5.9).")] = False,
    method: Annotated[str, typer.Option(help="nsi: the RQ-FDP fit; rfs: eq. 5.11 of a grounded attachment from a LOG.")] = "nsi",
    hit: Annotated[int | None, typer.Option(help="rfs: the identification hit (default: the first accepted).")] = None,
    validate: Annotated[str | None, typer.Option(help="rfs: validation hits, e.g. 1,2,3 (default: the others).")] = None,
    out_toml: Annotated[Path | None, typer.Option("--out", help="rfs: write the rig with the identified values.")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write the RQ-FDP with the fit as PNG.")] = None,
    csv_out: Annotated[Path | None, typer.Option("--csv", help="LOG: per-window table (default LOG.nsi-windows.csv).")] = None,
    window: Annotated[float | None, typer.Option(help="LOG: window length, s (default ~T/2 of the fundamental, Ch. 5).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON summary instead of tables.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Identify α|δ|^β δ of the rig's attachment from a force sweep: whole-run δ̄, RQ-FDP, eq. 5.8 fit."""
    if method != "nsi":  # --method rfs: the grounded attachment's eq. 5.11 from a session log (daq/rfs_cmd.py)
        from daq.rfs_cmd import cli_rfs

        return cli_rfs(method, source, rig, hit, validate, png, out_toml, json_out, overwrite)
    from daq.identify_cmd import IdentifyOptions

    opts = IdentifyOptions(frequency=frequency, law=law, max_ratio=max_ratio, smooth=smooth, n_boot=boot,
                           intersection=not no_intersection)  # fmt: skip
    opts.validate()
    if not source.exists():
        fail(f"{source}: no such file or directory")
    if not source.is_dir():  # a session LOG: windowed δ̄ as in the seed's Ch. 5 experiment (daq/identify_log.py)
        from daq.identify_log import cli_identify_log

        return cli_identify_log(source, rig, opts, png, csv_out, window, json_out, overwrite)
    if png is not None:
        check_output(png, overwrite, "--png")
    r = open_rig(rig)
    from daq.identify_cmd import identify_sweep, plot_fdp, print_report, summary_json

    with Progress(err if json_out else out) as report:
        ident = identify_sweep(r, source, opts, progress=report)
    if png is not None:
        plot_fdp(ident, png)
    if json_out:
        out.print_json(summary_json(ident))
    else:
        print_report(out, ident)
