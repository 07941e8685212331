"""Hammer trigger and hit quality gate on simulated-device data with known hits."""

from __future__ import annotations

import json
import tomllib
from dataclasses import replace

import numpy as np
import pytest

from analysis.model.config import RigConfig
from analysis.model.loader import validate
from analysis.model.rig import build_rig
from daq.hits import ChannelHealth, HitDetector, TriggerSettings, _median_without, column_extrema, judge_channels
from drivers.blocks import SampleBlock
from drivers.sim.device import HitSchedule, SimulatedDevice
from drivers.sim.sensor_model import measure

from .conftest import RIGS

TIMES = (0.20, 0.70, 1.200, 1.204, 1.70, 2.20, 2.70)
FORCES = (800.0, 900.0, 700.0, 400.0, 2600.0, 50.0, 1000.0)  # a double hit at 1.2 s, an overload, a weak one
EXPECT = ["accepted", "accepted", "double_hit", "overload", "force_range", "accepted"]


def _device(a09_range: float | None = None, seed: int = 4) -> SimulatedDevice:
    data = tomllib.loads((RIGS / "beam_ch4_exp.toml").read_text())
    if a09_range is not None:
        data["sensors"][8]["range"] = a09_range
    rig = build_rig(validate(RigConfig, data), RIGS / "beam_ch4_exp.toml")
    return SimulatedDevice(rig, HitSchedule(TIMES, FORCES), duration=3.1, block_size=256, seed=seed)


@pytest.fixture(scope="module")
def device():
    return _device()


def _ranges(dev: SimulatedDevice) -> dict[str, float]:
    return {m.name: m.range for m in dev.channel_models if m.range is not None}


def _run(dev: SimulatedDevice, settings: TriggerSettings, block: int = 256, skip: set[int] | None = None):
    det = HitDetector(settings, dev.channels, dev.fs, _ranges(dev))
    hits = []
    n = int(3.1 * dev.fs)
    for k, start in enumerate(range(0, n, block)):
        if skip and k in skip:
            continue
        stop = min(n, start + block)
        hits += det.feed(SampleBlock("dev0", start, dev.fs, dev.channels, dev.samples(start, stop)))
    hits += det.finish()
    return det, hits


SETTINGS = TriggerSettings(level=20.0, pre_trigger=0.01, record_length=0.3, force_range=(100.0, 2000.0), driving_point="a13")


def test_every_hit_found_with_its_verdict_and_pre_trigger(device):
    det, hits = _run(device, SETTINGS)
    assert [h.verdict for h in hits] == EXPECT
    for h, t0, p in zip(hits, [0.2, 0.7, 1.2, 1.7, 2.2, 2.7], [800, 900, 700, 2600, 50, 1000], strict=True):
        edge_t = t0 + np.arcsin(min(1.0, 20.0 / p)) / np.pi * 0.001  # the half-sine crosses 20 N here
        assert abs(h.t_s - edge_t) <= 1.5 / device.fs
        assert h.end_index - h.start_index == round(0.31 * device.fs)
        assert np.array_equal(h.data, device.samples(h.start_index, h.end_index))  # pre-trigger intact
    ok = hits[0]
    assert ok.peak_force_N == pytest.approx(800.0, rel=0.02)
    assert 0.0008 <= ok.pulse_width_s <= 0.0011  # a 1 ms half-sine above 10 % of its peak: 0.94 ms
    assert ok.impulse_Ns == pytest.approx(2 * 800.0 * 0.001 / np.pi, rel=0.03)
    assert ok.input_energy_J > 0
    assert "double hit" in hits[2].reasons[0] and "4." in hits[2].reasons[0]  # ~4 ms after the first edge
    assert "hammer" in hits[3].clipped_channels and hits[3].peak_force_N == pytest.approx(2224.0, rel=1e-3)
    assert "outside the requested" in hits[4].reasons[0]
    assert det.suspects() == []


