"""The ``gvt`` command line (typer). Each verb is a thin shell over library functions.

Errors a user can fix (a bad config, a bad path) print one line and exit 2; anything unexpected prints
one line and exits 1 (``GVT_DEBUG=1`` shows the traceback).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from daq.config.loader import ConfigError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="gvtlink: ground-vibration-test data acquisition and nonlinear modal analysis.",
)
model_app = typer.Typer(no_args_is_help=True, help="Structural model of a rig: modes, limits.")
app.add_typer(model_app, name="model")
from daq.log_cli import log_app  # noqa: E402 - after app exists, keeps `gvt --help` listing in order

app.add_typer(log_app, name="log")
from daq.device_cli import device_app  # noqa: E402

app.add_typer(device_app, name="device")

out = Console(highlight=False)
err = Console(stderr=True, highlight=False)

RigArg = Annotated[str, typer.Argument(help="Rig TOML file, or the name of a rig in configs/rigs (e.g. beam_ch4_exp).")]


def fail(message: str, code: int = 2) -> None:
    err.print(f"gvt: error: {message}", markup=False, soft_wrap=True)
    raise typer.Exit(code)


@model_app.command("modes")
def model_modes(
    rig: RigArg,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    limit: Annotated[str, typer.Option(help="low: the linear structure; high: nonlinear springs pinned (seed L1244).")] = "low",
    count: Annotated[int, typer.Option(min=1, help="How many modes to list.")] = 10,
) -> None:
    """List the rig's natural frequencies (FE, and Guyan-reduced to the sensor DOFs)."""
    from daq.modes_report import modes_report, print_modes

    if limit not in ("low", "high"):
        fail(f"--limit must be 'low' or 'high', got {limit!r}")
    r = _open(rig)
    report = modes_report(r, limit=limit, count=count)
    if json_out:
        out.print_json(json.dumps(report))
    else:
        print_modes(out, report)


@app.command()
def simulate(
    rig: RigArg,
    force: Annotated[
        float | None, typer.Option(min=0.0, help="Peak hammer force, N (one hit; default: the rig's nominal).")
    ] = None,
    duration: Annotated[
        float | None, typer.Option(min=1e-6, help="Seconds to simulate (one hit; default: record length).")
    ] = None,
    out_path: Annotated[Path, typer.Option("--out", help="Output file: .mcap for a session log, .npz for one hit.")] = Path(
        "session.mcap"
    ),
    hits: Annotated[int, typer.Option(min=1, max=1000, help="Hits in a session (.mcap): rising force to the nominal.")] = 1,
    forces: Annotated[str | None, typer.Option(help="Comma-separated peak forces, N, one per hit (overrides --hits).")] = None,
    spacing: Annotated[float | None, typer.Option(min=0.01, help="Seconds between hits (default: record length).")] = None,
    seed: Annotated[int | None, typer.Option(help="Noise seed (default: the rig's).")] = None,
) -> None:
    """Simulate hammer hits: a session log (.mcap) with ground truth, or one hit as .npz."""
    r = _open(rig)
    if out_path.parent and not out_path.parent.exists():
        fail(f"--out {out_path}: directory {out_path.parent} does not exist")
    if out_path.suffix == ".npz":
        from daq.simulate_cmd import simulate_to_npz

        out.print(simulate_to_npz(r, out_path, force=force, duration=duration, seed=seed))
        return
    if out_path.suffix != ".mcap":
        fail(f"--out {out_path}: use .mcap (session log) or .npz (one hit)")
    from daq.sim_session import SessionPlan, default_forces, simulate_session

    if forces:
        try:
            peaks = tuple(float(x) for x in forces.split(",") if x.strip())
        except ValueError:
            fail(f"--forces {forces!r}: expected comma-separated numbers, e.g. 30,1583")
        if not peaks or min(peaks) < 0:
            fail("--forces: give at least one non-negative force")
    elif force is not None:
        peaks = (force,) * hits
    else:
        peaks = default_forces(r, hits)
    rec = r.config.daq.record_length
    plan = SessionPlan(forces=peaks, pre_trigger=0.1, spacing=spacing or rec, tail=duration or rec, block_size=1024)
    with _progress(out) as report:
        summary = simulate_session(r, out_path, plan, seed=seed, progress=report)
    clip = ", ".join(f"{k}: {v}" for k, v in summary["clipped"].items()) or "none"
    out.print(
        f"wrote {out_path}: {summary['hits']} hits, {summary['samples']} samples x {summary['channels']} channels "
        f"({summary['duration_s']:.2f} s); input energies {', '.join(f'{x:.3g}' for x in summary['energies_J'])} J; "
        f"clipped: {clip}",
        markup=False,
    )


