"""CAN / CAN FD driver on python-can's in-process virtual bus: device → CanSimNode → CanDriver → blocks."""

from __future__ import annotations

import itertools
import os
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.base import LinkBudgetError, make_driver
from drivers.blocks import BlockStatus
from drivers.can.dbc_map import load_layouts
from drivers.can.driver import DEFAULT_DBC, CanConfig, CanDriver, budget_frames_per_s, channels_budget
from drivers.can.sim_node import CanSimNode
from drivers.sim.device import HitSchedule, SimulatedDevice
from drivers.sim.faults import Faults
from drivers.sim.faults import merge_ranges as merged

FUZZ_EXAMPLES = int(os.environ.get("GVT_FUZZ_EXAMPLES", 500))  # make fuzz: 200 000 (make test: 500, 2 CPU-s: its budget)
_bus_names = (f"gvt-test-{i}" for i in itertools.count())


@pytest.fixture(scope="module")
def device(rigs):
    return SimulatedDevice(rigs("beam_ch4_exp"), HitSchedule.every(2.0, [200.0, 800.0]), duration=12.0, block_size=256, seed=1)


def run_link(device, message: str, seconds: float, faults: Faults | None = None, **cfg):
    """Run node and driver for ``seconds`` of device time; return (driver, node, blocks)."""
    channel = next(_bus_names)
    fd = load_layouts(DEFAULT_DBC, [message])[0].is_fd
    drv = make_driver("can", {"channel": channel, "fd": fd, "messages": [message], **cfg})
    drv.open()
    node = CanSimNode(device, faults, message=message, channel=channel, fd=fd)
    node.start()
    stopper = threading.Timer(seconds, node.stop)
    stopper.start()
    blocks = []
    try:
        while node._thread is not None and node._thread.is_alive():
            blocks += list(drv.blocks(timeout=0.25))
        deadline = time.monotonic() + 5
        while drv.stats.frames_ok < node.frames_sent and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        stopper.cancel()
        node.stop()
        drv.close()
    blocks += list(drv.blocks(timeout=1))
    assert node.error is None
    return drv, node, blocks


def check_blocks(device, node, blocks, *, lost=()):
    """Blocks are exact in index, equal to the device within int16 quantisation, and lose only ``lost``."""
    lay = node.layout
    assert blocks, "no block received"
    idx = [b.first_index for b in blocks]
    assert idx == sorted(idx)
    got = sum(b.n_samples for b in blocks)
    end = blocks[-1].end_index
    assert got + sum(b - a for a, b in lost) == end
    assert end <= node.samples_done
    for b in blocks:
        assert b.channels == lay.channels
        ref = device.samples(b.first_index, b.end_index)[:, node.columns]
        err = np.abs(b.data.astype(np.float64) - ref)
        assert np.all(err <= lay.scales / 2 * (1 + 1e-6) + 1e-4 * np.abs(ref)), err.max(axis=0)
    return got, end


# --- DBC and decoder ---------------------------------------------------------------------------
def test_dbc_layouts():
    lays = {lay.name: lay for lay in load_layouts(DEFAULT_DBC)}
    fd, cc = lays["GVT_FD3"], lays["GVT_CC1"]
    assert (fd.is_fd, fd.length, fd.counter_bits, fd.spf, fd.channels) == (True, 64, 32, 10, ("hammer", "a01", "a02"))
    assert (cc.is_fd, cc.length, cc.counter_bits, cc.spf, cc.channels) == (False, 8, 16, 3, ("hammer",))
    assert fd.units == ("N", "m/s^2", "m/s^2") and fd.fast and cc.fast


def test_fast_decoder_equals_cantools():
    rng = np.random.default_rng(7)
    for lay in load_layouts(DEFAULT_DBC):
        frames = rng.integers(0, 256, (500, lay.length), dtype=np.uint8)
        batch = lay.decode_frames(frames.tobytes(), len(frames))
        for i, row in enumerate(frames):
            c_ref, x_ref = lay.decode_cantools(row.tobytes())
            c, x = lay.decode_fast(row.tobytes())
            assert c == c_ref
            np.testing.assert_array_equal(x, x_ref)
            np.testing.assert_array_equal(batch[i * lay.spf : (i + 1) * lay.spf], x_ref)
        raw = rng.integers(-32768, 32768, (4 * lay.spf, lay.n_channels))
        enc = lay.encode_frames(65534, raw)
        for i in range(4):
            assert enc[i].tobytes() == lay.encode(65534 + i, raw[i * lay.spf : (i + 1) * lay.spf])
            assert enc[i].tobytes() == bytes(
                lay.message.encode(
                    {
                        "FrameCounter": (65534 + i) % lay.counter_modulus,
                        **{
                            f"{ch}_{k}": int(raw[i * lay.spf + k, j]) for j, ch in enumerate(lay.channels) for k in range(lay.spf)
                        },
                    },
                    scaling=False,
                )
            )


