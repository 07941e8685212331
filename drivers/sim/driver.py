"""The simulated device behind an in-process transport: blocks straight from the device, paced by its
clock or at full speed (for long soak tests and end-to-end benchmarks without a link in the way)."""

from __future__ import annotations

import time

from pydantic import Field

from drivers.base import Driver, DriverConfig, LinkBudget
from drivers.blocks import SampleBlock
from drivers.sim.timing import precise_wakeups


class SimConfig(DriverConfig):
    rig: str = "beam_ch4_exp"
    sample_rate: float = Field(16384.0, gt=0)  # must equal the rig's; checked on connect
    channels: list[str] = Field(default_factory=list)  # filled from the device on connect when empty
    block_size: int = Field(1024, ge=1)
    paced: bool = False  # False: full speed
    forces: list[float] = Field(default_factory=lambda: [800.0])  # scheduled hits, every `period` s from 0.2 s
    period: float = Field(1.0, gt=0)
    physics_seconds: float = Field(5.0, gt=0)  # simulated span; the device rests (noise floor) after it
    seed: int = 0
    duration: float | None = None  # stop after this many seconds of data
    # a roving hammer (daq/roving.py): the model DOF name each hit lands on; empty: all at the rig's hammer
    hit_dofs: list[str] = Field(default_factory=list)


class SimDriver(Driver):
    name = "sim"
    config_model = SimConfig
    #: the reading thread's :func:`precise_wakeups` (paced: blocks when due; unpaced nothing waits: False); None until
    #: it started, as the serial and CAN simulators' flags
    precise_wakeups: bool | None = None

    @property
    def realtime(self) -> bool:
        return bool(self.config.paced)

    def link_budget(self) -> LinkBudget:
        return LinkBudget(0.0, 1.0, "B/s", "in-process transport")

    def _connect(self) -> None:
        from analysis.model.rigs import open_rig
        from drivers.sim.device import HitSchedule, SimulatedDevice

        c: SimConfig = self.config  # type: ignore[assignment]
        rig = open_rig(c.rig)
        if abs(rig.sample_rate - c.sample_rate) > 1e-9:
            raise ValueError(f"sim driver: sample_rate {c.sample_rate:g} Hz but rig {rig.name} runs at {rig.sample_rate:g} Hz")
        schedule = HitSchedule.every(c.period, c.forces)
        if c.hit_dofs:
            if len(c.hit_dofs) != len(c.forces):
                raise ValueError(f"sim driver: {len(c.hit_dofs)} hit_dofs for {len(c.forces)} hits")
            schedule = HitSchedule(schedule.times_s, schedule.forces_n, tuple(rig.structure.dof_index(d) for d in c.hit_dofs))
        self.device = SimulatedDevice(rig, schedule, c.physics_seconds, block_size=c.block_size, seed=c.seed)
        if not c.channels:
            c.channels = list(self.device.channels)
        missing = [ch for ch in c.channels if ch not in self.device.channels]
        if missing:
            raise ValueError(f"sim driver: unknown channels {missing}; the device has {list(self.device.channels)}")
        self._cols = [self.device.channels.index(ch) for ch in c.channels]

    def _run(self) -> None:
        c: SimConfig = self.config  # type: ignore[assignment]
        dev = self.device
        # blocks when due, not up to a host timer's slack later (drivers/sim/timing.py)
        self.precise_wakeups = precise_wakeups() if c.paced else False
        dev.start_clock()
        names = tuple(c.channels)
        end = None if c.duration is None else round(c.duration * dev.fs)
        k = 0
        while not self.stopping:
            start = k * dev.block_size
            if end is not None and start >= end:
                return
            if c.paced:
                delay = dev.time_of_block(k) - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
            stop = start + dev.block_size if end is None else min(end, start + dev.block_size)
            data = dev.samples(start, stop)[:, self._cols]
            while not self.stopping:  # full speed: back-pressure instead of overrunning our own queue
                if self._blocks.qsize() < self._blocks.maxsize - 1 or c.paced:
                    break
                self._stop.wait(0.001)
            self._emit(SampleBlock(c.stream, start, dev.fs, names, data))
            k += 1
