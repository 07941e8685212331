"""Modal identification (issue 20 item 4): pLSCF + stabilisation + auto/manual pick + LSFD, MAC, MPC, MPD.

Test data: FRFs synthesised from a rig's own FE modes and modal damping (``Rig.modes``, the rig's
``[damping]``), every mode below 5 kHz summed (so the band 0-1 kHz has out-of-band modes the residuals must
absorb), times ``-w^2`` for accelerance, with 1 % complex Gaussian noise proportional to |H| at each line
(seeded). Oracles: the rig model (frequency, damping, shapes at the sensor DOFs, mass normalisation), the
residues of the partial-fraction expansion, and sdypy-EMA run on the same FRFs.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.errors import BadInput
from analysis.lsfd import lsfd, modal_frf
from analysis.mac import auto_mac, mac, mpc, mpd
from analysis.modal_id import (
    Criteria,
    Target,
    auto_select,
    fe_modes_at_sensors,
    identify_arrays,
    load_targets,
    pair_with_fe,
    select_targets,
    stabilisation,
)
from analysis.plscf import plscf

NOISE = 0.01


def synth(rig, refs: list[int], freq: np.ndarray, noise: float, seed: int) -> np.ndarray:
    """Accelerance (n_sensors, n_refs, n_f) of the rig's linear model + proportional complex noise."""
    modes = rig.modes
    keep = modes.frequencies_hz < 5000.0
    zeta = rig.structure.damping.ratios(len(modes))[keep]
    phi = modes.shapes[:, keep]
    H = modal_frf(freq, modes.omega[keep], zeta, phi[rig.sensor_dofs], phi[refs], "accelerance")
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)
    return H * (1.0 + noise / np.sqrt(2.0) * e)


@pytest.fixture(scope="module")
def beam(rigs):
    rig = rigs("beam_ch4_exp")
    freq = np.arange(0.0, 1000.0 + 1e-9, 0.5)  # 2 s records: 0.5 Hz lines, as the rig's DAQ
    drive = rig.sensor_dofs.index(rig.hammer.dof)  # a13 sits at the hammer point (0.7 m)
    H = synth(rig, [rig.hammer.dof], freq, NOISE, seed=20)
    res = identify_arrays(freq, H, "accelerance", 2.0, 1000.0, max_order=60, driving=[drive])
    return rig, freq, H, res


def check_against_model(res, rig, n: int):
    f_fe, z_fe, phi_fe = fe_modes_at_sensors(rig, n)
    assert res.freq_hz.size == n, f"selected {np.round(res.freq_hz, 2)}"
    np.testing.assert_array_less(np.abs(res.freq_hz / f_fe - 1.0), 0.001)  # 0.1 %
    np.testing.assert_array_less(np.abs(res.zeta / z_fe - 1.0), 0.05)  # 5 %
    j, m = pair_with_fe(res.shapes, phi_fe)
    assert list(j) == list(range(n))
    assert np.all(m >= 0.99), m
    return phi_fe


def test_beam_single_reference_matches_the_model(beam):
    rig, _freq, _H, res = beam
    phi_fe = check_against_model(res, rig, 6)
    # mass normalisation from the driving point: phi = A_oi / sqrt(A_ii) reproduces the FE scaling (same sign
    # convention up to +-1 per mode); 1 % noise on a handful of lines per peak -> a few per mille expected
    scale = np.real(np.sum(res.shapes * phi_fe, axis=0)) / np.sum(phi_fe**2, axis=0)
    np.testing.assert_allclose(np.abs(scale), 1.0, atol=0.02)
    assert np.all(res.mpc > 0.99) and np.all(res.mpd < 3.0)  # real modes (proportional damping)
    am = auto_mac(res.shapes)
    assert np.max(am - np.eye(6)) < 0.1  # 14 sensors tell the six modes apart


