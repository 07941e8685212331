"""Acceleration → velocity → displacement (analysis/preprocess.py, seed L1322–L1323).

Oracles: exact integrals of sinusoids and the analytic Butterworth high-pass response
``H(s) = s³ / (s³ + 2 ωc s² + 2 ωc² s + ωc³)`` (independent of scipy's filter design); streaming equals
batch for arbitrary block splits (hypothesis).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis.preprocess import CausalPreprocessor, PreprocessSettings, acc_to_disp, frequency_response

FS = 16384.0


def _butter3_hp(f: float, fc: float) -> complex:
    s = 1j * f / fc  # normalised Laplace variable
    return s**3 / (s**3 + 2 * s**2 + 2 * s + 1)


def _sine_fit(y: np.ndarray, t: np.ndarray, f: float) -> complex:
    """Complex amplitude A with y ≈ Re(A e^{iωt}), least squares."""
    w = 2 * np.pi * f
    B = np.stack([np.cos(w * t), -np.sin(w * t)], axis=1)
    (re, im), *_ = np.linalg.lstsq(B, y, rcond=None)
    return re + 1j * im


@pytest.mark.parametrize("f", [21.0, 68.0])
@pytest.mark.parametrize("mode", ["zero_phase", "causal"])
def test_gain_and_phase_match_analytic_butterworth(f, mode):
    """Displacement from a = −ω² sin ωt versus the exact sin ωt, away from the record's edges."""
    t = np.arange(int(6 * FS)) / FS
    w = 2 * np.pi * f
    acc = (-(w**2) * np.sin(w * t))[:, None]
    s = PreprocessSettings(mode=mode)
    _, d = acc_to_disp(acc, FS, s)
    mid = slice(int(2 * FS), int(4 * FS))
    ratio = _sine_fit(d[mid, 0], t[mid], f) / _sine_fit(np.sin(w * t[mid]), t[mid], f)
    h = _butter3_hp(f, 18.0) * _butter3_hp(f, 10.0)
    expect = abs(h) ** 2 if mode == "zero_phase" else h
    assert abs(ratio - expect) < 2e-3 * abs(expect)  # bilinear warping + trapezoid error (ωdt)²/12 ~ 1e-5
    gain, phase = frequency_response(FS, np.array([f]), s)
    assert abs(gain[0] - abs(expect)) < 1e-3 * abs(expect)
    assert abs(phase[0] - np.angle(expect)) < 1e-3


def test_documented_numbers_at_21_and_68_hz():
    """docs/preprocessing.md: zero phase keeps 70.8 % of 21 Hz and 99.96 % of 68 Hz; causal 84.1 % and
    99.98 % with phase leads of 170.5° and 47.6°."""
    g_zp, p_zp = frequency_response(FS, np.array([21.0, 68.0]), PreprocessSettings())
    g_c, p_c = frequency_response(FS, np.array([21.0, 68.0]), PreprocessSettings(mode="causal"))
    np.testing.assert_allclose(g_zp, [0.7078, 0.99965], atol=5e-4)
    np.testing.assert_allclose(p_zp, 0.0, atol=1e-12)
    np.testing.assert_allclose(g_c, [0.8413, 0.99982], atol=5e-4)
    np.testing.assert_allclose(np.degrees(p_c), [170.5, 47.6], atol=0.2)


