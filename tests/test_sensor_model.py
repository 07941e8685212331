"""Sensor/DAQ front-end model: sensitivity, range, quantisation, noise, seeded randomness."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from drivers.sim.sensor_model import AdcModel, ChannelModel, measure

ACC = ChannelModel("a", "acceleration", "m/s^2", sensitivity_v_per_unit=1.02e-3, range=4905.0, noise_rms=0.0)


def test_quantisation_step_is_one_lsb_over_sensitivity():
    adc = AdcModel(bits=16, input_range_volts=10.0)
    x = np.linspace(-100, 100, 10001)[:, None]
    m = measure(x, [ACC], adc, np.random.default_rng(0))
    step = adc.lsb_volts / ACC.sensitivity_v_per_unit
    assert np.max(np.abs(m.data[:, 0] - x[:, 0])) <= 0.5 * step * (1 + 1e-6) + 1e-4
    levels = np.unique(np.round(m.data[:, 0] / step))
    assert np.allclose(np.diff(levels), 1.0)


def test_sensor_range_and_adc_range_clip_and_are_counted():
    adc = AdcModel(bits=24, input_range_volts=2.0)  # 2 V / 1.02 mV = 1961 m/s^2 < sensor range
    x = np.array([[0.0], [1000.0], [3000.0], [-6000.0]])
    m = measure(x, [ACC], adc, np.random.default_rng(0))
    assert m.clip_counts == {"a": 2}
    assert m.data[2, 0] == pytest.approx(2.0 / 1.02e-3, rel=1e-5)
    assert m.data[3, 0] == pytest.approx(-2.0 / 1.02e-3, rel=1e-5)


def test_noise_is_seeded_and_has_the_set_rms():
    ch = ChannelModel("a", "acceleration", "m/s^2", 1.02e-3, noise_rms=0.5)
    adc = AdcModel(bits=24)
    x = np.zeros((200000, 1))
    a = measure(x, [ch], adc, np.random.default_rng(7)).data
    b = measure(x, [ch], adc, np.random.default_rng(7)).data
    c = measure(x, [ch], adc, np.random.default_rng(8)).data
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.std(a) == pytest.approx(0.5, rel=0.01)


def test_bad_models_raise():
    with pytest.raises(ValueError):
        ChannelModel("a", "acceleration", "m/s^2", 0.0)
    with pytest.raises(ValueError):
        AdcModel(bits=1)
    with pytest.raises(ValueError):
        measure(np.zeros((3, 2)), [ACC], AdcModel(), np.random.default_rng(0))


@given(arrays(np.float64, st.tuples(st.integers(1, 50), st.just(1)), elements=st.floats(-1e6, 1e6)))
def test_property_output_is_bounded_by_the_ranges(x):
    adc = AdcModel(bits=12, input_range_volts=5.0)
    m = measure(x, [ACC], adc, np.random.default_rng(0))
    bound = min(ACC.range, 5.0 / ACC.sensitivity_v_per_unit) * (1 + 1e-6)
    assert np.all(np.abs(m.data) <= bound)
    assert m.data.dtype == np.float32


def test_sensor_faults_hum_polarity_stuck_as_the_session_device_makes_them():
    """Issue 29: hum on a channel is a line at 50 Hz + harmonics of the stated RMS whose phase runs on the device's
    clock (two blocks made apart join the one made whole), a reversed sensor reads -x, a stuck one its value."""
    from drivers.sim.faults import SensorFaults

    fs, n = 4096.0, 4096
    chans = SensorFaults(50.0, {"a": 0.3}, ("b",), {"c": 0.37}).apply(
        [ChannelModel(name, "acceleration", "m/s^2", 1.02e-3) for name in "abcd"]
    )
    x = np.tile(np.sin(2 * np.pi * 20 * np.arange(n) / fs)[:, None], (1, 4))
    adc = AdcModel(bits=24, input_range_volts=10.0)
    whole = measure(x, chans, adc, np.random.default_rng(0), fs=fs).data
    parts = np.concatenate([measure(x[a : a + 1000], chans, adc, np.random.default_rng(0), fs=fs, first_index=a).data
                            for a in range(0, n, 1000)])  # fmt: skip
    assert np.allclose(parts, whole, atol=1e-3)  # one quantisation step (10 V / 2^23 / 1.02 mV = 1.2e-3)
    hum = whole[:, 0] - x[:, 0]
    assert np.sqrt(np.mean(hum**2)) == pytest.approx(0.3, rel=0.01)
    spec = np.abs(np.fft.rfft(hum)) / n  # 1 Hz bins over 1 s
    assert set(np.argsort(spec)[-4:]) == {50, 100, 150, 200}
    assert np.allclose(whole[:, 1], -x[:, 1], atol=2e-3) and np.all(whole[:, 2] == np.float32(0.37))
    assert np.allclose(whole[:, 3], x[:, 3], atol=2e-3)
    with pytest.raises(ValueError, match="no channel 'z'"):
        SensorFaults(reversed=("z",)).apply(chans)
