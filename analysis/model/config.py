"""Rig configs: the structure under test, its attachments, sensors, hammer and DAQ (``configs/rigs``).

SI units throughout, except sensor sensitivities, which are given as on a calibration sheet in
millivolts per SI unit (e.g. 1.02 mV/(m/s^2) for the seed's accelerometers, L1320).

Every number must be finite (``inf``/``nan`` are refused with the field named), and the ones that size
memory or time have a named limit below, with the measurement behind it: a config that would take an hour
and 5 GB to load is refused in a line, before anything is allocated.

The schema is data: it imports the loader and three leaves that convert or check what a rig file writes (units.py,
wireframe.py, update_targets.py), never the modules that use it (rig, channel table, geometry, updater, export),
so no import circle runs through it (issue 28).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from analysis.model.loader import ConfigFieldError, at_least, at_most, at_most_items, check_limit
from analysis.model.units import parse_direction, parse_sensitivity  # pint loads on the first conversion
from analysis.model.update_targets import check_parameters

# --- limits: what a config may ask for (measured on the 2-core dev machine, shared with other jobs) -----------
#: Beam elements. load_rig + modes + ``gvt model modes`` (dense eigenproblem, 2 DOF a node) measured 0.01 s /
#: 126 MB peak RSS at 107 elements (beam_ch4_exp), 0.2 s / 194 MB at 500, 1.5 s / 345 MB at 1000, 11 s / 1.0 GB
#: at 2000 and 5 min / 5.5 GB at 5000 (the old limit). The seed's finest mesh is 107 elements (7 mm); 1000
#: elements put a node every 0.75 mm on that beam, finer than any sensor is placed.
MAX_BEAM_ELEMENTS = 1000
#: Lumped DOFs: the same dense eigenproblem as a 1000-element beam; a 2000-mass chain measured 1.8 s / 258 MB.
MAX_LUMPED_DOFS = 2000
#: Channels of a rig, the hammer's force included: the biggest DAQ frame the drivers carry (the serial frame's
#: channel count is one byte, 1..255 a device) and 256 channels x 51.2 kHz = 52 MB/s of float32 data to record.
MAX_CHANNELS = 256
MAX_SENSORS = MAX_CHANNELS - 1
#: Device sample rates: the supported devices run 256 Hz .. 51.2 kHz and the 2-DOF example rig 50 Hz; outside
#: 1 Hz .. 1 MHz a rate is a unit mistake (kHz for Hz), and above it one second of 256 channels is 1 GB.
MIN_SAMPLE_RATE = 1.0
MAX_SAMPLE_RATE = 1e6
#: The force channel's name in every rig (analysis/model/rig.py places the hammer under it).
HAMMER_CHANNEL = "hammer"
#: Hammer and simulated hit forces (N). The largest impact hammers measure ~22 kN (PCB 086D50, 5000 lbf); 1 MN is
#: 100 tonnes-force. The simulator sub-steps a hit by the stiffness it reaches: one second of beam_ch4_exp with
#: one hit computed in 0.09 s at 1583 N and at 1e6 N, 0.16 s at 1e12 N, and 56 s at 1e30 N (the 4096-sub-step cap).
MAX_FORCE_N = 1e6
#: A simulated record (rig ``daq.record_length`` here, a simulated session's span in daq/config/session.py), in
#: channel-samples: the simulated device peaked at ~40-60 B a channel-sample (force, 3 response arrays, the
#: sensor/ADC model): beam_ch4_exp 60 s (14.7 M) measured 11 s / 0.97 GB peak RSS, bench_64ch 10 s (32.8 M)
#: 6.8 s / 1.5 GB. 2^24 (16.8 M: 68 s of beam_ch4_exp, 5 s of 64 ch at 51.2 kHz) stays under ~1 GB.
MAX_SIMULATED_CHANNEL_SAMPLES = 1 << 24
#: A rig's simulated record (s); the 2-DOF example needs 200 s (its periods are 3.3 and 5.3 s).
MAX_RIG_RECORD_S = 3600.0
#: The simulator's step control: below 0.05 rad a step costs 5x the default 0.25 for no accuracy the
#: 4th-order stepper needs; towards 0 every sample hits the 4096-sub-step cap, as the 1e30 N hit did (56 s a second).
MIN_OMEGA_DT = 0.05

_ALLOC = "to bound memory and time"

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Force = Annotated[float, Field(gt=0), at_most(MAX_FORCE_N, "N", "1 MN; the simulator's cost grows without bound with the force")]
SampleRate = Annotated[
    float,
    Field(gt=0),
    at_least(MIN_SAMPLE_RATE, "Hz", "is the rate in Hz?"),
    at_most(MAX_SAMPLE_RATE, "Hz", "devices run 256 Hz .. 51.2 kHz; is the rate in Hz?"),
]


class _Strict(BaseModel):
    """Unknown keys, ``inf`` and ``nan`` are mistakes; a loaded config never changes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Located(_Strict):
    """Where an attachment or sensor sits: ``x`` (m along a beam) or ``dof`` (a lumped DOF's name)."""

    x: float | None = None
    dof: str | None = None

    @model_validator(mode="after")
    def _one_location(self) -> Located:
        if (self.x is not None and self.dof is not None) or (self.x is None and self.dof is None and _no_node(self)):
            raise ValueError("give exactly one of 'x' (position along a beam, m) or 'dof' (a lumped DOF name)")
        return self