def test_lsfd_fit_leaves_only_the_noise(beam):
    """The fitted FRFs differ from the data by the 1 % proportional noise, no more: the residuals carry the
    modes above 1 kHz. The noise is 1 % rms of |H| at every line, so ||H - fit|| / ||H|| per FRF should be
    ~0.010 (the 14 fitted parameters remove a negligible share of 2 x 1997 noise samples); allow 0.8..1.3 %.
    (Relative error line by line is not the measure: the unweighted fit spends nothing on the few lines
    near 2 Hz where the accelerance is 1e-4 of its peaks.)"""
    _, _freq, H, res = beam
    k = res.fit.band
    err = np.linalg.norm(H[:, :, k] - res.fit.H_fit[:, :, k], axis=-1) / np.linalg.norm(H[:, :, k], axis=-1)
    assert np.all((0.008 < err) & (err < 0.013)), err


def test_lsfd_recovers_exact_residues_without_noise(rigs):
    """All modes in band, exact poles: LSFD must return the partial-fraction residues phi_o phi_i / (2j w_d)."""
    rig = rigs("panels_close_modes")
    modes = rig.modes
    zeta = rig.structure.damping.ratios(len(modes))
    freq = np.arange(0.0, 600.0, 0.25)
    phi = modes.shapes[rig.sensor_dofs]
    H = modal_frf(freq, modes.omega, zeta, phi, modes.shapes[[2, 3]], "mobility")
    s = -zeta * modes.omega + 1j * modes.omega * np.sqrt(1 - zeta**2)
    fit = lsfd(freq, H, s, "mobility", 1.0, 599.0)
    expect = np.einsum("or,ir->oir", phi, modes.shapes[[2, 3]]) / (2j * s.imag)
    np.testing.assert_allclose(fit.residues, expect, rtol=1e-7, atol=1e-9 * np.abs(expect).max())
    assert np.abs(fit.upper).max() < 1e-9 * np.abs(H).max()


def test_close_modes_polyreference(rigs):
    """Two modes 1.16 % apart whose half-power bands overlap; hammer at two points (a3 and b1)."""
    rig = rigs("panels_close_modes")
    f_fe = rig.modes.frequencies_hz
    assert f_fe[1] / f_fe[0] - 1.0 < 0.02
    freq = np.arange(0.0, 500.0 + 1e-9, 0.25)
    refs = [rig.structure.dof_index("a3"), rig.structure.dof_index("b1")]
    H = synth(rig, refs, freq, NOISE, seed=7)
    res = identify_arrays(freq, H, "accelerance", 20.0, 500.0, max_order=60, driving=[2, 3])
    check_against_model(res, rig, 4)
    # the pair's participation vectors differ: both references are needed to separate them
    L = res.table.L[:, res.selected[:2]]
    assert mac(L[:, 0], L[:, 1])[0, 0] < 0.9


def test_stabilisation_labels_and_manual_pick(beam, tmp_path):
    _rig, freq, H, res = beam
    table = res.table
    assert set(np.unique(table.status)) <= {0, 1, 2, 3, 4}
    # a physical mode is stable at (nearly) every order once it appears; noise poles are not
    near = np.abs(table.freq_hz / res.freq_hz[2] - 1) < 0.001
    assert np.sum(near & (table.status == 4)) >= 40
    stricter = stabilisation(plscf(freq, H, 2.0, 1000.0, 30), Criteria(freq=1e-6, damping=1e-6, vector=1e-6))
    assert auto_select(stricter).size == 0  # nothing is stable at 1 ppm: the criteria are applied
    poles = tmp_path / "poles.toml"
    poles.write_text("[[poles]]\nfreq_hz = 68.4\ntol = 0.01\n\n[[poles]]\nfreq_hz = 387.0\n")
    sel = select_targets(table, load_targets(poles))
    np.testing.assert_allclose(table.freq_hz[sel], res.freq_hz[[1, 3]], rtol=2e-4)
    assert np.all(table.status[sel] == 4)
    bad = tmp_path / "bad.toml"
    bad.write_text("[[poles]]\nfrequency = 3\n")
    with pytest.raises(BadInput, match="freq_hz"):
        load_targets(bad)
    with pytest.raises(BadInput, match="no pole within"):
        select_targets(table, [Target(1234.0)])  # above the band: no pole there


