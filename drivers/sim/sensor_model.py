"""Sensor and DAQ front-end model for the simulated device: what a real chain does to a signal.

Per channel, in this order: polarity (a sensor mounted or wired the wrong way round reads ``-x``) → sensor
noise floor (rms, SI units, seeded) → sensor measurement range (the transducer saturates) → mains hum picked
up in the cable (``hum_hz`` and 3 harmonics, ``hum_rms`` in SI units, on the stream's sample clock so blocks
made apart join; analysis/lines.py) → sensitivity (mV per unit) → ADC input range (clips in volts) → ADC
quantisation (``bits`` over ± input range) → back to SI units with the nominal sensitivity, as a DAQ
with calibration applied reports it; a stuck channel (``stuck_at``) reads that one value whatever comes in
(a hung ADC channel or a failed IEPE bias). Faults are set per channel by drivers/sim/faults.py
(:class:`~drivers.sim.faults.SensorFaults`). Clipping is counted per channel, never hidden: the seed lost its
9th accelerometer to saturation in every run and found out afterwards (L1320).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.lines import hum_waveform
from analysis.model.beam import FloatArray

#: the hum's fundamental and harmonics 2-4 in these proportions (analysis/evaluation/errors.py HUM_PROFILE)
HUM_PROFILE = (1.0, 0.5, 0.35, 0.25)


@dataclass(frozen=True)
class ChannelModel:
    name: str
    quantity: str
    unit: str
    sensitivity_v_per_unit: float
    range: float | None = None  # ± SI units; None = the ADC is the only limit
    noise_rms: float = 0.0  # SI units
    hum_hz: float = 0.0  # mains pickup: its fundamental (50 or 60 Hz), 0 = none
    hum_rms: float = 0.0  # ... and the RMS of the fundamental and 3 harmonics together, SI units
    polarity: int = 1  # -1: mounted or wired the wrong way round
    stuck_at: float | None = None  # the one value a stuck channel reads (SI units)

    def __post_init__(self) -> None:
        if self.polarity not in (1, -1) or self.hum_hz < 0 or self.hum_rms < 0:
            raise ValueError(f"channel {self.name}: polarity is 1 or -1, hum_hz and hum_rms >= 0")
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


def measure(
    physical: FloatArray, channels: Sequence[ChannelModel], adc: AdcModel, rng: np.random.Generator, *,
    fs: float | None = None, first_index: int = 0,
) -> Measurement:  # fmt: skip
    """Pass true signals ``(n_samples, n_channels)`` through sensors and ADC. ``fs`` and ``first_index`` (the first
    sample's index on the device's clock) place the hum's phase; needed only when a channel has hum."""
    x = np.asarray(physical, dtype=float)
    if x.ndim != 2 or x.shape[1] != len(channels):
        raise ValueError(f"expected (n_samples, {len(channels)}) physical signals, got {x.shape}")
    out = np.empty(x.shape, dtype=np.float32)
    clipped = np.zeros(x.shape, dtype=bool)
    lsb = adc.lsb_volts
    vmax = adc.input_range_volts
    top_code = 2 ** (adc.bits - 1) - 1
    for k, ch in enumerate(channels):
        col = x[:, k] * ch.polarity
        if ch.noise_rms > 0:
            col = col + rng.normal(0.0, ch.noise_rms, size=col.shape)
        if ch.range is not None:
            clipped[:, k] |= np.abs(col) > ch.range
            col = np.clip(col, -ch.range, ch.range)
        if ch.hum_hz > 0 and ch.hum_rms > 0:
            if fs is None:
                raise ValueError(f"channel {ch.name} has hum: measure() needs the sample rate (fs)")
            p = np.asarray(HUM_PROFILE)
            amps = p * ch.hum_rms / np.sqrt(0.5 * np.sum(p**2))
            phases = np.random.default_rng([k, 29]).uniform(0, 2 * np.pi, p.size)  # per channel, fixed: the same every block
            col = col + hum_waveform(col.size, fs, ch.hum_hz, amps, phases, first_index)
        volts = col * ch.sensitivity_v_per_unit
        clipped[:, k] |= np.abs(volts) > vmax
        codes = np.clip(np.round(volts / lsb), -top_code - 1, top_code)
        out[:, k] = (codes * lsb / ch.sensitivity_v_per_unit).astype(np.float32)
        if ch.stuck_at is not None:
            out[:, k] = np.float32(ch.stuck_at)
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