# --- end to end on the virtual bus -------------------------------------------------------------------
def test_fd_three_channels_10s_no_loss(device):
    drv, node, blocks = run_link(device, "GVT_FD3", 10.0)
    got, end = check_blocks(device, node, blocks)
    assert end == node.samples_done >= 10 * 16384 - 2 * 256
    assert got == end and blocks[0].first_index == 0
    assert drv.stats.gaps == [] and drv.stats.lost_samples == 0 and drv.stats.frames_bad == 0
    assert drv.stats.frames_ok == node.frames_sent == end // 10


def test_classic_one_channel_and_raw_blf_log(device, tmp_path):
    log = tmp_path / "raw.blf"
    drv, node, blocks = run_link(device, "GVT_CC1", 2.5, raw_log=str(log))
    got, end = check_blocks(device, node, blocks)
    assert got == end == node.samples_done and drv.stats.gaps == []
    assert drv.stats.frames_ok == node.frames_sent == end // 3
    frames = list(can.BLFReader(str(log)))
    assert len(frames) == node.frames_sent and frames[0].arbitration_id == 0x101 and len(frames[0].data) == 8


def test_one_percent_frames_dropped_reported_exactly(device):
    faults = Faults(frame_drop_rate=0.01, seed=11)
    drv, node, blocks = run_link(device, "GVT_FD3", 4.0, faults)
    end = blocks[-1].end_index
    injected = merged(r for r in faults.injected if r[1] <= end)
    assert len(injected) > 20
    check_blocks(device, node, blocks, lost=injected)
    assert merged(drv.stats.gaps) == injected
    assert drv.stats.lost_samples == sum(b - a for a, b in injected)
    assert drv.stats.frames_bad == 0 and drv.can.rejected_frames == 0
    gap_blocks = [b for b in blocks if b.status & 1]
    assert len(gap_blocks) == len(drv.stats.gaps)


def test_disconnect_2s_gap_reported_and_carries_on(device):
    faults = Faults(disconnect_at_s=1.0, disconnect_for_s=2.0)
    drv, node, blocks = run_link(device, "GVT_FD3", 4.5, faults)
    injected = merged(faults.injected)
    assert len(injected) == 1 and abs((injected[0][1] - injected[0][0]) - 2 * 16384) <= 2 * node.layout.spf
    check_blocks(device, node, blocks, lost=injected)
    assert drv.stats.gaps == injected
    assert drv.stats.timeouts >= 1  # the silence was noticed
    assert blocks[-1].end_index > injected[0][1] + 16384  # and it carried on after the link came back
    kinds = [e.kind for e in drv.drain_events()]
    assert "gap" in kinds and "timeout" in kinds


class FlakyBus(can.BusABC):
    """A bus that delivers queued frames and then raises like an unplugged adapter / bus-off."""

    def __init__(self, frames, fail_after: int | None) -> None:
        super().__init__(channel="flaky")
        self.frames = list(frames)
        self.fail_after = fail_after
        self.delivered = 0
        self.channel_info = "flaky"

    def _recv_internal(self, timeout):
        if self.fail_after is not None and self.delivered >= self.fail_after:
            raise can.CanOperationError("controller went bus-off")
        if not self.frames:
            time.sleep(min(timeout or 0.01, 0.01))
            return None, False
        self.delivered += 1
        return self.frames.pop(0), False

    def send(self, msg, timeout=None):  # pragma: no cover - receive-only
        raise NotImplementedError


def _frames(lay, first: int, n: int):
    raw = np.arange(n * lay.spf * lay.n_channels).reshape(n * lay.spf, lay.n_channels) % 1000
    enc = lay.encode_frames(first, raw)
    return [can.Message(arbitration_id=lay.frame_id, is_extended_id=False, is_fd=lay.is_fd, data=r.tobytes()) for r in enc]