def _no_node(item: object) -> bool:
    """A sensor or the hammer of an imported (``kind = "matrices"``) rig may be placed by ``node`` (+ ``direction``)
    alone, as the FE model's DOF map names it (analysis/model/matrices.py)."""
    return getattr(item, "node", None) is None


class BeamSpec(_Strict):
    kind: Literal["beam"]
    length: Positive = Field(description="m")
    width: Positive = Field(description="m")
    height: Positive = Field(description="m")
    youngs_modulus: Positive = Field(description="Pa")
    density: Positive = Field(description="kg/m^3")
    elements: Annotated[int, Field(ge=1), at_most(MAX_BEAM_ELEMENTS, "elements", "a finer mesh takes minutes and GBs to solve")]
    left: Literal["clamped", "pinned", "free"] = "clamped"
    right: Literal["clamped", "pinned", "free"] = "free"


class LumpedSpring(_Strict):
    """A linear spring between DOF ``i`` and DOF ``j`` (``j`` omitted: to ground)."""

    i: str
    j: str | None = None
    k: Positive = Field(description="N/m")


class LumpedSpec(_Strict):
    kind: Literal["lumped"]
    masses: Annotated[
        list[Positive], Field(min_length=1), at_most_items(MAX_LUMPED_DOFS, "masses", "more take minutes and GBs to solve")
    ]
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


#: Matrix file formats an imported rig reads (analysis/model/matrices.py): MatrixMarket (Ansys ``*EXPORT,,MMF``, any
#: code through scipy), MATLAB .mat (the usual way FE matrices leave Abaqus/Nastran DMAP scripts, as the seed's did)
#: and Harwell-Boeing RUA (``HBMAT``), each read by scipy.io.
MatrixFormat = Literal["matrixmarket", "matlab", "harwell-boeing"]


class MatrixPart(_Strict):
    """A named substructure stiffness ``K_i`` of ``K = sum p_i K_i`` (``scale`` is ``p_i``, what updating changes)."""

    name: Annotated[str, Field(min_length=1)]
    file: Annotated[str, Field(min_length=1)]
    scale: Positive = 1.0


class MatricesSpec(_Strict):
    """A linear model exported by an FE code at the measured DOFs (analysis/model/matrices.py, docs/fe-import.md).

    Paths are relative to the rig TOML; a .mat file names its variable as ``file.mat#K``. ``dofs`` is a CSV with
    one row per matrix row: ``node,direction[,x,y,z]``. Attachments, nonlinear springs, sensors and the hammer
    are placed by ``dof = "<node>:<direction>"`` (e.g. ``"12:Z"``), sensors and the hammer also by ``node`` and
    ``direction``."""

    kind: Literal["matrices"]
    format: MatrixFormat = "matrixmarket"
    dofs: Annotated[str, Field(min_length=1)]
    mass: Annotated[str, Field(min_length=1)]
    stiffness: str | None = None
    stiffness_parts: list[MatrixPart] = []
    damping: str | None = Field(default=None, description="viscous damping matrix C (projected onto the modes)")

    @model_validator(mode="after")
    def _one_stiffness(self) -> MatricesSpec:
        if (self.stiffness is None) == (not self.stiffness_parts):
            raise ValueError("give exactly one of 'stiffness' (a file) or 'stiffness_parts' (named K_i of K = sum p_i K_i)")
        if len({p.name for p in self.stiffness_parts}) != len(self.stiffness_parts):
            raise ValueError("stiffness_parts: each part needs its own name")
        return self


class PointMass(Located):
    mass: Positive = Field(description="kg")


class LinearSpring(Located):
    k: Positive = Field(description="N/m, to ground")


