"""The gvt command line. The verbs' work runs in this process (``daq.cli.run``, which maps every error to the
line and exit code the console script gives: the imports of a child process cost 1-2 CPU-s each); the console
script itself, as a shell runs it, is under test in the usage and help tests at the end."""

from __future__ import annotations

import functools
import json
import subprocess

import numpy as np
import pytest

from .conftest import gvt_command, gvt_in_process

TABLE_3_1 = [3.794, 23.78, 66.60, 130.6, 216.2, 323.9, 454.5, 608.9, 787.3, 978.7]


def run(*args, timeout=300):
    """The installed console script in a child process, as a shell runs it."""
    return subprocess.run([*gvt_command(), *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def gvt(capsys):
    """``gvt`` in this process (conftest.gvt_in_process): returncode, stdout, stderr."""
    return functools.partial(gvt_in_process, capsys)


def test_model_modes_json_prints_the_table_3_1_numbers(gvt):
    p = gvt("model", "modes", "beam_ch3", "--json")
    assert p.returncode == 0, p.stderr
    rep = json.loads(p.stdout)
    f = np.array([m["frequency_hz"] for m in rep["modes"]])
    assert np.all(np.abs(f / TABLE_3_1 - 1) < 1e-3)


def test_model_modes_high_limit(gvt):
    p = gvt("model", "modes", "configs/rigs/beam_ch4_sim.toml", "--json", "--limit", "high", "--count", "4")
    assert p.returncode == 0, p.stderr
    f = np.array([m["frequency_hz"] for m in json.loads(p.stdout)["modes"]])
    assert np.all(np.abs(f / [16.70, 54.11, 112.89, 193.05] - 1) < 5e-3)


def test_model_modes_table_and_bad_limit(gvt):
    p = gvt("model", "modes", "beam_ch4_exp")
    assert p.returncode == 0 and "20.80" in p.stdout and "Guyan" in p.stdout
    bad = gvt("model", "modes", "beam_ch4_exp", "--limit", "middle")
    assert bad.returncode == 2 and "--limit" in bad.stderr


def test_simulate_writes_npz_with_ground_truth(gvt, tmp_path):
    out = tmp_path / "hit.npz"
    p = gvt("simulate", "beam_ch4_exp", "--force", "200", "--duration", "0.5", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "wrote" in p.stdout and out.exists()
    with np.load(out) as z:
        assert z["measured"].shape == (8192, 15) and z["measured"].dtype == np.float32
        assert list(z["channel_names"][:2]) == ["hammer", "a01"]
        assert z["modal_q"].shape[0] == 8192
        closure = (
            z["energy_input_work"]
            - z["energy_dissipated"]
            - (z["energy_kinetic"] + z["energy_potential_linear"] + z["energy_potential_nonlinear"])
        )
        assert np.max(np.abs(closure)) < 1e-6 * z["energy_input_work"][-1]
        # measured = true through the sensor model: within noise + quantisation
        err = np.abs(z["measured"][:, 1:] - z["true"][:, 1:]).max()
        assert err < 0.2  # m/s^2: 0.02 rms noise, 5 sigma << 0.2


def test_simulate_rejects_bad_output_path(gvt, tmp_path):
    p = gvt("simulate", "two_dof", "--out", str(tmp_path / "x.csv"))
    assert p.returncode == 2 and ".npz" in p.stderr
    p = gvt("simulate", "two_dof", "--out", str(tmp_path / "missing" / "x.npz"))
    assert p.returncode == 2 and "does not exist" in p.stderr


def test_demo_runs_and_shows_nnm1_moving_with_energy_and_a_session(gvt, tmp_path):
    out = tmp_path / "demo.mcap"
    p = gvt("demo", "--duration", "2.0", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "NNM1 frequency" in p.stdout and "strong" in p.stdout and "weak" in p.stdout
    assert "hits and verdicts (10 found)" in p.stdout and "double_hit" in p.stdout and "nothing lost" in p.stdout
    from daq.log.reader import LogReader

    assert LogReader(out).report.complete and len(LogReader(out).json_messages("/daq/hits")) == 10
    # issue 29: the demo log's modes are the linear FE modes 1-6, paired one to one, none extra and none flagged
    # (its three 30 N hits are averaged; the 150-1583 N hits, on the cubic spring, are left out and said)
    p = gvt("modal", str(out), "--json")
    assert p.returncode == 0, p.stderr
    modes = json.loads(p.stdout)["modes"]
    assert [m["fe_mode"] for m in modes] == [1, 2, 3, 4, 5, 6] and not any(m["flags"] for m in modes)
    assert max(abs(m["freq_error"]) for m in modes) < 1e-3  # measured 0.04 % at mode 1, the rest <= 0.022 %


@pytest.mark.parametrize("args", [["model"], ["frobnicate"]])
def test_usage_errors_exit_2(args):
    p = run(*args)
    assert p.returncode == 2
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["simulate", "two_dof", "--force", "-5"], "--force"),
        (["model", "modes", "beam_ch3", "--count", "0"], "--count"),
        (["frobnicate"], "No such command"),
    ],
)
def test_bad_values_give_one_line(gvt, args, text):
    p = gvt(*args)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and text in lines[0] and p.stdout == ""


def test_help_exits_zero():
    p = run("model", "modes", "--help")
    assert p.returncode == 0 and "--limit" in p.stdout
