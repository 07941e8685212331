"""The simulated DAQ's anti-alias filter (analysis/model/antialias.py, drivers/sim/device.py; issue 29, item 7).

Oracles: the filter's own stated spec (0.45 fs flat to 1e-4 dB, 100 dB from 0.55 fs) measured on its taps and
kernel; a tone above Nyquist and in band, whose samples are known in closed form; the convolution integral by
brute force on a fine grid; the impulse of a half-sine (2 P T / pi); and, for the device, the same structure
sampled at 16384 Hz, where no simulated mode lies above Nyquist (nothing to fold), read in the 2048 Hz band.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.signal

from analysis.model.antialias import ATTENUATION_DB, PASSBAND, STOPBAND, design, filtered_force
from analysis.model.forces import pulse_train
from analysis.model.rigs import open_rig
from daq.sim_devices import simulated_rig
from drivers.sim.device import HitSchedule, daq_filter, roving_signals

RIPPLE_DB = 1e-4  # Kaiser's one delta: 100 dB down is 1 +- 1e-5 in the passband, 8.7e-5 dB


@pytest.mark.parametrize("fs,top,r", [(2048.0, 7308.0, 5), (16384.0, 7308.0, 1)])
def test_the_filter_meets_its_stated_spec(fs, top, r):
    aaf = design(fs, top)
    assert aaf.oversampling == r  # 2048: 5 * 2048 - 7308 >= 0.55 * 2048; 16384: nothing above Nyquist
    f = np.linspace(0.0, 4 * fs if r == 1 else aaf.modulator_rate / 2, 6001)
    gain = aaf.response_db(f)
    assert np.abs(gain[f <= PASSBAND * fs]).max() <= RIPPLE_DB
    assert gain[f >= STOPBAND * fs].max() <= -ATTENUATION_DB
    assert aaf.delay_s == aaf.half_samples / fs and aaf.facts()["group_delay_compensated"] == "true"
    if r > 1:
        assert len(aaf.taps) == 2 * r * aaf.half_samples + 1 and np.allclose(aaf.taps, aaf.taps[::-1])


def test_a_tone_above_nyquist_is_gone_and_one_in_band_is_unchanged_and_undelayed():
    """beam_ch4_exp's 1339 Hz mode at 2048 Hz would fold to 709 Hz; through the filter it is 100 dB down. A 300 Hz
    tone comes out at the same instants (delay compensated) with the passband's ripple."""
    aaf = design(2048.0, 7308.0)
    n = 4096
    t = np.arange((n + aaf.half_samples) * aaf.oversampling) / aaf.modulator_rate
    x = np.stack([np.sin(2 * np.pi * 1339.0 * t), np.sin(2 * np.pi * 300.0 * t + 0.3)], axis=1)
    y = aaf.apply(x, n)
    steady = slice(aaf.half_samples, n)  # after the filter's reach from the signal's start at t = 0
    assert np.abs(y[steady, 0]).max() <= 10 ** (-ATTENUATION_DB / 20)
    tk = np.arange(n) / 2048.0
    assert np.abs(y[steady, 1] - np.sin(2 * np.pi * 300.0 * tk + 0.3)[steady]).max() <= 2e-5  # ripple 1e-5 + fold


def test_the_filtered_pulse_is_the_convolution_integral():
    """Quadrature against a brute-force convolution on a 512-fold grid, and the impulse kept (unit DC gain)."""
    aaf = design(2048.0, 7308.0)
    peak, dur = 1500.0, 1e-3
    force = pulse_train([0.1003], [peak], dur)
    y = filtered_force(aaf, force.t, force.force, 512)
    k = 256
    fine = np.arange(512 * k) / (2048.0 * k)
    h = aaf.kernel(np.arange(-aaf.half_samples * k, aaf.half_samples * k + 1) / (2048.0 * k)) / (2048.0 * k)
    brute = scipy.signal.fftconvolve(force.shape_at(fine), h)[aaf.half_samples * k :: k][:512]
    assert np.abs(y - brute).max() <= 1e-5 * peak  # the fine grid's own error is ~2e-6 of the peak
    # the impulse is kept (unit DC gain; the samples' sum is the integral, the filtered pulse having nothing at fs):
    # the series' own (trapezoidal) impulse, 1.3e-5 below the half-sine's 2 P T / pi for 257 points a pulse
    assert y.sum() / 2048.0 == pytest.approx(np.trapezoid(force.force, force.t), rel=1e-6)
    assert y.sum() / 2048.0 == pytest.approx(2 * peak * dur / np.pi, rel=2e-5)
    assert y.max() < 0.97 * peak  # a 1 ms pulse has content above the 922 Hz passband: the DAQ reads it lower


