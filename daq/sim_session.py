"""``gvt simulate RIG --hits N --out session.mcap``: a whole simulated impact session in the log format.

One continuous simulation of the rig under a train of hammer pulses (so each hit starts from the
previous one's tail, as on a real structure), passed through the sensor/DAQ model and cut into
sample blocks at the rig's DAQ rate. The log gets the blocks, one hit record per pulse (from the
simulator: the session issue adds the real trigger), calibration metadata, the rig file as an
attachment, and ground truth on ``/sim/...``: per block, the linear modal energies and the energy
budget at the block's last sample; per hit, the input work.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.model.forces import pulse_train
from analysis.model.rig import Rig, channel_signals
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import BlockStatus, SampleBlock
from drivers.sim.sensor_model import AdcModel, channel_models_for, measure

STREAM = "dev0"


@dataclass(frozen=True)
class SessionPlan:
    forces: tuple[float, ...]
    pre_trigger: float  # s of quiet before the first hit
    spacing: float  # s between hits
    tail: float  # s after the last hit
    block_size: int

    @property
    def hit_times(self) -> list[float]:
        return [self.pre_trigger + k * self.spacing for k in range(len(self.forces))]

    @property
    def duration(self) -> float:
        return self.pre_trigger + (len(self.forces) - 1) * self.spacing + self.tail


def default_forces(rig: Rig, n_hits: int) -> tuple[float, ...]:
    """Rising force from 10 % to 100 % of the rig's nominal hit, as a GVT engineer would hit."""
    peak = rig.config.hammer.peak_force
    if n_hits == 1:
        return (peak,)
    return tuple(float(f) for f in np.linspace(0.1 * peak, peak, n_hits))


def channel_infos(rig: Rig) -> list[ChannelInfo]:
    return [
        ChannelInfo(
            name=p.name,
            quantity=p.quantity,
            unit=p.unit,
            sensitivity_mv_per_unit=p.props.sensitivity_mv_per_unit,
            position_m=p.x_model,
            model_dof=p.dof_name,
            sensor_model=p.props.model,
        )
        for p in [rig.hammer, *rig.sensors]
    ]


def simulate_session(
    rig: Rig,
    out: Path,
    plan: SessionPlan,
    seed: int | None = None,
    progress: Callable[[str, float], None] | None = None,
    writer_kwargs: dict | None = None,
) -> dict:
    fs = rig.sample_rate
    hits = plan.hit_times
    force = pulse_train(hits, plan.forces, rig.config.hammer.pulse_duration)
    if progress:
        progress("simulating", 0.0)
    res = rig.simulator.run(force, plan.duration, fs, amplitudes=[1.0])
    placed, physical = channel_signals(rig, res)
    models = channel_models_for(placed)
    adc = AdcModel(bits=rig.config.daq.adc_bits, input_range_volts=rig.config.daq.input_range_volts)
    meas = measure(physical, models, adc, np.random.default_rng(rig.config.simulation.seed if seed is None else seed))
    names = tuple(m.name for m in models)
    n = meas.data.shape[0]
    e = res.energy
    with LogWriter(out, **(writer_kwargs or {})) as w:
        w.add_stream(STREAM, channel_infos(rig), fs, t0_ns=0)
        w.add_metadata(
            "gvtlink.simulation",
            {
                "rig": rig.name,
                "seed": str(rig.config.simulation.seed if seed is None else seed),
                "forces_N": json.dumps(list(plan.forces)),
                "hit_times_s": json.dumps(hits),
                "mode_frequencies_hz": json.dumps(res.mode_frequencies_hz[:10].tolist()),
            },
        )
        rig_path = Path(rig.path)
        if rig_path.exists():
            w.add_attachment(f"rig/{rig_path.name}", rig_path.read_bytes(), "application/toml")
        n_modes = min(10, res.modal_q.shape[-1])
        for start in range(0, n, plan.block_size):
            stop = min(n, start + plan.block_size)
            block = meas.data[start:stop]
            status = BlockStatus.CLIPPED if meas.clipped[start:stop].any() else BlockStatus.OK
            w.write_block(SampleBlock(STREAM, start, fs, names, block, status), wait=True)  # offline: back-pressure
            last = stop - 1
            w.write_json(
                "/sim/energy",
                {
                    "index": int(last),
                    "modal_energy_J": res.modal_energy[0, last, :n_modes].tolist(),
                    "kinetic_J": float(e.kinetic[0, last]),
                    "potential_linear_J": float(e.potential_linear[0, last]),
                    "potential_nonlinear_J": float(e.potential_nonlinear[0, last]),
                    "dissipated_J": float(e.dissipated[0, last]),
                    "input_work_J": float(e.input_work[0, last]),
                },
                log_time_ns=round(last * 1e9 / fs),
            )
            if progress:
                progress("writing", stop / n)
        dur = rig.config.hammer.pulse_duration
        for k, (t0, peak) in enumerate(zip(hits, plan.forces, strict=True)):
            i0 = int(np.ceil(t0 * fs))
            i1 = min(n - 1, int(np.floor((t0 + dur) * fs)) + 1)
            work = float(e.input_work[0, i1] - e.input_work[0, max(i0 - 1, 0)])
            hit = {
                "hit": k,
                "index": i0,
                "t_s": i0 / fs,
                "peak_force_N": float(peak),
                "pulse_width_s": dur,
                "input_energy_J": work,
                "verdict": "accepted",
                "source": "simulator",
            }
            w.write_hit(hit)
            w.write_json("/sim/hits", hit, log_time_ns=round(i0 * 1e9 / fs))
        clipped = {k: v for k, v in meas.clip_counts.items() if v}
        for name, count in clipped.items():
            w.write_event("overload", stream=STREAM, count=count, message=f"channel {name} clipped on {count} samples")
    return {
        "samples": n,
        "channels": len(names),
        "hits": len(hits),
        "duration_s": n / fs,
        "clipped": clipped,
        "energies_J": [
            float(x)
            for x in np.diff(np.concatenate([[0.0], e.input_work[0, [min(n - 1, int((t + dur) * fs) + 1) for t in hits]]]))
        ],
    }
