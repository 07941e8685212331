"""FE beam, boundary conditions, attachments, modal analysis, Guyan reduction and the RQ."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.model.beam import BeamMesh, assemble_beam, element_mass, element_stiffness
from analysis.model.guyan import guyan_reduce
from analysis.model.modal import modal_analysis, modal_damping_matrix, structure_modes
from analysis.model.structure import ModalDamping, build_beam, build_lumped
from analysis.rayleigh import rayleigh_quotient_hz

# Seed Table 3.1 (L1223-L1236).
TABLE_3_1 = [3.794, 23.78, 66.60, 130.6, 216.2, 323.9, 454.5, 608.9, 787.3, 978.7]
# Seed Table 4.2, FE column (L1348-L1357).
TABLE_4_2_FE = [20.90, 68.7, 194.1, 387.0, 645.7, 967.0]


def test_element_matrices_are_symmetric_with_two_rigid_modes():
    ke = element_stiffness(2.0, 0.3)
    me = element_mass(5.0, 0.3)
    assert np.allclose(ke, ke.T) and np.allclose(me, me.T)
    lam = np.linalg.eigvalsh(ke)
    assert np.sum(np.abs(lam) < 1e-9 * lam.max()) == 2  # translation + rotation of a free element
    assert np.all(np.linalg.eigvalsh(me) > 0)
    # consistent mass carries the element's whole mass in translation
    ones = np.array([1.0, 0.0, 1.0, 0.0])
    assert ones @ me @ ones == pytest.approx(5.0 * 0.3)


# Analytic Euler-Bernoulli roots (beta_n L), an oracle independent of the seed.
CANTILEVER = [1.875104069, 4.694091133, 7.854757438, 10.99554073]
FREE_FREE = [4.730040745, 7.853204624, 10.99560784]


@pytest.mark.parametrize(
    ("left", "right", "roots", "n_rigid"),
    [
        ("clamped", "free", CANTILEVER, 0),
        ("pinned", "pinned", [np.pi, 2 * np.pi, 3 * np.pi, 4 * np.pi], 0),
        ("free", "free", FREE_FREE, 2),
        ("clamped", "clamped", FREE_FREE, 0),
    ],
)
def test_boundary_conditions_match_analytic_beam_theory(left, right, roots, n_rigid):
    L, b, h, E, rho = 1.0, 0.05, 0.01, 200e9, 7800.0
    s = build_beam(length=L, width=b, height=h, E=E, rho=rho, n_elements=60, left=left, right=right)
    f = structure_modes(s).frequencies_hz
    assert np.all(f[:n_rigid] < 1e-3)
    EI, rhoA = E * b * h**3 / 12, rho * b * h
    exact = np.array(roots) ** 2 / (2 * np.pi * L**2) * np.sqrt(EI / rhoA)
    got = f[n_rigid : n_rigid + len(roots)]
    assert np.allclose(got, exact, rtol=2e-5)  # 60 Hermite elements converge to ~1e-6 for these modes


def test_beam_ch3_matches_table_3_1(rigs):
    f = rigs("beam_ch3").modes.frequencies_hz[:10]
    assert np.all(np.abs(f / TABLE_3_1 - 1) < 1e-3)


def test_beam_ch4_exp_matches_table_4_2_fe_column(rigs):
    f = rigs("beam_ch4_exp").modes.frequencies_hz[:6]
    assert np.all(np.abs(f / TABLE_4_2_FE - 1) < 1e-2)


def test_beam_ch4_sim_low_and_high_energy_limits(rigs):
    rig = rigs("beam_ch4_sim")
    low = structure_modes(rig.limit_structure("low")).frequencies_hz[:4]
    high = structure_modes(rig.limit_structure("high")).frequencies_hz[:4]
    assert np.all(np.abs(low / [3.807, 23.86, 66.81, 130.9] - 1) < 2e-3)
    assert np.all(np.abs(high / [16.70, 54.11, 112.89, 193.05] - 1) < 5e-3)


def test_point_mass_and_spring_shift_frequencies_as_physics_says():
    kw = dict(length=0.749, width=0.045, height=0.008, E=190e9, rho=7800.0, n_elements=107)
    bare = structure_modes(build_beam(**kw)).frequencies_hz[0]
    heavy = structure_modes(build_beam(**kw, point_masses=[(0.7, 0.171)])).frequencies_hz[0]
    stiff = structure_modes(build_beam(**kw, springs=[(0.7, 10854.0)])).frequencies_hz[0]
    assert heavy < bare < stiff
    # A lumped 1-DOF oscillator: f = sqrt(k/m) / 2 pi exactly.
    one = build_lumped(masses=[2.0], springs=[(0, None, 8.0)])
    assert structure_modes(one).omega[0] == pytest.approx(2.0, rel=1e-12)


def test_two_dof_linear_frequencies(rigs):
    # eq. 2.1 linearised: K = [[2, -1], [-1, 3]], M = I -> omega^2 = (5 -+ sqrt 5) / 2
    om = rigs("two_dof").modes.omega
    assert om == pytest.approx(np.sqrt([(5 - np.sqrt(5)) / 2, (5 + np.sqrt(5)) / 2]), rel=1e-12)


def test_snap_to_node_and_half_element_rule():
    mesh = BeamMesh(length=1.0, n_elements=10)
    assert mesh.snap(0.52) == (5, pytest.approx(0.02))
    assert mesh.snap(1.04)[0] == 10  # within half an element past the tip
    with pytest.raises(ValueError, match="off the beam"):
        mesh.snap(1.06)
    with pytest.raises(ValueError, match="off the beam"):
        mesh.snap(-0.051)


def test_modal_damping_matrix_is_diagonal_in_modes_with_factor_two():
    s = build_beam(length=1.0, width=0.05, height=0.01, E=200e9, rho=7800.0, n_elements=12)
    modes = structure_modes(s)
    zeta = (0.01, 0.02, 0.03)
    for factor2, k in ((True, 2.0), (False, 1.0)):
        D = modal_damping_matrix(s.M, modes, ModalDamping(zeta=zeta, zeta_rest=0.001, factor2=factor2))
        modal = modes.shapes.T @ D @ modes.shapes
        expect = k * np.array([*zeta, *[0.001] * (len(modes) - 3)]) * modes.omega
        assert np.allclose(np.diag(modal), expect, rtol=1e-8)
        off = modal - np.diag(np.diag(modal))
        assert np.max(np.abs(off)) < 1e-8 * np.max(np.abs(modal))


def test_guyan_to_translational_dofs_keeps_first_ten_modes(rigs):
    rig = rigs("beam_ch4_sim")
    st = rig.limit_structure("low")
    g = guyan_reduce(st.M, st.K, st.translational_dofs())
    assert g.M.shape == (100, 100)
    full = structure_modes(st).frequencies_hz[:10]
    red = modal_analysis(g.M, g.K).frequencies_hz[:10]
    assert np.all(np.abs(red / full - 1) < 1e-3)


def test_rayleigh_quotient_of_exact_mode_returns_its_frequency(rigs):
    rig = rigs("beam_ch4_sim")
    st = rig.limit_structure("low")
    masters = st.translational_dofs()
    g = guyan_reduce(st.M, st.K, masters)
    modes = structure_modes(st)
    trial = modes.shapes[masters, :6]  # translational part of the exact modes
    f_rq = rayleigh_quotient_hz(trial, g.K, g.M)
    assert np.all(np.abs(f_rq / modes.frequencies_hz[:6] - 1) < 1e-3)
    # a single vector, and scale invariance
    assert rayleigh_quotient_hz(3.0 * trial[:, 1], g.K, g.M) == pytest.approx(f_rq[1], rel=1e-9)


def test_guyan_is_exact_statically():
    # Static condensation must reproduce the full static deflection at the masters.
    s = build_beam(length=1.0, width=0.05, height=0.01, E=200e9, rho=7800.0, n_elements=8)
    masters = s.translational_dofs()
    g = guyan_reduce(s.M, s.K, masters)
    F = np.zeros(s.n_dof)
    F[masters[-1]] = 10.0
    x_full = np.linalg.solve(s.K, F)
    x_red = np.linalg.solve(g.K, F[masters])
    assert np.allclose(x_red, x_full[masters], rtol=1e-10)


def test_assembly_total_mass():
    mesh = BeamMesh(length=2.0, n_elements=7)
    M, _ = assemble_beam(200e9, 7800.0, 0.1, 0.02, mesh)
    ones = np.zeros(M.shape[0])
    ones[::2] = 1.0
    assert ones @ M @ ones == pytest.approx(7800.0 * 0.1 * 0.02 * 2.0, rel=1e-12)


def test_high_energy_limit_removes_the_spring_dof(rigs):
    rig = rigs("beam_ch4_exp")
    high = rig.limit_structure("high")
    assert high.n_dof == rig.structure.n_dof - 1
    assert high.nonlinear == ()
    assert "w100" not in [d.name for d in high.dofs]


def test_guyan_by_name_with_damping(rigs):
    from analysis.model.guyan import guyan_reduce_named

    rig = rigs("beam_ch4_exp")
    names = [s.dof_name for s in rig.sensors]
    g = guyan_reduce_named(rig.structure, names, with_damping=True)
    assert g.M.shape == (14, 14) and g.D is not None
    f = modal_analysis(g.M, g.K).frequencies_hz[:2]
    assert np.allclose(f, rig.modes.frequencies_hz[:2], rtol=1e-3)
    with pytest.raises(KeyError):
        guyan_reduce_named(rig.structure, ["w999"])
