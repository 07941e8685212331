"""Wake-up timing of a simulated device's sending thread: as a device's own clock sends, not as a host timer does.

A real DAQ sends a block a fixed latency after its last sample, on its own hardware clock. The simulated devices
(drivers/serial/sim_server.py, drivers/can/sim_node.py, the paced drivers/sim/driver.py) wait on a host timer until a
block is due, and Linux lets a normal thread's timer fire anywhere in ``[due, due + timer slack]`` (50 µs by default,
``prctl(PR_SET_TIMERSLACK)``) so that wake-ups can be batched. On a quiet host nothing else wakes the core inside that
span, so most blocks leave ~50 µs late and only the odd one on time; on a busy host other interrupts end the span early
more often. The clock offset between two devices is the difference of their arrival-time floors (daq/timeline.py), so
a floor set by how many lucky wake-ups each simulated device happened to get put up to a sample period (61 µs at
16384 Hz) of error into a quiet two-device session that no hardware link has. The slack of the sending thread is
therefore set to 1 ns: the device's own timing, not the host's batching (docs/decisions.md D129).
"""

from __future__ import annotations

import ctypes
import functools
import sys

PR_SET_TIMERSLACK = 29  # linux/prctl.h
PR_GET_TIMERSLACK = 30
SLACK_NS = 1  # the smallest the kernel takes (0 would restore the thread's default)


@functools.cache
def _prctl():
    """libc's ``prctl`` (returning a C long: the slack read back can exceed an int), None off Linux or without it."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_long
    return fn


def precise_wakeups() -> bool:
    """Set the calling thread's timer slack to ``SLACK_NS``. False (nothing changed) off Linux or where ``prctl``
    refuses; the device then sends up to the default slack late, as before."""
    prctl = _prctl()
    return prctl is not None and prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(SLACK_NS), 0, 0, 0) == 0


def timer_slack_ns() -> int | None:
    """The calling thread's timer slack in ns (per thread: Linux has no /proc file for one thread's), None off Linux."""
    prctl = _prctl()
    return None if prctl is None else int(prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0))
