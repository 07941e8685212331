"""Lanes: what a recording or a replay is made of, beside its sources of sample blocks.

A :class:`~daq.recorder.Recorder` owns sources (devices, or a log being replayed), one fan-out, and
lanes. Blocks reach a lane through its own bounded fan-out subscription (taken when the lane is built);
results (hits, driver events, analysis windows, IR events, confirmations) reach it through
:meth:`Lane.offer`, routed by topic by :class:`Results`. The protocol is deliberately small so that
``gvt record`` and ``gvt replay`` assemble the same lanes, and shutdown is one ordered loop over them
(docs/session.md, "Who owns what").

Every lane keeps the rules of the recording path (architecture.md): ``offer`` never blocks, a lane that
falls behind drops its own input and says so, and nothing a lane does can stop the log writer.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol

#: ``sink(topic, obj, log_time_ns)``: where a lane's results go (the Results router, in a recorder).
Sink = Callable[[str, dict, int | None], None]


class Lane(Protocol):
    """One consumer of a session's blocks and results, with its own thread(s) and bounded queue(s)."""

    name: str

    def offer(self, topic: str, obj: dict) -> None:
        """A result from elsewhere (only the topics the lane was routed); must never block."""

    def finish(self, deadline: float) -> None:
        """The source has ended (the fan-out is closed): finish the work in hand, emit the last results,
        and join the lane's threads, by ``deadline`` (``time.monotonic()``) at the latest."""


@dataclass
class Route:
    lane: Lane
    topics: frozenset[str] | None  # None: every topic


@dataclass
class Results:
    """Routes result records: first to the log (if the session records one), then to each lane that asked
    for the topic. One instance per recorder; lanes get :meth:`emit` as their sink."""

    log: Sink | None = None
    routes: list[Route] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    #: the log's path for records already JSON-encoded (``LogLane.sink_encoded``); None: decoded and given to ``log``
    log_encoded: Callable[[list[tuple[str, bytes, int | None]]], None] | None = None

    def route(self, lane: Lane, topics: Iterable[str] | None = None) -> None:
        self.routes.append(Route(lane, None if topics is None else frozenset(topics)))

    def emit(self, topic: str, obj: dict, log_time_ns: int | None = None) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.log is not None:
            self.log(topic, obj, log_time_ns)
        for r in self.routes:
            if r.topics is None or topic in r.topics:
                r.lane.offer(topic, obj)

    def emit_encoded(self, batch: list[tuple[str, bytes, int | None]]) -> None:
        """Records a lane worker encoded as JSON (``(topic, bytes, log_time_ns)``, daq/lanes/host.py): the bytes to the
        log as they are; a lane that asked for the topic gets the decoded dict (what a replay of the log gives it)."""
        for topic, _raw, _t in batch:
            self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.log_encoded is not None:
            self.log_encoded(batch)
        elif self.log is not None:
            for topic, raw, t in batch:
                self.log(topic, json.loads(raw), t)
        for topic, raw, _t in batch:
            wants = [r.lane for r in self.routes if r.topics is None or topic in r.topics]
            if wants:
                obj = json.loads(raw)
                for lane in wants:
                    lane.offer(topic, obj)


class NullLane:
    """A lane that wants nothing: the default for optional parts (tests, replays without a view)."""

    name = "null"

    def offer(self, topic: str, obj: dict) -> None:
        pass

    def finish(self, deadline: float) -> None:
        pass
