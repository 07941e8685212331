"""A confirmation computes what its tests share once, and the numbers stay those of the separate computations.

Issue 30 item 5: the confirmation lane was ~0.5 core of a 15-channel session. One confirmation read the same two
IMFs' analytic signals 24 times (ten slow-flow trajectories, the slow-angle test, the mean frequencies) although
only the instantaneous frequency's low-pass differs between them (analysis.wavelet.AnalyticMemo). The oracle here
is the analytic signal written out independently (scipy's Hilbert transform, unwrapped angle, gradient, the
zero-phase Butterworth), compared bit for bit: sharing must not move a single number.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

import analysis.slowflow as sf
from analysis.confirm import ConfirmSettings, slow_angle_test
from analysis.wavelet import AnalyticMemo, analytic

FS = 500.0
t = np.arange(int(8.0 * FS)) / FS
TH1 = 2 * np.pi * np.cumsum(8.0 - 0.2 * t) / FS
LOW = np.exp(-0.05 * t) * np.cos(TH1)
HIGH = 0.5 * np.exp(-0.08 * t) * np.cos(3.0 * TH1 + 0.8 * np.sin(2 * np.pi * 0.35 * t))  # a 3:1 lock with a wobble


def written_out(c: np.ndarray, lowpass_hz: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(amplitude, phase, frequency) as eqs. 2.31–2.33 define them, without gvtlink's code."""
    z = signal.hilbert(c)
    phase = np.unwrap(np.angle(z))
    f = np.gradient(phase) * FS / (2.0 * np.pi)
    if lowpass_hz is not None:
        sos = signal.butter(3, lowpass_hz, btype="low", fs=FS, output="sos")
        f = signal.sosfiltfilt(sos, f, padlen=min(c.size - 1, 3 * (2 * sos.shape[0] + 1)))
    return np.abs(z), phase, f


@pytest.fixture
def hilbert_calls(monkeypatch) -> list[int]:
    """Counts the Hilbert transforms computed (the real one runs)."""
    calls: list[int] = []
    real = signal.hilbert

    def counting(x, *args, **kwargs):
        calls.append(np.asarray(x).size)
        return real(x, *args, **kwargs)

    monkeypatch.setattr(signal, "hilbert", counting)
    return calls


def test_a_memo_at_several_cut_offs_equals_each_analytic_signal_written_out(hilbert_calls):
    m = AnalyticMemo(LOW, FS)
    for lp in (1.6, None, 2.0, 1.6):  # a cut-off asked again, and out of order
        got, want = m(lp), written_out(LOW, lp)
        for a, b in zip((got.amplitude, got.phase, got.frequency_hz), want, strict=True):
            assert np.array_equal(a, b)
    assert len(hilbert_calls) == 1 + 4  # the memo's one, and the oracle's four
    a = analytic(LOW, FS, lowpass_hz=2.0)
    assert np.array_equal(a.frequency_hz, m(2.0).frequency_hz)
    with pytest.raises(ValueError, match="lowpass_hz must lie"):
        m(FS)