class NonlinearSpringSpec(Located):
    """Nonlinear spring: ``cubic`` f = coefficient w^3, ``power`` f = coefficient |w|^exponent sign(w).

    Grounded by default (w = the DOF's displacement); with ``to`` (a position on a beam, m, or a DOF name) it
    acts between the two, w = x(at) - x(to) — the seed's NES coupling (eq. 5.7) and LO–store flexure (eq. 6.4)."""

    law: Literal["cubic", "power"] = "cubic"
    coefficient: Positive = Field(description="N/m^3 (cubic) or N/m^exponent (power)")
    exponent: Positive = 3.0
    to: float | str | None = None

    @model_validator(mode="after")
    def _cubic_is_three(self) -> NonlinearSpringSpec:
        if self.law == "cubic" and self.exponent != 3.0:
            raise ValueError("a cubic spring has exponent 3; use law = 'power' for other exponents")
        return self


class DamperSpec(Located):
    """``[[dampers]]``: a local viscous damper and Coulomb friction at a DOF, to ground or (``to``) between two — the
    seed's grounded NES on its rails, eq. 5.11: ``d_r x' + mu_r m g sgn(x')`` (L1642).

    ``coulomb`` is the friction force in N (``mu m g``: the normal force is the rig's business, e.g. the NES's
    weight on its rails, 0.032 x 0.0908 kg x 9.81 m/s^2 = 0.0285 N). The sign is regularised, ``tanh(v / v_eps)``
    (analysis/model/nonlinear.py Damper; v_eps 1e-4 m/s by default, justified in docs/rfs.md)."""

    viscous: NonNegative = Field(default=0.0, description="N s/m")
    coulomb: NonNegative = Field(default=0.0, description="N, the friction force (mu m g)")
    v_eps: Positive = Field(default=1e-4, description="m/s, the sign's regularisation tanh(v / v_eps)")
    to: float | str | None = None

    @model_validator(mode="after")
    def _something(self) -> DamperSpec:
        if self.viscous == 0 and self.coulomb == 0:
            raise ValueError("a damper needs 'viscous' (N s/m) or 'coulomb' (N) above zero")
        return self


class OscillatorSpec(_Strict):
    """``[[oscillators]]`` of a beam rig: a mass with its own translational DOF ``name``, tied to the beam at ``x``
    by a linear spring ``k`` — an attachment such as the seed's NES on its wing (0.25 kg, 10 N/m; L1515).
    Sensors, the hammer and nonlinear springs reach it by ``dof = name``."""

    name: Annotated[str, Field(min_length=1)]
    x: float = Field(description="m along the beam")
    mass: Positive = Field(description="kg")
    k: Positive = Field(description="N/m, to the beam")


class DampingSpec(_Strict):
    """Modal damping ratios: ``zeta[r]`` for mode r+1, ``zeta_rest`` above; ``factor2`` see ModalDamping."""

    zeta: list[Annotated[float, Field(ge=0, lt=1)]] = []
    zeta_rest: Annotated[float, Field(ge=0, lt=1)] = 0.0
    factor2: bool = True


Quantity = Literal["acceleration", "velocity", "displacement", "force"]
#: A UFF node number (datasets 15/55/58/82 write I10; 0 is "pen up" in a trace line): analysis/model/wireframe.py.
NodeId = Annotated[int, Field(ge=1, le=2_147_483_647)]
#: Test geometry nodes: a measured structure has tens to hundreds of points; 10000 keeps a file's UFF 15 small.
MAX_GEOMETRY_NODES = 10_000


def _sensitivity_from_text(data: object, quantity_default: str) -> object:
    """``sensitivity = "100 mV/g"`` (with ``gain = "1 mV/pC"`` for a charge sensor) -> ``sensitivity_mv_per_unit``,
    converted by pint (analysis/model/units.py); the unit must be of the channel's quantity. Both given: they
    must agree (a sensor array's expansion passes both)."""
    if not isinstance(data, dict) or data.get("sensitivity") is None:
        if isinstance(data, dict) and data.get("gain") is not None:
            raise ValueError("gain: applies to a 'sensitivity' written with its unit (e.g. sensitivity = \"10 pC/N\")")
        return data
    text = data["sensitivity"]
    if not isinstance(text, str):
        raise ValueError(f'sensitivity: write the value with its unit as text, e.g. "100 mV/g" (got {text!r})')
    try:
        v_per_si, quantity = parse_sensitivity(text, data.get("gain"))
    except ValueError as exc:
        raise ValueError(f"sensitivity: {exc}") from None
    want = data.get("quantity", quantity_default)
    if quantity != want:
        raise ValueError(f"sensitivity: {text!r} is a sensitivity to {quantity}, but this channel measures {want}")
    mv = 1e3 * v_per_si
    given = data.get("sensitivity_mv_per_unit")
    if given is not None and not (isinstance(given, int | float) and abs(given - mv) <= 1e-9 * mv):
        raise ValueError(f"sensitivity: {text!r} is {mv:.6g} mV per SI unit but sensitivity_mv_per_unit = {given!r}; give one")
    return {**data, "sensitivity_mv_per_unit": mv}


