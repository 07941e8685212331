"""Live FRFs after each hit (daq/lanes/frf.py): in a replay, in a recording, in the view and on the terminal.

Data: a simulated log of the linear ``beam_ch4_exp`` (tests/test_frf.py's ``session()``: order-4 stepping,
1 % noise, 10 s between hits) with five 200 N hits and one 3000 N hit that overloads the 2224 N hammer
(the log of tests/test_frf.py, test_modal_cmd.py, test_modes_view.py and test_report.py, simulated once);
15 channels at 16384 Hz, the issue's size. Oracles: ``gvt frf`` on the same log (an independent path: it
reads the records back with ``LogReader.read_stream``, the lane cuts them from the replayed blocks), the
rig's modal model (peaks within one 0.5 Hz bin of its natural frequencies), and the count of hits.
"""

from __future__ import annotations

import json
import queue
import threading
import time

import jsonschema
import numpy as np
import pytest

from analysis.model.rigs import open_rig
from analysis.records import FRF_TOPIC, FRFUpdate
from daq.cli import run as gvt
from daq.config.session import AnalysisSpec, DeviceSpec, SessionConfig, TriggerSpec
from daq.fanout import FanOut
from daq.lanes.frf import FRFLane, FRFPlan, SampleRing
from daq.log.reader import LogReader
from daq.replay_session import run_replay
from daq.session import run_session
from drivers.blocks import SampleBlock
from tests.test_frf import FORCE, shared_session
from tests.test_view import RERUN, rrd_entity_paths, rrd_verify


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    return shared_session(tmp_path_factory, 0.01, 0.01, (FORCE,) * 5 + (3000.0,))  # tests/test_frf.py's ``clean``


@pytest.fixture(scope="module")
def replayed(linear, tmp_path_factory):
    """A full-speed replay with the live FRF lane, its terminal lines and a view saved to an .rrd."""
    from daq.lanes.view import open_view

    rig, log = linear
    rrd = tmp_path_factory.mktemp("frf_view") / "live.rrd"
    target = open_view("save", str(rrd))
    lines: list[str] = []
    res = run_replay(log, speed=None, rig=rig, analysis=False, confirm=False, view=target, frf_line=lines.append)
    target.close()
    return res, lines, rrd


def test_one_record_per_hit_with_the_averages_and_the_refusal(replayed):
    res, lines, _ = replayed
    recs = res.frf
    assert [r["hit"] for r in recs] == [0, 1, 2, 3, 4, 5]
    assert [r["averages"] for r in recs if r["verdict"] == "accepted"] == [1, 2, 3, 4, 5]
    last = recs[-1]
    assert last["verdict"] == "refused" and last["averages"] == 5 and last["refused"] == 1
    assert last["reason"].startswith("overload: force reached its full scale 2224 N")
    for r in recs:  # every record is valid against the schema the log would store, and small
        jsonschema.validate(r, FRFUpdate.SCHEMA)
        assert len(json.dumps(r)) < 3000
    assert len(lines) == 6 and "3 averages at hammer (0 refused); driving point a13: 21.0 Hz (1.000)" in lines[2]
    assert lines[5].startswith("FRF hit 5 at 50.100 s: refused (overload")


