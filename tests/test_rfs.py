"""Coulomb friction and viscous dampers in the simulator; the RFS + time-series identification of eq. 5.11
(analysis/rfs.py, daq/studies/identify/rfs.py, ``gvt identify --method rfs``) on the seed's grounded NES (L1633–1660)."""

from __future__ import annotations

import json
import math
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis import rfs
from analysis.model.forces import HalfSine
from analysis.model.loader import ConfigError
from analysis.model.nonlinear import DEFAULT_V_EPS, Damper
from analysis.model.rig import load_rig
from analysis.model.simulate import ImpactSimulator
from analysis.model.structure import build_lumped
from daq.cli import run as gvt

from .conftest import gvt_command

RIG = Path(__file__).resolve().parent.parent / "configs" / "rigs" / "nes_grounded_ch5.toml"
M, K, FC = 0.0908, 75.0, 0.0285  # the NES's mass, k_r and mu_r m g (eq. 5.11, L1653; mass per D1)
TRUTH = {"k": 75.0, "alpha": 9.22e8, "beta": 2.499, "d": 0.35, "mu": 0.0285 / (0.0908 * rfs.G)}


def run(*args, timeout=300):
    """``gvt`` as a real process: kept for the one test here about what a shell sees (exit code, one line, no
    traceback); the rest run the verb in-process (``daq.cli.run``: the same code, exit codes and lines, without
    ~1-2 CPU-s of imports per call)."""
    return subprocess.run([*gvt_command(), *args], capture_output=True, text=True, timeout=timeout)


def _coulomb_oscillator(v_eps: float = DEFAULT_V_EPS) -> ImpactSimulator:
    s = build_lumped(masses=[M], springs=[(0, None, K)], names=["x"])
    return ImpactSimulator(replace(s, dampers=(Damper(0, coulomb=FC, v_eps=v_eps),)), 0, [0])


def test_coulomb_free_decay_matches_the_exact_oscillator():
    """Exact oracle (m x'' + F_c sgn x' + k x = 0): between turning points the motion is a half cycle of the linear
    oscillator about ±F_c/k, so each extremum is 2 F_c/k smaller than the previous (4 F_c/k a cycle), half-cycles last
    pi/omega_n, and the mass stops at the first extremum inside |x| <= F_c/k. With v_eps = 1e-4 m/s (velocities here
    ~0.1 m/s) the decrements agree to 0.1 % (measured 1e-4 rel.; 1e-2 m/s gave 0.4-25 % errors near the stop)."""
    sim = _coulomb_oscillator()
    fs = 32768.0
    res = sim.run(HalfSine(20.0, 0.001), 3.0, fs)
    x, v = res.displacement[0, :, 0], res.velocity[0, :, 0]
    turn = np.nonzero(np.diff(np.sign(v[40:])))[0] + 40  # velocity sign changes after the pulse
    d0 = FC / K
    turn = turn[np.abs(x[turn]) > d0]  # the turning points while it moves (a creep after the stop may add one)
    amp = np.abs(x[turn])
    assert np.allclose(-np.diff(amp), 2 * d0, rtol=1e-3)
    n_exact = math.ceil((amp[0] - d0) / (2 * d0))  # extrema above the band: A_0 - 2 n F_c/k > F_c/k
    assert len(amp) == n_exact
    half = math.pi / math.sqrt(K / M)
    assert np.allclose(np.diff(turn) / fs, half, atol=2.0 / fs)
    stop = turn[-1] + round(half * fs)  # the exact oscillator's last half cycle ends at -(A_L - 2 F_c/k) and sticks
    assert x[stop] == pytest.approx(-np.sign(x[turn[-1]]) * (amp[-1] - 2 * d0), abs=2e-3 * d0)
    assert np.max(np.abs(x[stop:])) <= d0  # inside the band from then on, creeping (regularised sign) at < v_eps
    assert np.mean(np.abs(v[-int(fs) :])) < DEFAULT_V_EPS


def test_energy_budget_closes_with_friction_and_dampers():
    """input work - dissipated = stored energy to rounding, and the dissipation is the dampers' work: on the seed's
    grounded NES (spring, power law, viscous + Coulomb: the 3-row vector Newton) and on two masses with a damper
    between them (``to``) and one to ground; the dissipated energy checked against the integral of f(v) v dt."""
    rig = load_rig(RIG)
    res = rig.simulator.run(rig.hammer_force(236.0), 2.0, rig.sample_rate)
    e = res.energy
    assert e.input_work[0, -1] > 0.1
    assert np.max(np.abs(e.closure_error)) < 1e-9 * e.input_work[0, -1]
    v = res.velocity[0, :, 0]
    damper = rig.structure.dampers[0]
    power = damper.force(v) * v
    work = float(np.sum(0.5 * (power[1:] + power[:-1]))) / rig.sample_rate
    assert e.dissipated[0, -1] == pytest.approx(work, rel=2e-3)
    s = build_lumped(masses=[1.0, 0.5], springs=[(0, None, 1e4), (0, 1, 2e3)], names=["a", "b"])
    s = replace(s, dampers=(Damper(1, viscous=2.0, coulomb=0.5, ref=0), Damper(0, viscous=1.0)))
    two = ImpactSimulator(s, 0, [0, 1]).run(HalfSine(50.0, 0.001), 1.0, 8192.0)
    rel = two.velocity[0, :, 1] - two.velocity[0, :, 0]
    p = Damper(1, viscous=2.0, coulomb=0.5).force(rel) * rel + 1.0 * two.velocity[0, :, 0] ** 2
    assert np.max(np.abs(two.energy.closure_error)) < 1e-9 * two.energy.input_work[0, -1]
    assert two.energy.dissipated[0, -1] == pytest.approx(float(np.sum(0.5 * (p[1:] + p[:-1]))) / 8192.0, rel=5e-3)


