"""Force levels and the linearity check (analysis/frf_levels.py, issue 29 item 1).

Oracle for the linearity check: FRFs written down from a modal model (three modes, accelerance
``sum A_r s^2 / (s^2 + 2 zeta_r omega_r s + omega_r^2)``), so the shift and the height change a test puts in
are known exactly; the check only sees the sampled FRFs (0.5 Hz lines, the rigs' 2 s records).
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.errors import BadInput
from analysis.frf_levels import LinearityCheck, choose_level, level_groups, linearity_check, peak_in

FREQ = np.arange(0.0, 1000.5, 0.5)  # Hz: df 0.5 Hz (2 s records)
MODES = np.array([20.8, 131.0, 367.0])  # Hz
ZETA = 0.025  # the rigs' 0.5 % plus the exponential window's ~2 % at mode 1


def accelerance(freq_hz: np.ndarray, fn: np.ndarray, amp: np.ndarray | None = None) -> np.ndarray:
    """Two outputs (different mode shapes), one reference: (2, 1, n_f)."""
    s = 2j * np.pi * freq_hz
    amp = np.ones(fn.size) if amp is None else amp
    shapes = np.array([[1.0, -0.7, 0.4], [0.5, 0.9, -1.0]])[:, : fn.size]
    w = 2 * np.pi * fn[:, None]
    modal = s**2 / (s**2 + 2 * ZETA * w * s + w**2)  # (n_modes, n_f)
    return ((shapes * amp) @ modal / 1e3)[:, None, :]


def test_level_groups_split_at_gaps_and_ramps():
    # two intended levels (20 N and 200 N, a hand's +-25 % scatter) in mixed order: two groups
    f = np.array([21.0, 190.0, 18.0, 240.0, 24.0, 205.0, 16.5])
    g = level_groups(f)
    assert [x.tolist() for x in g] == [[0, 2, 4, 6], [1, 3, 5]]
    # the demo log's accepted forces: a ramp, cut into pieces of at most 2x, ascending
    demo = np.array([150.0, 400.0, 1000.0, 1300.0, 1583.0])
    g = level_groups(demo)
    assert all(demo[x].max() / demo[x].min() <= 2.0 for x in g)
    assert [x.tolist() for x in g] == [[0], [1], [2, 3, 4]]
    assert np.concatenate(g).size == demo.size
    # one level: one group, whatever the order
    assert [x.tolist() for x in level_groups(np.array([200.0, 210.0, 190.0]))] == [[0, 1, 2]]
    assert level_groups(np.array([])) == []
    with pytest.raises(BadInput):
        level_groups(np.array([100.0, -1.0]))
    with pytest.raises(BadInput):
        level_groups(np.array([100.0, np.nan]))


def test_choose_level_lowest_with_enough_hits():
    g = level_groups(np.array([150.0, 400.0, 1000.0, 1300.0, 1583.0]))
    assert choose_level(g) == 2  # the single 150 N and 400 N hits are too few to average
    assert choose_level(g, min_hits=1) == 0
    assert choose_level(level_groups(np.array([20.0, 21.0, 200.0, 210.0, 220.0]))) == 0
    assert choose_level(level_groups(np.array([20.0, 400.0]))) == 0  # none has enough: the most hits, lowest of a tie
    assert choose_level([]) == -1


def test_peak_interpolation_within_a_tenth_of_a_bin():
    # a peak between lines: the parabola on log |H| finds it to well under df/10 (bin error alone: up to df/2)
    for fn in (20.8, 20.95, 131.13):
        mif = np.abs(accelerance(FREQ, np.array([fn]))).sum(axis=(0, 1))
        k = int(np.searchsorted(FREQ, fn))
        f, _ = peak_in(FREQ, mif, k - 10, k + 10)
        assert abs(f - fn / np.sqrt(1 - 2 * ZETA**2)) < 0.05, (fn, f)  # accelerance peaks at omega_n / sqrt(1 - 2 zeta^2)


def test_linear_levels_pass_with_noise():
    rng = np.random.default_rng(3)
    low = accelerance(FREQ, MODES)
    high = low * (1 + 0.01 * (rng.standard_normal(low.shape) + 1j * rng.standard_normal(low.shape)))
    chk = linearity_check(FREQ, low, high, n_peaks=3)
    assert isinstance(chk, LinearityCheck)
    assert chk.linear, chk.reason
    assert np.allclose(chk.freq_hz, MODES, rtol=0.005)
    assert np.all(np.abs(chk.shift_pct) < 0.2) and np.all(np.abs(chk.ratio_db) < 0.3)
    assert chk.reason.startswith("linear:")


def test_hardening_and_amplitude_drop_are_caught():
    low = accelerance(FREQ, MODES)
    # mode 1 up 3 %, mode 2 down in height by 0.8 (-1.94 dB), mode 3 unchanged
    high = accelerance(FREQ, MODES * np.array([1.03, 1.0, 1.0]), amp=np.array([1.0, 0.8, 1.0]))
    chk = linearity_check(FREQ, low, high, MODES)
    assert not chk.linear
    # shift within 0.3 % of the 3 % put in (0.3 %: a tenth of a bin at 20.8 Hz is 0.24 %)
    assert chk.shift_pct[0] == pytest.approx(3.0, abs=0.3)
    assert chk.ratio_db[1] == pytest.approx(20 * np.log10(0.8), abs=0.15)  # the other modes' tails: < 0.15 dB
    assert abs(chk.shift_pct[2]) < 0.2 and abs(chk.ratio_db[2]) < 0.2
    assert "not linear" in chk.reason and "2 of 3 modes" in chk.reason
    d = chk.as_dict()
    assert d["linear"] is False and len(d["shift_pct"]) == 3


def test_a_peak_moved_far_is_still_its_mode():
    # a hardening spring moves mode 1 by +40 %: found between its neighbours, not missed by a narrow search
    low = accelerance(FREQ, MODES)
    high = accelerance(FREQ, MODES * np.array([1.4, 1.0, 1.0]))
    chk = linearity_check(FREQ, low, high, MODES)
    assert chk.shift_pct[0] == pytest.approx(40.0, abs=1.0)
    assert not chk.linear and "20.8 Hz" in chk.reason


def test_shape_mismatch_is_bad_input():
    with pytest.raises(BadInput):
        linearity_check(FREQ, accelerance(FREQ, MODES), accelerance(FREQ[:-1], MODES))


def test_prominent_peaks_are_scipys_on_noise_and_on_a_mode_indicator():
    """The numpy peak prominence the level check uses (no scipy.signal import in `gvt modal`) equals
    scipy.signal.find_peaks(prominence=0) on every maximum it returns: white noise (ties included, as rounded
    values make them) and a six-mode indicator with 1 % noise."""
    from scipy.signal import find_peaks

    from analysis.frf_levels import prominent_peaks

    rng = np.random.default_rng(3)
    f = np.linspace(0, 1000, 4001)
    mif = sum(1 / np.abs(fn**2 - f**2 + 2j * 0.01 * fn * f) for fn in (21, 68, 194, 387, 645, 964))
    for y in (np.round(rng.normal(size=3000), 1), mif * (1 + 0.01 * rng.normal(size=f.size))):
        idx, prom = prominent_peaks(y)
        ref, props = find_peaks(y, prominence=0.0)
        assert np.array_equal(idx, ref) and np.allclose(prom, props["prominences"])
        for top in (1, 6, 40):  # the early stop keeps exactly scipy's most prominent (no ties in these values)
            idx, prom = prominent_peaks(y, top=top)
            want = set(ref[np.argsort(props["prominences"], kind="stable")[::-1][:top]].tolist())
            got = set(idx[np.argsort(prom, kind="stable")[::-1][:top]].tolist())
            assert got == want or np.allclose(sorted(prom)[-top:], sorted(props["prominences"])[-top:])
    idx, prom = prominent_peaks(mif, top=6)
    assert np.allclose(np.sort(f[idx[np.argsort(prom)[::-1][:6]]]), [21, 68, 194, 387, 645, 964], atol=0.25)
