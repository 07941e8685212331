"""Morlet CWT (eq. 3.2), MWT (eq. 3.3) and the analytic signal (eqs. 2.30–2.33) against independent oracles."""

from __future__ import annotations

import numpy as np
import pytest

from analysis._cwt_reference import cwt_direct
from analysis.wavelet import analytic, morlet_cwt, mwt


def _signal(fs: float = 4096.0, seconds: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(fs * seconds)) / fs
    rng = np.random.default_rng(1)
    return t, np.sin(2 * np.pi * 60 * t) + 0.4 * np.cos(2 * np.pi * 210 * t + 0.7) + 0.05 * rng.standard_normal(t.size)


def test_fft_cwt_equals_the_direct_integral_of_eq_3_2():
    """The FFT form (eq. 2.29) must equal the Riemann sum of eq. 3.1 with the eq. 3.2 wavelet, edges included:
    zero padding makes it a linear, not circular, correlation. 1e-9 of the row peak: rounding only."""
    fs = 4096.0
    t, x = _signal(fs)
    f = np.array([20.0, 60.0, 133.0, 210.0, 900.0])
    idx = np.array([0, 5, 300, 4000, t.size - 40, t.size - 1])
    z = morlet_cwt(x, fs, f, normalization="literal")
    ref = cwt_direct(x, fs, f, idx)
    scale = np.abs(z).max(axis=1, keepdims=True)
    assert np.max(np.abs(z[:, idx] - ref) / scale) < 1e-9


def test_amplitude_normalisation_reads_the_sinusoid_amplitude_and_literal_has_the_derived_gain():
    """method-wbemd-slowflow §1.1 [DERIVED]: a cosine A·cos(Ωt) gives |Z(Ω,t)| = A (amplitude) and ≈ 0.9414·A·ω0/Ω (literal)."""
    fs = 2048.0
    t = np.arange(4096) / fs
    A, f0 = 2.5, 100.0
    x = A * np.cos(2 * np.pi * f0 * t)
    mid = slice(1024, 3072)
    amp = np.abs(morlet_cwt(x, fs, [f0])[0, mid])
    assert np.allclose(amp, A, rtol=1e-9)
    lit = np.abs(morlet_cwt(x, fs, [f0], normalization="literal")[0, mid])
    gain = np.pi**-0.25 * np.sqrt(2 * np.pi) / 2  # literal / amplitude peak ratio at ω0/Ω scale 1
    assert np.allclose(lit, A * gain * 2 * np.pi / (2 * np.pi * f0), rtol=1e-9)
    assert gain == pytest.approx(0.9414, abs=1e-3)  # the method note's 0.9414 constant


def test_mwt_peaks_at_the_components_and_ranks_them():
    fs = 4096.0
    _t, x = _signal(fs)
    f = np.arange(10.0, 400.0, 1.0)
    m = mwt(morlet_cwt(x, fs, f), fs, trim_s=0.25)
    peaks = [i for i in range(1, f.size - 1) if m[i] > m[i - 1] and m[i] > m[i + 1] and m[i] > 0.1]
    assert len(peaks) == 2 and abs(f[peaks[0]] - 60) <= 1 and abs(f[peaks[1]] - 210) <= 1  # 1 Hz grid
    # the maximum over time also picks up the peak of the 5 % white noise in each band (wider at 210 Hz)
    assert m[50] == pytest.approx(1.0, rel=0.05) and m[200] == pytest.approx(0.4, rel=0.1)


def test_analytic_phase_and_frequency_of_a_chirp():
    """Linear chirp f(t) = 40 + 10 t: the low-passed instantaneous frequency follows it (edges excluded),
    and the unwrapped phase equals 2π∫f within a constant."""
    fs = 2000.0
    t = np.arange(int(4 * fs)) / fs
    phase = 2 * np.pi * (40 * t + 5 * t**2)
    ins = analytic(1.5 * np.cos(phase), fs, lowpass_hz=5.0)
    mid = slice(int(0.5 * fs), int(3.5 * fs))
    assert np.max(np.abs(ins.frequency_hz[mid] - (40 + 10 * t[mid]))) < 0.05
    d = ins.phase[mid] - phase[mid]
    assert np.ptp(d) < 1e-2
    assert np.allclose(ins.amplitude[mid], 1.5, rtol=1e-2)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: morlet_cwt(np.zeros((2, 10)), 100.0, [10.0]), "1-D"),
        (lambda: morlet_cwt(np.zeros(10), 100.0, [0.0]), "> 0 Hz"),
        (lambda: morlet_cwt(np.zeros(10), 100.0, [np.nan]), "finite"),
        (lambda: morlet_cwt(np.zeros(10), 100.0, [5.0], normalization="bad"), "normalization"),
        (lambda: mwt(np.zeros((1, 10)), 100.0, trim_s=1.0), "leaves no samples"),
        (lambda: analytic(np.zeros(100), 100.0, lowpass_hz=60.0), "lowpass_hz"),
    ],
)
def test_bad_input_raises_one_line_value_errors(call, match):
    with pytest.raises(ValueError, match=match) as info:
        call()
    assert "\n" not in str(info.value)


def test_shorter_padding_for_display_stays_within_1e_4_of_the_exact_transform():
    """The live view pads 4 sigma instead of 9 (speed): the wrapped tail of the lowest row is below exp(-8) of its
    peak, so |Z| may differ by ~3e-4 at most; measured 2e-5. A padding of one sigma must differ visibly (the check
    can fail)."""
    fs = 5461.0
    t = np.arange(2731) / fs
    x = np.sin(2 * np.pi * 21 * t) + 0.5 * np.exp(-3 * t) * np.sin(2 * np.pi * 194 * t)
    f = np.geomspace(10.4, 2000.0, 48)
    exact = np.abs(morlet_cwt(x, fs, f))
    short = np.abs(morlet_cwt(x, fs, f, pad_sigmas=4.0))
    assert np.abs(short - exact).max() <= 1e-4 * exact.max()
    assert np.abs(np.abs(morlet_cwt(x, fs, f, pad_sigmas=1.0)) - exact).max() > 1e-3 * exact.max()


def test_analytic_memo_hands_out_read_only_arrays():
    """The memo's arrays are shared by every caller that asks again: writing into one must fail, not change the
    next answer."""
    from analysis.wavelet import AnalyticMemo

    fs = 1000.0
    t = np.arange(2000) / fs
    memo = AnalyticMemo(np.sin(2 * np.pi * 12.0 * t), fs)
    first = memo(1.0)
    for arr in (first.amplitude, first.phase, first.frequency_hz, memo(None).frequency_hz):
        with pytest.raises(ValueError):
            arr[0] = 0.0
    assert memo(1.0).frequency_hz is first.frequency_hz  # the same array, unchanged
