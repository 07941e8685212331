"""The simulated DAQ device: the foundation's simulator plus sensor model behind a sample-exact clock.

The device's physics is computed ahead for ``duration`` seconds (one continuous simulation under the
scheduled hammer pulses, through the DAQ's anti-alias filter and the sensor/DAQ model: a real DAQ's
sigma-delta decimation filter, group delay compensated, analysis.model.antialias); after that it keeps producing the sensor
noise floor of a structure at rest, so it runs for ever. Its clock is sample-exact: at device time t
exactly ``floor(t * fs)`` samples exist — no drift, no rounding accumulation — and block k holds
samples ``[k * block_size, (k + 1) * block_size)``. Transports (serial, CAN, Modbus) read blocks from
here and apply their own encoding and fault knobs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.model.antialias import AntiAliasFilter, design, filtered_force
from analysis.model.forces import ForceSeries, pulse_train
from analysis.model.rig import Rig, channel_signals
from drivers.sim.faults import SensorFaults
from drivers.sim.sensor_model import AdcModel, ChannelModel, channel_models_for, measure


@dataclass(frozen=True)
class HitSchedule:
    """Hit times and peak forces; ``dofs`` (optional) the model DOF each hit lands on (a roving hammer,
    daq/roving.py), else every hit is at the rig's hammer DOF."""

    times_s: tuple[float, ...]
    forces_n: tuple[float, ...]
    dofs: tuple[int, ...] | None = None

    @classmethod
    def every(cls, period: float, forces: Sequence[float], first: float = 0.2) -> HitSchedule:
        return cls(tuple(first + k * period for k in range(len(forces))), tuple(float(f) for f in forces))


def simulator_at(rig: Rig, dof: int):
    """The rig's simulator with the force at model DOF ``dof`` instead of the hammer's (same settings and modes)."""
    if dof == rig.hammer.dof:
        return rig.simulator
    from analysis.model.simulate import ImpactSimulator

    sim = rig.config.simulation
    return ImpactSimulator(rig.structure, dof, rig.sensor_dofs, cutoff_hz=sim.modal_cutoff_hz,
                           residual_vectors=sim.residual_vectors, max_omega_dt=sim.max_omega_dt, order=sim.order,
                           modes=rig.modes)  # fmt: skip


def daq_filter(rig: Rig, sims=()) -> AntiAliasFilter:
    """The anti-alias filter of the rig's simulated DAQ (analysis.model.antialias): its modulator rate keeps every
    basis frequency of ``sims`` (default the rig's simulator) from folding below 0.55 fs."""
    top = max(float(s.reduced.omega.max()) for s in (sims or (rig.simulator,))) / (2.0 * np.pi)
    return design(rig.sample_rate, top)


def filtered_signals(rig: Rig, sim, force: ForceSeries, n: int, aaf: AntiAliasFilter) -> np.ndarray:
    """Physical signals (hammer, then sensors) of one simulation under ``force`` from t = 0, ``n`` samples at
    fs, as the DAQ's filter delivers them: the force and its instantaneous share of each accelerometer
    filtered exactly (the pulse's broadband tail never folds), the rest simulated at the modulator rate and
    filtered there (analysis.model.antialias). Group delay compensated: sample k is the signal at k / fs."""
    r, fs = aaf.oversampling, rig.sample_rate
    extra = aaf.half_samples if r > 1 else 0  # the FIR looks half its length ahead
    res = sim.run(force, (n + extra) / fs, r * fs, amplitudes=[1.0])
    _, x = channel_signals(rig, res)
    gain = np.array([1.0] + [c if s.quantity == "acceleration" else 0.0
                             for s, c in zip(rig.sensors, sim.feedthrough, strict=True)])  # fmt: skip
    # filter(x - F g) + filtered(F) g, with the filter linear: filter(x) plus a correction that is zero away from
    # the pulses, so it costs one pass over the samples (none when R is 1)
    y = aaf.apply(x, n) if aaf.oversampling > 1 else x[:n]
    delta = filtered_force(aaf, force.t, force.force, n) - aaf.apply(res.force[0][:, None], n)[:, 0]
    live = np.flatnonzero(delta)
    y[live] += delta[live, None] * gain[None, :]
    return y


