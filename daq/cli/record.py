"""``gvt record SESSION.toml``: a device (or several) into an MCAP log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, check_output, err, fail, open_rig, out


def record(
    session: Annotated[Path, typer.Argument(help="Session config (configs/sessions/*.toml).")],
    out_path: Annotated[Path | None, typer.Option("--out", help="Output log (default: the config's output).")] = None,
    duration: Annotated[float | None, typer.Option(min=0.1, help="Seconds of data to record (default: the config's).")] = None,
    view: Annotated[bool, typer.Option("--view", help="Serve the rerun web viewer on 127.0.0.1, show it live.")] = False,
    connect: Annotated[str | None, typer.Option("--connect", help="Show it in a running rerun viewer (gRPC url).")] = None,
    overwrite: OverwriteOpt = False,
    no_wait: Annotated[
        bool, typer.Option("--no-wait", help="Do not wait for the background confirmations after the data ends.")
    ] = False,
    frf: Annotated[bool, typer.Option("--frf/--no-frf", help="Live FRFs of the accepted hits, one line per hit.")] = True,
) -> None:
    """Record a session: device → MCAP log, with the hammer trigger and hit quality gate.

    The session ends when DURATION seconds of data are recorded, on Ctrl-C or SIGTERM, or when a device fails;
    exit 0 when all is well, 1 on a failure, 3 when data is missing (the last line says which)."""
    import threading

    from analysis.model.loader import parse_toml, validate
    from daq.config.rig_checks import check_session_against_rig
    from daq.config.session import SessionConfig
    from daq.live_status import LiveStatus
    from daq.session import run_session

    data = parse_toml(session)
    if duration is not None:  # validated like the file's own value (limits, the simulated span)
        data["duration"] = duration
    cfg = validate(SessionConfig, data, session)
    r = open_rig(cfg.rig)
    target = out_path or Path(cfg.output)
    overwrite = overwrite or cfg.overwrite
    check_output(target, overwrite)
    check_session_against_rig(cfg, r, cfg.source)  # every config mistake before the first line of output
    until = f"{cfg.duration:g} s of data" if cfg.duration else "Ctrl-C or SIGTERM"
    out.print(f"recording {cfg.name} into {target} until {until} (Ctrl-C or SIGTERM stops and finalises the file)",
              markup=False)  # fmt: skip
    stop = threading.Event()
    restore = _stop_on_signals(stop)
    try:
        vtarget = _open_view(view, connect)
        drain = _drain_reporter()
        with LiveStatus(out, cfg.name) as live:
            res = run_session(cfg, r, target, stop=stop, status=live.update, view=vtarget, overwrite=overwrite,
                              wait_confirmations=not no_wait, drain_progress=drain, frf=frf,
                              frf_line=lambda s: out.print(s, markup=False))  # fmt: skip
    finally:
        restore()
    _print_results(cfg, res, target)
    if vtarget is not None:
        from daq.view.cli_glue import close_live_view

        close_live_view(out, vtarget, None)
    if res.view_dropped_samples:
        out.print(f"view: did not show {res.view_dropped_samples} samples (view_overrun event in the log)", markup=False)
    o = res.outcome
    if o is not None and o.exit_code:
        fail(f"{o.message}; what was recorded is in {target}", code=o.exit_code)
    lost = res.lost_samples + res.writer_overrun_samples
    if lost:  # the session ran to its end, but not every sample made it: exit 3, as gvt log recover does
        fail(f"data lost: {lost} samples of {', '.join(res.streams)} were not recorded (the gaps are in /daq/events; "
             f"'gvt log info {target}' lists them)", code=3)  # fmt: skip


def _stop_on_signals(stop):
    """SIGTERM and the first Ctrl-C stop the session cleanly (the file is finalised); a second Ctrl-C aborts.
    Returns a function that puts the previous handlers back."""
    import signal

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}

    def on_int(*_: object) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        err.print("gvt: stopping (the file is being finalised; Ctrl-C again to abort)", markup=False)
        stop.set()

    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, on_int)

    def restore() -> None:
        for s, h in old.items():
            signal.signal(s, h)

    return restore


def _open_view(view: bool, connect: str | None):
    if not (view or connect):  # rerun (pyarrow, its bindings: ~100 MB resident) is imported only for a view
        return None
    from daq.view.cli_glue import open_live_view

    return open_live_view(out, view, connect)


def _drain_reporter():
    """The confirmation drain after the data ends: progress the user can see (never a silent wait). On the
    status display's console: rich nests the two live displays instead of garbling them."""
    from daq.terminal import drain_progress

    return drain_progress(out, what="confirming", noun="IR events", hint="--no-wait skips this")


def _print_results(cfg, res, target: Path) -> None:
    from daq.log.writer import BACKLOG_NOTE_S, backlog_line
    from daq.terminal import hits_table

    out.print(hits_table(res.hits, f"{cfg.name}: {len(res.hits)} hits"))
    lost = f"{res.lost_samples} samples in {len(res.gaps)} gaps" if res.lost_samples else "nothing"
    if res.estimated_lost_samples:
        lost += f" ({res.estimated_lost_samples} of them estimated from the host clock at device restarts)"
    restarts = f"; device restarts: {res.restarts} (a new segment each)" if res.restarts else ""
    rejected = f"; implausible blocks rejected: {res.rejected_blocks}" if res.rejected_blocks else ""
    suspects = ", ".join(f"{c} ({why})" for c, why in res.suspect_reasons.items()) or "none"
    out.print(f"wrote {target}: {res.samples} samples in {res.seconds:.1f} s; lost: {lost}; writer overruns: "
              f"{res.writer_overrun_samples}{restarts}{rejected}; suspect channels: {suspects}", markup=False)  # fmt: skip
    backlog = res.writer_backlog
    if backlog.get("peak_seconds", 0.0) > BACKLOG_NOTE_S:  # how far behind the writer fell: what a crash then would lose
        out.print(backlog_line(backlog["peak_seconds"], int(backlog["peak_bytes"])), markup=False)
    if cfg.analysis.enabled:
        from daq.studies.analyze.tables import events_table

        out.print(events_table(res.analysis_events, "internal-resonance events (near-live analysis)"))
        if res.confirmations:
            from daq.studies.confirm import confirmations_table

            out.print(confirmations_table(sorted(res.confirmations, key=lambda c: c.get("event_id") or 0),
                                          "confirmations (WBEMD + slow flow, in the background)"))  # fmt: skip