def test_reconnect_with_backoff_when_bus_raises():
    cfg = CanConfig(fd=True, messages=["GVT_FD3"], reconnect_initial_s=0.01, reconnect_max_s=0.03, flush_s=0.01)
    lay = load_layouts(DEFAULT_DBC, ["GVT_FD3"])[0]
    attempts = []

    def factory():
        attempts.append(time.monotonic())
        if len(attempts) == 1:
            return FlakyBus(_frames(lay, 0, 50), fail_after=50)
        if len(attempts) <= 4:
            raise OSError("adapter not found")
        return FlakyBus(_frames(lay, 60, 40), fail_after=None)

    drv = CanDriver(cfg, bus_factory=factory)
    with drv:
        blocks = []
        deadline = time.monotonic() + 5
        while sum(b.n_samples for b in blocks) < 900 and time.monotonic() < deadline:
            blocks += list(drv.blocks(timeout=0.1))
    blocks += list(drv.blocks(timeout=1))
    assert drv.stats.reconnects == 1 and len(attempts) == 5
    assert drv.can.backoff_waits == [0.01, 0.02, 0.03, 0.03]
    assert drv.can.bus_off == 1
    assert drv.stats.gaps == [(500, 600)]
    assert sum(b.n_samples for b in blocks) == 900
    after = [b for b in blocks if b.first_index >= 600]
    assert after[0].status & 1 and after[0].status & 16  # GAP_BEFORE | RECONNECT
    kinds = [e.kind for e in drv.drain_events()]
    assert kinds.count("reconnect_failed") == 3 and "reconnect" in kinds and "link_error" in kinds


def test_error_frames_and_bus_off_counted():
    drv = CanDriver(CanConfig(fd=True, messages=["GVT_FD3"]))
    drv.handle(can.Message(is_error_frame=True, arbitration_id=0x004, data=bytes(8)), 0.0)
    drv.handle(can.Message(is_error_frame=True, arbitration_id=0x040, data=bytes(8)), 0.0)
    drv.handle(can.Message(arbitration_id=0x7FF, data=b"x"), 0.0)
    assert (drv.can.error_frames, drv.can.bus_off, drv.can.ignored_frames, drv.stats.frames_bad) == (2, 1, 1, 2)


# --- link budget --------------------------------------------------------------------------------------
def test_link_budget_refuses_full_rig_with_numbers():
    assert 8_700 < budget_frames_per_s(False) < 8_850  # landscape.md §3.3: 8,771 frames/s
    assert 9_500 < budget_frames_per_s(True) < 10_000  # ≈ 9.5–10 k frames/s
    with pytest.raises(LinkBudgetError, match=r"needs 81,920 frames/s.*carries 8,77\d frames/s.*15 ch × 16,384 Hz"):
        channels_budget(15, 16384, fd=False).check(0.7)
    with pytest.raises(LinkBudgetError, match=r"needs 8,192 frames/s.*carries 9,8\d\d frames/s \(8\d %"):
        channels_budget(15, 16384, fd=True).check(0.7)
    channels_budget(3, 16384, fd=True).check(0.7)
    channels_budget(1, 16384, fd=False).check(0.7)
    # a driver config that selects too much refuses on open, before touching the bus
    drv = make_driver("can", {"messages": ["GVT_CC1", "GVT_CC1A"], "channel": next(_bus_names)})
    with pytest.raises(LinkBudgetError, match=r"needs 10,923 frames/s"):
        drv.open()
    assert make_driver("can", {"fd": True, "messages": ["GVT_FD3"]}).link_budget().utilisation < 0.2


def test_config_is_strict_and_fd_needed():
    with pytest.raises(Exception, match="extra"):
        make_driver("can", {"bogus": 1})
    from drivers.base import DriverError

    with pytest.raises(DriverError, match="fd = true"):
        make_driver("can", {"messages": ["GVT_FD3"]}).open()


# --- fuzz ----------------------------------------------------------------------------------------------
_LAYS = load_layouts(DEFAULT_DBC)
_IDS = [lay.frame_id for lay in _LAYS]


@st.composite
def can_frames(draw):
    kind = draw(st.sampled_from(["random", "known_id", "mutated"]))
    if kind == "mutated":
        lay = draw(st.sampled_from(_LAYS))
        counter = draw(st.integers(0, 40))
        n = lay.spf * lay.n_channels
        raw = np.frombuffer(draw(st.binary(min_size=2 * n, max_size=2 * n)), "<i2").reshape(lay.spf, lay.n_channels)
        data = bytearray(lay.encode(counter, raw))
        for _ in range(draw(st.integers(0, 3))):
            op = draw(st.sampled_from(["flip", "truncate", "extend"]))
            if op == "flip" and data:
                i = draw(st.integers(0, len(data) - 1))
                data[i] ^= 1 << draw(st.integers(0, 7))
            elif op == "truncate":
                data = data[: draw(st.integers(0, len(data)))]
            elif len(data) < 64:
                data += draw(st.binary(min_size=1, max_size=64 - len(data)))
        return can.Message(
            arbitration_id=lay.frame_id,
            is_extended_id=draw(st.booleans()) and draw(st.booleans()),
            is_fd=draw(st.booleans()) if len(data) <= 8 else True,
            data=bytes(data),
            is_remote_frame=draw(st.integers(0, 20)) == 0,
        )
    ext = draw(st.booleans())
    fid = draw(st.sampled_from(_IDS)) if kind == "known_id" else draw(st.integers(0, (1 << 29) - 1 if ext else 0x7FF))
    data = draw(st.binary(max_size=64))
    return can.Message(
        arbitration_id=fid,
        is_extended_id=ext,
        is_fd=len(data) > 8 or draw(st.booleans()),
        data=data,
        is_error_frame=draw(st.integers(0, 30)) == 0,
    )


