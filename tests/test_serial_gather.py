"""The serial driver's reading turns while data flows (D106): with ``gather_s`` a turn begins at most every ``gather_s``.

Before, a turn that found bytes waiting took them at once; a steady stream from a device in its own process nearly
always has some (the tty hands them over in pieces), so a turn read about one 64-sample frame: 147 turns a second at
15 ch x 16384 Hz, each a decode and a turn of the loop. Checked on a real pty: bytes are waiting at every turn, and
still the turns are ``gather_s`` apart and every byte is read, in order. A loaded machine only spaces them more.
"""

from __future__ import annotations

import itertools
import os
import pty
import time
import tty

from drivers.serial.driver import SerialConfig, SerialDriver

GATHER_S = 0.02


def test_turns_are_gather_apart_while_bytes_wait():
    master, slave = pty.openpty()
    tty.setraw(slave)
    drv = SerialDriver(SerialConfig.model_validate({"port": os.ttyname(slave), "usb_cdc": True, "sample_rate": 16384.0,
                                                    "channels": ["a"]}))  # fmt: skip
    drv.gather_s = GATHER_S
    port = drv._open_port()
    try:
        sent, got, stamps = b"", b"", []
        for k in range(6):
            chunk = bytes([k]) * 3000  # a frame's worth, waiting before each turn begins
            os.write(master, chunk)
            sent += chunk
            time.sleep(0.002)  # the kernel moves it to the tty's input
            got += drv._read_available(port)
            stamps.append(drv._next_read - GATHER_S)  # when this turn's read ended (exact, whatever the load)
        while len(got) < len(sent) and (more := drv._read_available(port)):
            got += more
    finally:
        port.close()
        os.close(master)
        os.close(slave)
    assert got == sent  # nothing lost or reordered by the pacing or by os.read
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert min(gaps) >= GATHER_S, gaps  # before: ~2 ms apart (the sleep above), one turn per frame that was waiting
