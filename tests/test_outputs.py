"""Verb outputs: written atomically (temporary file, then rename) and never over the verb's own input."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from daq.outputs import atomic_output, part_path

from .conftest import gvt_command

LOGS = Path(__file__).resolve().parents[1] / "replay_logs"


def _gvt(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*gvt_command(), *args], capture_output=True, text=True, timeout=120)


def test_atomic_output_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        tmp.write_text("half a fi")
        raise RuntimeError("interrupted")
    assert target.read_text() == "old" and not part_path(target).exists()
    with atomic_output(target) as tmp:
        assert tmp.parent == target.parent and tmp != target
        tmp.write_text("new")
    assert target.read_text() == "new" and list(tmp_path.iterdir()) == [target]


@pytest.mark.parametrize(
    "verb",
    [
        ["report", "{log}", "--out", "{log}"],
        ["analyze", "{log}", "--rrd", "{log}"],
        ["confirm", "{log}", "--out", "{log}"],
        ["log", "recover", "{log}", "{log}"],
        ["log", "export", "{log}", "--format", "csv", "--out", "{log}"],
    ],
)
def test_no_verb_writes_over_its_own_input_even_with_overwrite(tmp_path, verb):
    log = tmp_path / "s.mcap"
    shutil.copy(LOGS / "two_dof_3hits.mcap", log)
    before = log.read_bytes()
    p = _gvt(*[a.format(log=log) for a in verb], "--overwrite")
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr
    assert log.read_bytes() == before


def test_analyze_rrd_refuses_an_existing_file_without_overwrite(tmp_path):
    rrd = tmp_path / "a.rrd"
    rrd.write_bytes(b"mine")
    p = _gvt("analyze", str(LOGS / "two_dof_3hits.mcap"), "--rrd", str(rrd))
    assert p.returncode == 2 and "pass --overwrite" in p.stderr and rrd.read_bytes() == b"mine"