def _check_direction(v: str | None) -> str | None:
    if v is not None:
        parse_direction(v)  # ValueError: "'+W' is not a direction; use one of +X, -X, ..."
    return v


Direction = Annotated[str | None, AfterValidator(_check_direction)]


class SensorProps(_Strict):
    quantity: Quantity = "acceleration"
    sensitivity_mv_per_unit: Positive = Field(description="mV per SI unit of the quantity")
    sensitivity: str | None = Field(default=None, description='as on the calibration sheet, e.g. "100 mV/g" (pint)')
    gain: str | None = Field(default=None, description='charge amplifier gain for a pC/... sensitivity, e.g. "1 mV/pC"')
    direction: Direction = Field(default=None, description="+X .. -Z; default +Z on a beam, +X on a lumped chain")
    range: Positive | None = Field(default=None, description="± measurement range, SI units; None = unlimited")
    noise_rms: NonNegative = Field(
        default=0.0,
        description="noise floor, SI units rms: the simulated device adds it, and the exchange detector gates on it until it "
        "has measured the floor itself (0 = unknown); give the real floor, not a bound (docs/decisions.md D36)",
    )
    model: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _sensitivity_text(cls, data: object) -> object:
        return _sensitivity_from_text(data, "acceleration")


class SensorSpec(SensorProps):
    name: Annotated[str, Field(min_length=1)]
    x: float | None = None
    dof: str | None = None
    node: NodeId | None = Field(default=None, description="test-geometry node id (UFF node number)")

    @model_validator(mode="after")
    def _one_location(self) -> SensorSpec:
        if (self.x is not None and self.dof is not None) or (self.x is None and self.dof is None and _no_node(self)):
            raise ValueError("give exactly one of 'x' (position along a beam, m) or 'dof' (a lumped DOF name)")
        return self


class SensorArraySpec(SensorProps):
    """``count`` equally spaced sensors from ``start`` to ``stop`` (m), named prefix + 1-based index."""

    prefix: Annotated[str, Field(min_length=1)]
    start: float
    stop: float
    count: Annotated[int, Field(ge=1), at_most(MAX_SENSORS, "sensors", f"{MAX_CHANNELS} channels with the hammer")]

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
    sensitivity: str | None = Field(default=None, description='as on the calibration sheet, e.g. "2.25 mV/N", "11.2 mV/lbf"')
    gain: str | None = Field(default=None, description='charge amplifier gain for a pC/N sensitivity, e.g. "1 mV/pC"')
    direction: Direction = Field(default=None, description="+X .. -Z; default as the sensors")
    node: NodeId | None = Field(default=None, description="test-geometry node id of the driving point")
    range: Force | None = Field(default=None, description="± force range, N")
    noise_rms: NonNegative = 0.0
    model: str | None = None
    pulse: Literal["half_sine"] = "half_sine"
    pulse_duration: Positive = Field(description="s")
    peak_force: Force = Field(description="N, nominal strong hit (demo, simulate default)")

    @model_validator(mode="before")
    @classmethod
    def _sensitivity_text(cls, data: object) -> object:
        return _sensitivity_from_text(data, "force")


class DaqSpec(_Strict):
    sample_rate: SampleRate = Field(description="Hz")
    adc_bits: Annotated[int, Field(ge=8, le=32)] = 24
    input_range_volts: Positive = 10.0
    record_length: Annotated[float, Field(gt=0), at_most(MAX_RIG_RECORD_S, "s", "1 hour")] = Field(
        default=2.0, description="s per hit record"
    )


class SimulationSpec(_Strict):
    modal_cutoff_hz: Positive = 5000.0
    max_omega_dt: Annotated[float, Field(le=2.0), at_least(MIN_OMEGA_DT, "rad", "smaller steps cost time for nothing")] = 0.25
    order: Literal[2, 4] = 2
    residual_vectors: bool = True
    seed: Annotated[int, Field(ge=0)] = 0  # numpy's generators take a non-negative seed


class GeometryNode(_Strict):
    id: NodeId
    x: float = Field(description="m")
    y: float = Field(default=0.0, description="m")
    z: float = Field(default=0.0, description="m")


