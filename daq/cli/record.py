"""``gvt record SESSION.toml``: a device (or several) into an MCAP log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import fail, open_rig, out


def record(
    session: Annotated[Path, typer.Argument(help="Session config (configs/sessions/*.toml).")],
    out_path: Annotated[Path | None, typer.Option("--out", help="Output log (default: the config's output).")] = None,
    duration: Annotated[float | None, typer.Option(min=0.1, help="Seconds to record (default: the config's).")] = None,
    view: Annotated[bool, typer.Option("--view", help="Serve the rerun web viewer on 127.0.0.1, show it live.")] = False,
    connect: Annotated[str | None, typer.Option("--connect", help="Show it in a running rerun viewer (gRPC url).")] = None,
) -> None:
    """Record a session: device → MCAP log, with the hammer trigger and hit quality gate."""
    import signal
    import threading

    from analysis.model.loader import load_config
    from daq.config.session import SessionConfig
    from daq.session import run_session

    cfg = load_config(SessionConfig, session)
    if duration is not None:
        cfg = cfg.model_copy(update={"duration": duration})
    r = open_rig(cfg.rig)
    target = out_path or Path(cfg.output)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())

    from daq.live_status import LiveStatus

    vtarget = None
    if view or connect:  # rerun (pyarrow, its bindings: ~100 MB resident) is imported only for a view
        from daq.view.cli_glue import open_live_view
        from daq.view.lane import ViewError

        try:
            vtarget = open_live_view(out, view, connect)
        except ViewError as exc:
            fail(str(exc))
    try:
        with LiveStatus(out, cfg.name) as live:
            res = run_session(cfg, r, target, stop=stop, status=live.update, view=vtarget)
    except KeyboardInterrupt:
        stop.set()
        raise
    from rich.table import Table

    table = Table(title=f"{cfg.name}: {len(res.hits)} hits")
    for col in ("#", "t [s]", "peak [N]", "width [ms]", "energy [J]", "verdict", "reason"):
        table.add_column(col)
    for h in res.hits:
        e = "—" if h.input_energy_J is None else f"{h.input_energy_J:.3g}"
        table.add_row(
            str(h.hit),
            f"{h.t_s:.3f}",
            f"{h.peak_force_N:.0f}",
            f"{1000 * h.pulse_width_s:.2f}",
            e,
            h.verdict,
            "; ".join(h.reasons) or "ok",
        )
    out.print(table)
    lost = f"{res.lost_samples} samples in {len(res.gaps)} gaps" if res.lost_samples else "nothing"
    out.print(
        f"wrote {target}: {res.samples} samples in {res.seconds:.1f} s; lost: {lost}; writer overruns: "
        f"{res.writer_overrun_samples}; suspect channels: {', '.join(res.suspects) or 'none'}",
        markup=False,
    )
    if cfg.analysis.enabled:
        from daq.analyze_cmd import events_table

        out.print(events_table(res.analysis_events, "internal-resonance events (near-live analysis)"))
        if res.confirmations:
            from daq.confirm_cmd import confirmations_table

            out.print(confirmations_table(sorted(res.confirmations, key=lambda c: c.get("event_id") or 0),
                                          "confirmations (WBEMD + slow flow, in the background)"))  # fmt: skip
    if vtarget is not None:
        from daq.view.cli_glue import close_live_view

        close_live_view(out, vtarget, None)
    if res.view_dropped_samples:
        out.print(f"view: did not show {res.view_dropped_samples} samples (view_overrun event in the log)", markup=False)
    if res.driver_error:
        fail(f"the driver stopped: {res.driver_error}", code=1)
