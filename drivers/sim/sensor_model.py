"""Sensor and DAQ front-end model for the simulated device: what a real chain does to a signal.

Per channel, in this order: sensor noise floor (rms, SI units, seeded) → sensor measurement range
(the transducer saturates) → sensitivity (mV per unit) → ADC input range (clips in volts) → ADC
quantisation (``bits`` over ± input range) → back to SI units with the nominal sensitivity, as a DAQ
with calibration applied reports it. Clipping is counted per channel, never hidden: the seed lost its
9th accelerometer to saturation in every run and found out afterwards (L1320).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.model.beam import FloatArray


@dataclass(frozen=True)
class ChannelModel:
    name: str
    quantity: str
    unit: str
    sensitivity_v_per_unit: float
    range: float | None = None  # ± SI units; None = the ADC is the only limit
    noise_rms: float = 0.0  # SI units

    def __post_init__(self) -> None:
        if self.sensitivity_v_per_unit <= 0:
            raise ValueError(f"channel {self.name}: sensitivity must be positive")
        if self.range is not None and self.range <= 0:
            raise ValueError(f"channel {self.name}: range must be positive")
        if self.noise_rms < 0:
            raise ValueError(f"channel {self.name}: noise must be >= 0")


@dataclass(frozen=True)
class AdcModel:
    bits: int = 24
    input_range_volts: float = 10.0

    def __post_init__(self) -> None:
        if not 2 <= self.bits <= 32:
            raise ValueError("ADC bits must lie in [2, 32]")
        if self.input_range_volts <= 0:
            raise ValueError("ADC input range must be positive")

    @property
    def lsb_volts(self) -> float:
        return 2.0 * self.input_range_volts / 2**self.bits


@dataclass(frozen=True)
class Measurement:
    data: np.ndarray  # float32 (n_samples, n_channels), SI units
    clipped: np.ndarray  # bool (n_samples, n_channels): sensor or ADC saturated at that sample
    channels: tuple[ChannelModel, ...]

    @property
    def clip_counts(self) -> dict[str, int]:
        return {c.name: int(n) for c, n in zip(self.channels, self.clipped.sum(axis=0), strict=True)}


def measure(physical: FloatArray, channels: Sequence[ChannelModel], adc: AdcModel, rng: np.random.Generator) -> Measurement:
    """Pass true signals ``(n_samples, n_channels)`` through sensors and ADC."""
    x = np.asarray(physical, dtype=float)
    if x.ndim != 2 or x.shape[1] != len(channels):
        raise ValueError(f"expected (n_samples, {len(channels)}) physical signals, got {x.shape}")
    out = np.empty(x.shape, dtype=np.float32)
    clipped = np.zeros(x.shape, dtype=bool)
    lsb = adc.lsb_volts
    vmax = adc.input_range_volts
    top_code = 2 ** (adc.bits - 1) - 1
    for k, ch in enumerate(channels):
        col = x[:, k]
        if ch.noise_rms > 0:
            col = col + rng.normal(0.0, ch.noise_rms, size=col.shape)
        if ch.range is not None:
            clipped[:, k] |= np.abs(col) > ch.range
            col = np.clip(col, -ch.range, ch.range)
        volts = col * ch.sensitivity_v_per_unit
        clipped[:, k] |= np.abs(volts) > vmax
        codes = np.clip(np.round(volts / lsb), -top_code - 1, top_code)
        out[:, k] = (codes * lsb / ch.sensitivity_v_per_unit).astype(np.float32)
    return Measurement(data=out, clipped=clipped, channels=tuple(channels))


def channel_models_for(placed) -> list[ChannelModel]:
    """ChannelModels from a rig's placed channels (``analysis.model.rig.PlacedChannel``)."""
    return [
        ChannelModel(
            name=p.name,
            quantity=p.quantity,
            unit=p.unit,
            sensitivity_v_per_unit=p.props.sensitivity_mv_per_unit * 1e-3,
            range=p.props.range,
            noise_rms=p.props.noise_rms,
        )
        for p in placed
    ]
