"""The lanes that can wait in their own process (issue 30, item 1): the byte ring, the lane-host worker in a session,
its death and restart, and the priority line."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.model.rigs import open_rig
from daq.config.session import AnalysisSpec, DeviceSpec, SessionConfig, TriggerSpec
from daq.lanes.host import READY_TIMEOUT_S
from daq.lanes.shm_ring import ALIGN, HEADER, ByteRing, ShedLog
from daq.log.reader import LogReader
from daq.priority import base_nice
from daq.session import Session, SessionOptions
from daq.sim_devices import start_simulation


def _rows(n: int, ncols: int, seed: int) -> np.ndarray:
    return (np.arange(n * ncols, dtype=np.float32).reshape(n, ncols) + 1000.0 * seed).astype(np.float32)


# --- the ring ---------------------------------------------------------------------------------------------
def test_records_wrap_around_without_splitting_and_read_back_in_place():
    ring = ByteRing(bytearray(ByteRing.size_for(1000)))  # 1000 bytes: 5 records of 3 x 15 float32 (180 B) + a tail
    slots = [ring.put(_rows(3, 15, k)) for k in range(5)]
    assert all(s is not None for s in slots) and ring.put(_rows(3, 15, 5)) is None  # 5 x 184 = 920; 6th: no room
    ring.release(slots[1].end)  # the reader consumed two
    s5 = ring.put(_rows(3, 15, 5))  # 80 bytes left at the end: the record starts at the beginning again
    assert s5 is not None and s5.start % ring.capacity == 0 and s5.start == ring.capacity
    np.testing.assert_array_equal(ring.view(s5.start, (3, 15)), _rows(3, 15, 5))
    np.testing.assert_array_equal(ring.view(slots[4].start, (3, 15)), _rows(3, 15, 4))  # not overwritten
    v = ring.view(s5.start, (3, 15))
    v[0, 0] = -1.0  # a view, not a copy: the reader sees the ring's memory
    assert ring.view(s5.start, (3, 15))[0, 0] == -1.0


def test_a_full_ring_sheds_and_the_shed_log_names_exact_ranges():
    ring, shed = ByteRing(bytearray(HEADER + 4096)), ShedLog()
    first, kept = 0, []
    for n in (64, 64, 64, 64, 64):  # 64 x 4 ch x 4 B = 1024 B: four fit
        slot = ring.put(_rows(n, 4, first))
        if slot is None:
            shed.add("dev0", first, first + n)
        else:
            kept.append(first)
        first += n
    ring.release(ring.write_pos)
    for n in (64, 100):
        assert ring.put(_rows(n, 4, first)) is not None
        first += n
    shed.add("dev0", 400, 464)
    shed.add("dev0", 464, 500)  # contiguous: merged
    assert kept == [0, 64, 128, 192]
    assert shed.ranges == [("dev0", 256, 320), ("dev0", 400, 500)] and shed.samples == 164 and shed.blocks == 3


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 40), st.booleans()), min_size=1, max_size=60), st.integers(64, 600))
def test_any_block_sizes_never_overwrite_an_unreleased_record(ops, capacity):
    """Oracle: the records not yet released read back exactly as written, and a put fails only when the record
    cannot be placed contiguously in the bytes not held (geometry of the buffer, independent of the counters)."""
    ring = ByteRing(bytearray(ByteRing.size_for(capacity)))
    cap = ring.capacity
    live: list[tuple[int, int, int]] = []  # (start, end, seed)
    for k, (n, consume) in enumerate(ops):
        if consume and live:
            ring.release(live.pop(0)[1])
        arr = _rows(n, 2, k)
        size = -(-arr.nbytes // ALIGN) * ALIGN
        held = ring.write_pos - ring.read_pos
        slot = ring.put(arr)
        off = ring.write_pos % cap if slot is None else None
        if slot is None:
            tail = cap - off if off + size > cap else 0
            assert size > cap or held + tail + size > cap  # really no room
        else:
            live.append((slot.start, slot.end, k))
            assert slot.start % cap + size <= cap  # never split
        assert ring.write_pos - ring.read_pos <= cap
        for start, _end, seed in live:
            rows = (_end - start) // 8  # 2 float32 per row, rounded up to 8 bytes
            got = ring.view(start, (rows, 2))
            want = _rows(rows, 2, seed)
            np.testing.assert_array_equal(got, want)


# --- a session with the lanes in the worker ----------------------------------------------------------------
def _cfg(process: str, duration: float = 1.4, confirm: bool = False, physics_s: float | None = None) -> SessionConfig:
    return SessionConfig(
        name=f"host-{process}", rig="beam_ch4_exp", duration=duration,
        device=DeviceSpec(driver="sim", config={"paced": True, "block_size": 256, "forces": [1583.0], "period": 0.6,
                                                "physics_seconds": physics_s or duration + 0.2, "seed": 3}),
        trigger=TriggerSpec(level=20.0, record_length=0.3), queue_seconds=30.0,
        analysis=AnalysisSpec(process=process, confirm=confirm),
    )  # fmt: skip


def _session(cfg: SessionConfig, out, **opts) -> Session:
    rig = open_rig(cfg.rig)
    harness = start_simulation(cfg, rig)
    session = Session(cfg, harness.rig or rig, out, harness, SessionOptions(**opts))
    session.harness_stop = harness.stop
    return session


def _run(session: Session):
    try:
        return session.run()
    finally:
        session.harness_stop()


@pytest.fixture(scope="module")
def both_modes(tmp_path_factory):
    import daq.lanes.host as host_module

    d = tmp_path_factory.mktemp("host")
    worker = _session(_cfg("worker"), d / "worker.mcap")
    pid, nice = worker.host.pids[0], os.getpriority(os.PRIO_PROCESS, worker.host.pids[0])
    # the same results as the thread mode need every sample analysed: the worker at nice +10 may take longer than the
    # recorder's 5 s to catch up after the data on a loaded host (4 hogs beside make test: it skipped the last 922)
    catch_up, host_module.END_CATCH_UP_S = host_module.END_CATCH_UP_S, 120.0
    try:
        res_w = _run(worker)
    finally:
        host_module.END_CATCH_UP_S = catch_up
    res_t = _run(_session(_cfg("thread"), d / "thread.mcap"))
    return (d / "worker.mcap", res_w, pid, nice), (d / "thread.mcap", res_t)


def test_the_analysis_runs_in_the_worker_and_logs_what_the_thread_mode_logs(both_modes):
    (wlog, rw, pid, nice), (tlog, rt) = both_modes
    assert pid != os.getpid() and nice == min(19, base_nice() + 10)  # below the recorder's start value
    assert rw.outcome.exit_code == 0 and rw.lost_samples == 0 and rw.writer_overrun_samples == 0
    assert rw.analysis_dropped_samples == 0 and rt.analysis_dropped_samples == 0
    assert rt.analysis_events and rw.analysis_events == rt.analysis_events  # the same detector on the same samples
    w, t = LogReader(wlog), LogReader(tlog)
    for topic in ("/analysis/rq", "/analysis/modal", "/analysis/events"):
        assert w.json_messages(topic) == t.json_messages(topic), topic
    assert len(rw.analysis_latencies_s) == len(rt.analysis_latencies_s) > 0 and rw.analysis_cpu_s > 0
    kinds = [e["kind"] for e in w.json_messages("/daq/events")]
    assert "analysis_overrun" not in kinds and "lane_restarted" not in kinds


def test_a_killed_worker_is_restarted_once_then_the_lanes_go_off_with_one_line(tmp_path):
    """The worker is killed once it reads blocks, its replacement once that one reads blocks, both mid-session; then
    the session is stopped (as Ctrl-C would). The session runs until then, however long a loaded host takes to
    start the replacement (a cold worker on a loaded 2-core host took ~19 s, beyond a short session's end)."""
    lines: list[str] = []
    stop = threading.Event()
    # a duration beyond both waits for a worker (the test stops the session itself); the simulated physics 3 s (the
    # device computes its whole span at the start, then serves its noise floor): 60 s of it cost seconds and 120 MB
    duration = 2 * READY_TIMEOUT_S + 60.0
    session = _session(_cfg("worker", duration=duration, physics_s=3.0), tmp_path / "k.mcap", line=lines.append, stop=stop)
    host = session.host

    def consumed(n_pids: int) -> bool:  # the ring is reset at a restart: a worker consumed blocks when read_pos moves
        t0 = time.monotonic()
        while (len(host.pids) < n_pids or host.ring.read_pos == 0) and time.monotonic() - t0 < READY_TIMEOUT_S:
            time.sleep(0.05)
        return len(host.pids) == n_pids and host.ring.read_pos > 0

    def killer() -> None:
        try:
            host.alive_at_start = consumed(1)
            time.sleep(0.3)  # some way in: the lost range is not empty
            os.kill(host.pids[0], signal.SIGKILL)
            host.alive_after_restart = consumed(2)
            os.kill(host.pids[-1], signal.SIGKILL)
            t0 = time.monotonic()
            while host.deaths < 2 and time.monotonic() - t0 < 30.0:
                time.sleep(0.05)
            time.sleep(0.3)
        finally:
            stop.set()

    th = threading.Thread(target=killer)
    th.start()
    res = _run(session)
    th.join()
    # the recording is whole whatever the restarts cost; how long they took is the host's business (no wall clock)
    assert res.outcome.exit_code == 0 and res.outcome.reason == "stopped" and res.lost_samples == 0, res.outcome
    assert host.alive_at_start and host.alive_after_restart and host.deaths == 2 and len(host.pids) == 2
    events = LogReader(tmp_path / "k.mcap").json_messages("/daq/events")
    restarted = [e for e in events if e["kind"] == "lane_restarted"]
    off = [e for e in events if e["kind"] == "analysis_error"]
    assert len(restarted) == 1 and restarted[0]["from_index"] < restarted[0]["to_index"]
    msg = off[0]["message"] if len(off) == 1 else ""
    assert "died a second time" in msg and lines == [msg], (off, lines)  # mid-session, one line
    overrun = next(e for e in events if e["kind"] == "analysis_overrun")
    r = restarted[0]
    assert [r["from_index"], r["to_index"]] in [list(x) for x in overrun["ranges"]]  # the lost range, counted exactly
    assert overrun["count"] == res.analysis_dropped_samples == sum(b - a for a, b in overrun["ranges"])


def test_the_recorder_says_once_when_it_cannot_raise_its_priority():
    code = ("import os\n"
            "from daq.priority import raise_priority  # imported first: the interpreter may live where nobody reads\n"
            "if os.getuid() == 0: os.setresuid(65534, 65534, 65534)  # root may always: drop it\n"
            "n0 = os.getpriority(os.PRIO_PROCESS, 0); print(n0)\n"
            "a = raise_priority(); b = raise_priority()\n"
            "print(a); print(a is b, os.getpriority(os.PRIO_PROCESS, 0) == n0)\n")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30,
                         cwd=os.path.dirname(os.path.dirname(__file__)))  # fmt: skip
    n0, first, second = out.stdout.strip().splitlines()
    n0 = int(n0)  # the test process's own value (a session before may have raised it)
    assert f"recording at normal priority (nice {n0})" in first and "refused" in first and f"nice {n0 + 10}" in first
    assert second == "True True"  # one verdict per process, and nothing changed


