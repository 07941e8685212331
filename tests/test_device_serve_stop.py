"""`gvt device serve` says how to stop it, and Ctrl-C or SIGTERM stop it cleanly (the loss line, exit 0)."""

from __future__ import annotations

import signal
import subprocess

import pytest

from .conftest import gvt_command

SERVE = [*gvt_command(), "device", "serve", "two_dof", "--transport", "serial", "--hits", "1", "--period", "0.5"]


def test_serve_for_a_time_says_so_and_stops_by_itself():
    p = subprocess.run([*SERVE, "--seconds", "0.5"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert "port = '/dev/" in lines[0]  # how to connect comes first (tests/test_device_serve.py reads it)
    assert lines[1].startswith("serving for 0.5 s;") and "Ctrl-C or SIGTERM" in lines[1]
    assert lines[-1].startswith("stopped; injected loss: 0 samples")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_serve_until_stopped_by_a_signal(sig):
    proc = subprocess.Popen(SERVE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        second = proc.stdout.readline()
        assert "port = '/dev/" in first, proc.stderr.read() if not first else first
        assert second.strip() == f"serving until Ctrl-C or SIGTERM (kill {proc.pid})"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert out.strip().splitlines()[-1].startswith("stopped; injected loss: 0 samples in 0 ranges")
    assert "Traceback" not in err and "Aborted" not in err
