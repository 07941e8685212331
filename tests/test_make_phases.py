"""``make test`` runs the host_timing and alone tests in a phase of their own, from the files its Makefile names: a
test so marked in any other file would run in neither phase. This keeps the two lists one."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_host_timing_and_alone_test_is_in_a_file_the_second_phase_runs():
    make = (ROOT / "Makefile").read_text()
    listed = set(re.search(r"^ALONE_FILES\s*:=\s*(.+)$", make, re.M).group(1).split())
    marks = ["pytest.mark." + m for m in ("host_timing", "alone")]  # split, so this file does not count itself
    marked = {f"tests/{p.name}" for p in (ROOT / "tests").glob("test_*.py") if any(m in p.read_text() for m in marks)}
    assert marked and listed == marked, (sorted(listed), sorted(marked))
    assert '-m "not host_timing and not alone"' in make and '-m "host_timing or alone" $(ALONE_FILES)' in make
