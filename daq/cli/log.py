"""``gvt log info|recover|export``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, err, fail, out

log_app = typer.Typer(no_args_is_help=True, help="Inspect, repair and export session logs (MCAP).")


@log_app.command("info")
def info_cmd(
    file: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    verify: Annotated[bool, typer.Option("--verify", help="Read and check every chunk (CRC) and sample block.")] = False,
) -> None:
    """Streams, channels, rates, durations, sample counts, gaps, hits, events and file health (from the summary;
    --verify checks every chunk). Exit 0 whatever the health (the report says it), except that --verify exits 3
    when it found damage, so a script can check a log: `gvt log info --verify LOG || gvt log recover LOG FIXED`."""
    from daq.log.tools import info_json, info_text, log_info

    info = log_info(file, verify=verify)
    if json_out:
        out.print(info_json(info), markup=False, soft_wrap=True)
    else:
        out.print(info_text(info), markup=False)
    if verify and str(info["health"]).startswith("damaged"):
        raise typer.Exit(3)


@log_app.command("recover")
def recover_cmd(
    src: Annotated[Path, typer.Argument(help="Damaged (or any) log.")],
    dst: Annotated[Path, typer.Argument(help="New, fully indexed log.")],
    overwrite: OverwriteOpt = False,
) -> None:
    """Rewrite everything readable; exit 0 when nothing was lost, 3 when data was lost."""
    from daq.log.tools import recover

    check_output(dst, overwrite, "DST", inputs=[src])
    rep = recover(src, dst)
    if rep.data_lost:
        reasons = [rep.stopped_because, rep.chunks_bad and f"{rep.chunks_bad} damaged chunk(s) skipped",
                   rep.missing_by_sequence and f"{rep.missing_by_sequence} messages missing by sequence number"]  # fmt: skip
        why = f" ({'; '.join(str(x) for x in reasons if x)})" if any(reasons) else ""
        err.print(
            f"gvt: recovered {rep.messages} messages from {rep.chunks_ok} complete chunks into {dst}; data was lost"
            f"{why}: read {rep.bytes_scanned} of {rep.file_size} bytes",
            markup=False,
        )
        raise typer.Exit(3)
    notes = [n for n in (rep.summary_problem and f"the summary was unusable: {rep.summary_problem}",
                         rep.duplicates and f"{rep.duplicates} duplicated messages kept once") if n]  # fmt: skip
    out.print(f"recovered {rep.messages} messages into {dst}; nothing lost" + "".join(f"; {n}" for n in notes), markup=False)


@log_app.command("export")
def export_cmd(
    file: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    fmt: Annotated[str, typer.Option("--format", help="npz or csv.")] = "npz",
    out_path: Annotated[Path | None, typer.Option("--out", help="Output file (default: FILE with the format's suffix).")] = None,
    channels: Annotated[str | None, typer.Option(help="Comma-separated channel names.")] = None,
    start: Annotated[float | None, typer.Option(help="Start time, s since the session start.")] = None,
    end: Annotated[float | None, typer.Option(help="End time, s since the session start.")] = None,
    stream: Annotated[str | None, typer.Option(help="Only this stream (default: all, merged on one time axis).")] = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Export samples to npz or csv on the session's timeline (every stream on one time axis, units in the header),
    optionally by channel and time range."""
    from daq.log.export import export

    if fmt not in ("npz", "csv"):
        fail(f"--format must be npz or csv, got {fmt!r}")
    if start is not None and end is not None and end <= start:
        fail("--end must be after --start")
    target = out_path or file.with_suffix(f".{fmt}")
    check_output(target, overwrite, inputs=[file])
    chans = [c.strip() for c in channels.split(",") if c.strip()] if channels else None
    out.print(export(file, target, fmt, chans, start, end, stream), markup=False)
