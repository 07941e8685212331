"""``make test`` runs the host_timing tests in a phase of their own, from the files its Makefile names: a test
marked host_timing in any other file would run in neither phase. This keeps the two lists one."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_host_timing_test_is_in_a_file_the_second_phase_runs():
    make = (ROOT / "Makefile").read_text()
    listed = set(re.search(r"^HOST_TIMING_FILES\s*:=\s*(.+)$", make, re.M).group(1).split())
    mark = "pytest.mark." + "host_timing"  # split, so this file does not count itself (a decorator or a param mark)
    marked = {f"tests/{p.name}" for p in (ROOT / "tests").glob("test_*.py") if mark in p.read_text()}
    assert marked and listed == marked, (sorted(listed), sorted(marked))
    assert '-m "not host_timing"' in make and "-m host_timing $(HOST_TIMING_FILES)" in make
