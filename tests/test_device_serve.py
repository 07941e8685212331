"""`gvt device serve` as a separate process, read by drivers found through their entry points."""

from __future__ import annotations

import itertools
import re
import subprocess

import numpy as np
import pytest

from drivers.base import available_drivers, make_driver

from .conftest import gvt_command


def test_all_transports_are_registered_plugins():
    drivers = available_drivers()
    assert {"serial", "can", "modbus", "sim"} <= set(drivers)
    for name, cls in drivers.items():
        assert cls.name == name


def _serve(*args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [*gvt_command(), "device", "serve", "beam_ch4_exp", "--hits", "1", "--period", "0.5", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    if not line:
        proc.kill()
        pytest.fail(f"device did not start: {proc.stderr.read()}")
    return proc, line


def _read(drv, seconds: float) -> list:
    got, total = [], 0
    with drv:
        for b in drv.blocks(timeout=5):
            got.append(b)
            total += b.n_samples
            if total >= seconds * 16384:
                break
    return got


@pytest.mark.parametrize("transport", ["modbus", "serial"])
def test_device_process_over_a_real_transport(transport):
    if transport == "modbus":
        proc, line = _serve("--transport", "modbus", "--seconds", "20")
        port = int(re.search(r"port=(\d+)", line).group(1))
        drv = make_driver("modbus", {"port": port, "channels": ["hammer", "a01", "a02"], "sample_rate": 16384.0})
    else:
        proc, line = _serve("--transport", "serial", "--seconds", "20", "--channels", "hammer,a13,a14")
        path = re.search(r"port = '([^']+)'", line).group(1)
        drv = make_driver("serial", {"port": path, "sample_rate": 16384.0, "channels": ["hammer", "a13", "a14"], "usb_cdc": True})
    try:
        blocks = _read(drv, 1.5)
    finally:
        proc.terminate()
        out, _err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and "stopped" in out
    first = [b.first_index for b in blocks]
    assert all(b.first_index == a.end_index for a, b in itertools.pairwise(blocks))  # contiguous
    assert drv.stats.lost_samples == 0 and first
    data = np.concatenate([b.data for b in blocks])
    assert data.shape[1] == 3 and np.all(np.isfinite(data))
    assert "127.0.0.1" in line if transport == "modbus" else "/dev/" in line
