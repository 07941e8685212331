"""The impact simulator of a rig, as the sweep (``gvt sweep``) and the NSI (``gvt identify``) run it.

Both studies, and the validation by re-simulation, simulate the same rig at the same outputs with the rig's
own ``[simulation]`` settings; the choice lives here, below all of them.
"""

from __future__ import annotations

from analysis.model.rig import Rig
from analysis.model.simulate import ImpactSimulator


def output_dofs(rig: Rig, which: str) -> list[int]:
    """``translational``: every transverse DOF of the structure (the seed's 100 nodes, L1251);
    ``sensors``: the distinct sensor DOFs (the experiment's masters, L1367)."""
    return rig.structure.translational_dofs() if which == "translational" else rig.master_dofs()


def rig_simulator(rig: Rig, dofs: list[int], order: int | None) -> ImpactSimulator:
    """The rig's impact simulator observed at ``dofs``, with its ``[simulation]`` settings (``order`` overrides)."""
    sim = rig.config.simulation
    return ImpactSimulator(
        rig.structure,
        rig.hammer.dof,
        dofs,
        cutoff_hz=sim.modal_cutoff_hz,
        residual_vectors=sim.residual_vectors,
        max_omega_dt=sim.max_omega_dt,
        order=sim.order if order is None else order,
        modes=rig.modes,
    )