class GeometrySpec(_Strict):
    """The test geometry (analysis/model/wireframe.py): nodes and trace lines, for a structure the FE model does
    not draw (a beam model of a frame); every sensor and the hammer then name their ``node``."""

    nodes: Annotated[
        list[GeometryNode], Field(min_length=1), at_most_items(MAX_GEOMETRY_NODES, "nodes", "a test has far fewer points")
    ]
    lines: Annotated[list[tuple[NodeId, NodeId]], at_most_items(4 * MAX_GEOMETRY_NODES, "lines", "four per node")] = []

    @model_validator(mode="after")
    def _consistent(self) -> GeometrySpec:
        import numpy as np  # numpy only for a rig with [geometry]: loading a config stays light

        from analysis.model.wireframe import geometry_problem

        ids = np.array([n.id for n in self.nodes], dtype=np.int64)
        xyz = np.array([[n.x, n.y, n.z] for n in self.nodes], dtype=float)
        problem = geometry_problem(ids, xyz, np.array(self.lines, dtype=np.int64).reshape(-1, 2))
        if problem:
            raise ValueError(problem)
        return self


#: Updating parameters a rig may declare (analysis/model/updating.py): a handful in practice (the seed updated 2 in
#: Ch. 4, 3-4 in Ch. 5-6); each costs ~15 model solves a generation of the global search.
MAX_UPDATE_PARAMETERS = 12
#: Measured modes an update may use: the seed used 6; the FE eigenproblem is solved for 2x as many to pair them.
MAX_UPDATE_MODES = 50


class UpdateParameter(_Strict):
    """One updating parameter (``[[update.parameters]]``): ``target`` names the value it sets, e.g.
    ``structure.youngs_modulus``, ``point_masses[0].mass``, ``springs[0].k`` (analysis/model/update_targets.py TARGETS)."""

    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]
    target: Annotated[str, Field(min_length=1)]
    bounds: tuple[Positive, Positive] = Field(description="lowest and highest value, the target's SI unit")

    @model_validator(mode="after")
    def _ordered(self) -> UpdateParameter:
        if not self.bounds[0] < self.bounds[1]:
            raise ValueError(f"bounds: the lower bound must be below the upper one (got {list(self.bounds)})")
        return self


class UpdateModeRow(_Strict):
    """One measured mode of an update's provenance: its FE partner, the two frequencies, eq. 4.5's term."""

    mode: int
    fe_mode: int
    measured_hz: float
    model_hz: float
    residual: float = Field(description="(f_measured - f_model) / (n f_measured), n = fe_mode (seed eq. 4.5)")
    mac: float | None = None
    std_hz: float | None = Field(default=None, description="the measured frequency's 1-sigma, when known")
    z: float | None = Field(default=None, description="(f_measured - f_model) / std_hz")


class UpdateValue(_Strict):
    name: str
    target: str
    nominal: float
    value: float
    sigma: float | None = Field(default=None, description="1-sigma from the residuals' Jacobian; absent if undefined")
    identifiable: bool | None = None


class UpdateProvenance(_Strict):
    """Where an updated rig's values came from (written by ``gvt model update``; read back by every verb)."""

    rig: str
    source: str
    date: str
    objective: str
    objective_value: float
    optimiser: str
    evaluations: int
    uncertainty: str
    chi2_nu: float | None = None
    warnings: list[str] = []
    data: dict[str, str | list[str]] = Field(default={}, description="what of the source was used: hits, channels, band")
    modes: list[UpdateModeRow] = []
    values: list[UpdateValue] = []


class UpdateSpec(_Strict):
    """``[update]``: what ``gvt model update`` may change and how it scores a model (seed eq. 4.5, L1363)."""

    objective: Literal["eq45", "eq45+mac"] = "eq45"
    modes: Annotated[int, Field(ge=1), at_most(MAX_UPDATE_MODES, "modes", "the seed used 6")] = 6
    mac_weight: NonNegative = 1.0
    seed: Annotated[int, Field(ge=0)] = 0
    parameters: Annotated[
        list[UpdateParameter], at_most_items(MAX_UPDATE_PARAMETERS, "parameters", "each one widens the global search")
    ] = []
    provenance: UpdateProvenance | None = None


