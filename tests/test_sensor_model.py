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
