"""Session configs (``configs/sessions/*.toml``): what to record, from which device, and how to trigger."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from daq.config.loader import ConfigFieldError

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


class DeviceSpec(_Strict):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")] = "dev0"
    driver: Literal["serial", "modbus", "can", "sim"]
    config: dict[str, Any] = {}  # the driver's own config table (drivers/<kind>/driver.py)
    simulate: SimulateSpec | None = None


class TriggerSpec(_Strict):
    channel: str = "hammer"
    level: Positive
    pre_trigger: Annotated[float, Field(ge=0)] = 0.01
    record_length: Positive = 0.3
    hysteresis: Annotated[float, Field(gt=0, le=1)] = 0.5
    force_range: tuple[float, float] | None = None
    driving_point: str | None = None
    suspect_after: Annotated[int, Field(ge=1)] = 3


class SessionConfig(_Strict):
    name: Annotated[str, Field(min_length=1)]
    rig: str  # rig TOML or shipped rig name: calibration, positions, model
    output: str = "session.mcap"
    duration: Positive | None = None  # seconds; None = until Ctrl-C / SIGTERM
    queue_seconds: Positive = 0.5
    rotate_bytes: Annotated[int, Field(gt=0)] | None = None  # start a new file past this size
    rotate_seconds: Positive | None = None  # or after this many seconds of wall time
    device: DeviceSpec
    trigger: TriggerSpec

    def check(self) -> None:
        if self.trigger.force_range is not None and self.trigger.force_range[0] >= self.trigger.force_range[1]:
            raise ConfigFieldError("trigger.force_range", "give [min, max] with min < max")
        if self.device.simulate is not None and self.device.driver == "can":
            raise ConfigFieldError("device.simulate", "the simulated CAN node runs in-process only; use serial or modbus")
        if self.duration is None and self.device.simulate is not None:
            raise ConfigFieldError("duration", "a simulated session needs a duration (s)")
