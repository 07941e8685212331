"""The Recorder: sources of sample blocks, one fan-out, lanes, and the order in which it all stops.

``gvt record`` and ``gvt replay`` are the same machine with different parts (:mod:`daq.session` and
:mod:`daq.replay_session` assemble them):

* **sources** (:mod:`daq.sources`) put blocks on the fan-out — devices (recording to the log lane first),
  or a log being replayed;
* **lanes** (:mod:`daq.lanes`) read their own fan-out subscriptions and get results by topic through the
  :class:`~daq.lanes.Results` router: hit gate, near-live analysis, confirmation, live view;
* the **log lane** owns the file; it is finished last, so every lane's final records are in it.

Who owns what (docs/session.md): the recorder owns the sources, the lanes and the fan-out; each source
owns its driver (and so the driver's thread); each lane owns its threads, the confirmation lane its
worker process; the log lane owns the writer thread and the file lock. The stop order is fixed:

1. sources stop reading and close their links (no block can enter after this); a device that holds samples it
   has not sent yet (a Modbus FIFO) delivers them first, within its driver's bound (``stop_drain_s``);
2. the fan-out closes (every subscriber gets END);
3. lanes finish in the order given (hit gate, live FRFs, analysis, confirmation, view): each one's last
   results may feed the next (the gate's last hits reach the FRF lane, the analysis' last IR events the
   confirmation lane before it drains);
4. the log lane finalises the file.

A session ends only for a reason it states (:class:`Outcome`): the duration reached in data time, a
stop request (Ctrl-C, SIGTERM), a source that ended or failed, the wall-clock deadline (duration +
grace) with data missing, or a writer failure.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from daq.fanout import FanOut
from daq.lanes import Lane, Results
from daq.lanes.log import LogLane
from daq.log import layout
from daq.sources import Source

#: seconds a lane may take to finish after the source ended, by lane name (the confirmation lane has its own)
#: (a replay's confirmations have no deadline)
FINISH_S = {"hits": 30.0, "frf": 30.0, "analysis": 60.0, "view": 12.0, "confirm": 3600.0}
#: ... and after a stop request (Ctrl-C, SIGTERM): the confirmations get 15 s, not an hour. A stop asks for the file
#: now; a service manager sends SIGKILL after its own timeout (systemd's default: 90 s), and on a busy host the
#: confirmation worker at nice +10 held ``gvt record`` 124 s after SIGTERM (6 CPU hogs, one IR event). What is left
#: is recorded as abandoned, and ``gvt confirm LOG`` confirms it from the log afterwards. A stop that arrives while a
#: session that ran to its duration is draining cuts what is left of that drain to the same (a lane's ``cut``).
STOPPED_FINISH_S = {"confirm": 15.0}


@dataclass
class Outcome:
    """Why the recording ended, the one line for the user, and the exit code (0, 1 failure, 3 data lost)."""

    reason: str  # duration | stopped | source_ended | source_failed | deadline | writer_failed
    message: str | None
    exit_code: int
    seconds: float


#: a wait of the recorder's main loop (50 ms) that ended this much later was the host's doing: a ``host_stall`` event
STALL_S = 1.0
#: ... and a stall this long is also one line on the console (as long as the default silence threshold: a stall that
#: short explains no silence, and a loaded host's second is the log's business, not the user's)
STALL_LINE_S = 2.0


@dataclass(frozen=True)
class Stall:
    """A span in which the recording process's main thread did not run: ``at_s`` (session time, s) for ``seconds``;
    ``cpu_s`` the process's CPU time meanwhile (None: not measured), which tells the two causes apart."""

    at_s: float
    seconds: float
    cpu_s: float | None = None

    @property
    def cause(self) -> str:
        if self.cpu_s is None:
            return "the host overloaded or suspended, the process stopped, or a thread holding the interpreter"
        if self.cpu_s < 0.05 * self.seconds + 0.05:
            return (f"it used {self.cpu_s:.2f} s of CPU meanwhile: the host did not run it (overloaded or suspended) or "
                    "it was stopped")
        return f"it used {self.cpu_s:.1f} s of CPU meanwhile: a thread of its own held the interpreter"

    def message(self) -> str:
        return (f"host: this process did not run for {self.seconds:.1f} s from {self.at_s:.1f} s into the session "
                f"({self.cause}): a silence or loss in that span is the host's, not the device's")  # fmt: skip


