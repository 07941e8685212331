"""What the near-live analysis needs of a rig (:class:`RigModel`): the sensors in model order, the Guyan M and K at
their DOFs, the damping, positions, ranges, sensitivities and noise a sensor's checks use.

Apart from the operator (analysis/operator.py, which re-exports it) because it needs only the rig and numpy:
``gvt report`` and the view set up their figures from it without loading the detection kernels, their JIT and
scipy.signal (docs/decisions.md D108).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RigModel:
    """What the operator needs of the rig: sensor names in model order, Guyan M and K at their DOFs."""

    sensors: tuple[str, ...]
    hammer: str | None
    M: np.ndarray
    K: np.ndarray
    damping: tuple[float, ...] | None = None
    x: np.ndarray | None = None
    nonlinearity_measured: bool | None = None  # a sensor sits on every nonlinear spring's DOF (L69); None: no springs
    nonlinear_sensors: tuple[str, ...] = ()  # the sensors on the nonlinear springs' DOFs: losing one blinds detection
    ranges: tuple[float | None, ...] | None = None  # ± range per sensor (SI), for the clipping check
    sensitivities: tuple[float, ...] | None = None  # mV per SI unit per sensor: noise compared in volts
    #: the sensors' specified noise (SI rms, the rig's ``noise_rms``): the band noise the exchange detector gates on
    #: until it has measured the floor itself (None: not declared for every sensor)
    noise_rms: tuple[float, ...] | None = None

    @classmethod
    def from_rig(cls, rig) -> RigModel:
        masters = rig.master_dofs()
        if len(masters) != len(rig.sensors):
            raise ValueError("the rig has two sensors on one DOF: the RQ needs one sensor per model DOF (assumption 7, L65)")
        order = sorted(range(len(rig.sensors)), key=lambda i: masters.index(rig.sensors[i].dof))
        g = rig.guyan([rig.sensors[i].dof for i in order])
        z = rig.config.damping
        zeta = (*z.zeta, *([z.zeta_rest] * 8)) if z is not None else None
        nl_dofs = {sp.dof for sp in rig.structure.nonlinear}
        return cls(
            sensors=tuple(rig.sensors[i].name for i in order), hammer=rig.hammer.name, M=g.M, K=g.K, damping=zeta,
            x=np.array([rig.sensors[i].x_model or 0.0 for i in order]),
            nonlinearity_measured=all(sp.dof in masters for sp in rig.structure.nonlinear) if rig.structure.nonlinear else None,
            nonlinear_sensors=tuple(rig.sensors[i].name for i in order if rig.sensors[i].dof in nl_dofs),
            ranges=tuple(getattr(getattr(rig.sensors[i], "props", None), "range", None) for i in order),
            sensitivities=_sensitivities(rig, order),
            noise_rms=_noise_rms(rig, order),
        )  # fmt: skip


def _sensitivities(rig, order: list[int]) -> tuple[float, ...] | None:
    s = [getattr(getattr(rig.sensors[i], "props", None), "sensitivity_mv_per_unit", None) for i in order]
    return None if any(v is None for v in s) else tuple(float(v) for v in s)


def _noise_rms(rig, order: list[int]) -> tuple[float, ...] | None:
    n = [getattr(getattr(rig.sensors[i], "props", None), "noise_rms", None) for i in order]
    return None if any(v is None or v <= 0 for v in n) else tuple(float(v) for v in n)
