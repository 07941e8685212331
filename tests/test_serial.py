"""Serial driver: protocol, decoder fuzz, link budget, and end to end over a real pty with faults."""

from __future__ import annotations

import itertools
import os
import time
from importlib.metadata import entry_points

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.base import ENTRY_POINT_GROUP, LinkBudgetError
from drivers.blocks import BlockStatus
from drivers.serial.driver import SerialConfig, SerialDriver
from drivers.serial.protocol import (
    FORMATS,
    FrameDecoder,
    LineDecoder,
    crc16_ccitt,
    crc32,
    encode_frame,
    frame_length,
)
from drivers.sim.faults import Faults
from drivers.sim.faults import merge_ranges as merge

FUZZ = int(os.environ.get("GVT_FUZZ_EXAMPLES", 1000))  # per fuzz test in make test; make fuzz runs 200 000 each


@pytest.fixture(scope="module")
def device(rigs):
    from drivers.sim.device import HitSchedule, SimulatedDevice

    return SimulatedDevice(rigs("beam_ch4_exp"), HitSchedule.every(2.0, [200.0, 800.0]), duration=12.0, block_size=256, seed=1)


def run_link(device, faults, *, n_samples, fmt="int24", frame_samples=64, timeout=5.0, arrivals=None, **server_kw):
    """Serve the device over a pty and read it with SerialDriver until sample n_samples (or timeout).
    ``arrivals``: a list to append each block's host arrival time to. The device clock starts once the port is
    open (``hold``, as a session does): pyserial flushes the input buffer on open, so frames written before would
    be lost to the test harness, not the link (on a busy host the open came after frame 0, and the first block
    read was at index 64)."""
    from drivers.serial.sim_server import SerialSimServer

    srv = SerialSimServer(device, faults, fmt=fmt, frame_samples=frame_samples, **server_kw)
    info = srv.start(hold=True)
    assert srv.path in info
    chans = [device.channels[c] for c in srv.channels]
    cfg = {"port": srv.path, "usb_cdc": True, "sample_rate": srv.fs, "channels": chans}
    if fmt == "ascii":
        cfg.update(mode="ascii", baudrate=921600, usb_cdc=False)
    else:
        cfg.update(sample_format=fmt, frame_samples=frame_samples)
    drv = SerialDriver(SerialConfig.model_validate(cfg))
    blocks = []
    try:
        with drv:
            srv.go()
            for b in drv.blocks(timeout=timeout):
                blocks.append(b)
                if arrivals is not None:
                    arrivals.append(time.monotonic())
                if b.end_index >= n_samples:
                    break
    finally:
        srv.stop()
    assert srv.error is None
    return srv, drv, blocks


def lost_before(drv, end):
    """Gaps the driver reported before sample ``end`` (it may have read on while the test stopped)."""
    return [g for g in drv.stats.gaps if g[0] < end]


def check_against_device(device, srv, blocks, fmt):
    ref_all = device.samples(0, blocks[-1].end_index * srv.decimate)[:: srv.decimate][:, srv.channels]
    tol = srv.scales * 0.51 + 1e-6 * np.abs(ref_all).max(axis=0) if fmt != "ascii" else 0.0
    for b in blocks:
        ref = ref_all[b.first_index : b.end_index]
        assert b.data.dtype == np.float32
        assert np.all(np.abs(b.data - ref) <= tol)