def simulators(rig: Rig, schedule: HitSchedule) -> dict[int, object]:
    """The simulator of each DOF the schedule hits, in order of first hit."""
    dofs = schedule.dofs if schedule.dofs is not None else (rig.hammer.dof,)
    return {dof: simulator_at(rig, dof) for dof in dict.fromkeys(dofs)}


def roving_signals(rig: Rig, schedule: HitSchedule, duration: float, aaf: AntiAliasFilter | None = None,
                   sims: dict[int, object] | None = None) -> tuple[list, np.ndarray]:  # fmt: skip
    """Physical signals (hammer, then sensors) of the scheduled hits, each at its own DOF, through the DAQ filter.

    One simulation per DOF hit, over the span from that DOF's first hit, summed: exact for a linear structure
    (superposition; the hammer channel is the sum of the forces, wherever they land; the filter is linear too).
    With nonlinear springs it neglects the coupling of one point's ring-down with the next point's hits; a
    roving test spaces its hits by a record, so that ring-down is small, but the sum is then an approximation
    (docs/session.md)."""
    pulse = rig.config.hammer.pulse_duration
    n = max(2, round(duration * rig.sample_rate))
    placed = [rig.hammer, *rig.sensors]
    sims = sims or simulators(rig, schedule)
    aaf = aaf or daq_filter(rig, tuple(sims.values()))
    if schedule.dofs is None:  # the fixed hammer: one simulation
        return placed, filtered_signals(rig, rig.simulator, pulse_train(schedule.times_s, schedule.forces_n, pulse), n, aaf)
    dofs = schedule.dofs
    total = np.zeros((n, 1 + len(rig.sensors)))
    for dof, sim in sims.items():
        ks = [k for k, d in enumerate(dofs) if d == dof]
        # start a whole number of samples before this DOF's first hit and the filter's reach: before it, zero
        i0 = max(0, int(np.floor((schedule.times_s[ks[0]] - 0.01 - aaf.delay_s) * rig.sample_rate)))
        t0 = i0 / rig.sample_rate
        force = pulse_train([schedule.times_s[k] - t0 for k in ks], [schedule.forces_n[k] for k in ks], pulse)
        total[i0:] += filtered_signals(rig, sim, force, n - i0, aaf)
    return placed, total


