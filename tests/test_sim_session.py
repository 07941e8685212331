"""``gvt simulate`` to a session log streams: segments written as computed, the same log whatever the cut,
memory bounded for any duration (issue: start-up and footprint)."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

import numpy as np
import pytest

from daq.log.reader import LogReader
from daq.studies.simulate.session import SessionPlan, channel_noise, measure_segment, simulate_session
from drivers.sim.sensor_model import AdcModel, ChannelModel, measure


def _log(path):
    r = LogReader(path)
    return r.read_stream("dev0").data, {t: r.json_messages(t) for t in ("/sim/energy", "/sim/hits", "/daq/hits", "/daq/events")}


def test_segmented_log_equals_the_one_piece_log(rigs, tmp_path):
    """Segments of one block and one piece give the same samples bit for bit (the measured data are quantised
    from outputs that agree to a few ulp, tests/test_simulator.py), the same ground truth and hit records."""
    rig = rigs("beam_ch4_exp")
    plan = SessionPlan(forces=(300.0, 2600.0), pre_trigger=0.05, spacing=0.13, tail=0.2, block_size=512)
    logs = {}
    for seg in (512, 1500, 10**9):
        out = tmp_path / f"s{seg}.mcap"
        summary = simulate_session(rig, out, plan, seed=5, segment=seg)
        logs[seg] = (summary, *_log(out))
    ref_summary, ref_data, ref_msgs = logs[10**9]
    assert ref_summary["clipped"]  # the 2600 N hit overloads the hammer's range: clip counts add up over segments
    for seg in (512, 1500):
        summary, data, msgs = logs[seg]
        assert summary == ref_summary
        assert np.array_equal(data, ref_data), seg
        assert msgs == ref_msgs, seg


def test_noise_is_the_one_piece_stream_whatever_the_cut():
    """Each channel draws, segment by segment, exactly the noise ``measure`` draws for the whole record from
    ``default_rng(seed)`` (channel after channel; a noiseless channel draws none) — so the noise depends on the
    seed alone; another seed gives other noise."""
    rng = np.random.default_rng(0)
    n = 1000
    x = rng.normal(size=(n, 4)) * [1.0, 2.0, 3.0, 4.0]
    models = [ChannelModel(f"c{k}", "acceleration", "m/s^2", 0.1, noise_rms=s) for k, s in enumerate((0.5, 0.0, 0.2, 1.0))]
    adc = AdcModel(bits=24, input_range_volts=10.0)
    whole = measure(x, models, adc, np.random.default_rng(42))
    for cuts in ([0, n], [0, 1, 2, 500, n], [0, 333, 666, 999, n]):
        noise = channel_noise(42, models, n, chunk=97)
        parts = [measure_segment(x[a:b], models, adc, noise) for a, b in itertools.pairwise(cuts)]
        assert np.array_equal(np.concatenate([p.data for p in parts]), whole.data), cuts
        assert np.array_equal(np.concatenate([p.clipped for p in parts]), whole.clipped), cuts
    other = measure_segment(x, models, adc, channel_noise(43, models, n))
    assert not np.array_equal(other.data, whole.data)


_PEAK_RSS = """
import json, resource, sys, tempfile
from pathlib import Path
from analysis.model.rigs import open_rig
from daq.studies.simulate.session import SessionPlan, simulate_session
rig = open_rig("beam_ch4_exp")
peaks = []
with tempfile.TemporaryDirectory() as tmp:
    for seconds in (5.0, 20.0):
        plan = SessionPlan(forces=(800.0, 1500.0), pre_trigger=0.1, spacing=2.0, tail=seconds - 2.1, block_size=1024)
        simulate_session(rig, Path(tmp) / f"s{seconds:g}.mcap", plan, seed=1)
        peaks.append(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
print(json.dumps(peaks))
"""


def test_long_simulation_memory_is_bounded():
    """20 s of the seed's rig (15 ch at 16384 Hz, both hits inside the first 5 s) after 5 s in the same process:
    the peak resident memory grows by less than 15 MB (one-piece, the 15 more seconds cost ~19 MB each: ~285 MB).
    The bound is 1 MB per added second, as it was for 40 s after 10 s (30 MB); measured growth 0.0-0.9 MB. Half
    the simulated seconds of before: the same check at half the CPU (~4 CPU-s less)."""
    p = subprocess.run([sys.executable, "-c", _PEAK_RSS], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    after_5s, after_20s = json.loads(p.stdout.strip().splitlines()[-1])
    assert after_20s - after_5s < 15.0, (after_5s, after_20s)


@pytest.mark.parametrize("segment", [0, -3])
def test_bad_segment_length_is_refused(rigs, segment):
    sim = rigs("two_dof").simulator
    with pytest.raises(ValueError, match="segment"):
        next(sim.run_segments(rigs("two_dof").hammer_force(), 1.0, 50.0, segment=segment))