def test_damper_config_is_checked(tmp_path):
    text = RIG.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("viscous = 0.35", "viscous = 0.0").replace("coulomb = 0.02850", "coulomb = 0.0"))
    with pytest.raises(ConfigError, match="dampers"):
        load_rig(bad)
    bad.write_text(text.replace('[[dampers]]\ndof = "nes"', '[[dampers]]\ndof = "nes"\nto = "base"'))
    with pytest.raises(ConfigError, match=r"dampers\[0\]\.to"):
        load_rig(bad)


def test_chain_and_slice_fits_recover_exact_values():
    """The chain on a simulated hit's acceleration gives the exact displacement through its two high-passes (what
    the time-series fit compares the model with) to 0.5 % of the peak; the slice fits recover exact laws."""
    s = build_lumped(masses=[M], springs=[(0, None, K)], names=["x"])
    s = replace(s, dampers=(Damper(0, viscous=0.35),))
    fs = 32768.0
    res = ImpactSimulator(s, 0, [0]).run(HalfSine(20.0, 0.001, start=0.1), 2.1, fs)
    chain = rfs.Chain()
    _v, x = chain.integrate(res.acceleration[0, :, 0], fs)
    ref = chain.filter_displacement(res.displacement[0, :, 0], fs)
    assert np.max(np.abs(x - ref)) < 5e-3 * np.max(np.abs(ref))
    law = rfs.Eq511(75.0, 9.22e8, 2.499, 0.35, 0.0285)
    xs = np.linspace(-8e-3, 8e-3, 401)
    k, a, b = rfs.fit_stiffness(xs, law.stiffness_force(xs))
    assert (k, a, b) == pytest.approx((75.0, 9.22e8, 2.499), rel=1e-4)  # beta to the search's xatol 1e-5
    vs = np.linspace(-1.0, 1.0, 400)
    assert rfs.fit_damping(vs, law.damping_force(vs)) == pytest.approx((0.35, 0.0285), rel=1e-9)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A simulated session on the grounded-NES rig: the seed's identification hit then its three validation hits
    (L1656-1660), with the rig's 1 % acceleration and force noise. 2 s apart: the friction stops the NES within each
    record, and the identification reads as with 3 s (measured: k -2.5 %, alpha -1.6 %, beta -0.1 %, d +0.1 %,
    mu -0.8 % at 2 s; -2.3, -2.5, -0.2, +0.2, -0.8 % at 3 s; validation R² >= 0.998 both): each record is the rig's
    2 s either way (cut at the next hit's pre-trigger: 2.0 s, not 2.1 s), the session 8.1 s to simulate and read
    instead of 11.1 s; 1.5 s apart cut the records short (k +6.5 %)."""
    log = tmp_path_factory.mktemp("rfs") / "nes.mcap"
    assert gvt(["simulate", str(RIG), "--forces", "236,114.7,189.7,305.5", "--spacing", "2", "--out", str(log)]) == 0
    return log


def test_identify_rfs_recovers_eq_511_and_validates(session, tmp_path, capsys):
    """From the 236 N hit through the acceleration path (1 % noise): each of k, alpha, beta, d, mu within 5 %; the
    identified model reproduces the 114.7, 189.7 and 305.5 N hits with displacement R² >= 0.95; the written rig
    loads and ``gvt simulate`` runs it."""
    png, toml = tmp_path / "rfs.png", tmp_path / "identified.toml"
    code = gvt(["identify", str(session), "--rig", str(RIG), "--method", "rfs", "--hit", "0", "--validate", "1,2,3",
                "--json", "--png", str(png), "--out", str(toml)])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    rep = json.loads(out.out)
    got = {r["parameter"]: r["optimised"] for r in rep["parameters"]}
    for name, true in TRUTH.items():
        assert got[name] == pytest.approx(true, rel=0.05), name
    assert [v["peak_force_N"] for v in rep["validation"]] == pytest.approx([114.7, 189.7, 305.5], rel=2e-3)
    assert all(v["r2"] >= 0.95 for v in rep["validation"])
    assert rep["identification"]["r2"] >= 0.95
    assert png.stat().st_size > 10_000
    ident = load_rig(toml)
    assert ident.structure.dampers[0].viscous == pytest.approx(got["d"], rel=1e-5)
    assert gvt(["simulate", str(toml), "--out", str(tmp_path / "hit.npz")]) == 0, capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--method", "foo"], "--method 'foo'"),
        (["--validate", "a,b"], "--validate"),
        (["--hit", "9"], "--hit 9"),
        (["--rig", "two_dof"], "one grounded DOF"),
    ],
)
def test_identify_rfs_bad_input_is_one_line_exit_2(session, args, message, capsys):
    """In-process: run() maps each error to the line and exit code a shell sees (the real process is checked by
    test_identify_rfs_missing_log_and_directory)."""
    base = ["identify", str(session), "--rig", str(RIG), "--method", "rfs"]
    if "--rig" in args:
        base = [*base[:3], args[1], *base[4:]]
        args = []
    code = gvt([*base, *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_identify_rfs_missing_log_and_directory(tmp_path, capsys):
    """A missing log as a real ``gvt`` process (exit 2 seen by the shell, one line, no traceback); a directory
    in-process, the same mapping."""
    p = run("identify", str(tmp_path / "none.mcap"), "--rig", str(RIG), "--method", "rfs")
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr, p.stderr
    assert gvt(["identify", str(tmp_path), "--rig", str(RIG), "--method", "rfs"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
