"""A recorder process for the crash test: writes deterministic blocks at real-time pace and prints
the end index of every block it has handed to the writer, until it is killed.

    python tests/crash_recorder.py OUT.mcap FS CHANNELS BLOCK
"""

from __future__ import annotations

import sys
import time

import numpy as np

from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock


def block_data(first: int, n: int, n_ch: int) -> np.ndarray:
    i = np.arange(first, first + n, dtype=np.float64)[:, None]
    ch = np.arange(n_ch)[None, :]
    return (np.sin(0.001 * i * (ch + 1)) + 0.001 * ch).astype(np.float32)


def main() -> None:
    out, fs, n_ch, block = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    names = tuple(f"c{k}" for k in range(n_ch))
    w = LogWriter(out, flush_interval=0.25, queue_size=16)
    w.add_stream("dev0", [ChannelInfo(n, "acceleration", "m/s^2") for n in names], fs, t0_ns=0)
    start = time.monotonic()
    first = 0
    while True:
        due = start + first / fs
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        w.write_block(SampleBlock("dev0", first, fs, names, block_data(first, block, n_ch)))
        first += block
        print(first, flush=True)


if __name__ == "__main__":
    main()
