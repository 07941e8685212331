"""A session config against its rig: what cannot be checked until the rig is known.

The session schema (:mod:`daq.config.session`) is data and checks what needs the session only; the checks
here need the rig and the roving-hammer plan's resolution (:func:`daq.roving.resolve_plan`) too, so they sit
above both, and the schema imports no behaviour. The recorder calls :func:`check_session_against_rig` at
start-up, before anything is opened or allocated.
"""

from __future__ import annotations

import math
from pathlib import Path

from analysis.model.config import MAX_SIMULATED_CHANNEL_SAMPLES
from analysis.model.loader import ConfigError, ConfigFieldError
from analysis.model.rig import Rig
from daq.config.session import MAX_BUFFER_BYTES, SessionConfig, TimelineSpec, check_recorded, unknown_channel
from daq.roving import resolve_plan


def _rig_channels(rig: Rig) -> list[str]:
    return [rig.hammer.name, *(s.name for s in rig.sensors)]


def _check_against_rig(cfg: SessionConfig, rig: Rig) -> None:
    chans = _rig_channels(rig)
    in_rig, its = f"in rig {rig.name}", "its channels"
    recorded: list[str] = []
    rates: list[float] = []
    for i, d in enumerate(cfg.device_list):
        listed = d.config.get("channels")
        if isinstance(listed, list):
            for k, c in enumerate(listed):
                if c not in chans:
                    raise ConfigFieldError(cfg._field(i, f"config.channels[{k}]"), unknown_channel(c, chans, in_rig, its))
        s = d.simulate
        if s is not None:
            for k, c in enumerate(s.channels or []):
                if c not in chans:
                    raise ConfigFieldError(cfg._field(i, f"simulate.channels[{k}]"), unknown_channel(c, chans, in_rig, its))
            named = [(f"ranges.{c}", c) for c in s.ranges] + [(f"hum_rms.{c}", c) for c in s.hum_rms]
            named += [(f"reversed_polarity[{k}]", c) for k, c in enumerate(s.reversed_polarity)]
            for where, c in named + [(f"stuck.{c}", c) for c in s.stuck]:
                if c not in chans:
                    raise ConfigFieldError(cfg._field(i, f"simulate.{where}"), unknown_channel(c, chans, in_rig, its))
        names = d.channel_names()
        recorded.extend(c for c in (names if names is not None else chans) if c not in recorded)
        rate = d.configured_rate() or rig.sample_rate
        rates.append(rate)
        pulse = rig.config.hammer.pulse_duration
        if s is not None and s.sample_rate is not None and pulse * s.sample_rate < 2.0:
            raise ConfigFieldError(
                cfg._field(i, "simulate.sample_rate"),
                f"the rig's hammer pulse ({pulse:g} s) is shorter than two samples at {s.sample_rate:g} Hz; "
                f"needs >= {2.0 / pulse:g} Hz",
            )
        if d.driver == "sim" and "rig" not in d.config and rate != rig.sample_rate:
            raise ConfigFieldError(
                cfg._field(i, "config.sample_rate"),
                f"the in-process simulated device runs at the rig's {rig.sample_rate:g} Hz (got {rate:g})",
            )
    label = "recorded" if cfg.listed_channels() is not None else f"a device that lists no channels records rig {rig.name}'s"
    check_recorded(cfg, recorded, label)
    if cfg.plan is not None:
        resolve_plan(cfg.plan, rig)  # raises ConfigFieldError naming plan.points[k].<field>
        _check_roving_span(cfg, rig)
    _check_level(cfg, rig)
    _check_budgets(cfg, rig, len(recorded), max(rates))


def _check_roving_span(cfg: SessionConfig, rig: Rig) -> None:
    """A simulated roving session computes one simulation per hit point, from that point's first hit to the end of
    the session; a point whose first hit comes after the end has no span to compute. ``sim_roving.toml --duration
    0.5`` passed every check and ended as "internal error: duration must be positive" (issue 30)."""
    from daq.roving import scheduled_dofs

    sim = next((d.simulate for d in cfg.device_list if d.simulate is not None), None)
    if sim is None or not sim.forces:
        return
    dofs = scheduled_dofs(cfg.plan, rig, list(sim.forces), list(sim.double_hits))
    first: dict[int, float] = {}
    for k, dof in enumerate(dofs):
        first.setdefault(dof, sim.first + k * sim.period)
    late = max(first.values())
    if cfg.duration is None or late >= cfg.duration:
        given = "none given" if cfg.duration is None else f"{cfg.duration:g} s"
        raise ConfigFieldError(
            "duration",
            f"{given}: the simulated roving plan's last hit point is first hit at {late:g} s (simulate.first + "
            f"k x simulate.period); give a duration of at least {math.ceil(late + sim.period):g} s, or fewer "
            "simulate.forces",
        )


