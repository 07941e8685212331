"""Issue 21, item 7: the realistic grid's error classes do what they say (analysis/evaluation/errors.py, sessions.py).

Oracles: exact arithmetic for gains and dead channels; the grid's own noise draws; a finer FE mesh
with nodes at the moved sensor positions for the shape-function interpolation; exact stiffness
scaling (K -> (1 + e) K moves every frequency by sqrt(1 + e)) and first-order mass perturbation
(df/f = -dm phi(x)^2 / 2) for the model errors; the modal-damping identity for the second
structure's linear twin; isolated single-hit simulations for a session's per-hit truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from analysis.evaluation.detectors import _model, modal_exchange_acc, rig_model
from analysis.evaluation.errors import (
    DEAD_NOISE_REL,
    Measured,
    ModelError,
    kill_channels,
    model_error_rig,
    noise_std,
    position_offsets,
    sensitivity_gains,
    simulate_offset_cases,
    with_gain_errors,
    with_gains,
    with_noise,
)
from analysis.evaluation.grid import GridCase, case_rig, rig_data, rig_toml, simulate_case, simulate_cases
from analysis.evaluation.sessions import SessionCase, hit_of, per_hit, segment, session_grid, simulate_sessions
from analysis.model.config import RigConfig
from analysis.model.loader import validate
from analysis.model.rig import build_rig

SECOND = "beam_al_mid"


@dataclass(frozen=True)
class _Ev:
    start_s: float
    end_s: float


@pytest.fixture(scope="module")
def short_case():
    """A nonlinear beam_ch4_exp hit, 0.5 s (enough for the channel arithmetic), 1 % grid noise."""
    return simulate_case(GridCase(1300.0, 0.005, True, 9), duration=0.5, cache_dir=None)


def test_noise_at_one_percent_is_the_grids_noise_and_its_level_is_as_stated(short_case):
    d = short_case
    assert np.array_equal(with_noise(d, 0.01, ref_s=None).acc, d.acc)  # the grid's rule, the grid's draws
    n = with_noise(d, 0.03)
    ref = np.sqrt(np.mean(d.acc_clean.astype(float) ** 2, axis=0))  # a 0.5 s record: the 2 s reference is all of it
    err = np.std(n.acc.astype(float) - d.acc_clean, axis=0)
    # 8192 samples per channel: the sample std is within 1/sqrt(2 N) = 0.8 % of the true one; 4 sigma.
    np.testing.assert_allclose(err, 0.03 * ref, rtol=0.032)
    # Only the first ref_s seconds set the level: a longer record keeps the 2 s noise.
    np.testing.assert_allclose(
        noise_std(d.acc_clean, 0.02, d.fs, 0.25),
        0.02 * np.sqrt(np.mean(d.acc_clean[: round(0.25 * d.fs)].astype(float) ** 2, axis=0)),
    )


def test_a_gain_error_scales_the_channel_by_the_stated_factor(short_case):
    d = short_case
    g = np.linspace(0.95, 1.05, 14)
    m = with_gains(d, g)
    np.testing.assert_allclose(m.acc.astype(float), d.acc.astype(float) * g, rtol=1e-6)  # float32 rounding only
    drawn = with_gain_errors(d, 3.0)
    ratio = np.median(drawn.acc.astype(float) / np.where(d.acc == 0, np.nan, d.acc), axis=0)
    np.testing.assert_allclose(ratio, sensitivity_gains(14, 3.0, np.random.default_rng([d.case.seed, 1])), rtol=1e-6)
    assert np.all(np.abs(ratio - 1) <= 0.03) and np.ptp(ratio) > 0.02  # uniform in ±3 %: spread over most of it


def test_a_dead_channel_is_dead_and_the_others_are_untouched(short_case):
    d = short_case
    m = kill_channels(d, ["a13"])
    k = d.sensor_names.index("a13")
    assert np.std(m.acc[:, k]) <= 1.1 * DEAD_NOISE_REL * d.noise_std[k]
    assert abs(np.mean(m.acc[:, k])) <= 5 * DEAD_NOISE_REL * d.noise_std[k] / np.sqrt(d.t.size)
    assert np.std(m.acc[:, k]) < 1e-4 * np.std(d.acc_clean[:, k])
    others = [i for i in range(14) if i != k]
    assert np.array_equal(m.acc[:, others], d.acc[:, others])
    full = Measured(0.03, 3.0, ("a07",))(d)  # the chain composes: noise, gains, then the dead channel
    assert np.std(full.acc[:, d.sensor_names.index("a07")]) < 1e-4 * np.std(d.acc_clean[:, 6])
    with pytest.raises(ValueError, match="no channel"):
        kill_channels(d, ["a99"])


def test_position_offsets_move_the_response_as_the_shape_functions_say():
    """Interpolating the 7 mm mesh's w/theta with Hermite shape functions at x + 3.5 mm gives what a 3.5 mm mesh
    with a node there gives (to FE discretisation, < 1e-3), while the nominal position's response is 1-10 % off."""
    c = GridCase(1000.0, 0.005, False, 0)
    dx = np.full(14, 0.0035)
    dx[-1] = -0.0035  # the free-end sensor moves inward
    moved = simulate_offset_cases([c], dx, duration=0.25, cache_dir=None)
    nominal = simulate_offset_cases([c], np.zeros(14), duration=0.25, cache_dir=None)
    data = rig_data(c.zeta, c.cubic)
    data["structure"] = {**data["structure"], "elements": 214}
    data["sensors"] = [{**s, "x": s["x"] + d} for s, d in zip(data["sensors"], dx, strict=True)]
    fine = build_rig(validate(RigConfig, data, rig_toml()), "fine")
    assert np.allclose([s.x_model for s in fine.sensors], [s.x_model for s in case_rig(c).sensors] + dx, atol=1e-12)
    res = fine.simulator.run(fine.hammer_force(c.force_n), 0.25, fine.sample_rate)
    for got, nom, ref in ((moved[0].disp_true, nominal[0].disp_true, res.displacement[0]),
                          (moved[0].acc_clean, nominal[0].acc_clean, res.acceleration[0])):  # fmt: skip
        scale = np.sqrt(np.mean(ref**2, axis=0))
        e_moved = np.sqrt(np.mean((got - ref) ** 2, axis=0)) / scale
        e_nominal = np.sqrt(np.mean((nom - ref) ** 2, axis=0)) / scale
        assert e_moved.max() < 1e-3, e_moved
        assert e_nominal.min() > 5e-3 and np.all(e_moved < 0.05 * e_nominal)
    assert np.array_equal(nominal[0].acc_clean, simulate_case(c, duration=0.25, cache_dir=None).acc_clean)
    off = position_offsets(case_rig(c), 5.0)
    assert np.all(np.abs(off) <= 5e-3) and off[-1] <= 0  # on the beam


