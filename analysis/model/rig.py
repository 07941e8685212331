"""A test rig built from its config: structure, placed sensors and hammer, and a ready simulator.

Building a rig needs numpy and the config only; the modes and Guyan reduction (scipy) and the simulator
(numba) are imported when first asked for, so a recorder that only needs the rig's channels stays light.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.model.config import BeamSpec, MatricesSpec, RigConfig, SensorProps
from analysis.model.forces import HalfSine
from analysis.model.loader import load_config
from analysis.model.nonlinear import Damper
from analysis.model.structure import ModalDamping, Structure, build_beam, build_lumped

if TYPE_CHECKING:  # scipy (modes, Guyan) and numba (the simulator) load when a rig first needs them
    from analysis.model.guyan import GuyanModel
    from analysis.model.modal import Modes
    from analysis.model.simulate import ImpactSimulator

UNITS = {"acceleration": "m/s^2", "velocity": "m/s", "displacement": "m", "force": "N"}


@dataclass(frozen=True)
class PlacedChannel:
    """A sensor (or the hammer's force cell) snapped onto a model DOF."""

    name: str
    quantity: str
    dof: int
    dof_name: str
    x_requested: float | None
    x_model: float | None
    props: SensorProps

    @property
    def unit(self) -> str:
        return UNITS[self.quantity]


@dataclass(frozen=True)
class Rig:
    config: RigConfig
    structure: Structure
    sensors: tuple[PlacedChannel, ...]
    hammer: PlacedChannel
    path: str = "<config>"

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def sample_rate(self) -> float:
        return self.config.daq.sample_rate

    @property
    def sensor_dofs(self) -> list[int]:
        return [s.dof for s in self.sensors]

    @cached_property
    def modes(self) -> Modes:
        from analysis.model.modal import structure_modes

        return structure_modes(self.structure)

    def limit_structure(self, limit: str = "low") -> Structure:
        """``low``: the underlying linear structure; ``high``: nonlinear springs replaced by pins."""
        if limit == "low":
            return self.structure.linear()
        if limit == "high":
            return self.structure.high_energy_limit()
        raise ValueError("limit must be 'low' or 'high'")

    def master_dofs(self) -> list[int]:
        """Distinct sensor DOFs in order along the structure (the seed's Guyan masters, L1367)."""
        return sorted(set(self.sensor_dofs))

    def guyan(self, masters: list[int] | None = None) -> GuyanModel:
        from analysis.model.guyan import guyan_reduce

        return guyan_reduce(self.structure.M, self.structure.K, masters if masters is not None else self.master_dofs())

    def hammer_force(self, peak: float | None = None) -> HalfSine:
        h = self.config.hammer
        return HalfSine(peak=h.peak_force if peak is None else float(peak), duration=h.pulse_duration)

    @cached_property
    def simulator(self) -> ImpactSimulator:
        from analysis.model.simulate import ImpactSimulator

        sim = self.config.simulation
        return ImpactSimulator(
            self.structure,
            self.hammer.dof,
            self.sensor_dofs,
            cutoff_hz=sim.modal_cutoff_hz,
            residual_vectors=sim.residual_vectors,
            max_omega_dt=sim.max_omega_dt,
            order=sim.order,
            modes=self.modes,
        )


def _place(
    structure: Structure,
    cfg: RigConfig,
    name: str,
    quantity: str,
    x: float | None,
    dof: str | None,
    props: SensorProps,
    node: int | None = None,
    field: str = "sensors",
) -> PlacedChannel:
    if isinstance(cfg.structure, MatricesSpec):  # by "<node>:<direction>" or node + direction (matrices.py)
        from analysis.model.matrices import resolve_dof

        idx = resolve_dof(structure.dofs, field, dof, node, props.direction)
        d = structure.dofs[idx]
        return PlacedChannel(name, quantity, idx, d.name, None, d.x, props)
    if isinstance(cfg.structure, BeamSpec) and dof is not None:  # an [[oscillators]] mass, by its name
        return PlacedChannel(name, quantity, structure.dof_index(dof), dof, None, None, props)
    if isinstance(cfg.structure, BeamSpec):
        assert structure.mesh is not None and x is not None
        node, _ = structure.mesh.snap(x)
        dof_name = f"w{node}"
        try:
            idx = structure.dof_index(dof_name)
        except KeyError:
            raise ValueError(f"{name} at x = {x:g} m sits on a constrained DOF (a support)") from None
        return PlacedChannel(name, quantity, idx, dof_name, x, float(structure.mesh.node_x[node]), props)
    assert dof is not None
    return PlacedChannel(name, quantity, structure.dof_index(dof), dof, None, None, props)


def _damper(structure: Structure, cfg: RigConfig, i: int) -> Damper:
    """``[[dampers]]`` entry ``i`` on the built structure's DOFs (placed as a sensor is: ``x``, a DOF name or an
    imported rig's ``"<node>:<direction>"``; ``to`` likewise)."""
    from analysis.model.nonlinear import Damper

    d = cfg.dampers[i]
    props = SensorProps(quantity="force", sensitivity_mv_per_unit=1.0)
    at = _place(structure, cfg, "damper", "force", d.x, d.dof, props, None, f"dampers[{i}]").dof
    ref = None
    if d.to is not None:
        x_to, dof_to = (float(d.to), None) if isinstance(d.to, int | float) else (None, d.to)
        ref = _place(structure, cfg, "damper", "force", x_to, dof_to, props, None, f"dampers[{i}].to").dof
    return Damper(dof=at, viscous=d.viscous, coulomb=d.coulomb, v_eps=d.v_eps, ref=ref)


def build_rig(cfg: RigConfig, path: str | Path = "<config>") -> Rig:
    damping = ModalDamping(zeta=tuple(cfg.damping.zeta), zeta_rest=cfg.damping.zeta_rest, factor2=cfg.damping.factor2)
    s = cfg.structure
    if isinstance(s, BeamSpec):
        structure = build_beam(
            length=s.length,
            width=s.width,
            height=s.height,
            E=s.youngs_modulus,
            rho=s.density,
            n_elements=s.elements,
            left=s.left,
            right=s.right,
            point_masses=[(p.x, p.mass) for p in cfg.point_masses],
            springs=[(p.x, p.k) for p in cfg.springs],
            nonlinear_springs=[
                (p.x if p.dof is None else p.dof, p.law, p.coefficient, p.exponent, p.to) for p in cfg.nonlinear_springs
            ],
            damping=damping,
            oscillators=[(o.name, o.x, o.mass, o.k) for o in cfg.oscillators],
        )
    elif isinstance(s, MatricesSpec):  # matrices from an FE code, attachments added on top (matrices.py)
        from analysis.model.matrices import build_imported

        structure = build_imported(cfg, Path(path).parent if str(path) != "<config>" else Path.cwd(), damping)
    else:
        names = s.names
        idx = {n: i for i, n in enumerate(names)}
        springs = [(idx[sp.i], None if sp.j is None else idx[sp.j], sp.k) for sp in s.springs]
        springs += [(idx[p.dof], None, p.k) for p in cfg.springs]
        masses = list(s.masses)
        for p in cfg.point_masses:
            masses[idx[p.dof]] += p.mass
        structure = build_lumped(
            masses=masses,
            springs=springs,
            nonlinear_springs=[
                (idx[p.dof], p.law, p.coefficient, p.exponent, None if p.to is None else idx[str(p.to)])
                for p in cfg.nonlinear_springs
            ],
            names=names,
            damping=damping,
        )
    if cfg.dampers:
        structure = replace(structure, dampers=tuple(_damper(structure, cfg, i) for i in range(len(cfg.dampers))))
    n_listed = len(cfg.sensors)

    def where(i: int) -> str:
        return f"sensors[{i}]" if i < n_listed else "sensor_arrays"

    sensors = tuple(
        _place(structure, cfg, sn.name, sn.quantity, sn.x, sn.dof, sn, sn.node, where(i)) for i, sn in enumerate(cfg.all_sensors)
    )
    h = cfg.hammer
    hprops = SensorProps(
        quantity="force", sensitivity_mv_per_unit=h.sensitivity_mv_per_unit, range=h.range, noise_rms=h.noise_rms, model=h.model
    )
    if isinstance(s, MatricesSpec):
        hprops = hprops.model_copy(update={"direction": h.direction})
    hammer = _place(structure, cfg, "hammer", "force", h.x, h.dof, hprops, h.node, "hammer")
    return Rig(config=cfg, structure=structure, sensors=sensors, hammer=hammer, path=str(path))


def load_rig(path: str | Path) -> Rig:
    """Load and build a rig; raises :class:`ConfigError` (one line naming file and field) on a bad file.

    ``RigConfig.check`` has refused what the assembly would (positions off the beam or on a support, limits);
    a ``ValueError`` the assembly still raises becomes a one-line error too, never a traceback."""
    from analysis.model.loader import ConfigError, ConfigFieldError

    cfg = load_config(RigConfig, path)
    try:
        return build_rig(cfg, path)
    except ConfigFieldError as exc:
        raise ConfigError(path, exc.field, exc.problem) from None
    except (ValueError, KeyError) as exc:  # the assembly's own checks (the schema should have caught them)
        raise ConfigError(path, "structure", str(exc).strip("'\"")) from None


def channel_signals(rig: Rig, result, index: int = 0) -> tuple[list[PlacedChannel], np.ndarray]:
    """Physical signals (n_samples, 1 + n_sensors) for the hammer then each sensor, SI units."""
    cols = [result.force[index]]
    for k, s in enumerate(rig.sensors):
        arr = {"acceleration": result.acceleration, "velocity": result.velocity, "displacement": result.displacement}[s.quantity]
        cols.append(arr[index, :, k])
    return [rig.hammer, *rig.sensors], np.stack(cols, axis=1)
