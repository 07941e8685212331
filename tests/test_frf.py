"""FRFs, coherence, windows and hammer checks (analysis/frf.py, analysis/hammer.py, ``gvt frf``): issue 20.

Data: simulated sessions of a linear ``beam_ch4_exp`` (its cubic spring removed, order-4 stepping) written
by the project's simulator and sensor model into real logs, read back by ``gvt frf``. Oracle: the rig's
modal model, computed here and nowhere in the estimator: accelerance
``sum_r phi_o phi_i s^2 / (s^2 + 2 sigma_r s + omega_r^2)`` with the window's exact effect (every pole
moved by ``a = 1 / tau``: ``s -> s + a`` in the whole expression; analysis/frf.py ``exponential_window``).

Why order 4 (``simulation.order``): the default 2nd-order midpoint rule shifts mode 6 (965 Hz) by
``(omega h)^2 / 12`` = 2e-4, which at a 0.5 Hz bin moves |H| there by up to 1 % (measured: 1.05 % on a13);
order 4 leaves < 0.5 % at every peak. Why 10 s between hits: the previous hit's mode 1 still rings with
``exp(-0.654 * 10)`` = 0.15 % of its amplitude, which is the ~0.1 % offset seen at mode 1.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from analysis.frf import FRFAccumulator, FRFSet, choose_tau, convert_quantity, remove_window_damping
from analysis.frf_setup import PRE_TRIGGER_S, force_full_scale, lowest_decay_rate
from analysis.hammer import check_hit
from analysis.model.forces import pulse_train
from analysis.model.rig import Rig, channel_signals, load_rig
from analysis.records import HITS_TOPIC, Hit
from daq.cli import run as gvt
from daq.log.reader import LogReader
from daq.studies.simulate.session import SessionPlan, simulate_session
from drivers.sim.sensor_model import AdcModel, channel_models_for, measure

ROOT = Path(__file__).resolve().parents[1]
FORCE = 200.0  # N: a moderate hit, no sensor near its range
SPACING = 10.0  # s between hits (module docstring)
# The two noise-bias tests below judge medians over thousands of lines (every response, 5 Hz-1 kHz) and identities
# that hold at every line (|H2| gamma^2 = |H1|, |H1| <= |H2|); 4 s between hits leaves mode 1 ringing at
# exp(-0.654 * 4) = 7 % of its amplitude into the next record (mode 2, sigma 2.1 /s: 2e-4), which touches only the
# few lines around 21 Hz: 18 s simulated instead of 42 s, and the medians and identities hold as before.
NOISE_SPACING = 4.0
# Modes above 2 kHz (mode 9 on, 2238 Hz and up) simulated by the residual vectors' static part only: the oracle's
# modal model keeps every mode, and at the first six peaks (<= 965 Hz) what the static part leaves out of a mode at
# f_r is ~(f / f_r)^4 <= 4 % of its residue against a peak of residue / (2 zeta) = 100 residues, < 0.05 %; the medians
# of the noise tests moved by < 0.1 % (measured). A session then costs ~3/4 of the 5 kHz rig's.
CUTOFF_HZ = 2000.0


def linear_rig(tmp: Path, noise: float, force_noise: float) -> Rig:
    """beam_ch4_exp without its cubic spring, order 4, modes to ``CUTOFF_HZ``, each channel's noise ``noise`` (the
    hammer's ``force_noise``) times the rms of its noise-free response to one ``FORCE`` hit over a record."""
    src = (ROOT / "configs/rigs/beam_ch4_exp.toml").read_text()
    txt = re.sub(r"\[\[nonlinear_springs\]\].*?(?=\n\[)", "", src, flags=re.S).replace("seed = 2", "seed = 2\norder = 4")
    txt = txt.replace("modal_cutoff_hz = 5000.0", f"modal_cutoff_hz = {CUTOFF_HZ}")
    path = tmp / "beam_ch4_exp_linear.toml"
    path.write_text(txt)
    rig = load_rig(path)
    res = rig.simulator.run(rig.hammer_force(FORCE), rig.config.daq.record_length, rig.sample_rate)
    rms = np.sqrt((channel_signals(rig, res)[1] ** 2).mean(axis=0))
    names = ["hammer", *[s.name for s in rig.sensors]]
    lines, cur = [], None
    for ln in txt.split("\n"):
        m = re.match(r'name = "(a\d\d)"', ln)
        cur = names.index(m.group(1)) if m else (0 if ln.startswith("[hammer]") else cur)
        if ln.startswith("noise_rms"):
            ln = f"noise_rms = {(force_noise if cur == 0 else noise) * rms[cur]:.6g}"
        lines.append(ln)
    path.write_text("\n".join(lines))
    return load_rig(path)


