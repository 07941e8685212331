"""The log writer's output and its failures, on real files: refused outputs (one line, exit 2), the lock (a
second recorder, a SIGKILLed one), and failures while recording (disk full, I/O errors, the file deleted or
moved): one line, nothing raised into a producer, everything written before readable."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.errors import BadInput, DataLost
from daq.log.reader import LogReader
from daq.log.writer import (
    ChannelInfo,
    LogOutputError,
    LogOutputExistsError,
    LogOutputInUseError,
    LogOutputLostError,
    LogWriter,
    LogWriterError,
)
from drivers.blocks import SampleBlock

from .conftest import gvt_command

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("a", "b", "c", "d")
BLOCK = 256
FS = 1000.0

# a traceback in the writer thread is a failure of these tests, not a warning
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")


def _data(k: int) -> np.ndarray:
    """Block k's samples: random, so zstd cannot shrink them and a small disk fills quickly."""
    return np.random.default_rng(k).standard_normal((BLOCK, len(NAMES))).astype(np.float32)


def _block(k: int) -> SampleBlock:
    return SampleBlock("dev0", k * BLOCK, FS, NAMES, _data(k))


def _writer(path: Path, **kw) -> LogWriter:
    w = LogWriter(path, **kw)
    w.add_stream("dev0", [ChannelInfo(n, "acceleration", "m/s^2") for n in NAMES], FS, t0_ns=0)
    return w


def _one_line(text: str) -> None:
    assert text and "\n" not in text and "Traceback" not in text and len(text) < 700, text


def _writer_threads() -> int:
    return sum(t.name.startswith("mcap-writer:") for t in threading.enumerate())


def _assert_prefix(path: Path, n_samples: int) -> None:
    """The log at ``path`` holds exactly samples 0..n_samples-1, bit for bit."""
    d = LogReader(path).read_stream("dev0")
    assert np.array_equal(d.index, np.arange(n_samples))
    n_blocks = n_samples // BLOCK
    want = np.concatenate([_data(k) for k in range(n_blocks)]) if n_blocks else np.zeros((0, len(NAMES)), np.float32)
    assert d.data.tobytes() == want.tobytes()


def _feed_until_failed(w: LogWriter, start: int = 0, limit_s: float = 20.0, wait: bool = True, pace: float = 0.0) -> int:
    """Write blocks start, start+1, ... until the writer fails; the number of the next block."""
    k = start
    t_end = time.monotonic() + limit_s
    while not w.failed.is_set() and time.monotonic() < t_end:
        w.write_block(_block(k), wait=wait)
        k += 1
        if pace:
            time.sleep(pace)
    assert w.failed.is_set(), "the writer never failed"
    return k


def _lost_tail(written: int, total: int) -> list[tuple[str, int, int]]:
    """What a failure should have lost when blocks were offered in order: the tail after what was written
    (nothing, when the writer failed between two blocks and the producer saw it before offering another)."""
    return [("dev0", written, total)] if written < total else []


def _refused(make) -> LogOutputError:
    before = _writer_threads()
    with pytest.raises(LogOutputError) as ei:
        make()
    err = ei.value
    _one_line(str(err))
    assert err.exit_code == 2 and isinstance(err, BadInput) and isinstance(err, LogWriterError)
    assert _writer_threads() == before  # refused on the caller's thread: no writer thread was started
    return err


@pytest.fixture
def mount_tmpfs(tmp_path):
    """Mount a tmpfs with ``opts`` under tmp_path (root only); unmounted afterwards."""
    mounted: list[Path] = []

    def mount(opts: str) -> Path:
        if os.geteuid() != 0:
            pytest.skip("mounting a tmpfs needs root")
        if shutil.which("mount") is None:
            pytest.skip("no mount command")
        d = tmp_path / f"mnt{len(mounted)}"
        d.mkdir()
        p = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(d)], capture_output=True, text=True)
        if p.returncode != 0:
            pytest.skip(f"mount -t tmpfs -o {opts} not permitted here: {p.stderr.strip()}")
        mounted.append(d)
        return d

    yield mount
    for d in mounted:
        if subprocess.run(["umount", str(d)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(d)], capture_output=True)


