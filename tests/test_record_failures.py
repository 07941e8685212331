"""`gvt record` when things go wrong: wild frames, a device that stops, the output and the disk, a SIGKILL.

Each one ends with a stated reason, one line and the right exit code (2 bad input, 1 runtime failure, 3 data
lost), a finalised (or recoverable) file, and no traceback or orphan process.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from analysis.model.loader import load_config
from analysis.model.rigs import open_rig
from daq.config.session import SessionConfig
from daq.log.reader import LogReader
from daq.session import run_session

from .conftest import gvt_command
from .test_record_matrix import session_file

ROOT = Path(__file__).resolve().parents[1]
FS = 16384


def gvt(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([*gvt_command(), *args], capture_output=True, text=True, timeout=timeout)


def one_line(p: subprocess.CompletedProcess) -> str:
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gvt: error: ") and "Traceback" not in p.stderr, p.stderr
    return lines[0]


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


def test_a_device_that_stops_delivering_ends_the_session_at_duration_plus_grace_with_exit_3(tmp_path):
    path = session_file(tmp_path, "serial-binary", FS, {"disconnect_at_s": 1.0, "disconnect_for_s": 60.0})
    text = path.read_text().replace("end_grace_s = 10.0", "end_grace_s = 1.0")
    path.write_text(text)
    out = tmp_path / "short.mcap"
    t0 = time.monotonic()
    p = gvt("record", str(path), "--out", str(out))
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


def test_output_mistakes_are_one_line_exit_2_before_anything_starts(tmp_path):
    cfg = ROOT / "configs" / "sessions" / "sim_serial_20hits.toml"
    p = gvt("record", str(cfg), "--out", str(tmp_path / "missing" / "s.mcap"))
    assert p.returncode == 2 and "does not exist" in one_line(p)
    p = gvt("record", str(cfg), "--out", str(tmp_path))
    assert p.returncode == 2 and "is a directory" in one_line(p)
    existing = tmp_path / "keep.mcap"
    existing.write_bytes(b"the user's own file")
    p = gvt("record", str(cfg), "--out", str(existing))
    assert p.returncode == 2 and "--overwrite" in one_line(p)
    assert existing.read_bytes() == b"the user's own file"


def test_a_read_only_directory_is_refused(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
            pytest.skip("running as root, where permissions do not stop writes, and chattr +i is not available here")
    else:
        d.chmod(0o500)
    try:
        p = gvt("record", str(ROOT / "configs" / "sessions" / "sim_serial_20hits.toml"), "--out", str(d / "s.mcap"))
        assert p.returncode == 2, p.stderr
        one_line(p)
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(d)], capture_output=True)
        else:
            d.chmod(0o700)


def test_a_full_disk_stops_the_session_with_one_line_and_a_readable_log(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to mount a small tmpfs")
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs is not permitted here")
    try:
        path = session_file(tmp_path, "serial-binary", FS, duration=8.0, forces=[300.0] * 6)
        out = mnt / "full.mcap"
        p = gvt("record", str(path), "--out", str(out), timeout=60)
        assert p.returncode == 1, p.stdout + p.stderr
        line = one_line(p)
        assert "disk is full" in line
        d = LogReader(out).read_stream("dev0")  # everything before the failure point reads back
        assert len(d.index) > 0.2 * FS and d.index[0] == 0
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _status_line_seen(proc: subprocess.Popen, timeout: float = 60.0) -> None:
    until = time.monotonic() + timeout
    while time.monotonic() < until:
        line = proc.stdout.readline()
        if "samples" in line:
            return
    raise AssertionError("the recorder printed no status line")


def test_a_second_recorder_on_the_same_output_is_refused(tmp_path):
    path = session_file(tmp_path, "serial-binary", FS, duration=20.0, forces=[300.0] * 10)
    out = tmp_path / "one.mcap"
    first = subprocess.Popen([*gvt_command(), "record", str(path), "--out", str(out)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _status_line_seen(first)
        p = gvt("record", str(path), "--out", str(out), "--overwrite")
        assert p.returncode == 2 and "in use by another recorder" in one_line(p)
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=60)
    assert first.returncode == 0
    assert LogReader(out).report.complete  # the first recorder's file is untouched by the refused second one


def _descendants(pid: int) -> set[int]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    out, todo = set(), [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_sigkill_leaves_no_child_process_behind(tmp_path):
    """The confirmation worker (~300 MB) and the rerun viewer server used to outlive a SIGKILLed recorder."""
    cfg = ROOT / "configs" / "sessions" / "sim_serial_20hits.toml"
    proc = subprocess.Popen([*gvt_command(), "record", str(cfg), "--out", str(tmp_path / "k.mcap"), "--view",
                             "--duration", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        until = time.monotonic() + 60
        kids: set[int] = set()
        while time.monotonic() < until and len(kids) < 2:  # the viewer server, then the confirmation worker
            time.sleep(0.5)
            kids = _descendants(proc.pid)
        assert len(kids) >= 2, f"expected a viewer and a confirmation worker, saw {kids}"
        proc.kill()
        proc.wait(timeout=10)
        until = time.monotonic() + 10
        while time.monotonic() < until and any(_alive(k) for k in kids):
            time.sleep(0.2)
        assert not [k for k in kids if _alive(k)]
    finally:
        for k in _descendants(proc.pid):
            try:
                os.kill(k, signal.SIGKILL)
            except ProcessLookupError:
                pass
