"""Slow-flow IR confirmation (analysis/slowflow.py) on components whose phase relation is known exactly.

Oracles: synthetic tone pairs built from their phases (locked 3:1 with a bounded wobble, a steady 3.2
ratio, a single passage through 3), and the simulator's exact linear modal coordinates of the linear
beam_ch4_exp rig, for which no slow angle can exist (eq. 2.42: away from resonance averaging holds).
"""

from __future__ import annotations

import math
import tomllib
from functools import cache
from pathlib import Path

import numpy as np
import pytest

import analysis.slowflow as sf

FS = 500.0
T = 20.0
t = np.arange(int(T * FS)) / FS


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def phase_of(f_hz: np.ndarray) -> np.ndarray:
    return 2.0 * np.pi * np.cumsum(f_hz) / FS


F1 = 8.0 - 0.2 * t  # a hardening system losing energy: its fundamental falls from 8 to 4 Hz
TH1 = phase_of(F1)


def locked_pair(t1: float = 6.0, t2: float = 14.0, wobble: float = 1.0, fw: float = 0.35, detune: float = 0.4,
                lock_end_at_record_end: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """θ2 = 3θ1 + D(t) + wobble·sin(2π fw t) inside [t1, t2]: D is a detuning phase (component 2 runs
    ``detune`` Hz above 3f1 before the lock and below after), the wobble is the bounded slow angle."""
    det = detune * (1 - smoothstep(t - (t1 - 1.0)))
    if not lock_end_at_record_end:
        det = det - detune * smoothstep(t - t2)
    w = smoothstep((t - t1) / 0.5) * (1 - smoothstep((t - (t2 - 0.5)) / 0.5))
    th2 = 3.0 * TH1 + phase_of(det) + wobble * w * np.sin(2 * np.pi * fw * t)
    return np.exp(-0.05 * t) * np.cos(TH1), 0.5 * np.exp(-0.08 * t) * np.cos(th2)


def test_phase_variable_is_the_linear_combination_of_phases():
    th_a, th_b = 2 * np.pi * 5.0 * t, 2 * np.pi * 16.0 * t + 0.3
    phi, phi_dot = sf.phase_variable(th_a, th_b, 3, 1, fs=FS)
    np.testing.assert_allclose(phi, -2 * np.pi * 1.0 * t - 0.3, atol=1e-9)  # 3·5 − 16 = −1 Hz
    np.testing.assert_allclose(phi_dot, -2 * np.pi, rtol=1e-9)
    _, pd = sf.phase_variable(th_a, th_b, 5, 2, omega_a=np.full(t.size, 10.0), omega_b=np.full(t.size, 20.0))
    np.testing.assert_allclose(pd, 5 * 10.0 - 2 * 20.0)
    with pytest.raises(ValueError, match="positive integers"):
        sf.phase_variable(th_a, th_b, 0, 1, fs=FS)
    with pytest.raises(ValueError, match="give omega_a"):
        sf.phase_variable(th_a, th_b, 3, 1)


def test_locked_pair_confirms_3to1_over_the_locked_interval():
    c1, c2 = locked_pair()
    conf = sf.test_ratios(c1, c2, FS, 3, 1)
    assert conf.status == "confirmed" and (conf.m, conf.n) == (3, 1) and conf.bracketed, conf.reason
    # [T1, T2] runs from the first to the last reversal of Φ: the wobble reverses Φ every half period
    # (1/(2·0.35) = 1.43 s), so each end may sit up to one half period inside the lock [6, 14] s.
    half = 1.0 / (2 * 0.35)
    assert 6.0 - 0.2 <= conf.start_s <= 6.0 + half and 14.0 - half <= conf.end_s <= 14.0 + 0.2
    by = {(c.m, c.n): c for c in conf.candidates}
    assert set(by) == {(1, 1), (2, 1), (3, 1), (4, 1), (5, 1)}
    assert by[(2, 1)].trusted == () and by[(4, 1)].trusted == ()  # 2:1 and 4:1 are time-like
    assert by[(2, 1)].drift_sign == -1 and by[(4, 1)].drift_sign == 1  # and bracket the 3:1 lock
    assert by[(3, 1)].captured_fraction > 0.3
    assert conf.t.size <= sf.MAX_TRAJECTORY_POINTS and conf.t.size == conf.phi.size == conf.phi_dot.size


def test_a_wrong_label_finds_the_true_ratio_among_its_neighbours():
    c1, c2 = locked_pair()
    conf = sf.test_ratios(c1, c2, FS, 4, 1)  # candidates 2..6:1 contain the true 3:1
    assert conf.confirmed and (conf.m, conf.n) == (3, 1)


def test_steady_ratio_3_2_is_not_confirmed_and_3to1_4to1_bracket_it():
    c1, c2 = np.cos(TH1), 0.5 * np.cos(3.2 * TH1)
    conf = sf.test_ratios(c1, c2, FS, 3, 1)
    assert conf.status == "not_confirmed" and math.isnan(conf.start_s)
    by = {(c.m, c.n): c for c in conf.candidates}
    assert all(c.trusted == () for c in conf.candidates)
    # bracketing rule (L1298): Φ̇_{3:1} = (3 − 3.2)ω1 < 0, Φ̇_{4:1} = (4 − 3.2)ω1 > 0
    assert by[(3, 1)].drift_sign == -1 and by[(4, 1)].drift_sign == 1
    assert by[(2, 1)].drift_sign == -1 and by[(5, 1)].drift_sign == 1


def test_a_single_passage_through_3_is_not_a_capture():
    """The ratio sweeps 2.7 → 3.3 without locking: Φ reverses once (a fold, not a loop) — time-like."""
    r = 2.7 + 0.6 * t / T
    th2 = phase_of(r * F1)
    conf = sf.test_ratios(np.cos(TH1), 0.5 * np.cos(th2), FS, 3, 1)
    assert conf.status == "not_confirmed", conf.reason


def test_loop_at_the_record_end_is_flagged_not_confirmed():
    """Capture from 18.5 s to the end of a 20 s record: the loop is there, but with < 0.3 s (and less than
    the filter's own 1/cut-off transient) after it the seed would not trust it (L1314, L1426)."""
    c1, c2 = locked_pair(t1=18.0, t2=T + 1.0, wobble=1.0, fw=1.0, lock_end_at_record_end=True)
    conf = sf.test_ratios(c1, c2, FS, 3, 1)
    assert conf.status == "not_confirmed", conf.reason
    three = next(c for c in conf.candidates if (c.m, c.n) == (3, 1))
    assert any(iv.end_effect and iv.end_s > 18.5 for iv in three.intervals)  # seen, but flagged
    assert three.trusted == ()


def test_the_same_loop_away_from_the_end_is_confirmed():
    """Control for the previous test: the detector does see a 1 Hz wobble lock of 3 s."""
    c1, c2 = locked_pair(t1=12.0, t2=15.0, fw=1.0)
    conf = sf.test_ratios(c1, c2, FS, 3, 1)
    # first/last reversal within a half wobble period (0.5 s) of the lock, or inside the 1 s detuning ramp
    # that ends it (Φ̇ stays near 0 for its first part)
    assert conf.confirmed and 11.8 <= conf.start_s <= 12.5 and 14.5 <= conf.end_s <= 15.5, conf.reason


@cache
def linear_exp_modal_q() -> tuple[np.ndarray, float]:
    from analysis.model.rig import build_rig
    from daq.config.loader import validate
    from daq.config.rig import RigConfig
    from daq.rigs import resolve_rig_path

    path = resolve_rig_path("beam_ch4_exp")
    data = tomllib.loads(Path(path).read_text())
    data.pop("nonlinear_springs")  # cubic term zero
    rig = build_rig(validate(RigConfig, data, str(path)), str(path))
    fs = 4096.0  # modes 1-2 at ~21/68 Hz; the 2 s record decimated honestly by simulating at 4 kHz
    res = rig.simulator.run(rig.hammer_force(), 2.0, fs)
    return res.modal_q[0], fs


def test_linear_beam_modal_coordinates_have_no_slow_angle():
    """Linear beam_ch4_exp (f2/f1 = 68.4/20.8 = 3.29): exact modal coordinates are decaying sinusoids,
    so no m:1 or m:2 phase variable up to 6 may show a trusted non-time-like interval (eq. 2.42)."""
    q, fs = linear_exp_modal_q()
    ratios = [(m, 1) for m in range(1, 7)] + [(m, 2) for m in range(1, 13, 2)]
    for m, n in ratios:
        traj = sf.trajectory(q[:, 0], q[:, 1], fs, m, n)
        rt = sf.ratio_test(traj)
        assert rt.trusted == (), (m, n, rt.intervals)
        assert rt.drift_sign == (-1 if m / n < 3.29 else 1), (m, n)  # bracketing: 3.29 lies between 3 and 3.5
    assert not sf.test_ratios(q[:, 0], q[:, 1], fs, 3, 1).confirmed


def test_detector_params_are_validated():
    with pytest.raises(ValueError, match="DetectorParams"):
        sf.DetectorParams(min_sign_changes=1)
    with pytest.raises(ValueError, match="DetectorParams"):
        sf.DetectorParams(dead_band_rel=-1.0)
