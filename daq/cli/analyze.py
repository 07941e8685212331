"""``gvt analyze``: near-live detection in batch over a log."""

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
    rerun_hint,
    rig_arg,
)


def analyze(
    logs: Annotated[
        list[Path], typer.Argument(metavar="LOG...", help="Session log (.mcap); several, or a directory: a campaign.")
    ],
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    stream: Annotated[str | None, typer.Option(help="Stream to analyse (default: the one with all the rig's sensors).")] = None,
    window: Annotated[float | None, typer.Option(min=0.0, help="Window length, s (default: 0.45 / f1 of the rig).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON (summary, events, warnings).")] = False,
    windows_out: Annotated[bool, typer.Option("--windows", help="With --json: also every window's RQ and modal result.")] = False,
    rrd: Annotated[Path | None, typer.Option("--rrd", help="Also write a rerun recording (.rrd).")] = None,
    overwrite: OverwriteOpt = False,
    out_dir: OutDirOpt = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = None,
) -> None:
    """Near-live detection in batch over a log: RQ curves, window-robust spikes and IR events (same kernels as live).
    Over several logs or a directory: one Dask job, one summary table (docs/campaign.md)."""
    if is_campaign(logs, scheduler, workers, out_dir):
        if window is not None and window <= 0:
            fail("--window must be > 0 s")
        opts = {"rig": rig_arg(rig), "stream": stream, "window": window, "windows": windows_out}
        return campaign("analyze", logs, opts, {"--rrd": rrd}, out_dir, scheduler, workers, json_out, overwrite)
    log = logs[0]
    console = err if json_out else out
    if rrd is not None:
        check_output(rrd, overwrite, "--rrd", inputs=[log])
    if window is not None and window <= 0:
        fail("--window must be > 0 s")
    if not json_out:  # what is being analysed, before the analysis libraries load (~1-3 s): the first line in < 1 s
        header = log_header(log)
        if header:
            out.print(header, markup=False)
    r = open_rig(rig) if rig is not None else None
    from analysis.forked_worker import WorkerDied
    from analysis.jit_cache import compile_notice
    from analysis.operator import AnalysisSettings, compiled_kernels
    from daq.studies.analyze.batch import AnalyzeError, analyze_log
    from daq.studies.analyze.tables import print_json, print_report

    notice = compile_notice(compiled_kernels())  # a cold numba cache: ~5 s of compiling before the first window
    if notice:
        console.print(notice, markup=False)
    try:
        with Progress(console) as report:
            run = analyze_log(log, r, stream, AnalysisSettings(window_s=window), progress=lambda f: report("analysing", f))
    except AnalyzeError as exc:
        fail(str(exc))
    except WorkerDied as exc:  # the seed lane's worker process was killed (out of memory, kill -9): a runtime failure
        err.print(f"gvt: error: {exc}; nothing was written", markup=False)
        raise typer.Exit(1) from None
    if run.bad_blocks:
        err.print(f"skipped {len(run.bad_blocks)} undecodable sample block(s), analysed as gaps; first: {run.bad_blocks[0]}",
                  markup=False)  # fmt: skip
    if rrd is not None:
        from daq.outputs import atomic_output
        from daq.studies.analyze.rrd import build_rrd

        with atomic_output(rrd) as tmp:
            summary = build_rrd(log, tmp, rig=r, results=run.results)
        console.print(f"wrote {rrd} ({summary.blocks} blocks); open it: {rerun_hint()} {rrd}", markup=False)
    if json_out:
        print_json(out, run, full=windows_out)
    else:
        print_report(out, run)
    if run.bad_blocks:  # the results are of what was readable: say so in the exit code (docs/log-format.md)
        raise typer.Exit(3)


def log_header(log: Path) -> str | None:
    """``analysing LOG: dev0, 15 channels at 16384 Hz, 2.10 s``: what the log holds, from its summary (no samples read,
    no analysis library loaded); None when the log cannot be opened (the analysis says why, one line)."""
    from daq.log.reader import LogReader

    try:
        reader = LogReader(log)
        streams, counts = reader.streams(), reader.stream_records()
    except Exception:  # only a header: the analysis opens the log again and says what is wrong (one line)
        return None
    parts = []
    for name, info in sorted(streams.items()):
        n = counts.get(name, {}).get("samples")
        secs = f", {n / info.sample_rate:.2f} s" if isinstance(n, int) and info.sample_rate > 0 else ""
        parts.append(f"{name}, {len(info.channels)} channels at {info.sample_rate:g} Hz{secs}")
    return f"analysing {log}: {'; '.join(parts) or 'no sample streams'}"
