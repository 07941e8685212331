"""Every mode ``gvt modal`` reports says how far to trust it (issue 29 item 2), and UFF 58 states its window (item 8).

Data, cheapest first, each with an oracle that does not come from the code under test:

* measured FRFs of a real free-free beam (pyuff's ``data/meas_point_*.txt``, tests/data/pyuff_meas_points/README.md:
  one accelerometer, three hammer points): the oracle is the FRFs' own peaks, found by eye-equivalent peak
  picking of ``sum |H|`` (a mode is where every measured FRF peaks);
* the FRF matrix of ``gvt record configs/sessions/sim_roving.toml`` (tests/data/sim_roving_frf.npz, made as its
  README says): 200 N hits on the nonlinear ``beam_ch4_exp`` 2.5 s apart, so modes 1-2 still ring from the previous
  hit and the cubic spring distorts them -- on main this gave 13 "modes" and paired three of them with FE mode 1;
* ``replay_logs/beam_ch4_exp_weak.mcap`` (one 30 N hit on the same nonlinear rig: the linear regime the demo's
  mixed-level FRFs are not) and ``..._strong.mcap`` (1583 N: strongly nonlinear);
* synthetic FRFs of a modal model (``analysis.lsfd.modal_frf``) with two modes 1 % apart;
* pairing cases built by hand, where the right answer is known.

The FE oracle is the rig's own model (``Rig.modes``). Tolerance 0.1 % in frequency is the issue's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis.frf import FRFSet
from analysis.lsfd import modal_frf
from analysis.mac import mac
from analysis.modal_id import identify_arrays
from analysis.modal_pairing import pair_modes
from daq.cli import run as gvt

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).resolve().parents[1]


def _peaks(freq: np.ndarray, H: np.ndarray, rel: float = 0.01) -> np.ndarray:
    """Lines where sum |H| over all FRFs is a local maximum standing ``rel`` of the largest above its neighbours."""
    from scipy.signal import find_peaks

    a = np.abs(H).reshape(-1, freq.size).sum(axis=0)
    k, _ = find_peaks(a, prominence=rel * a.max())
    return freq[k]


def test_real_beam_roving_hammer_finds_every_peak_and_no_false_mode():
    """The issue's case: on main the automatic pick missed the largest mode (959 Hz) and reported one at 900.9 Hz.
    Now each identified mode sits within one line (1 Hz) of a peak of the measured FRFs, every peak has its mode,
    and the 900.9 Hz pole is left out as spurious (it explains 32 % of the FRFs there)."""
    H = np.array([np.genfromtxt(DATA / "pyuff_meas_points" / f"meas_point_{i}.txt", dtype=complex) for i in (1, 2, 3)])
    H = H[None]  # one response, three references (the hammer points)
    freq = np.arange(H.shape[-1], dtype=float)  # 0..1000 Hz, 1 Hz lines (the README's abscissa)
    res = identify_arrays(freq, H, "accelerance", 2.0, 1000.0)
    peaks = _peaks(freq, H)
    assert peaks.size == 6, peaks  # 52, 142, 279, 460, 687, 959 Hz
    assert res.freq_hz.size == 6, res.freq_hz
    # physics: a free-free Euler-Bernoulli beam's frequencies stand as (beta_n L)^2 (Blevins, Formulas for Natural
    # Frequency and Mode Shape, table 8-1); the identified ones do within 0.5 % (the 1 Hz lines: 2 % of mode 1)
    beta = np.array([4.73004, 7.85320, 10.99561, 14.13717, 17.27876, 20.42035])
    np.testing.assert_allclose(res.freq_hz / res.freq_hz[0], (beta / beta[0]) ** 2, rtol=5e-3)
    np.testing.assert_array_less(np.abs(res.freq_hz - peaks), 1.0)  # the lines are 1 Hz apart
    assert not any(res.flags), res.flags
    gone = [r for r in res.rejected if abs(r["freq_hz"] - 900.9) < 0.5]
    assert gone and gone[0]["reason"].startswith("spurious"), res.rejected


@pytest.fixture(scope="module")
def sim_roving():
    from analysis.model.rigs import open_rig

    with np.load(DATA / "sim_roving_frf.npz") as z:
        meta = json.loads(str(z["meta"]))
        H = z["H"].astype(complex)
        frf = FRFSet(freq=z["freq"], H=H, coherence=np.ones(H.shape), outputs=meta["outputs"],
                     references=meta["references"], quantity=meta["quantity"], kind=meta["kind"], units=meta["units"],
                     n_averages=np.asarray(meta["n_averages"]), window={"sigma_added": meta["sigma_added"]})  # fmt: skip
    return open_rig("beam_ch4_exp"), frf, meta["driving"]


def test_roving_log_gives_fe_modes_1_to_6_one_to_one(sim_roving):
    """sim_roving.toml's FRFs: modes 1-6 within 0.1 % of the FE model, each FE mode paired once, no other mode in
    the table (main: 13 modes, FE mode 1 paired with 20.8, 21.1 and 110.8 Hz, a 148 Hz pole with FE mode 7 at
    1339 Hz). The poles left out are listed with a reason: the 21.06 Hz pole as a duplicate of mode 1, the
    148 Hz one as spurious."""
    from daq.studies.modal import modal_from_frf

    rig, frf, driving = sim_roving
    run = modal_from_frf(frf, rig, 2.0, 1000.0, driving=driving)
    assert [r["fe_mode"] for r in run.rows] == [1, 2, 3, 4, 5, 6], [(r["freq_hz"], r.get("fe_mode")) for r in run.rows]
    for r in run.rows:
        assert abs(r["freq_error"]) < 1e-3 and r["mac"] > 0.99 and not r["flags"], r
    assert run.warnings == []
    left = {round(x["freq_hz"]): x["reason"].split(":")[0].split(" ")[0] for x in run.result.rejected}
    assert left[21] == "duplicate" and left[148] == "spurious", left


def test_weak_hit_log_linear_regime_gives_fe_modes_within_0p1_percent(tmp_path, capsys):
    """The demo's rig in its linear regime (one 30 N hit): gvt modal's table is FE modes 1-6, one to one, within
    0.1 %, every row "ok", no warning; the modes file carries the same quality figures."""
    modes = tmp_path / "m.json"
    assert gvt(["modal", str(ROOT / "replay_logs/beam_ch4_exp_weak.mcap"), "--json", "--modes-out", str(modes)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [r["fe_mode"] for r in doc["modes"]] == [1, 2, 3, 4, 5, 6]
    for r in doc["modes"]:
        assert abs(r["freq_error"]) < 1e-3 and r["flags"] == [] and r["stability"] >= 12 and r["contribution"] > 0.9, r
    assert doc["warnings"] == []
    saved = json.loads(modes.read_text())
    assert saved["modes"] == doc["modes"] and len(saved["freq_hz"]) == 6


def test_strong_hit_log_is_warned_not_paired_wrongly(capsys):
    """1583 N on the hardening spring: mode 1 rings at 29.7 Hz (+43 % from FE). Main paired it with FE mode 1 without
    a word and paired a 71.7 Hz pole with FE mode 1 as well (+245 %). Now no pair is past the 30 % gate, every pair
    past 5 % or any unpaired mode is flagged, and the warnings name FE mode 1 as not identified."""
    assert gvt(["modal", str(ROOT / "replay_logs/beam_ch4_exp_strong.mcap"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    paired = [r["fe_mode"] for r in doc["modes"] if r["fe_mode"] is not None]
    assert len(paired) == len(set(paired)) and 1 not in paired
    for r in doc["modes"]:
        if r["fe_mode"] is None or abs(r["freq_error"]) > 0.05:
            assert r["flags"], r
        else:
            assert abs(r["freq_error"]) <= 0.30
    assert any(w.startswith("FE mode 1 (20.81 Hz) has no identified partner") for w in doc["warnings"])
    assert any("29.70 Hz" in w and "closest shape: FE mode 1" in w for w in doc["warnings"])


def test_two_modes_one_percent_apart_are_both_resolved():
    """A modal model with modes at 100 and 101 Hz (half-power bandwidths 1 Hz: the peaks overlap), 0.5 % damping,
    random shapes on 8 responses, one reference, 1 % noise: both found within 0.1 %, neither merged nor flagged."""
    rng = np.random.default_rng(4)
    fn, zeta = np.array([100.0, 101.0, 250.0]), np.array([0.005, 0.005, 0.004])
    phi = rng.standard_normal((8, 3))
    freq = np.arange(0.0, 400.0 + 1e-9, 0.25)
    H = modal_frf(freq, 2 * np.pi * fn, zeta, phi, phi[[0]], "accelerance")
    H = H * (1 + 0.01 / np.sqrt(2) * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)))
    res = identify_arrays(freq, H, "accelerance", 20.0, 400.0, driving=[0])
    assert res.freq_hz.size == 3 and res.rejected == [], (res.freq_hz, res.rejected)
    np.testing.assert_array_less(np.abs(res.freq_hz / fn - 1), 1e-3)
    np.testing.assert_array_less(np.abs(res.zeta / zeta - 1), 0.05)
    assert np.all(np.diag(mac(res.shapes, phi)) > 0.99) and not any(res.flags)


# Modal models built to fool the peak check (analysis/modal_select.py step 5): modes the FRFs show although |H| has
# no clean peak of its own, or where the neighbours' terms cancel part of it. Each: (fn Hz, zeta, outputs' constants,
# reference's constants, driving); a constant 1/sqrt(10) gives a peak 10x lower. A weak mode 10x / 30x below its
# neighbour with the same or the other sign, the latter near the share the pick keeps a mode at (0.53-0.57; at 3 % the
# weak mode is a shoulder: no line within 3 of its half-power half-widths is a local maximum of |H|, checked below);
# two modes 1 % apart whose constants have opposite signs in the one FRF (the quadrature bound's worst case, share
# 1.1); a driving point where a mode's constant is 0.02 at the driving output and 1 at the other.
_FOOLING = {
    "weak 10x, 10 % away, driving point": ([100, 110], [0.005, 0.005], [[1, 0.316]], [[1, 0.316]], [0]),
    "weak 10x, 10 % away, other sign": ([100, 110], [0.005, 0.005], [[1, -0.316]], [[1, 0.316]], None),
    "weak 10x, 3 % away, other sign": ([100, 103], [0.005, 0.005], [[1, -0.316]], [[1, 0.316]], None),
    "weak 30x, 12 % away, other sign": ([100, 112], [0.005, 0.005], [[1, -0.183]], [[1, 0.183]], None),
    "weak 30x, 20 % away, driving point": ([100, 120], [0.005, 0.005], [[1, 0.183]], [[1, 0.183]], [0]),
    "two modes 1 % apart, other sign, one FRF": ([100, 101, 250], [0.005, 0.005, 0.004], [[1, -1, 0.7]], [[1, 1, 0.5]], None),
    "low constant at the driving output": ([80, 100, 130], [0.005] * 3, [[1, 0.02, 0.8], [0.6, 1, -0.5]], [[1, 0.02, 0.8]], [0]),
}


@pytest.mark.parametrize("case", list(_FOOLING))
def test_real_modes_beside_stronger_or_close_ones_are_not_flagged_no_peak(case):
    """Each case's modes (the model's truth, 1 % complex noise) are all identified within 0.2 % and none is flagged:
    neither "no peak" nor any other check. Model order 30 (the cases are 2-3 modes) keeps each case near 0.05 s."""
    fn, zeta, phi_out, phi_in, driving = _FOOLING[case]
    fn, zeta = np.asarray(fn, float), np.asarray(zeta, float)
    rng = np.random.default_rng(7)
    freq = np.arange(0.0, 1.6 * fn.max(), 0.25)
    H = modal_frf(freq, 2 * np.pi * fn, zeta, np.asarray(phi_out, float), np.asarray(phi_in, float), "accelerance")
    H = H * (1 + 0.01 / np.sqrt(2) * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)))
    res = identify_arrays(freq, H, "accelerance", 0.2 * fn.min(), freq[-1], max_order=30, driving=driving)
    assert res.freq_hz.size == fn.size, (res.freq_hz, res.rejected)
    np.testing.assert_array_less(np.abs(res.freq_hz / fn - 1), 2e-3)
    assert not any(res.flags), list(zip(res.freq_hz, res.contribution, res.flags, strict=True))
    if case == "weak 10x, 3 % away, other sign":  # the case fools a local-maximum test: |H| has none near 103 Hz
        from analysis.modal_select import local_maxima

        assert not local_maxima(freq, H)[np.abs(freq - 103.0) <= 3 * 0.005 * 103.0].any()


def test_a_pole_standing_for_a_resonance_past_the_band_is_flagged_and_one_inside_is_not():
    """The measured hits' 3000 Hz case rebuilt from a modal model (60, 120 Hz and a third mode; band 10-200 Hz): a
    pole at 199.5 Hz, zeta 1 %, fitted (LSFD) where the model's third mode is at 203 Hz, past the band, is flagged
    "no peak ... widen the band"; the same pole where that mode is at 199.6 Hz, inside the band, is not, nor are the
    modes at 60 and 120 Hz in either."""
    from analysis.lsfd import lsfd
    from analysis.modal_select import contributions, peak_flags

    freq = np.arange(0.0, 260.0, 0.25)
    s = 2 * np.pi * np.array([60.0, 120.0, 199.5]) * (-np.array([0.005, 0.005, 0.01]) + 1j)
    out = {}
    for f3 in (203.0, 199.6):
        H = modal_frf(freq, 2 * np.pi * np.array([60.0, 120.0, f3]), np.array([0.005, 0.005, 0.002]),
                      np.array([[1.0, -0.8, 1.0]]), np.array([[1.0, -0.8, 1.0]]), "accelerance")  # fmt: skip
        fit = lsfd(freq, H, s, "accelerance", 10.0, 200.0)
        out[f3] = peak_flags(freq, H, fit, contributions(freq, H, fit, "accelerance"))
    assert out[203.0][:2] == [[], []] and out[199.6] == [[], [], []], out
    assert out[203.0][2] and "widen the band" in out[203.0][2][0], out


def test_pairing_is_one_to_one_and_gated_on_frequency():
    """Hand-built: two identified modes with FE mode 1's shape (only the nearer in frequency gets it); a mode whose
    shape matches FE mode 3 but 89 % below it in frequency (the roving log's 148 Hz pole vs 1339 Hz) stays
    unpaired; FE mode 2 keeps its own partner."""
    fe = np.eye(4)[:, :3]
    f_fe = np.array([20.8, 68.4, 1339.0])
    shapes = np.column_stack([fe[:, 0], fe[:, 0] + 0.05, fe[:, 1], fe[:, 2] + 0.1])
    f_id = np.array([20.82, 21.06, 68.37, 148.2])
    p = pair_modes(f_id, shapes, f_fe, fe)
    assert p.fe.tolist() == [0, -1, 1, -1]
    assert p.nearest.tolist() == [0, 0, 1, 2] and p.nearest_mac[3] > 0.95
    assert p.unpaired_fe(3) == [2]


def test_uff58_states_the_window_and_sdypy_damping_agrees_once_taken_out(tmp_path, capsys):
    """gvt frf -> gvt modal -> gvt export of the weak-hit log, read back by pyuff and sdypy-EMA 0.31. The FRFs are
    exported as measured, windowed: sdypy-EMA's damping from them is +424 % at mode 1 (the issue's "+197 %" on the
    demo). The file states the window (ID line 3 of each FRF and a dataset 1858 before it) and the export warns;
    with the stated sigma taken out (zeta - sigma/w) sdypy-EMA's damping is within 5 % of gvt modal's for all six
    modes (measured: within 1.4 %, pol_order_high 60; at 30 the 964 Hz mode near the band edge is 16 % off in
    sdypy's own estimate), and each mode shape (55) carries gvt modal's quality figures in its ID line 2."""
    pyuff = pytest.importorskip("pyuff")
    EMA = pytest.importorskip("sdypy.EMA")
    log = ROOT / "replay_logs/beam_ch4_exp_weak.mcap"
    frf, modes, uff = tmp_path / "f.npz", tmp_path / "m.json", tmp_path / "w.uff"
    assert gvt(["frf", str(log), "--out", str(frf)]) == 0
    assert gvt(["modal", str(frf), "--rig", "beam_ch4_exp", "--modes-out", str(modes)]) == 0
    capsys.readouterr()
    assert gvt(["export", str(log), "--binary", "--frf", str(frf), "--modes", str(modes), "--out", str(uff)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert [x for x in said if x.startswith("warning: the FRFs carry the exponential window")], said
    m = json.loads(modes.read_text())
    sigma = m["window_sigma_added"]
    sets = pyuff.UFF(str(uff)).read_sets()
    for k, d in enumerate(sets):
        if d["type"] == 58 and d["func_type"] == 4:
            q = sets[k - 1]
            assert q["type"] == 1858 and q["window_type"] == 6
            assert q["exponential_window_damping_factor"] == pytest.approx(sigma, rel=1e-6)  # E15.7
            assert d["id3"].startswith(f"exp window sigma {sigma:.6g} 1/s")
    shapes = [d for d in sets if d["type"] == 55]
    assert [d["id2"].split()[-1] for d in shapes] == ["ok"] * 6 and all(" FE" in d["id2"] for d in shapes)
    f_gvt, z_gvt = np.array(m["freq_hz"]), np.array(m["zeta"])
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, "blas"):  # order 60 on two busy cores: 14 s with two BLAS threads, 0.3 s with one
        model = EMA.Model(lower=2, upper=1000, pol_order_high=60)
        model.read_uff(str(uff))
        model.get_poles("lscf", show_progress=False)
        model.select_closest_poles(f_gvt, f_window=10)  # f_window 10: see test_modal_id.test_sdypy_ema_agrees
    fn, z_read = np.asarray(model.nat_freq), np.asarray(model.nat_xi)
    np.testing.assert_allclose(fn, f_gvt, rtol=1e-3)
    assert z_read[0] / z_gvt[0] - 1 > 1.0  # the window's damping, read as the structure's
    np.testing.assert_allclose(z_read - sigma / (2 * np.pi * fn), z_gvt, rtol=0.05)


def test_the_assignment_is_scipys_optimum_on_rectangular_gated_costs():
    """analysis/modal_pairing.py assign (csgraph, without importing scipy.optimize into `gvt modal`) reaches the
    same minimum total cost as scipy.optimize.linear_sum_assignment, square and rectangular both ways, with gated
    (1e6) pairs as pair_modes makes them; one pair per row and column."""
    from scipy.optimize import linear_sum_assignment

    from analysis.modal_pairing import assign

    rng = np.random.default_rng(0)
    for n, m in [(3, 5), (5, 3), (6, 6), (1, 4), (4, 1), (13, 10)]:
        for _ in range(30):
            c = rng.random((n, m))
            c[rng.random((n, m)) < 0.3] = 1e6
            r1, c1 = linear_sum_assignment(c)
            r2, c2 = assign(c)
            assert c[r2, c2].sum() == pytest.approx(c[r1, c1].sum(), rel=1e-12)
            assert len(r2) == min(n, m) and np.all(np.diff(r2) > 0) and len(set(c2.tolist())) == len(c2)
