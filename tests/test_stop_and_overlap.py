"""Issue 30 items 6 and 7, the last four correctness cases (helper H4): a replay of overlapping blocks, an export of
a recovered log whose first chunk was damaged, samples a Modbus device holds at a stop, and a stop request during
the confirmation drain. Each is one line and the right exit code (2 bad input, 1 runtime failure, 3 data lost),
nothing lost without a word."""

from __future__ import annotations

from pathlib import Path

from daq.cli import run

from .test_probe_cases import _overlapping, _rewrite

ROOT = Path(__file__).resolve().parents[1]
SMALL_LOG = ROOT / "replay_logs" / "two_dof_3hits.mcap"


def _replay(log: Path, capsys) -> tuple[int, str, str]:
    code = run(["replay", str(log), "--no-analysis", "--no-frf"])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_replay_of_overlapping_blocks_says_which_samples_disagree_and_exits_3(tmp_path, capsys):
    """D78 for replay: the reader's overlap check was export's and ``--verify``'s only, and a replay published the
    block that disagrees (the fan-out saw samples 2560..3584 twice, with other values, and exited 0). Now the block is
    left out with one line naming the stream and its samples, exit 3; the samples the blocks agree on are replayed
    once."""
    code, out, err = _replay(_overlapping(tmp_path / "o.mcap"), capsys)
    assert code == 3, (code, out, err)
    assert err.count("\n") == 1 and err.startswith("left out 1 overlapping block(s) that disagree"), err
    assert "dev0 samples [2560, 3584) skipped: two overlapping blocks hold them and do not agree" in err, err
    assert "Traceback" not in err
    clean_code, clean_out, _ = _replay(SMALL_LOG, capsys)
    assert clean_code == 0
    line = [ln for ln in out.splitlines() if ln.startswith("replayed dev0:")]
    assert line and line == [ln for ln in clean_out.splitlines() if ln.startswith("replayed dev0:")], (line, clean_out)


def test_a_replay_keeps_a_bit_identical_repeated_block_once_without_a_word(tmp_path, capsys):
    """A block logged twice (a copy, a recover of a duplicated chunk) is the same samples: replayed once, exit 0."""

    def again(m, k):
        return (m.log_time, m.data) if k == 2 else None

    code, out, err = _replay(_rewrite(SMALL_LOG, tmp_path / "d.mcap", extra_block=again), capsys)
    assert code == 0 and "skipped" not in err, (code, out, err)
    _, clean_out, _ = _replay(SMALL_LOG, capsys)
    want = [ln for ln in clean_out.splitlines() if ln.startswith("replayed ")]
    assert want and [ln for ln in out.splitlines() if ln.startswith("replayed ")] == want, out
