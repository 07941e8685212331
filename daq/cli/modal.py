"""``gvt modal``: modal parameters (pLSCF + LSFD) of a session or an FRF file, against the rig's FE modes."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import (
    OutDirOpt,
    OverwriteOpt,
    Progress,
    SchedulerOpt,
    WorkersOpt,
    campaign,
    check_output,
    err,
    fail,
    is_campaign,
    open_rig,
    out,
    rig_arg,
)


def modal(
    sources: Annotated[
        list[Path],
        typer.Argument(
            metavar="SOURCE...",
            help="Session log (.mcap), FRFs of `gvt frf --out` (.npz), a UFF 58 FRF file or its import; "
            "several, or a directory of logs: a campaign.",
        ),
    ],
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    band: Annotated[
        tuple[float, float] | None, typer.Option(help="Band to identify in, Hz: LOW HIGH (default 2 Hz to the FRFs' band).")
    ] = None,
    poles: Annotated[
        Path | None, typer.Option("--poles", help="Pick these poles ([[poles]] freq_hz, tol) instead of the automatic rule.")
    ] = None,
    max_order: Annotated[int, typer.Option(min=2, max=200, help="Highest model order of the stabilisation.")] = 60,
    png: Annotated[Path | None, typer.Option("--png", help="Write the stabilisation chart to this PNG.")] = None,
    modes_out: Annotated[
        Path | None, typer.Option("--modes-out", help="Write the modes (JSON; gvt export --modes reads it).")
    ] = None,
    rrd: Annotated[
        Path | None, typer.Option("--rrd", help="Write the mode shapes, animated on the rig's test geometry (rerun .rrd).")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    overwrite: OverwriteOpt = False,
    out_dir: OutDirOpt = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = None,
) -> None:
    """Stabilisation chart, one pole per physical mode, shapes, quality figures and one-to-one pairing with the rig's
    FE modes (docs/modal-id.md). Over several logs or a directory: one Dask job, one summary table (docs/campaign.md)."""
    import json

    from analysis.modal_id import load_targets
    from daq.outputs import atomic_output
    from daq.studies.importing.frfs import frf_file
    from daq.studies.modal import load_frf_source, modal_from_frf, rejected_note, rows_summary, table_text, write_modes

    if is_campaign(sources, scheduler, workers, out_dir):
        opts = {"rig": rig_arg(rig), "band": band, "max_order": max_order,
                "targets": load_targets(poles) if poles is not None else None}  # fmt: skip
        outputs = {"--png": png, "--modes-out": modes_out, "--rrd": rrd}
        return campaign("modal", sources, opts, outputs, out_dir, scheduler, workers, json_out, overwrite)
    source = sources[0]
    for p, what in ((png, "--png"), (modes_out, "--modes-out"), (rrd, "--rrd")):
        if p is not None:
            check_output(p, overwrite, what, inputs=[source])
    targets = load_targets(poles) if poles is not None else None
    r = open_rig(rig) if rig is not None else None
    given = None if source.suffix == ".npz" else frf_file(source)  # a UFF 58 FRF file, or a log gvt import made of one
    if source.suffix == ".npz" or given is not None:
        if rrd is not None and r is None:
            fail("--rrd draws the modes on the rig's test geometry: give --rig (an FRF file carries none)")
        frf, driving, refused = given[0] if given else load_frf_source(source), None, []
        for note in given[1] if given else []:
            (err if json_out else out).print(f"assumed: {note}", markup=False)
    else:
        r, frf, driving, refused = _frfs_of_log(source, r, None if band is None else band[1], json_out)
    band = band or (2.0, min(1000.0, float(frf.freq[-1])))
    run = modal_from_frf(frf, r, band[0], band[1], targets, max_order, source=str(source), driving=driving)
    run.refused_hits = refused
    if modes_out is not None:
        with atomic_output(modes_out) as tmp:
            write_modes(run, tmp)
    if png is not None:
        from analysis.modal_plot import stabilisation_png

        with atomic_output(png) as tmp:
            stabilisation_png(run.result.table, tmp, frf.freq, frf.H, run.result.selected)
    if rrd is not None:
        from daq.view.modes import write_modal_run_rrd

        with atomic_output(rrd) as tmp:
            write_modal_run_rrd(run, r, tmp)
    if json_out:
        out.print_json(json.dumps(rows_summary(run), default=float))
        return
    out.print(f"{source}: {len(run.rows)} modes in {band[0]:g}-{band[1]:g} Hz from {len(frf.outputs)} responses x "
              f"{len(frf.references)} reference(s); window damping removed ({run.result.sigma_added:.3f} 1/s)",
              markup=False)  # fmt: skip
    out.print(table_text(run), markup=False)
    for w in run.warnings:
        out.print(f"warning: {w}", markup=False)
    if (left := rejected_note(run.result)) is not None:
        out.print(f"note: {left}", markup=False)
    for h in refused:
        out.print(f"hit {h['hit']} {'left out' if h['verdict'] == 'left out' else 'refused'}: {h['reason']}", markup=False)
    for p in (png, modes_out, rrd):
        if p is not None:
            out.print(f"wrote {p}", markup=False)


def _frfs_of_log(source: Path, r, band_hi: float | None, json_out: bool) -> tuple:
    """(rig, FRFs, driving points, refused hits) of a session log: its attached rig unless one was given, and
    gvt frf's FRFs of the accepted hits (every hit point of a roving plan a reference); none accepted: exit 2."""
    from daq.log.reader import LogReader
    from daq.log.rig import rig_from_log
    from daq.studies.frf import frf_from_log

    r = r if r is not None else rig_from_log(LogReader(source))
    with Progress(err if json_out else out) as report:
        fr = frf_from_log(source, r, band_hz=band_hi, progress=lambda f: report("hits", f))
    refused = [h for h in fr.hits if h["verdict"] != "accepted"]
    if fr.frf is None:
        fail(f"{source}: no accepted hit to build FRFs from ({len(refused)} refused; `gvt frf {source}` says why)")
    return r, fr.frf, fr.driving, refused