class SimulatedDevice:
    def __init__(self, rig: Rig, schedule: HitSchedule, duration: float, *, block_size: int = 256, seed: int = 0,
                 sensor_faults: SensorFaults | None = None) -> None:  # fmt: skip
        """``sensor_faults``: hum, reversed polarity, stuck channels (drivers/sim/faults.py), carried by every
        sample the device serves, the rest noise after the simulated span included (the hum on the device's clock)."""
        self.rig = rig
        self.fs = rig.sample_rate
        self.block_size = int(block_size)
        self.schedule = schedule
        self.seed = seed
        n = max(1, round(duration * self.fs))
        #: the DAQ's anti-alias filter (analysis.model.antialias): what a report states about it, ``facts()``
        sims = simulators(rig, schedule)
        self.anti_alias = daq_filter(rig, tuple(sims.values()))
        if schedule.times_s:
            placed, physical = roving_signals(rig, schedule, n / self.fs, self.anti_alias, sims)
        else:
            placed = [rig.hammer, *rig.sensors]
            physical = np.zeros((n, len(placed)))
        self.channel_models: list[ChannelModel] = channel_models_for(placed)
        if sensor_faults is not None:
            self.channel_models = sensor_faults.apply(self.channel_models)
        self.channels = tuple(m.name for m in self.channel_models)
        self.units = tuple(m.unit for m in self.channel_models)
        self.adc = AdcModel(bits=rig.config.daq.adc_bits, input_range_volts=rig.config.daq.input_range_volts)
        self._rng = np.random.default_rng(seed)
        meas = measure(physical, self.channel_models, self.adc, self._rng, fs=self.fs)
        self._data = meas.data
        self._lock = threading.Lock()
        self._t0: float | None = None

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    def samples(self, start: int, stop: int) -> np.ndarray:
        """Samples ``[start, stop)`` (float32, SI units); deterministic for the same seed."""
        n_pre = self._data.shape[0]
        out = np.empty((stop - start, self.n_channels), np.float32)
        a, b = max(start, 0), min(stop, n_pre)
        if b > a:
            out[a - start : b - start] = self._data[a:b]
        if stop > n_pre:
            lo = max(start, n_pre)
            # At rest after the simulated span: the noise floor, generated in whole aligned blocks seeded by
            # the block number, so any request for the same samples returns the same values.
            bs = self.block_size
            for j in range(lo // bs, (stop - 1) // bs + 1):
                rng = np.random.default_rng([self.seed, j])
                noise = measure(np.zeros((bs, self.n_channels)), self.channel_models, self.adc, rng, fs=self.fs,
                                first_index=j * bs).data  # fmt: skip
                a0, a1 = max(lo, j * bs), min(stop, (j + 1) * bs)
                out[a0 - start : a1 - start] = noise[a0 - j * bs : a1 - j * bs]
        return out

    def block(self, k: int) -> np.ndarray:
        return self.samples(k * self.block_size, (k + 1) * self.block_size)

    # --- the clock --------------------------------------------------------------------------
    def start_clock(self, t0: float | None = None) -> None:
        self._t0 = time.monotonic() if t0 is None else t0

    def samples_available(self, now: float | None = None) -> int:
        """Samples that exist at device time ``now``: exactly floor(t * fs)."""
        if self._t0 is None:
            raise RuntimeError("start_clock() first")
        t = (time.monotonic() if now is None else now) - self._t0
        return max(0, int(np.floor(t * self.fs + 1e-9)))

    def blocks_available(self, now: float | None = None) -> int:
        return self.samples_available(now) // self.block_size

    def time_of_block(self, k: int) -> float:
        """Monotonic time at which block k is complete."""
        assert self._t0 is not None
        return self._t0 + (k + 1) * self.block_size / self.fs


class DelayedDeviceView:
    """A second DAQ device looking at the same simulated structure, its clock started later.

    Why: the seed's Ch. 6 test had the hammer on one acquisition system and the accelerometers on
    another, with independent sample clocks. Two :class:`SimulatedDevice` objects would simulate two
    structures; a view shares one. The view's sample ``k`` is the base device's sample
    ``k + delay_samples``, and its clock is bound to the base's: its sample 0 exists exactly
    ``delay_samples / fs`` after the base's sample 0. So the true offset between two views is known to
    the sample (the oracle of the two-device tests), and every transport server works on a view
    unchanged (same interface as SimulatedDevice: fs, channels, channel_models, adc, samples(),
    start_clock(), samples_available(), ``_t0`` ...).
    """

    def __init__(self, device: SimulatedDevice, delay_samples: int) -> None:
        if delay_samples < 0:
            raise ValueError("delay_samples must be >= 0 (a view starts at or after its base device)")
        self.base = device
        self.delay_samples = int(delay_samples)
        self.rig = device.rig
        self.fs = device.fs
        self.block_size = device.block_size
        self.schedule = device.schedule
        self.seed = device.seed
        self.channel_models = device.channel_models
        self.channels = device.channels
        self.units = device.units
        self.adc = device.adc
        self.anti_alias = device.anti_alias
        self._t0: float | None = None

    @property
    def n_channels(self) -> int:
        return self.base.n_channels

    @property
    def delay_s(self) -> float:
        return self.delay_samples / self.fs

    def samples(self, start: int, stop: int) -> np.ndarray:
        return self.base.samples(start + self.delay_samples, stop + self.delay_samples)

    def block(self, k: int) -> np.ndarray:
        return self.samples(k * self.block_size, (k + 1) * self.block_size)

    def start_clock(self, t0: float | None = None) -> None:
        """Switch this device on. Its sample 0 is ``delay_s`` after the base's sample 0; the base clock is
        started (at ``t0`` or now) if it is not running yet, and never restarted: several views of one
        base may be started in any order and keep their exact relative offset."""
        if self.base._t0 is None:
            self.base.start_clock(t0)
        assert self.base._t0 is not None
        self._t0 = self.base._t0 + self.delay_samples / self.fs

    def samples_available(self, now: float | None = None) -> int:
        if self._t0 is None:
            raise RuntimeError("start_clock() first")
        return max(0, self.base.samples_available(now) - self.delay_samples)

    def blocks_available(self, now: float | None = None) -> int:
        return self.samples_available(now) // self.block_size

    def time_of_block(self, k: int) -> float:
        assert self._t0 is not None
        return self._t0 + (k + 1) * self.block_size / self.fs
