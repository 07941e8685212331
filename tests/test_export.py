"""Aligned exports (issue 19): ``gvt log export`` applies the timeline and puts several streams on one time axis
(npz and CSV), with units, the session's UTC start, NaN / empty cells where a stream has no sample, written
atomically and never over its input.

Oracles: streams whose values encode their reference-grid index (so a misplaced sample shows its own
address); a recorded two-device session and the format 1 copy of one, where the hammer's onset and the
driving point's response onset must coincide.
"""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from analysis.errors import BadInput
from daq.log.export import export, time_base
from daq.log.reader import LogReader
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock

from .conftest import gvt_command
from .test_time_base import onset

ROOT = Path(__file__).resolve().parents[1]
FORMAT1 = ROOT / "tests" / "data" / "format1"
FS = 1000.0
ORIGIN = 1_790_000_000_000_000_000  # 2026-09-21T14:13:20Z
D = 237  # stream "a"'s sample 0 is reference sample D


def _synthetic(path: Path) -> None:
    """Reference ``h`` (hammer, value = its index) for [0, 1000); ``a`` (two channels, value = 10·grid index + col)
    for own [0, 900) with [300, 350) missing: on the grid [237, 1137) with a hole [537, 587)."""
    with LogWriter(path, origin_ns=ORIGIN) as w:
        w.add_stream("h", [ChannelInfo("hammer", "force", "N")], FS, offset_ns=0)
        w.add_stream("a", [ChannelInfo("a1", "acceleration", "m/s^2"), ChannelInfo("a2", "acceleration", "")], FS,
                     offset_ns=round(D * 1e9 / FS))  # fmt: skip
        for k in range(10):
            idx = np.arange(100 * k, 100 * k + 100)
            w.write_block(SampleBlock("h", 100 * k, FS, ("hammer",), idx[:, None].astype(np.float32)), wait=True)
        for first in range(0, 900, 50):
            if 300 <= first < 350:
                continue
            g = np.arange(first, first + 50) + D
            data = np.stack([g * 10.0, g * 10.0 + 1], axis=1).astype(np.float32)
            w.write_block(SampleBlock("a", first, FS, ("a1", "a2"), data), wait=True)


def test_merged_npz_puts_every_sample_on_the_reference_grid(tmp_path):
    log, out = tmp_path / "s.mcap", tmp_path / "s.npz"
    _synthetic(log)
    line = export(log, out, "npz")
    with np.load(out) as z:
        idx, data = z["index"], z["data"]
        assert list(z["channels"]) == ["hammer", "a1", "a2"] and list(z["units"]) == ["N", "m/s^2", ""]
        assert list(z["column_stream"]) == ["h", "a", "a"] and int(z["start_utc_ns"]) == ORIGIN
        assert str(z["start_utc"]) == "2026-09-21T14:13:20.000000000Z" and float(z["sample_rate"]) == FS
        assert np.array_equal(idx, np.concatenate([np.arange(0, 1137)]))  # the union of both streams' grid indices
        assert np.array_equal(z["t"], idx / FS)
        h = ~np.isnan(data[:, 0])
        assert np.array_equal(idx[h], np.arange(1000)) and np.array_equal(data[h, 0], idx[h])
        a = ~np.isnan(data[:, 1])
        want = np.setdiff1d(np.arange(D, 900 + D), np.arange(300 + D, 350 + D))
        assert np.array_equal(idx[a], want)
        assert np.array_equal(data[a, 1], idx[a] * 10.0) and np.array_equal(data[a, 2], idx[a] * 10.0 + 1)
        # each stream as recorded too: its own index, and its session time
        assert z["a/index"][0] == 0 and z["a/t"][0] == pytest.approx(D / FS, abs=1e-12)
        assert list(z["offset_samples"]) == [0, D] and z["a/gaps"].tolist() == [[300, 350]]
    assert "NaN" in line and "a (+237 samples)" in line  # the holes are said, not only filled


def test_merged_csv_has_units_the_utc_start_and_empty_cells(tmp_path):
    log, out = tmp_path / "s.mcap", tmp_path / "s.csv"
    _synthetic(log)
    export(log, out, "csv", start=0.5, end=0.6)  # seconds since the session start, on the reference's timeline
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t [s] since 2026-09-21T14:13:20.000000000Z", "index", "hammer [N]", "a1 [m/s^2]", "a2"]
    body = rows[1:]
    assert [int(r[1]) for r in body] == list(range(500, 600))
    for r in body:
        i = int(r[1])
        assert float(r[0]) == pytest.approx(i / FS, abs=1e-9) and float(r[2]) == i
        if 537 <= i < 587:  # a's hole: empty cells, not zeros
            assert r[3] == r[4] == ""
        else:
            assert float(r[3]) == i * 10.0 and float(r[4]) == i * 10.0 + 1


