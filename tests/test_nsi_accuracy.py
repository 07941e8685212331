"""How well computational NSI identifies α and β on the seed's rigs (issue 22), and why α misses 5 % (docs/nsi.md).

Oracles: the laws the simulator integrates (lo_store_ch6: a cubic 1.058e10 N/m³ between store and LO; beam_nes_ch5:
a cubic 3e9 N/m³ between NES and beam tip; β = 2 for both). 20 runs each (~4 s of simulation per rig on one core);
the 40–80-run tables are in bench/eval_nsi.py --table. beam_ch4_sim's test is tests/test_nsi.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest


def _runs(name: str, pmin: float, pmax: float, n: int = 20, duration: float = 1.0):
    from analysis.model.rig import build_rig
    from analysis.model.rigs import open_rig
    from analysis.nsi_target import resolve_target
    from daq.studies.identify.sweep import simulate_runs

    rig = open_rig("lo_store_ch6" if name == "lo_store_hit" else name)
    if name == "lo_store_hit":  # the store hit directly: the LO stays nearly still and the store's curve is clean
        rig = build_rig(rig.config.model_copy(update={"hammer": rig.config.hammer.model_copy(update={"dof": "store"})}))
    dofs = rig.structure.translational_dofs()
    g = rig.guyan(dofs)
    target = resolve_target(rig, dofs, g.M, g.K)
    return rig, target, simulate_runs(rig, np.logspace(math.log10(pmin), math.log10(pmax), n), duration, dofs, target, g.M, g.K)


def test_lo_store_beta_from_the_exact_backbone():
    """lo_store_ch6 hit on the store, P 0.1–20 N (store 26 → 34 Hz), POM frequency, two-parameter fit.

    The harmonic-balance law under-reads the backbone's Δω² at a given δ̄ by up to 2.8 % at the top of the curve,
    so its β is high (measured +0.8 … +1.0 % over 20–60 runs) and, through dα/α = −ln δ̄ · dβ (≈ 9 dβ at δ̄ ~ 1e-4 m),
    its α +14 … +18 %. The exact one-DOF backbone halves the β error (−0.35 … −0.5 %); what remains (the run's
    amplitude decay averaged into one δ̄, the LO's participation, [nsi] mass = I_s/h² against 1/φ_δ² = +1.1 %)
    still costs α −7 … −10 % — measured, not noise: the bootstrap interval is ±5 % and excludes the truth.
    Tolerances: β within 1 % (measured −0.35 %), α within 15 % (measured −7.2 %), HB's β error the larger."""
    from daq.studies.identify.sweep import IdentifyOptions, identify_runs

    rig, target, runs = _runs("lo_store_hit", 0.1, 20.0)
    exact = identify_runs(rig, target, runs, IdentifyOptions(frequency="pom", law="exact", intersection=False, n_boot=0), "t").fit
    hb = identify_runs(rig, target, runs, IdentifyOptions(frequency="pom", law="hb", intersection=False, n_boot=0), "t").fit
    assert exact.mode == "two-parameter" and exact.r2 > 0.9999
    assert exact.beta == pytest.approx(2.0, rel=0.01)
    assert exact.alpha == pytest.approx(1.058e10, rel=0.15)
    assert abs(hb.beta - 2.0) > abs(exact.beta - 2.0)
    assert hb.beta > 2.0 > exact.beta
    # the α–β coupling: the two laws' α differ by about δ̄_c^−Δβ at the curve's δ̄ (geometric centre of the fitted points)
    dc = math.exp(np.mean(np.log(runs.dbar)))
    assert hb.alpha / exact.alpha == pytest.approx(dc ** -(hb.beta - exact.beta), rel=0.1)


def test_nes_beta_within_10_percent_and_alpha_undetermined():
    """beam_nes_ch5, P 0.3–300 N, POM frequency, two-parameter fit (the intersection of eqs. 5.9–5.10 pins α at a
    δ̄₁ where the one-DOF law no longer holds — the NES mode veers with 1B — and reads α +390 … +1000 %).

    β is within 10 % (measured −5.7 % here, −4 … −8 % over 40–80 runs), but the data do not determine α: the bootstrap
    interval spans a factor > 3 and contains the truth. 1 s holds one cycle of the 1 Hz NES (docs/nsi.md)."""
    from daq.studies.identify.sweep import IdentifyOptions, identify_runs

    rig, target, runs = _runs("beam_nes_ch5", 0.3, 300.0)
    fit = identify_runs(rig, target, runs, IdentifyOptions(frequency="pom", law="exact", intersection=False, n_boot=50), "t").fit
    assert fit.beta == pytest.approx(2.0, rel=0.10)
    assert fit.alpha_ci[0] <= 3e9 <= fit.alpha_ci[1]
    assert fit.alpha_ci[1] / fit.alpha_ci[0] > 3.0
    inter = identify_runs(rig, target, runs, IdentifyOptions(frequency="pom", law="exact", n_boot=0), "t").fit
    assert inter.mode == "intersection" and abs(inter.alpha / 3e9 - 1) > abs(fit.alpha / 3e9 - 1)