@pytest.mark.parametrize("block", [256, 8192])
def test_hit_records_equal_pytriggers_on_the_same_samples(device, block):
    """pyTrigger (ladisk/pyTrigger, a trigger nobody here wrote; docs/landscape.md), on the same samples with the same
    level, pre-trigger and record length, a new instance armed once the force fell back below the level (it has no
    re-arm of its own; bench/bench_hits.py times it so): every record it takes equals a gvtlink hit record bit for bit,
    so the trigger sample and the pre-trigger ring agree, at a live and a replay block size of gvtlink's. pyTrigger is fed
    64 samples at a time: it does not say how much of a block its finished record used, so the harness drops the rest
    of that block, and 64 samples are less than the 0.19 s between one record's end and the next hit's pre-trigger.
    The double hit at 1.204 s lies inside the 1.2 s record for both."""
    from pyTrigger import pyTrigger

    _, hits = _run(device, SETTINGS, block=block)
    rows, pre = hits[0].data.shape[0], round(SETTINGS.pre_trigger * device.fs)
    data = device.samples(0, int(3.1 * device.fs)).astype(np.float64)
    theirs, wait_below = [], False
    trig = pyTrigger(rows=rows, channels=data.shape[1], trigger_channel=0, trigger_level=SETTINGS.level, presamples=pre)
    for s in range(0, data.shape[0], 64):
        b = data[s : s + 64]
        if wait_below:
            low = np.flatnonzero(b[:, 0] < SETTINGS.level)
            if low.size == 0:
                continue
            b, wait_below = b[low[0] :], False
        if trig.add_data(b):
            theirs.append(trig.get_data())
            trig = pyTrigger(rows=rows, channels=data.shape[1], trigger_channel=0, trigger_level=SETTINGS.level,
                             presamples=pre)  # fmt: skip
            wait_below = True
    assert len(theirs) == len(hits) == 6
    for h, r in zip(hits, theirs, strict=True):
        assert np.array_equal(np.asarray(h.data, np.float64), r), (h.hit, h.t_s)


def test_block_size_does_not_change_anything(device):
    _, a = _run(device, SETTINGS, block=256)
    _, b = _run(device, SETTINGS, block=37)
    _, c = _run(device, SETTINGS, block=5000)
    for x, y, z in zip(a, b, c, strict=True):
        assert x.summary() == y.summary() == z.summary()
        assert np.array_equal(x.data, y.data) and np.array_equal(x.data, z.data)


def test_a_gap_inside_a_record_makes_it_too_short(device):
    # block 12 covers samples 3072-3327 = 0.1875-0.203 s: the first hit's record is cut by the gap
    _, hits = _run(device, SETTINGS, skip={13})
    assert hits[0].verdict == "too_short" and "data gap" in hits[0].reasons[0]
    assert [h.verdict for h in hits[1:]] == EXPECT[1:]


def test_a_channel_that_clips_on_every_hit_is_excluded_from_each_and_suspect():
    """One clipping accelerometer costs only itself: the hits keep their own verdicts."""
    dev = _device(a09_range=2.0)
    det, hits = _run(dev, SETTINGS)
    assert [h.verdict for h in hits] == EXPECT
    assert all("a09" in h.clipped_channels and "a09" in h.excluded_channels for h in hits)
    assert all(h.channel_verdicts["a09"] == "clipped" for h in hits)
    assert hits[0].reasons == ("a09 excluded: clipped (reached its ±2 range)",)
    assert det.suspects() == ["a09"]
    assert det.suspect_reasons() == {"a09": "clipped on every one of 6 hits"}


def test_energy_estimate_tracks_the_simulators_input_work(device):
    """∫F v dt from the driving-point accelerometer against the simulator's exact input work."""
    from analysis.model.rig import load_rig

    rig = load_rig(RIGS / "beam_ch4_exp.toml")
    res = rig.simulator.run(rig.hammer_force(800.0), 0.05, rig.sample_rate)
    _, hits = _run(device, SETTINGS)
    assert hits[0].input_energy_J == pytest.approx(res.energy.input_work[0, -1], rel=0.1)