_fuzz_driver = CanDriver(CanConfig(fd=True, block_samples=30, queue_blocks=100_000))
_fuzz_state = {"t": 0.0, "accepted": 0}


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(can_frames(), min_size=1, max_size=6), st.floats(0, 3))
def test_fuzz_frame_decoder(frames, dt):
    drv = _fuzz_driver
    for msg in frames:
        _fuzz_state["t"] += dt
        for lay in _LAYS:  # the fast decoder agrees with cantools on anything the layout accepts
            if lay.accepts(msg):
                _fuzz_state["accepted"] += 1
                c, x = lay.decode_fast(msg.data)
                c_ref, x_ref = lay.decode_cantools(msg.data)
                assert c == c_ref
                np.testing.assert_array_equal(x, x_ref)
        drv.handle(msg, _fuzz_state["t"])
    drv._flush_all()
    streams = drv.streams
    while not drv._blocks.empty():
        b = drv._blocks.get_nowait()
        lay = streams[b.stream]
        assert b.channels == lay.channels and b.n_samples % lay.spf == 0 and b.n_samples > 0
        assert np.all(np.isfinite(b.data))
        assert np.all(np.abs(b.data) <= 32768 * lay.scales * (1 + 1e-6))
        seg = [s for s in drv.stats.segments if s.stream == b.stream and s.stream_first <= b.first_index][-1]
        assert (b.first_index - seg.stream_first + seg.device_first) % lay.spf == 0  # device index = counter x spf
        assert b.end_index * 1e9 / b.sample_rate < 2**62  # whatever the counters said, a log can time it
    emitted = drv.stats.samples
    assert emitted <= sum(lay.spf for lay in _LAYS) * drv.stats.frames_ok
    assert drv.stats.frames_ok <= _fuzz_state["accepted"]


def test_fast_decode_equals_cantools_on_random_frames():
    """The vectorised decoder and cantools read the same 200 random FD frames to the same samples (float32,
    so exact: both compute raw * scale + offset from the same integers). Their speeds are compared in
    bench/bench_can.py, not here: a wall-clock ratio on a shared 2-core machine is a coin toss."""
    lay = load_layouts(DEFAULT_DBC, ["GVT_FD3"])[0]
    frames = np.random.default_rng(1).integers(0, 256, (200, 64), dtype=np.uint8).tobytes()
    fast = lay.decode_frames(frames, 200)
    ref = np.concatenate([lay.decode_cantools(frames[64 * i : 64 * (i + 1)])[1] for i in range(200)])
    assert fast.shape == ref.shape == (200 * lay.spf, lay.n_channels)
    np.testing.assert_allclose(fast, ref, rtol=1e-6, atol=float(np.max(np.abs(lay.scales))) * 1e-3)
    counters = [lay.decode_cantools(frames[64 * i : 64 * (i + 1)])[0] for i in range(200)]
    assert counters == [lay.counter_of(frames[64 * i : 64 * (i + 1)]) for i in range(200)]
    assert Path(DEFAULT_DBC).exists()


# --- restarts, wild counters, stalls, the connect line, config ---------------------------------------
def _device_pairs(drv, blocks):
    return [(drv.stats.device_index(b.stream, b.first_index), b) for b in blocks]


