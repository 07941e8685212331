"""`gvt record` when things go wrong: wild frames, a device that stops, the output and the disk, a SIGKILL.

Each one ends with a stated reason, one line and the right exit code (2 bad input, 1 runtime failure, 3 data
lost), a finalised (or recoverable) file, and no traceback or orphan process. Where the process is not what is
under test the verb runs in this process (``daq.cli.run`` maps every error to the console script's line and code;
a child's imports cost 1-2 CPU-s); the running recorder a second one meets and the SIGKILLed one are real processes.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from analysis.model.loader import load_config
from analysis.model.rigs import open_rig
from daq.config.session import SessionConfig
from daq.log.reader import LogReader
from daq.session import run_session

from .conftest import gvt_in_process
from .test_record_matrix import session_file

ROOT = Path(__file__).resolve().parents[1]
FS = 16384


def one_line(p: subprocess.CompletedProcess) -> str:
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gvt: error: ") and "Traceback" not in p.stderr, p.stderr
    return lines[0]


@pytest.fixture
def gvt_here(capfd):
    """``gvt`` in this process (conftest.gvt_in_process), read at the file descriptors: returncode, stdout, stderr."""
    return functools.partial(gvt_in_process, capfd)


def test_wild_serial_frames_are_rejected_counted_and_cost_nothing_else(tmp_path):
    """A CRC-valid frame claiming index 1e9, another 2^62 (which used to overflow the log time and kill the writer)."""
    path = session_file(tmp_path, "serial-binary", FS, {"wild_frames": [[1.0, 10**9], [2.0, 2**62]]})
    out = tmp_path / "wild.mcap"
    cfg = load_config(SessionConfig, path)
    res = run_session(cfg, open_rig(cfg.rig), out)
    assert res.outcome.reason == "duration" and res.rejected_blocks == 2 and res.lost_samples == 0
    r = LogReader(out)
    assert r.report.complete
    d = r.read_stream("dev0")
    assert d.gaps == [] and len(d.index) == 3 * FS and int(d.index[-1]) == 3 * FS - 1
    ev = [e for e in r.json_messages("/daq/events") if e["kind"] == "implausible_index"]
    assert sorted(e["device_start"] for e in ev) == [10**9, 2**62]


def test_a_device_that_stops_delivering_ends_the_session_at_duration_plus_grace_with_exit_3(tmp_path, gvt_here):
    path = session_file(tmp_path, "serial-binary", FS, {"disconnect_at_s": 1.0, "disconnect_for_s": 60.0})
    text = path.read_text().replace("end_grace_s = 10.0", "end_grace_s = 1.0")
    path.write_text(text)
    out = tmp_path / "short.mcap"
    t0 = time.monotonic()
    p = gvt_here("record", str(path), "--out", str(out))
    took = time.monotonic() - t0
    assert p.returncode == 3, p.stderr
    line = one_line(p)
    assert "no more data within 1 s" in line and f"of {3 * FS} samples" in line
    assert took < 50  # duration 3 s + grace 1 s + start-up, never the 60 s the device stays silent: no hang
    r = LogReader(out)
    assert r.report.complete
    kinds = [e["kind"] for e in r.json_messages("/daq/events")]
    assert "duration_not_reached" in kinds and "silence" in kinds
    n = len(r.read_stream("dev0").index)
    assert 0.9 * FS <= n <= 1.1 * FS  # what came before the link died is all there


def test_output_mistakes_are_one_line_exit_2_before_anything_starts(tmp_path, gvt_here):
    cfg = ROOT / "configs" / "sessions" / "sim_serial_20hits.toml"
    p = gvt_here("record", str(cfg), "--out", str(tmp_path / "missing" / "s.mcap"))
    assert p.returncode == 2 and "does not exist" in one_line(p)
    p = gvt_here("record", str(cfg), "--out", str(tmp_path))
    assert p.returncode == 2 and "is a directory" in one_line(p)
    existing = tmp_path / "keep.mcap"
    existing.write_bytes(b"the user's own file")
    p = gvt_here("record", str(cfg), "--out", str(existing))
    assert p.returncode == 2 and "--overwrite" in one_line(p)
    assert existing.read_bytes() == b"the user's own file"


def test_a_read_only_directory_is_refused(tmp_path, gvt_here):
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
            pytest.skip("running as root, where permissions do not stop writes, and chattr +i is not available here")
    else:
        d.chmod(0o500)
    try:
        p = gvt_here("record", str(ROOT / "configs" / "sessions" / "sim_serial_20hits.toml"), "--out", str(d / "s.mcap"))
        assert p.returncode == 2, p.stderr
        one_line(p)
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(d)], capture_output=True)
        else:
            d.chmod(0o700)


def test_a_full_disk_stops_the_session_with_one_line_and_a_readable_log(tmp_path, gvt_here):
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a small tmpfs")
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs is not permitted here")
    try:
        path = session_file(tmp_path, "serial-binary", FS, duration=8.0, forces=[300.0] * 6)
        out = mnt / "full.mcap"
        p = gvt_here("record", str(path), "--out", str(out))
        assert p.returncode == 1, p.stdout + p.stderr
        line = one_line(p)
        assert "disk is full" in line
        d = LogReader(out).read_stream("dev0")  # everything before the failure point reads back
        assert len(d.index) > 0.2 * FS and d.index[0] == 0
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


# A second recorder on the same output, and a SIGKILL leaving no child process behind: tests/test_session.py, in
# its SIGTERM and SIGKILL sessions (one real recorder each, shared with the finalised-file and recovery checks).