@app.command()
def sweep(
    rig: RigArg,
    pmin: Annotated[float, typer.Option(help="Smallest peak force P, N (seed: 10).")] = 1e1,
    pmax: Annotated[float, typer.Option(help="Largest peak force P, N (seed: 1e12).")] = 1e12,
    n: Annotated[int, typer.Option(help="Runs, P = logspace(pmin, pmax, n) (seed: 1000).")] = 200,
    duration: Annotated[float, typer.Option(help="Seconds per run (seed: 1).")] = 1.0,
    outputs: Annotated[str, typer.Option(help="translational: every transverse DOF; sensors: the sensor DOFs.")] = (
        "translational"
    ),
    order: Annotated[int | None, typer.Option(help="Integrator order 2 or 4 (default: the rig's).")] = None,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address (default: a local cluster).")] = None,
    workers: Annotated[int, typer.Option(help="Workers of the local cluster.")] = 2,
    out_dir: Annotated[Path, typer.Option("--out", help="Directory for rqfep.csv, rqfep.png, sweep.json.")] = Path("sweep"),
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON summary instead of tables.")] = False,
) -> None:
    """The seed's computational study: a force sweep, POD + RQ per run, the RQ-FEP and flagged interactions."""
    from daq.sweep_cmd import SweepSpec, print_report, run_sweep, summary_json, write_outputs

    spec = SweepSpec(
        pmin=pmin, pmax=pmax, n=n, duration=duration, outputs=outputs, order=order, scheduler=scheduler, workers=workers
    )
    try:
        spec.validate()
    except ValueError as exc:
        fail(str(exc))
    if out_dir.exists() and not out_dir.is_dir():
        fail(f"--out {out_dir}: exists and is not a directory")
    r = _open(rig)
    try:
        with _progress(err if json_out else out) as report:
            rep = run_sweep(r, spec, progress=report)
    except ValueError as exc:
        fail(str(exc))
    paths = write_outputs(rep, out_dir)
    if json_out:
        out.print_json(summary_json(rep))
    else:
        print_report(out, rep, paths)


class _progress:
    """Rich progress bar on a terminal, plain lines otherwise (architecture.md, CLI verbs)."""

    def __init__(self, console: Console) -> None:
        self.console = console
        self.last = ("", -1.0)

    def __enter__(self):
        if self.console.is_terminal:
            from rich.progress import Progress

            self.bar = Progress(console=self.console, transient=True)
            self.bar.start()
            self.task = self.bar.add_task("simulating", total=1.0)
        else:
            self.bar = None
        return self.report

    def report(self, stage: str, fraction: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, description=stage, completed=fraction)
        elif stage != self.last[0] or fraction - self.last[1] >= 0.25 or fraction >= 1.0 > self.last[1]:
            self.console.print(f"{stage}: {100 * fraction:.0f} %", markup=False)
            self.last = (stage, fraction)

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()


@app.command()
def demo(
    rig: RigArg = "beam_ch4_exp",
    duration: Annotated[float | None, typer.Option(min=0.1, help="Seconds per hit (default: the rig's record length).")] = None,
    session_out: Annotated[Path, typer.Option("--out", help="Where the demo session log goes.")] = Path("demo_session.mcap"),
) -> None:
    """The experimental beam rig: modes, a strong and a weak hit, then a recorded session over a real pty."""
    from daq.demo import run_demo

    run_demo(out, _open(rig), duration=duration, session_out=str(session_out))


@app.command()
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
        r = _open(rig_arg) if rig_arg is not None else rig_from_log(rep.reader)
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
        r = _open(rig_arg) if rig_arg is not None else rig_from_log(rep.reader)
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


@app.command()
def analyze(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    stream: Annotated[str | None, typer.Option(help="Stream to analyse (default: the one with all the rig's sensors).")] = None,
    window: Annotated[float | None, typer.Option(min=0.0, help="Window length, s (default: 0.45 / f1 of the rig).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON (summary, events, warnings).")] = False,
    windows_out: Annotated[bool, typer.Option("--windows", help="With --json: also every window's RQ and modal result.")] = False,
    rrd: Annotated[Path | None, typer.Option("--rrd", help="Also write a rerun recording (.rrd).")] = None,
) -> None:
    """Near-live detection in batch over a log: RQ curves, window-robust spikes and IR events (same kernels as live)."""
    from analysis.operator import AnalysisSettings
    from daq.analyze import AnalyzeError, analyze_log
    from daq.analyze_cmd import print_json, print_report

    r = _open(rig) if rig is not None else None
    if window is not None and window <= 0:
        fail("--window must be > 0 s")
    try:
        with _progress(err if json_out else out) as report:
            run = analyze_log(log, r, stream, AnalysisSettings(window_s=window), progress=lambda f: report("analysing", f))
    except AnalyzeError as exc:
        fail(str(exc))
    if run.bad_blocks:
        err.print(f"skipped {len(run.bad_blocks)} undecodable sample block(s), analysed as gaps; first: {run.bad_blocks[0]}",
                  markup=False)  # fmt: skip
    if rrd is not None:
        from daq.view.build import build_rrd

        summary = build_rrd(log, rrd, rig=r, results=run.results)
        (err if json_out else out).print(f"wrote {rrd} ({summary.blocks} blocks); open it: {_rerun_hint()} {rrd}", markup=False)
    if json_out:
        print_json(out, run, full=windows_out)
    else:
        print_report(out, run)