def _check_level(cfg: SessionConfig, rig: Rig) -> None:
    """A trigger level at or above the trigger channel's range can never be crossed: no hit would be found."""
    t = cfg.trigger
    placed = {p.name: p for p in [rig.hammer, *rig.sensors]}
    ranges = {n: p.props.range for n, p in placed.items()}
    for d in cfg.device_list:
        if d.simulate is not None:
            ranges.update(d.simulate.ranges)
    rng = ranges.get(t.channel)
    if rng is not None and t.level >= rng:
        unit = placed[t.channel].unit if t.channel in placed else ""
        raise ConfigFieldError(
            "trigger.level",
            f"{t.level:g} {unit} is at or above the range of {t.channel!r} (±{rng:g} {unit}): the trigger would never fire",
        )


def _check_budgets(cfg: SessionConfig, rig: Rig, n_channels: int, fs: float) -> None:
    """Buffers in bytes (float32 blocks of every recorded channel) and the span a simulated device computes ahead."""
    per_s = 4.0 * n_channels * fs
    why = f"{n_channels} channels x {fs:g} Hz x 4 B = {per_s / 1e6:.3g} MB/s of data"
    t = cfg.trigger
    buffers = [("trigger.record_length", t.pre_trigger + t.record_length), ("queue_seconds", cfg.queue_seconds)]
    if cfg.analysis.enabled:
        buffers.append(("analysis.queue_seconds", cfg.analysis.queue_seconds))
        if cfg.analysis.window_s is not None:
            buffers.append(("analysis.window_s", cfg.analysis.window_s))
    if cfg.multi:
        buffers.append(("timeline.max_buffer_s", (cfg.timeline or TimelineSpec()).max_buffer_s))
    for field, seconds in buffers:
        if seconds * per_s > MAX_BUFFER_BYTES:
            raise ConfigFieldError(
                field,
                f"{seconds:g} s of data is {seconds * per_s / 2**20:.0f} MiB in memory ({why}): above the limit of "
                f"{MAX_BUFFER_BYTES >> 20} MiB a buffer; at most {MAX_BUFFER_BYTES / per_s:.3g} s",
            )
    n_rig = len(_rig_channels(rig))
    sims = [d for d in cfg.device_list if d.simulate is not None]
    if sims:
        s0 = sims[0].simulate
        assert s0 is not None
        rate = s0.sample_rate or rig.sample_rate
        span = (cfg.duration or 0.0) + 1.0 + max(d.simulate.start_delay for d in sims if d.simulate is not None)
        _check_span("duration", span, rate, n_rig)
    for i, d in enumerate(cfg.device_list):
        if d.driver == "sim" and "rig" not in d.config:
            phys = d.config.get("physics_seconds", 5.0)
            if isinstance(phys, int | float) and not isinstance(phys, bool):
                _check_span(cfg._field(i, "config.physics_seconds"), float(phys), rig.sample_rate, n_rig)


def _check_span(field: str, seconds: float, fs: float, n_channels: int) -> None:
    """A simulated device computes its whole span ahead (drivers/sim/device.py): bounded like a rig's record."""
    samples = seconds * fs * n_channels
    if samples > MAX_SIMULATED_CHANNEL_SAMPLES:
        most = MAX_SIMULATED_CHANNEL_SAMPLES / (fs * n_channels)
        raise ConfigFieldError(
            field,
            f"the simulated device computes {seconds:g} s x {fs:g} Hz x {n_channels} channels = {samples / 1e6:.3g} M "
            f"channel-samples ahead: above the limit of {MAX_SIMULATED_CHANNEL_SAMPLES / 1e6:.3g} M (~1 GB); "
            f"at most {math.floor(most * 10) / 10:g} s",
        )


def check_session_against_rig(cfg: SessionConfig, rig: Rig, path: str | Path | None = None) -> None:
    """What needs the session and its rig, for the recorder to call at start-up before opening anything.

    Channels named in ``config.channels``, ``simulate.channels`` and ``simulate.ranges`` exist in the rig; the
    trigger channel, driving point and ``[channels]`` lists name recorded channels (a single device that lists
    none records the rig's: "hammer" and the sensors' names); a trigger level the range can reach; every
    in-memory buffer and a simulated device's precomputed span within their limits (:data:`MAX_BUFFER_BYTES`,
    ``MAX_SIMULATED_CHANNEL_SAMPLES``). Raises :class:`ConfigError` (one line). Messages name the file the
    config was loaded from; ``path`` names a config built in code (default: its ``name``).
    """
    try:
        _check_against_rig(cfg, rig)
    except ConfigFieldError as exc:
        raise ConfigError(cfg._source or path or cfg.name, exc.field, exc.problem) from None
    _check_can_tables(cfg, cfg._source or path or cfg.name)


def _check_can_tables(cfg: SessionConfig, source: str | Path) -> None:
    """A CAN device's table through the driver's own model now (its DBC and message names), not when the
    device opens: a simulated CAN node reads ``messages`` first, and an unknown name ended as "internal error:
    DbcLayoutError" after the session had started (issue 30). Every CAN field has a default, so the table
    validates alone; the session adds only the stream name."""
    from pydantic import ValidationError

    from daq.config.session import driver_table_error
    from drivers.can.driver import CanConfig

    for i, d in enumerate(cfg.device_list):
        if d.driver == "can":
            try:
                CanConfig.model_validate({"stream": d.name, **d.config})
            except ValidationError as exc:
                raise driver_table_error(source, cfg._field(i, "config"), exc) from None