def test_bad_settings_raise(device):
    with pytest.raises(ValueError):
        TriggerSettings(level=0.0)
    with pytest.raises(ValueError, match="trigger channel"):
        HitDetector(TriggerSettings(level=1.0, channel="nope"), device.channels, device.fs)


# --- per-channel verdicts: the 20-hit session's schedule through the kernel --------------------------------

SESSION20 = RIGS.parent / "sessions" / "sim_serial_20hits.toml"


def _rig(edit=None):
    data = tomllib.loads((RIGS / "beam_ch4_exp.toml").read_text())
    if edit is not None:
        edit(data)
    return build_rig(validate(RigConfig, data), RIGS / "beam_ch4_exp.toml")


@pytest.fixture(scope="module")
def session20():
    """The device `gvt record sim_serial_20hits.toml` serves, built as daq.session does it (a09's range
    overridden, a second tap 4 ms after each double hit at 0.6 of its force), and its samples."""
    cfg = tomllib.loads(SESSION20.read_text())
    sim = cfg["device"]["simulate"]

    def ranges(data):
        for s in data["sensors"]:
            s["range"] = sim["ranges"].get(s["name"], s["range"])

    times, forces = [], []
    for k, f in enumerate(sim["forces"]):
        times.append(0.2 + k * sim["period"])
        forces.append(float(f))
        if k in sim["double_hits"]:
            times.append(times[-1] + 0.004)
            forces.append(0.6 * f)
    dev = SimulatedDevice(
        _rig(ranges), HitSchedule(tuple(times), tuple(forces)), duration=cfg["duration"] + 1.0, seed=sim["seed"]
    )
    t = cfg["trigger"]
    settings = TriggerSettings(level=t["level"], channel=t["channel"], pre_trigger=t["pre_trigger"],
                               record_length=t["record_length"], force_range=tuple(t["force_range"]),
                               driving_point=t["driving_point"])  # fmt: skip
    hammer = next(m.range for m in dev.channel_models if m.name == "hammer")
    expect = [
        "overload" if f > hammer else "double_hit" if k in sim["double_hits"] else "accepted" for k, f in enumerate(sim["forces"])
    ]
    assert expect.count("accepted") == 16 and expect.count("overload") == 2
    return dev, dev.samples(0, round(cfg["duration"] * dev.fs)), settings, expect


def _feed(dev, x: np.ndarray, settings: TriggerSettings, block: int = 256, ranges: dict[str, float] | None = None):
    det = HitDetector(settings, dev.channels, dev.fs, ranges or _ranges(dev))
    hits = []
    for start in range(0, x.shape[0], block):
        hits += det.feed(SampleBlock("dev0", start, dev.fs, dev.channels, np.ascontiguousarray(x[start : start + block])))
    return det, hits + det.finish()


def _with(x: np.ndarray, dev, name: str, kind: str) -> np.ndarray:
    """``x`` with channel ``name`` broken: zeroed with the sensor's own noise left, stuck, zero, or a NaN every 0.25 s."""
    y = x.copy()
    k = dev.channels.index(name)
    if kind == "noise":
        y[:, k] = measure(np.zeros((len(y), 1)), [dev.channel_models[k]], dev.adc, np.random.default_rng(11)).data[:, 0]
    elif kind == "constant":
        y[:, k] = 0.37
    elif kind == "zero":
        y[:, k] = 0.0
    else:
        y[:: round(dev.fs / 4), k] = np.nan
    return y