def test_the_ratio_scan_and_the_slow_angle_test_share_one_transform_per_component(hilbert_calls):
    lo, hi = AnalyticMemo(LOW, FS), AnalyticMemo(HIGH, FS)
    c = sf.test_ratios(lo, hi, FS, 3, 1)
    sa = slow_angle_test(lo, hi, FS, 0.0, 2.0, 6.0, 3, 1, ConfirmSettings())
    assert len(hilbert_calls) == 2  # was 24: each trajectory, mean frequency and the gain transformed both again
    hilbert_calls.clear()
    # the same test on plain arrays (the path every other caller takes) gives the same record, bit for bit
    c_plain = sf.test_ratios(LOW, HIGH, FS, 3, 1)
    assert len(hilbert_calls) == 2  # test_ratios shares its own transforms too
    assert (c.status, c.m, c.n, c.start_s, c.end_s, c.bracketed) == (
        c_plain.status, c_plain.m, c_plain.n, c_plain.start_s, c_plain.end_s, c_plain.bracketed)  # fmt: skip
    assert c.candidates == c_plain.candidates and np.array_equal(c.phi, c_plain.phi)
    # each candidate's trajectory against the one written out: Φ = 3θ̂_low − θ̂_high low-passed at 0.2 × mean f
    _, ph_lo, f_lo = written_out(LOW, None)
    lp = sf.LOWPASS_FRACTION * abs(ph_lo[-1] - ph_lo[0]) / (2.0 * math.pi) * FS / (ph_lo.size - 1)
    (_, p_lo, _), (_, p_hi, _) = written_out(LOW, lp), written_out(HIGH, lp)
    sos = signal.butter(3, lp, btype="low", fs=FS, output="sos")
    for k in (2, 3, 4):
        tr = sf.trajectory(lo, hi, FS, k, 1)
        want = signal.sosfiltfilt(sos, k * p_lo - p_hi, padlen=min(t.size - 1, 3 * (2 * sos.shape[0] + 1)))
        assert np.array_equal(tr.phi, want) and tr.lowpass_hz == lp
    assert sa.ratio == (3, 1) and sa.passed is not None
    assert np.isfinite(f_lo).all()


def test_a_memo_at_another_sample_rate_is_refused():
    with pytest.raises(ValueError, match="analysed at fs"):
        sf.trajectory(AnalyticMemo(LOW, FS), HIGH, 2 * FS, 3, 1)


def test_the_sifts_envelope_is_scipys_cubic_spline_bit_for_bit(monkeypatch):
    """The sifts' envelopes (analysis.emd.not_a_knot_spline) against scipy's CubicSpline on random extrema (4 to
    400 points, values over nine decades), and a whole first-IMF sift against PyEMD's own (its envelope, and its
    extrema searched at every ask, not remembered)."""
    from scipy.interpolate import CubicSpline

    import analysis.emd as emd

    rng = np.random.default_rng(7)
    grid = np.arange(5000, dtype=float)
    for _ in range(200):
        n = int(rng.integers(4, 400))
        x = np.sort(rng.choice(np.arange(-5, grid.size + 5), n, replace=False)).astype(float) + rng.random()
        y = rng.standard_normal(n) * 10 ** rng.uniform(-6, 3)
        tt = grid[(grid >= x[0]) & (grid <= x[-1])]
        assert np.array_equal(emd.not_a_knot_spline(x, y, tt), CubicSpline(x, y)(tt))

    class PyEmdSift(emd._RillingEMD):
        spline_points = emd.EMD.spline_points  # PyEMD's, through scipy's CubicSpline
        find_extrema = emd.EMD.find_extrema  # PyEMD's, every time

    searches: list[int] = []
    real = emd.EMD._find_extrema_simple
    monkeypatch.setattr(emd.EMD, "_find_extrema_simple", staticmethod(lambda T, S: searches.append(1) or real(T, S)))
    sig = LOW + HIGH + 0.01 * np.random.default_rng(3).standard_normal(t.size)
    mine = emd._RillingEMD(emd.RILLING_STOP, emd.NO_END_THRESHOLDS).emd(sig, max_imf=1)
    n_mine = len(searches)
    theirs = PyEmdSift(emd.RILLING_STOP, emd.NO_END_THRESHOLDS).emd(sig, max_imf=1)
    assert np.array_equal(mine, theirs)
    assert 3 * n_mine < 2 * (len(searches) - n_mine)  # PyEMD searched 3 times an iteration, this sift once (+1)
    # input CubicSpline refuses (repeated positions) is still refused, by PyEMD's own path
    with pytest.raises(ValueError):
        emd._RillingEMD().spline_points(grid, np.array([[0.0, 1.0, 1.0, 2.0, 3.0], [0.0, 1.0, 2.0, 1.0, 0.0]]))