def test_finish_never_waits_past_its_deadline_on_a_hung_worker():
    from analysis.operator import RigModel
    from daq.fanout import FanOut
    from daq.lanes.host import LaneHost
    from drivers.blocks import SampleBlock

    rig = open_rig("beam_ch4_exp")
    chans = tuple(p.name for p in [rig.hammer, *rig.sensors])
    fan, got = FanOut(), []
    host = LaneHost(fan, RigModel.from_rig(rig), "dev0", chans, rig.sample_rate, lambda *a: got.append(a), confirm=False)
    pid = host.pids[0]
    try:
        os.kill(pid, signal.SIGSTOP)  # hung: alive, silent, reading nothing
        for k in range(8):
            fan.publish(SampleBlock("dev0", 1024 * k, rig.sample_rate, chans, np.zeros((1024, len(chans)), np.float32)))
        fan.close()
        t0 = time.monotonic()
        host.analysis_lane().finish(t0 + 1.0)
        # its deadline, plus the kill and the joins of a killed process (5.5 s by design), with room for a busy host
        assert time.monotonic() - t0 < 10.0
    finally:
        with contextlib.suppress(ProcessLookupError):  # killed by finish already: the normal case
            os.kill(pid, signal.SIGKILL)
    msgs = [obj["message"] for _t, obj, _n in got if obj.get("kind") == "lane_abandoned"]
    assert msgs and "did not finish by its deadline" in msgs[0]
    # every block the hung worker never read is counted in the analysis_overrun event, as the session's figure is
    # (the load matrix at 8 hogs found the event written before the killed worker's in-flight blocks were counted)
    over = [obj for _t, obj, _n in got if obj.get("kind") == "analysis_overrun"]
    assert over and over[0]["count"] == host.shed.samples + host.sub.dropped_samples == 8 * 1024, over
    assert host.shm is None and not os.path.exists(f"/dev/shm/{host.spec.shm_name.lstrip('/')}")  # the ring is freed


