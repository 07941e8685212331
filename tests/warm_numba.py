"""Build numba's on-disk cache before the suite starts (make test): ``python tests/warm_numba.py sweep|analysis``.

On a fresh clone the cache is empty, and the first test of each worker, and every ``gvt`` child process started
before some process has written the cache, compiled the same kernels again (the simulator's integrator alone is
~14 s). ``make test`` runs the two groups here side by side, one a core, so the suite's processes load the
kernels instead of compiling them; the tests are unchanged (a kernel whose signature is missed here is compiled
where it is first used, as before). The cache is the one ``gvt`` run directly uses (analysis/jit_cache.py, D70).
"""

from __future__ import annotations

import sys
import time

import numpy as np


def sweep() -> None:
    """The integrator's batch of moments (second and fourth order) and the sweep's modal-phase kernels."""
    from analysis.model.rig_sim import output_dofs, rig_simulator
    from analysis.model.rigs import open_rig
    from analysis.model.sweep import ModalProbe, run_with_modal_phase

    rig = open_rig("beam_ch4_sim")
    dofs = output_dofs(rig, "translational")
    for order in (2, 4):
        rig_simulator(rig, dofs, order).run_moments(rig.hammer_force(), 0.01, rig.sample_rate, [1.0, 2.0])
    g = rig.guyan(dofs)
    probe = ModalProbe.from_guyan(g.M, g.K, 2)
    run_with_modal_phase(rig_simulator(rig, dofs, None), rig.hammer_force(), 0.05, rig.sample_rate, np.array([1.0]), probe)


def analysis() -> None:
    """One simulated hit (the integrator's single run) and the near-live kernels (operator, modal filter,
    exchange detector, integration, RQ spikes)."""
    from analysis.model.rigs import open_rig
    from analysis.operator import RigModel
    from daq.lanes.analysis import warm_up

    rig = open_rig("beam_ch4_exp")
    rig.simulator.run(rig.hammer_force(10.0), 0.01, rig.sample_rate)
    sim = open_rig("beam_ch4_sim")  # the batch of amplitudes, time series and moments (~20 s, test_simulator)
    sim.simulator.run_moments(sim.hammer_force(), 0.01, sim.sample_rate, [1.0, 2.0])
    sim.simulator.run(sim.hammer_force(), 0.01, sim.sample_rate, amplitudes=[1.0, 2.0])
    names = tuple(s.name for s in rig.sensors)
    warm_up(RigModel.from_rig(rig), "dev0", ("hammer", *names), rig.sample_rate)


if __name__ == "__main__":
    t0 = time.perf_counter()
    {"sweep": sweep, "analysis": analysis}[sys.argv[1]]()
    from analysis.jit_cache import cache_dir

    print(f"numba cache warmed ({sys.argv[1]}, in {cache_dir()}): {time.perf_counter() - t0:.1f} s")
