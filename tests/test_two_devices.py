"""Two DAQ devices on one timeline (issue 5): clock-offset estimate, stream aligner, config, a real session.

Oracles: synthetic arrival times with a known offset, drift and latency distribution (the estimator);
exact sample values that encode their own index (the aligner); the simulated device view's exact delay
(``start_delay`` × fs samples) and a hit gate run offline on the logged streams merged with the TRUE
offset (the end-to-end session).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis.model.loader import ConfigError, load_config, validate
from daq.config.session import SessionConfig
from daq.hits import HitDetector, TriggerSettings
from daq.timeline import ClockOffsetEstimator, StreamAligner
from drivers.blocks import BlockStatus, SampleBlock

from .hogs import sim_devices_wake_precisely

ROOT = Path(__file__).resolve().parents[1]
CFG = ROOT / "configs" / "sessions" / "sim_two_devices.toml"
FS = 16384.0


# --- the estimator ------------------------------------------------------------------------------
def _arrivals(t0: float, ppm: float, seconds: float, rng: np.random.Generator, frame: int = 64):
    """(t_arrival, end_index) of a device whose sample i is taken at host time t0 + i/fs·(1 + ppm·1e-6),
    frames of 64 samples, latency 80 µs + exponential (mean 0.5 ms) + 2 % spikes of 2–10 ms."""
    ends = np.arange(frame, int(seconds * FS), frame)
    lat = 80e-6 + rng.exponential(0.5e-3, ends.size)
    spikes = rng.random(ends.size) < 0.02
    lat[spikes] += rng.uniform(2e-3, 10e-3, spikes.sum())
    return t0 + ends / FS * (1 + ppm * 1e-6) + lat, ends


def _feed(est: ClockOffsetEstimator, streams: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """Interleave the streams in host-time order, as a session sees them."""
    rows = sorted((t, s, int(e)) for s, (ts, es) in streams.items() for t, e in zip(ts, es, strict=True))
    for t, s, e in rows:
        est.add(s, t, e, FS)


def test_estimator_finds_offset_and_drift_through_latency_jitter():
    rng = np.random.default_rng(3)
    est = ClockOffsetEstimator(window_s=0.1, drift_min_span_s=10.0)
    _feed(est, {"A": _arrivals(100.0, 0.0, 20.0, rng), "B": _arrivals(100.2371, 30.0, 20.0, rng)})
    rel = est.relative("B", "A")
    eb = est.estimate("B")
    assert rel is not None and eb is not None
    true_now = 0.2371 + 30e-6 * eb.at_s  # B's clock ran 30 ppm fast: the offset grew by 0.6 ms in 20 s
    # the lower envelope of 25 arrivals per window: the minimum's excess is ~ 0.5 ms / 25 = 20 µs
    assert abs(rel.offset_s - true_now) < 20e-6, (rel.offset_s - true_now) * 1e6
    assert rel.offset_samples == round(true_now * FS)
    assert abs(rel.drift_ppm - 30.0) < 2.0  # slope of ~200 window minima with ~20 µs scatter: σ ≈ 0.3 ppm
    assert 1e-6 < rel.uncertainty_s < 100e-6  # the spread of the window minima, not of the raw latency (ms)


def test_estimator_without_drift_span_reports_zero_drift_and_the_lower_envelope():
    rng = np.random.default_rng(4)
    est = ClockOffsetEstimator(window_s=0.1, drift_min_span_s=10.0)
    _feed(est, {"A": _arrivals(5.0, 0.0, 0.6, rng), "B": _arrivals(5.0 - 0.0123, 0.0, 0.6, rng)})
    rel = est.relative("B", "A")
    assert rel.drift_ppm == 0.0 and est.estimate("A").n_windows >= 6
    assert abs(rel.offset_s + 0.0123) < 50e-6  # B started first: a negative offset
    assert rel.method == "host-arrival-lower-envelope"


def _loaded(arr: tuple[np.ndarray, np.ndarray], rng: np.random.Generator, lag_s: float, lag_at: float, lag_for: float):
    """A starved reader (issue 30, 6 busy loops on 2 cores): 40 % of blocks a further 1–20 ms late, and from
    ``lag_at`` for ``lag_for`` s (device time) every block behind by a steady ``lag_s`` plus jitter (the reader
    then catches up: the blocks that waited arrive together)."""
    t, e = arr
    late = rng.random(t.size) < 0.4
    t = t + late * rng.uniform(1e-3, 20e-3, t.size)
    dev = e / FS
    backlog = (dev >= lag_at) & (dev < lag_at + lag_for)
    t = t + backlog * (lag_s + rng.exponential(0.2e-3, t.size))
    return np.maximum.accumulate(t), e  # one link is a FIFO: a block held up holds up the ones behind it


@pytest.mark.parametrize("seed", range(5))
def test_two_devices_with_different_block_sizes_keep_the_offset_within_its_stated_uncertainty(seed):
    """The case that fools a quantile floor (tried as D127, reverted): two DAQs of different kinds deliver different
    block sizes (256 and 4096 samples at 16384 Hz), each block read 0-20 ms after its last sample (a serial driver's
    read turns). A 0.1 s window holds ~6 blocks of one device and 0.4 of one of the other, so a quantile of the
    window minima sits ~3 ms higher for the sparse device: the 20th percentile put the offset 36-81 samples off with an
    uncertainty of 21-45. The lowest point errs by the sparse stream's fewer draws only, within 1.5x the uncertainty
    it states (measured: 0.06-1.18x over these seeds)."""
    fs, true = 16384.0, 0.1
    rng = np.random.default_rng(seed)
    arrivals = [(off + end / fs + rng.uniform(0.0, 0.02), name, end)
                for name, blk, off in (("ref", 256, 0.0), ("other", 4096, true))
                for end in range(blk, int(10 * fs) + 1, blk)]  # fmt: skip
    est = ClockOffsetEstimator()
    for t, name, end in sorted(arrivals):
        est.add(name, t, end, fs)
    rel = est.relative("other", "ref")
    assert abs(rel.offset_s - true) <= 1.5 * rel.uncertainty_s, (rel.offset_s - true, rel.uncertainty_s)


def test_a_steady_backlog_of_a_second_neither_moves_the_offset_nor_counts_as_a_clock_step():
    """Measured on main: the last-second minimum put the offset at 0.78 s (true 0.2371 s) after a second in which
    every accelerometer block arrived 0.54 s late; the floor over the horizon must not move at all."""
    rng = np.random.default_rng(5)
    est = ClockOffsetEstimator(window_s=0.1, drift_min_span_s=10.0)
    b = _loaded(_arrivals(100.2371, 0.0, 8.0, rng), rng, 0.54, 6.0, 2.5)  # the last 2 s: all late
    _feed(est, {"A": _loaded(_arrivals(100.0, 0.0, 8.0, rng), rng, 0.0, 0.0, 0.0), "B": b})
    rel = est.relative("B", "A")
    # the floor of ~80 windows, each the minimum of 25 arrivals of which 60 % are at the quiet latency: tens of µs
    assert abs(rel.offset_s - 0.2371) < 1 / FS, rel
    assert rel.uncertainty_s < 1e-3  # the floor is sharp: most windows still had a quiet arrival


def test_a_clock_step_held_for_step_s_is_followed_and_a_shorter_one_is_not():
    rng = np.random.default_rng(6)
    t, e = _arrivals(100.2371, 0.0, 12.0, rng)
    stepped = t + (e / FS > 4.0) * 0.005  # B's clock steps 5 ms later at 4 s
    for upto, want in ((8.0, 0.2371), (12.0, 0.2421)):  # 4 s after the step: not yet; 8 s after: followed
        est = ClockOffsetEstimator(window_s=0.1, drift_min_span_s=30.0)
        keep = e / FS <= upto
        _feed(est, {"A": _arrivals(100.0, 0.0, upto, rng), "B": (stepped[keep], e[keep])})
        assert abs(est.relative("B", "A").offset_s - want) < 1 / FS, (upto, est.relative("B", "A"))


# --- the aligner --------------------------------------------------------------------------------
def _blocks(stream: str, chans: tuple[str, ...], values, n: int, sizes, drop=()) -> list[SampleBlock]:
    """Blocks of a stream whose channel j holds values(index, j), split at ``sizes``; ranges in
    ``drop`` (own index) never arrive (a gap)."""
    out, i, k = [], 0, 0
    while i < n:
        m = min(int(sizes[k % len(sizes)]), n - i)
        idx = np.arange(i, i + m)
        data = np.stack([values(idx, j) for j in range(len(chans))], axis=1).astype(np.float32)
        keep = not any(a < i + m and i < b for a, b in drop)
        if keep:
            out.append(SampleBlock(stream, i, FS, chans, data))
        i += m
        k += 1
    return out


def _interleave(*streams: list[SampleBlock]) -> list[SampleBlock]:
    out = [b for s in streams for b in s]
    return sorted(out, key=lambda b: (b.end_index, b.stream))  # by own index: B lags by the offset


D = 3885  # B's sample i is reference (A) sample i + D


def _ab(n_a=20000, n_b=16000, drop_a=(), drop_b=()):
    a = _blocks("A", ("hammer",), lambda i, j: i, n_a, [64, 100, 37], drop_a)  # A's value = its index
    b = _blocks("B", ("a1", "a2"), lambda i, j: (i + D) * 10 + j, n_b, [64, 250], drop_b)  # B's = 10·ref index + col
    return a, b


def _merge(aligner: StreamAligner, blocks) -> list[SampleBlock]:
    out = []
    for blk in blocks:
        out += aligner.feed(blk)
    return out + aligner.finish()


def test_aligner_with_a_configured_offset_puts_every_sample_on_the_reference_index():
    al = StreamAligner({"A": ("hammer",), "B": ("a1", "a2")}, "A", FS, offsets={"B": D / FS})
    a, b = _ab()
    out = _merge(al, _interleave(a, b))
    assert out[0].channels == ("hammer", "a1", "a2") and out[0].stream == "timeline"
    r = np.concatenate([np.arange(o.first_index, o.end_index) for o in out])
    data = np.concatenate([o.data for o in out])
    assert r[0] == D and r[-1] == min(20000, 16000 + D) - 1 and np.all(np.diff(r) == 1)  # the overlap, whole
    assert np.array_equal(data[:, 0], r) and np.array_equal(data[:, 1], r * 10.0) and np.array_equal(data[:, 2], r * 10.0 + 1)
    assert all(o.status == BlockStatus.OK for o in out)
    msgs = al.drain_messages()
    assert msgs[0]["kind"] == "fixed" and msgs[0]["method"] == "configured" and msgs[0]["offset_samples"] == D
    assert msgs[-1]["kind"] == "final"


@pytest.mark.parametrize("which", ["A", "B"])
def test_a_gap_in_either_stream_is_a_gap_in_the_merged_stream_and_cuts_a_hit_record(which):
    gap = (9000, 9100) if which == "A" else (9000 - D, 9100 - D)  # the same reference range, own index
    a, b = _ab(drop_a=[gap] if which == "A" else (), drop_b=[gap] if which == "B" else ())
    al = StreamAligner({"A": ("hammer",), "B": ("a1", "a2")}, "A", FS, offsets={"B": D / FS})
    out = _merge(al, _interleave(a, b))
    r = np.concatenate([np.arange(o.first_index, o.end_index) for o in out])
    missing = sorted(set(range(D, 19885)) - set(r.tolist()))  # the overlap is [D, min(20000, 16000 + D))
    assert missing and missing[0] <= 9000 and missing[-1] >= 9099  # the dropped blocks cover [9000, 9100)
    assert np.all(np.diff(missing) == 1)  # one contiguous hole
    after = [o for o in out if o.first_index == missing[-1] + 1]
    assert len(after) == 1 and after[0].status & BlockStatus.GAP_BEFORE and al.merged_gaps == 1
    # a hit whose record spans the hole is cut: too_short (hits.py), fed the merged stream
    det = HitDetector(TriggerSettings(level=0.5, channel="hammer", pre_trigger=0.001, record_length=0.2), out[0].channels, FS)
    hits = []
    for o in out:
        blk = SampleBlock(o.stream, o.first_index, FS, o.channels, o.data.copy())
        blk.data[:, 0] = (np.arange(o.first_index, o.end_index) >= 8000) & (np.arange(o.first_index, o.end_index) < 8010)
        hits += det.feed(blk)
    hits += det.finish()
    assert len(hits) == 1 and hits[0].verdict == "too_short" and "data gap" in hits[0].reasons[0]


def test_aligner_buffers_are_bounded_when_a_device_is_silent():
    al = StreamAligner({"A": ("hammer",), "B": ("a1", "a2")}, "A", FS, offsets={"B": D / FS}, settle_s=0.5, max_buffer_s=1.0)
    a, b = _ab(n_a=int(10 * FS), n_b=int(10 * FS) - D)
    for blk in a:  # ten seconds of A while B says nothing
        assert al.feed(blk) == []
        assert al._buf["A"].n <= FS  # never more than max_buffer_s
    assert al.dropped_samples["A"] == int(10 * FS) - FS
    out = []
    for blk in b:  # B arrives late: only A's last second can still be matched
        out += al.feed(blk)
    r = np.concatenate([np.arange(o.first_index, o.end_index) for o in out])
    assert r[0] == int(9 * FS) and np.array_equal(np.concatenate([o.data for o in out])[:, 0], r)


def test_aligner_estimates_fixes_and_reports_a_moved_clock():
    rng = np.random.default_rng(7)
    al = StreamAligner({"A": ("hammer",), "B": ("a1", "a2")}, "A", FS, settle_s=0.5, window_s=0.1, report_s=1.0)
    a, b = _ab(n_a=int(8 * FS), n_b=int(8 * FS) - D)
    t0 = 50.0

    def arrival(blk: SampleBlock) -> float:
        t0_dev = t0 + (D / FS if blk.stream == "B" else 0.0)
        # B's clock steps by 5 ms at 2 s: followed once it has held for the estimator's step_s (5 s), so within 8 s
        step = 0.005 if blk.stream == "B" and blk.end_index / FS > 2.0 else 0.0
        return t0_dev + step + blk.end_index / FS + 80e-6 + rng.exponential(0.3e-3)

    rows = sorted(((arrival(x), x) for x in a + b), key=lambda p: p[0])
    out = []
    for t, blk in rows:
        got = al.feed(blk, t)
        assert got == [] or al.fixed
        out += got
    out += al.finish()
    assert al.applied["B"] == D  # fixed after 0.5 s of both streams, to the sample here
    r = np.concatenate([np.arange(o.first_index, o.end_index) for o in out])
    data = np.concatenate([o.data for o in out])
    assert np.array_equal(data[:, 1], r * 10.0)  # every merged sample on the right reference index
    kinds = [m["kind"] for m in al.drain_messages()]
    assert kinds[0] == "fixed" and "periodic" in kinds and kinds[-1] == "final"
    assert kinds.count("moved") == 1  # the 5 ms step (82 samples) is reported once; the merged stream keeps D


# --- the simulated second device ----------------------------------------------------------------
def test_delayed_view_is_the_same_structure_exactly_delay_samples_later(rigs):
    from drivers.sim.device import DelayedDeviceView, HitSchedule, SimulatedDevice

    dev = SimulatedDevice(rigs("beam_ch4_exp"), HitSchedule.every(1.0, [100.0]), duration=0.3, seed=2)
    view = DelayedDeviceView(dev, 1000)
    view.start_clock(t0=500.0)  # switching the view on first starts the base clock (never restarts it)
    DelayedDeviceView(dev, 0).start_clock(t0=900.0)
    assert dev._t0 == 500.0 and view._t0 == 500.0 + 1000 / FS
    for t in (0.0, 0.01, 0.0611, 0.2, 7.0):
        assert view.samples_available(500.0 + t) == max(0, dev.samples_available(500.0 + t) - 1000)
    assert np.array_equal(view.samples(3000, 6000), dev.samples(4000, 7000))  # spans the simulated end (4915)


# --- config --------------------------------------------------------------------------------------
def _cfg(**over) -> dict:
    base = {
        "name": "t", "rig": "beam_ch4_exp", "duration": 1.0, "trigger": {"level": 20.0},
        "devices": [
            {"name": "h", "driver": "serial", "simulate": {"forces": [100.0], "channels": ["hammer"]}},
            {"name": "acc", "driver": "serial", "simulate": {"channels": ["a01", "a02"], "start_delay": 0.1}},
        ],
    }  # fmt: skip
    base.update(over)
    return base


def test_two_device_config_shares_one_structure_and_picks_the_hammer_device_as_reference():
    cfg = validate(SessionConfig, _cfg(), "t.toml")
    assert cfg.multi and [d.name for d in cfg.device_list] == ["h", "acc"] and cfg.reference_device() == "h"
    assert cfg.devices[1].simulate.forces == [100.0] and cfg.devices[1].simulate.start_delay == 0.1
    ex = load_config(SessionConfig, CFG)
    assert ex.reference_device() == "hammer_daq" and ex.devices[1].simulate.forces == ex.devices[0].simulate.forces
    single = load_config(SessionConfig, ROOT / "configs" / "sessions" / "sim_serial_20hits.toml")
    assert not single.multi and single.device_list == [single.device]


def _devs(a: dict, b: dict) -> list[dict]:
    return [{"name": "h", "driver": "serial", **a}, {"name": "acc", "driver": "serial", **b}]


@pytest.mark.parametrize(
    ("over", "field", "words"),
    [
        ({"device": {"driver": "serial"}}, "devices", "not both"),
        ({"devices": _devs({"config": {"channels": ["hammer"]}}, {"name": "h", "config": {"channels": ["a01"]}})},
         "devices[1].name", "used twice"),
        ({"devices": _devs({"config": {"channels": ["a02"]}}, {"config": {"channels": ["a01"]}})},
         "trigger.channel", "no device"),
        ({"devices": _devs({"config": {"channels": ["hammer"]}}, {"config": {"channels": ["hammer", "a01"]}})},
         "devices[1].channels", "on both"),
        ({"devices": _devs({"config": {"channels": ["hammer"], "sample_rate": 16384}},
                           {"config": {"channels": ["a01"], "sample_rate": 8192}})}, "devices", "resampling is not supported"),
        ({"devices": _devs({"config": {"channels": ["hammer"]}}, {})}, "devices[1]", "list the device's channels"),
        ({"timeline": {"reference": "nope"}}, "timeline.reference", "no device named 'nope'"),
        ({"timeline": {"offsets": {"x": 0.1}}}, "timeline.offsets.x", "no device named"),
        ({"timeline": {"settle_s": 4.0, "max_buffer_s": 5.0}}, "timeline.max_buffer_s", "2 x settle_s"),
        ({"devices": None, "device": {"driver": "serial"}, "timeline": {}}, "timeline", "several [[devices]]"),
        ({"devices": [{"name": "h", "driver": "serial", "simulate": {"forces": [1.0], "channels": ["hammer"]}},
                      {"name": "a", "driver": "serial", "simulate": {"forces": [2.0], "channels": ["a01"]}}]},
         "devices[1].simulate.forces", "share one structure"),
    ],
)  # fmt: skip
def test_bad_multi_device_configs_give_one_clear_line(over, field, words):
    data = _cfg(**over)
    if data.get("devices") is None:
        data.pop("devices")
    with pytest.raises(ConfigError) as ei:
        validate(SessionConfig, data, "bad.toml")
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"bad.toml: {field}: ") and words in msg, msg


# --- a real two-device session over two ptys ----------------------------------------------------
@pytest.fixture(scope="module")
def two(tmp_path_factory):
    from analysis.model.rigs import open_rig
    from daq.session import run_session

    cfg = load_config(SessionConfig, CFG)
    out = tmp_path_factory.mktemp("two") / "two.mcap"
    # the confirmations are not under test here (tests/test_confirm_lane.py): not waited for after the data ends, as
    # `gvt record --no-wait` (the drain of this session's ~10 events cost ~12 CPU-s of the suite's budget)
    return cfg, out, run_session(cfg, open_rig(cfg.rig), out, wait_confirmations=False)


TRUE_DELAY = round(0.2371 * FS)  # samples by which acc_daq's clock starts after hammer_daq's (the view's exact delay)


@pytest.mark.slow
def test_two_device_session_finds_every_hit_and_records_the_offset(two):
    cfg, _out, res = two
    sim = cfg.devices[0].simulate
    assert res.driver_error is None and res.lost_samples == 0 and res.writer_overrun_samples == 0
    assert res.reference == "hammer_daq" and res.aligner_dropped == {"hammer_daq": 0, "acc_daq": 0}
    assert len(res.hits) == len(sim.forces)
    for k, h in enumerate(res.hits):  # the hammer is on the reference: its times are sample-exact
        assert abs(h.t_s - (sim.first + k * sim.period)) < 0.002
        assert h.input_energy_J is not None and h.input_energy_J > 0  # driving point a13 is on the other device
    assert [any(r.startswith("double hit") for r in h.reasons) for h in res.hits] == [k in sim.double_hits for k in range(8)]
    # the offset: host-arrival latency on the pty was measured at median 0.12 ms, p99 4.7 ms, max 9.6 ms per block
    # above its minimum (load 6-7 on 2 cores); the lower envelope removed it to 20-70 µs late (the 14-channel link's
    # last-byte stamp and the simulated device's late encoding; since D95 the error scatters about 0 by ±0.5 sample).
    # 1 ms (16 samples) leaves a > 10-fold margin.
    final = res.timeline["acc_daq"]
    assert final["method"] == "host-arrival-lower-envelope"
    assert abs(final["offset_s"] - TRUE_DELAY / FS) < 1e-3, final
    assert abs(final["applied_samples"] - TRUE_DELAY) <= 16 and final["uncertainty_s"] < 1e-3


@pytest.mark.slow
def test_two_device_log_holds_both_streams_whole_and_the_timeline(two):
    from daq.log.reader import LogReader

    cfg, out, res = two
    r = LogReader(out)
    assert r.report.complete
    h, a = r.read_stream("hammer_daq"), r.read_stream("acc_daq")
    for d, n in ((h, res.streams["hammer_daq"]), (a, res.streams["acc_daq"])):
        assert d.gaps == [] and d.index[0] == 0 and len(d.index) == n and np.all(np.diff(d.index) == 1)
    assert h.channels == ["hammer"] and a.channels == [f"a{k:02d}" for k in range(1, 15)]
    tl = r.json_messages("/daq/timeline")
    assert tl[0]["kind"] == "fixed" and tl[-1]["kind"] == "final"
    # a periodic report every report_s (1 s) of the reference's data after the fix: 4 when fixed after settle_s, 2 when a
    # busy host held the estimate until the 2.5 s deadline (the fixed message's settled_s says which; the accelerometer
    # stream starts 0.2371 s after the reference); one may fall past the end
    after_fix = cfg.duration - tl[0]["settled_s"] - 0.2371
    assert sum(m["kind"] == "periodic" for m in tl) >= max(1, int(after_fix) - 1), (tl[0], [m["kind"] for m in tl])
    meta = r.metadata()["gvtlink.timeline"]
    assert meta["reference"] == "hammer_daq" and json.loads(meta["final"])["acc_daq"] == res.timeline["acc_daq"]
    # oracle: the logged streams merged with the TRUE offset, through an independent hit gate
    n = min(len(h.index), len(a.index) + TRUE_DELAY)
    merged = np.concatenate([h.data[TRUE_DELAY:n], a.data[: n - TRUE_DELAY]], axis=1).astype(np.float32)
    t = cfg.trigger
    det = HitDetector(
        TriggerSettings(level=t.level, pre_trigger=t.pre_trigger, record_length=t.record_length, force_range=t.force_range,
                        driving_point=t.driving_point),
        ("hammer", *a.channels), FS,
        _ranges(cfg),
    )  # fmt: skip
    oracle = det.feed(SampleBlock("x", TRUE_DELAY, FS, ("hammer", *a.channels), merged)) + det.finish()
    assert [o.index for o in oracle] == [x.index for x in res.hits]
    assert [o.verdict for o in oracle] == [x.verdict for x in res.hits]
    applied = res.timeline["acc_daq"]["applied_samples"]  # TRUE_DELAY + 1 before D95; now TRUE_DELAY or a neighbour
    for o, x in zip(oracle, res.hits, strict=True):
        assert np.array_equal(o.data[:, 0], x.data[:, 0])  # the hammer: identical samples
        # each accelerometer sample in the record is acc_daq's sample (reference index − applied offset)
        assert np.array_equal(x.data[:, 1:], a.data[x.start_index - applied : x.end_index - applied])


def _ranges(cfg) -> dict[str, float]:
    from analysis.model.rigs import open_rig

    rig = open_rig(cfg.rig)
    return {p.name: p.props.range for p in [rig.hammer, *rig.sensors] if p.props.range is not None}


@pytest.mark.slow
def test_gvt_frf_reads_the_responses_on_the_other_device_through_the_time_base(two):
    """``gvt frf`` on a two-device log: the force from hammer_daq, the 14 responses from acc_daq at the log's
    offset. Oracle: the same FRFs accumulated here from the two streams sliced by hand at the offset the hit gate
    applied during the session (res.timeline), which must also be the offset the log's time base gives."""
    from analysis.frf import FRFAccumulator
    from analysis.model.rigs import open_rig
    from daq.log.export import time_base
    from daq.log.reader import LogReader
    from daq.studies.frf import frf_from_log

    cfg, out, res = two
    rig = open_rig(cfg.rig)
    run = frf_from_log(out, rig, level="all")  # every force level (300-1700 N): the oracle slices every accepted hit
    r = LogReader(out)
    off = time_base(r).offset_samples["acc_daq"]
    assert off == res.timeline["acc_daq"]["applied_samples"]
    assert run.streams == {"hammer_daq": 0, "acc_daq": off}
    f = run.frf
    assert f.outputs == [f"a{k:02d}" for k in range(1, 15)] and int(f.n_averages[0]) == 7  # the double hit refused
    assert [h["verdict"] for h in run.hits].count("accepted") == 7
    n, pre = round(run.record_s * FS), round(run.pre_s * FS)
    acc = FRFAccumulator(FS, n, f.outputs, "hammer", tau=run.tau_s, t0=pre / FS, f_max=run.band_hz, end_level=1e-3)
    h, a = r.read_stream("hammer_daq").data.astype(float), r.read_stream("acc_daq").data.astype(float)
    for hit, row in zip(r.json_messages("/daq/hits"), run.hits, strict=True):
        if row["verdict"] == "accepted":
            i0, left_out = hit["index"] - pre, hit.get("excluded_channels") or ()
            acc.add(h[i0 : i0 + n, 0], a[i0 - off : i0 - off + n], use=[o not in left_out for o in f.outputs])
    np.testing.assert_allclose(f.H, acc.frf().H, rtol=1e-9, atol=1e-12)


