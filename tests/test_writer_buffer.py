"""The log writer's buffer is a memory budget (issue 30 item 2, D67): a stalled disk or a busy host fills memory,
not the loss count; an exhausted budget is an exact overrun; results are never starved by blocks; a SIGKILL
loses the backlog at that moment plus one flush interval, and the writer says how far behind it fell."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from daq.log import writer as writer_mod
from daq.log.reader import LogReader
from daq.log.tools import log_info, recover
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock

from .crash_recorder import block_data

ROOT = Path(__file__).resolve().parents[1]
FS = 1000.0
NAMES = ("a", "b", "c", "d")


def _block(k: int, n: int = 1000) -> SampleBlock:
    return SampleBlock("dev0", k * n, FS, NAMES, np.full((n, len(NAMES)), k, np.float32))


def test_a_stalled_disk_fills_the_memory_budget_then_overruns_exactly_and_results_still_get_in(tmp_path, monkeypatch):
    disk = threading.Event()  # the disk answers once this is set: until then every write of the writer thread waits
    write = writer_mod._pwrite_all
    monkeypatch.setattr(writer_mod, "_pwrite_all", lambda fd, data, off: (disk.wait(30), write(fd, data, off)))
    nbytes = _block(0).data.nbytes  # 16,000 B: 1000 samples x 4 channels x float32
    w = LogWriter(tmp_path / "s.mcap", queue_size=None, buffer_bytes=10 * nbytes, note_backlog_s=1.0)
    w.add_stream("dev0", [ChannelInfo(c, "acceleration", "m/s^2") for c in NAMES], FS, t0_ns=0)
    taken = [w.write_block(_block(k)) for k in range(30)]
    assert taken == [True] * 10 + [False] * 20  # exactly the budget: 10 blocks of 16 kB in 160 kB
    t0 = time.monotonic()
    for i in range(200):  # results while the block budget is exhausted: queued at once, never behind the blocks' bound
        w.write_json("/analysis/windows", {"i": i})
    assert time.monotonic() - t0 < 5.0  # a control record waiting for block space would wait the 10 s control timeout
    b = w.backlog()
    assert b["bytes"] == b["peak_bytes"] == 10 * nbytes and b["seconds"] == b["peak_seconds"] == 10.0
    disk.set()
    stats = w.close()
    assert stats.overrun_samples == 20_000 and stats.samples_written == 10_000
    assert stats.peak_backlog_s == 10.0 and stats.buffer_bytes == 10 * nbytes
    r = LogReader(tmp_path / "s.mcap")
    ev = r.json_messages("/daq/events")
    over = [e for e in ev if e["kind"] == "overrun"]
    assert [(e["start_index"], e["end_index"]) for e in over] == [(10_000, 30_000)]  # the range, exact
    (note,) = [e for e in ev if e["kind"] == "writer_backlog"]
    assert note["peak_s"] == 10.0 and "a crash then would have lost up to 10.5 s" in note["message"]
    assert len(r.json_messages("/analysis/windows")) == 200
    assert log_info(tmp_path / "s.mcap")["named_events"]["log writer"] == [note["message"]]  # gvt log info names it


def test_sigkill_while_the_disk_stalls_loses_the_backlog_plus_one_flush_interval(tmp_path):
    """The measured crash bound: the disk stops answering 0.6 s into the recording; the recorder is killed once its
    writer says it is 1 s behind. Nothing is overrun (a 256 MiB budget holds hours of this stream) and the recovered
    log lacks the backlog the writer reported at the kill plus at most the chunk it was writing (one flush interval)."""
    out = tmp_path / "crash.mcap"
    fs, n_ch, block, flush_s = 8192.0, 8, 512, 0.25  # crash_recorder.py flushes every 0.25 s
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "crash_recorder.py"), str(out), str(fs), str(n_ch),
                             str(block), "0.6", "60"], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})  # this checkout's writer  # fmt: skip
    last, backlog_s, t_end = 0, 0.0, time.monotonic() + 30
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # by what the recorder says, not by this process's clock (it may lag on a busy host)
            last, backlog_s = int(line.split()[0]), float(line.split()[1])
            if backlog_s >= 1.0 or time.monotonic() > t_end:
                break
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    assert backlog_s >= 1.0  # the writer really was behind at the kill
    rec = tmp_path / "recovered.mcap"
    recover(out, rec)
    d = LogReader(rec).read_stream("dev0")
    n = len(d.index)
    assert d.gaps == [] and np.array_equal(d.index, np.arange(n)) and d.data.tobytes() == block_data(0, n, n_ch).tobytes()
    lost_s = (last - n) / fs
    # the bound: the backlog (exact, in whole blocks) + the chunk being written (<= one flush interval of data and the
    # block handled before the flush); and not far below it, or the backlog would not be what a crash loses
    assert backlog_s - block / fs <= lost_s <= backlog_s + flush_s + 2 * block / fs, (lost_s, backlog_s)