def test_zero_phase_follows_the_seed_steps():
    """Means removed around each step (L1323): outputs are zero-mean; a pure offset on a vanishes."""
    rng = np.random.default_rng(0)
    t = np.arange(int(2 * FS)) / FS
    acc = np.stack([np.sin(2 * np.pi * 40 * t), np.cos(2 * np.pi * 70 * t)], axis=1) + rng.standard_normal((t.size, 2)) * 0.01
    v, d = acc_to_disp(acc + 9.81, FS, PreprocessSettings())
    _, d0 = acc_to_disp(acc, FS, PreprocessSettings())
    np.testing.assert_allclose(v.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(d, d0, atol=1e-12 * np.abs(d0).max())
    assert v.shape == d.shape == acc.shape
    none = PreprocessSettings(vel_corner_hz=None, disp_corner_hz=None)
    _, d_raw = acc_to_disp(np.sin(2 * np.pi * 40 * t), FS, none)
    # No filter: the double integral of a 40 Hz sine, up to the line that the integration constants leave.
    ref = -np.sin(2 * np.pi * 40 * t) / (2 * np.pi * 40) ** 2
    mid = slice(1000, -1000)
    lin = np.polyfit(t, d_raw[:, 0] - ref, 1)  # only a line (integration constants) may separate them
    assert np.max(np.abs(d_raw[mid, 0] - ref[mid] - np.polyval(lin, t[mid]))) < 5e-3 * np.abs(ref).max()


def test_causal_baseline_removes_a_pretrigger_offset():
    """A constant offset measured in the pre-trigger is gone from the start; without it the
    high-pass removes it only after a transient."""
    t = np.arange(int(2 * FS)) / FS
    hit = t >= 0.05
    acc = np.where(hit, np.sin(2 * np.pi * 40 * (t - 0.05)), 0.0)[:, None]
    s_base = PreprocessSettings(mode="causal", causal_baseline_s=0.05)
    _, d_ref = acc_to_disp(acc, FS, s_base)
    _, d_off = acc_to_disp(acc + 0.3, FS, s_base)
    np.testing.assert_allclose(d_off, d_ref, atol=1e-12 * np.abs(d_ref).max())
    _, d_hp = acc_to_disp(acc + 0.3, FS, PreprocessSettings(mode="causal"))
    err = np.abs(d_hp - d_ref)[:, 0] / np.abs(d_ref).max()
    assert err[: int(0.3 * FS)].max() > 0.05  # an unremoved 0.3 m/s² offset disturbs the first 0.3 s ...
    assert err[int(1.5 * FS) :].max() < 0.01  # ... and has decayed by 1.5 s


@given(
    cuts=st.lists(st.integers(min_value=0, max_value=3000), max_size=8),
    baseline=st.sampled_from([0.0, 0.01, 0.05]),
)
def test_streaming_equals_batch_causal(cuts, baseline):
    rng = np.random.default_rng(7)
    acc = rng.standard_normal((3000, 3)) + np.array([0.5, -1.0, 0.0])
    s = PreprocessSettings(mode="causal", causal_baseline_s=baseline)
    v_b, d_b = acc_to_disp(acc, FS, s)
    pre = CausalPreprocessor(FS, 3, s)
    edges = [0, *sorted(cuts), 3000]
    outs = [pre.feed(acc[a:b]) for a, b in itertools.pairwise(edges)]
    v_s = np.concatenate([o[0] for o in outs])
    d_s = np.concatenate([o[1] for o in outs])
    assert v_s.shape == v_b.shape and d_s.shape == d_b.shape
    assert np.max(np.abs(v_s - v_b)) <= 1e-12 * np.abs(v_b).max()
    assert np.max(np.abs(d_s - d_b)) <= 1e-12 * np.abs(d_b).max()


def test_streaming_holds_samples_until_the_baseline_is_known():
    s = PreprocessSettings(mode="causal", causal_baseline_s=100 / FS)
    pre = CausalPreprocessor(FS, 2, s)
    v, _ = pre.feed(np.ones((60, 2)))
    assert v.shape == (0, 2) and pre.pending == 60
    v, d = pre.feed(np.ones((60, 2)))
    assert v.shape == (120, 2) and pre.pending == 0
    np.testing.assert_array_equal(d, 0.0)  # a constant acceleration is all baseline
    assert pre.feed(np.ones((5, 2)))[0].shape == (5, 2)
    with pytest.raises(ValueError):
        pre.feed(np.ones((5, 3)))
    short = acc_to_disp(np.ones((30, 2)), FS, s)  # record shorter than the baseline: use what there is
    assert short[0].shape == (30, 2)


@pytest.mark.parametrize("n_ch", [4, 13, 17])
@pytest.mark.parametrize("corners", [(18.0, 10.0), (None, 10.0), (18.0, None), (5.0, 5.0)])
def test_fused_chain_is_the_library_filters_bit_for_bit(corners, n_ch):
    """The compiled one-pass chain (analysis.preprocess._causal_chain, at 4, 13 and 17 channels) must give exactly what
    the library filters give stage by stage — ``lfilter`` trapezoids and ``sosfilt`` high-passes with carried ``zi`` —
    so that the speed-up changes no result (tolerance 0: same operations in the same order)."""
    import scipy.signal

    from analysis.preprocess import highpass_sos

    rng = np.random.default_rng(3)
    acc = rng.standard_normal((2500, n_ch)) * np.resize([1.0, 1e-3, 50.0, 0.2], n_ch) + 0.7
    s = PreprocessSettings(vel_corner_hz=corners[0], disp_corner_hz=corners[1], mode="causal", causal_baseline_s=0.004)
    pre = CausalPreprocessor(FS, n_ch, s)
    outs = [pre.feed(acc[a:b]) for a, b in itertools.pairwise([0, 17, 40, 41, 1300, 2500])]
    v_s, d_s = np.concatenate([o[0] for o in outs]), np.concatenate([o[1] for o in outs])
    # the reference: library calls, the record cut elsewhere (carried states make the split irrelevant)
    a = acc - acc[: round(0.004 * FS)].mean(axis=0)
    dt = 1.0 / FS
    b_int, a_int = np.array([0.5 * dt, 0.5 * dt]), np.array([1.0, -1.0])

    def chain(x, st):
        v, st[0] = scipy.signal.lfilter(b_int, a_int, x, axis=0, zi=st[0] if st[0] is not None else (-b_int[0] * x[0])[None, :])
        sos = highpass_sos(corners[0], FS, 3)
        if sos is not None:
            v, st[1] = scipy.signal.sosfilt(sos, v, axis=0, zi=st[1])
        d, st[2] = scipy.signal.lfilter(b_int, a_int, v, axis=0, zi=st[2] if st[2] is not None else (-b_int[0] * v[0])[None, :])
        sos = highpass_sos(corners[1], FS, 3)
        if sos is not None:
            d, st[3] = scipy.signal.sosfilt(sos, d, axis=0, zi=st[3])
        return v, d

    st_ = [None, np.zeros((2, 2, n_ch)), None, np.zeros((2, 2, n_ch))]
    ref = [chain(a[x:y], st_) for x, y in itertools.pairwise([0, 66, 1300, 2500])]
    np.testing.assert_array_equal(v_s, np.concatenate([r[0] for r in ref]))
    np.testing.assert_array_equal(d_s, np.concatenate([r[1] for r in ref]))
    # feed_after (the seed lane's: displacement only, written after a kept tail, held baseline included): the same
    pre2, kept, new_rows = CausalPreprocessor(FS, n_ch, s), np.full((3, n_ch), 7.0), []
    for a_, b_ in itertools.pairwise([0, 17, 40, 41, 1300, 2500]):
        joined, new = pre2.feed_after(kept, acc[a_:b_])
        assert np.array_equal(joined[: kept.shape[0]], kept) and joined.shape[0] == kept.shape[0] + new
        new_rows.append(joined[kept.shape[0] :])
        kept = joined[-3:] if joined.shape[0] >= 3 else joined
    np.testing.assert_array_equal(np.concatenate(new_rows), d_s)


def test_butter_sos_is_scipys_design_once_and_a_fresh_copy_each_call():
    import scipy.signal

    from analysis.preprocess import butter_sos

    for args in ((3, 18.0, "highpass", 16384.0), (2, (20.3, 61.7), "bandpass", 16384.0), (4, (5.0, 300.0), "bandpass", 2048)):
        want = scipy.signal.butter(args[0], args[1], btype=args[2], fs=args[3], output="sos")
        got = butter_sos(*args)
        assert np.array_equal(got, want)
        got[:] = 0.0  # the caller's own copy: the next call is not spoiled
        assert np.array_equal(butter_sos(*args), want)
    same = butter_sos(2, (20.3, 61.7), "bandpass", 16384.0)
    assert np.array_equal(butter_sos(2, np.array([20.3, 61.7]), "bandpass", 16384), same)
