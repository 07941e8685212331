"""``gvt replay``: a log through the live fan-out, with the near-live analysis (the recorder of ``gvt record``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, err, fail, note, open_rig, out


def replay(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    speed: Annotated[float, typer.Option(min=0.0, help="1 = real time, 2 = twice as fast, 0 = full speed.")] = 0.0,
    analysis: Annotated[bool, typer.Option(help="Run the near-live analysis on the replayed blocks.")] = True,
    rig: Annotated[str | None, typer.Option(help="Rig for the analysis (default: the one attached to the log).")] = None,
    view: Annotated[bool, typer.Option("--view", help="Serve the rerun web viewer on 127.0.0.1 and show the replay.")] = False,
    connect: Annotated[str | None, typer.Option("--connect", help="Show it in a running rerun viewer (gRPC url).")] = None,
    confirm: Annotated[bool, typer.Option(help="Confirm the IR events (WBEMD + slow flow) in the background.")] = True,
    frf: Annotated[bool, typer.Option(help="Live FRFs of the log's accepted hits, one line per hit.")] = True,
    overwrite: OverwriteOpt = False,
) -> None:
    """Feed a log through the live fan-out (block boundaries and sample indices kept), with the near-live analysis.

    Confirmations go to LOG.confirm.mcap beside the log (an existing one is replaced only with --overwrite)."""
    import signal
    import threading

    from daq.log.reader import LogReader
    from daq.replay_session import run_replay
    from daq.studies.confirm import companion_path

    LogReader(log).require_log()  # a file that is not a log: one line before anything starts (issue 30)
    companion = companion_path(log)
    if analysis and confirm:
        check_output(companion, overwrite, "the companion log", inputs=[log])
    r = open_rig(rig) if rig is not None else None
    vtarget = None
    if view or connect:
        from daq.view.cli_glue import open_live_view

        vtarget = open_live_view(out, view, connect)
    stop = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        res = run_replay(log, speed=speed or None, rig=r, analysis=analysis, confirm=confirm,
                         view=vtarget, note=note, stop=stop, drain_progress=_drain(), frf=frf,
                         frf_line=lambda s: out.print(s, markup=False))  # fmt: skip
    finally:
        signal.signal(signal.SIGTERM, old)
    _print(log, res, companion)
    if vtarget is not None:
        from daq.view.cli_glue import close_live_view

        close_live_view(out, vtarget, res.view_lane)
    if res.outcome.exit_code:
        fail(res.outcome.message or "replay failed", res.outcome.exit_code)
    if res.stats.bad_blocks:  # replayed around damage: the skipped ranges were printed; data was lost
        raise typer.Exit(3)


def _drain():
    from daq.terminal import drain_progress

    return drain_progress(err, what="confirming", noun="IR events")


def _print(log: Path, res, companion: Path) -> None:
    if res.stream is not None:
        from daq.studies.analyze.tables import events_table

        out.print(events_table(res.events, f"internal-resonance events (analysis of {res.stream})"))
        if res.analysis_dropped_samples:
            out.print(f"analysis fell behind: skipped {res.analysis_dropped_samples} samples (restarted after each gap)",
                      markup=False)  # fmt: skip
    if res.confirmations is not None:
        from daq.studies.confirm import ConfirmRun, confirmations_table, write_companion

        out.print(confirmations_table(res.confirmations, f"confirmations (WBEMD + slow flow, {res.stream})"))
        if res.confirmations:
            from daq.outputs import atomic_output

            with atomic_output(companion) as tmp:
                write_companion(ConfirmRun(str(log), res.stream, "replay", "replay", res.confirmations), tmp)
            out.print(f"wrote {len(res.confirmations)} confirmation records to {companion}", markup=False)
    stats = res.stats
    health = "" if res.complete_log else f" (damaged log: {res.salvaged_messages} messages salvaged)"
    if stats.bad_blocks:
        from daq.log.reader import OVERLAP

        bad = [b for b in stats.bad_blocks if OVERLAP not in b]
        contra = [b for b in stats.bad_blocks if OVERLAP in b]
        if bad:
            err.print(f"skipped {len(bad)} undecodable sample block(s), replayed as gaps; first: {bad[0]}", markup=False)
        if contra:  # D78: the samples are replayed once, as first read; the block that says otherwise is left out
            err.print(f"left out {len(contra)} overlapping block(s) that disagree with the samples replayed; first: {contra[0]}",
                      markup=False)  # fmt: skip
    for stream, n in stats.samples.items():
        gaps = stats.gaps.get(stream, [])
        out.print(f"replayed {stream}: {n} samples, {len(gaps)} gaps ({sum(b - a for a, b in gaps)} samples missing)",
                  markup=False)  # fmt: skip
    out.print(f"{stats.blocks} blocks, {stats.log_seconds:.3f} s of data in {stats.wall_seconds:.3f} s wall; subscriber "
              f"received {res.counted_blocks}, dropped {res.dropped_blocks}{health}", markup=False)  # fmt: skip
