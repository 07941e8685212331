"""The reliability probe's remaining cases (issue 30, items 6 and 7): each is one line, the right exit code
(2 bad input, 1 runtime failure, 3 data lost) and nothing lost or replaced that the user had.

The live-file case runs a real ``gvt record`` (a short paced session in a child process) and points other
verbs at the file it is writing; the rest call the verbs in this process (``daq.cli.run``), which is cheap.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

from daq.cli import run
from daq.log.reader import LogReader

from .conftest import gvt_command
from .test_record_matrix import session_file

ROOT = Path(__file__).resolve().parents[1]
SMALL_LOG = ROOT / "replay_logs" / "two_dof_3hits.mcap"


def one_error(capsys, code: int, expected: int = 2) -> str:
    """The verb's whole stderr is one ``gvt: error:`` line, nothing on stdout, and the exit code is ``expected``."""
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == expected, (code, out, err)
    assert len(lines) == 1 and lines[0].startswith("gvt: error: ") and "Traceback" not in err, err
    return lines[0]


def _locked(path: Path, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """Wait until the recorder holds its output's lock (earlier than its first status line: seconds saved)."""
    from daq.outputs import lock_holder

    until = time.monotonic() + timeout
    while time.monotonic() < until and proc.poll() is None:
        if lock_holder(path) is not None:
            return
        time.sleep(0.05)
    raise AssertionError(f"the recorder never locked {path}: {proc.poll()}")


# --- item 6: no verb replaces a file a running recorder holds, even with --overwrite ---------------------------
def test_no_verb_replaces_the_log_a_running_recorder_writes(tmp_path, capsys):
    path = session_file(tmp_path, "serial-binary", 16384, duration=20.0, forces=[300.0] * 10)
    live = tmp_path / "live.mcap"
    rec = subprocess.Popen([*gvt_command(), "record", str(path), "--out", str(live)], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _locked(live, rec)
        inode = live.stat().st_ino
        verbs = [  # every verb that writes a file, each told to replace the live log
            ["log", "export", str(SMALL_LOG), "--out", str(live), "--overwrite"],
            ["log", "recover", str(SMALL_LOG), str(live), "--overwrite"],
            ["report", str(SMALL_LOG), "--out", str(live), "--overwrite"],
            ["confirm", str(SMALL_LOG), "--out", str(live), "--overwrite"],
            ["export", str(SMALL_LOG), "--out", str(live), "--overwrite"],
            ["frf", str(SMALL_LOG), "--out", str(live), "--overwrite"],
            ["analyze", str(SMALL_LOG), "--rrd", str(live), "--overwrite"],
            ["simulate", "two_dof", "--out", str(live), "--overwrite"],
        ]
        for argv in verbs:
            line = one_error(capsys, run(argv))
            assert f"(pid {rec.pid})" in line and "recorder" in line and "--overwrite does not" in line, (argv, line)
        assert live.stat().st_ino == inode  # the name still points at the recorder's file
    finally:
        rec.send_signal(signal.SIGTERM)
        rec.communicate(timeout=60)
    assert rec.returncode == 0
    r = LogReader(live)
    assert r.report.complete and r.read_stream("dev0").gaps == []  # the session is whole


def test_the_rename_checks_again_for_a_recorder_that_started_meanwhile(tmp_path):
    """The check before the work is not enough: a recorder can start on the name while a report is built."""
    import fcntl
    import os

    from analysis.errors import BadInput
    from daq.outputs import atomic_output

    target = tmp_path / "t.mcap"
    with pytest.raises(BadInput, match="recorder"), atomic_output(target) as tmp:
        tmp.write_text("new")
        fd = os.open(target, os.O_RDWR | os.O_CREAT)  # a recorder takes the name meanwhile
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.close(fd)
    assert target.read_text() == "" and not list(tmp_path.glob(".*.part*"))  # its file kept, no temporary left
