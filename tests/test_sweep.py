"""The Dask sweep returns, in order, exactly what in-process runs give."""

from __future__ import annotations

import numpy as np

from analysis.model.sweep import ModalProbe, SweepMoments, run_with_modal_phase, sweep_moments


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


def test_dask_sweep_with_a_modal_probe_equals_in_process_runs(rigs):
    """The per-run modal frequencies come back through Dask in order, chunks concatenated, and the moments
    are unchanged by measuring them (one worker: the CI machine is shared)."""
    rig = rigs("beam_ch4_sim")
    sim = rig.simulator
    g = rig.guyan(sim.output_dofs)
    probe = ModalProbe.from_guyan(g.M, g.K, 2)
    amps = np.array([20.0, 150.0, 400.0])
    res = sweep_moments(sim, rig.hammer_force(), amps, 0.4, rig.sample_rate, n_workers=1, chunk_size=2, probe=probe)
    ref = run_with_modal_phase(sim, rig.hammer_force(), 0.4, rig.sample_rate, amps, probe)
    plain = sim.run_moments(rig.hammer_force(), 0.4, rig.sample_rate, amps)
    assert isinstance(res, SweepMoments) and res.modal_windows_s == probe.windows_s
    assert np.array_equal(res.modal_freq_hz, ref.modal_freq_hz) and res.modal_freq_hz.shape == (3, 2, 2)
    assert np.array_equal(res.covariance, plain.covariance)
    f1 = res.modal_freq_hz[:, 0, 0]
    assert np.all(np.diff(f1) > 0)  # the tip spring hardens NNM1 with P