def test_model_error_rig_moves_the_detectors_frequencies_by_the_expected_amount():
    c = GridCase(1300.0, 0.005, True, 9)
    truth = rig_model(case_rig(c))[2].omega
    # K -> (1 + e) K (beam E and the attachment spring together), M unchanged: every Guyan frequency x sqrt(1 + e).
    e = 0.04
    scaled = rig_model(model_error_rig(c, ModelError(E=e, k=e)))[2].omega
    np.testing.assert_allclose(scaled / truth, np.sqrt(1 + e), rtol=1e-9)
    # Attachment mass +5 %: first-order perturbation df/f = -dm phi(x_att)^2 / 2 with mass-normalised FE modes.
    rig = case_rig(c)
    dm = 0.05 * rig.config.point_masses[0].mass
    node = rig.structure.dof_index("w100")  # 0.700 m on the 7 mm mesh
    phi = rig.modes.shapes[node, :4]
    heavier = rig_model(model_error_rig(c, ModelError(m=0.05)))[2].omega
    predicted = -0.5 * dm * phi**2
    np.testing.assert_allclose(heavier / truth - 1, predicted, rtol=0.05, atol=2e-5)
    assert predicted[0] < -1e-3  # the check is not vacuous: mode 1 moves by more than 0.1 %
    # No model_rig: the detector's model is the case's own rig, as before.
    d = simulate_case(c, duration=0.5, cache_dir=None)
    assert _model(d)[2] is rig_model(case_rig(c))[2]
    assert [e.start_s for e in modal_exchange_acc(d)] == [e.start_s for e in modal_exchange_acc(d, model_rig=case_rig(c))]


def test_second_structure_has_major_exchanges_and_its_linear_twin_none():
    nl, lin = simulate_cases(
        [GridCase(1000.0, 0.002, True, 0, SECOND), GridCase(1000.0, 0.002, False, 0, SECOND)], 1.0, cache_dir=None
    )
    rig = case_rig(lin.case)
    f = rig.modes.frequencies_hz[:2]
    np.testing.assert_allclose(f, [18.84, 64.24], atol=0.01)  # as the TOML's header says
    assert rig.config.name == SECOND and nl.sensor_names[5] == "s06" and abs(nl.sensor_x[5] - 0.3) < 1e-12
    assert len(nl.exchanges) >= 2 and max(e.gain for e in nl.exchanges) > 5
    assert {e.label for e in nl.exchanges} <= {"5:2", "3:1", "7:2", "4:1"}
    assert lin.exchanges == ()
    # Modal damping: after the pulse a linear modal energy never rises (dE/dt = -2 zeta w v^2 <= 0), to rounding.
    e2 = lin.modal_energy[lin.t > lin.pulse_end_s, 1]
    assert np.max(np.diff(e2)) <= 1e-9 * e2.max()


