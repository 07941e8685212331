"""Session configs (``configs/sessions/*.toml``): what to record, from which device(s), and how to trigger.

One device: a ``[device]`` table. Several devices on one timeline (the seed's Ch. 6 test had the hammer
on one system and the accelerometers on another): ``[[devices]]`` tables plus an optional ``[timeline]``
table (docs/session.md, "Two devices on one timeline").

Every mistake is one :class:`~analysis.model.loader.ConfigError` line naming file, field and value (exit 2),
found in three places, all before anything is opened or allocated:

* loading (:func:`~analysis.model.loader.load_config`): types, unknown keys, ``inf``/``nan``, the resource
  limits below, and :meth:`SessionConfig.check`'s cross-field checks that need the session only;
* :func:`daq.config.rig_checks.check_session_against_rig`: what needs the rig too (channel names, buffer sizes in
  bytes, the span a simulated device computes ahead); the recorder calls it at start-up;
* :func:`driver_table_error`: a device's ``config`` table, validated by its driver's own model.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_validator

from analysis.model.config import (
    MAX_CHANNELS,
    MAX_FORCE_N,
    MAX_SAMPLE_RATE,
    MIN_SAMPLE_RATE,
    SampleRate,
)
from analysis.model.loader import (
    ConfigError,
    ConfigFieldError,
    at_least,
    at_most,
    at_most_items,
    check_limit,
    non_finite,
    validation_error_to_config_error,
)

# --- limits (rig limits: analysis/model/config.py) ----------------------------------------------------------------
#: A session's duration: a week-long campaign. The recorder's memory does not grow with the duration (the 1-hour
#: soak peaked at the same 270 MB as 120 s, docs/session.md); a longer value is a unit mistake (ms for s).
MAX_DURATION_S = 7 * 86400.0
#: Seconds of data a queue may hold (the log writer's and the analysis lane's; test_view.py uses 30 s). Queues fill
#: only when a consumer falls behind, and then hold float32 blocks of every channel.
MAX_QUEUE_S = 60.0
#: Bytes one in-memory buffer may hold, checked against the rig's channels and rate (check_session_against_rig):
#: the queues, a hit record (pre-trigger + record), the analysis window, the timeline aligner's per-stream buffer.
#: 256 MiB holds 270 s of the seed rig (15 ch x 16384 Hz x 4 B = 0.98 MB/s) but 20 s of 64 ch x 51.2 kHz
#: (13 MB/s): one full buffer at most doubles the recorder's measured 270 MB peak RSS (docs/session.md).
MAX_BUFFER_BYTES = 256 << 20
#: The log writer's buffer (MiB, D67): blocks wait there only while the writer is behind (a stall's burst, a busy
#: host), so it is a memory budget, not a crash bound. 256 MiB = 270 s of the seed rig, 20 s of 64 ch x 51.2 kHz;
#: at most 4 GiB (a quarter of a 16 GB lab PC), at least 1 MiB (one 4096-sample block of 64 channels).
WRITER_BUFFER_MIB = 256.0
MAX_WRITER_BUFFER_MIB = 4096.0
#: A hit record after the trigger edge (s); the seed's records are 0.3 s (hit gate) and 2 s (rig).
MAX_RECORD_S = 60.0
#: The pre-trigger (s). The hit gate keeps it in a float32 ring it shifts on every block: measured (np.roll, 1024-
#: sample blocks, 64 ch x 51.2 kHz) 0.1 s of CPU per s of data at 1 s, 0.9 s/s at 5 s (the gate falls behind);
#: 15 ch x 16384 Hz: 0.006 s/s at 1 s. The seed uses 10 ms; a pre-trigger of seconds holds the last hit's ring-down.
MAX_PRE_TRIGGER_S = 1.0
#: Rotation: each file repeats the header, schemas, metadata and rig attachment and ends with an index; below
#: 1 MiB (1 s of the seed rig) or 1 s a session writes files faster than anyone can use them.
MIN_ROTATE_BYTES = 1 << 20
MIN_ROTATE_S = 1.0
#: The near-live analysis window (s): 0.45 / f1 by default (0.0216 s for beam_ch4_exp, 2.4 s for two_dof).
MAX_ANALYSIS_WINDOW_S = 10.0
#: Simulated hits in one schedule, double hits and wild frames (the shipped schedules have 4-40 hits).
MAX_SIM_HITS = 10_000
MAX_WILD_FRAMES = 1000
#: Waits at the end of a session and the silence threshold (s): a device is late by seconds, not hours.
MAX_WAIT_S = 3600.0

_WEEK = "7 days"

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Seconds = Annotated[float, Field(ge=0), at_most(MAX_DURATION_S, "s", _WEEK)]
HitForce = Annotated[
    float, Field(ge=0), at_most(MAX_FORCE_N, "N", "1 MN; the simulator's cost grows without bound with the force")
]
QueueSeconds = Annotated[float, Field(gt=0), at_most(MAX_QUEUE_S, "s", "an in-memory buffer")]
WaitSeconds = Annotated[float, at_most(MAX_WAIT_S, "s", "1 hour")]
ChannelName = Annotated[str, Field(min_length=1, max_length=64)]
ChannelList = Annotated[list[ChannelName], at_most_items(MAX_CHANNELS, "channels", "the biggest DAQ frame")]


class _Strict(BaseModel):
    """Unknown keys, ``inf`` and ``nan`` are mistakes; a loaded config never changes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _no_repeats(field: str, names: list[str]) -> None:
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ConfigFieldError(field, f"channel {n!r} is listed twice")


