"""The simulated devices send on their own schedule, not a host timer's slack later (drivers/sim/timing.py).

Why it matters: the two-device clock offset is the difference of two arrival-time floors (daq/timeline.py). With the
default 50 µs slack a quiet host woke most sends ~50 µs late and only the odd one on time, so each simulated device's
floor was set by its luck: 3 s two-device sessions on a quiet host were off by up to 0.93 samples (10 runs, rms 0.41)
and by 1.20 samples in a 60 s one; with 1 ns slack within 0.17 samples (10 runs, rms 0.10) (docs/decisions.md D129).
"""

from __future__ import annotations

import sys
import threading
import time

import pytest

from drivers.sim.timing import SLACK_NS, precise_wakeups, timer_slack_ns

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="timer slack is a Linux prctl")


def _in_thread(fn):
    out: list = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join()
    return out[0]


def _set_by_its_thread(sim, timeout_s: float = 10.0) -> bool | None:
    """What a simulator's sending thread got from :func:`precise_wakeups` once it started (None: not started yet)."""
    deadline = time.monotonic() + timeout_s
    while sim.precise_wakeups is None and time.monotonic() < deadline:
        time.sleep(0.01)
    return sim.precise_wakeups


@linux
def test_precise_wakeups_sets_the_calling_threads_slack_and_no_other():
    before = timer_slack_ns()
    assert before is not None and before > SLACK_NS  # the kernel's default for a normal thread (50 µs unless changed)
    ok, slack = _in_thread(lambda: (precise_wakeups(), timer_slack_ns()))
    assert ok is True and slack == SLACK_NS
    assert timer_slack_ns() == before  # per thread: the recorder's own threads keep theirs
    assert _in_thread(timer_slack_ns) == before  # and a new thread inherits the creator's, not the device's


@linux
def test_the_serial_and_can_simulators_send_from_a_precise_thread(rigs):
    from drivers.can.sim_node import CanSimNode
    from drivers.serial.sim_server import SerialSimServer
    from drivers.sim.device import HitSchedule, SimulatedDevice

    device = SimulatedDevice(rigs("beam_ch4_exp"), HitSchedule.every(2.0, [200.0]), duration=1.0, block_size=256, seed=1)
    srv = SerialSimServer(device, None, fmt="int24", frame_samples=64)
    srv.start(hold=True)
    try:
        srv.go()
        assert _set_by_its_thread(srv) is True
    finally:
        srv.stop()
    node = CanSimNode(device, None, message="GVT_FD3", channel="gvt-test-sim-timing", fd=True)
    node.start()
    try:
        assert _set_by_its_thread(node) is True
    finally:
        node.stop()


@linux
def test_the_paced_in_process_simulator_reads_from_a_precise_thread():
    """The paced in-process driver (drivers/sim/driver.py) waits for each block as the pty and CAN simulators do, so
    its reading thread asks for 1 ns slack too; unpaced, nothing waits and nothing is asked."""
    from drivers.sim.driver import SimConfig, SimDriver

    for paced, want in ((True, True), (False, False)):
        drv = SimDriver(SimConfig(stream="dev0", block_size=256, duration=0.5, physics_seconds=0.5, paced=paced))
        assert drv.precise_wakeups is None  # not started yet
        with drv:
            assert _set_by_its_thread(drv) is want
            assert sum(b.n_samples for b in drv.blocks(timeout=10)) > 0


def test_the_offset_tests_know_when_the_host_refuses_the_slack(monkeypatch):
    """The one-sample offset bar of tests/test_load_matrix.py and tests/test_two_devices.py holds where the simulated
    devices wake on time; a host whose prctl refuses (a seccomp profile, another OS) is seen, and those tests then say
    so in their failure messages instead of failing by chance."""
    import drivers.sim.timing as timing

    from .hogs import sim_devices_wake_precisely

    assert sim_devices_wake_precisely() is sys.platform.startswith("linux")
    monkeypatch.setattr(timing, "_prctl", lambda: None)
    assert sim_devices_wake_precisely() is False