class StallWatch:
    """Spans in which the process was not scheduled, from the lateness of a timed wait (sans-IO: times in, stalls out).

    Why: when a host freezes the whole recording process (a VM paused, SIGSTOP, swap, a C call holding the GIL), the
    device keeps sampling, its buffer overflows and the log shows a silence and a loss that look like the link's fault
    (make test beside 4 hogs: a 64.6 s silence of an in-process Modbus device with no timeout or reconnect, whose cause
    the log could not tell). The recorder's main loop waits 50 ms at a time; a tick that comes more than ``threshold_s``
    after the last one plus its wait means no thread of the process ran the loop, so the span is named, which a quiet
    link alone cannot explain."""

    def __init__(self, threshold_s: float = STALL_S) -> None:
        self.threshold_s = float(threshold_s)
        self.stalls: list[Stall] = []

    def feed(self, started_s: float, asked_s: float, ended_s: float, cpu_s: float | None = None) -> Stall | None:
        """One wait: begun at ``started_s`` for ``asked_s``, returned at ``ended_s`` (session time, s); ``cpu_s`` the
        process's CPU seconds over it."""
        late = ended_s - started_s - asked_s
        if late <= self.threshold_s:
            return None
        stall = Stall(started_s + asked_s, late, cpu_s)
        self.stalls.append(stall)
        return stall