class SimulateSpec(_Strict):
    """Start the simulated device for this driver (serial: a pty; modbus: TCP on 127.0.0.1 or RTU on a pty;
    can: a node on python-can's in-process virtual bus) — daq/sim_devices.py."""

    forces: Annotated[list[HitForce], Field(min_length=1), at_most_items(MAX_SIM_HITS, "hits", "a schedule, not a stream")]
    # hit numbers (from 0) followed by a second tap 4 ms later
    double_hits: Annotated[list[Annotated[int, Field(ge=0)]], at_most_items(MAX_SIM_HITS, "double hits", "one per hit")] = []
    period: Annotated[float, Field(gt=0), at_most(MAX_DURATION_S, "s", _WEEK)] = 0.5
    first: Annotated[float, Field(ge=0.05), at_most(MAX_DURATION_S, "s", _WEEK)] = 0.2
    seed: Annotated[int, Field(ge=0)] = 0  # numpy's generators take a non-negative seed
    # serial only: the frame's sample format, or "ascii" lines
    format: Literal["int16", "int24", "int32", "float32", "ascii"] = "int24"
    ranges: dict[ChannelName, Positive] = {}  # override sensor ranges (e.g. make a channel clip on every hit)
    channels: ChannelList | None = None  # the rig channels this device serves (default: all)
    # [[devices]] only: this device's clock starts this long after the first simulated device's (s)
    start_delay: Annotated[float, Field(ge=0, le=60)] = 0.0
    # serve the simulated device at this rate instead of the rig's daq.sample_rate (e.g. 2048 Hz)
    sample_rate: SampleRate | None = None
    transport: Literal["tcp", "rtu"] = "tcp"  # modbus only: Modbus TCP on 127.0.0.1, or RTU on a pty
    # fault knobs for tests (drivers/sim/faults.py), device time in s; per device, not shared
    stall_at_s: Seconds | None = None  # output pauses here for stall_for_s (data accrues; nothing lost)
    stall_for_s: Seconds = 0.0
    disconnect_at_s: Seconds | None = None  # the link closes here for disconnect_for_s (samples lost)
    disconnect_for_s: Seconds = 0.0
    restart_at_s: Seconds | None = None  # the device restarts here, down for restart_down_s, index back at 0
    restart_down_s: Seconds = 0.0
    # sensor faults (drivers/sim/faults.py SensorFaults): mains hum on these channels (RMS in the channel's SI
    # unit, 50 or 60 Hz plus 3 harmonics), sensors mounted the wrong way round, channels stuck at a value
    hum_hz: Literal[50.0, 60.0] = 50.0
    hum_rms: dict[ChannelName, Positive] = {}
    reversed_polarity: Annotated[list[ChannelName], at_most_items(MAX_CHANNELS, "channels", "one per channel")] = []
    stuck: dict[ChannelName, float] = {}
    # serial only: extra CRC-valid frames at (device time s, first sample index), e.g. [[1.0, 1000000000]]
    wild_frames: Annotated[
        list[tuple[Seconds, Annotated[int, Field(ge=0)]]], at_most_items(MAX_WILD_FRAMES, "wild frames", "a test knob")
    ] = []

    @model_validator(mode="after")
    def _consistent(self) -> SimulateSpec:
        n = len(self.forces)
        for k in self.double_hits:
            if k >= n:
                raise ValueError(f"double_hits: hit {k} is not in the schedule (forces has {n} hits, numbered from 0)")
        for knob, length in (("stall", "stall_for_s"), ("disconnect", "disconnect_for_s"), ("restart", "restart_down_s")):
            if getattr(self, length) > 0 and getattr(self, f"{knob}_at_s") is None:
                raise ValueError(f"{length}: give {knob}_at_s too (when the {knob} happens, device time in s)")
        if self.stall_at_s is not None and self.stall_for_s <= 0:
            raise ValueError("stall_for_s: a stall needs a length > 0 (s)")
        if self.disconnect_at_s is not None and self.disconnect_for_s <= 0:
            raise ValueError("disconnect_for_s: a disconnect needs a length > 0 (s)")
        if self.channels is not None:
            _no_repeats("channels", self.channels)
        return self


