"""Tests for analysis.emd: PyEMD configured like emd.m, masked EMD (seed L485), IO (L934) and PCC (L853)."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.emd import eemd, emd, masked_first_imf, orthogonality_index, pcc

FS = 8000.0
T = np.arange(int(0.5 * FS)) / FS


def test_emd_reconstructs_and_separates_octave_apart_tones():
    # 1000 Hz and 100 Hz are a decade apart: plain EMD separates them (Rilling: ratio > 2).
    hi, lo = np.sin(2 * np.pi * 1000 * T), np.sin(2 * np.pi * 100 * T)
    c = emd(hi + lo, FS)
    np.testing.assert_allclose(c.sum(axis=0), hi + lo, atol=1e-9)  # residual row makes the sum exact
    assert pcc(c[0], hi) > 0.98  # 0.02: end effects over 0.5 s of a 1 kHz tone
    assert max(pcc(r, lo) for r in c[1:]) > 0.98


def test_masked_first_imf_recovers_tone_next_to_equal_tone():
    # 900 Hz and 600 Hz, equal amplitude: ratio 1.5 < 2, plain EMD mixes them (PCC 0.86 measured); a mask
    # at 1.4·900 Hz with amplitude 2 makes IMF1 the 900 Hz tone (Deering & Kaiser; measured PCC 0.997).
    fs = 16000.0
    t = np.arange(int(0.5 * fs)) / fs
    hi, lo = np.sin(2 * np.pi * 900 * t), np.sin(2 * np.pi * 600 * t)
    plain = emd(hi + lo, fs, max_imf=1)[0]
    c = masked_first_imf(hi + lo, fs, 2.0 * np.sin(2 * np.pi * 1260 * t))
    assert pcc(c, hi) > 0.98  # margin 0.017 below the measured value
    assert pcc(plain, hi) < 0.9  # the mask must matter, or this test proves nothing


def test_masked_first_imf_well_separated_pair():
    hi, lo = np.sin(2 * np.pi * 1200 * T), 0.8 * np.sin(2 * np.pi * 150 * T)
    c = masked_first_imf(hi + lo, FS, np.max(np.abs(hi + lo)) * np.sin(2 * np.pi * 1200 * T))
    assert pcc(c, hi) > 0.98
    assert pcc(hi + lo - c, lo) > 0.98


def test_orthogonality_index_oracles():
    s, c = np.sin(2 * np.pi * 5 * T[:800]), np.cos(2 * np.pi * 5 * T[:800])  # 5 whole periods
    assert orthogonality_index(np.vstack([s, c])) == pytest.approx(0.0, abs=1e-12)
    # Two identical rows a = b = s: IO = ½·(2|Σ s²|)/Σ(2s)² = Σs²/(4Σs²) = 0.25 exactly.
    assert orthogonality_index(np.vstack([s, s])) == pytest.approx(0.25, rel=1e-12)
    # Sign must not cancel: rows s and −0.5 s, x = 0.5 s → ½·2·0.5Σs² / 0.25Σs² = 2.
    assert orthogonality_index(np.vstack([s, -0.5 * s])) == pytest.approx(2.0, rel=1e-12)


def test_pcc_oracle():
    a = np.sin(np.linspace(0, 20, 500))
    assert pcc(a, 3 * a + 1) == pytest.approx(1.0)
    assert pcc(a, -a) == pytest.approx(-1.0)
    assert pcc(a, np.ones_like(a)) == 0.0


def test_eemd_is_seeded_and_sums():
    x = np.sin(2 * np.pi * 300 * T[:1000]) + 0.3 * np.sin(2 * np.pi * 40 * T[:1000])
    a = eemd(x, FS, trials=4, seed=3)
    b = eemd(x, FS, trials=4, seed=3)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a.sum(axis=0), x, atol=1e-9)


@pytest.mark.parametrize("bad", [np.array([1.0, np.nan] * 50), np.ones(5), np.ones((2, 50))])
def test_bad_input_raises(bad):
    with pytest.raises(ValueError, match="emd"):
        emd(bad, FS)