HOGS = 4  # busy loops on 2 cores (issue 30: 4-8). At 6 the in-process simulated 14-channel device itself falls
# 0.1-0.8 s behind (median arrival latency 0.43 s) and the floor lands 1-3 samples late, with the console saying
# it is not within one sample (the uncertainty covered the error in every run); see docs/session.md


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    """sim_two_devices.toml for 3 s, analysis and live FRF off (the busy loops are the load), recorded with HOGS
    busy loops running (started once the simulated devices are computed, which is no part of a real session;
    each ends by itself after 30 s, and is killed in the finally)."""
    import subprocess
    import sys

    from analysis.model.rigs import open_rig
    from daq.session import Session, SessionOptions, start_simulation

    tmp = tmp_path_factory.mktemp("loaded")
    path = tmp / "two.toml"
    path.write_text(CFG.read_text().replace("duration = 5.0", "duration = 3.0") + "\n[analysis]\nenabled = false\n")
    cfg = load_config(SessionConfig, path)
    rig = open_rig(cfg.rig)
    harness = start_simulation(cfg, rig)
    code = "import time\nend = time.monotonic() + 30\nwhile time.monotonic() < end:\n    pass\n"
    hogs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(HOGS)]
    lines: list[str] = []
    try:
        res = Session(cfg, harness.rig or rig, tmp / "two.mcap", harness, SessionOptions(frf=False, line=lines.append)).run()
    finally:
        for h in hogs:
            h.kill()
            h.wait()
        harness.stop()
    return res, lines, tmp / "two.mcap"


