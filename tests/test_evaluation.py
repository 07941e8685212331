"""Issue 6 evaluation harness: truth (major exchanges), the grid's simulated cases, and the event scorer.

Oracles: constructed energy envelopes whose rise is known by construction; the modal-damping identity
dE_r/dt = -2 zeta_r w_r v_r^2 <= 0 (a linear rig's modal energy can never rise); an independent FFT
of the simulator's modal coordinates for the frequency ratio; hand-counted matches for the scorer.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.evaluation.grid import DEFAULT_ZETAS, GridCase, default_grid, simulate_case, simulate_cases
from analysis.evaluation.score import DetectedEvent, format_markdown, match_case, score_events
from analysis.evaluation.truth import (
    Exchange,
    major_exchanges,
    modal_energy_smoothed,
    nearest_ratio,
    zigzag,
)

FS = 2000.0
W = 0.02


def _record(log_e2, f1=20.0, f2=60.0, duration=2.0):
    """Modal coordinates at f1, f2 and an energy matrix whose E2 envelope is exp(log_e2(t)), E1 = 1 J."""
    t = np.arange(round(duration * FS)) / FS
    q = np.stack([np.sin(2 * np.pi * f1 * t), np.sin(2 * np.pi * f2 * t)], axis=1)
    E = np.stack([np.ones_like(t), np.exp(log_e2(t))], axis=1)
    return q, E


def _piecewise(t, knots, logs):
    return np.interp(t, knots, logs)


def test_constructed_doubling_is_found_with_its_bounds_gain_and_label():
    # E2 decays slowly to 0.8 s, rises x4 (exponentially) to 1.0 s, then decays: one exchange [0.8, 1.0].
    ln4 = np.log(4.0)
    q, E = _record(lambda t: _piecewise(t, [0, 0.8, 1.0, 2.0], [-4.0, -4.2, -4.2 + ln4, -6.0]))
    ex = major_exchanges(q, E, FS, pulse_end_s=0.001, window_s=W, input_work=1.0)
    assert len(ex) == 1
    e = ex[0]
    # A centred moving average moves a kink by at most half a window.
    assert abs(e.start_s - 0.8) <= W / 2 and abs(e.end_s - 1.0) <= W / 2
    assert 3.5 < e.gain <= 4.0 + 1e-9
    assert (e.ratio_m, e.ratio_n) == (3, 1)
    assert abs(e.f1_hz - 20.0) < 0.02 and abs(e.f2_hz - 60.0) < 0.06


def test_label_is_the_nearest_listed_ratio():
    q, E = _record(lambda t: _piecewise(t, [0, 0.8, 1.0, 2.0], [-4.0, -4.2, -2.0, -6.0]), f1=20.0, f2=50.0)
    (e,) = major_exchanges(q, E, FS, 0.001, W, input_work=1.0)
    assert e.label == "5:2" and abs(e.ratio - 2.5) < 0.01
    assert nearest_ratio(3.29) == (7, 2)  # the linear rig's 68.37 / 20.81 is nearer 3.5 than 3
    assert nearest_ratio(2.24) == (2, 1) and nearest_ratio(3.8) == (4, 1)


def test_decaying_or_small_or_floor_level_rises_are_not_exchanges():
    decay = _record(lambda t: -1.0 - 3.0 * t)
    assert major_exchanges(*decay, FS, 0.001, W, input_work=1.0) == []
    # A x1.8 rise is below the factor 2.
    small = _record(lambda t: _piecewise(t, [0, 0.8, 1.0, 2.0], [-4.0, -4.2, -4.2 + np.log(1.8), -6.0]))
    assert major_exchanges(*small, FS, 0.001, W, input_work=1.0) == []
    # A x10 rise that ends at 1e-8 of the input work is at the floor (1e-6).
    floor = _record(lambda t: _piecewise(t, [0, 0.8, 1.0, 2.0], [-25.0, -25.0, -25.0 + np.log(10.0), -26.0]))
    assert major_exchanges(*floor, FS, 0.001, W, input_work=1.0) == []
    assert len(major_exchanges(*floor, FS, 0.001, W, input_work=1.0, floor_rel=1e-12)) == 1


def test_rise_during_the_pulse_is_ignored():
    # E2 rises x20 up to 0.05 s (as if the hammer were still on), then decays; the pulse ends at 0.05 s.
    q, E = _record(lambda t: _piecewise(t, [0, 0.05, 2.0], [-6.0, -3.0, -5.0]))
    assert major_exchanges(q, E, FS, pulse_end_s=0.05, window_s=W, input_work=1.0) == []
    assert len(major_exchanges(q, E, FS, pulse_end_s=0.001, window_s=W, input_work=1.0)) == 1


def test_merge_rule_small_dip_does_not_split_a_rise():
    up = np.log(1.6)
    # Rise x1.6, dip 10 % (< the 1.25 hysteresis), rise x1.6: one exchange of gain ~ 2.3.
    k = [0, 0.6, 0.7, 0.75, 0.85, 2.0]
    dip = np.log(0.9)
    merged = _record(lambda t: _piecewise(t, k, [-3.0, -3.2, -3.2 + up, -3.2 + up + dip, -3.2 + 2 * up + dip, -5]))
    (e,) = major_exchanges(*merged, FS, 0.001, W, input_work=1.0)
    assert abs(e.start_s - 0.6) <= W / 2 and abs(e.end_s - 0.85) <= W / 2 and 2.0 < e.gain <= 1.6 * 1.6 * 0.9
    # The same with a 50 % dip: two rises of x1.6, neither an exchange.
    dip = np.log(0.5)
    split = _record(lambda t: _piecewise(t, k, [-3.0, -3.2, -3.2 + up, -3.2 + up + dip, -3.2 + 2 * up + dip, -5]))
    assert major_exchanges(*split, FS, 0.001, W, input_work=1.0) == []


def test_zigzag_and_smoothing_basics():
    x = np.array([5, 4, 3, 3.2, 2.9, 6, 7, 6.9, 4, 8.0])
    assert zigzag(x, 1.25) == [(0, 1), (4, -1), (6, 1), (8, -1), (9, 1)]
    E = np.zeros((101, 2))
    E[50] = 7.0
    s = modal_energy_smoothed(E, fs=100.0, window_s=0.07)  # 7 samples
    assert np.allclose(s[47:54], 1.0) and s[46, 0] == 0 and s[54, 0] == 0


def test_default_grid_spans_force_and_damping_with_linear_twins():
    g = default_grid()
    nl = [c for c in g if c.cubic]
    lin = [c for c in g if not c.cubic]
    assert len(nl) >= 20 and len(lin) == len(nl)
    assert min(c.zeta for c in nl) == 0.002 and max(c.zeta for c in nl) == 0.015
    assert max(c.force_n for c in nl) / min(c.force_n for c in nl) >= 4
    assert {(c.force_n, c.zeta, c.seed) for c in nl} == {(c.force_n, c.zeta, c.seed) for c in lin}
    assert GridCase(1000, 0.015).zeta_rest == 0.004 and GridCase(1000, 0.002).zeta_rest == 0.002
    assert set(DEFAULT_ZETAS) == {c.zeta for c in nl}


@pytest.mark.slow
def test_linear_grid_has_no_major_exchange_and_modal_energy_never_rises():
    lin = [c for c in default_grid() if not c.cubic]
    data = simulate_cases(lin, cache_dir=None)
    assert all(d.exchanges == () for d in data)
    for d in data:
        # Modal damping: dE2/dt = -2 zeta w2 v2^2 <= 0 after the pulse, to the integrator's rounding.
        e2 = d.modal_energy[d.t > d.pulse_end_s, 1]
        assert np.max(np.diff(e2)) <= 1e-9 * e2[0]
        assert d.truth(window_s=0.0108) == [] and d.truth(window_s=0.0432) == []


def test_nonlinear_case_has_a_3_to_1_exchange_confirmed_by_an_fft(tmp_path):
    case = GridCase(1300.0, 0.010, True, seed=3)
    d = simulate_case(case, duration=1.0, cache_dir=tmp_path)
    assert not d.from_cache and d.acc.shape == (16384, 14) and d.acc.dtype == np.float32
    big = max(d.exchanges, key=lambda e: e.gain)
    assert big.gain >= 10 and big.label == "3:1"
    # Independent reading: FFT peaks (Hann, x16 zero padding) of modal coordinates 1 and 2 over the interval.
    m = (d.t >= big.start_s) & (d.t <= big.end_s)
    nfft = 16 * 16384
    fr = np.fft.rfftfreq(nfft, 1 / d.fs)
    peaks = []
    for r in (0, 1):
        seg = d.modal_q[m, r] * np.hanning(int(m.sum()))
        spec = np.abs(np.fft.rfft(seg, nfft))
        band = (fr > 10) & (fr < 120)
        peaks.append(fr[band][np.argmax(spec[band])])
    assert abs(peaks[1] / peaks[0] - big.ratio) / big.ratio < 0.03
    assert nearest_ratio(peaks[1] / peaks[0]) == (3, 1)
    # Noise: 1 % of each channel's RMS, seeded; the cache returns the same record.
    resid = d.acc.astype(float) - d.acc_clean
    rms = np.sqrt(np.mean(d.acc_clean.astype(float) ** 2, axis=0))
    assert np.allclose(np.std(resid, axis=0) / rms, 0.01, rtol=0.05)
    again = simulate_case(case, duration=1.0, cache_dir=tmp_path)
    assert again.from_cache and np.array_equal(again.acc, d.acc) and again.exchanges == d.exchanges


def _ex(a, b, m=3, n=1):
    return Exchange(a, b, 4.0, m, n, 22.0, 66.0)


def test_scorer_counts_lag_one_to_one_and_labels():
    truths = [[_ex(1.0, 1.2), _ex(1.5, 1.6, 5, 2)], [], [_ex(0.3, 0.4)]]
    events = [
        [
            DetectedEvent(1.1, 1.15, 3, 1),  # inside the first: TP, right label
            DetectedEvent(1.619, 1.65, 3, 1),  # starts within one window (0.02) after the second: TP, wrong label
            DetectedEvent(1.18, 1.19, 3, 1),  # second event on the first exchange: FP
        ],
        [DetectedEvent(0.5, 0.6)],  # no truth in this case: FP
        [DetectedEvent(0.421, 0.45, 3, 1)],  # starts 0.021 s after the end: beyond the lag, FP; the truth is a FN
    ]
    s = score_events(events, truths, window_s=0.02, case_names=["a", "b", "c"])
    assert (s.tp, s.fp, s.fn) == (2, 3, 1)
    assert s.precision == pytest.approx(2 / 5) and s.recall == pytest.approx(2 / 3) and s.label_accuracy == 0.5
    assert [r.tp for r in s.rows] == [2, 0, 0] and s.rows[0].labels_right == 1
    assert "| 2 | 3 | 1 | 0.40 | 0.67 | 0.50 |" in format_markdown({"x": s})


def test_scorer_finds_the_maximum_matching_not_a_greedy_one():
    truths = [_ex(1.0, 1.1), _ex(1.2, 1.3)]
    # Event 0 overlaps both truths, event 1 only the first: a greedy first-come match would give 1 TP.
    events = [DetectedEvent(1.05, 1.25), DetectedEvent(1.0, 1.05)]
    assert sorted(match_case(events, truths, 0.0)) == [(0, 1), (1, 0)]
    s = score_events([[]], [truths], 0.02)
    assert (s.tp, s.fp, s.fn) == (0, 0, 2) and np.isnan(s.precision) and s.recall == 0.0
