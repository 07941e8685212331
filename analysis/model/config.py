"""Rig configs: the structure under test, its attachments, sensors, hammer and DAQ (``configs/rigs``).

SI units throughout, except sensor sensitivities, which are given as on a calibration sheet in
millivolts per SI unit (e.g. 1.02 mV/(m/s^2) for the seed's accelerometers, L1320).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from analysis.model.loader import ConfigFieldError

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Located(_Strict):
    """Where an attachment or sensor sits: ``x`` (m along a beam) or ``dof`` (a lumped DOF's name)."""

    x: float | None = None
    dof: str | None = None

    @model_validator(mode="after")
    def _one_location(self) -> Located:
        if (self.x is None) == (self.dof is None):
            raise ValueError("give exactly one of 'x' (position along a beam, m) or 'dof' (a lumped DOF name)")
        return self


class BeamSpec(_Strict):
    kind: Literal["beam"]
    length: Positive = Field(description="m")
    width: Positive = Field(description="m")
    height: Positive = Field(description="m")
    youngs_modulus: Positive = Field(description="Pa")
    density: Positive = Field(description="kg/m^3")
    elements: Annotated[int, Field(ge=1, le=5000)]
    left: Literal["clamped", "pinned", "free"] = "clamped"
    right: Literal["clamped", "pinned", "free"] = "free"


class LumpedSpring(_Strict):
    """A linear spring between DOF ``i`` and DOF ``j`` (``j`` omitted: to ground)."""

    i: str
    j: str | None = None
    k: Positive = Field(description="N/m")


class LumpedSpec(_Strict):
    kind: Literal["lumped"]
    masses: Annotated[list[Positive], Field(min_length=1)]
    dof_names: list[str] | None = None
    springs: list[LumpedSpring] = []

    @model_validator(mode="after")
    def _names(self) -> LumpedSpec:
        if self.dof_names is not None and len(self.dof_names) != len(self.masses):
            raise ValueError("dof_names must name every mass")
        return self

    @property
    def names(self) -> list[str]:
        return self.dof_names or [f"x{i + 1}" for i in range(len(self.masses))]


class PointMass(Located):
    mass: Positive = Field(description="kg")


class LinearSpring(Located):
    k: Positive = Field(description="N/m, to ground")


class NonlinearSpringSpec(Located):
    """Grounded nonlinear spring: ``cubic`` f = coefficient w^3, ``power`` f = coefficient |w|^exponent sign(w)."""

    law: Literal["cubic", "power"] = "cubic"
    coefficient: Positive = Field(description="N/m^3 (cubic) or N/m^exponent (power)")
    exponent: Positive = 3.0

    @model_validator(mode="after")
    def _cubic_is_three(self) -> NonlinearSpringSpec:
        if self.law == "cubic" and self.exponent != 3.0:
            raise ValueError("a cubic spring has exponent 3; use law = 'power' for other exponents")
        return self


class DampingSpec(_Strict):
    """Modal damping ratios: ``zeta[r]`` for mode r+1, ``zeta_rest`` above; ``factor2`` see ModalDamping."""

    zeta: list[Annotated[float, Field(ge=0, lt=1)]] = []
    zeta_rest: Annotated[float, Field(ge=0, lt=1)] = 0.0
    factor2: bool = True


Quantity = Literal["acceleration", "velocity", "displacement", "force"]


class SensorProps(_Strict):
    quantity: Quantity = "acceleration"
    sensitivity_mv_per_unit: Positive = Field(description="mV per SI unit of the quantity")
    range: Positive | None = Field(default=None, description="± measurement range, SI units; None = unlimited")
    noise_rms: NonNegative = Field(default=0.0, description="noise floor, SI units rms")
    model: str | None = None


class SensorSpec(SensorProps):
    name: Annotated[str, Field(min_length=1)]
    x: float | None = None
    dof: str | None = None

    @model_validator(mode="after")
    def _one_location(self) -> SensorSpec:
        if (self.x is None) == (self.dof is None):
            raise ValueError("give exactly one of 'x' (position along a beam, m) or 'dof' (a lumped DOF name)")
        return self


class SensorArraySpec(SensorProps):
    """``count`` equally spaced sensors from ``start`` to ``stop`` (m), named prefix + 1-based index."""

    prefix: Annotated[str, Field(min_length=1)]
    start: float
    stop: float
    count: Annotated[int, Field(ge=1, le=10000)]

    def expand(self) -> list[SensorSpec]:
        props = self.model_dump(include=set(SensorProps.model_fields))
        if self.count == 1:
            xs = [self.start]
        else:
            xs = [self.start + (self.stop - self.start) * i / (self.count - 1) for i in range(self.count)]
        width = len(str(self.count))
        return [SensorSpec(name=f"{self.prefix}{i + 1:0{width}d}", x=x, **props) for i, x in enumerate(xs)]


class HammerSpec(Located):
    sensitivity_mv_per_unit: Positive = Field(description="mV/N")
    range: Positive | None = Field(default=None, description="± force range, N")
    noise_rms: NonNegative = 0.0
    model: str | None = None
    pulse: Literal["half_sine"] = "half_sine"
    pulse_duration: Positive = Field(description="s")
    peak_force: Positive = Field(description="N, nominal strong hit (demo, simulate default)")


class DaqSpec(_Strict):
    sample_rate: Positive = Field(description="Hz")
    adc_bits: Annotated[int, Field(ge=8, le=32)] = 24
    input_range_volts: Positive = 10.0
    record_length: Positive = Field(default=2.0, description="s per hit record")


class SimulationSpec(_Strict):
    modal_cutoff_hz: Positive = 5000.0
    max_omega_dt: Annotated[float, Field(gt=0, le=2.0)] = 0.25
    order: Literal[2, 4] = 2
    residual_vectors: bool = True
    seed: int = 0


class RigConfig(_Strict):
    name: Annotated[str, Field(min_length=1)]
    description: str = ""
    source: str = ""
    structure: Annotated[BeamSpec | LumpedSpec, Field(discriminator="kind")]
    point_masses: list[PointMass] = []
    springs: list[LinearSpring] = []
    nonlinear_springs: list[NonlinearSpringSpec] = []
    damping: DampingSpec = DampingSpec()
    sensors: list[SensorSpec] = []
    sensor_arrays: list[SensorArraySpec] = []
    hammer: HammerSpec
    daq: DaqSpec
    simulation: SimulationSpec = SimulationSpec()

    @property
    def all_sensors(self) -> list[SensorSpec]:
        out = list(self.sensors)
        for arr in self.sensor_arrays:
            out.extend(arr.expand())
        return out

    def check(self) -> None:
        """Cross-field checks, each raising a :class:`ConfigFieldError` at the offending path."""
        s = self.structure
        if not self.sensors and not self.sensor_arrays:
            raise ConfigFieldError("sensors", "a rig needs at least one sensor")
        located: list[tuple[str, Located | SensorSpec]] = [
            *((f"point_masses[{i}]", p) for i, p in enumerate(self.point_masses)),
            *((f"springs[{i}]", p) for i, p in enumerate(self.springs)),
            *((f"nonlinear_springs[{i}]", p) for i, p in enumerate(self.nonlinear_springs)),
            *((f"sensors[{i}]", p) for i, p in enumerate(self.sensors)),
            ("hammer", self.hammer),
        ]
        for a, arr in enumerate(self.sensor_arrays):
            for sensor in arr.expand():
                located.append((f"sensor_arrays[{a}]", sensor))
        if isinstance(s, BeamSpec):
            half = 0.5 * s.length / s.elements
            for path, item in located:
                if item.dof is not None:
                    raise ConfigFieldError(f"{path}.dof", "a beam rig places things by 'x' (m), not by DOF name")
                assert item.x is not None
                if item.x < -half or item.x > s.length + half:
                    raise ConfigFieldError(
                        f"{path}.x",
                        f"position {item.x:g} m is off the beam [0, {s.length:g}] m by more than half an element "
                        f"({half:g} m); move it onto the beam",
                    )
        else:
            names = s.names
            for path, item in located:
                if item.x is not None:
                    raise ConfigFieldError(f"{path}.x", "a lumped rig places things by 'dof' name, not by 'x'")
                if item.dof not in names:
                    raise ConfigFieldError(f"{path}.dof", f"unknown DOF {item.dof!r}; this rig has {names}")
            for i, sp in enumerate(s.springs):
                for end in ("i", "j"):
                    v = getattr(sp, end)
                    if v is not None and v not in names:
                        raise ConfigFieldError(f"structure.springs[{i}].{end}", f"unknown DOF {v!r}; this rig has {names}")
        seen: set[str] = set()
        for sensor in self.all_sensors:
            if sensor.name in seen:
                raise ConfigFieldError("sensors", f"sensor name {sensor.name!r} is used twice")
            seen.add(sensor.name)
        fs = self.daq.sample_rate
        if self.hammer.pulse_duration * fs < 2.0:
            raise ConfigFieldError(
                "hammer.pulse_duration",
                f"{self.hammer.pulse_duration:g} s is shorter than two samples at {fs:g} Hz "
                f"(needs >= {2.0 / fs:g} s); lengthen the pulse or raise daq.sample_rate",
            )
        if self.daq.record_length * fs < 2.0:
            raise ConfigFieldError("daq.record_length", "shorter than two samples at daq.sample_rate")