@pytest.mark.host_timing
def test_the_offset_holds_within_one_sample_with_busy_loops_running(loaded):
    """Issue 30: at load ≈ 5 the offset ended at 0.776-0.83 s against the true 0.2371 s with nothing on the
    console. With HOGS busy loops: the applied offset and the final estimate within one sample of the view's
    exact delay, the offset on the console with its uncertainty, in the log's timeline and in log info."""
    from daq.log.reader import LogReader
    from daq.log.tools import info_text, log_info

    res, lines, out = loaded
    final = res.timeline["acc_daq"]
    # the one sample (61 µs; issue 30 measured 0.54 s). Before D95 the floor's latency asymmetry between the 1-
    # and 14-channel links was 20-70 µs quiet; with 4 busy loops 32-131 µs, and the bar was 3 samples. Since the
    # simulated devices send with 1 ns timer slack (D129): final estimates within -0.03..+0.10 samples, the applied
    # offset exact, in 8 runs
    bar, why = (1, "") if sim_devices_wake_precisely() else (2, "bar 2 samples: this host refused the 1 ns timer slack, D129")
    assert abs(final["applied_samples"] - TRUE_DELAY) <= bar, (final, lines, why)
    assert abs(final["offset_s"] - TRUE_DELAY / FS) <= bar / FS, (final, lines, why)
    assert not any("MOVED" in s for s in lines), lines
    fixed = [s for s in lines if s.startswith("timeline: acc_daq placed")]
    assert len(fixed) == 1 and "±" in fixed[0] and str(final["applied_samples"]) in fixed[0], lines
    r = LogReader(out)
    tl = r.json_messages("/daq/timeline")
    assert tl[0]["kind"] == "fixed" and tl[0]["settled_s"] >= 0.5 and "within_accept" in tl[0]
    assert all(abs(m["offset_samples"] - TRUE_DELAY) <= bar for m in tl), ([m["offset_samples"] for m in tl], why)
    held = [e for e in r.json_messages("/daq/events") if e["kind"] == "stream_held"]
    assert [(e["stream"], e["first_index"]) for e in held] == [("acc_daq", 0)]  # written before the offset was fixed
    info = log_info(out)
    assert info["timeline"]["acc_daq"]["applied_samples"] == final["applied_samples"] and info["problems"] == []
    # issue 30 saw ~35,000 samples "NOT RECORDED (writer overrun)" in two-device logs; log info says what the writer counted
    assert sum(s["overrun_samples"] for s in info["streams"]) == res.writer_overrun_samples
    assert "timeline_acausal" not in info["events"] and not any("ACAUSAL" in s for s in lines)  # the physics agrees
    assert "timeline: acc_daq placed" in info_text(info)


