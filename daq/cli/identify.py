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
        str,
        typer.Option(
            help="seed: eq. 5.8 as printed; hb: harmonic-balance factor; exact: the one-mass backbone; "
            "modal / modal-exact: the attachment's mode of the rig's lowest modes + the spring (two-parameter)."
        ),
    ] = "seed",
    max_ratio: Annotated[float | None, typer.Option(help="Fit only points with f <= ratio x f_n (default: all).")] = None,
    smooth: Annotated[int, typer.Option(help="Running-median window (points, odd) of the RQ-FDP.")] = 5,
    boot: Annotated[int, typer.Option(help="Bootstrap replicates for the uncertainty (0: none).")] = 200,
    no_intersection: Annotated[bool, typer.Option("--no-intersection", help="Fit α and β together (no eq. 5.9).")] = False,
    method: Annotated[str, typer.Option(help="nsi: the RQ-FDP fit; rfs: eq. 5.11 of a grounded attachment from a LOG.")] = "nsi",
    hit: Annotated[int | None, typer.Option(help="rfs: the identification hit (default: the first accepted).")] = None,
    quantity: Annotated[
        str | None, typer.Option(help="rfs: velocity|displacement compared (default: velocity for a rotational [nsi]).")
    ] = None,
    validate: Annotated[
        str | None, typer.Option(help="LOG: validation hits, e.g. 1,2,3 (rfs default: the others; nsi: lowest, middle, highest).")
    ] = None,
    out_toml: Annotated[
        Path | None, typer.Option("--out", help="Write the rig with the identified law (then validate it).")
    ] = None,
    validate_forces: Annotated[
        str | None, typer.Option(help="Sweep: validation forces F,F,F in N (default: 3 log-spaced, off the sweep's grid).")
    ] = None,
    validation_png: Annotated[Path | None, typer.Option(help="Write the validation overlays (δ, δ') as PNG.")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write the RQ-FDP with the fit as PNG.")] = None,
    csv_out: Annotated[Path | None, typer.Option("--csv", help="LOG: per-window table (default LOG.nsi-windows.csv).")] = None,
    window: Annotated[float | None, typer.Option(help="LOG: window length, s (default ~T/2 of the fundamental, Ch. 5).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON summary instead of tables.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Identify α|δ|^β δ of the rig's attachment from a force sweep: whole-run δ̄, RQ-FDP, eq. 5.8 fit."""
    if method != "nsi":  # --method rfs: the grounded attachment's eq. 5.11 from a session log (daq/studies/identify/rfs.py)
        from daq.studies.identify.rfs import cli_rfs

        return cli_rfs(method, source, rig, hit, validate, png, out_toml, json_out, overwrite, quantity)
    if quantity is not None:
        fail("--quantity is for --method rfs")
    from daq.studies.identify.sweep import IdentifyOptions

    opts = IdentifyOptions(frequency=frequency, law=law, max_ratio=max_ratio, smooth=smooth, n_boot=boot,
                           intersection=not no_intersection)  # fmt: skip
    opts.validate()
    if not source.exists():
        fail(f"{source}: no such file or directory")
    outs = [(p, w) for p, w in ((png, "--png"), (out_toml, "--out"), (validation_png, "--validation-png")) if p is not None]
    if len({p.resolve() for p, _ in outs}) < len(outs):
        fail(f"{', '.join(w for _, w in outs)} must name different files")
    if not source.is_dir():  # a session LOG: windowed δ̄ as in the seed's Ch. 5 experiment (daq/studies/identify/log.py)
        from daq.studies.identify.log import cli_identify_log

        if validate_forces is not None:
            fail("--validate-forces is for a sweep; a LOG validates on its hits (--validate 1,2,3)")
        return cli_identify_log(source, rig, opts, png, csv_out, window, json_out, overwrite, out_toml, validation_png, validate)
    if validate is not None:
        fail("--validate names hits of a LOG; a sweep validates at forces (--validate-forces F,F,F)")
    for p, w in outs:
        check_output(p, overwrite, w)
    from daq.studies.identify import validate as iv

    forces = iv.parse_forces(validate_forces) if validate_forces is not None else None
    r = open_rig(rig)
    if out_toml is not None and Path(r.path).resolve() == out_toml.resolve():
        fail(f"--out {out_toml}: is the rig itself; give a new file name")
    from daq.studies.identify.sweep import identify_sweep, plot_fdp, print_report

    with Progress(err if json_out else out) as report:
        ident = identify_sweep(r, source, opts, progress=report)
    if png is not None:
        plot_fdp(ident, png)
    res = None
    if out_toml is not None or validation_png is not None or forces is not None:
        dofs, validator = iv.sweep_validator(ident, r, source, forces)
        res = iv.finish(ident, r, dofs, out_toml, validation_png, validator)
    if json_out:
        doc = ident.summary()
        doc["png"] = str(png) if png is not None else None
        if res is not None:
            doc.update(res.to_dict())
        out.print_json(iv.dumps(doc))
    else:
        print_report(out, ident)
        if res is not None and res.validation is not None:
            iv.print_validation(out, res.validation)
        for path, what in ((png, "RQ-FDP"), (out_toml, "identified rig"), (validation_png, "validation overlays")):
            if path is not None:
                out.print(f"wrote {what}: {path}", markup=False)
