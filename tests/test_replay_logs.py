"""The committed replay logs read, replay and say what their README says."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from daq.fanout import FanOut
from daq.log.reader import LogReader
from daq.log.tools import log_info
from daq.replay import Replayer

from .conftest import gvt_command

LOGS = Path(__file__).resolve().parents[1] / "replay_logs"


@pytest.mark.parametrize("name", ["beam_ch4_exp_strong", "beam_ch4_exp_weak", "two_dof_3hits"])
def test_logs_are_small_complete_and_replay(name):
    p = LOGS / f"{name}.mcap"
    assert p.stat().st_size <= 2 * 1024 * 1024
    info = log_info(p)
    assert info["complete"] and info["streams"][0]["gaps"] == [] and info["streams"][0]["overrun_samples"] == 0
    fan = FanOut()
    sub = fan.subscribe("t", maxsize=100_000)
    stats = Replayer(p, fan).run()
    blocks = list(iter(sub))
    assert stats.samples["dev0"] == info["streams"][0]["samples"] == sum(b.n_samples for b in blocks)
    assert [b.first_index for b in blocks] == sorted(b.first_index for b in blocks)


def test_strong_log_content():
    r = LogReader(LOGS / "beam_ch4_exp_strong.mcap")
    (hit,) = r.json_messages("/sim/hits")
    assert hit["index"] == 1639 and hit["peak_force_N"] == 1583.0
    assert hit["input_energy_J"] == pytest.approx(1.011, rel=0.01)
    d = r.read_stream("dev0", ["hammer"])
    assert np.max(d.data) == pytest.approx(1583.0, rel=0.01)
    kinds = {e["kind"] for e in r.json_messages("/daq/events")}
    assert "overload" in kinds


def test_weak_log_regenerates_to_the_same_samples(tmp_path):
    out = tmp_path / "weak.mcap"
    p = subprocess.run(
        [*gvt_command(), "simulate", "beam_ch4_exp", "--forces", "30", "--duration", "2.0", "--seed", "12", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    a = LogReader(LOGS / "beam_ch4_exp_weak.mcap").read_stream("dev0").data
    b = LogReader(out).read_stream("dev0").data
    assert a.shape == b.shape
    # same seed, same physics: equal to within an ADC step (BLAS rounding may move a code at most)
    lsb = 2 * 10.0 / 2**24 / 1.02e-3
    assert np.max(np.abs(a[:, 1:] - b[:, 1:])) <= 2 * lsb


@pytest.mark.parametrize("name", ["beam_ch4_exp_strong", "beam_ch4_exp_weak"])
def test_format1_logs_still_analyse_like_their_format2_regeneration(name):
    """The logs in tests/data/format1/ (written before issue 19) analyse as the regenerated replay_logs do:
    the same IR events (the samples differ only by ADC quantisation, max 2.3e-3 m/s²)."""
    from daq.studies.analyze.batch import analyze_log

    old = analyze_log(Path(__file__).resolve().parent / "data" / "format1" / f"{name}.mcap")
    new = analyze_log(LOGS / f"{name}.mcap")
    assert not old.bad_blocks and not new.bad_blocks
    assert len(old.results) == len(new.results) and len(old.events) == len(new.events)
    for a, b in zip(old.events, new.events, strict=True):
        assert abs(a["start_s"] - b["start_s"]) < 0.05 and a.get("ratio") == b.get("ratio")


def test_the_slow_two_dof_log_analyses_without_false_sensor_faults():
    """The seed's 2-DOF log (50 Hz, modes at 0.19 and 0.30 Hz) analyses: its band-pass used to invert (the modes lie
    below the 5 Hz corner: scipy's "Wn[0] must be less than Wn[1]", exit 2), and spans tuned at 16 kHz (2 samples at
    50 Hz) called x2, still at rest 0.16 s after the hit, dead, and a 1 s drift window (a sixth of a period) called
    both sensors drifting. Both sensors are healthy: the simulator wrote them without a fault."""
    from daq.studies.analyze.batch import analyze_log

    run = analyze_log(LOGS / "two_dof_3hits.mcap")
    warnings = run.results.get("/analysis/warnings", [])
    faults = [w["message"] for w in warnings if any(f in w["message"] for f in ("dead", "drifting", "stuck", "blind"))]
    assert not faults, faults
    assert len(run.results.get("/analysis/rq", [])) > 50  # 180 s analysed, window by window