def test_the_offset_waits_for_one_sample_of_certainty_and_says_when_the_deadline_fixed_it_without():
    """The fix waits past settle_s while the floor is blurred (every block 0-5 ms late, none at the link's minimum),
    up to settle_max_s = max_buffer_s / 2, then fixes and says in one line that it is not within one sample.
    The blur: each 0.1 s window of each stream late by its own 0-5 ms (a starved reader), so the lowest window
    minima lie ~5 ms / n apart: about 0.5 ms after 2 s, far over one sample (61 µs)."""
    from daq.timeline import timeline_line

    rng = np.random.default_rng(9)
    for jitter, want_s, within in ((0.0, 0.5, True), (5e-3, 2.0, False)):
        al = StreamAligner({"A": ("hammer",), "B": ("a1", "a2")}, "A", FS, settle_s=0.5, max_buffer_s=4.0)
        a, b = _ab(n_a=int(3 * FS), n_b=int(3 * FS) - D)
        late = {(s, w): rng.uniform(0.0, jitter) for s in "AB" for w in range(40)}
        for blk in sorted(a + b, key=lambda x: x.end_index / FS + (D / FS if x.stream == "B" else 0)):
            lat = 80e-6 + rng.exponential(0.1e-3) + late[blk.stream, int(blk.end_index / FS / 0.1)]
            al.feed(blk, 50.0 + (D / FS if blk.stream == "B" else 0.0) + blk.end_index / FS + lat)
        msg = next(m for m in al.drain_messages() if m["kind"] == "fixed")
        assert msg["within_accept"] is within and abs(msg["settled_s"] - want_s) < 0.2, msg
        line = timeline_line(msg, FS)
        assert line.startswith("timeline: B placed") and ("NOT within one sample" in line) is not within, line


