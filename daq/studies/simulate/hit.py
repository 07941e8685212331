"""``gvt simulate``: one hit through the simulator and the sensor/DAQ model into an .npz file."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from analysis.model.rig import Rig, channel_signals
from daq.outputs import atomic_output
from drivers.sim.sensor_model import AdcModel, channel_models_for, measure


def simulate_hit(rig: Rig, force: float | None = None, duration: float | None = None, seed: int | None = None):
    """Simulate one hit; returns (result, channels, measurement)."""
    dur = rig.config.daq.record_length if duration is None else duration
    res = rig.simulator.run(rig.hammer_force(force), dur, rig.sample_rate)
    placed, physical = channel_signals(rig, res)
    models = channel_models_for(placed)
    adc = AdcModel(bits=rig.config.daq.adc_bits, input_range_volts=rig.config.daq.input_range_volts)
    rng = np.random.default_rng(rig.config.simulation.seed if seed is None else seed)
    meas = measure(physical, models, adc, rng)
    return res, models, meas, physical


def simulate_to_npz(
    rig: Rig, path: Path, force: float | None = None, duration: float | None = None, seed: int | None = None
) -> str:
    t0 = time.perf_counter()
    res, models, meas, physical = simulate_hit(rig, force, duration, seed)
    elapsed = time.perf_counter() - t0
    e = res.energy
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:  # a full disk: one line, the previous file kept, no .part
        np.savez_compressed(
            fh,
            t=res.t,
            sample_rate=res.sample_rate,
            channel_names=np.array([m.name for m in models]),
            channel_units=np.array([m.unit for m in models]),
            channel_quantities=np.array([m.quantity for m in models]),
            measured=meas.data,
            clipped_samples=meas.clipped.sum(axis=0),
            true=physical,
            modal_q=res.modal_q[0],
            modal_v=res.modal_v[0],
            modal_energy=res.modal_energy[0],
            mode_frequencies_hz=res.mode_frequencies_hz,
            energy_kinetic=e.kinetic[0],
            energy_potential_linear=e.potential_linear[0],
            energy_potential_nonlinear=e.potential_nonlinear[0],
            energy_dissipated=e.dissipated[0],
            energy_input_work=e.input_work[0],
            peak_force=res.amplitudes[0],
            rig_name=rig.name,
            rig_toml=Path(rig.path).read_text() if Path(rig.path).exists() else "",
        )
    clipped = {k: v for k, v in meas.clip_counts.items() if v}
    clip_txt = "none" if not clipped else ", ".join(f"{k}: {v} samples" for k, v in clipped.items())
    return (
        f"wrote {path}: {len(res.t)} samples x {len(models)} channels at {res.sample_rate:g} Hz, "
        f"peak force {res.amplitudes[0]:g} N, input energy {e.input_work[0, -1]:.4g} J, "
        f"clipped: {clip_txt}; simulated in {elapsed:.2f} s"
    )
