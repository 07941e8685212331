"""A long session from the simulated device at full speed through `gvt record`: bounded memory, rotation.

``make test`` records 150 s of data with rotation every 16 MiB (~6 s, ~50 MB, 3+ files);
``make bench`` runs the full hour of the shipped config (rotation every 256 MB, ~1.2 GB, ~80 s on 2 busy
cores) with ``GVT_SOAK_SECONDS=3600``, as issue 18 allowed to keep ``make test`` within its 10 minutes.
The bound asserted is the same in both: the long session peaks where a 10 s one does.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from daq.log.proto import decode_block
from daq.log.reader import LogReader

from .conftest import gvt_command

CFG = Path(__file__).resolve().parents[1] / "configs" / "sessions" / "soak_1h.toml"
SECONDS = float(os.environ.get("GVT_SOAK_SECONDS", 150))
#: rotation: the config's 256 MB for the hour; 16 MiB for the suite's minutes, so they rotate as often
ROTATE = 268435456 if SECONDS >= 3600 else 16777216


WRAPPER = (
    "import resource, subprocess, sys; p = subprocess.run(sys.argv[1:]); "
    "print('PEAK_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(p.returncode)"
)


def _record(cfg: Path, out: Path, *extra: str) -> tuple[subprocess.CompletedProcess, float]:
    """Run the recorder under a wrapper whose only child it is: returns (result, recorder peak RSS in MB)."""
    p = subprocess.run(
        [sys.executable, "-c", WRAPPER, *gvt_command(), "record", str(cfg), "--out", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert p.returncode == 0, p.stderr
    return p, int(p.stdout.rsplit("PEAK_KB", 1)[1].split()[0]) / 1024


def test_long_session_with_bounded_memory_and_rotation(tmp_path):
    """Memory must not grow with the session: minutes (or the hour) of data peak where 10 s does.

    The first run also warms numba's on-disk cache, so neither measurement includes JIT compilation
    (a cold first run compiles the kernels once: ~13 s, ~440 MB peak). Absolute peaks measured: 270 MB
    in a long-lived checkout, ~315 MB in a fresh clone — the import baseline (numba/llvmlite, scipy,
    numpy…), not the session; the issue's 300 MB is a reported target, the growth bound is asserted.
    """
    cfg = tmp_path / "soak.toml"
    text = CFG.read_text()
    assert "duration = 3600.0" in text and "rotate_bytes = 268435456" in text
    cfg.write_text(text.replace("duration = 3600.0", f"duration = {SECONDS}").replace(
        "rotate_bytes = 268435456", f"rotate_bytes = {ROTATE}"))  # fmt: skip
    _, short_mb = _record(cfg, tmp_path / "short.mcap", "--duration", "10")
    for f in tmp_path.glob("short*.mcap"):
        f.unlink()
    out = tmp_path / "soak.mcap"
    p, peak_mb = _record(cfg, out)
    try:
        assert "lost: nothing" in p.stdout and "writer overruns: 0" in p.stdout
        files = sorted(tmp_path.glob("soak*.mcap"))
        assert len(files) >= (4 if SECONDS >= 3600 else 2)  # ~1.4 bytes a sample: 1.2 GB an hour, ~50 MB in 150 s
        total = 0
        for f in files:
            r = LogReader(f)
            assert r.report.complete
            info = r.streams()["dev0"]
            for _ch, msg in r.iter_messages([info.topic]):
                total += decode_block(msg.data, view=True).data.shape[0]  # a view: the count, no copy of 1 GB
        assert total == SECONDS * 16384  # every sample of the session, across the rotated files
        assert peak_mb <= short_mb + 25, f"peak {peak_mb:.0f} MB for {SECONDS:g} s vs {short_mb:.0f} MB for 10 s: memory grows"
        assert peak_mb <= 400, f"peak RSS {peak_mb:.0f} MB"
    finally:
        for f in tmp_path.glob("soak*.mcap"):
            f.unlink()