def session(tmp: Path, noise: float, force_noise: float, forces: tuple[float, ...], spacing: float = SPACING) -> tuple[Rig, Path]:
    rig = linear_rig(tmp, noise, force_noise)
    log = tmp / "session.mcap"
    plan = SessionPlan(forces=forces, pre_trigger=0.1, spacing=spacing, tail=2.0, block_size=1024)
    simulate_session(rig, log, plan, seed=3)
    return rig, log


def shared_session(tmp_path_factory: pytest.TempPathFactory, noise: float, force_noise: float,
                   forces: tuple[float, ...]) -> tuple[Rig, Path]:  # fmt: skip
    """``session()`` simulated once per test run for every test file that asks for the same one (tests/test_frf.py,
    test_modal_cmd.py, test_modes_view.py share the five 200 N hits and the overload; test_frf_lane.py and
    test_report.py the three and the overload): each costs 3-5 CPU-s to simulate. The first asker simulates it
    under an exclusive file lock, the others wait and read the same files; under pytest-xdist the directory is the
    run's base temporary directory that every worker shares (the parent of each worker's own), pytest-xdist's
    documented way to run a fixture once. The simulation is deterministic (seed 3), so which file asks first does
    not change the data; the tests only read the log and the rig."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    key = hashlib.sha256(repr((noise, force_noise, tuple(map(float, forces)), SPACING)).encode()).hexdigest()[:12]
    where = root / f"frf_session_{key}"
    with open(root / f"frf_session_{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (where / "done").exists():
            shutil.rmtree(where, ignore_errors=True)  # an attempt that failed half-way
            where.mkdir()
            session(where, noise, force_noise, forces)
            (where / "done").write_text("")
    return load_rig(where / "beam_ch4_exp_linear.toml"), where / "session.mcap"


def analytic_accelerance(rig: Rig, freq: np.ndarray, outputs: list[str], a: float) -> np.ndarray:
    """(n_out, n_f) windowed accelerance of the rig's modal model, force at the hammer (module docstring)."""
    modes = rig.modes
    sigma = rig.structure.damping.modal_coefficients(modes.omega) / 2.0
    dofs = [next(s.dof for s in rig.sensors if s.name == o) for o in outputs]
    res = modes.shapes[dofs, :] * modes.shapes[rig.hammer.dof, :]
    s = 2j * np.pi * freq + a
    den = s[None, :] ** 2 + 2.0 * sigma[:, None] * s[None, :] + modes.omega[:, None] ** 2
    return (res[:, :, None] / den[None]).sum(axis=1) * s**2


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """1 % noise, five 200 N hits, then one 3000 N hit that overloads the 2224 N hammer."""
    return shared_session(tmp_path_factory, 0.01, 0.01, (FORCE,) * 5 + (3000.0,))


