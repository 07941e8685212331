"""The hit-gate lane: the hammer trigger and hit quality gate (:mod:`daq.hits`) on its own thread.

With several devices it reads them through a :class:`~daq.timeline.StreamAligner` (one timeline on the
reference device's index) and reports the clock-offset estimates on ``/daq/timeline``. Hits go to
``/daq/hits`` as they complete; at the end, channels that failed every hit go to ``/daq/events`` as
``suspect_channel`` (named, with why), and a hit gate that fell behind says how much it missed.

Times (docs/log-format.md, "Time base"): hits at their trigger sample, timeline reports at the reference
sample the aligner had reached, relative to the session's origin; when the aligner fixes a stream's offset
it is handed to ``offsets`` (the log places that stream on the reference's timeline with it).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from typing import Any

from daq.fanout import FanOut, Subscription
from daq.hits import HitDetector, HitRecord
from daq.lanes import Sink
from daq.log import layout
from daq.timeline import StreamAligner
from drivers.blocks import SampleBlock

TIMELINE_TOPIC = layout.TIMELINE_TOPIC
META_TIMELINE = "gvtlink.timeline"


class HitGateLane:
    name = "hits"

    def __init__(self, fan: FanOut, detector: HitDetector, sink: Sink, *, aligner: StreamAligner | None = None,
                 maxsize: int = 64, metadata: Callable[[str, dict], None] | None = None,
                 offsets: Callable[[str, int, str], None] | None = None) -> None:  # fmt: skip
        self.detector = detector
        self.offsets = offsets  # (stream, applied samples, method) once the aligner fixes them
        self.metadata = metadata  # the log's metadata records (the timeline's fixed and final offsets)
        self.aligner = aligner
        self.sink = sink
        self.sub: Subscription = fan.subscribe("hits", maxsize=maxsize)
        self.hits: list[HitRecord] = []
        self.error: str | None = None
        self._thread = threading.Thread(target=self._main, name="hit-gate", daemon=True)

    def start(self) -> HitGateLane:
        self._thread.start()
        return self

    def offer(self, topic: str, obj: dict) -> None:
        pass

    # --- thread ---------------------------------------------------------------------------------------
    def _hit(self, h: HitRecord) -> None:
        self.hits.append(h)
        self.sink(layout.HITS_TOPIC, h.summary(), round(h.t_s * 1e9))

    def _feed(self, blk: SampleBlock) -> None:
        for h in self.detector.feed(blk):
            self._hit(h)

    def _main(self) -> None:
        try:
            for blk in self.sub:
                if self.aligner is None:
                    self._feed(blk)
                    continue
                for m in self.aligner.feed(blk):
                    self._feed(m)
                self._timeline()
            if self.aligner is not None:
                for m in self.aligner.finish():
                    self._feed(m)
                self._timeline()
            for h in self.detector.finish():
                self._hit(h)
        except Exception as exc:  # said in the log; the recording goes on without the gate
            self.error = f"{type(exc).__name__}: {exc}"
            self.sink(layout.EVENTS_TOPIC, {"kind": "hit_gate_error", "message": self.error}, None)
            for _ in self.sub:
                pass

    def _timeline(self) -> None:
        assert self.aligner is not None
        ref = self.aligner.reference
        end = self.aligner.reference_end
        t_ns = None if end is None else round(end * 1e9 / self.aligner.fs)
        for m in self.aligner.drain_messages():
            if m["kind"] == "fixed" and self.offsets is not None and m.get("applied_samples") is not None:
                self.offsets(m["stream"], int(m["applied_samples"]), str(m.get("method", "")))
            self.sink(TIMELINE_TOPIC, m, t_ns)
            if m["kind"] == "moved":
                self.sink(layout.EVENTS_TOPIC, {
                    "kind": "timeline_moved", "stream": m["stream"],
                    "message": f"clock offset of {m['stream']} to {ref} moved by {m['moved_samples']:.1f} samples "
                               f"(limit {m['limit_samples']:.1f}); the merged stream keeps {m['applied_samples']}",
                }, t_ns)  # fmt: skip

    # --- end ------------------------------------------------------------------------------------------
    def finish(self, deadline: float) -> None:
        self._thread.join(max(0.0, deadline - time.monotonic()))
        for c, why in self.suspects().items():
            self.sink(layout.EVENTS_TOPIC, {"kind": "suspect_channel", "channel": c, "message": f"channel {c} {why}"}, None)
        meta = self.timeline_metadata()
        if meta is not None and self.metadata is not None:
            self.metadata(META_TIMELINE, meta)
        if self.sub.dropped_blocks:
            self.sink(layout.EVENTS_TOPIC, {
                "kind": "subscriber_overrun", "count": self.sub.dropped_samples,
                "message": f"hit gate fell behind by {self.sub.dropped_blocks} blocks",
            }, None)  # fmt: skip

    def suspects(self) -> dict[str, str]:
        """Channels that failed every hit, with why (the gate's own wording)."""
        return dict(self.detector.suspect_reasons())

    def timeline_metadata(self) -> dict[str, str] | None:
        """The ``gvtlink.timeline`` metadata record (None with one device)."""
        a = self.aligner
        if a is None:
            return None
        fixed = {s: {**o.as_dict(), "applied_samples": o.offset_samples} for s, o in a.fixed_offsets.items()}
        data: dict[str, Any] = {
            "reference": a.reference, "sample_rate": repr(a.fs), "channels": json.dumps(list(a.channels)),
            "fixed": json.dumps(fixed), "final": json.dumps(a.current()), "dropped_samples": json.dumps(dict(a.dropped_samples)),
        }  # fmt: skip
        return data
