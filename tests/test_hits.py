"""Hammer trigger and hit quality gate on simulated-device data with known hits."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from analysis.model.config import RigConfig
from analysis.model.loader import validate
from analysis.model.rig import build_rig
from daq.hits import HitDetector, TriggerSettings
from drivers.blocks import SampleBlock
from drivers.sim.device import HitSchedule, SimulatedDevice

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


def test_a_channel_that_clips_on_every_hit_is_suspect():
    dev = _device(a09_range=2.0)
    det, hits = _run(dev, SETTINGS)
    assert all("a09" in h.clipped_channels for h in hits)
    assert det.suspects() == ["a09"]
    assert all(h.verdict in ("overload", "too_short") for h in hits)


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