def test_gvt_frf_matches_the_modal_model_at_the_first_six_peaks(clean, tmp_path, capsys):
    rig, log = clean
    npz, png = tmp_path / "frf.npz", tmp_path / "frf.png"
    assert gvt(["frf", str(log), "--json", "--out", str(npz), "--plot", str(png)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["averages"] == 5 and [h["verdict"] for h in doc["hits"]] == ["accepted"] * 5 + ["refused"]
    assert doc["hits"][5]["reason"].startswith("overload: force reached its full scale 2224 N")
    assert png.stat().st_size > 10_000
    frf = FRFSet.from_npz(npz)  # the contract file, read back
    assert frf.H.shape == (14, 1, frf.freq.size) and frf.units == "m/s^2/N" and frf.kind == "H1"
    tau = frf.window["tau_s"]
    # the window rule: the lowest mode decays to 1e-3 over the 2 s record
    assert np.exp(-(lowest_decay_rate(rig) + 1 / tau) * doc["record_s"]) == pytest.approx(1e-3, rel=1e-9)
    ha = analytic_accelerance(rig, frf.freq, frf.outputs, frf.window["sigma_added"])
    pk = frf.peaks(6)
    fn = rig.modes.frequencies_hz[:6]
    assert np.all(np.abs(frf.freq[pk] - fn) <= 0.5), (frf.freq[pk], fn)  # one bin (0.5 Hz)
    err = np.abs(frf.H[:, 0, pk]) / np.abs(ha[:, pk]) - 1
    assert np.abs(err).max() < 0.01, np.round(err * 100, 2)
    assert frf.coherence[:, 0, pk].min() >= 0.99
    # the peak table carries the same numbers
    row = next(r for r in doc["peaks"] if r["response"] == "a14" and r["freq_hz"] == frf.freq[pk[0]])
    assert row["mag"] == pytest.approx(abs(frf.H[13, 0, pk[0]]))


def test_mobility_and_receptance_are_accelerance_over_jw(clean):
    rig, log = clean
    reader = LogReader(log)
    fs, n = rig.sample_rate, round(2.0 * rig.sample_rate)
    hit = Hit.from_json(reader.json_messages(HITS_TOPIC)[0])
    pre = round(PRE_TRIGGER_S * fs)
    d = reader.read_stream("dev0", start=(hit.index - pre) / fs, end=(hit.index - pre + n) / fs).data.astype(float)
    acc = FRFAccumulator(fs, n, [s.name for s in rig.sensors], "hammer", tau=0.357, t0=pre / fs, f_max=1000.0)
    acc.add(d[:, 0], d[:, 1:])
    a, v, x = (acc.frf("H1", q) for q in ("accelerance", "mobility", "receptance"))
    jw = 2j * np.pi * a.freq[1:]
    np.testing.assert_allclose(v.H[..., 1:] * jw, a.H[..., 1:], rtol=1e-12)
    np.testing.assert_allclose(x.H[..., 1:] * jw**2, a.H[..., 1:], rtol=1e-12)
    assert v.units == "m/s/N" and x.units == "m/N" and x.H[..., 0].max() == 0  # DC of an integrated FRF: 0
    np.testing.assert_allclose(convert_quantity(x.H, x.freq, "receptance", "accelerance")[..., 1:], a.H[..., 1:], rtol=1e-12)


def test_window_damping_is_removed_exactly():
    """A pole at 20.81 Hz, zeta 0.005, seen through tau = 0.357 s: the windowed FRF's pole has the same damped
    frequency and sigma + 1/tau (the identity of exponential_window); removing 1/tau gives the pole back."""
    wn, z, a = 2 * np.pi * 20.81, 0.005, 1 / 0.357
    wd, sig = wn * np.sqrt(1 - z**2), z * wn + a
    wn_w = np.hypot(wd, sig)
    f, zeta = remove_window_damping(np.array([wn_w / (2 * np.pi)]), np.array([sig / wn_w]), a)
    assert f[0] == pytest.approx(20.81, rel=1e-12) and zeta[0] == pytest.approx(0.005, rel=1e-9)
    assert sig / wn_w > 4 * z  # the window more than quadruples mode 1's damping: removing it is not optional
    assert choose_tau(10.0, 2.0, 1e-3) is None  # a structure that decays alone gets no window


def accumulate_hits(rig: Rig, log: Path) -> tuple[FRFAccumulator, float, list[str], list[np.ndarray]]:
    """Every hit of ``log`` into one accumulator (2 s records from 10 ms before each hit, the rig's tau): the
    accumulator, tau, the responses and each hit's raw force record."""
    fs, n, pre = rig.sample_rate, round(2.0 * rig.sample_rate), round(PRE_TRIGGER_S * rig.sample_rate)
    tau = choose_tau(lowest_decay_rate(rig), 2.0)
    reader = LogReader(log)
    outs = [s.name for s in rig.sensors]
    acc = FRFAccumulator(fs, n, outs, "hammer", tau=tau, t0=pre / fs, f_max=1000.0)
    raw = []
    for h in reader.json_messages(HITS_TOPIC):
        i0 = h["index"] - pre
        d = reader.read_stream("dev0", start=i0 / fs, end=(i0 + n) / fs).data.astype(float)
        acc.add(d[:, 0], d[:, 1:])
        raw.append(d[:, 0])
    return acc, tau, outs, raw


def test_ten_percent_response_noise_biases_h2_up_not_h1(tmp_path):
    """Theory (Bendat & Piersol §9.2): noise on the response only leaves H1 unbiased and makes
    ``|H2| = |H1| / gamma^2`` too high. Where the response noise matters (coherence < 0.9: near
    antiresonances and between modes) H2's median excess is large and H1's median ratio stays near 1;
    at the peaks the coherence is >= 0.99 even at 10 % noise, so there the bias (< 1 %) is smaller than H1's
    random error with 5 averages (up to 4 % measured), and H1 can land on either side of the model."""
    rig, log = session(tmp_path, 0.10, 0.0, (FORCE,) * 5, spacing=NOISE_SPACING)
    acc, tau, outs, _ = accumulate_hits(rig, log)
    H1, H2 = acc.frf("H1"), acc.frf("H2")
    ha = analytic_accelerance(rig, H1.freq, outs, 1 / tau)
    g = H1.coherence[:, 0]
    low = (g < 0.9) & (H1.freq > 5)[None, :]
    r1, r2 = np.abs(H1.H[:, 0]) / np.abs(ha), np.abs(H2.H[:, 0]) / np.abs(ha)
    assert low.sum() > 100
    assert np.median(r2[low]) > 1.3, np.median(r2[low])
    assert 0.9 < np.median(r1[low]) < 1.1, np.median(r1[low])
    np.testing.assert_allclose(r2 * g, r1, rtol=1e-9)  # |H2| = |H1| / gamma^2 at every line
    pk = H1.peaks(6)
    assert np.all(r2[:, pk] >= r1[:, pk])


def test_force_noise_is_cut_by_the_force_window(tmp_path):
    """The other half of the theory (Bendat & Piersol §9.2): noise on the force makes H1 too low by gamma^2 and
    leaves H2 unbiased. The force window (the pulse plus one width, cosine taper) keeps the force record only where
    the hammer acts (~2 ms of the 2 s), so force noise at 100 % of the record's force rms hardly reaches the spectra:
    measured median coherence 0.999, H1 within 0.3 % of the model; without the window that noise would dominate."""
    rig, log = session(tmp_path, 0.0, 1.0, (FORCE,) * 5, spacing=NOISE_SPACING)
    fs = rig.sample_rate
    acc, tau, outs, raw = accumulate_hits(rig, log)
    H1, H2 = acc.frf("H1"), acc.frf("H2")
    ha = analytic_accelerance(rig, H1.freq, outs, 1 / tau)
    g = H1.coherence[:, 0]
    band = (H1.freq > 5)[None, :].repeat(len(outs), 0)
    r1 = np.abs(H1.H[:, 0]) / np.abs(ha)
    assert np.median(g[band]) > 0.99 and abs(np.median(r1[band]) - 1) < 0.02, (np.median(g[band]), np.median(r1[band]))
    assert np.all(np.abs(H1.H[:, 0]) <= np.abs(H2.H[:, 0]) * (1 + 1e-9))  # |H1| = gamma^2 |H2|
    # the noise is there: outside the pulse the raw force record is noise of about the record's force rms
    quiet = np.concatenate([r[round(0.5 * fs) :] for r in raw])
    assert np.std(quiet) > 0.5 * np.sqrt(np.mean(np.concatenate(raw) ** 2)) / 2


# --- hammer checks ------------------------------------------------------------------------------------------
def force_record(rig: Rig, times, peaks, duration=0.001, seed=0) -> np.ndarray:
    """One hit's hammer channel through the project's force model (pulse_train) and sensor/ADC model."""
    fs = rig.sample_rate
    t = np.arange(round(2.0 * fs)) / fs
    ft = pulse_train(times, peaks, duration)
    phys = np.interp(t, ft.t, ft.force, left=0.0, right=0.0)[:, None]
    adc = AdcModel(rig.config.daq.adc_bits, rig.config.daq.input_range_volts)
    return measure(phys, channel_models_for([rig.hammer]), adc, np.random.default_rng(seed)).data[:, 0].astype(float)


@pytest.fixture(scope="module")
def exp_rig():
    return load_rig(ROOT / "configs/rigs/beam_ch4_exp.toml")


def test_clean_hits_pass_and_pyfrf_is_compared(exp_rig):
    """20 clean hits (50-1500 N, each its own noise) are accepted with a 10x margin on the rise threshold.
    pyFRF 1.5.0's spectral test (default limit 1e-3) on the same records: it flags none of them here either,
    but its ratio for a clean hit is 6.5e-4 to 7.3e-4, within 1.5x of its limit (the issue's "20 of 20
    flagged" came from other records; not reproduced on these); it does flag the 50 % double hit."""
    pyFRF = pytest.importorskip("pyFRF")
    fs, full = exp_rig.sample_rate, force_full_scale(exp_rig)
    forces = np.linspace(50.0, 1500.0, 20)
    checks = [check_hit(force_record(exp_rig, [0.01], [p], seed=k), fs, 1000.0, full) for k, p in enumerate(forces)]
    assert [c.verdict for c in checks] == ["accepted"] * 20, [c.reason for c in checks]
    assert max(c.rise_db for c in checks) < 0.2  # 10x below the 2 dB threshold
    assert all(1000.0 < c.bw10_hz < 1040.0 and 1280.0 < c.bw20_hz < 1320.0 for c in checks)  # half-sine: 1.02/T, 1.30/T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frf = pyFRF.FRF(int(fs), exc=np.zeros(100), resp=np.zeros(100))
        flagged = sum(bool(frf._is_double_impact(force_record(exp_rig, [0.01], [p], seed=k))) for k, p in enumerate(forces))
        double = bool(frf._is_double_impact(force_record(exp_rig, [0.01, 0.013], [300.0, 150.0])))
    assert flagged == 0 and double


def test_double_hit_overload_and_soft_tip_are_refused_with_the_reason(exp_rig):
    fs, full = exp_rig.sample_rate, force_full_scale(exp_rig)
    double = check_hit(force_record(exp_rig, [0.01, 0.013], [300.0, 150.0]), fs, 1000.0, full)
    assert double.verdict == "refused" and "double hit" in double.reason and "3.0 ms later" in double.reason
    late = check_hit(force_record(exp_rig, [0.01, 0.03], [300.0, 90.0]), fs, 200.0, full)  # 20 ms, band 200 Hz
    assert late.reason.startswith("double hit") and "overload" not in late.reason and "bandwidth" not in late.reason
    over = check_hit(force_record(exp_rig, [0.01], [3000.0]), fs, 900.0, full)
    assert over.verdict == "refused" and over.reason.startswith("overload: force reached its full scale 2224 N")
    assert "double hit" not in over.reason  # a clipped (flat-topped) pulse is not a double hit
    soft = check_hit(force_record(exp_rig, [0.01], [300.0], duration=0.003), fs, 1000.0, full)
    assert soft.reason.startswith("bandwidth below band: -10 dB at 3") and soft.bw10_hz == pytest.approx(1.02 / 0.003, rel=0.02)


def test_pyfrf_h1_agrees_on_the_same_windowed_records(clean):
    """pyFRF's H1 over the same five records, windowed by us (pyFRF's own windows differ: its force window has
    no taper and it scales the FRF by ``frf_norm = sum(w_force)/sum(w_exp)``, an amplitude correction meant for
    periodic signals that is wrong for a transient), agrees with ours to rounding."""
    pyFRF = pytest.importorskip("pyFRF")
    from analysis.frf import exponential_window, force_window

    rig, log = clean
    fs, n, pre = rig.sample_rate, round(2.0 * rig.sample_rate), round(PRE_TRIGGER_S * rig.sample_rate)
    tau = choose_tau(lowest_decay_rate(rig), 2.0)
    reader = LogReader(log)
    outs = [s.name for s in rig.sensors]
    acc = FRFAccumulator(fs, n, outs, "hammer", tau=tau, t0=pre / fs, f_max=1000.0)
    w = exponential_window(n, fs, tau, pre / fs)
    exc, resp = [], []
    for h in reader.json_messages(HITS_TOPIC)[:5]:
        i0 = h["index"] - pre
        d = reader.read_stream("dev0", start=i0 / fs, end=(i0 + n) / fs).data.astype(float)
        acc.add(d[:, 0], d[:, 1:])
        exc.append(d[:, 0] * force_window(d[:, 0], fs) * w)
        resp.append((d[:, 1:] * w[:, None]).T)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = pyFRF.FRF(int(fs), exc=np.array(exc), resp=np.array(resp), window="none", resp_type="a")
        theirs = p.get_FRF("H1", frf_form="accelerance")[:, 0, : acc.n_f]
        coh = p.get_coherence()[:, : acc.n_f]
    ours = acc.frf("H1")
    np.testing.assert_allclose(theirs[:, 1:], ours.H[:, 0, 1:], rtol=1e-9)
    np.testing.assert_allclose(coh[:, 1:], ours.coherence[:, 0, 1:], atol=1e-9)


def test_a_response_excluded_on_a_hit_is_averaged_over_the_other_hits_only(clean):
    """A clipped accelerometer on one hit (the gate's ``excluded_channels``) must not enter that output's average:
    the output is the average of the hits it was good on, the other outputs keep every hit."""
    rig, log = clean
    r = LogReader(log)
    stream = next(iter(r.streams()))
    d = r.read_stream(stream)
    cols = ["hammer", *[s.name for s in rig.sensors]]
    idx = [d.channels.index(c) for c in cols]
    hits = [Hit.from_json(h) for h in r.json_messages(HITS_TOPIC)][:3]
    fs, n = rig.sample_rate, 2 * int(rig.sample_rate)
    pre = round(PRE_TRIGGER_S * fs)
    recs = [d.data[h.index - pre : h.index - pre + n][:, idx].astype(float) for h in hits]
    bad = recs[1].copy()
    bad[:, 5] = np.clip(bad[:, 5], -0.2, 0.2)  # a05 clipped on hit 1
    kw = dict(tau=0.357, t0=pre / fs, f_max=1000.0)
    outs = cols[1:]
    mixed = FRFAccumulator(fs, n, outs, "hammer", **kw)
    for k, rec in enumerate([recs[0], bad, recs[2]]):
        mixed.add(rec[:, 0], rec[:, 1:], use=[not (k == 1 and o == "a05") for o in outs])
    all3, two = FRFAccumulator(fs, n, outs, "hammer", **kw), FRFAccumulator(fs, n, outs, "hammer", **kw)
    for rec in recs:
        all3.add(rec[:, 0], rec[:, 1:])
    for rec in (recs[0], recs[2]):
        two.add(rec[:, 0], rec[:, 1:])
    m, a, t = mixed.frf(), all3.frf(), two.frf()
    o = outs.index("a05")
    assert m.window["averages_per_output"][o] == 2 and m.n_averages[0] == 3 and sum(m.window["averages_per_output"]) == 3 * 14 - 1
    np.testing.assert_allclose(m.H[o], t.H[o], rtol=1e-12)  # a05: the two good hits only
    others = [k for k in range(len(outs)) if k != o]
    np.testing.assert_allclose(m.H[others], a.H[others], rtol=1e-12)  # the rest: all three
    clipped = FRFAccumulator(fs, n, outs, "hammer", **kw)
    for rec in [recs[0], bad, recs[2]]:
        clipped.add(rec[:, 0], rec[:, 1:])
    pk = a.peaks(1)
    assert abs(clipped.frf().H[o, 0, pk] / a.H[o, 0, pk] - 1).max() > 1e-3  # what the exclusion prevents
    none = FRFAccumulator(fs, n, outs, "hammer", **kw)
    none.add(recs[0][:, 0], recs[0][:, 1:], use=[oo != "a05" for oo in outs])
    assert np.isnan(none.frf().H[o]).all() and not np.isnan(none.frf().H[others]).any()
