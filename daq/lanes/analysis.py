"""The near-live analysis as a fan-out subscriber: ``gvt record`` and ``gvt replay`` run it beside the log.

It reads its own bounded subscription (architecture.md: the recording path never waits on analysis —
when the lane falls behind, the fan-out drops *its* input and counts exactly which ranges it missed),
feeds the blocks of one stream to :class:`~analysis.operator.AnalysisOperator` in a thread, and hands
every result to a sink (the session's log writer: ``/analysis/...`` topics, log time = the window's
end on the stream's clock). Missed ranges show up to the operator as gaps (it restarts after them and
says so) and are written as ``analysis_overrun`` events at the end.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np

from analysis.exchange import IREvent
from analysis.operator import AnalysisOperator, AnalysisSettings, RigModel
from daq.fanout import END, FanOut, Subscription
from daq.log import layout
from drivers.blocks import SampleBlock, coalesce

Sink = Callable[[str, dict, int | None], None]  # topic, object, log time (ns) or None


def analysis_stream(streams: dict[str, tuple[str, ...]], model: RigModel) -> str | None:
    """The stream that carries every sensor of the rig (the first by name), or None."""
    for name in sorted(streams):
        if all(c in streams[name] for c in model.sensors):
            return name
    return None


class LaneUnavailable(Exception):
    """Why a log or session cannot be analysed (one line: the rig does not fit its streams)."""


def rig_stream(rig, streams: dict[str, tuple[str, ...]]) -> tuple[RigModel, str]:
    """The rig's model and the stream the analysis reads (in a thread or a lane host); :class:`LaneUnavailable`
    (one line) when the rig has no model or no stream records all its sensors."""
    try:
        model = RigModel.from_rig(rig)
    except ValueError as exc:
        raise LaneUnavailable(f"rig {rig.name}: {exc}") from None
    name = analysis_stream(streams, model)
    if name is None:
        raise LaneUnavailable(f"no stream records all the rig's sensors {list(model.sensors)}")
    return model, name


def start_analysis_lane(
    fan: FanOut, rig, streams: dict[str, tuple[str, ...]], sample_rate: float, sink: Sink,
    settings: AnalysisSettings | None = None, maxsize: int = 512, **frame: float,
) -> AnalysisLane:  # fmt: skip
    """Start the lane on the stream that carries every sensor of ``rig``; :class:`LaneUnavailable` if none.
    ``frame``: ``frame_samples`` / ``frame_wait_s`` of :class:`AnalysisLane`."""
    model, name = rig_stream(rig, streams)
    try:
        lane = AnalysisLane(fan, model, name, streams[name], sample_rate, sink, settings, maxsize=maxsize, **frame)
    except ValueError as exc:  # the rig's modes and the sample rate do not fit (analysis/operator.py resolvable_basis)
        raise LaneUnavailable(f"rig {rig.name}: {exc}") from None
    return lane.start()


def warm_up(model: RigModel, stream: str, channels: tuple[str, ...], sample_rate: float,
            settings: AnalysisSettings | None = None) -> float:  # fmt: skip
    """Run a throwaway operator over 0.25 s of small noise so every compiled kernel is built (or loaded from
    the numba cache) *now*, before a device streams. Returns the seconds it took.

    Compiling holds the GIL: on a fresh install (cold numba cache) the first session compiled ~3 s of
    kernels while its device was streaming, and a paced simulated device recorded 0.78 s of a 3.2 s
    session (tests/test_analysis_session.py in a fresh clone); a serial reader starved like that loses
    data in the OS buffer. Warm, this costs a few milliseconds."""
    t0 = time.perf_counter()
    op = AnalysisOperator(model, channels, sample_rate, settings, lambda *_: None)
    n = max(64, int(0.25 * sample_rate))
    data = (1e-6 * np.random.default_rng(0).standard_normal((n, len(channels)))).astype(np.float32)
    op.feed(SampleBlock(stream, 0, sample_rate, tuple(channels), data))
    op.finish()
    return time.perf_counter() - t0


class AnalysisLane:
    """The operator on its own thread, fed in frames.

    Why frames: the operator costs per call as much as per sample (a serial device's 64-sample blocks cost
    0.084 CPU-s per data-s, the same data in 1024-sample blocks 0.015, identical results — docs/session.md).
    The lane joins contiguous blocks of its stream until ``frame_samples`` or until it has waited
    ``frame_wait_s`` since the frame's first block arrived, so each window's result is at most
    ``frame_wait_s`` later than block by block; a lane that is behind joins what is queued without waiting.
    Latencies are counted from the arrival of a frame's first block (the operator's ``t_arrival``).
    """

    name = "analysis"

    def __init__(
        self, fan: FanOut, model: RigModel, stream: str, channels: tuple[str, ...], sample_rate: float, sink: Sink,
        settings: AnalysisSettings | None = None, maxsize: int = 512, frame_samples: int = 1024, frame_wait_s: float = 0.02,
    ) -> None:  # fmt: skip
        self.frame_samples = frame_samples
        self.frame_wait_s = frame_wait_s
        self.frames = 0
        self.thread_cpu_s = 0.0  # CPU of the lane's thread (the operator runs on it)
        self.stream = stream
        self.channels = channels
        self.sink = sink
        self.error: str | None = None
        #: called with each frame once the operator has consumed it (the lane host gives its ring memory back)
        self.after_feed: Callable[[SampleBlock], None] | None = None
        self.sub: Subscription = fan.subscribe(f"analysis:{stream}", maxsize=maxsize)
        self.op = AnalysisOperator(model, channels, sample_rate, settings, self._emit)
        warm_up(model, stream, channels, sample_rate, settings)
        self._thread = threading.Thread(target=self._main, name=f"analysis:{stream}", daemon=True)

    def start(self) -> AnalysisLane:
        self._thread.start()
        return self

    def offer(self, topic: str, obj: dict) -> None:  # the analysis takes no results from other lanes
        pass

    def finish(self, deadline: float) -> None:
        """The Lane protocol's end: the operator's last windows and events, then the overrun note."""
        self.join(max(0.0, deadline - time.monotonic()))

    def join(self, timeout: float | None = None) -> list[IREvent]:
        self._thread.join(timeout)
        if self.sub.dropped_blocks:
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "analysis_overrun", "stream": self.stream, "count": self.sub.dropped_samples,
                "message": f"the analysis fell behind and skipped {self.sub.dropped_blocks} blocks "
                           f"({self.sub.dropped_samples} samples); it restarted after each gap",
            }, None)  # fmt: skip
        return list(self.op.events)

    def _emit(self, topic: str, obj: dict) -> None:
        t = obj.get("t_end_s", obj.get("end_s"))
        self.sink(topic, obj, None if t is None else round(float(t) * 1e9))

    def _frames(self) -> Iterator[tuple[SampleBlock, float]]:
        """Frames of contiguous blocks of the lane's stream, each with the arrival time (perf_counter clock) of
        its first block."""
        carry: SampleBlock | None = None
        while True:
            first = carry if carry is not None else self.sub.get()
            carry = None
            if first is END:
                return
            if first.stream != self.stream:
                continue
            parts, n = [first], first.n_samples
            t_host = first.extra.get("t_host")
            t0 = time.perf_counter() - (time.monotonic() - t_host if t_host is not None else 0.0)
            until = (t_host if t_host is not None else time.monotonic()) + self.frame_wait_s  # a lane behind does not wait
            while n < self.frame_samples:
                try:
                    nxt = self.sub.get(timeout=max(0.0, until - time.monotonic()))
                except queue.Empty:
                    break
                if nxt is END or (nxt.stream == self.stream and nxt.first_index != parts[-1].end_index):
                    carry = nxt  # the end, or a gap: this frame goes out first
                    break
                if nxt.stream == self.stream:
                    parts.append(nxt)
                    n += nxt.n_samples
            self.frames += 1
            yield (parts[0] if len(parts) == 1 else next(coalesce(parts, n))), t0

    def _main(self) -> None:
        c0 = time.thread_time()
        try:
            for frame, t0 in self._frames():
                self.op.feed(frame, t_arrival=t0)
                if self.after_feed is not None:
                    self.after_feed(frame)
            self.op.finish()
        except Exception as exc:  # reported and logged; the recording goes on without analysis
            self.error = f"{type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "analysis_error", "stream": self.stream, "message": self.error}, None)
            for _ in self.sub:  # keep draining so close() never has to drop for us
                pass
        finally:
            self.thread_cpu_s = time.thread_time() - c0
