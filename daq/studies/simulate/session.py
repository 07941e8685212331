"""``gvt simulate RIG --hits N --out session.mcap``: a whole simulated impact session in the log format.

One continuous simulation of the rig under a train of hammer pulses (so each hit starts from the
previous one's tail, as on a real structure), passed through the sensor/DAQ model and cut into
sample blocks at the rig's DAQ rate. The log gets the blocks, one hit record per pulse (from the
simulator: the session issue adds the real trigger), calibration metadata, the rig file as an
attachment, and ground truth on ``/sim/...``: per block, the linear modal energies and the energy
budget at the block's last sample; per hit, the input work.

The session is computed and written in segments of whole blocks (the integrator continues from the
state at the end of the previous one: ``ImpactSimulator.run_segments``), so memory stays bounded however
long it is. Each channel draws, segment by segment, the stretch of the seed's noise stream a one-piece
run gives it (:func:`channel_noise`), so the log does not depend on the segment length.

Time base: a simulated session has no wall clock to tie to, so its origin is fixed at 0 (the Unix epoch;
``gvtlink.time`` says so): every ``log_time`` is the session time in ns — blocks at their first sample, hits
at their first sample, ``/sim/*`` at the sample they describe, events at the data time reached — and the
same seed gives the same times.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.model.forces import pulse_train
from analysis.model.rig import Rig, channel_signals
from analysis.records import Hit, SimEnergy
from daq.log import layout
from daq.log.rig import channel_infos
from daq.log.writer import LogWriter
from drivers.blocks import BlockStatus, SampleBlock
from drivers.sim.sensor_model import AdcModel, Measurement, channel_models_for, measure

STREAM = "dev0"
SEGMENT_SAMPLES = 16384  # samples simulated and written at a time (rounded up to whole blocks): 1 s at 16384 Hz


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


def channel_noise(seed: int, models, n: int, chunk: int = 1 << 20) -> list[np.random.Generator]:
    """Per channel, a generator at the start of that channel's stretch of the seed's noise stream: the noise
    a one-piece run draws (drivers.sim.sensor_model.measure: all ``n`` samples of the first noisy channel,
    then of the next ...). Found by one pass over the stream in chunks of ``chunk`` normals (numpy's
    ``Generator.normal`` draws ``a`` then ``b`` samples exactly as it draws ``a + b``), so each channel can
    then draw its noise segment by segment and the log does not depend on the segment length."""
    shared = np.random.default_rng(seed)
    gens = []
    for ch in models:
        g = np.random.Generator(type(shared.bit_generator)())
        g.bit_generator.state = shared.bit_generator.state
        gens.append(g)
        if ch.noise_rms > 0:  # a channel without noise draws nothing
            for left in range(n, 0, -chunk):
                shared.standard_normal(min(chunk, left))
    return gens


def measure_segment(physical: np.ndarray, models, adc: AdcModel, noise: list[np.random.Generator]) -> Measurement:
    """The sensor/DAQ model (drivers.sim.sensor_model.measure) on consecutive samples ``(m, n_channels)``,
    channel k drawing its noise from ``noise[k]``."""
    cols = [measure(physical[:, k : k + 1], [ch], adc, noise[k]) for k, ch in enumerate(models)]
    return Measurement(
        data=np.concatenate([c.data for c in cols], axis=1),
        clipped=np.concatenate([c.clipped for c in cols], axis=1),
        channels=tuple(models),
    )


def simulate_session(
    rig: Rig,
    out: Path,
    plan: SessionPlan,
    seed: int | None = None,
    progress: Callable[[str, float], None] | None = None,
    writer_kwargs: dict | None = None,
    segment: int = SEGMENT_SAMPLES,
) -> dict:
    """Simulate the session into the log at ``out`` in segments of about ``segment`` samples (a whole number
    of blocks), each written as soon as it is computed: memory is bounded by one segment for any duration.
    Returns the summary ``gvt simulate`` prints."""
    fs = rig.sample_rate
    hits = plan.hit_times
    force = pulse_train(hits, plan.forces, rig.config.hammer.pulse_duration)
    seed = rig.config.simulation.seed if seed is None else seed
    sim = rig.simulator
    n = sim.n_samples(plan.duration, fs)
    seg = plan.block_size * max(1, -(-int(segment) // plan.block_size))
    models = channel_models_for([rig.hammer, *rig.sensors])
    adc = AdcModel(bits=rig.config.daq.adc_bits, input_range_volts=rig.config.daq.input_range_volts)
    noise = channel_noise(seed, models, n)
    names = tuple(m.name for m in models)
    dur = rig.config.hammer.pulse_duration
    # the input work is kept only at the samples the hit records and the summary read
    spans = [(int(np.ceil(t0 * fs)), min(n - 1, int(np.floor((t0 + dur) * fs)) + 1)) for t0 in hits]
    ends = [min(n - 1, int((t + dur) * fs) + 1) for t in hits]
    wanted = {i for i0, i1 in spans for i in (max(i0 - 1, 0), i1)} | set(ends)
    work_at: dict[int, float] = {}
    clip_counts = np.zeros(len(models), dtype=np.int64)
    if progress:
        progress("simulating", 0.0)
    segments = sim.run_segments(force, plan.duration, fs, amplitudes=[1.0], segment=seg)
    first = next(segments)
    with LogWriter(out, **(writer_kwargs or {})) as w:
        w.add_stream(STREAM, channel_infos(rig), fs, offset_ns=0)  # origin 0 (the writer's default): see below
        w.add_metadata(
            "gvtlink.simulation",
            {
                "rig": rig.name,
                "seed": str(seed),
                "forces_N": json.dumps(list(plan.forces)),
                "hit_times_s": json.dumps(hits),
                "mode_frequencies_hz": json.dumps(first.mode_frequencies_hz[:10].tolist()),
            },
        )
        rig_path = Path(rig.path)
        if rig_path.exists():
            w.add_attachment(f"rig/{rig_path.name}", rig_path.read_bytes(), "application/toml")
        n_modes = min(10, first.modal_q.shape[-1])
        for res in itertools.chain([first], segments):
            n0, m = res.first_index, res.t.size
            _, physical = channel_signals(rig, res)
            meas = measure_segment(physical, models, adc, noise)
            del physical
            clip_counts += meas.clipped.sum(axis=0)
            e = res.energy
            for i in wanted:
                if n0 <= i < n0 + m:
                    work_at[i] = float(e.input_work[0, i - n0])
            for start in range(0, m, plan.block_size):
                stop = min(m, start + plan.block_size)
                status = BlockStatus.CLIPPED if meas.clipped[start:stop].any() else BlockStatus.OK
                block = SampleBlock(STREAM, n0 + start, fs, names, meas.data[start:stop], status)
                w.write_block(block, wait=True)  # offline: back-pressure
                last = stop - 1
                w.write_json(
                    layout.SIM_ENERGY_TOPIC,
                    SimEnergy(
                        index=int(n0 + last),
                        modal_energy_J=tuple(res.modal_energy[0, last, :n_modes].tolist()),
                        kinetic_J=float(e.kinetic[0, last]),
                        potential_linear_J=float(e.potential_linear[0, last]),
                        potential_nonlinear_J=float(e.potential_nonlinear[0, last]),
                        dissipated_J=float(e.dissipated[0, last]),
                        input_work_J=float(e.input_work[0, last]),
                    ),
                    log_time_ns=round((n0 + last) * 1e9 / fs),
                )
            if progress:
                progress("simulating", (n0 + m) / n)
        for k, ((i0, i1), peak) in enumerate(zip(spans, plan.forces, strict=True)):
            hit = Hit(
                hit=k,
                index=i0,
                t_s=i0 / fs,
                peak_force_N=float(peak),
                pulse_width_s=dur,
                input_energy_J=work_at[i1] - work_at[max(i0 - 1, 0)],
                verdict="accepted",
                source="simulator",
            )
            w.write_hit(hit, log_time_ns=round(i0 * 1e9 / fs))
            w.write_json(layout.SIM_HITS_TOPIC, hit, log_time_ns=round(i0 * 1e9 / fs))
        clipped = {name: int(c) for name, c in zip(names, clip_counts, strict=True) if c}
        for name, count in clipped.items():
            w.write_event("overload", stream=STREAM, count=count, message=f"channel {name} clipped on {count} samples")
    return {
        "samples": n,
        "channels": len(names),
        "hits": len(hits),
        "duration_s": n / fs,
        "clipped": clipped,
        "energies_J": [float(x) for x in np.diff(np.concatenate([[0.0], [work_at[i] for i in ends]]))],
    }