#: The simulated structure's fields: one structure (and one clock rate) is shared by every simulated device of
#: a session. The fault knobs (stall, disconnect, restart, wild frames) and the transport stay per device.
PHYSICS_FIELDS = ("forces", "double_hits", "period", "first", "seed", "ranges", "sample_rate")


class DeviceSpec(_Strict):
    name: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")] = "dev0"
    driver: Literal["serial", "modbus", "can", "sim"]
    # the driver's own config table (drivers/<kind>/driver.py), validated by the driver's model at start-up
    # (driver_table_error); here only what the session itself reads: channels, sample_rate, no inf/nan
    config: dict[str, Any] = {}
    simulate: SimulateSpec | None = None

    def channel_names(self) -> list[str] | None:
        """The channels this device delivers, when the config says (driver table or simulate table)."""
        chans = self.config.get("channels")
        if isinstance(chans, list) and chans:
            return [str(c) for c in chans]
        if self.simulate is not None and self.simulate.channels is not None:
            return list(self.simulate.channels)
        return None

    def configured_rate(self) -> float | None:
        """The device's sample rate when the session says (driver table, else the simulated rate), else None."""
        v = self.config.get("sample_rate")
        if isinstance(v, int | float) and not isinstance(v, bool):
            return float(v)
        return self.simulate.sample_rate if self.simulate is not None else None


class TimelineSpec(_Strict):
    """How several devices' sample clocks are put on one timeline (``daq/timeline.py``)."""

    reference: str | None = None  # device name; default: the device carrying the trigger channel
    # seconds by which a device's sample 0 follows the reference's, for clocks already synchronised
    # (PTP/GPS or a shared trigger): no estimate is made for these devices
    offsets: dict[str, Annotated[float, Field(ge=-MAX_DURATION_S, le=MAX_DURATION_S)]] = {}
    settle_s: Annotated[float, Field(gt=0, le=30)] = 0.5  # estimate this long before fixing the offset
    # one lower-envelope point per window of device time (>= 1 ms: finer is per-block work for nothing)
    window_s: Annotated[float, Field(le=10), at_least(1e-3, "s", "one envelope point per window")] = 0.1
    # a /daq/timeline message this often (s of data; >= 10 ms: at most 100 messages a second of data)
    report_s: Annotated[float, at_least(0.01, "s", "at most 100 messages a second"), at_most(MAX_WAIT_S, "s", "1 hour")] = 1.0
    max_buffer_s: Annotated[float, Field(gt=0, le=120)] = 5.0  # the aligner's buffer bound per stream


class TriggerSpec(_Strict):
    channel: ChannelName = "hammer"
    level: Positive
    pre_trigger: Annotated[
        float, Field(ge=0), at_most(MAX_PRE_TRIGGER_S, "s", "the gate shifts the pre-trigger ring on every block")
    ] = 0.01
    record_length: Annotated[float, Field(gt=0), at_most(MAX_RECORD_S, "s", "a hit record is held in memory")] = 0.3
    hysteresis: Annotated[float, Field(gt=0, le=1)] = 0.5
    force_range: tuple[HitForce, HitForce] | None = None
    driving_point: ChannelName | None = None
    suspect_after: Annotated[int, Field(ge=1)] = 3