def test_final_peaks_equal_gvt_frf_and_the_modal_model(linear, replayed, capsys):
    rig, log = linear
    res, _, _ = replayed
    assert gvt(["frf", str(log), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    final = res.frf[-1]
    assert doc["averages"] == final["averages"] == 5
    assert final["peaks_hz"] == sorted({p["freq_hz"] for p in doc["peaks"]})
    assert np.all(np.abs(np.array(final["peaks_hz"]) - rig.modes.frequencies_hz[:6]) <= 0.5)  # one bin
    dp = {p["freq_hz"]: p for p in doc["peaks"] if p["response"] == final["driving_point"]}
    assert final["dp_mag"] == pytest.approx([dp[f]["mag"] for f in final["peaks_hz"]], rel=1e-9)
    assert min(final["dp_coherence"]) >= 0.99 and min(final["min_coherence"]) >= 0.99


def test_cost_per_hit_at_15_channels_16384_hz(linear, replayed):
    rig, _ = linear
    res, _, _ = replayed
    assert rig.sample_rate == 16384.0 and 1 + len(rig.sensors) == 15
    cost = [r["elapsed_s"] for r in res.frf]
    # the budget is 50 ms a hit: measured ~10-25 ms wall clock beside the replay and view threads, but a
    # loaded test run (xdist workers, load 4) stretched the wall clock past it once, and past 4x it since; the lane
    # thread's own CPU time is what the lane costs, so that is what is held to the budget. The wall clock is the
    # host's: here only a hang guard (a quiet machine's wall clock is bench/bench_frf.py's)
    cpu = res.frf_cpu_s
    assert len(cpu) == len(cost) and max(cpu) <= 0.05, cpu
    assert max(cost) <= 5.0, cost


@pytest.mark.skipif(not RERUN.exists(), reason="the rerun CLI is not installed next to python")
def test_the_view_draws_the_frf_entities(replayed):
    res, _, rrd = replayed
    assert res.view_lane.view.counts.get("/frf") == 5 and res.view_lane.view.counts.get(FRF_TOPIC) == 6
    assert rrd_verify(rrd).returncode == 0
    import subprocess

    from tests.test_view import ENV

    p = subprocess.run([str(RERUN), "rrd", "print", str(rrd)], capture_output=True, text=True, env=ENV, timeout=60)
    want = {"/frf/magnitude/a13", "/frf/phase/a13", "/frf/coherence/a13", "/frf/magnitude/a14", "/frf/hammer", "/frf/averages"}
    assert all(w in p.stdout for w in want), p.stdout[:2000]
    assert "/log/analysis" in rrd_entity_paths(rrd)


def test_gvt_replay_prints_a_line_per_hit_and_no_frf_turns_it_off(linear, capsys):
    _, log = linear
    assert gvt(["replay", str(log), "--no-analysis", "--no-confirm"]) == 0
    out = capsys.readouterr().out
    assert out.count("FRF hit ") == 6 and "FRF hit 2 at 20.100 s: 3 averages" in out
    assert gvt(["replay", str(log), "--no-analysis", "--no-confirm", "--no-frf"]) == 0
    assert "FRF hit" not in capsys.readouterr().out


def test_a_recording_logs_one_frf_record_per_hit(tmp_path):
    """gvt record's wiring: the hit gate's hits reach the lane through the results router, the records the log."""
    out = tmp_path / "rec.mcap"
    cfg = SessionConfig(
        name="frf-live", rig="beam_ch4_exp", duration=5.4, analysis=AnalysisSpec(enabled=False),
        device=DeviceSpec(driver="sim", config={"block_size": 1024, "forces": [300.0, 300.0], "period": 2.6,
                                                "physics_seconds": 5.6, "seed": 3}),
        trigger=TriggerSpec(level=20.0, record_length=0.3),
    )  # fmt: skip
    lines: list[str] = []
    res = run_session(cfg, open_rig("beam_ch4_exp"), out, frf_line=lines.append)
    assert res.lost_samples == 0 and len(res.hits) == 2
    logged = LogReader(out).json_messages(FRF_TOPIC)
    assert logged == res.frf and [r["hit"] for r in logged] == [h.hit for h in res.hits]
    accepted = [r for r in logged if r["verdict"] == "accepted"]
    assert [r["averages"] for r in accepted] == list(range(1, len(accepted) + 1)) and accepted, logged
    assert len(lines) == 2
    # the lane off: one hit is enough to show that nothing is computed or logged for it (half the session above)
    dev = cfg.device.model_copy(update={"config": {**cfg.device.config, "forces": [300.0], "physics_seconds": 3.0}})
    one = cfg.model_copy(update={"duration": 2.8, "device": dev})
    no = run_session(one, open_rig("beam_ch4_exp"), tmp_path / "off.mcap", frf=False)
    assert len(no.hits) == 1 and no.frf == [] and LogReader(tmp_path / "off.mcap").json_messages(FRF_TOPIC) == []


def _plan(fs: float = 1000.0, n: int = 500) -> FRFPlan:
    return FRFPlan(stream="s", channels=("f", "x"), reference="f", outputs=("x",), quantities=("acceleration",), fs=fs, n=n,
                   pre=10, tau=None, band_hz=100.0, full_scale=1e6, driving_point="x", shown="x")  # fmt: skip


def _pulse_block(first: int, m: int) -> SampleBlock:
    data = np.zeros((m, 2), np.float32)
    data[:, 1] = np.sin(np.arange(first, first + m) * 0.3)
    return SampleBlock("s", first, 1000.0, ("f", "x"), data)


def test_a_slow_frf_lane_never_holds_up_the_publisher():
    """The lane stuck in its sink (a stand-in for a slow computation): publishing stays non-blocking, the lane's
    blocks are dropped and counted, and a hit whose record lost samples is refused with that reason."""
    fan = FanOut()
    gate = threading.Event()
    got: list[tuple[str, dict]] = []

    def sink(topic, obj, t):
        got.append((topic, dict(obj)))
        gate.wait(5.0)

    lane = FRFLane(fan, _plan(), sink, maxsize=4).start()
    lane.offer("/daq/hits", {"hit": 0, "index": 100, "t_s": 0.1, "verdict": "refused", "reason": "double_hit"})
    fan.publish(_pulse_block(0, 100))
    time.sleep(0.3)  # the lane takes the block and the hit, and blocks in the sink
    t0 = time.perf_counter()  # after the sleep: its oversleep on a busy host is not the publisher's
    for k in range(1, 200):
        fan.publish(_pulse_block(100 * k, 100))
    publish_s = time.perf_counter() - t0
    lane.offer("/daq/hits", {"hit": 1, "index": 1000, "t_s": 1.0, "verdict": "accepted", "reason": "ok"})
    gate.set()
    fan.close()
    lane.finish(time.monotonic() + 10)
    assert publish_s < 2.0 and lane.sub.dropped_blocks >= 150  # blocked on the sink it would be >= 5 s
    frf = [o for t, o in got if t == FRF_TOPIC]
    assert [r["verdict"] for r in frf] == ["refused", "refused"] and frf[0]["reason"] == "hit gate: double_hit"
    assert frf[1]["reason"].startswith("record incomplete")
    assert any(t == "/daq/events" and o["kind"] == "frf_overrun" for t, o in got)


def test_the_ring_keeps_the_last_samples_and_restarts_at_a_gap():
    ring = SampleRing(250, 1)
    for k in range(10):
        ring.append(100 * k, np.arange(100 * k, 100 * k + 100, dtype=np.float32)[:, None])
    assert (ring.start, ring.end) == (750, 1000)
    assert np.array_equal(ring.span(800, 1000)[:, 0], np.arange(800, 1000))
    assert ring.span(700, 800) is None and ring.span(900, 1001) is None
    ring.append(1200, np.zeros((50, 1), np.float32))  # a gap: what came before cannot join a record after it
    assert (ring.start, ring.end) == (1200, 1250) and ring.span(900, 1000) is None


def test_a_full_hit_queue_drops_and_counts():
    lane = FRFLane(FanOut(), _plan(), lambda *a: None, hit_queue=2)  # not started: nothing takes the hits
    for k in range(5):
        lane.offer("/daq/hits", {"hit": k, "index": k})
    lane.offer("/daq/events", {"kind": "note"})  # other topics are not the lane's
    assert lane.hits.qsize() == 2 and lane.dropped_hits == 3
    with pytest.raises(queue.Empty):
        for _ in range(3):
            lane.hits.get_nowait()
