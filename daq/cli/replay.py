"""``gvt replay``: a log through the live fan-out, with the near-live analysis."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import err, fail, open_rig, out


def replay(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    speed: Annotated[float, typer.Option(min=0.0, help="1 = real time, 2 = twice as fast, 0 = full speed.")] = 0.0,
    analysis: Annotated[bool, typer.Option(help="Run the near-live analysis on the replayed blocks.")] = True,
    rig: Annotated[str | None, typer.Option(help="Rig for the analysis (default: the one attached to the log).")] = None,
    view: Annotated[bool, typer.Option("--view", help="Serve the rerun web viewer on 127.0.0.1 and show the replay.")] = False,
    connect: Annotated[str | None, typer.Option("--connect", help="Show it in a running rerun viewer (gRPC url).")] = None,
    confirm: Annotated[bool, typer.Option(help="Confirm the IR events (WBEMD + slow flow) in the background.")] = True,
) -> None:
    """Feed a log through the live fan-out (block boundaries and sample indices kept), with the near-live analysis."""
    import threading

    from daq.fanout import END, FanOut
    from daq.log.reader import LogReadError
    from daq.replay import Replayer

    fan = FanOut()
    sub = fan.subscribe("summary", maxsize=1024)
    counted = {"blocks": 0}

    def consume() -> None:
        while sub.get() is not END:
            counted["blocks"] += 1

    try:
        rep = Replayer(log, fan, speed=speed or None)
    except LogReadError as exc:
        fail(str(exc))
    vtarget, vlane = _replay_view(rep, fan, rig, view, connect, recorded_topics(analysis and confirm))
    clane_box: list = []
    lane = _replay_lane(rep, fan, rig, vlane, clane_box) if analysis else None
    if lane is not None and confirm:
        from daq.confirm_lane import start_confirm_lane

        vsink = vlane.sink() if vlane is not None else (lambda *_: None)
        clane_box.append(start_confirm_lane(fan, lane, vsink, log_path=str(log)))
    t = threading.Thread(target=consume, daemon=True)
    t.start()
    try:
        stats = rep.run()
    except KeyboardInterrupt:
        rep.stop()
        raise
    t.join()
    if lane is not None:
        from daq.analyze_cmd import events_table

        lane_events = [e.as_dict() for e in lane.join()]
        out.print(events_table(lane_events, f"internal-resonance events (analysis of {lane.stream})"))
        if lane.sub.dropped_blocks:
            out.print(f"analysis fell behind: skipped {lane.sub.dropped_samples} samples (restarted after each gap)",
                      markup=False)  # fmt: skip
    if clane_box:
        from daq.confirm_cmd import ConfirmRun, companion_path, confirmations_table, write_companion

        records = clane_box[0].join(timeout=60)
        out.print(confirmations_table(records, f"confirmations (WBEMD + slow flow, {lane.stream})"))
        if records:
            dest = write_companion(ConfirmRun(str(log), lane.stream, "replay", "replay", records), companion_path(log))
            out.print(f"wrote {len(records)} confirmation records to {dest}", markup=False)
    if vlane is not None:
        vlane.join()
    if vtarget is not None:
        from daq.view.cli_glue import close_live_view

        close_live_view(out, vtarget, vlane)
    health = "" if rep.reader.report.complete else f" (damaged log: {rep.reader.report.messages} messages salvaged)"
    if stats.bad_blocks:
        err.print(f"skipped {len(stats.bad_blocks)} undecodable sample block(s), replayed as gaps; first: {stats.bad_blocks[0]}",
                  markup=False)  # fmt: skip
    for stream, n in stats.samples.items():
        gaps = stats.gaps.get(stream, [])
        out.print(
            f"replayed {stream}: {n} samples, {len(gaps)} gaps ({sum(b - a for a, b in gaps)} samples missing)", markup=False
        )
    out.print(
        f"{stats.blocks} blocks, {stats.log_seconds:.3f} s of data in {stats.wall_seconds:.3f} s wall; subscriber received "
        f"{counted['blocks']}, dropped {sub.dropped_blocks}{health}",
        markup=False,
    )
    if stats.error:
        fail(f"replay stopped early: {stats.error}; 'gvt log recover {log} fixed.mcap' rewrites what is readable")


def recorded_topics(confirming: bool) -> tuple[str, ...]:
    """The log's own results a replay view shows as recorded: hits and driver events always (a replay does not
    detect them again); the recorded confirmations only when the replay does not confirm its events anew —
    otherwise each would be drawn twice."""
    return ("/daq/hits", "/daq/events") + (() if confirming else ("/analysis/confirmations",))


def _replay_view(rep, fan, rig_arg: str | None, view: bool, connect: str | None, topics: tuple[str, ...] = ()):
    """The live view of a replay (``--view`` / ``--connect``): target and lane, or (None, None); the log's
    ``topics`` are offered to it as recorded."""
    if not view and not connect:
        return None, None
    from daq.analyze import AnalyzeError, rig_from_log
    from daq.view.cli_glue import open_live_view
    from daq.view.lane import ViewError, start_view_lane

    try:
        target = open_live_view(out, view, connect)
    except ViewError as exc:
        fail(str(exc))
    infos = rep.reader.streams()
    try:
        r = open_rig(rig_arg) if rig_arg is not None else rig_from_log(rep.reader)
    except AnalyzeError:
        r = None
    fs = next(iter(infos.values())).sample_rate if infos else 1.0
    vlane = start_view_lane(fan, r, {n: tuple(i.channels) for n, i in infos.items()}, fs, target)
    for topic in topics:  # recorded results: shown as they are
        for obj in rep.reader.json_messages(topic):
            vlane.offer(topic, obj)
    return target, vlane


def _replay_lane(rep, fan, rig_arg: str | None, vlane=None, confirm_box: list | None = None):
    """The analysis lane for a replay (None, with a note, when the log cannot be analysed); its IR events also
    go to the confirmation lane in ``confirm_box`` once there is one."""
    from daq.analysis_lane import LaneUnavailable, start_analysis_lane
    from daq.analyze import AnalyzeError, rig_from_log

    infos = rep.reader.streams()
    streams = {n: tuple(i.channels) for n, i in infos.items()}
    try:
        r = open_rig(rig_arg) if rig_arg is not None else rig_from_log(rep.reader)
        # every stream of a session shares one sample rate (daq/session.py refuses mixed rates)
        fs = next(iter(infos.values())).sample_rate
        vsink = vlane.sink() if vlane is not None else (lambda *_: None)

        def sink(topic: str, obj: dict, t_ns: int | None) -> None:
            vsink(topic, obj, t_ns)
            if topic == "/analysis/events" and confirm_box:
                confirm_box[0].offer(obj)

        return start_analysis_lane(fan, r, streams, fs, sink, maxsize=4096)
    except (AnalyzeError, LaneUnavailable, StopIteration) as exc:
        err.print(f"gvt: note: no analysis: {exc or 'the log has no sample streams'}", markup=False, soft_wrap=True)
        return None
