"""analysis/forked_worker.py: a forked child runs an object's methods in submit order, raises its errors in the parent,
and never leaves the parent hanging when it dies or the parent stops it."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

from analysis.errors import GvtError
from analysis.forked_worker import ForkedWorker, WorkerDied, can_fork, reap

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the forked worker is Linux-only")


class Counter:
    def __init__(self) -> None:
        self.n = 0
        self.parent_pid = os.getpid()

    def add(self, k: int) -> tuple[int, int]:
        self.n += k
        return self.n, os.getpid()

    def total(self, a: np.ndarray) -> float:
        return float(a.sum())

    def fail(self) -> None:
        raise ValueError("bad block at sample 7")

    def sleep(self, s: float) -> None:
        time.sleep(s)

    def unpicklable(self):
        return threading.Lock()

    def double_in_place(self, a: np.ndarray) -> None:
        a *= 2

    def burn(self, s: float) -> None:
        t = time.process_time()
        while time.process_time() - t < s:
            pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is not alive
        return f.read().split()[2] != "Z"


def test_calls_run_in_a_child_in_order_on_its_own_copy():
    c = Counter()
    w = ForkedWorker(c, "test-worker")
    try:
        pend = [w.submit("add", k) for k in (1, 2, 3)]
        total = w.submit(np.sum, np.arange(10.0))  # a module-level function, by reference
        big = w.submit("total", np.ones((16384, 14)))  # a replay block's size crosses whole
        assert pend[2].result() == (6, w.pid)  # reading a later reply first keeps the earlier ones
        assert [p.result()[0] for p in pend] == [1, 3, 6]
        assert w.pid != os.getpid()
        assert total.result() == 45.0 and big.result() == 16384 * 14
        assert c.n == 0  # the parent's object is untouched: the child works on its copy
    finally:
        w.close()
    assert not _alive(w.pid)


def test_an_error_in_the_child_is_raised_by_result_and_the_worker_goes_on():
    w = ForkedWorker(Counter(), "test-worker")
    try:
        bad, good = w.submit("fail"), w.submit("add", 5)
        with pytest.raises(ValueError, match="bad block at sample 7"):
            bad.result()
        assert good.result()[0] == 5
        with pytest.raises(RuntimeError, match="unpicklable"):  # a reply that does not pickle says which call
            w.submit("unpicklable").result()
        assert w.submit("add", 1).result()[0] == 6
    finally:
        w.close()


def test_a_dead_child_raises_workerdied_not_a_hang():
    w = ForkedWorker(Counter(), "test-worker")
    try:
        assert w.submit("add", 1).result()[0] == 1
        os.kill(w.pid, signal.SIGKILL)
        t0 = time.monotonic()
        with pytest.raises(WorkerDied, match=r"test-worker: the worker process ended \(exit code -9: killed by SIGKILL, "
                                             r"the system's out-of-memory killer or a kill -9\)"):
            w.submit("add", 1).result()
        assert time.monotonic() - t0 < 5
    finally:
        w.close()
    w = ForkedWorker(Counter(), "test-worker")  # another signal is named as it is
    try:
        os.kill(w.pid, signal.SIGTERM)
        with pytest.raises(WorkerDied, match=r"\(exit code -15: killed by SIGTERM\)") as died:
            w.submit("add", 1).result()
        # one of gvt's runtime failures: any verb that ran the worker says it in one line and exits 1 (daq/cli run())
        assert isinstance(died.value, GvtError) and died.value.exit_code == 1
    finally:
        w.close()


def test_close_stops_a_busy_child_and_ctrl_c_is_the_parents():
    w = ForkedWorker(Counter(), "test-worker")
    os.kill(w.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the whole group: the child ignores it
    assert w.submit("add", 2).result()[0] == 2
    w.submit("sleep", 30.0)
    t0 = time.monotonic()
    w.close(timeout_s=0.5)  # it does not finish a 30 s call: terminated after the timeout
    assert time.monotonic() - t0 < 3
    assert not _alive(w.pid)


def test_a_ctrl_c_in_the_childs_first_moments_does_not_kill_it(tmp_path):
    """The child ignores SIGINT from its first instruction: a Ctrl-C that reached it before its loop had set SIG_IGN
    killed it with a KeyboardInterrupt (make test beside 4 hogs). multiprocessing's after-fork hook holds the child
    (it says so in a file) before its loop starts, and the Ctrl-C lands there every time."""
    import multiprocessing.util

    flag = tmp_path / "held"

    class Hold:
        pass

    def hold_child(_h) -> None:  # in the child, before _serve
        flag.touch()
        time.sleep(0.5)

    hold = Hold()
    multiprocessing.util.register_after_fork(hold, hold_child)
    try:
        w = ForkedWorker(Counter(), "test-worker")
    finally:
        del hold  # later forks (other tests) are not held
    try:
        t0 = time.monotonic()
        while not flag.exists() and time.monotonic() - t0 < 30:
            time.sleep(0.005)
        os.kill(w.pid, signal.SIGINT)
        assert w.submit("add", 2).result()[0] == 2 and _alive(w.pid)
    finally:
        w.close()


def test_arrays_cross_in_shared_slots_never_overwritten_while_a_call_reads_them():
    """Two slots: the first two arrays wait in them, the third and a too-large one cross the pipe (the slots' calls
    are unanswered), the fifth reuses a slot answered meanwhile; the child's view is read-only (it must not keep or
    change what the parent will overwrite)."""
    w = ForkedWorker(Counter(), "test-worker", slot_bytes=8 * 10000, slots=2)
    try:
        pend = [w.submit("total", np.full(10000, float(k))) for k in range(3)]
        big = w.submit("total", np.ones(50000))
        assert w._slot_user == pend[:2]  # the first two in the slots; the third and the large one through the pipe
        assert [p.result() for p in pend] == [0.0, 10000.0, 20000.0] and big.result() == 50000.0
        assert w.submit("total", np.full(10000, 7.0)).result() == 70000.0
        with pytest.raises(ValueError, match="read-only"):
            w.submit("double_in_place", np.ones(10000)).result()
    finally:
        w.close()


def test_close_without_waiting_is_collected_by_reap():
    w = ForkedWorker(Counter(), "test-worker", slot_bytes=1 << 17)
    assert w.submit("total", np.ones(10000)).result() == 10000.0  # through a shared slot
    w.close(wait=False)
    reap()
    assert w._proc.exitcode == 0 and not _alive(w.pid)


def test_workers_closed_without_waiting_do_not_pile_up_between_reaps():
    """A long-lived process (a campaign, a service replaying log after log) that never calls reap(): each close
    collects the workers that ended since, so the list holds at most the ones still ending, and no zombie stays."""
    import analysis.forked_worker as fw

    reap()
    ended = []
    for _ in range(4):
        w = ForkedWorker(Counter(), "test-worker")
        w.close(wait=False)
        ended.append(w._proc)
        t0 = time.monotonic()  # until it ended: waitid with WNOWAIT sees the exit without collecting it
        while os.waitid(os.P_PID, w.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None and time.monotonic() - t0 < 30:
            time.sleep(0.01)
    last = ForkedWorker(Counter(), "test-worker")
    last.close(wait=False)
    assert [p for p, _t in fw._stopping] == [last._proc], fw._stopping
    assert all(p.exitcode == 0 for p in ended)  # collected: not zombies
    reap()


def test_can_fork_only_with_this_thread_alone():
    assert can_fork() == (threading.active_count() == 1)
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not can_fork()
    finally:
        stop.set()
        t.join()


@pytest.mark.parametrize("answered_s", [0.0, 0.3])
def test_the_operator_says_when_its_seed_worker_dies_and_closes_without_hanging(answered_s):
    """The pipelined operator's seed-lane process killed mid-run (out of memory, a user's kill), at once or after it
    answered a block still in flight: the next feed that needs it raises WorkerDied naming the worker, and close()
    returns at once without raising it again; nothing waits forever (issue 30 item 3)."""
    from analysis.model.rigs import open_rig
    from analysis.operator import AnalysisOperator, RigModel
    from drivers.blocks import SampleBlock

    rig = open_rig("beam_ch4_exp")
    res = rig.simulator.run(rig.hammer_force(), 1.0, rig.sample_rate)
    fs = rig.sample_rate
    data = np.column_stack([res.force[0], res.acceleration[0]]).astype(np.float32)
    chans = (rig.hammer.name, *(s.name for s in rig.sensors))
    op = AnalysisOperator(RigModel.from_rig(rig), chans, fs, pipelined=True, seed_process=True)
    blk = 4096
    op.feed(SampleBlock("dev0", 0, fs, chans, data[:blk]))
    op.feed(SampleBlock("dev0", blk, fs, chans, data[blk : 2 * blk]))  # one block's results in flight
    time.sleep(answered_s)
    pid = op._seed_proc.pid
    os.kill(pid, signal.SIGKILL)  # the next submit may still reach it (a race, as with a real kill): either way
    t0 = time.monotonic()
    with pytest.raises(WorkerDied, match="gvt-seed-lane: the worker process ended"):
        for s in range(2 * blk, data.shape[0], blk):
            op.feed(SampleBlock("dev0", s, fs, chans, data[s : s + blk]))
        op.finish()
    op.close()
    reap()
    assert time.monotonic() - t0 < 10 and op._seed_proc is None and not _alive(pid)


def test_a_feed_after_close_starts_fresh_lanes_not_a_worker_forked_from_stale_state():
    """The operator's seed-lane state lives in its worker process; after close the parent's copy is the one from the
    fork. A later feed must start the lanes afresh (as a new stream would), giving what a new operator gives."""
    from analysis.model.rigs import open_rig
    from analysis.operator import AnalysisOperator, RigModel
    from drivers.blocks import SampleBlock

    rig = open_rig("beam_ch4_exp")
    fs = rig.sample_rate
    res = rig.simulator.run(rig.hammer_force(), 1.0, fs)
    data = np.column_stack([res.force[0], res.acceleration[0]]).astype(np.float32)
    chans = (rig.hammer.name, *(s.name for s in rig.sensors))
    model = RigModel.from_rig(rig)

    def rq_after(op: AnalysisOperator, start: int) -> list:
        got: list = []
        op.emit = lambda t, o: got.append((o["start"], o["rq_hz"])) if t == "/analysis/rq" else None
        for s in range(start, data.shape[0], 4096):
            op.feed(SampleBlock("dev0", s, fs, chans, data[s : s + 4096]))
        op.finish()
        return got

    op = AnalysisOperator(model, chans, fs, pipelined=True, seed_process=True)
    for s in range(0, 8192, 4096):
        op.feed(SampleBlock("dev0", s, fs, chans, data[s : s + 4096]))
    op.close()
    later = rq_after(op, 8192)
    fresh = rq_after(AnalysisOperator(model, chans, fs), 8192)
    reap()
    assert len(later) > 10 and later == fresh


def test_balance_says_which_side_used_more_cpu_since_the_fork():
    """ForkedWorker.balance (where the operator places an event's lock fit): the child's CPU as its answers report it
    minus this process's. Oracle: the test burns CPU on one side, then the other (0.3 s each; a sleep costs none)."""
    w = ForkedWorker(Counter(), "test-worker")
    try:
        w.submit("burn", 0.3).result()
        assert w.balance() > 0.15  # the child burnt 0.3 s, this side only waited
        Counter().burn(0.6)
        assert w.balance() < -0.15  # now this side has burnt 0.6 s against the child's 0.3 s
        w.submit("sleep", 0.2).result()
        assert w.balance() < -0.15  # a sleeping child uses no CPU
    finally:
        w.close()
