"""A recorder process for the crash tests: writes deterministic blocks at real-time pace and prints
the end index of every block it has handed to the writer, until it is killed.

    python tests/crash_recorder.py OUT.mcap FS CHANNELS BLOCK [STALL_AT_S STALL_FOR_S]

With a stall: the disk stops answering from ``STALL_AT_S`` for ``STALL_FOR_S`` seconds (every write the
writer thread makes in that window waits for its end: a USB disk or a network share that hangs), the
writer's buffer is a memory budget of 256 MiB as in a session, and each line also carries the writer's
backlog in seconds of data at that moment: ``END BACKLOG_S``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from daq.log import writer as writer_mod
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock


def block_data(first: int, n: int, n_ch: int) -> np.ndarray:
    i = np.arange(first, first + n, dtype=np.float64)[:, None]
    ch = np.arange(n_ch)[None, :]
    return (np.sin(0.001 * i * (ch + 1)) + 0.001 * ch).astype(np.float32)


def stall_disk(start: float, at_s: float, for_s: float) -> None:
    """Every file write the writer makes between ``at_s`` and ``at_s + for_s`` (s after ``start``) waits for the
    window's end, then writes: the disk is slow, the data it is given is not lost."""
    write = writer_mod._pwrite_all

    def slow(fd, data, offset) -> None:
        late = start + at_s + for_s - time.monotonic()
        if late > 0 and time.monotonic() >= start + at_s:
            time.sleep(late)
        write(fd, data, offset)

    writer_mod._pwrite_all = slow


def main() -> None:
    out, fs, n_ch, block = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    stall = [float(a) for a in sys.argv[5:7]]
    names = tuple(f"c{k}" for k in range(n_ch))
    start = time.monotonic()
    if stall:
        stall_disk(start, *stall)
        w = LogWriter(out, flush_interval=0.25, queue_size=None, buffer_bytes=256 << 20)
    else:
        w = LogWriter(out, flush_interval=0.25, queue_size=16)
    w.add_stream("dev0", [ChannelInfo(n, "acceleration", "m/s^2") for n in names], fs, t0_ns=0)
    first = 0
    while True:
        due = start + first / fs
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        w.write_block(SampleBlock("dev0", first, fs, names, block_data(first, block, n_ch)))
        first += block
        print(f"{first} {w.backlog()['seconds']:.4f}" if stall else first, flush=True)


if __name__ == "__main__":
    main()