class NsiSpec(_Strict):
    """``[nsi]``: the nonlinear attachment ``gvt identify`` characterises (seed §5.1, docs/nsi.md).

    The attachment sits at ``x`` (beam, m) or ``dof`` (a DOF name); δ is its displacement minus the mean of
    the ``relative_to`` points (eq. 5.13: positions on a beam, DOF names otherwise), or the attachment itself
    when the list is empty (grounded). ``mass``: the attachment's mass in eq. 5.8 (default: the effective mass
    1/φ_δ² of its mass-normalised linear mode), or ``inertia`` and ``arm`` for a rotational attachment (a store
    pinned at one end, its spring at arm h: m = I/h² in z = hθ, eq. 6.11 with h²/I, method-nsi D3); ``mode``: that
    linear mode, 1-based (default: the lowest mode whose φ_δ² is at least half the largest); ``delta_highpass_hz``:
    the Butterworth high-pass on δ before δ̄ of measured data (Ch. 5 used 6 Hz, L1747; none by default)."""

    x: float | None = None
    dof: str | None = None
    relative_to: list[float | str] = []
    mass: Positive | None = Field(default=None, description="kg")
    inertia: Positive | None = Field(default=None, description="kg m^2: a rotational attachment (store, eq. 6.11)")
    arm: Positive | None = Field(default=None, description="m: the arm h at which the rotational attachment's spring acts")
    mode: Annotated[int, Field(ge=1)] | None = None
    delta_highpass_hz: Positive | None = Field(default=None, description="Hz")

    @model_validator(mode="after")
    def _one_location(self) -> NsiSpec:
        if (self.x is None) == (self.dof is None):
            raise ValueError("give exactly one of 'x' (position along a beam, m) or 'dof' (a DOF name) for the attachment")
        if (self.inertia is None) != (self.arm is None):
            raise ValueError("a rotational attachment needs both 'inertia' (kg m^2) and 'arm' (m)")
        if self.inertia is not None and self.mass is not None:
            raise ValueError("give 'mass' (translational) or 'inertia' and 'arm' (rotational, m = I/h^2), not both")
        return self

    @property
    def attachment_mass(self) -> float | None:
        """The m of eq. 5.8 in the attachment's coordinate: ``mass``, or ``I/h²`` for a rotational one (eq. 6.11 in
        z = hθ, with the erratum's h²/I: method-nsi D3); None: the linear mode's effective mass."""
        if self.inertia is not None and self.arm is not None:
            return self.inertia / self.arm**2
        return self.mass


