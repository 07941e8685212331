"""Session configs (``configs/sessions/*.toml``): what to record, from which device(s), and how to trigger.

One device: a ``[device]`` table. Several devices on one timeline (the seed's Ch. 6 test had the hammer
on one system and the accelerometers on another): ``[[devices]]`` tables plus an optional ``[timeline]``
table (docs/session.md, "Two devices on one timeline").
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from analysis.model.loader import ConfigFieldError

Positive = Annotated[float, Field(gt=0)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SimulateSpec(_Strict):
    """Start the simulated device for this driver (serial: a pty; modbus: TCP on 127.0.0.1)."""

    forces: list[Annotated[float, Field(ge=0)]] = Field(min_length=1)
    double_hits: list[int] = []  # hit numbers followed by a second tap 4 ms later
    period: Positive = 0.5
    first: Annotated[float, Field(ge=0.05)] = 0.2
    seed: int = 0
    format: Literal["int16", "int24", "int32", "float32"] = "int24"
    ranges: dict[str, Positive] = {}  # override sensor ranges (e.g. make a channel clip on every hit)
    channels: list[str] | None = None  # the rig channels this device serves (default: all)
    # [[devices]] only: this device's clock starts this long after the first simulated device's (s)
    start_delay: Annotated[float, Field(ge=0, le=60)] = 0.0


#: The simulated structure's fields: one structure is shared by every simulated device of a session.
PHYSICS_FIELDS = ("forces", "double_hits", "period", "first", "seed", "ranges")


class DeviceSpec(_Strict):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")] = "dev0"
    driver: Literal["serial", "modbus", "can", "sim"]
    config: dict[str, Any] = {}  # the driver's own config table (drivers/<kind>/driver.py)
    simulate: SimulateSpec | None = None

    def channel_names(self) -> list[str] | None:
        """The channels this device delivers, when the config says (driver table or simulate table)."""
        if self.config.get("channels") is not None:
            return [str(c) for c in self.config["channels"]]
        if self.simulate is not None and self.simulate.channels is not None:
            return list(self.simulate.channels)
        return None


class TimelineSpec(_Strict):
    """How several devices' sample clocks are put on one timeline (``daq/timeline.py``)."""

    reference: str | None = None  # device name; default: the device carrying the trigger channel
    # seconds by which a device's sample 0 follows the reference's, for clocks already synchronised
    # (PTP/GPS or a shared trigger): no estimate is made for these devices
    offsets: dict[str, float] = {}
    settle_s: Annotated[float, Field(gt=0, le=30)] = 0.5  # estimate this long before fixing the offset
    window_s: Annotated[float, Field(gt=0, le=10)] = 0.1  # one lower-envelope point per window of device time
    report_s: Annotated[float, Field(gt=0)] = 1.0  # a /daq/timeline message this often (s of data)
    max_buffer_s: Annotated[float, Field(gt=0, le=120)] = 5.0  # the aligner's buffer bound per stream


class TriggerSpec(_Strict):
    channel: str = "hammer"
    level: Positive
    pre_trigger: Annotated[float, Field(ge=0)] = 0.01
    record_length: Positive = 0.3
    hysteresis: Annotated[float, Field(gt=0, le=1)] = 0.5
    force_range: tuple[float, float] | None = None
    driving_point: str | None = None
    suspect_after: Annotated[int, Field(ge=1)] = 3


class AnalysisSpec(_Strict):
    """The near-live analysis lane (analysis/operator.py); results go to the log's ``/analysis/...`` topics."""

    enabled: bool = True
    window_s: Positive | None = None  # None: 0.45 / f1 of the rig (the seed's 0.0216 s for beam_ch4_exp)
    n_keep: Annotated[int, Field(ge=1)] = 4  # NNMs of interest (POMs kept per window)
    seed_lane: bool = True  # POD/RQ curves and window-robust spikes (off: modal lane only)
    queue_seconds: Positive = 2.0  # the lane's own input queue; beyond it, it drops (and says so)
    confirm: bool = True  # confirm each IR event (WBEMD + slow flow) in a background worker (daq/confirm_lane.py)


class SessionConfig(_Strict):
    name: Annotated[str, Field(min_length=1)]
    rig: str  # rig TOML or shipped rig name: calibration, positions, model
    output: str = "session.mcap"
    duration: Positive | None = None  # seconds; None = until Ctrl-C / SIGTERM
    queue_seconds: Positive = 0.5
    rotate_bytes: Annotated[int, Field(gt=0)] | None = None  # start a new file past this size
    rotate_seconds: Positive | None = None  # or after this many seconds of wall time
    device: DeviceSpec | None = None
    devices: list[DeviceSpec] | None = None
    timeline: TimelineSpec | None = None
    trigger: TriggerSpec
    analysis: AnalysisSpec = AnalysisSpec()

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
    def device_list(self) -> list[DeviceSpec]:
        """Every device of the session, in config order (one for a ``[device]`` session)."""
        return [self.device] if self.device is not None else list(self.devices or [])

    @property
    def multi(self) -> bool:
        return self.devices is not None

    def _field(self, i: int, rest: str = "") -> str:
        return (f"devices[{i}]" if self.multi else "device") + (f".{rest}" if rest else "")

    def check(self) -> None:
        if self.trigger.force_range is not None and self.trigger.force_range[0] >= self.trigger.force_range[1]:
            raise ConfigFieldError("trigger.force_range", "give [min, max] with min < max")
        if self.device is not None and self.devices is not None:
            raise ConfigFieldError("devices", "give either one [device] table or [[devices]] tables, not both")
        if self.device is None and not self.devices:
            raise ConfigFieldError("device", "required: a [device] table, or [[devices]] tables for several devices")
        for i, d in enumerate(self.device_list):
            if d.simulate is not None and d.driver == "can":
                raise ConfigFieldError(
                    self._field(i, "simulate"), "the simulated CAN node runs in-process only; use serial or modbus"
                )
            if d.simulate is not None and not self.multi and d.simulate.start_delay:
                raise ConfigFieldError(
                    "device.simulate.start_delay", "only for [[devices]] (a second device whose clock starts later)"
                )
        if self.duration is None and any(d.simulate is not None for d in self.device_list):
            raise ConfigFieldError("duration", "a simulated session needs a duration (s)")
        if not self.multi:
            if self.timeline is not None:
                raise ConfigFieldError("timeline", "only for a session with several [[devices]]")
            return
        self._check_devices()

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
        rates = {d.name: float(d.config["sample_rate"]) for d in devs if "sample_rate" in d.config}
        if len(set(rates.values())) > 1:
            shown = ", ".join(f"{n} {r:g} Hz" for n, r in rates.items())
            raise ConfigFieldError("devices", f"the devices sample at different rates ({shown}); resampling is not supported")
        sims = [(i, d.simulate) for i, d in enumerate(devs) if d.simulate is not None]
        for i, s in sims[1:]:
            for k in PHYSICS_FIELDS:
                if getattr(s, k) != getattr(sims[0][1], k):
                    raise ConfigFieldError(
                        f"devices[{i}].simulate.{k}",
                        "the simulated devices share one structure: give the hit schedule once (first simulated device)",
                    )
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

    def reference_device(self) -> str:
        """The device whose sample index is the session's timeline (and the hit records' index)."""
        if not self.multi:
            return self.device_list[0].name
        tl = self.timeline or TimelineSpec()
        if tl.reference is not None:
            return tl.reference
        return next(d.name for d in self.device_list if self.trigger.channel in (d.channel_names() or []))