@app.command()
def confirm(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    event: Annotated[int | None, typer.Option("--event", help="Only the IR event with this id (see gvt analyze).")] = None,
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    out_path: Annotated[Path | None, typer.Option("--out", help="Where the results go (default: LOG.confirm.mcap).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the confirmation records as JSON.")] = False,
) -> None:
    """Confirm IR events with WBEMD + slow-flow phase analysis (seed Ch. 3); results to a companion log."""
    import json

    from daq.analyze import AnalyzeError
    from daq.confirm_cmd import companion_path, confirm_log, confirmations_table, write_companion

    r = _open(rig) if rig is not None else None
    console = err if json_out else out
    try:
        with _progress(console) as report:
            run = confirm_log(log, r, event, progress=lambda f: report("confirming", f))
    except AnalyzeError as exc:
        fail(str(exc))
    dest = write_companion(run, out_path or companion_path(log))
    if json_out:
        slim = [{k: v for k, v in rec.items() if k != "trajectory"} for rec in run.records]
        out.print_json(json.dumps({"log": str(log), "stream": run.stream, "events_from": run.events_from, "out": str(dest),
                                   "seconds": run.wall_seconds, "confirmations": slim}, default=float))  # fmt: skip
    else:
        out.print(confirmations_table(run.records, f"confirmations ({run.stream}, events from the {run.events_from})"))
    console.print(f"wrote {len(run.records)} confirmation records to {dest} in {run.wall_seconds:.1f} s", markup=False)


@app.command()
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

    from daq.config.loader import load_config
    from daq.config.session import SessionConfig
    from daq.session import run_session

    cfg = load_config(SessionConfig, session)
    if duration is not None:
        cfg = cfg.model_copy(update={"duration": duration})
    r = _open(cfg.rig)
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


@app.command()
def report(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    out_path: Annotated[Path, typer.Option("--out", help="Output HTML file (self-contained).")] = Path("report.html"),
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
) -> None:
    """A static HTML report of a session: plots and tables of hits, verdicts, loss, RQ-FEP, IR events, confirmations."""
    from daq.log.reader import LogReadError
    from daq.report import build_report

    if out_path.parent and not out_path.parent.exists():
        fail(f"--out {out_path}: directory {out_path.parent} does not exist")
    try:
        s = build_report(log, out_path, rig=_open(rig) if rig is not None else None)
    except LogReadError as exc:
        fail(str(exc))
    out.print(f"wrote {out_path}: {len(s.figures)} plots, {len(s.tables)} tables (analysis results from {s.results_from})",
              markup=False)  # fmt: skip


def _rerun_hint() -> str:
    exe = Path(sys.executable).parent / "rerun"
    return str(exe) if exe.exists() else "rerun"


def _open(rig: str):
    from daq.rigs import open_rig

    try:
        return open_rig(rig)
    except ConfigError as exc:
        fail(str(exc))


def _click_exceptions():
    """The click exception module typer is using (typer >= 0.2x vendors its own copy of click)."""
    try:
        from typer._click import exceptions
    except ImportError:  # older typer: plain click
        from click import exceptions
    return exceptions


def main() -> None:
    cx = _click_exceptions()
    try:
        code = app(standalone_mode=False)
        sys.exit(code if isinstance(code, int) else 0)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except cx.UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # the help text has been printed already
            sys.exit(2)
        cmd = exc.ctx.command_path if exc.ctx is not None else "gvt"
        err.print(f"gvt: error: {exc.format_message()} (see '{cmd} --help')", markup=False, soft_wrap=True)
        sys.exit(2)
    except typer.Abort:
        err.print("gvt: aborted", markup=False)
        sys.exit(130)
    except ConfigError as exc:
        err.print(f"gvt: error: {exc}", markup=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        err.print("gvt: interrupted", markup=False)
        sys.exit(130)
    except Exception as exc:  # never a traceback to a user
        if os.environ.get("GVT_DEBUG"):
            raise
        err.print(
            f"gvt: internal error: {type(exc).__name__}: {exc} (set GVT_DEBUG=1 for the traceback)", markup=False, soft_wrap=True
        )
        sys.exit(1)


if __name__ == "__main__":
    main()