def test_sdypy_ema_agrees(beam):
    """sdypy-EMA's single-reference LSCF on the same FRFs (14 x 1): poles within 0.1 % of ours.

    sdypy's ``select_closest_poles`` searches windows of +-f_window/2 around each guess in a matrix where
    unstable entries are 0 Hz; with the default f_window = 50 the 20.8 Hz search window reaches below 0 Hz
    and the zeros drag its estimate to 0 (it returns 0 Hz). f_window = 10 keeps the window above 0 Hz."""
    EMA = pytest.importorskip("sdypy.EMA")
    _, freq, H, res = beam
    model = EMA.Model(frf=H[:, 0], freq=freq, lower=2, upper=1000, pol_order_high=30, frf_form="accelerance")
    model.get_poles("lscf", show_progress=False)
    model.select_closest_poles(res.freq_hz, f_window=10)
    np.testing.assert_array_less(np.abs(model.nat_freq / res.freq_hz - 1.0), 0.001)
    np.testing.assert_array_less(np.abs(model.nat_xi / res.zeta - 1.0), 0.05)


def test_stabilisation_png(beam, tmp_path):
    from analysis.modal_plot import stabilisation_png

    _, freq, H, res = beam
    out = stabilisation_png(res.table, tmp_path / "stab.png", freq, H, res.selected)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_mac_mpc_mpd_against_theory():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((8, 3))
    np.testing.assert_allclose(np.diag(mac(a, a * np.exp(0.7j) * 3.0)), 1.0, rtol=1e-12)
    e = np.eye(4)
    np.testing.assert_allclose(mac(e, e), e, atol=1e-15)
    np.testing.assert_allclose(mpc(a * np.exp(1.1j)), 1.0, rtol=1e-12)
    np.testing.assert_allclose(mpd(a * np.exp(1.1j)), 0.0, atol=1e-6)
    # two equal-amplitude components 20 deg apart: the best line bisects them, each deviates 10 deg
    two = np.array([1.0, np.exp(1j * np.radians(20.0))])
    np.testing.assert_allclose(mpd(two), 10.0, rtol=1e-9)
    # components 90 deg apart with equal amplitude: no preferred line, MPC = 0
    np.testing.assert_allclose(mpc(np.array([1.0, 1j])), 0.0, atol=1e-12)


def test_one_triangular_solve_gives_every_orders_normal_matrix(beam):
    """normal_matrices' shortcut (leading rows of one solve, rank updates) against the textbook formula
    M_p = T_p - sum_o S_o,p^T R_p^-1 S_o,p with R_p inverted on its own, at three orders."""
    from analysis.plscf import normal_matrices, output_weights, reduced_blocks

    _, freq, H, _ = beam
    idx = (freq >= 2) & (freq <= 1000)
    Hb = H[:, :, idx] * output_weights(H[:, :, idx])[:, None, None]
    m, P = Hb.shape[1], 12
    R, S, T = reduced_blocks(freq[idx], Hb, P, float(freq[idx][-1]))
    got = dict(normal_matrices(np.linalg.cholesky(R), S, T, m, P))
    for p in (1, 5, P):
        nb, q = p + 1, (p + 1) * m
        Rinv = np.linalg.inv(R[:nb, :nb])
        want = T[:q, :q] - sum(S[o, :nb, :q].T @ Rinv @ S[o, :nb, :q] for o in range(S.shape[0]))
        np.testing.assert_allclose(got[p], want, rtol=1e-8, atol=1e-8 * np.abs(want).max())
