"""A replay (``gvt replay``): a recorded log as the source of the same recorder and lanes a live session uses.

The parts differ from :mod:`daq.session` only where a replay differs: the source is the log
(:class:`ReplaySource`, paced or at full speed), there is no log lane (the session log is read, never
written; confirmations go to a companion ``LOG.confirm.mcap``, docs/decisions.md D22), and no hit gate
(the log's own hits and driver events are shown as recorded). Analysis, confirmation (reading each event's
samples from the log: no ring, nothing skipped) and the view are the live session's lanes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daq.fanout import END, FanOut
from daq.lanes import Lane, Results
from daq.lanes.confirm import DrainingConfirmLane
from daq.log import layout
from daq.recorder import Outcome, Recorder
from daq.replay import Replayer, ReplayStats
from daq.sources import SourceReport


class ReplaySource:
    """The log's blocks on the fan-out, on a thread of their own; ends when the log does (or cannot be read on)."""

    def __init__(self, replayer: Replayer) -> None:
        self.rep = replayer
        self.name = "replay"
        self.need = None
        self.report = SourceReport("replay")
        self.done = threading.Event()
        self.stats: ReplayStats | None = None
        self._thread: threading.Thread | None = None

    def open(self) -> None:
        pass

    def start(self) -> None:
        self._thread = threading.Thread(target=self._main, name="replay", daemon=True)
        self._thread.start()

    def _main(self) -> None:
        try:
            self.stats = self.rep.run(close=False)
            self.report.samples = sum(self.stats.samples.values())
            self.report.error = self.stats.error
            self.report.reached_end = self.stats.error is None
        finally:
            self.done.set()

    def stop(self) -> None:
        self.rep.stop()

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def drain_events(self) -> None:
        pass

    def failure(self) -> tuple[str, int] | None:
        if self.report.error is None:
            return None
        path = self.rep.reader.path
        return f"replay stopped early: {self.report.error}; 'gvt log recover {path} fixed.mcap' rewrites what is readable", 2


class _Counter:
    """A fan-out subscriber that only counts what it receives (the replay's own check that blocks flow)."""

    name = "count"

    def __init__(self, fan: FanOut) -> None:
        self.sub = fan.subscribe("summary", maxsize=1024)
        self.blocks = 0
        self._thread = threading.Thread(target=self._main, name="replay-count", daemon=True)
        self._thread.start()

    def _main(self) -> None:
        while self.sub.get() is not END:
            self.blocks += 1

    def offer(self, topic: str, obj: dict) -> None:
        pass

    def finish(self, deadline: float) -> None:
        import time

        self._thread.join(max(0.0, deadline - time.monotonic()))


def recorded_topics(confirming: bool) -> tuple[str, ...]:
    """The log's own results a replay view shows as recorded: hits and driver events always (a replay does not
    detect them again); the recorded confirmations only when the replay does not confirm its events anew —
    otherwise each would be drawn twice."""
    return (layout.HITS_TOPIC, layout.EVENTS_TOPIC) + (() if confirming else (layout.CONFIRMATIONS_TOPIC,))


@dataclass
class ReplayResult:
    outcome: Outcome
    stats: ReplayStats
    counted_blocks: int = 0
    dropped_blocks: int = 0
    stream: str | None = None  # the analysed stream
    events: list[dict] = field(default_factory=list)
    analysis_dropped_samples: int = 0
    confirmations: list[dict] | None = None  # None: the replay did not confirm
    view_lane: Any = None
    complete_log: bool = True
    salvaged_messages: int = 0
    frf: list[dict] | None = None  # the live FRF lane's records (None: no lane: --no-frf, or no hammer and sensors)
    frf_cpu_s: list[float] = field(default_factory=list)  # the FRF lane thread's CPU time per hit (its cost, whatever the load)