# --- refused outputs --------------------------------------------------------------------------------
def test_missing_directory_is_refused_in_one_line(tmp_path):
    out = tmp_path / "nope" / "deeper" / "x.mcap"
    err = _refused(lambda: LogWriter(out))
    assert f"directory {tmp_path / 'nope'} does not exist" in str(err)
    assert not (tmp_path / "nope").exists()


def test_output_that_is_a_directory_is_refused(tmp_path):
    err = _refused(lambda: LogWriter(tmp_path))
    assert "is a directory" in str(err) and tmp_path.is_dir()


def test_read_only_directory_is_refused(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() == 0:  # root writes through permission bits: make the directory immutable instead
        if shutil.which("chattr") is None:
            pytest.skip("root ignores permissions and chattr is not available")
        p = subprocess.run(["chattr", "+i", str(d)], capture_output=True, text=True)
        if p.returncode != 0:
            pytest.skip(f"root ignores permissions and chattr +i is not supported here: {p.stderr.strip()}")
        undo = ["chattr", "-i", str(d)]
    else:
        d.chmod(0o555)
        undo = ["chmod", "755", str(d)]
    try:
        err = _refused(lambda: LogWriter(d / "x.mcap"))
        assert "permission denied" in str(err)
        assert not (d / "x.mcap").exists()
    finally:
        subprocess.run(undo, check=True)


def test_read_only_file_system_is_refused(mount_tmpfs):
    d = mount_tmpfs("ro,size=1m")
    err = _refused(lambda: LogWriter(d / "x.mcap"))
    assert "read-only file system" in str(err)


def test_existing_file_is_refused_without_overwrite_and_replaced_with_it(tmp_path):
    p = tmp_path / "old.mcap"
    precious = b"precious" * 200_000
    p.write_bytes(precious)
    err = _refused(lambda: LogWriter(p))
    assert isinstance(err, LogOutputExistsError) and "exists; pass --overwrite" in str(err)
    assert p.read_bytes() == precious  # untouched
    w = _writer(p, overwrite=True)
    for k in range(4):
        w.write_block(_block(k), wait=True)
    w.close()
    assert p.stat().st_size < len(precious)  # truncated, not written over the old bytes
    assert LogReader(p).report.complete
    _assert_prefix(p, 4 * BLOCK)


def test_an_earlier_rotated_part_is_not_overwritten(tmp_path):
    part = tmp_path / "rot-0001.mcap"
    part.write_bytes(b"old part")
    err = _refused(lambda: LogWriter(tmp_path / "rot.mcap", rotate_bytes=10_000))
    assert isinstance(err, LogOutputExistsError) and str(part) in str(err)
    assert not (tmp_path / "rot.mcap").exists() and part.read_bytes() == b"old part"


# --- the lock --------------------------------------------------------------------------------------
def test_second_writer_on_the_same_path_is_refused_and_the_first_stays_whole(tmp_path):
    p = tmp_path / "one.mcap"
    w1 = _writer(p)
    for k in range(10):
        w1.write_block(_block(k), wait=True)
    for overwrite in (True, False):  # "in use" comes before "exists": --overwrite would not help
        err = _refused(lambda ow=overwrite: LogWriter(p, overwrite=ow))
        assert isinstance(err, LogOutputInUseError)
        assert f"in use by another writer in this process (pid {os.getpid()})" in str(err)
    for k in range(10, 20):
        w1.write_block(_block(k), wait=True)
    stats = w1.close()
    assert w1.failure is None and stats.samples_written == 20 * BLOCK
    assert LogReader(p).report.complete
    _assert_prefix(p, 20 * BLOCK)


def test_a_sigkilled_recorder_holds_the_lock_until_it_dies(tmp_path):
    out = tmp_path / "killed.mcap"
    recorder = [sys.executable, str(ROOT / "tests" / "crash_recorder.py"), str(out), "2000", "2", "100"]
    proc = subprocess.Popen(recorder, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip()  # it has written a block
        time.sleep(0.4)  # and flushed
        size = out.stat().st_size
        err = _refused(lambda: LogWriter(out, overwrite=True))
        assert isinstance(err, LogOutputInUseError) and f"in use by another recorder (pid {proc.pid})" in str(err)
        assert out.stat().st_size >= size > 0  # the refused writer did not truncate it
    finally:
        proc.kill()
        proc.wait(timeout=10)
    w = _writer(out, overwrite=True)  # no stale lock after SIGKILL
    w.write_block(_block(0), wait=True)
    w.close()
    _assert_prefix(out, BLOCK)


# --- failures while recording ------------------------------------------------------------------------
def test_disk_full_stops_with_one_line_and_keeps_everything_before_it(mount_tmpfs, tmp_path):
    d = mount_tmpfs("size=2m")
    out = d / "full.mcap"
    w = _writer(out, flush_interval=0.05, chunk_size=64 * 1024)
    k = _feed_until_failed(w)
    t0 = time.monotonic()
    for j in range(k, k + 200):  # after the failure: nothing raises, nothing blocks
        assert w.write_block(_block(j)) is False
    w.write_event("note", message="after the failure")
    w.write_hit({"index": 1})
    w.add_metadata("late", {"a": "b"})
    assert time.monotonic() - t0 < 5.0  # milliseconds: a hang guard for a call that blocked
    total = (k + 200) * BLOCK
    assert w.failure is not None  # read: close() does not raise
    stats = w.close()
    line = w.failure
    assert line is not None
    _one_line(line)
    assert "the disk is full" in line and f"gvt log recover {out} FIXED.mcap" in line, line
    assert f"last complete chunk (byte {out.stat().st_size})" in line, line
    assert f"dev0 samples 0-{stats.samples_written - 1}" in line, line
    assert stats.samples_written > 0 and stats.overrun_samples == 0
    assert stats.samples_written + stats.lost_after_failure_samples == total
    assert stats.lost_after_failure_ranges == [("dev0", stats.samples_written, total)]
    assert f"{total - stats.samples_written} samples from t={stats.samples_written / FS:.3f} s on were not recorded" in line
    assert stats.dropped_after_failure >= 3
    err = w.failure_error
    assert isinstance(err, LogWriterError) and not isinstance(err, DataLost) and err.exit_code == w.failure_exit_code == 1
    r = LogReader(out)  # the tolerant reader gets every block up to the failure
    assert not r.report.complete
    _assert_prefix(out, stats.samples_written)
    fixed = tmp_path / "fixed.mcap"
    rec = subprocess.run([*gvt_command(), "log", "recover", str(out), str(fixed)], capture_output=True, text=True, timeout=60)
    assert rec.returncode == 3 and "Traceback" not in rec.stderr, rec.stderr
    assert LogReader(fixed).report.complete
    _assert_prefix(fixed, stats.samples_written)


def _inject(monkeypatch, path: Path, limit: int, err: int, times: int | None) -> dict:
    """Writes to ``path`` past ``limit`` bytes: a short write up to it, then ``err`` (``times`` times, or for ever)."""
    real = os.pwrite
    state = {"raised": 0}

    def pwrite(fd, data, offset):
        try:
            ours = os.readlink(f"/proc/self/fd/{fd}") == str(path)
        except OSError:
            ours = False
        if ours and offset + len(data) > limit and (times is None or state["raised"] < times):
            if offset < limit:
                return real(fd, memoryview(data)[: limit - offset], offset)
            state["raised"] += 1
            raise OSError(err, os.strerror(err))
        return real(fd, data, offset)

    monkeypatch.setattr(os, "pwrite", pwrite)
    return state


def test_io_error_cuts_the_file_back_to_its_last_complete_chunk(tmp_path, monkeypatch):
    p = tmp_path / "eio.mcap"
    _inject(monkeypatch, p, 300_000, errno.EIO, None)
    w = _writer(p, flush_interval=0.05, chunk_size=32 * 1024)
    k = _feed_until_failed(w)
    line = w.failure
    stats = w.close()
    assert line is not None
    _one_line(line)
    assert "input/output error" in line and "gvt log recover" in line, line
    size = p.stat().st_size
    assert size < 300_000 and f"(byte {size})" in line, line  # the partial record before the limit is cut off
    assert stats.samples_written + stats.lost_after_failure_samples == k * BLOCK
    assert stats.lost_after_failure_ranges == _lost_tail(stats.samples_written, k * BLOCK)
    _assert_prefix(p, stats.samples_written)  # a partial record was written past the cut: it is gone


def test_a_transient_disk_full_still_finishes_the_file(tmp_path, monkeypatch):
    """The write that failed is retried once when the writer finalises: if the disk takes it, the log is
    complete — with no block twice, and the failure recorded in the log itself."""
    p = tmp_path / "transient.mcap"
    state = _inject(monkeypatch, p, 200_000, errno.ENOSPC, 1)
    w = _writer(p, flush_interval=0.05, chunk_size=32 * 1024)
    k = _feed_until_failed(w)
    assert w.failure is not None
    stats = w.close()
    line = w.failure  # final counts
    assert line is not None and state["raised"] == 1
    _one_line(line)
    assert "the disk is full" in line and "the file is complete" in line and "recover" not in line, line
    r = LogReader(p)
    assert r.indexed and r.report.complete and not r.report.data_lost
    _assert_prefix(p, stats.samples_written)
    assert stats.samples_written + stats.lost_after_failure_samples == k * BLOCK
    assert stats.lost_after_failure_ranges == _lost_tail(stats.samples_written, k * BLOCK)
    assert any(e["kind"] == "writer_failure" for e in r.json_messages("/daq/events"))


def test_deleting_the_output_is_noticed_within_a_flush_and_is_data_lost(tmp_path):
    p = tmp_path / "deleted.mcap"
    w = _writer(p)  # default flush interval: 0.5 s
    for k in range(20):
        w.write_block(_block(k))
        time.sleep(0.01)
    p.unlink()
    t_del = time.monotonic()
    k = _feed_until_failed(w, start=20, limit_s=5.0, wait=False, pace=0.01)
    noticed = time.monotonic() - t_del
    # one 0.5 s flush interval on a quiet host; a loaded one delays the writer thread by seconds at worst, and an
    # unnoticed deletion would run to _feed_until_failed's 5 s limit and fail there
    assert noticed < 4.0, f"noticed after {noticed:.2f} s"
    for j in range(k, k + 10):
        assert w.write_block(_block(j)) is False
    total = (k + 10) * BLOCK
    with pytest.raises(LogOutputLostError) as ei:  # nobody read ``failure``: close() raises it, once
        w.close()
    err = ei.value
    assert err.exit_code == 3 and isinstance(err, DataLost) and w.failure_exit_code == 3
    line = str(err)
    _one_line(line)
    stats = w.close()
    assert stats.overrun_samples == 0
    assert "the output file was deleted while recording" in line
    assert f"{total} samples from t=0.000 s on were not recorded" in line, line
    assert stats.samples_written == 0 and stats.lost_after_failure_samples == total
    assert stats.lost_after_failure_ranges == [("dev0", 0, total)]
    assert not p.exists()


def test_moving_the_output_stops_the_recording_and_finishes_the_moved_file(tmp_path):
    p = tmp_path / "moved.mcap"
    elsewhere = tmp_path / "elsewhere.mcap"
    w = _writer(p, flush_interval=0.1)
    for k in range(10):
        w.write_block(_block(k), wait=True)
    time.sleep(0.3)
    os.rename(p, elsewhere)
    k = _feed_until_failed(w, start=10, limit_s=5.0, pace=0.005)
    line = w.failure
    stats = w.close()
    assert line is not None
    _one_line(line)
    assert "moved or replaced while recording" in line and f"(it is now {elsewhere})" in line, line
    assert "the file is complete" in line
    assert LogReader(elsewhere).report.complete
    _assert_prefix(elsewhere, stats.samples_written)
    assert stats.samples_written + stats.lost_after_failure_samples == k * BLOCK
    assert stats.lost_after_failure_ranges == _lost_tail(stats.samples_written, k * BLOCK)
    assert not p.exists()
