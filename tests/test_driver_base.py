"""Driver base: exact gap accounting, a dying thread is reported, bounded queues, link budget, device clock."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.base import Driver, DriverConfig, DriverError, DriverEvent, LinkBudget, LinkBudgetError
from drivers.blocks import BlockStatus, SampleBlock
from drivers.sim.device import HitSchedule, SimulatedDevice
from drivers.sim.faults import Faults


class ListDriver(Driver):
    """A driver whose 'link' is a list of (first_index, n) blocks, optionally failing at the end."""

    name = "list"

    def __init__(self, config, blocks, fail_with=None, budget=(1.0, 10.0)):
        super().__init__(config)
        self._items = blocks
        self._fail = fail_with
        self._budget = budget

    def link_budget(self):
        return LinkBudget(self._budget[0], self._budget[1], "B/s", "test link")

    def _connect(self):
        pass

    def _run(self):
        for first, n in self._items:
            self._emit(SampleBlock("d", first, 100.0, ("a",), np.full((n, 1), first, np.float32)))
        if self._fail is not None:
            raise self._fail


def test_gaps_are_reported_exactly_and_flagged():
    drv = ListDriver(DriverConfig(), [(0, 10), (10, 10), (25, 5), (30, 10), (50, 1)])
    with drv:
        got = list(drv.blocks(timeout=5))
    assert [b.first_index for b in got] == [0, 10, 25, 30, 50]
    assert [bool(b.status & BlockStatus.GAP_BEFORE) for b in got] == [False, False, True, False, True]
    assert drv.stats.gaps == [(20, 25), (40, 50)] and drv.stats.lost_samples == 15
    gaps = [e for e in drv.drain_events() if e.kind == "gap"]
    assert [(e.start_index, e.end_index, e.count) for e in gaps] == [(20, 25, 5), (40, 50, 10)]


def test_a_block_going_back_in_time_is_dropped_and_counted():
    drv = ListDriver(DriverConfig(), [(0, 10), (5, 10), (10, 10)])
    with drv:
        got = list(drv.blocks(timeout=5))
    assert [b.first_index for b in got] == [0, 10]
    assert drv.stats.frames_bad == 1


def test_a_dying_driver_thread_is_reported_to_the_owner_after_its_blocks():
    drv = ListDriver(DriverConfig(), [(0, 10), (10, 10)], fail_with=OSError("device unplugged"))
    drv.open()
    seen = []
    with pytest.raises(DriverError, match="device unplugged"):
        for b in drv.blocks(timeout=5):
            seen.append(b.first_index)
    assert seen == [0, 10]
    drv.close()


def test_owner_not_reading_is_an_overrun_not_unbounded_memory():
    drv = ListDriver(DriverConfig(queue_blocks=4), [(k * 10, 10) for k in range(20)])
    drv.open()
    drv._thread.join(timeout=5)
    got = list(drv.blocks(timeout=1))
    drv.close()
    assert drv.stats.overruns > 0 and len(got) + drv.stats.overruns == 20
    over = [e for e in drv.drain_events() if e.kind == "overrun"]
    assert sum(e.count for e in over) == 10 * drv.stats.overruns


def test_link_budget_refuses_with_the_numbers():
    drv = ListDriver(DriverConfig(), [], budget=(950.0, 1000.0))
    with pytest.raises(LinkBudgetError, match=r"needs 950 B/s, the link carries 1,000 B/s \(95 % > 90 %\)"):
        drv.open()


def test_device_clock_is_sample_exact_and_deterministic(rigs):
    rig = rigs("beam_ch4_exp")
    dev = SimulatedDevice(rig, HitSchedule.every(1.0, [100.0]), duration=0.5, block_size=128, seed=5)
    dev.start_clock(t0=1000.0)
    for t in (0.0, 0.5, 1.0, 10.0, 3600.0):
        assert dev.samples_available(1000.0 + t) == int(t * 16384)  # after N s exactly N * fs samples
    a = dev.samples(8000, 9000)  # spans the end of the simulated 0.5 s and the rest noise after it
    b = SimulatedDevice(rig, HitSchedule.every(1.0, [100.0]), duration=0.5, block_size=128, seed=5).samples(8000, 9000)
    assert np.array_equal(a, b) and a.dtype == np.float32 and a.shape == (1000, 15)
    assert np.array_equal(dev.samples(8500, 8700), a[500:700])


def test_faults_count_merged_injections():
    f = Faults(seed=1)
    f.record(0, 10)
    f.record(5, 20)
    f.record(30, 31)
    assert f.injected_samples() == 21


def test_loss_before_the_first_block_is_reported_when_the_start_index_is_known():
    drv = ListDriver(DriverConfig(expect_first_index=0), [(30, 10), (40, 10)])
    with drv:
        got = list(drv.blocks(timeout=5))
    assert [b.first_index for b in got] == [30, 40] and drv.stats.gaps == [(0, 30)]
    joining = ListDriver(DriverConfig(), [(30, 10)])
    with joining:
        list(joining.blocks(timeout=5))
    assert joining.stats.gaps == []  # joining a running device: no bogus gap from 0


def test_sim_driver_paced_follows_the_device_clock():
    import time

    from drivers.base import make_driver

    drv = make_driver(
        "sim",
        {
            "rig": "beam_ch4_exp",
            "paced": True,
            "duration": 0.5,
            "block_size": 512,
            "channels": ["hammer", "a13"],
            "physics_seconds": 0.6,
        },
    )
    assert drv.realtime
    with drv:
        t0 = time.monotonic()
        blocks = list(drv.blocks(timeout=2))
        took = time.monotonic() - t0
    assert sum(b.n_samples for b in blocks) == 8192 and blocks[0].data.shape[1] == 2
    assert 0.4 <= took <= 10.0  # real time, not full speed (full speed: ~0.05 s); the top only says it ends
    assert not make_driver("sim", {"rig": "beam_ch4_exp"}).realtime


def test_wild_block_rejected_and_restart_makes_a_segment_through_the_driver():
    from drivers.base import Segment

    drv = ListDriver(DriverConfig(), [(0, 10), (10, 10), (10**9, 10), (20, 10), (0, 10), (10, 10)])
    with drv:
        got = list(drv.blocks(timeout=5))
    # the wild block is gone, nothing else; the restarted run (device 0..20) continues the stream after >= 1 sample
    assert [(b.first_index, b.n_samples) for b in got] == [(0, 10), (10, 10), (20, 10), (31, 10), (41, 10)]
    assert [float(b.data[0, 0]) for b in got] == [0, 10, 20, 0, 10]  # the data are the device's blocks, unchanged
    assert [b.status for b in got] == [0, 0, 0, BlockStatus.RESTART | BlockStatus.GAP_BEFORE, 0]
    s = drv.stats
    assert (s.restarts, s.rejected_blocks, s.frames_bad, s.samples) == (1, 1, 0, 50)
    assert s.gaps == [(30, 31)] and s.lost_samples == s.estimated_lost_samples == 1
    assert s.segments == [Segment("d", 0, 0, 0, 0), Segment("d", 1, 31, 0, 1)]
    ev = {e.kind: e for e in drv.drain_events()}
    bad, rs = ev["implausible_index"], ev["restart"]
    assert (bad.start_index, bad.end_index, bad.count, bad.device_start, bad.device_end) == (20, 20, 10, 10**9, 10**9 + 10)
    assert (rs.start_index, rs.end_index, rs.count, rs.device_start) == (30, 31, 1, 0)
    assert "segment 1" in rs.message and "estimated from the host clock" in rs.message and "index went to 0" in rs.message
    assert rs.as_dict()["device_start"] == 0 and "device_start" not in DriverEvent("gap", "d", 0, 1, 1).as_dict()


def test_a_suspect_still_held_when_the_driver_ends_is_rejected():
    drv = ListDriver(DriverConfig(), [(0, 10), (10, 10), (2**62, 10)])
    with drv:
        got = list(drv.blocks(timeout=5))
    assert [b.first_index for b in got] == [0, 10] and drv.stats.rejected_blocks == 1
    assert [e.device_start for e in drv.drain_events() if e.kind == "implausible_index"] == [2**62]


def test_coalesce_never_joins_two_runs():
    from drivers.blocks import coalesce

    d = np.zeros((4, 1), np.float32)
    parts = [SampleBlock("s", 0, 10.0, ("a",), d), SampleBlock("s", 4, 10.0, ("a",), d, BlockStatus.RESTART)]
    assert [b.first_index for b in coalesce(parts, 100)] == [0, 4]


def test_configs_refuse_inf_and_nan():
    from pydantic import ValidationError

    from drivers.serial.driver import SerialConfig

    with pytest.raises(ValidationError, match="finite"):
        DriverConfig(plausible_jump_s=float("nan"))
    with pytest.raises(ValidationError, match="finite"):
        SerialConfig(port="x", sample_rate=float("inf"), channels=["a"])
    with pytest.raises(ValidationError, match="finite"):
        SerialConfig(port="x", sample_rate=100, channels=["a"], read_timeout_s=float("nan"))