def test_session_truth_attributes_each_exchange_to_the_hit_before_it():
    """Two hits 3 s apart at zeta 0.015: the first hit's tail is e^-11.8 of its energy (2.7e-3 of its amplitude) when
    the second lands, so each hit's exchanges are those of the same hit simulated alone, moved to its time.

    Intervals and gains are compared, not labels: the truth's label counts zero crossings of q2 over the interval,
    which starts at E2's minimum, where the 0.3 % the first hit leaves behind can add crossings (measured: one
    exchange of the second hit reads f2 = 92.7 Hz, 4:1, against 67.7 Hz, 3:1, alone).
    """
    s = SessionCase((700.0, 1600.0), (0.5, 3.5), 5.5, 0.015, True, 7)
    (d,) = simulate_sessions([s], cache_dir=None)
    alone = [simulate_case(GridCase(f, 0.015, True, 7), duration=dur, cache_dir=None) for f, dur in ((700.0, 3.0), (1600.0, 2.0))]
    assert len(alone[1].exchanges) >= 1
    got = [[e for e in d.exchanges if hit_of(d, e.start_s) == k] for k in range(2)]
    assert all(0.5 <= e.start_s < 3.5 for e in got[0]) and all(e.start_s >= 3.5 for e in got[1])
    for k, (h, ref) in enumerate(zip(s.hit_times_s, alone, strict=True)):
        assert len(got[k]) == len(ref.exchanges)
        for a, b in zip(got[k], ref.exchanges, strict=True):
            assert abs(a.start_s - h - b.start_s) < 2e-3 and abs(a.end_s - h - b.end_s) < 2e-3
            assert a.gain == pytest.approx(b.gain, rel=0.15)
    # The input is marked at both pulses; a per-hit detector sees each hit's segment from its own pulse.
    inp = d.input_active()
    assert inp[round(0.5005 * d.fs)] and inp[round(3.5005 * d.fs)] and not inp[round(2.0 * d.fs)]
    seg = segment(d, 1)
    assert seg.t.size == round(2.0 * d.fs) and np.array_equal(seg.acc_clean, d.acc_clean[round(3.5 * d.fs) :])
    moved = per_hit(lambda c, **kw: [_Ev(0.1, 0.2)])(d)
    np.testing.assert_allclose([(e.start_s, e.end_s) for e in moved], [(0.6, 0.7), (3.6, 3.7)], atol=1e-12)
    grid = session_grid(1, 5, zetas=(0.005,))
    gaps = np.diff(grid[0].hit_times_s)
    assert len(grid) == 2 and not grid[1].cubic and np.all((gaps >= 2.0) & (gaps <= 6.0))


def _beat(locked: float, free_ratio: float, fs: float = 4096.0, dur: float = 1.5):
    """Exact modal coordinates of a detuned internal resonance as measured on both grid rigs (docs/evaluation.md §8):
    mode 1 at f1 drifting 21.5 -> 20.5 Hz; q2 = a component locked at ``locked`` θ1 + mode 2's free oscillation at
    ``free_ratio`` x 21 Hz of comparable amplitude + the cubic's off-resonant f1 response. E2 beats at their difference."""
    t = np.arange(int(dur * fs)) / fs
    th1 = 2 * np.pi * (21.5 * t - 0.5 * t**2 / dur)
    q1 = 1e-2 * np.cos(th1)
    th2f = 2 * np.pi * free_ratio * 21.0 * t
    q2 = 1e-4 * (0.8 * np.cos(locked * th1 + 0.3) + np.cos(th2f) + 0.3 * np.cos(th1))
    w = 2 * np.pi * np.array([18.8, 64.2])
    v = np.gradient(np.column_stack([q1, q2]), 1 / fs, axis=0)
    q = np.column_stack([q1, q2])
    return t, q, 0.5 * (v**2 + w**2 * q**2), fs


def test_truth_labels_the_component_locked_to_mode_1_not_the_beats_mean_frequency():
    """Issue 21 (docs/evaluation.md §8): the truth's m:n is the candidate whose component of exact q2 is phase-locked
    to θ1 (:func:`locked_ratio`, eq. 4.2), not f2/f1 of the beat rounded. Oracle: the construction. A 3 f1 component
    beating against a free oscillation at 3.29 f1 (the beam_al_mid exchanges' make-up) is 3:1 in every exchange, while
    issue 6's zero crossings read ratios spread across the 3.25 boundary; a 3.5 f1 component is 7:2; a free
    oscillation alone (nothing locked) gets no lock label and falls back to the zero-crossing rule."""
    from analysis.evaluation.truth import giving_phase, locked_ratio, major_exchanges

    t, q, E, fs = _beat(3.0, 3.29)
    ex = major_exchanges(q, E, fs, 0.05)
    assert len(ex) >= 4 and all(e.label == "3:1" for e in ex)
    zc = major_exchanges(q, E, fs, 0.05, label_rule="zero_crossing")
    assert [e.label for e in zc] == [e.zc_label for e in ex] and {e.zc_label for e in ex} != {"3:1"}
    th = giving_phase(q[:, 0])
    _, q7, _, _ = _beat(3.5, 3.2)
    assert locked_ratio(q7[:, 1], th, fs, 0.75, 21.0) == (7, 2)
    free = 1e-4 * (np.cos(2 * np.pi * 69.0 * t) + 0.3 * np.cos(th))
    assert locked_ratio(free, th, fs, 0.75, 21.0) is None
    with pytest.raises(ValueError):
        major_exchanges(q, E, fs, 0.05, label_rule="nearest")
