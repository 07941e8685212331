"""The Dask sweep returns, in order, exactly what in-process runs give."""

from __future__ import annotations

import numpy as np

from analysis.model.sweep import sweep_moments


def test_dask_sweep_equals_in_process_moments(rigs):
    rig = rigs("beam_ch4_sim")
    sim = rig.simulator
    amps = np.logspace(1, 9, 5)
    seen = []
    res = sweep_moments(
        sim,
        rig.hammer_force(),
        amps,
        0.05,
        rig.sample_rate,
        n_workers=2,
        chunk_size=2,
        progress=lambda done, total: seen.append((done, total)),
    )
    ref = sim.run_moments(rig.hammer_force(), 0.05, rig.sample_rate, amps)
    assert np.array_equal(res.amplitudes, amps)
    assert np.allclose(res.covariance, ref.covariance, rtol=1e-12, atol=0)
    assert np.allclose(res.input_work, ref.input_work, rtol=1e-12)
    assert seen[-1] == (5, 5) and len(seen) == 3