@pytest.fixture(scope="module")
def beam():
    return open_rig("beam_ch4_exp")


def test_the_device_at_2048_hz_gives_the_in_band_frf_of_16384_hz(beam):
    """In the 2048 Hz band (fs / 2.56 = 800 Hz) the FRFs equal those sampled at 16384 Hz (where nothing folds):
    0.14 % of each channel's peak measured (before the filter: 54 %, the folded 965 and 1339 Hz modes)."""
    sched = HitSchedule.every(2.0, [300.0])
    _, ref = roving_signals(beam, sched, 2.0)
    rig = simulated_rig(beam, 2048.0, {})
    assert daq_filter(rig).oversampling == 5
    _, got = roving_signals(rig, sched, 2.0)
    f = np.fft.rfftfreq(got.shape[0], 1 / 2048.0)
    band = (f > 5.0) & (f < 2048.0 / 2.56)

    def frf(x: np.ndarray) -> np.ndarray:
        spec = np.fft.rfft(x, axis=0)[: f.size]
        return spec[:, 1:] / spec[:, :1]

    h, h_ref = frf(got)[band], frf(ref)[band]
    assert (np.abs(h - h_ref) / np.abs(h_ref).max(axis=0)).max() <= 0.005


def test_gvt_modal_at_2048_hz_reports_no_folded_mode(tmp_path, capsys):
    """A recorded 2048 Hz session of beam_ch4_exp: the modes in the band are the FE's, and nothing sits where the
    1339 Hz mode (709 Hz) or the 965 Hz one (1083 -> 965 is below Nyquist, 1339 folds) would fold."""
    from analysis.model.rig import load_rig
    from daq.cli import run as gvt
    from daq.config.session import AnalysisSpec, DeviceSpec, SessionConfig, TriggerSpec
    from daq.session import run_session

    text = open_rig("beam_ch4_exp").path
    src = open(text).read().replace("sample_rate = 16384.0", "sample_rate = 2048.0")
    assert "sample_rate = 2048.0" in src
    path = tmp_path / "beam2048.toml"
    path.write_text(src)
    cfg = SessionConfig(
        name="aaf-2048", rig=str(path), duration=7.6, analysis=AnalysisSpec(enabled=False),
        device=DeviceSpec(driver="sim", config={"rig": str(path), "sample_rate": 2048.0, "block_size": 256,
                                                "forces": [300.0, 300.0, 300.0], "period": 2.5, "physics_seconds": 8.0,
                                                "seed": 3}),
        trigger=TriggerSpec(level=20.0, record_length=2.0),
    )  # fmt: skip
    out = tmp_path / "s.mcap"
    res = run_session(cfg, load_rig(path), out, frf=False)
    assert res.lost_samples == 0 and len(res.hits) == 3
    assert gvt(["modal", str(out), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["modes"]
    freqs = [r["freq_hz"] for r in rows]
    assert not any(abs(f - (2048.0 - 1339.0)) < 15.0 for f in freqs), freqs
    # modes 2-5 at the FE's frequencies (mode 1 moves with the hit level: beam_ch4_exp's attachment spring is cubic)
    fe = [r["fe_mode"] for r in rows if r.get("fe_mode") is not None and abs(r["freq_error"]) < 5e-3]
    assert {2, 3, 4, 5} <= set(fe), [(r["freq_hz"], r.get("fe_mode")) for r in rows]
