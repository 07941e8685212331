"""The Dask sweep returns, in order, exactly what in-process runs give."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.model.sweep import ModalProbe, SweepMoments, run_with_modal_phase, sweep_moments

#: five runs, two per chunk: three chunks over two worker processes, so chunks can finish out of order; the first three
#: forces are where the tip spring visibly hardens NNM1, the last two reach the stiff end of the sweep
AMPS = np.array([20.0, 150.0, 400.0, 1e5, 1e9])
DURATION_S = 0.4  # the modal probe's whole-record window needs a few NNM1 periods (3.8 Hz): 0.4 s is 1.5


@pytest.fixture(scope="module")
def dask_sweep(rigs):
    """One sweep on a local cluster of two worker processes (started and closed by sweep_moments), with the modal
    probe: both tests below read it (one cluster start-up, ~2 CPU-s of worker imports, instead of two)."""
    rig = rigs("beam_ch4_sim")
    sim = rig.simulator
    g = rig.guyan(sim.output_dofs)
    probe = ModalProbe.from_guyan(g.M, g.K, 2)
    seen = []
    res = sweep_moments(sim, rig.hammer_force(), AMPS, DURATION_S, rig.sample_rate, n_workers=2, chunk_size=2,
                        probe=probe, progress=lambda done, total: seen.append((done, total)))  # fmt: skip
    return rig, sim, probe, res, seen


def test_dask_sweep_equals_in_process_moments(dask_sweep):
    rig, sim, _probe, res, seen = dask_sweep
    ref = sim.run_moments(rig.hammer_force(), DURATION_S, rig.sample_rate, AMPS)
    assert np.array_equal(res.amplitudes, AMPS)
    # bit for bit: the same compiled kernel on the same inputs, one run at a time, whichever process runs it
    assert np.array_equal(res.covariance, ref.covariance)
    assert np.array_equal(res.input_work, ref.input_work)
    assert seen[-1] == (5, 5) and len(seen) == 3


def test_dask_sweep_with_a_modal_probe_equals_in_process_runs(dask_sweep):
    """The per-run modal frequencies come back through Dask in order, chunks concatenated, and the moments
    are unchanged by measuring them."""
    rig, sim, probe, res, _seen = dask_sweep
    ref = run_with_modal_phase(sim, rig.hammer_force(), DURATION_S, rig.sample_rate, AMPS, probe)
    assert isinstance(res, SweepMoments) and res.modal_windows_s == probe.windows_s
    assert np.array_equal(res.modal_freq_hz, ref.modal_freq_hz, equal_nan=True) and res.modal_freq_hz.shape == (5, 2, 2)
    assert np.array_equal(res.covariance, ref.covariance) and np.array_equal(res.substep_cap_hits, ref.substep_cap_hits)
    f1 = res.modal_freq_hz[:3, 0, 0]
    assert np.all(np.isfinite(f1)) and np.all(np.diff(f1) > 0)  # the tip spring hardens NNM1 with P