def run_replay(log: Path, *, speed: float | None, rig: Any = None, analysis: bool = True, confirm: bool = True,
               view: Any = None, note: Callable[[str], None] | None = None, stop: threading.Event | None = None,
               drain_progress: Callable[[int, int], None] | None = None, frf: bool = True,
               frf_line: Callable[[str], None] | None = None) -> ReplayResult:  # fmt: skip
    """Replay ``log``: the same recorder and lanes as a live session (module docstring). ``rig``: a Rig, or None
    for the one attached to the log; ``note``: where a one-line note goes when the log cannot be analysed."""
    fan = FanOut()
    rep = Replayer(log, fan, speed=speed)
    results = Results()
    counter = _Counter(fan)
    lanes: list[Lane] = []
    infos = rep.reader.streams()
    streams = {n: tuple(i.channels) for n, i in infos.items()}
    fs = next(iter(infos.values())).sample_rate if infos else 1.0
    the_rig, why_no_rig = _rig(rep, rig)
    vlane = None
    if view is not None:
        from daq.lanes.view import start_view_lane

        vlane = start_view_lane(fan, the_rig, streams, fs, view)
        results.route(vlane)
        for topic in recorded_topics(analysis and confirm):  # recorded results: shown as they are
            for obj in rep.reader.json_messages(topic):
                vlane.offer(topic, obj)
    flane = _frf(fan, the_rig, streams, fs, results, vlane, frf_line, rep) if frf and the_rig is not None else None
    alane = _analysis(fan, the_rig, why_no_rig, streams, fs, results, note) if analysis else None
    clane = None
    if alane is not None and confirm:
        from daq.lanes.confirm import start_confirm_lane

        clane = start_confirm_lane(fan, alane, results.emit, log_path=str(log))
        results.route(clane, [layout.IR_EVENTS_TOPIC])
    draining = DrainingConfirmLane(clane, drain_progress) if clane is not None else None
    lanes += [lane for lane in (flane, alane, draining, vlane, counter) if lane is not None]
    source = ReplaySource(rep)
    outcome = Recorder(fan=fan, results=results, sources=[source], lanes=lanes, stop=stop).run()
    return ReplayResult(
        outcome=outcome, stats=source.stats or ReplayStats(), counted_blocks=counter.blocks,
        dropped_blocks=counter.sub.dropped_blocks, stream=alane.stream if alane is not None else None,
        events=[e.as_dict() for e in alane.op.events] if alane is not None else [],
        analysis_dropped_samples=alane.sub.dropped_samples if alane is not None else 0,
        confirmations=list(clane.results) if clane is not None else None, view_lane=vlane,
        complete_log=rep.reader.report.complete, salvaged_messages=rep.reader.report.messages,
        frf=[r.to_json() for r in flane.records] if flane is not None else None,
        frf_cpu_s=list(flane.cpu_costs_s) if flane is not None else [],
    )  # fmt: skip


def _rig(rep: Replayer, rig: Any) -> tuple[Any, str]:
    """The rig given, else the one attached to the log; (None, why) when there is none."""
    if rig is not None:
        return rig, ""
    from daq.log.rig import AnalyzeError, rig_from_log

    try:
        return rig_from_log(rep.reader), ""
    except AnalyzeError as exc:
        return None, str(exc)


def _frf(fan: FanOut, rig: Any, streams: dict, fs: float, results: Results, vlane: Any, say: Callable[[str], None] | None,
         rep: Replayer):  # fmt: skip
    """The live FRF lane on the log's own hits (all offered now: the lane waits for each record's samples)."""
    from daq.lanes.frf import start_frf_lane

    lane = start_frf_lane(fan, rig, streams, fs, results.emit, say=say, view=vlane.offer if vlane is not None else None,
                          maxsize=4096)  # fmt: skip
    if lane is not None:
        for obj in rep.reader.json_messages(layout.HITS_TOPIC):
            lane.offer(layout.HITS_TOPIC, obj)
    return lane


def _analysis(fan: FanOut, rig: Any, why_no_rig: str, streams: dict, fs: float, results: Results,
              note: Callable[[str], None] | None):  # fmt: skip
    """The analysis lane for a replay (None, with a note, when the log cannot be analysed)."""
    from daq.lanes.analysis import LaneUnavailable, start_analysis_lane

    if rig is None or not streams:
        if note is not None:
            note("no analysis: " + ("the log has no sample streams" if not streams else why_no_rig))
        return None
    try:
        return start_analysis_lane(fan, rig, streams, fs, results.emit, maxsize=4096)
    except LaneUnavailable as exc:
        if note is not None:
            note(f"no analysis: {exc}")
        return None