class RigConfig(_Strict):
    name: Annotated[str, Field(min_length=1)]
    description: str = ""
    source: str = ""
    structure: Annotated[BeamSpec | LumpedSpec | MatricesSpec, Field(discriminator="kind")]
    point_masses: list[PointMass] = []
    springs: list[LinearSpring] = []
    nonlinear_springs: list[NonlinearSpringSpec] = []
    dampers: list[DamperSpec] = []
    oscillators: list[OscillatorSpec] = []
    damping: DampingSpec = DampingSpec()
    sensors: list[SensorSpec] = []
    sensor_arrays: list[SensorArraySpec] = []
    hammer: HammerSpec
    daq: DaqSpec
    simulation: SimulationSpec = SimulationSpec()
    geometry: GeometrySpec | None = None
    update: UpdateSpec | None = None
    nsi: NsiSpec | None = None

    @property
    def all_sensors(self) -> list[SensorSpec]:
        out = list(self.sensors)
        for arr in self.sensor_arrays:
            out.extend(arr.expand())
        return out

    @staticmethod
    def _check_supports(s: BeamSpec, located: list[tuple[str, Located | SensorSpec]]) -> None:
        """A sensor, the hammer or a nonlinear spring snapped onto a support's (constrained) deflection has no
        DOF to sit on: said here, at its field, instead of by the assembly (``BeamMesh.snap``'s rounding)."""
        le = s.length / s.elements
        fixed = {0: s.left, s.elements: s.right}
        for path, item in located:
            if path.startswith(("point_masses", "springs")) or item.x is None:
                continue  # a mass or a linear spring on a support is carried by the support
            node = min(max(round(item.x / le), 0), s.elements)
            end = fixed.get(node)
            if end in ("clamped", "pinned"):
                what = (
                    {"hammer": "the hammer"}.get(path)
                    or getattr(item, "name", None)
                    or ("the damper" if path.startswith("dampers") else "the nonlinear spring")
                )
                raise ConfigFieldError(
                    f"{path}.x",
                    f"{what} at x = {item.x:g} m snaps to node {node}, a constrained DOF of the {end} support; "
                    f"move it at least {0.5 * le:g} m away",
                )

    def _check_nodes(self) -> None:
        """With a ``[geometry]`` table the hammer and every sensor name a node of it (there is no position to
        derive one from)."""
        if self.geometry is None:
            return
        ids = {n.id for n in self.geometry.nodes}
        if self.sensor_arrays:
            raise ConfigFieldError("sensor_arrays", "a rig with [geometry] lists its sensors one by one, each with its node")
        where = [("hammer.node", "the hammer", self.hammer.node)]
        where += [(f"sensors[{i}].node", s.name, s.node) for i, s in enumerate(self.sensors)]
        for path, what, node in where:
            if node is None:
                raise ConfigFieldError(path, f"{what} needs a node of [geometry] (ids {min(ids)}..{max(ids)})")
            if node not in ids:
                raise ConfigFieldError(path, f"node {node} is not among the [geometry] nodes; add it there or correct the id")

    def check(self) -> None:
        """Cross-field checks, each raising a :class:`ConfigFieldError` at the offending path: sensors and their
        count, where each thing sits on this kind of structure, geometry nodes, update parameters, sensor names,
        then the hammer pulse and the record against the sample rate."""
        n_sensors = self._check_sensor_count()
        located = self._located()
        s = self.structure
        if self.oscillators and not isinstance(s, BeamSpec):
            raise ConfigFieldError("oscillators", "[[oscillators]] attach to a beam; a lumped rig lists the mass and its spring")
        if isinstance(s, BeamSpec):
            self._check_on_beam(s, located)
        elif isinstance(s, MatricesSpec):
            self._check_on_matrices(s, located)
        else:
            self._check_on_lumped(s, located)
        self._check_nodes()
        if self.update is not None and self.update.parameters:
            check_parameters(self, self.update.parameters)
        self._check_sensor_names()
        self._check_timing(n_sensors)

    def _check_sensor_count(self) -> int:
        """At least one sensor and at most :data:`MAX_SENSORS`, counted before any array is expanded."""
        if not self.sensors and not self.sensor_arrays:
            raise ConfigFieldError("sensors", "a rig needs at least one sensor")
        n_sensors = len(self.sensors) + sum(a.count for a in self.sensor_arrays)  # before any array is expanded
        where = "sensor_arrays" if self.sensor_arrays else "sensors"
        check_limit(where, n_sensors, MAX_SENSORS, "sensors", f"{MAX_CHANNELS} channels with the hammer")
        return n_sensors

    def _located(self) -> list[tuple[str, Located | SensorSpec]]:
        """Everything placed on the structure, with the path its errors name: attachments, sensors, the hammer,
        then each array's expanded sensors."""
        located: list[tuple[str, Located | SensorSpec]] = [
            *((f"point_masses[{i}]", p) for i, p in enumerate(self.point_masses)),
            *((f"springs[{i}]", p) for i, p in enumerate(self.springs)),
            *((f"nonlinear_springs[{i}]", p) for i, p in enumerate(self.nonlinear_springs)),
            *((f"dampers[{i}]", p) for i, p in enumerate(self.dampers)),
            *((f"sensors[{i}]", p) for i, p in enumerate(self.sensors)),
            ("hammer", self.hammer),
        ]
        for a, arr in enumerate(self.sensor_arrays):
            for sensor in arr.expand():
                located.append((f"sensor_arrays[{a}]", sensor))
        return located

    def _check_on_beam(self, s: BeamSpec, located: list[tuple[str, Located | SensorSpec]]) -> None:
        """On a beam everything sits at ``x`` within half an element of the beam, or on an oscillator's own DOF by
        its name, and nothing that needs a DOF on a support's constrained deflection."""
        half = 0.5 * s.length / s.elements
        osc = [o.name for o in self.oscillators]
        if len(set(osc)) != len(osc):
            raise ConfigFieldError("oscillators", "each oscillator needs its own name")
        located = located + self._beam_anchors(osc)
        for path, item in located:
            if item.dof is not None and item.dof in osc:
                continue  # on an oscillator's own DOF
            if item.dof is not None:
                raise ConfigFieldError(
                    f"{path}.dof", f"a beam rig places things by 'x' (m), or by an oscillator's name {osc}, not by DOF name"
                )
            if item.x is None:
                raise ConfigFieldError(f"{path}.x", "a beam rig places things by 'x' (m along the beam)")
            if item.x < -half or item.x > s.length + half:
                raise ConfigFieldError(
                    f"{path}.x",
                    f"position {item.x:g} m is off the beam [0, {s.length:g}] m by more than half an element "
                    f"({half:g} m); move it onto the beam",
                )
        self._check_supports(s, located)

    def _beam_anchors(self, osc: list[str]) -> list[tuple[str, Located | SensorSpec]]:
        """The other points a beam rig places: each oscillator's tie to the beam, and the ``to`` end of a nonlinear
        spring or damper given as a position (one given as a name must be an oscillator's)."""
        anchors: list[tuple[str, Located | SensorSpec]] = [
            (f"oscillators[{i}]", Located(x=o.x)) for i, o in enumerate(self.oscillators)
        ]
        for kind, items in (("nonlinear_springs", self.nonlinear_springs), ("dampers", self.dampers)):
            for i, p in enumerate(items):
                if isinstance(p.to, str) and p.to not in osc:
                    raise ConfigFieldError(f"{kind}[{i}].to", f"unknown oscillator {p.to!r}; this rig has {osc}")
                if isinstance(p.to, float):
                    anchors.append((f"{kind}[{i}].to", Located(x=p.to)))
        return anchors

    def _check_on_matrices(self, s: MatricesSpec, located: list[tuple[str, Located | SensorSpec]]) -> None:
        """An imported rig places things by DOF (names come from the DOF map: checked when it is read, matrices.py)
        and brings its own damping matrix or the ``[damping]`` ratios, not both."""
        for path, item in located:
            if item.x is not None:
                raise ConfigFieldError(f"{path}.x", "an imported rig places things by 'dof' ('<node>:<direction>') or 'node'")
        if s.damping is not None and "damping" in self.model_fields_set:
            raise ConfigFieldError("damping", "the model brings its damping matrix (structure.damping); drop [damping]")

    def _check_on_lumped(self, s: LumpedSpec, located: list[tuple[str, Located | SensorSpec]]) -> None:
        """A lumped rig places things, and ends its springs, nonlinear springs and dampers, on its own DOF names."""
        names = s.names
        for path, item in located:
            if item.x is not None:
                raise ConfigFieldError(f"{path}.x", "a lumped rig places things by 'dof' name, not by 'x'")
            if item.dof not in names:
                raise ConfigFieldError(f"{path}.dof", f"unknown DOF {item.dof!r}; this rig has {names}")
        for kind, items in (("nonlinear_springs", self.nonlinear_springs), ("dampers", self.dampers)):
            for i, p in enumerate(items):
                if p.to is not None and (not isinstance(p.to, str) or p.to not in names or p.to == p.dof):
                    raise ConfigFieldError(f"{kind}[{i}].to", f"{p.to!r} is not another DOF of this rig ({names})")
        for i, sp in enumerate(s.springs):
            for end in ("i", "j"):
                v = getattr(sp, end)
                if v is not None and v not in names:
                    raise ConfigFieldError(f"structure.springs[{i}].{end}", f"unknown DOF {v!r}; this rig has {names}")

    def _check_sensor_names(self) -> None:
        """Each sensor, listed or expanded from an array, has its own name (a channel is found by it), and none
        takes the hammer's channel name: a sensor named "hammer" relabelled the force channel (issue 30)."""
        seen: set[str] = set()
        for sensor in self.all_sensors:
            if sensor.name == HAMMER_CHANNEL:
                raise ConfigFieldError(
                    "sensors", f"sensor name {HAMMER_CHANNEL!r} is the hammer's force channel; give the sensor another name"
                )
            if sensor.name in seen:
                raise ConfigFieldError("sensors", f"sensor name {sensor.name!r} is used twice")
            seen.add(sensor.name)

    def _check_timing(self, n_sensors: int) -> None:
        """The hammer pulse and the record span at least two samples, the pulse fits in the record, and the
        simulated record stays under :data:`MAX_SIMULATED_CHANNEL_SAMPLES`."""
        fs = self.daq.sample_rate
        if self.hammer.pulse_duration * fs < 2.0:
            raise ConfigFieldError(
                "hammer.pulse_duration",
                f"{self.hammer.pulse_duration:g} s is shorter than two samples at {fs:g} Hz "
                f"(needs >= {2.0 / fs:g} s); lengthen the pulse or raise daq.sample_rate",
            )
        if self.daq.record_length * fs < 2.0:
            raise ConfigFieldError("daq.record_length", "shorter than two samples at daq.sample_rate")
        if self.hammer.pulse_duration > self.daq.record_length:
            raise ConfigFieldError(
                "hammer.pulse_duration",
                f"{self.hammer.pulse_duration:g} s is longer than the record (daq.record_length {self.daq.record_length:g} s)",
            )
        check_limit(
            "daq.record_length",
            self.daq.record_length * fs * (n_sensors + 1),
            MAX_SIMULATED_CHANNEL_SAMPLES,
            "channel-samples",
            f"record_length x sample_rate x channels; ~1 GB to simulate; shorten the record or lower the rate, {_ALLOC}",
        )