def test_response_lead_is_the_steepest_change_of_the_response_against_the_force_s():
    """A 1 ms half-sine hammer pulse and a driving point that rings at 70 Hz from an earlier hit, then answers
    this hit (feedthrough + a decaying 200 Hz mode) from the pulse's start: shifted by k samples, the lead moves
    by exactly k; the unshifted response does not lead by more than half the pulse."""
    from daq.timeline import response_lead

    n, at, w = 4000, 400, 16
    i = np.arange(n)
    force = np.where((i >= at) & (i < at + w), 1000 * np.sin(np.pi * (i - at) / w), 0.0)
    ring = 3.0 * np.sin(2 * np.pi * 70 * i / FS)
    s = np.clip(i - at, 0, None) / FS
    resp = ring + 0.05 * force + (i >= at) * 40 * np.exp(-30 * s) * np.sin(2 * np.pi * 200 * s)
    base = response_lead(force, resp)
    assert base is not None and base <= w // 2
    for k in (30, 100, -50):
        assert response_lead(force, np.roll(resp, -k)) == base + k
    assert response_lead(np.zeros(n), resp) is None


def test_a_wrong_offset_is_caught_by_the_physics_the_response_before_the_hit(tmp_path):
    """sim_two_devices.toml with the accelerometer device configured 49 samples too early (0.2341 s, true 0.2371 s):
    every hit's driving point moves before the hammer, an event per hit and one console line. (Measured: the lead is
    -15 samples with the true offset, 36 here, -177 with the device 163 samples late.)"""
    from analysis.model.rigs import open_rig
    from daq.session import run_session

    path = tmp_path / "two.toml"
    text = CFG.read_text().replace("duration = 5.0", "duration = 2.0")
    text = text.replace("[timeline]\n", "[timeline]\noffsets = { acc_daq = 0.2341 }\n")
    path.write_text(text + "\n[analysis]\nenabled = false\n")
    cfg = load_config(SessionConfig, path)
    lines: list[str] = []
    res = run_session(cfg, open_rig(cfg.rig), tmp_path / "two.mcap", frf=False, line=lines.append)
    from daq.log.reader import LogReader

    ev = [e for e in LogReader(tmp_path / "two.mcap").json_messages("/daq/events") if e["kind"] == "timeline_acausal"]
    hits = [h for h in res.hits if h.verdict == "accepted"]
    assert hits and len(ev) >= len(hits), (ev, [h.verdict for h in res.hits])
    # 49 samples early, less the 15 by which the response's steepest change follows the force's rise when aligned
    assert all(30 <= e["lead_samples"] <= 40 for e in ev), ev
    assert sum(s.startswith("timeline ACAUSAL") for s in lines) == 1, lines