def test_twenty_hit_session_keeps_its_hits_with_a09_excluded_from_each_and_named_suspect(session20):
    dev, x, settings, expect = session20
    det, hits = _feed(dev, x, settings)
    assert [h.verdict for h in hits] == expect  # was: all 20 "overload" because of a09 alone
    for h in hits:
        v = h.channel_verdicts
        assert set(v) == set(dev.channels)
        assert v["a09"] == "clipped" and "a09" in h.excluded_channels and "a09" in h.clipped_channels
        assert "a09 excluded: clipped (reached its ±2 range)" in h.reasons
        assert "dead" not in v.values()  # no live channel of a real session is ever called dead
        assert set(h.excluded_channels) == {c for c, s in v.items() if s != "ok" and c != "hammer"}
        assert (v["hammer"] == "clipped") == (h.verdict == "overload")
        if h.verdict == "overload":
            assert h.reasons[0] == "overload: hammer reached the measurement range"
        s = h.summary()
        assert s["channels"] == v and s["excluded_channels"] == list(h.excluded_channels) and "a09" in s["clipped_channels"]
        json.dumps(s)
    accepted = [h for h in hits if h.verdict == "accepted"]
    assert all(h.input_energy_J is not None and h.input_energy_J > 0 for h in accepted if h.channel_verdicts["a13"] == "ok")
    assert accepted[0].summary()["reason"] == "a09 excluded: clipped (reached its ±2 range)"
    assert det.suspects() == ["a09"]
    assert det.suspect_reasons() == {"a09": "clipped on every one of 20 hits"}


def test_a_required_channel_that_fails_rejects_the_hit(session20):
    dev, x, settings, expect = session20
    det, hits = _feed(dev, x, replace(settings, required=("a09",)))
    assert [h.verdict for h in hits] == ["overload"] * 20
    assert all(any(r.startswith("overload:") and "a09" in r for r in h.reasons) for h in hits)
    assert not any(r.startswith("a09 excluded") for h in hits for r in h.reasons)  # it rejects, it is not a note
    assert det.suspects() == ["a09"]
    # a required channel that is dead rejects too; the same channel not required is only left out
    y = _with(x, dev, "a05", "noise")
    _, hits = _feed(dev, y, replace(settings, required=("a05",)))
    assert [h.verdict for h in hits] == ["overload"] * 20
    assert all(any(r.startswith("overload: required channel a05 dead (no response") for r in h.reasons) for h in hits)
    _, hits = _feed(dev, y, settings)
    assert [h.verdict for h in hits] == expect


def test_an_excluded_channel_is_never_judged_nor_suspect(session20):
    dev, x, settings, expect = session20
    det, hits = _feed(dev, x, replace(settings, exclude=("a09",)))
    assert [h.verdict for h in hits] == expect
    for h in hits:
        assert h.channel_verdicts["a09"] == "excluded" and "a09" in h.excluded_channels
        assert "a09" not in h.clipped_channels and not any("a09" in r for r in h.reasons)
    assert det.suspects() == [] and det.suspect_reasons() == {} and "a09" not in det.health.judged


BROKEN = [("noise", "dead", "no response: rose"), ("constant", "stuck", "one value, 0.37,"), ("nan", "dead", "non-finite"),
          ("zero", "dead", "flat:")]  # fmt: skip


@pytest.mark.parametrize(("kind", "verdict", "why"), BROKEN)
def test_a_dead_or_stuck_channel_is_excluded_from_each_hit_and_named_suspect(session20, kind, verdict, why):
    """Issue 29: a channel frozen at a non-zero value is ``stuck`` (it lies), not ``dead`` (it is silent); a flat
    zero is dead."""
    dev, x, settings, expect = session20
    det, hits = _feed(dev, _with(x, dev, "a05", kind), settings)
    assert [h.verdict for h in hits] == expect
    for h in hits:
        assert h.channel_verdicts["a05"] == verdict and "a05" in h.excluded_channels
        assert any(r.startswith(f"a05 excluded: {verdict} ({why}") for r in h.reasons), h.reasons
        assert [c for c, v in h.channel_verdicts.items() if v in ("dead", "stuck")] == ["a05"]
    assert det.suspect_reasons() == {"a05": f"{verdict} on every one of 20 hits", "a09": "clipped on every one of 20 hits"}


