"""Experimental-style NSI from a session log (issue 22: ``gvt identify LOG``; analysis/nsi_windows.py,
daq/studies/identify/log.py).

Data: beam_ch4_sim (tip cubic spring, α = 5e8 N/m³, β = 2) with 20 accelerometers at 4096 Hz, each channel's noise
1 % of the rms of its response to the session's weakest hit; 8 hits 10–150 N, 6 s apart, recorded by the project's
simulator and sensor model into a real MCAP log (bench/bench_identify_log.py's helpers). Oracle: the rig's own α
and β. The kernels are checked against closed forms (sinusoids, their integrals).

Measured on this session: α +9.5 %, β +0.0 %; on other noise seeds of the same 8 hits α +13 % and +18.5 % (β +0.3 %,
+0.6 %), so the 10 % on α holds on this seed, not in general (docs/nsi.md, "Experimental-style NSI from a session
log").

Why 10–150 N: above ~1.5 f_n the one-mode law no longer describes a spring on a beam (the tip tends to pinned; at
300 N the windows read 10.6 Hz where the one-DOF backbone at their δ̄ gives 13.6 Hz: docs/nsi.md), which pulls a
two-parameter fit to β −10 %. Why 6 s apart with 5 s records: each hit then starts from a nearly single-mode tail;
1 s apart, hits landing on a ringing beam left multi-mode windows 10–27 % off the backbone.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from analysis import nsi_windows as nw
from bench.bench_identify_log import CASES, accelerometer_rig, record_session, session_forces
from daq.cli import run as gvt

N_HITS = 8


# ----------------------------------------------------------------------------------------------- kernels
def test_half_cycle_windows_give_the_sinusoid_mean_of_eq_5_2():
    """Windows snapped to δ's zero crossings hold whole half-cycles, so eq. 5.2's mean |δ| is 2A/π at any frequency;
    a fixed window that holds 0.7 of a cycle is off by up to ±20 % depending on its phase."""
    fs, f, amp = 4096.0, 6.3, 2e-3
    t = np.arange(int(3 * fs)) / fs
    d = amp * np.sin(2 * np.pi * f * t + 0.4)
    b = nw.half_cycle_windows(d, fs, 100, d.size - 100, window_s=0.11)
    assert b.shape[0] >= 10 and np.all(b[1:, 0] == b[:-1, 1])  # contiguous, non-overlapping
    half = fs / (2 * f)
    assert np.allclose((b[:, 1] - b[:, 0]) / half, 2, atol=2 / half)  # 0.11 s needs two 79 ms half-cycles
    from analysis.nsi import characteristic_displacement

    dbar = characteristic_displacement(d, b)
    assert np.allclose(dbar, 2 * amp / np.pi, rtol=2e-3)
    fixed = characteristic_displacement(d, nw.fixed_windows(100, d.size - 100, fs, 0.11))
    assert np.ptp(fixed) / (2 * amp / np.pi) > 0.1


def test_window_phase_frequency_of_a_decaying_sinusoid():
    fs, f = 4096.0, 4.4
    t = np.arange(int(5 * fs)) / fs
    a = np.exp(-0.17 * t) * np.cos(2 * np.pi * f * t) + 0.02 * np.cos(2 * np.pi * 23.9 * t)
    lo, hi = int(2.0 * fs), int(2.0 * fs + fs / (2 * f))  # one half-cycle inside a 5 s record
    assert nw.window_phase_hz(a, fs, lo, hi) == pytest.approx(f, rel=5e-3)


def test_to_displacement_integrates_acceleration_by_the_ch5_chain():
    """−a/ω² of a sinusoid, through the chain at 0.24 × its frequency (the seed's 2 Hz for 8.36 Hz): within 0.5 %."""
    fs, f = 2048.0, 4.0
    t = np.arange(int(20 * fs)) / fs
    x = 1e-3 * np.sin(2 * np.pi * f * t)
    acc = -((2 * np.pi * f) ** 2) * x
    s = nw.WindowSettings(0.12, 0.1, 0.1, nw.SEED_INTEGRATION_RATIO * f, None)
    d = nw.to_displacement(np.stack([acc, x, 2 * np.pi * f * 1e-3 * np.cos(2 * np.pi * f * t)], 1), fs,
                           ("acceleration", "displacement", "velocity"), s)  # fmt: skip
    mid = slice(int(5 * fs), int(15 * fs))
    for k in range(3):
        assert np.max(np.abs(d[mid, k] - x[mid])) < 5e-3 * 1e-3


def test_default_settings_scale_the_seeds_choices_to_the_rig():
    s = nw.default_settings(np.array([2.769, 8.362, 14.30]), 1, 0.0006)  # the seed's Ch. 5 wing (Table 5.2)
    assert s.window_s == pytest.approx(0.174, rel=1e-9)  # L1704
    assert s.integration_corner_hz == pytest.approx(2.0, rel=1e-9)  # L1646
    assert s.delta_corner_hz == pytest.approx(math.sqrt(2.769 * 8.362))  # between 1B and the NES, like the seed's 6 Hz
    assert nw.default_settings(np.array([3.8, 23.9]), 0, 0.0006).delta_corner_hz is None


# ----------------------------------------------------------------------------------------------- the log
@pytest.fixture(scope="module")
def session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nsi_log")
    forces = session_forces("beam_ch4_sim", N_HITS)
    rig = accelerometer_rig("beam_ch4_sim", tmp, 0.01, min(forces))
    log = tmp / "session.mcap"
    record_session(rig, log, forces, CASES["beam_ch4_sim"]["spacing"])
    return rig, log


def test_gvt_identify_log_recovers_the_tip_spring(session, tmp_path, capsys):
    """α and β of beam_ch4_sim's tip spring from windowed δ̄ of 8 accelerometer-recorded hits with 1 % noise:
    β within 2.5 %, α within its measured ±30 % (module docstring)."""
    rig, log = session
    png, table = tmp_path / "fdp.png", tmp_path / "windows.csv"
    args = ["identify", str(log), "--rig", rig.path, "--frequency", "pom", "--law", "exact", "--boot", "20",
            "--png", str(png), "--csv", str(table), "--json"]  # fmt: skip
    assert gvt(args) == 0
    doc = json.loads(capsys.readouterr().out)
    fit = doc["fit"]
    # β: within 2.5 % on every session measured (8/12/20 hits, 2-3 noise seeds each; docs/nsi.md). α: +9.5 % on this
    # session, but −24 … +23 % over those sessions — the fit extrapolates α to δ̄ = 1 m from δ̄ ≈ 2e-4–1e-3 m, so
    # dα/α ≈ −ln(δ̄) dβ ≈ 7.5 dβ, and the beam's mode shape change bends Δf² by 1–8 % against the one-DOF backbone
    assert fit["beta"] == pytest.approx(2.0, rel=0.025)
    assert fit["alpha"] == pytest.approx(5e8, rel=0.30)  # the measured spread, not the 10 % (not reached robustly)
    assert fit["r2"] > 0.95 and fit["mode"] == "two-parameter"
    assert doc["windows"] >= 10 * N_HITS and len(doc["hits"]) == N_HITS and all("windows" in h for h in doc["hits"])
    assert doc["window_settings"]["window_s"] == pytest.approx(nw.SEED_WINDOW_PERIODS / 3.8074, rel=1e-3)
    assert png.stat().st_size > 10_000
    rows = list(csv.DictReader(table.open()))
    assert len(rows) == doc["windows"] and {int(r["hit"]) for r in rows} == set(range(N_HITS))
    # windows start after the pulse + one window and are whole half-cycles: the δ̄ of a hit falls as it decays
    t0 = np.array([float(r["t_start_s"]) for r in rows])
    assert t0.min() >= doc["window_settings"]["skip_s"] - 1e-9
    # never over an existing file without --overwrite; with it, both outputs pass the check and the verb goes on to
    # the log (a rig whose sensors are not in it: the next refusal, not "exists", and no second identification)
    assert gvt(args) == 2
    assert "exists" in capsys.readouterr().err
    other_rig = [*args[:3], "lo_store_ch6", *args[4:]]
    assert gvt([*other_rig, "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "sensors are in the log" in err and "exists" not in err, err


def test_gvt_identify_log_bad_input(session, tmp_path, capsys):
    rig, log = session
    other = tmp_path / "x.csv"
    assert gvt(["identify", str(log), "--rig", "lo_store_ch6", "--csv", str(other)]) == 2  # no sensor of that rig in the log
    assert "sensors are in the log" in capsys.readouterr().err
    assert gvt(["identify", str(log), "--rig", rig.path, "--csv", str(other), "--window", "-1"]) == 2
    assert not other.exists()