class Recorder:
    def __init__(
        self, *, fan: FanOut, results: Results, sources: Sequence[Source], lanes: Sequence[Lane],
        log: LogLane | None = None, stop: threading.Event | None = None, duration_s: float | None = None,
        end_grace_s: float = 10.0, start_servers: Callable[[], None] | None = None,
        stopped_finish_s: dict[str, float] | None = None, say: Callable[[str], None] | None = None,
    ) -> None:  # fmt: skip
        self.fan = fan
        self.results = results
        self.sources = list(sources)
        self.lanes = list(lanes)
        self.log = log
        self.stop = stop or threading.Event()
        self.duration_s = duration_s
        self.end_grace_s = end_grace_s
        self.start_servers = start_servers  # simulated devices hold their clocks until the links are open
        self.stopped_finish_s = {**STOPPED_FINISH_S, **(stopped_finish_s or {})}  # a session's [analysis] confirm_stop_s
        self.t0 = time.monotonic()
        self.say = say  # one-line notices (a long host stall); None: the log only
        self.stalls = StallWatch()

    # --- running --------------------------------------------------------------------------------------
    def run(self, status: Callable[[float], None] | None = None, status_every_s: float = 1.0) -> Outcome:
        """Open every source, record until a reason to end, then stop everything in order."""
        try:
            for s in self.sources:
                s.open()
        except Exception:
            self.shutdown()
            raise
        if self.start_servers is not None:
            self.start_servers()
        self.t0 = time.monotonic()
        for s in self.sources:
            s.start()
        outcome = self._wait(status, status_every_s)
        self.shutdown()
        outcome.seconds = time.monotonic() - self.t0
        return self._after_finish(outcome)

    def _wait(self, status: Callable[[float], None] | None, every: float) -> Outcome:
        deadline = None if self.duration_s is None else self.t0 + self.duration_s + self.end_grace_s
        last_status = self.t0
        # a stall is timed from one tick to the next, not over the wait alone: a host that stops the process just
        # after a status line (the reader of that line woken, the writer preempted) stopped it outside the wait
        tick, cpu = time.monotonic(), time.process_time()
        while True:
            stopped = self.stop.wait(0.05)
            now, cpu_now = time.monotonic(), time.process_time()
            self._stalled(tick, now, cpu_now - cpu)  # a stall that a stop request ended is one too
            tick, cpu = now, cpu_now
            if stopped:
                return Outcome("stopped", None, 0, 0.0)
            if self.log is not None and self.log.failure is not None:
                return Outcome("writer_failed", f"the log writer failed: {self.log.failure}", self.log.failure_exit_code, 0.0)
            failed = [f for s in self.sources if s.done.is_set() and (f := s.failure()) is not None]
            if failed:
                return Outcome("source_failed", "; ".join(m for m, _ in failed), max(c for _, c in failed), 0.0)
            if self.sources and all(s.done.is_set() for s in self.sources):
                if all(s.report.reached_end for s in self.sources):
                    return Outcome("duration", None, 0, 0.0)
                if self.duration_s is not None:
                    return Outcome("source_ended", self._short_message("the device stopped delivering data"), 3, 0.0)
                return Outcome("source_ended", None, 0, 0.0)
            if deadline is not None and now >= deadline:
                why = f"no more data within {self.end_grace_s:g} s (wall clock) after the duration"
                return Outcome("deadline", self._short_message(why), 3, 0.0)
            if status is not None and now - last_status >= every:
                status(now - self.t0)
                last_status = now

    def _stalled(self, begun: float, now: float, cpu_s: float) -> None:
        stall = self.stalls.feed(begun - self.t0, 0.05, now - self.t0, cpu_s)
        if stall is None:
            return
        ev = {"kind": "host_stall", "at_s": round(stall.at_s, 3), "seconds": round(stall.seconds, 3),
              "cpu_s": round(cpu_s, 3), "message": stall.message()}  # fmt: skip
        self.results.emit(layout.EVENTS_TOPIC, ev, None)
        if self.say is not None and stall.seconds >= STALL_LINE_S:
            self.say(stall.message())

    def _short_message(self, why: str) -> str:
        parts = [f"{s.name} recorded {s.report.samples} of {s.need} samples" for s in self.sources if not s.report.reached_end]
        return f"{why}: {'; '.join(parts)}" if parts else why

    # --- stopping -------------------------------------------------------------------------------------
    def shutdown(self) -> None:
        """Stop in the documented order (module docstring)."""
        for s in self.sources:
            s.stop()
        for s in self.sources:
            s.join(10.0)
            s.drain_events()
        self.fan.close()
        watch = None if self.stop.is_set() else _StopDuringFinish(self.stop, self.lanes, self.stopped_finish_s)
        try:
            for lane in self.lanes:
                limits = {**FINISH_S, **self.stopped_finish_s} if self.stop.is_set() else FINISH_S
                lane.finish(time.monotonic() + limits.get(lane.name, 60.0))
        finally:
            if watch is not None:
                watch.close()

    def _after_finish(self, outcome: Outcome) -> Outcome:
        """Say in the log why the session ended, then finalise the file."""
        if outcome.reason in ("deadline", "source_ended") and outcome.message:
            self.results.emit(layout.EVENTS_TOPIC, {"kind": "duration_not_reached", "message": outcome.message}, None)
        if self.log is not None:
            self.log.finish(time.monotonic() + 30.0)
            if outcome.exit_code == 0 and self.log.failure is not None:
                outcome = Outcome("writer_failed", f"the log writer failed: {self.log.failure}", self.log.failure_exit_code,
                                  outcome.seconds)  # fmt: skip
        return outcome


class _StopDuringFinish:
    """While the lanes finish after a session that was not stopped (its duration reached, a device ended): a stop
    request (Ctrl-C, SIGTERM) then cuts each lane that can be cut (``lane.cut(deadline)``: the confirmation drain,
    an hour or its own 120 s) to ``stopped_finish_s`` from the request, as a stop before the end would have; the
    lane records what it abandons. Ctrl-C during a drain had waited the drain out (issue 30)."""

    def __init__(self, stop: threading.Event, lanes: Sequence[Lane], limits: dict[str, float]) -> None:
        self.stop, self.lanes, self.limits = stop, lanes, limits
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stop-during-finish", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._done.is_set():
            if self.stop.wait(0.1):
                t = time.monotonic()
                for lane in self.lanes:
                    cut = getattr(lane, "cut", None)
                    if cut is not None and lane.name in self.limits:
                        cut(t + self.limits[lane.name])
                return

    def close(self) -> None:
        self._done.set()
        self._thread.join(1.0)