def test_weak_hits_and_far_channels_are_not_called_dead():
    """A noisy floor (0.2 m/s^2 on every sensor) and 25-30 N taps that nobody answers clearly, between
    1500 N hits; a00 sits 7 mm from the clamped root, 0.69 m from the hammer, and hardly moves; a05 is
    dead (its own noise only). a05 is found on the strong hits only, and is still suspect."""

    def edit(data):
        data["sensors"].insert(0, {"name": "a00", "x": 0.007, "sensitivity_mv_per_unit": 1.02, "range": 4905.0})
        for s in data["sensors"]:
            s["noise_rms"] = 0.2

    forces = (30.0, 1500.0, 25.0, 1500.0, 30.0, 1500.0)
    dev = SimulatedDevice(_rig(edit), HitSchedule.every(0.4, forces), duration=2.6, seed=7)
    x = _with(dev.samples(0, round(2.6 * dev.fs)), dev, "a05", "noise")
    det, hits = _feed(dev, x, TriggerSettings(level=20.0, pre_trigger=0.01, record_length=0.2))
    assert [h.peak_force_N for h in hits] == pytest.approx(forces, rel=0.1)
    for h, f in zip(hits, forces, strict=True):
        assert h.verdict == "accepted" and h.channel_verdicts["a00"] == "ok"
        assert [c for c, v in h.channel_verdicts.items() if v == "dead"] == (["a05"] if f > 100 else [])
    assert det.suspect_reasons() == {"a05": "dead on every one of 3 hits; 3 more could not be judged"}


def test_the_force_channel_clipping_still_rejects(session20):
    dev, x, settings, expect = session20
    everything = tuple(c for c in dev.channels if c != "hammer")
    det, hits = _feed(dev, x, replace(settings, exclude=everything))
    assert [h.verdict for h in hits] == expect
    for h in hits:
        assert h.excluded_channels == everything
        assert h.clipped_channels == (("hammer",) if h.verdict == "overload" else ())
    assert det.suspects() == []  # clipped on 2 of 20 hits: hit softer, but the hammer is not broken


def test_a_failed_driving_point_drops_the_input_energy_not_the_hit(session20):
    dev, x, settings, expect = session20
    ranges = _ranges(dev) | {"a13": 50.0}  # the driving-point accelerometer now saturates on every hit
    det, hits = _feed(dev, x, settings, ranges=ranges)
    assert [h.verdict for h in hits] == expect
    for h in hits:
        assert h.input_energy_J is None and h.channel_verdicts["a13"] == "clipped"
        assert "no input energy: driving point a13 clipped (reached its ±50 range)" in h.reasons
    assert det.suspects() == ["a09", "a13"]


def test_channel_health_counts_only_hits_a_channel_could_be_judged_on():
    h = ChannelHealth()
    for _ in range(3):
        h.update({"hammer": "ok", "a1": "clipped", "a2": "dead", "a3": "excluded", "a4": "ok"})
    h.update({"hammer": "ok", "a1": "clipped", "a2": "ok", "a3": "excluded", "a4": "dead"}, unjudged={"a2"})
    assert h.hits == 4 and h.judged == {"hammer": 4, "a1": 4, "a2": 3, "a4": 4}
    assert h.failures == {"a1": {"clipped": 4}, "a2": {"dead": 3}, "a4": {"dead": 1}} and h.clipped == {"a1": 4}
    assert h.suspect_reasons(3) == {
        "a1": "clipped on every one of 4 hits",
        "a2": "dead on every one of 3 hits; 1 more could not be judged",
    }
    assert h.suspects(4) == ["a1"]  # a2 judged on 3 only
    h.update({"a1": "dead"})
    assert h.suspect_reasons(3)["a1"] == "failed on every one of 5 hits (clipped 4, dead 1)"
    h.update({"a1": "ok"})
    assert "a1" not in h.suspects(3)