def test_export_is_atomic_and_never_writes_over_its_input(tmp_path):
    log, out = tmp_path / "s.mcap", tmp_path / "s.csv"
    _synthetic(log)
    before = log.read_bytes()
    with pytest.raises(BadInput, match="input file"):
        export(log, log, "csv")
    assert log.read_bytes() == before
    out.write_text("mine")
    with pytest.raises(BadInput, match=r"no channel\(s\) \['nope'\]"):
        export(log, out, "csv", channels=["nope"])
    assert out.read_text() == "mine"
    export(log, out, "csv", channels=["a2"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv", "s.mcap"]  # no temporary file left behind
    assert out.read_text().splitlines()[0].endswith(",index,a2")


def _hit_onsets(t: np.ndarray, hammer: np.ndarray, resp: np.ndarray, hits_s: list[float]) -> list[tuple[float, float]]:
    """(hammer onset, response onset) in s around each hit (its pre-trigger 10 ms and first 20 ms)."""
    out = []
    for h in hits_s:
        ok_h, ok_r = ~np.isnan(hammer), ~np.isnan(resp)
        out.append((onset(t[ok_h], hammer[ok_h], h - 0.01, h + 0.02), onset(t[ok_r], resp[ok_r], h - 0.01, h + 0.02)))
    return out


def _check_aligned(npz: Path, csv_path: Path, hits_s: list[float]) -> None:
    """Hammer and driving-point (a13) onsets within 1 ms (16 samples; the issue's bound) in both exports."""
    with np.load(npz) as z:
        ch = list(z["channels"])
        t, data = z["t"], z["data"]
        assert list(z["units"])[ch.index("a13")] == "m/s^2"
        pairs = _hit_onsets(t, data[:, ch.index("hammer")], data[:, ch.index("a13")], hits_s)
    assert pairs and all(abs(a - h) <= 1e-3 for h, a in pairs), pairs
    with open(csv_path, newline="") as fh:
        head = next(csv.reader(fh))
    cols = [head.index("hammer [N]"), head.index("a13 [m/s^2]")]
    raw = np.genfromtxt(csv_path, delimiter=",", skip_header=1, usecols=[0, *cols], filling_values=np.nan)
    pairs = _hit_onsets(raw[:, 0], raw[:, 1], raw[:, 2], hits_s)
    assert pairs and all(abs(a - h) <= 1e-3 for h, a in pairs), pairs


def test_format1_two_device_log_exports_aligned_by_the_applied_offset(tmp_path):
    log = FORMAT1 / "two_devices.mcap"
    r = LogReader(log)
    hits_s = [h["index"] / 16384.0 for h in r.json_messages("/daq/hits")]
    export(log, tmp_path / "x.npz", "npz")
    export(log, tmp_path / "x.csv", "csv")
    with np.load(tmp_path / "x.npz") as z:
        assert int(z["start_utc_ns"]) == -1 and "format 1" in str(z["start_utc"])
        assert dict(zip(z["streams"], z["offset_samples"], strict=True)) == {"hammer_daq": 0, "acc_daq": 3885}
    _check_aligned(tmp_path / "x.npz", tmp_path / "x.csv", hits_s)


def test_format1_single_device_logs_still_export(tmp_path):
    for name in ("two_dof_3hits.mcap", "beam_ch4_exp_weak.mcap"):
        r = LogReader(FORMAT1 / name)
        s = next(iter(r.streams()))
        export(FORMAT1 / name, tmp_path / f"{name}.npz", "npz")
        with np.load(tmp_path / f"{name}.npz") as z:
            d = r.read_stream(s)
            assert np.array_equal(z["data"], d.data) and np.array_equal(z["index"], d.index)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from analysis.model.loader import load_config
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import run_session

    cfg = load_config(SessionConfig, ROOT / "configs" / "sessions" / "sim_two_devices.toml")
    cfg = cfg.model_copy(update={"duration": 2.45, "analysis": cfg.analysis.model_copy(update={"enabled": False})})
    out = tmp_path_factory.mktemp("ex") / "two.mcap"
    res = run_session(cfg, open_rig(cfg.rig), out)
    assert res.outcome is not None and res.outcome.exit_code == 0, res.outcome
    return out, res


@pytest.mark.slow
def test_gvt_log_export_of_a_recorded_two_device_session_is_aligned(recorded, tmp_path):
    out, res = recorded
    for fmt in ("npz", "csv"):
        p = subprocess.run([*gvt_command(), "log", "export", str(out), "--format", fmt, "--out", str(tmp_path / f"x.{fmt}")],
                           capture_output=True, text=True, timeout=60)  # fmt: skip
        assert p.returncode == 0 and "acc_daq (+38" in p.stdout, p.stdout + p.stderr
    hits_s = [h.t_s for h in res.hits]
    assert len(hits_s) == 4
    _check_aligned(tmp_path / "x.npz", tmp_path / "x.csv", hits_s)
    tb = time_base(LogReader(out))
    with np.load(tmp_path / "x.npz") as z:
        assert int(z["start_utc_ns"]) == tb.origin_ns and json.dumps(str(z["start_utc"])).endswith('Z"')
