"""``gvt report``: a static HTML report of a session."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, note, open_rig, out


def report(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    out_path: Annotated[Path, typer.Option("--out", help="Output HTML file (self-contained).")] = Path("report.html"),
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    frf_channel: Annotated[
        str | None, typer.Option(help="Response drawn beside the driving point in the FRF figures (default: the last).")
    ] = None,
    band: Annotated[
        float | None,
        typer.Option(min=1.0, help="Band of interest of the FRFs, Hz (a hit's -10 dB must reach it); default 1000 or fs/2.56."),
    ] = None,
    identify: Annotated[
        list[Path] | None,
        typer.Option("--identify", help="A 'gvt identify --json' summary for the Identification section (repeatable)."),
    ] = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """A static HTML report of a session: hits, verdicts, loss, RQ-FEP, IR events, confirmations, FRFs and modes."""
    from daq.outputs import atomic_output
    from daq.studies.report.build import build_report

    check_output(out_path, overwrite, inputs=[log])
    from daq.studies.report.identify import load_summaries

    ident = load_summaries(identify or [])

    with atomic_output(out_path) as tmp:
        s = build_report(log, tmp, rig=open_rig(rig) if rig is not None else None, frf_channel=frf_channel, band_hz=band,
                         identification=ident)  # fmt: skip
    out.print(f"wrote {out_path}: {len(s.figures)} plots, {len(s.tables)} tables (analysis results from {s.results_from})",
              markup=False)  # fmt: skip
    if s.rig_note and "carries no rig attachment" not in s.rig_note:
        note(f"drawn without the log's rig: {s.rig_note}")
    elif s.frf_absent:  # one line: a missing rig is said once, above
        note(f"no FRFs in the report: {s.frf_absent}")