def test_judge_channels_needs_the_others_to_answer_before_calling_one_dead():
    rng = np.random.default_rng(0)
    fs, n, start = 10000.0, 2000, 200
    t = np.arange(n - start) / fs
    kick = np.exp(-t / 0.01) * np.sin(2 * np.pi * 800 * t)
    rec = rng.normal(0, 0.01, (n, 5))
    rec[start:, 1:4] += kick[:, None] * np.array([100.0, 50.0, 30.0])  # three answering channels; ch 4 silent
    chans = ("F", "a", "b", "c", "d")
    ranges = np.full(5, np.inf)
    j = judge_channels(rec, chans, ranges, 0, start, fs)
    assert j.verdicts == {"F": "ok", "a": "ok", "b": "ok", "c": "ok", "d": "dead"} and "no response" in j.why["d"]
    weak = rec.copy()
    weak[start:, 1:4] = rng.normal(0, 0.01, (n - start, 3)) + kick[:, None] * 0.05  # nobody answers clearly
    j = judge_channels(weak, chans, ranges, 0, start, fs)
    assert set(j.verdicts.values()) == {"ok"} and j.unjudged == {"a", "b", "c", "d"}
    j = judge_channels(rec, chans, ranges, 0, start, fs, exclude=("d",))
    assert j.verdicts["d"] == "excluded" and "d" not in j.unjudged
    assert judge_channels(rec[:20], chans, ranges, 0, 10, fs).unjudged == {"a", "b", "c", "d"}  # no baseline


def test_flat_channels_are_dead_only_as_the_exception():
    rng = np.random.default_rng(1)
    rec = np.round(rng.normal(0, 3, (1000, 6))).astype(np.float32)  # quantised noise: many codes
    rec[:, 5] = np.where(np.arange(1000) % 2, 1.0, 2.0)  # two codes only: stuck
    chans = ("F", "a", "b", "c", "d", "e")
    j = judge_channels(rec, chans, np.full(6, np.inf), 0, 500, 1000.0)
    assert j.verdicts["e"] == "dead" and j.why["e"].startswith("flat")
    coarse = np.clip(np.round(rec / 8), -1, 1)  # a coarse ADC: every channel shows at most 3 codes
    j = judge_channels(coarse, chans, np.full(6, np.inf), 0, 500, 1000.0)
    assert "dead" not in j.verdicts.values() and {"a", "b", "c", "d", "e"} <= j.unjudged


def test_bad_channel_settings_raise(device):
    with pytest.raises(ValueError, match="both required and excluded"):
        TriggerSettings(level=1.0, required=("a01",), exclude=("a01",))
    with pytest.raises(ValueError, match="force channel"):
        TriggerSettings(level=1.0, exclude=("hammer",))
    with pytest.raises(ValueError, match="required channel 'a99'"):
        HitDetector(TriggerSettings(level=1.0, required=("a99",)), device.channels, device.fs)
    with pytest.raises(ValueError, match="excluded channel 'a99'"):
        HitDetector(TriggerSettings(level=1.0, exclude=["a99"]), device.channels, device.fs)
    assert TriggerSettings(level=1.0, exclude=["a01"]).exclude == ("a01",)  # a config's list, kept hashable


def test_block_reductions_equal_numpys():
    """The channel judgment's block-wise extrema and leave-one-out medians against numpy's own (exact: max, min and
    the mean of two middle values do not depend on the grouping), NaN and inf included, odd and even counts."""
    rng = np.random.default_rng(3)
    for n in (1, 63, 64, 1000):
        rec = rng.normal(0, 1, (n, 5)).astype(np.float32)
        rec[n // 2, 1], rec[0, 3] = np.nan, -np.inf
        hi, lo = column_extrema(rec)
        np.testing.assert_array_equal(hi, rec.max(axis=0))
        np.testing.assert_array_equal(lo, rec.min(axis=0))
    for n in range(1, 8):
        v = rng.integers(0, 4, n).astype(float)  # ties on purpose
        want = [np.median(v), *(np.median(np.delete(v, k)) if n > 1 else 0.0 for k in range(n))]
        np.testing.assert_array_equal(_median_without(v, np.arange(-1, n)), want)