# --- protocol ----------------------------------------------------------------------------------
def test_crc_test_vectors_and_frame_layout():
    assert crc16_ccitt(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE
    assert crc32(b"123456789") == 0xCBF43926  # CRC-32/ISO-HDLC
    fr = encode_frame(0, np.array([[1.0, -2.0]]), "int24", np.array([1.0, 1.0]))
    assert fr.hex() == "a55a01000000000000000000000000000100020154940000803f0000803f010000feffff2777c3df"  # docs example
    assert len(fr) == frame_length(1, 2, "int24")


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_round_trip_formats_split_anywhere(fmt):
    rng = np.random.default_rng(0)
    v = rng.normal(0, 100, (50, 7)).astype(np.float32)
    scales = np.full(7, 0.05 if fmt == "int16" else 1e-4, np.float32)
    stream = b"".join(encode_frame(50 * k, v, fmt, scales, seq=k) for k in range(5))
    dec = FrameDecoder()
    frames = []
    for i in range(0, len(stream), 97):
        frames += dec.feed(b"\x00\xa5" + stream[i : i + 97] if i == 0 else stream[i : i + 97])
    assert [f.first_index for f in frames] == [0, 50, 100, 150, 200]
    tol = 0 if fmt == "float32" else scales[0] / 2 + 1e-5
    assert all(np.abs(f.data - v).max() <= tol for f in frames)
    assert dec.stats.garbage_bytes == 2 and dec.stats.frames_bad == 0 and dec.buffered == 0


def _accounting_ok(dec: FrameDecoder, frames) -> bool:
    consumed = sum(frame_length(f.n_samples, f.data.shape[1], f.fmt) for f in frames)
    return dec.stats.garbage_bytes + consumed + dec.buffered == dec.stats.bytes_in


@settings(max_examples=FUZZ, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.lists(st.binary(max_size=300), max_size=8))
def test_fuzz_random_bytes(chunks):
    dec = FrameDecoder()
    frames = [f for c in chunks for f in dec.feed(c)]
    assert frames == []  # no random byte string passes a CRC-16 header check *and* a CRC-32
    assert _accounting_ok(dec, frames)


_V = np.arange(24, dtype=np.float32).reshape(6, 4) - 11.5
_FRAMES = [encode_frame(6 * k, _V + k, ("int16", "int24", "int32", "float32")[k % 4], np.full(4, 0.5), seq=k) for k in range(6)]
_STREAM = b"".join(_FRAMES)


@settings(max_examples=FUZZ, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    st.lists(
        st.tuples(st.integers(0, len(_STREAM) - 1), st.integers(0, 255), st.sampled_from(["flip", "set", "del", "ins"])),
        max_size=6,
    ),
    st.lists(st.integers(1, len(_STREAM)), max_size=6),
)
def test_fuzz_mutated_frame_stream(mutations, cuts):
    data = bytearray(_STREAM)
    hit = set()
    for pos, val, kind in mutations:
        pos = min(pos, len(data) - 1)
        if kind == "flip":
            data[pos] ^= 1 << (val % 8)
        elif kind == "set":
            data[pos] = val
        elif kind == "del":
            del data[pos]
        else:
            data.insert(pos, val)
        hit.add(pos)
    dec = FrameDecoder()
    frames = []
    prev = 0
    for c in sorted({*cuts, len(data)}):
        frames += dec.feed(bytes(data[prev:c]))
        prev = c
    originals = {(k, 6 * k) for k in range(6)}
    for f in frames:  # every frame that came out is one that went in, intact (so its CRC held)
        assert (f.seq, f.first_index) in originals
        k = f.seq
        ref = FrameDecoder().feed(_FRAMES[k])[0]
        assert np.array_equal(f.data, ref.data)
    assert len({f.seq for f in frames}) == len(frames)
    if not mutations:
        assert len(frames) == 6
    assert _accounting_ok(dec, frames)


# --- link budget and config ------------------------------------------------------------------
def test_link_budget_refuses_with_numbers():
    cfg = SerialConfig(port="/dev/null", sample_rate=16384, channels=[f"c{i}" for i in range(15)], sample_format="float32")
    drv = SerialDriver(cfg)
    lb = drv.link_budget()
    assert lb.capacity == 92160  # 921600 baud 8N1
    assert lb.needed == pytest.approx(16384 * 15 * 4 + 16384 / 64 * 26)
    with pytest.raises(LinkBudgetError, match=r"needs 989,[0-9]{3} B/s, the link carries 92,160 B/s"):
        drv.open()
    usb = SerialDriver(cfg.model_copy(update={"usb_cdc": True, "sample_format": "int24"})).link_budget()
    usb.check()  # int24 over native USB fits
    assert usb.needed < 0.9 * usb.capacity


def test_entry_point_and_config_validation():
    (ep,) = [e for e in entry_points(group=ENTRY_POINT_GROUP) if e.name == "serial"]
    cls = ep.load()
    assert cls is SerialDriver and cls.config_model is SerialConfig
    with pytest.raises(ValueError):
        SerialConfig(port="x", sample_rate=100, channels=["a", "b"], columns=[1])


# --- ASCII -----------------------------------------------------------------------------------
def test_line_decoder_columns_and_bad_lines():
    dec = LineDecoder(columns=(3, 1), index_column=0, delimiter="auto", scale=(2.0, 1.0))
    text = b"# idx a b c\n10 1.5 x 4\r\n11 2.5 x 5\n12 3.5 zz\n13 oops 6 7\n14 4.5 x 8\n"
    lines = dec.feed(text[:17]) + dec.feed(text[17:])
    assert [ln.index for ln in lines] == [10, 11, 14]
    assert lines[0].values.tolist() == [8.0, 1.5]
    assert dec.stats.lines_bad == 2 and dec.stats.comments == 1
    csv = LineDecoder(columns=(1,))
    assert [ln.index for ln in csv.feed(b"5,1e-3\n6;2\n7,nan\n")] == [5, 6]


def test_ascii_round_trip_over_pty_with_bad_lines(device):
    faults = Faults(byte_corruption_rate=3e-3, seed=5)
    srv, drv, blocks = run_link(device, faults, n_samples=2048, fmt="ascii", frame_samples=16, channels=[0, 1, 2, 3], decimate=16)
    end = blocks[-1].end_index
    assert end >= 2048
    assert drv.decoder.stats.lines_bad > 0 and drv.stats.frames_bad == drv.decoder.stats.lines_bad
    assert merge(lost_before(drv, end)) == merge(r for r in faults.injected if r[0] < end)
    assert sum(b.n_samples for b in blocks) + sum(b - a for a, b in lost_before(drv, end)) == end
    check_against_device(device, srv, blocks, "ascii")


# --- binary end to end over a pty --------------------------------------------------------------
def test_end_to_end_10s_nominal_rate_zero_loss(device):
    n = int(10 * device.fs)
    t = time.monotonic()
    srv, drv, blocks = run_link(device, Faults(), n_samples=n)
    assert time.monotonic() - t < 40  # ends; loss is what the lines below judge
    assert blocks[0].first_index == 0 and blocks[-1].end_index == n
    assert sum(b.n_samples for b in blocks) == n
    assert drv.stats.gaps == [] and drv.stats.lost_samples == 0 and drv.stats.frames_bad == 0 and drv.stats.overruns == 0
    check_against_device(device, srv, blocks, "int24")


def test_byte_corruption_drops_and_stalls_loss_reported_exactly(device):
    faults = Faults(byte_corruption_rate=1e-4, frame_drop_rate=0.02, stall_every_s=1.0, stall_for_s=0.2, seed=7)
    n = int(3 * device.fs)
    srv, drv, blocks = run_link(device, faults, n_samples=n)
    end = blocks[-1].end_index
    start = blocks[0].first_index  # loss before the first frame received cannot be seen by anyone
    injected = merge(r for r in faults.injected if start <= r[0] < end)
    assert merge(r for r in faults.injected if r[0] < start) == ([(0, start)] if start else [])
    assert len(injected) > 10  # ~25 % of the 2.9 kB frames get hit
    assert merge(lost_before(drv, end)) == injected
    assert sum(b.n_samples for b in blocks) + sum(b - a for a, b in lost_before(drv, end)) == end - start  # nothing else lost
    assert drv.stats.frames_bad > 0
    assert drv.stats.resyncs > 0 and drv.stats.garbage_bytes > 0  # line noise is visible to the operator
    check_against_device(device, srv, blocks, "int24")


def test_disconnect_2s_reconnects_and_reports_gap(device):
    faults = Faults(disconnect_at_s=1.0, disconnect_for_s=2.0, seed=1)
    n = int(4 * device.fs)
    _, drv, blocks = run_link(device, faults, n_samples=n)
    end = blocks[-1].end_index
    assert end >= n
    assert drv.stats.reconnects >= 1 and drv.stats.timeouts >= 1
    (gap,) = merge(lost_before(drv, end))
    assert [gap] == merge(faults.injected)
    assert gap[1] - gap[0] >= 2 * device.fs
    events = drv.drain_events()
    assert any(e.kind == "reconnect" for e in events)
    assert [(e.start_index, e.end_index) for e in events if e.kind == "gap" and e.start_index < end] == [gap]
    assert sum(b.n_samples for b in blocks) + sum(b - a for a, b in lost_before(drv, end)) == end


# --- restarts, wild frames, stalls ------------------------------------------------------------
def device_blocks(drv, blocks):
    """(device index, block) for each block: stream index minus its segment's offset."""
    return [(drv.stats.device_index(b.stream, b.first_index), b) for b in blocks]


def check_device_data(device, srv, pairs, fmt):
    """Every block equals the device's own samples at its device index (a restarted device replays from 0)."""
    end = max(d + b.n_samples for d, b in pairs)
    ref_all = device.samples(0, end * srv.decimate)[:: srv.decimate][:, srv.channels]
    tol = srv.scales * 0.51 + 1e-6 * np.abs(ref_all).max(axis=0) if fmt != "ascii" else 0.0
    for d, b in pairs:
        assert np.all(np.abs(b.data - ref_all[d : d + b.n_samples]) <= tol)


@pytest.mark.parametrize("fmt", ["int24", "ascii"])
def test_device_restart_is_a_new_segment_never_stitched(device, fmt):
    faults = Faults(restart_at_s=1.0, restart_down_s=0.5)
    kw = {"frame_samples": 16, "channels": [0, 1, 2, 3], "decimate": 16} if fmt == "ascii" else {}
    srv, drv, blocks = run_link(device, faults, n_samples=int(2.6 * device.fs / (16 if fmt == "ascii" else 1)), fmt=fmt, **kw)
    fs = srv.fs
    (rec,) = faults.restarts
    assert drv.stats.restarts == 1 and drv.stats.rejected_blocks == 0 and drv.stats.frames_bad == 0
    k = next(i for i, b in enumerate(blocks) if b.status & BlockStatus.RESTART)
    old, new = blocks[:k], blocks[k:]
    # before: the old run, contiguous from 0 up to the last sample it put on the link
    assert old[0].first_index == 0 and old[-1].end_index == rec.delivered
    assert all(b.first_index == a.end_index for a, b in itertools.pairwise(old))
    # the new segment starts after the old one, where the host clock puts the new run's first sample
    seg = drv.stats.segments[-1]
    assert (seg.number, seg.device_first, seg.stream_first) == (1, 0, new[0].first_index)
    # an estimate from the host clock (when the new run's first block arrived): within 200 ms. A quiet host puts it
    # within a few ms; make test with 4 CPU hogs measured 67 ms (the reading thread scheduled late). The exact
    # gap is not knowable from a restarted device, which is why it is a new segment, never stitched (below)
    assert abs(seg.stream_first - rec.stream_index(0, fs)) <= 0.2 * fs
    assert new[0].first_index > old[-1].end_index + 0.4 * fs  # 0.5 s down: never stitched on
    assert all(b.first_index == a.end_index for a, b in itertools.pairwise(new))
    (ev,) = [e for e in drv.drain_events() if e.kind == "restart"]
    assert (ev.start_index, ev.end_index, ev.device_start) == (rec.delivered, seg.stream_first, 0)
    assert drv.stats.gaps == [(rec.delivered, seg.stream_first)]
    assert drv.stats.lost_samples == drv.stats.estimated_lost_samples == seg.estimated_gap
    check_device_data(device, srv, device_blocks(drv, blocks), fmt)  # data before and after intact


def test_wild_frames_are_rejected_and_nothing_else_is_lost(device):
    faults = Faults(wild_frames=((0.5, 10**9), (1.0, 2**62)))
    # read to 3 s: a wild frame goes out after the frames of the burst it falls in, and a server thread late on a loaded
    # host sent one burst past 1.5 s with the second wild frame behind it, which a read to 1.5 s never saw
    srv, drv, blocks = run_link(device, faults, n_samples=int(3.0 * device.fs))
    end = blocks[-1].end_index
    assert drv.stats.rejected_blocks == 2 and drv.stats.restarts == 0
    assert [e.device_start for e in drv.drain_events() if e.kind == "implausible_index"] == [10**9, 2**62]
    assert drv.stats.gaps == [] and drv.stats.lost_samples == 0 and drv.stats.frames_bad == 0
    assert blocks[0].first_index == 0 and all(b.first_index == a.end_index for a, b in itertools.pairwise(blocks))
    assert sum(b.n_samples for b in blocks) == end >= 1.5 * device.fs
    check_against_device(device, srv, blocks, "int24")


def test_one_shot_stall_loses_nothing(device):
    faults = Faults(stall_at_s=0.5, stall_for_s=0.5)
    arrivals: list[float] = []
    srv, drv, blocks = run_link(device, faults, n_samples=int(1.5 * device.fs), arrivals=arrivals)
    # the device really went quiet: 0.5 s against blocks every few ms. The host stamps arrivals, and the block before the
    # stall may be read late on a loaded host, which shortens the gap it sees (0.398 s beside 4 hogs and the suite's
    # workers); half the stall is still ~60 frame periods (64 samples at 16384 Hz)
    assert max(np.diff(arrivals)) >= 0.25
    assert drv.stats.gaps == [] and drv.stats.lost_samples == 0 and drv.stats.reconnects == 0
    assert blocks[0].first_index == 0 and all(b.first_index == a.end_index for a, b in itertools.pairwise(blocks))
    check_against_device(device, srv, blocks, "int24")
