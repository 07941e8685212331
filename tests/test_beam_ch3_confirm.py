"""Seed §3.4.2 must-show on the beam_ch3 rig (spec method-wbemd-slowflow.md §6.2).

The seed's Chapter 3 beam (10 EB elements, 1e8 N/m^3 tip spring, 3000 N 1 ms half-sine at the tip, 30 s)
decomposed by WBEMD into four IMFs must (i) be more orthogonal than plain EMD's four (L934: IO 0.0039 vs
0.0164), and (ii) show a 3:1 internal resonance between IMFs 1 and 2 whose slow angle
Φ_{3:1} = 3θ̂_1 − θ̂_2 is non-time-like inside 3 ≤ t ≤ 8 s (eq. 3.19, L969–L986), with 2:1 and 4:1
time-like there. The rig uses 2ζω damping (configs/rigs/beam_ch3.toml → ModalDamping.factor2=True),
which the spec found to reproduce Table 3.2. The 30 s record is simulated at 2 kHz and FIR-decimated ×2
(zero-phase, anti-aliased) to 1 kHz: all four characteristic frequencies lie below 135 Hz, and this
halves plain EMD's time (3.2 s → 0.2 s); bench/eval_beam_ch3.py runs the full 2 kHz record and gives the
same 3:1 interval (5.65–6.66 s) and IMF-1 frequencies to 0.01 Hz.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

import analysis.slowflow as sf
from analysis.wavelet import analytic

pytestmark = pytest.mark.slow

FS_SIM = 2000.0
FS = 1000.0
DURATION_S = 30.0
TABLE_3_2 = {10: 6.95, 15: 5.02, 20: 4.12, 25: 3.86}  # f of NNM 1 [Hz], L1010–L1019
SPEC_RIDGE = {10: 6.85, 15: 4.95, 20: 4.10, 25: 3.85}  # method-wbemd-slowflow.md §6.2 [DERIVED]


@pytest.fixture(scope="session")
def beam_ch3_decomposition(rigs):
    wbemd_mod = pytest.importorskip("analysis.wbemd")
    from analysis.emd import emd, orthogonality_index

    rig = rigs("beam_ch3")
    res = rig.simulator.run(rig.hammer_force(), DURATION_S, FS_SIM)
    x = signal.decimate(res.displacement[0, :, res.output_names.index("w10")], round(FS_SIM / FS), ftype="fir", zero_phase=True)
    cf = wbemd_mod.characteristic_frequencies(x, FS, 4, 2.0, 200.0)
    wb = wbemd_mod.wbemd(x, FS, cf)
    io_emd = orthogonality_index(emd(x, FS, max_imf=4), x)
    return x, wb, io_emd


def test_rig_uses_2_zeta_omega_damping(rigs):
    """The spec's reproduction of Table 3.2 needs the standard 2ζω modal damping, not eq. 3.14 as printed."""
    from analysis.model.structure import ModalDamping

    rig = rigs("beam_ch3")
    omega = np.array([10.0, 20.0])
    d = ModalDamping(zeta=tuple(rig.config.damping.zeta), zeta_rest=rig.config.damping.zeta_rest,
                     factor2=rig.config.damping.factor2)  # fmt: skip
    np.testing.assert_allclose(d.modal_coefficients(omega), 2 * np.array([0.0071, 0.0011]) * omega)


def test_wbemd_gives_four_imfs_more_orthogonal_than_emd(beam_ch3_decomposition):
    x, wb, io_emd = beam_ch3_decomposition
    assert wb.imfs.shape == (4, x.size)
    # NNM 1 (3.8-12 Hz over the record) and NNM 2 (~24-31 Hz) are the two lowest characteristic frequencies
    assert 3.8 < wb.char_freqs_hz[0] < 12.0 and 23.0 < wb.char_freqs_hz[1] < 32.0
    # Seed L934: WBEMD 0.0039 < EMD 0.0164. Our absolute values differ (different EMD engine and stop
    # rule, PyEMD vs emd.m), so the must-show is the ordering, with a margin: WBEMD at most 3/4 of EMD.
    assert wb.orthogonality_index < 0.75 * io_emd, (wb.orthogonality_index, io_emd)


def test_3to1_internal_resonance_is_confirmed_within_3_to_8_s(beam_ch3_decomposition):
    _, wb, _ = beam_ch3_decomposition
    conf = sf.test_ratios(wb.imfs[0], wb.imfs[1], FS, 3, 1, lowpass_hz=1.0)  # 1 Hz low-pass: L961
    assert conf.status == "confirmed" and (conf.m, conf.n) == (3, 1) and conf.bracketed, conf.reason
    assert 3.0 <= conf.start_s < conf.end_s <= 8.0, (conf.start_s, conf.end_s)  # seed: 3 ≤ t ≤ 8 s
    by = {(c.m, c.n): c for c in conf.candidates}
    for ratio in ((1, 1), (2, 1), (4, 1), (5, 1)):
        assert by[ratio].trusted == (), (ratio, by[ratio].intervals)  # all other ratios time-like
    # the captured Φ stays within one loop (small phase range, L986)
    iv = max(by[(3, 1)].trusted, key=lambda v: v.strength)
    assert iv.phase_range < np.pi


def test_imf1_frequency_follows_table_3_2(beam_ch3_decomposition):
    """f̂_1 of IMF 1 (Hilbert, 1 Hz low-pass, L961) for t ≥ 10 s: within 2 % of Table 3.2 (the spec's
    suggested tolerance; the table comes from periodic-solution snapshots, L1010) and within 1 % of the
    spec's independent reproduction (wavelet ridge of a DOP853 run, §6.2) — measured: −1.3/−1.9/−0.9/−0.2 %
    and +0.2/−0.6/−0.4/+0.1 %."""
    _, wb, _ = beam_ch3_decomposition
    f1 = analytic(wb.imfs[0], FS, lowpass_hz=1.0).frequency_hz
    for t, f_tab in TABLE_3_2.items():
        assert f1[round(t * FS)] == pytest.approx(f_tab, rel=0.02), t
        assert f1[round(t * FS)] == pytest.approx(SPEC_RIDGE[t], rel=0.01), t
