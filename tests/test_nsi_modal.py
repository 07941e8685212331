"""The multi-mode backbone law (``--law modal``, analysis.nsi.ModalLaw): oracles on one- and two-DOF rigs.

On one DOF the law must be the one-mass harmonic-balance law (closed form eq. 5.8 with κ_hb) and, with the
exact/HB correction, the exact one-mass backbone (``exact_law_hz``); on lo_store_ch6's two-DOF linear model the
attachment mode's frequency at a given k_eq must be the eigenfrequency of the 2x2 problem with the spring added,
computed independently with scipy.linalg.eigh in physical coordinates.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import nsi
from analysis.errors import BadInput


def test_one_dof_modal_law_is_the_hb_closed_form():
    """m = 0.25 kg, ω_n² = 40 (the seed's Ch. 5 NES): one mass-normalised mode with b = 1/√m. The modal law is the
    eq. 5.8 κ_hb closed form to rounding (g(k) = b² exactly on one DOF, so the table's interpolation is exact)."""
    basis = nsi.ModalBasis(np.array([40.0]), np.array([2.0]), 0)
    law = nsi.ModalLaw(basis)
    d = np.logspace(-6, -2, 25)
    for beta in (1.5, 2.0, 2.5):
        want = nsi.law_hz(d, math.sqrt(40), 0.25, 3e9, beta, "hb")
        np.testing.assert_allclose(law.hz(d, 3e9, beta), want, rtol=1e-12)
    assert law.mass == pytest.approx(0.25) and law.omega_n == pytest.approx(math.sqrt(40))


def test_one_dof_modal_exact_is_the_exact_backbone():
    """With the exact/HB ratio the one-DOF modal law is the exact backbone; both sides interpolate tables of
    :func:`backbone_ratios` (300 points over 11–12 decades), hence 5e-4 rather than rounding (measured 1.2e-4)."""
    law = nsi.ModalLaw(nsi.ModalBasis(np.array([40.0]), np.array([2.0]), 0), exact=True)
    d = np.logspace(-6, -3, 13)  # up to f ≈ 8 f_n, inside both tables
    np.testing.assert_allclose(law.hz(d, 3e9, 2.0), nsi.exact_law_hz(d, math.sqrt(40), 0.25, 3e9, 2.0), rtol=5e-4)


def _lo_store():
    from analysis.model.rigs import open_rig
    from analysis.nsi_target import resolve_target

    rig = open_rig("lo_store_ch6")
    dofs = rig.structure.translational_dofs()
    g = rig.guyan(dofs)
    return g.M, g.K, resolve_target(rig, dofs, g.M, g.K)


def test_two_dof_modal_law_is_the_2x2_eigenproblem():
    """lo_store_ch6's linear model (store 26 Hz, LO 42.7 Hz): add k_eq across store − LO, solve (K + k_eq s sᵀ) φ =
    ω² M φ with scipy.linalg.eigh and take the eigenvector with the highest MAC to the linear store mode. The law's
    ω² comes from a table interpolated in log k_eq (200 points a decade): 1e-5 on the frequency, measured
    3.7e-7; the k_eq span covers the weakly nonlinear part, the veering near the LO and far beyond it."""
    import scipy.linalg

    M, K, t = _lo_store()
    assert M.shape == (2, 2)
    basis = t.model.modal_basis()
    law = nsi.ModalLaw(basis)
    s = np.zeros(2)
    s[t.attachment] += 1.0
    for r in t.relative_to:
        s[r] -= 1.0 / len(t.relative_to)
    _, v0 = scipy.linalg.eigh(K, M)
    ref = v0[:, t.model.mode]
    k_lin = 1.0 / float(s @ scipy.linalg.solve(K, s))  # scale of the spring across the stretch
    for k in k_lin * np.logspace(-4, 3, 15):
        w, v = scipy.linalg.eigh(K + k * np.outer(s, s), M)
        mac = (ref @ v) ** 2 / (np.sum(v**2, axis=0) * (ref @ ref))
        want = math.sqrt(w[int(np.argmax(mac))]) / (2 * math.pi)
        got = math.sqrt(float(law.omega2_at(k))) / (2 * math.pi)
        assert got == pytest.approx(want, rel=1e-5), k


def test_modal_law_needs_a_basis():
    with pytest.raises(BadInput, match="modal basis"):
        nsi.fit_power_law(np.logspace(-5, -3, 8), np.linspace(1, 2, 8), 6.0, 0.25, (), nsi.FitSettings(kappa="modal"))
    with pytest.raises(BadInput, match="does not stretch"):
        nsi.ModalLaw(nsi.ModalBasis(np.array([1.0, 4.0]), np.array([0.0, 1.0]), 0))


def test_lo_store_modal_exact_predicts_the_simulated_curve():
    """lo_store_ch6 hit on the store, 20 runs P 0.1–20 N (store 26 → 34 Hz), whole-run δ̄, POM frequency: the law the
    modal basis improves measurably. With the true spring (α 1.058e10, β 2) the one-mass exact backbone reads the
    top of the curve up to 0.38 % high (it has no LO: the LO's participation lowers the store's mode as its spring
    stiffens); the two-mode law with the exact/HB correction is within 0.15 % at every run (measured 0.10 %) and
    its worst error is under half the one-mass law's. The fit from those points: β within 0.6 % and α within 10 %
    (measured here +0.31 % / +5.5 %; on 40 runs +0.32 % / +5.6 %, bootstrap 95 % [+0.1, +8.9] %; the one-mass exact
    law: −0.35 % / −7.2 % here; what remains is not explained by the laws: docs/nsi.md "A multi-mode backbone")."""
    import math as _m

    from analysis.model.rig import build_rig
    from analysis.model.rigs import open_rig
    from analysis.nsi_target import resolve_target
    from daq.studies.identify.sweep import IdentifyOptions, identify_runs, simulate_runs

    lo = open_rig("lo_store_ch6")
    rig = build_rig(lo.config.model_copy(update={"hammer": lo.config.hammer.model_copy(update={"dof": "store"})}))
    dofs = rig.structure.translational_dofs()
    g = rig.guyan(dofs)
    t = resolve_target(rig, dofs, g.M, g.K)
    runs = simulate_runs(rig, np.logspace(_m.log10(0.1), _m.log10(20.0), 20), 1.0, dofs, t, g.M, g.K)
    m = t.model
    modal = nsi.ModalLaw(m.modal_basis(), exact=True).hz(runs.dbar, 1.058e10, 2.0)
    one = nsi.exact_law_hz(runs.dbar, m.omega_n, m.mass, 1.058e10, 2.0)
    e_modal = np.abs(modal / runs.f_pom - 1)
    e_one = np.abs(one / runs.f_pom - 1)
    assert e_modal.max() < 1.5e-3, e_modal.max()
    assert e_modal.max() < 0.5 * e_one.max(), (e_modal.max(), e_one.max())
    fit = identify_runs(rig, t, runs, IdentifyOptions(frequency="pom", law="modal-exact", n_boot=0), "test").fit
    assert fit.mode == "two-parameter" and fit.extra["modal_modes"] == 2
    assert abs(fit.beta / 2 - 1) < 6e-3, fit.beta
    assert abs(fit.alpha / 1.058e10 - 1) < 0.10, fit.alpha
