"""``gvt export LOG --format uff``: geometry, trace lines, accepted hits' time histories and, when given, FRFs
and mode shapes as one UFF file (daq/studies/uff/export.py, docs/uff.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, fail, out


def export(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    fmt: Annotated[str, typer.Option("--format", help="uff (universal file: datasets 15, 82, 164, 58, 55).")] = "uff",
    out_path: Annotated[Path | None, typer.Option("--out", help="Output file (default: LOG with suffix .uff).")] = None,
    frf: Annotated[Path | None, typer.Option("--frf", help="FRFs to add (FRF.npz from FRFSet.to_npz).")] = None,
    modes: Annotated[Path | None, typer.Option("--modes", help="Mode shapes to add (MODES.json, see docs/uff.md).")] = None,
    channels: Annotated[
        Path | None, typer.Option("--channels", help="Channel table CSV (name,node,x,y,z,direction,sensitivity,unit).")
    ] = None,
    binary: Annotated[bool, typer.Option("--binary", help="Write datasets 58 as binary 58b (about 3x smaller).")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Export a session log for modal software: UFF geometry (15), trace lines (82), time histories of the accepted
    hits (58), and FRFs/coherence (58) and mode shapes (55) when given."""
    from daq.outputs import atomic_output
    from daq.studies.uff.export import export_uff

    if fmt != "uff":
        fail(f"--format must be uff, got {fmt!r} (for npz or csv use `gvt log export`)")
    target = out_path or log.with_suffix(".uff")
    given = [p for p in (frf, modes, channels) if p is not None]
    for p in given:
        if not p.is_file():
            fail(f"{p}: no such file")
    check_output(target, overwrite, inputs=[log, *given])
    with atomic_output(target) as tmp:
        line = export_uff(log, tmp, channels_csv=channels, frf=frf, modes=modes, binary=binary)
    out.print(f"wrote {target}: {line}", markup=False)