def test_a_worker_behind_at_the_end_skips_what_is_left_after_its_catch_up_time(monkeypatch):
    """A worker starved when the data ends (stopped here) gets END_CATCH_UP_S to catch up; then it skips what it still
    holds, names the ranges (shed, in the analysis_overrun event) and says so in one line, and the lane finishes
    long before its deadline (at nice +10 beside 8 busy loops a 4 s session's drain took 44 s)."""
    import daq.lanes.host as host_mod
    from analysis.operator import RigModel
    from daq.fanout import FanOut
    from daq.lanes.host import LaneHost
    from drivers.blocks import SampleBlock

    monkeypatch.setattr(host_mod, "END_CATCH_UP_S", 0.5)
    rig = open_rig("beam_ch4_exp")
    chans = tuple(p.name for p in [rig.hammer, *rig.sensors])
    fan, got, said = FanOut(), [], []
    host = LaneHost(fan, RigModel.from_rig(rig), "dev0", chans, rig.sample_rate, lambda *a: got.append(a), confirm=False,
                    say=said.append)  # fmt: skip
    pid = host.pids[0]
    os.kill(pid, signal.SIGSTOP)  # starved: alive, reading nothing
    n = 16
    for k in range(n):
        fan.publish(SampleBlock("dev0", 1024 * k, rig.sample_rate, chans, np.zeros((1024, len(chans)), np.float32)))
    fan.close()
    threading.Timer(1.0, os.kill, (pid, signal.SIGCONT)).start()  # back after the catch-up time is over
    t0 = time.monotonic()
    host.analysis_lane().finish(t0 + 60.0)
    assert time.monotonic() - t0 < 30.0  # the catch-up's 5 s and a nice +10 worker's skip, well before the 60 s
    late = sum(b - a for a, b in host.late)
    assert 0 < late <= 1024 * n and all(a % 1024 == 0 and b % 1024 == 0 for a, b in host.late)  # whole blocks
    over = [obj for _t, obj, _n in got if obj.get("kind") == "analysis_overrun"]
    assert over and over[0]["count"] >= late  # the skipped tail is counted with whatever the ring shed
    assert any("were not analysed" in line for line in said)
    assert not [obj for _t, obj, _n in got if obj.get("kind") == "lane_abandoned"]  # skipped, not abandoned