class ChannelsSpec(_Strict):
    """Which channels the hit gate judges (daq/hits.py). Both lists must name recorded channels, not the trigger."""

    exclude: ChannelList = []  # left out of hit verdicts altogether (known bad or unused channels)
    required: ChannelList = []  # response channels whose failure (clipped or dead) rejects a hit


class LogSpec(_Strict):
    """What the session log holds beside the samples (docs/log-format.md)."""

    preview: bool = True  # /preview/<stream>: min/max per 256-sample bucket, for viewers ("Preview topic")


class AnalysisSpec(_Strict):
    """The near-live analysis lane (analysis/operator.py); results go to the log's ``/analysis/...`` topics."""

    enabled: bool = True
    # None: 0.45 / f1 of the rig (the seed's 0.0216 s for beam_ch4_exp)
    window_s: Annotated[float, Field(gt=0), at_most(MAX_ANALYSIS_WINDOW_S, "s", "one window is held per channel")] | None = None
    n_keep: Annotated[int, Field(ge=1, le=MAX_CHANNELS)] = 4  # NNMs of interest (POMs kept per window)
    seed_lane: bool = True  # POD/RQ curves and window-robust spikes (off: modal lane only)
    queue_seconds: QueueSeconds = 2.0  # the lane's own input queue; beyond it, it drops (and says so)
    confirm: bool = True  # confirm each IR event (WBEMD + slow flow) in a background worker (daq/lanes/confirm.py)
    # "worker": analysis and confirmation in a lane-host process at a lower priority (daq/lanes/host.py); "thread": in
    # the recorder's process, as before (gvt replay always runs them in-process: a replay is not real time)
    process: Literal["worker", "thread"] = "worker"
    worker_nice: Annotated[int, Field(ge=0, le=19)] = 10  # the worker's nice above the recorder's start (docs/decisions.md D64)
    # seconds the confirmations may still take after a stop request (Ctrl-C, SIGTERM), also one that arrives during the
    # drain after the duration (daq/recorder.py STOPPED_FINISH_S); a service manager's SIGKILL follows its own timeout
    confirm_stop_s: Annotated[float, Field(gt=0, le=3600)] = 15.0


#: Hit points of a roving-hammer plan and averages per point: a plan is typed by a person (hundreds of points on an
#: aircraft); each point holds one FRF accumulator (n_outputs x n_lines complex) in memory.
MAX_PLAN_POINTS = 1000
MAX_PLAN_AVERAGES = 1000
Averages = Annotated[int, Field(ge=1, le=MAX_PLAN_AVERAGES)]


class HitPointSpec(_Strict):
    """One hit point of a roving-hammer plan (daq/roving.py): where, in which direction, how many averages.

    Where: ``sensor`` (hit at that sensor: its model DOF, node and direction), or ``node`` (the test geometry's
    node of a channel, analysis/model/geometry.py ``rig_nodes``), or ``dof`` (a model DOF name such as ``w23`` or
    ``x1``; ``node`` then names its test node, needed when no channel sits on that DOF)."""

    name: Annotated[str, Field(min_length=1, max_length=32)] | None = None  # default P1, P2, ...
    sensor: ChannelName | None = None
    node: Annotated[int, Field(ge=1, le=2_147_483_647)] | None = None
    dof: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    direction: Annotated[str, Field(min_length=1, max_length=3)] | None = None  # "+Z", "-X", ... (default: the channel's)
    averages: Averages | None = None  # default: the plan's

    @model_validator(mode="after")
    def _one_place(self) -> HitPointSpec:
        if self.sensor is not None and (self.node is not None or self.dof is not None):
            raise ValueError("give sensor, or node, or dof (with an optional node): not sensor with another")
        if self.sensor is None and self.node is None and self.dof is None:
            raise ValueError("a hit point needs sensor, node or dof")
        if self.direction is not None:
            from analysis.model.units import parse_direction

            try:
                parse_direction(self.direction)
            except ValueError as exc:
                raise ValueError(f"direction {self.direction!r}: {exc}") from None
        return self