def test_node_restart_is_a_new_segment_never_stitched(device):
    faults = Faults(restart_at_s=1.0, restart_down_s=0.5)
    drv, node, blocks = run_link(device, "GVT_FD3", 2.6, faults)
    (rec,) = faults.restarts
    assert drv.stats.restarts == 1 and drv.stats.rejected_blocks == 0 and drv.can.rejected_frames == 0
    k = next(i for i, b in enumerate(blocks) if b.status & BlockStatus.RESTART)
    old, new = blocks[:k], blocks[k:]
    assert old[0].first_index == 0 and old[-1].end_index == rec.delivered
    seg = drv.stats.segments[-1]
    assert (seg.number, seg.device_first, seg.stream_first) == (1, 0, new[0].first_index)
    assert abs(seg.stream_first - rec.stream_index(0, 16384)) <= 0.2 * 16384  # the host clock (as tests/test_serial.py)
    for part in (old, new):
        assert all(b.first_index == a.end_index for a, b in itertools.pairwise(part))
    assert drv.stats.gaps == [(rec.delivered, seg.stream_first)] and drv.stats.lost_samples == seg.estimated_gap
    lay = node.layout
    for d, b in _device_pairs(drv, blocks):  # the data before and after are the device's, intact
        ref = device.samples(d, d + b.n_samples)[:, node.columns]
        assert np.all(np.abs(b.data.astype(np.float64) - ref) <= lay.scales / 2 * (1 + 1e-6) + 1e-4 * np.abs(ref))
    assert new[-1].end_index - new[0].first_index >= 0.9 * 16384 - 512  # it carried on after the restart


def test_one_shot_stall_loses_nothing_on_can(device):
    faults = Faults(stall_at_s=0.5, stall_for_s=0.5)
    drv, node, blocks = run_link(device, "GVT_FD3", 1.6, faults, silence_timeout_s=0.3)
    got, end = check_blocks(device, node, blocks)
    assert got == end == node.samples_done and blocks[0].first_index == 0
    assert drv.stats.gaps == [] and drv.stats.frames_bad == 0 and drv.stats.rejected_blocks == 0
    assert drv.stats.timeouts >= 1  # the node really went quiet for longer than 0.3 s


def _drive(drv, lay, counters, t0, dt=10 / 16384):
    t = t0
    for c in counters:
        for m in _frames(lay, c, 1):
            drv.handle(m, t)
        t += dt
    return t


def test_counter_restart_rebases_and_a_wild_counter_is_rejected():
    lay = load_layouts(DEFAULT_DBC, ["GVT_FD3"])[0]
    drv = CanDriver(CanConfig(fd=True, messages=["GVT_FD3"], block_samples=100))
    t = _drive(drv, lay, range(30), 0.0)
    t = _drive(drv, lay, [10**6], t)  # one wild counter: held, then rejected
    t = _drive(drv, lay, range(30, 40), t)
    t = _drive(drv, lay, range(0, 20), t + 0.5)  # the node restarted: its counter went back to 0
    drv._flush_all()
    drv._reject_suspects()
    blocks = []
    while not drv._blocks.empty():
        blocks.append(drv._blocks.get_nowait())
    assert drv.stats.rejected_blocks == 1 and drv.can.rejected_frames == 1 and drv.stats.restarts == 1
    assert sum(b.n_samples for b in blocks) == (40 + 20) * lay.spf  # every good frame, once
    (seg,) = [s for s in drv.stats.segments if s.number == 1]
    assert seg.device_first == 0 and seg.stream_first >= 400 + 0.45 * 16384
    flags = [bool(b.status & BlockStatus.RESTART) for b in blocks]
    assert flags.count(True) == 1 and blocks[flags.index(True)].first_index == seg.stream_first
    assert [b.first_index for b in blocks if b.first_index < 400] == [0, 100, 200, 300]  # no gap from the wild frame
    assert drv.stats.gaps == [(400, seg.stream_first)]


def test_sim_node_line_is_a_working_session_snippet(device):
    import tomllib

    channel = next(_bus_names)
    node = CanSimNode(device, message="GVT_FD3", channel=channel)
    line = node.start()
    try:
        spec = tomllib.loads(line.split("session TOML: ", 1)[1])["device"]
        assert spec["driver"] == "can" and spec["config"]["channel"] == channel
        drv = make_driver(spec["driver"], spec["config"])
        with drv:
            b = next(drv.blocks(timeout=3))
        assert b.channels == ("hammer", "a01", "a02") and b.sample_rate == 16384
    finally:
        node.stop()


def test_dbc_is_checked_with_the_config(tmp_path, monkeypatch):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=r"nope\.dbc.*not found"):
        CanConfig(dbc=str(tmp_path / "nope.dbc"))
    bad = tmp_path / "bad.dbc"
    bad.write_text("this is not a DBC file {")
    with pytest.raises(ValidationError, match=r"bad\.dbc.*cannot be used"):
        CanConfig(dbc=str(bad))
    with pytest.raises(ValidationError, match="NOPE"):
        CanConfig(messages=["NOPE"])
    with pytest.raises(ValidationError, match="finite"):
        CanConfig(plausible_jump_s=float("inf"))
    monkeypatch.chdir(tmp_path)
    assert CanConfig(dbc="configs/can/gvt_sim_node.dbc").dbc == str(DEFAULT_DBC)  # root-relative works anywhere
