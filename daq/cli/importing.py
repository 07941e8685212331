"""``gvt import SRC -o OUT.mcap``: another tool's measurement (UFF, CSV, TDMS, HDF5) as a gvtlink log (docs/import.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, err, out


def import_(
    src: Annotated[Path, typer.Argument(help="File to import: .uff/.unv/.58/.bunv, .csv, .tdms, .h5/.hdf5.")],
    out_path: Annotated[Path, typer.Option("-o", "--out", help="The gvtlink log to write (.mcap).")],
    fmt: Annotated[str, typer.Option("--format", help="auto (by suffix/content), uff, csv, tdms or hdf5.")] = "auto",
    channels: Annotated[
        Path | None, typer.Option("--channels", help="Channel table CSV (name,node,x,y,z,direction,sensitivity,unit).")
    ] = None,
    rate: Annotated[
        float | None, typer.Option("--rate", help="Sample rate (Hz) of a CSV or TDMS file that has no time information.")
    ] = None,
    group: Annotated[str | None, typer.Option("--group", help="The TDMS group to import (groups on different grids).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Read SRC, convert its units to SI (pint), and write a log every gvt verb takes, with its provenance; each
    assumption is printed once; bad input is one line and nothing is written."""
    import json

    from daq.studies.importing.formats import read_any
    from daq.studies.importing.log import write_log

    check_output(out_path, overwrite, "--out", inputs=[src])
    data = read_any(src, fmt, channels, rate=rate, group=group)
    summary = write_log(data, out_path, overwrite=overwrite)
    notes = list(data.provenance.assumptions)
    if summary.get("trigger_N"):
        notes.append(
            f"hits found by the hammer trigger at {summary['trigger_N']:.4g} N (5 % of the largest force), "
            f"records of {summary['record_s']:.4g} s (to the next hit or the end of the data, 1 s at most)"
        )
    for w in summary.get("warnings", []):  # on stderr, so --json's stdout stays one document
        err.print(f"warning: {w}", markup=False)
    if json_out:
        out.print_json(json.dumps({**summary, "out": str(out_path), "format": data.provenance.format,
                                   "sha256": data.provenance.sha256, "assumptions": notes}, default=float))  # fmt: skip
        return
    for n in notes:
        out.print(f"assumed: {n}", markup=False)
    if summary["kind"] == "time":
        units = ", ".join(f"{c} [{u}]" for c, u in zip(summary["channels"], summary["units"], strict=True))
        out.print(f"{src}: {len(summary['channels'])} channels x {summary['samples']} samples at {summary['fs_hz']:g} Hz "
                  f"({summary['duration_s']:.3f} s), {summary['hits']} hit(s), {summary['accepted']} accepted; {units}",
                  markup=False)  # fmt: skip
    else:
        out.print(f"{src}: {len(summary['outputs'])} output(s) x {len(summary['references'])} reference(s) "
                  f"{summary['form']} [{summary['units']}], {summary['lines']} lines {summary['band_hz'][0]:g}-"
                  f"{summary['band_hz'][1]:g} Hz, coherence {'in the file' if summary['coherence'] else 'absent'}",
                  markup=False)  # fmt: skip
    out.print(f"wrote {out_path}", markup=False)