class PlanSpec(_Strict):
    """A roving-hammer test plan: the hit points in the order the operator hits them, and averages per point."""

    averages: Averages = 3
    points: Annotated[list[HitPointSpec], Field(min_length=1), at_most_items(MAX_PLAN_POINTS, "points", "typed by a person")]

    @model_validator(mode="after")
    def _unique(self) -> PlanSpec:
        names = [p.name or f"P{k + 1}" for k, p in enumerate(self.points)]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"points: hit point name {n!r} is used twice")
        return self


class SessionConfig(_Strict):
    name: Annotated[str, Field(min_length=1, max_length=200)]
    rig: Annotated[str, Field(min_length=1)]  # rig TOML or shipped rig name: calibration, positions, model
    output: Annotated[str, Field(min_length=1)] = "session.mcap"
    overwrite: bool = False  # replace an existing output file (else an existing file is an error, exit 2)
    duration: Annotated[float, Field(gt=0), at_most(MAX_DURATION_S, "s", _WEEK)] | None = None  # s of data; None = until Ctrl-C
    # seconds of wall-clock time after `duration` the session waits for a device that delivers less data than
    # the duration asks for; then it ends with an event naming the device and the missing samples
    end_grace_s: Annotated[WaitSeconds, Field(ge=0)] = 10.0
    # a device silent for longer than this is a `silence` event (with its range); None = the larger of 2 s and
    # four block periods
    silence_s: Annotated[WaitSeconds, Field(gt=0)] | None = None
    # the hit gate's and the live FRF lane's input queues (s of data). Before issue 30 it also sized the log writer's
    # queue; that is now writer_buffer_mib (D67), and an old config's queue_seconds still means the lanes' queues
    queue_seconds: QueueSeconds = 0.5
    # the log writer's buffer, a memory budget: blocks wait there while the writer is behind; overrun (samples NOT
    # RECORDED, counted) only when it is exhausted
    writer_buffer_mib: Annotated[
        float, at_least(1.0, "MiB", "one block of 64 channels"), at_most(MAX_WRITER_BUFFER_MIB, "MiB", "4 GiB of memory")
    ] = WRITER_BUFFER_MIB
    # start a new file past this size / after this many seconds of wall time
    rotate_bytes: Annotated[int, Field(gt=0), at_least(MIN_ROTATE_BYTES, "bytes", "1 MiB; a file per few blocks")] | None = None
    rotate_seconds: (
        Annotated[float, at_least(MIN_ROTATE_S, "s", "a file a second at most"), at_most(MAX_DURATION_S, "s", _WEEK)] | None
    ) = None
    device: DeviceSpec | None = None
    devices: Annotated[list[DeviceSpec], at_most_items(64, "devices", "one thread and one stream each")] | None = None
    timeline: TimelineSpec | None = None
    trigger: TriggerSpec
    channels: ChannelsSpec = ChannelsSpec()
    analysis: AnalysisSpec = AnalysisSpec()
    log: LogSpec = LogSpec()
    plan: PlanSpec | None = None  # a roving-hammer test plan (docs/session.md, "Roving hammer")

    _source: str | None = PrivateAttr(default=None)  # the file it was loaded from (analysis/model/loader.py)

    @model_validator(mode="before")
    @classmethod
    def _share_physics(cls, data: Any) -> Any:
        """The simulated devices of one session are views of ONE structure: a ``[devices.simulate]``
        table may omit the hit schedule, which then comes from the first device that gives it."""
        if not isinstance(data, dict) or not isinstance(data.get("devices"), list):
            return data
        sims = [d.get("simulate") for d in data["devices"] if isinstance(d, dict) and isinstance(d.get("simulate"), dict)]
        src = next((s for s in sims if "forces" in s), None)
        if src is None:
            return data
        devices = []
        for d in data["devices"]:
            if isinstance(d, dict) and isinstance(d.get("simulate"), dict):
                d = {**d, "simulate": {**{k: src[k] for k in PHYSICS_FIELDS if k in src}, **d["simulate"]}}
            devices.append(d)
        return {**data, "devices": devices}

    @property
    def source(self) -> str:
        """What messages name: the file the config was loaded from, else its name."""
        return self._source or self.name

    @property
    def device_list(self) -> list[DeviceSpec]:
        """Every device of the session, in config order (one for a ``[device]`` session)."""
        return [self.device] if self.device is not None else list(self.devices or [])

    @property
    def multi(self) -> bool:
        return self.devices is not None

    def _field(self, i: int, rest: str = "") -> str:
        return (f"devices[{i}]" if self.multi else "device") + (f".{rest}" if rest else "")

    def listed_channels(self) -> list[str] | None:
        """The recorded channels when every device lists its own (``config.channels`` or ``simulate.channels``),
        in device order; None when a device records whatever it has (a single device: the rig's channels)."""
        out: list[str] = []
        for d in self.device_list:
            names = d.channel_names()
            if names is None:
                return None
            out.extend(names)
        return out

    def check(self) -> None:
        """Cross-field checks that need the session only (the rig's: :func:`daq.config.rig_checks.check_session_against_rig`)."""
        if self.device is not None and self.devices is not None:
            raise ConfigFieldError("devices", "give either one [device] table or [[devices]] tables, not both")
        if self.device is None and not self.devices:
            raise ConfigFieldError("device", "required: a [device] table, or [[devices]] tables for several devices")
        for i, d in enumerate(self.device_list):
            self._check_driver_table(i, d)
            if d.simulate is not None:
                self._check_simulate(i, d)
        if self.trigger.force_range is not None and self.trigger.force_range[0] >= self.trigger.force_range[1]:
            raise ConfigFieldError(
                "trigger.force_range", f"give [min, max] with min < max (got {list(self.trigger.force_range)})"
            )
        if self.duration is None and any(d.simulate is not None for d in self.device_list):
            raise ConfigFieldError("duration", "a simulated session needs a duration (s)")
        if self.rotate_seconds is not None and self.duration is not None and self.rotate_seconds > self.duration:
            raise ConfigFieldError(
                "rotate_seconds",
                f"{self.rotate_seconds:g} s is longer than the session ({self.duration:g} s): no file would rotate",
            )
        self._check_channel_roles()
        if not self.multi:
            if self.timeline is not None:
                raise ConfigFieldError("timeline", "only for a session with several [[devices]]")
        else:
            self._check_devices()
        recorded = self.listed_channels()
        if recorded is not None:
            check_recorded(self, recorded)
        self._check_rig_exists()

    def _check_driver_table(self, i: int, d: DeviceSpec) -> None:
        """What the session reads from a driver's free-form table; the rest is the driver model's (at start-up)."""
        p = self._field(i, "config")
        bad = non_finite(d.config)
        if bad is not None:
            raise ConfigFieldError(f"{p}.{bad[0]}", f"Input should be a finite number (got {bad[1]!r})")
        if "channels" in d.config:
            ch = d.config["channels"]
            if not isinstance(ch, list) or not ch or not all(isinstance(c, str) and 0 < len(c) <= 64 for c in ch):
                raise ConfigFieldError(f"{p}.channels", f'give a list of channel names, e.g. ["hammer", "a01"] (got {ch!r:.60})')
            check_limit(f"{p}.channels", len(ch), MAX_CHANNELS, "channels", "the biggest DAQ frame")
            _no_repeats(f"{p}.channels", ch)
        if "sample_rate" in d.config:
            v = d.config["sample_rate"]
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ConfigFieldError(f"{p}.sample_rate", f"give the sample rate in Hz, a number (got {v!r:.60})")
            if not MIN_SAMPLE_RATE <= v <= MAX_SAMPLE_RATE:
                raise ConfigFieldError(
                    f"{p}.sample_rate",
                    f"outside the limits of {MIN_SAMPLE_RATE:g} .. {MAX_SAMPLE_RATE:g} Hz (devices run 256 Hz .. 51.2 kHz) "
                    f"(got {v!r})",
                )
        if d.driver == "can" and "messages" in d.config:  # read by the simulated CAN node before the driver's model
            m = d.config["messages"]
            if not isinstance(m, list) or not m or not all(isinstance(x, str) and 0 < len(x) <= 64 for x in m):
                raise ConfigFieldError(f"{p}.messages", f'give a list of DBC message names, e.g. ["GVT_FD3"] (got {m!r:.60})')
            check_limit(f"{p}.messages", len(m), MAX_CHANNELS, "messages", "one stream each")
        if d.driver == "sim" and "forces" in d.config:  # the in-process simulated device's hit schedule
            forces = d.config["forces"]
            if not isinstance(forces, list) or not all(isinstance(f, int | float) and not isinstance(f, bool) for f in forces):
                raise ConfigFieldError(f"{p}.forces", f"give a list of hit forces in N (got {forces!r:.60})")
            check_limit(f"{p}.forces", len(forces), MAX_SIM_HITS, "hits", "a schedule, not a stream")
            for k, f in enumerate(forces):
                if not 0 <= f <= MAX_FORCE_N:
                    raise ConfigFieldError(
                        f"{p}.forces[{k}]",
                        f"outside 0 .. {MAX_FORCE_N:g} N (the simulator's cost grows with the force) (got {f!r})",
                    )

    def _check_simulate(self, i: int, d: DeviceSpec) -> None:
        s = d.simulate
        assert s is not None
        p = self._field(i, "simulate")
        if d.driver == "sim":
            raise ConfigFieldError(
                p,
                "driver 'sim' is the simulated device itself: give its hits in [device] config (forces, period, physics_seconds)",
            )
        if not self.multi and s.start_delay:
            raise ConfigFieldError(f"{p}.start_delay", "only for [[devices]] (a second device whose clock starts later)")
        if "transport" in s.model_fields_set and d.driver != "modbus":
            raise ConfigFieldError(f"{p}.transport", f"only for driver 'modbus' (tcp or rtu), not {d.driver!r}")
        if "format" in s.model_fields_set and d.driver != "serial":
            raise ConfigFieldError(f"{p}.format", f"only for driver 'serial' (the frame format), not {d.driver!r}")
        if s.wild_frames and d.driver != "serial":
            raise ConfigFieldError(f"{p}.wild_frames", f"only for driver 'serial' (extra CRC-valid frames), not {d.driver!r}")

    def _check_channel_roles(self) -> None:
        """The hit gate's rules (daq/hits.py, TriggerSettings): the force channel is always judged."""
        t, c = self.trigger, self.channels
        for what, names in (("exclude", c.exclude), ("required", c.required)):
            _no_repeats(f"channels.{what}", names)
            if t.channel in names:
                raise ConfigFieldError(
                    f"channels.{what}", f"the trigger channel {t.channel!r} is always required; leave it out of {what}"
                )
        both = [n for n in c.required if n in c.exclude]
        if both:
            raise ConfigFieldError("channels.required", f"channel {both[0]!r} is both required and excluded")

    def _check_devices(self) -> None:
        devs = self.device_list
        names = [d.name for d in devs]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ConfigFieldError(f"devices[{i}].name", f"device name {n!r} is used twice; each device is its own stream")
        owner: dict[str, str] = {}
        for i, d in enumerate(devs):
            chans = d.channel_names()
            if chans is None:
                raise ConfigFieldError(
                    f"devices[{i}]", "list the device's channels (config.channels, or simulate.channels for a simulated device)"
                )
            for c in chans:
                if c in owner:
                    raise ConfigFieldError(f"devices[{i}].channels", f"channel {c!r} is on both {owner[c]!r} and {d.name!r}")
                owner[c] = d.name
        trig = [d.name for d in devs if self.trigger.channel in (d.channel_names() or [])]
        if len(trig) != 1:
            where = "no device" if not trig else f"{len(trig)} devices"
            raise ConfigFieldError(
                "trigger.channel", f"trigger channel {self.trigger.channel!r} is on {where}; exactly one must carry it"
            )
        dp = self.trigger.driving_point
        if dp is not None and dp not in owner:
            raise ConfigFieldError("trigger.driving_point", f"channel {dp!r} is on no device")
        sims = [(i, d.simulate) for i, d in enumerate(devs) if d.simulate is not None]
        for i, s in sims[1:]:
            for k in PHYSICS_FIELDS:
                if getattr(s, k) != getattr(sims[0][1], k):
                    raise ConfigFieldError(
                        f"devices[{i}].simulate.{k}",
                        "the simulated devices share one structure and clock: give the hit schedule and sample_rate once "
                        "(first simulated device)",
                    )
        rates = {d.name: r for d in devs if (r := d.configured_rate()) is not None}
        if len(set(rates.values())) > 1:
            shown = ", ".join(f"{n} {r:g} Hz" for n, r in rates.items())
            raise ConfigFieldError("devices", f"the devices sample at different rates ({shown}); resampling is not supported")
        tl = self.timeline or TimelineSpec()
        if tl.reference is not None and tl.reference not in names:
            raise ConfigFieldError("timeline.reference", f"no device named {tl.reference!r} (devices: {', '.join(names)})")
        ref = tl.reference or trig[0]
        for n, v in tl.offsets.items():
            if n not in names:
                raise ConfigFieldError(f"timeline.offsets.{n}", f"no device named {n!r} (devices: {', '.join(names)})")
            if n == ref and v != 0:
                raise ConfigFieldError(f"timeline.offsets.{n}", "the reference device's offset is 0 by definition")
        if tl.max_buffer_s < 2 * tl.settle_s:
            raise ConfigFieldError("timeline.max_buffer_s", f"must be at least 2 x settle_s ({2 * tl.settle_s:g} s)")

    def _check_rig_exists(self) -> None:
        """The rig is a file or a shipped rig's name: said at ``rig``, not as a missing file later."""
        from analysis.model.rigs import RIG_DIR, resolve_rig_path

        p = resolve_rig_path(self.rig)
        if p.is_dir():
            raise ConfigFieldError("rig", f"{self.rig!r} is a directory; give a rig TOML file or a shipped rig's name")
        if not p.exists():
            shipped = ", ".join(sorted(q.stem for q in RIG_DIR.glob("*.toml")))
            raise ConfigFieldError(
                "rig", f"no rig file {self.rig!r} and no shipped rig of that name (shipped: {shipped}) (got {self.rig!r})"
            )

    def reference_device(self) -> str:
        """The device whose sample index is the session's timeline (and the hit records' index)."""
        if not self.multi:
            return self.device_list[0].name
        tl = self.timeline or TimelineSpec()
        if tl.reference is not None:
            return tl.reference
        return next(d.name for d in self.device_list if self.trigger.channel in (d.channel_names() or []))


