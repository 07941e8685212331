"""The lane worker's window records, JSON-encoded in the worker and sent in batches (D107): the log is the same.

The bytes the worker encodes must be the bytes the writer would have written, at the same log times (on the analysed
stream's clock), one MCAP message each; a batch never overtakes the IR event or other message sent after it; lanes
in the recorder that asked for a topic still get the record (decoded, as a replay gives it).
"""

from __future__ import annotations

import json
import multiprocessing
import time

import numpy as np
from mcap.reader import make_reader

from analysis.records import RQWindow
from daq.lanes import Results
from daq.lanes.host_worker import BATCH_S, Batcher
from daq.lanes.log import LogLane
from daq.log import layout
from daq.log.writer import ChannelInfo
from drivers.blocks import SampleBlock

FS = 1024.0


def _windows(n: int) -> list[RQWindow]:
    return [RQWindow(start=64 * k, stop=64 * k + 256, t_start_s=64 * k / FS, t_end_s=(64 * k + 256) / FS,
                     rq_hz=(12.5 + k, float("nan")), pov_fraction=(0.9, 0.1), seed_spike=k == 2) for k in range(n)]  # fmt: skip


def _log(path, encoded: bool) -> list[tuple[str, int, bytes]]:
    """A two-stream session log (the analysed stream offset from the reference) with the same windows given either as
    objects (``sink``) or encoded by a worker's :class:`Batcher` (``sink_encoded``); its JSON messages."""
    lane = LogLane(path, preview=False)
    lane.add_stream("ref", [ChannelInfo("f", "force", "N")], FS)
    lane.add_stream("acc", [ChannelInfo("a", "acceleration", "m/s^2")], FS, reference=False, offset_s=0.25, method="test")
    lane.clocks[layout.ANALYSIS_PREFIX] = "acc"
    for s in ("ref", "acc"):
        lane.write_block(SampleBlock(s, 0, FS, ("f",) if s == "ref" else ("a",), np.zeros((2048, 1), np.float32)))
    wins = _windows(5)
    if encoded:
        rx, tx = multiprocessing.Pipe(duplex=False)
        b = Batcher(tx)
        for w in wins:
            b.record(w.TOPIC, w, round(w.t_end_s * 1e9))
        b.send(("analysis_done",))
        msg = rx.recv()
        assert msg[0] == "rj" and len(msg[1]) == 5  # one message for the five records, before the next message
        assert rx.recv() == ("analysis_done",)
        lane.sink_encoded(msg[1])
    else:
        for w in wins:
            lane.sink(w.TOPIC, w, round(w.t_end_s * 1e9))
    lane.finish(time.monotonic() + 10)
    with open(path, "rb") as f:
        msgs = [(ch.topic, m.log_time, m.data) for _s, ch, m in make_reader(f).iter_messages()]
    origin = min(t for topic, t, _d in msgs if topic == layout.samples_topic("ref"))  # the host clock at ref's sample 0
    return [(topic, t - origin, d) for topic, t, d in msgs if topic.startswith(layout.ANALYSIS_PREFIX)]


def test_encoded_batches_write_the_same_messages(tmp_path):
    plain, batched = _log(tmp_path / "plain.mcap", False), _log(tmp_path / "batched.mcap", True)
    rq = [m for m in plain if m[0] == layout.RQ_TOPIC]
    assert len(rq) == 5  # each record its own message, as before
    assert batched == plain  # topics, log times (the analysed stream's offset applied) and bytes
    assert rq[0][1] == 250_000_000 + 250_000_000  # the window's end on acc's clock, acc 0.25 s after the origin
    assert b"NaN" in rq[0][2]  # as json.dumps writes it, in both paths


def test_batcher_keeps_order_and_flushes_a_quiet_batch():
    rx, tx = multiprocessing.Pipe(duplex=False)
    b = Batcher(tx)
    w = _windows(2)
    b.record(w[0].TOPIC, w[0], 1)
    b.record(layout.IR_EVENTS_TOPIC, {"id": 1}, 2)  # an object topic: the batch before it goes first
    assert rx.recv() == ("rj", [(w[0].TOPIC, json.dumps(dict(w[0]), separators=(",", ":")).encode(), 1)])
    assert rx.recv() == ("r", layout.IR_EVENTS_TOPIC, {"id": 1}, 2)
    b.record(w[1].TOPIC, w[1], 3)  # nothing follows it: the batch thread sends it within BATCH_S (+ its half-period)
    assert rx.poll(5 * BATCH_S)
    assert rx.recv()[1][0][2] == 3


def test_results_route_decoded_records_and_count_them():
    got, logged = [], []

    class Lane:
        name = "view"

        def offer(self, topic, obj):
            got.append((topic, obj))

    res = Results(log_encoded=logged.extend)
    res.route(Lane(), [layout.RQ_TOPIC])
    w = _windows(1)[0]
    raw = json.dumps(dict(w), separators=(",", ":")).encode()
    res.emit_encoded([(w.TOPIC, raw, 7), ("/analysis/other", b"{}", 8)])
    assert logged == [(w.TOPIC, raw, 7), ("/analysis/other", b"{}", 8)]
    assert got == [(w.TOPIC, json.loads(raw))] and got[0][1]["rq_hz"][0] == 12.5
    assert res.counts == {w.TOPIC: 1, "/analysis/other": 1}
