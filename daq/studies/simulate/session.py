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
from dataclasses import dataclass, field
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
    dur = rig.config.hammer.pulse_duration
    seed = rig.config.simulation.seed if seed is None else seed
    sim = rig.simulator
    n = sim.n_samples(plan.duration, fs)
    seg = plan.block_size * max(1, -(-int(segment) // plan.block_size))
    models = channel_models_for([rig.hammer, *rig.sensors])
    adc = AdcModel(bits=rig.config.daq.adc_bits, input_range_volts=rig.config.daq.input_range_volts)
    noise = channel_noise(seed, models, n)
    names = tuple(m.name for m in models)
    work = _InputWork.at_hits(hits, dur, fs, n)
    clip_counts = np.zeros(len(models), dtype=np.int64)
    if progress:
        progress("simulating", 0.0)
    segments = sim.run_segments(pulse_train(hits, plan.forces, dur), plan.duration, fs, amplitudes=[1.0], segment=seg)
    first = next(segments)
    with LogWriter(out, **(writer_kwargs or {})) as w:
        _write_setup(w, rig, plan, seed, first)
        n_modes = min(10, first.modal_q.shape[-1])
        for res in itertools.chain([first], segments):
            meas = _measure(rig, res, models, adc, noise)
            clip_counts += meas.clipped.sum(axis=0)
            work.keep(res)
            _write_segment(w, res, meas, names, fs, plan.block_size, n_modes)
            if progress:
                progress("simulating", (res.first_index + res.t.size) / n)
        _write_hits(w, plan, work, dur, fs)
        clipped = _write_clipping(w, names, clip_counts)
    return {
        "samples": n,
        "channels": len(names),
        "hits": len(hits),
        "duration_s": n / fs,
        "clipped": clipped,
        "energies_J": work.hit_energies(),
    }


@dataclass
class _InputWork:
    """The simulator's cumulative input work, kept only at the samples the hit records and the summary read
    (a session's whole energy budget would be as large as its samples): around each pulse (``spans``, first
    and last sample) and one past each pulse's end (``ends``, the summary's energies)."""

    spans: list[tuple[int, int]]
    ends: list[int]
    wanted: set[int]
    at: dict[int, float] = field(default_factory=dict)

    @classmethod
    def at_hits(cls, hits: list[float], dur: float, fs: float, n: int) -> _InputWork:
        spans = [(int(np.ceil(t0 * fs)), min(n - 1, int(np.floor((t0 + dur) * fs)) + 1)) for t0 in hits]
        ends = [min(n - 1, int((t + dur) * fs) + 1) for t in hits]
        wanted = {i for i0, i1 in spans for i in (max(i0 - 1, 0), i1)} | set(ends)
        return cls(spans, ends, wanted)

    def keep(self, res) -> None:
        """Keep the wanted samples of segment ``res``."""
        n0, m = res.first_index, res.t.size
        for i in self.wanted:
            if n0 <= i < n0 + m:
                self.at[i] = float(res.energy.input_work[0, i - n0])

    def of_pulse(self, k: int) -> float:
        """The work pulse ``k`` put in, from the sample before it to its last."""
        i0, i1 = self.spans[k]
        return self.at[i1] - self.at[max(i0 - 1, 0)]

    def hit_energies(self) -> list[float]:
        """The work put in up to one sample past each pulse, less that up to the previous one."""
        return [float(x) for x in np.diff(np.concatenate([[0.0], [self.at[i] for i in self.ends]]))]


def _write_setup(w: LogWriter, rig: Rig, plan: SessionPlan, seed: int, first) -> None:
    """The stream, the simulation's metadata (the first segment gives the mode frequencies) and the rig file."""
    w.add_stream(STREAM, channel_infos(rig), rig.sample_rate, offset_ns=0)  # origin 0 (the writer's default): module doc
    w.add_metadata(
        "gvtlink.simulation",
        {
            "rig": rig.name,
            "seed": str(seed),
            "forces_N": json.dumps(list(plan.forces)),
            "hit_times_s": json.dumps(plan.hit_times),
            "mode_frequencies_hz": json.dumps(first.mode_frequencies_hz[:10].tolist()),
        },
    )
    rig_path = Path(rig.path)
    if rig_path.exists():
        w.add_attachment(f"rig/{rig_path.name}", rig_path.read_bytes(), "application/toml")


def _measure(rig: Rig, res, models, adc: AdcModel, noise: list[np.random.Generator]) -> Measurement:
    """Segment ``res`` as the DAQ records it: the channels' physical signals through the sensor/DAQ model (the
    physical signals are dropped on return: one segment of them is held at a time)."""
    _, physical = channel_signals(rig, res)
    return measure_segment(physical, models, adc, noise)


def _write_segment(w: LogWriter, res, meas: Measurement, names: tuple[str, ...], fs: float, block_size: int,
                   n_modes: int) -> None:  # fmt: skip
    """The segment's sample blocks, each followed by the ground truth at its last sample (``/sim/energy``)."""
    n0, m = res.first_index, res.t.size
    e = res.energy
    for start in range(0, m, block_size):
        stop = min(m, start + block_size)
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


def _write_hits(w: LogWriter, plan: SessionPlan, work: _InputWork, dur: float, fs: float) -> None:
    """One hit record per pulse, at its first sample, on ``/daq/hits`` and as ground truth on ``/sim/hits``."""
    for k, ((i0, _i1), peak) in enumerate(zip(work.spans, plan.forces, strict=True)):
        hit = Hit(
            hit=k,
            index=i0,
            t_s=i0 / fs,
            peak_force_N=float(peak),
            pulse_width_s=dur,
            input_energy_J=work.of_pulse(k),
            verdict="accepted",
            source="simulator",
        )
        w.write_hit(hit, log_time_ns=round(i0 * 1e9 / fs))
        w.write_json(layout.SIM_HITS_TOPIC, hit, log_time_ns=round(i0 * 1e9 / fs))


def _write_clipping(w: LogWriter, names: tuple[str, ...], clip_counts: np.ndarray) -> dict[str, int]:
    """An ``overload`` event per channel that clipped, with its count; returns them by channel."""
    clipped = {name: int(c) for name, c in zip(names, clip_counts, strict=True) if c}
    for name, count in clipped.items():
        w.write_event("overload", stream=STREAM, count=count, message=f"channel {name} clipped on {count} samples")
    return clipped