# --- checks against the rig ------------------------------------------------------------------------------------------
def _shown(names: list[str], n: int = 16) -> str:
    return ", ".join(names[:n]) + (f", ... ({len(names)} channels)" if len(names) > n else "")


def unknown_channel(name: str, known: list[str], where: str, label: str) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"channel {name!r} is not {where} ({label}: {_shown(known)}){hint}"


def check_recorded(cfg: SessionConfig, recorded: list[str], label: str = "recorded") -> None:
    """The trigger channel, driving point and ``[channels]`` lists name channels the session records."""
    t = cfg.trigger
    if t.channel not in recorded:
        raise ConfigFieldError("trigger.channel", unknown_channel(t.channel, recorded, "recorded", label))
    if t.driving_point is not None and t.driving_point not in recorded:
        raise ConfigFieldError("trigger.driving_point", unknown_channel(t.driving_point, recorded, "recorded", label))
    for what in ("exclude", "required"):
        for k, c in enumerate(getattr(cfg.channels, what)):
            if c not in recorded:
                raise ConfigFieldError(f"channels.{what}[{k}]", unknown_channel(c, recorded, "recorded", label))


def driver_table_error(path: str | Path, field_prefix: str, exc: ValidationError) -> ConfigError:
    """One line for a device's ``config`` table refused by its driver's pydantic model: ``field_prefix`` is
    ``device`` or ``devices[1]`` (``.config`` is added), e.g. "s.toml: devices[1].config.port: required key is
    missing". A driver ``model_validator`` message "dbc: DBC file 'x.dbc' not found" lands on ``config.dbc``."""
    prefix = field_prefix if field_prefix.endswith(".config") else f"{field_prefix}.config"
    return validation_error_to_config_error(
        path, exc, prefix, unknown_key="unknown key for this driver (check the spelling; see docs/protocols/)"
    )
