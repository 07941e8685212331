"""Verified reads (issue 19): bit flips, truncation, decompression bombs — no garbage passed on, no crash.

``make test`` runs seeded subsets (60 offsets a width, every 16th byte of the last 4 KB, 50 cuts) of a 40-chunk log;
``make fuzz`` (GVT_FUZZ_EXAMPLES set) more than the issue's counts on a 120-chunk log: 2000 offsets × flips of 1, 8
and 64 bytes, every byte of the last 4 KB and 500 random cuts. The ``gvt`` verbs run as processes forked from one
server that has loaded their libraries (``gvt_fork``); one ``gvt log export`` is a fresh process.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zstandard

from daq.log.reader import LogReader, LogReadError, read_summary
from daq.log.tools import log_info, recover
from daq.log.writer import ChannelInfo, LogWriter
from daq.replay import iter_log_blocks
from drivers.blocks import SampleBlock

from .conftest import gvt_command

FUZZ = "GVT_FUZZ_EXAMPLES" in os.environ
#: Chunks in the many-chunk log. Reads, scans and recover walk it chunk by chunk (~0.35 ms of Python a chunk),
#: so every fuzz example costs in proportion: make test's 40 chunks (a 170 kB file, its summary and footer still
#: longer than the 4 KB the truncation cuts sweep) keep every record kind and the same outcomes a third as
#: dear as make fuzz's 120.
N_BLOCKS = 120 if FUZZ else 40


def _log(path: Path, n_blocks: int = 120, block: int = 256, n_ch: int = 4) -> np.ndarray:
    """A log of many small chunks (a chunk per flush), blocks of smooth data."""
    i = np.arange(n_blocks * block, dtype=np.float64)[:, None]
    data = np.sin(0.01 * i * (1 + np.arange(n_ch))[None, :]).astype(np.float32)
    chans = [ChannelInfo(f"c{k}", "acceleration", "m/s^2") for k in range(n_ch)]
    names = tuple(c.name for c in chans)
    with LogWriter(path, flush_interval=0.0) as w:
        w.add_stream("dev0", chans, 2048.0, t0_ns=0)
        w.add_attachment("rig/x.toml", b"name = 'x'\n", "application/toml")
        for k in range(n_blocks):
            w.write_block(SampleBlock("dev0", k * block, 2048.0, names, data[k * block : (k + 1) * block]), wait=True)
        w.write_event("suspect_channel", channel="c2", message="channel c2 clipped")
    return data


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> tuple[Path, np.ndarray]:
    p = tmp_path_factory.mktemp("integrity") / "clean.mcap"
    return p, _log(p, N_BLOCKS)


@pytest.fixture(scope="module", params=["small_chunks", "simulated_session"])
def any_clean(request, tmp_path_factory) -> tuple[Path, np.ndarray]:
    """A log of many small chunks, and a simulated session log (hits, events, analysis results, a rig)."""
    p = tmp_path_factory.mktemp("integrity") / "clean.mcap"
    if request.param == "small_chunks":
        return p, _log(p, N_BLOCKS)
    shutil.copy(Path(__file__).resolve().parents[1] / "replay_logs" / "two_dof_3hits.mcap", p)
    d = LogReader(p).read_stream("dev0")
    assert d.index[0] == 0 and len(d.index) == d.index[-1] + 1  # the oracle is the clean file's samples
    return p, d.data


def _check_read(p: Path, data: np.ndarray) -> str:
    """A read either refuses with one line or returns exactly the clean samples: never other values."""
    try:
        d = LogReader(p).read_stream("dev0")
    except LogReadError as exc:
        assert "\n" not in str(exc)
        return "refused"
    if len(d.index) == len(data) and d.data.tobytes() == data.tobytes():
        return "same"
    # only a prefix or a subset can differ in count (a cut footer read by the scan): the values must match
    assert d.data.tobytes() == data[d.index].tobytes()
    return "subset"


def _check_recover(p: Path, tmp: Path, data: np.ndarray) -> tuple[bool, np.ndarray | None]:
    """(data lost, the recovered file's samples of dev0 or None): they read clean and their values are exact."""
    out = tmp / "fixed.mcap"
    out.unlink(missing_ok=True)
    try:
        rep = recover(p, out)
    except LogReadError:
        return False, None
    r = LogReader(out)
    assert r.indexed
    if "dev0" not in r.streams():  # cut before the stream's first chunk: nothing salvaged, and that is loss
        assert rep.data_lost
        return True, None
    d = r.read_stream("dev0", on_damage="refuse")
    assert d.data.tobytes() == data[d.index].tobytes()  # the recovered file reads clean: values exact
    if not rep.data_lost:
        assert len(d.index) == len(data)
    return rep.data_lost, d.data


def _check_replay(p: Path, data: np.ndarray) -> str:
    """The replay/analyze path (``iter_log_blocks``): skipped ranges are named; every block passed on is exact."""
    bad: list[str] = []
    try:
        blocks = list(iter_log_blocks(LogReader(p), bad=bad))
    except LogReadError as exc:
        assert "\n" not in str(exc)
        return "refused"
    got = 0
    for b in blocks:
        assert b.data.tobytes() == data[b.first_index : b.first_index + b.n_samples].tobytes()
        got += b.n_samples
    assert bad or got == len(data) or not LogReader(p).indexed  # anything missing from an indexed log is named
    return "skipped" if bad else "same"


def _record_map(raw: bytes) -> list[tuple[int, int, str]]:
    """(start, end, kind) of every top-level record of a clean log, to say where a flip landed."""
    names = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk", 7: "message_index",
             8: "chunk_index", 9: "attachment", 10: "attachment_index", 11: "statistics", 12: "metadata",
             13: "metadata_index", 14: "summary_offset", 15: "data_end"}  # fmt: skip
    out, pos = [(0, 8, "magic")], 8
    while pos + 9 <= len(raw) - 8:
        op, ln = raw[pos], struct.unpack_from("<Q", raw, pos + 1)[0]
        out.append((pos, pos + 9 + ln, names.get(op, f"op{op}")))
        pos += 9 + ln
    return [*out, (len(raw) - 8, len(raw), "magic")]


@pytest.mark.parametrize("width", [1, 8, 64])
def test_fuzz_flipped_bytes_are_damage_never_data(any_clean, tmp_path, width):
    """Flip ``width`` bytes at seeded random offsets: a read refuses or is exact; the replay/analyze path
    passes on only exact blocks and names what it skipped; info (plain and --verify) and recover never crash;
    the recovered file reads clean. Outcomes per record kind hit are printed (pytest -s): a flip that reads
    "same" landed in bytes that carry no sample (publish times, a message index, the summary's indexes)."""
    src, data = any_clean
    raw = src.read_bytes()
    where = _record_map(raw)
    rng = np.random.default_rng(19 + width)
    n = 2000 if FUZZ else 60  # make fuzz runs 10x the 200 a width; make test a seeded 60 (~0.065 s a flip)
    outcomes: dict[str, dict[str, int]] = {}
    for k in range(n):
        at = int(rng.integers(8, len(raw) - width))
        bad = bytearray(raw)
        bad[at : at + width] = bytes(b ^ 0xFF for b in bad[at : at + width])
        p = tmp_path / f"flip{k}.mcap"
        p.write_bytes(bytes(bad))
        health = "refused"
        for verify in (False, True):
            try:
                health = log_info(p, verify=verify)["health"].split(":")[0].split(" ")[0]
            except LogReadError:
                health = "refused"
        o = f"{_check_read(p, data)}/{_check_replay(p, data)}/{health}"
        _check_recover(p, tmp_path, data)
        kind = next(kd for a, z, kd in where if a <= at < z)
        outcomes.setdefault(kind, {}).setdefault(o, 0)
        outcomes[kind][o] += 1
        p.unlink()
    print(f"width {width}: {outcomes}")
    assert sum(sum(v.values()) for v in outcomes.values()) == n
    if width >= 8:  # a chunk holds most of the file: flips there must have been seen as damage
        assert any(not o.startswith("same/same") for o in outcomes.get("chunk", {"x": 1}))
    if LogReader(src).metadata().get("gvtlink.session", {}).get("format_version") != "1":
        for kind in ("metadata", "attachment"):  # sealed / CRC'd records: a flip there is named by info --verify
            assert all(o.endswith("/damaged") or o.endswith("/refused") for o in outcomes.get(kind, {}))


def _cut_points(size: int) -> list[int]:
    step = 1 if FUZZ else 16  # make test: every 16th byte of the summary and footer (~300 cuts a log), make fuzz every one
    rng = np.random.default_rng(7)
    return sorted({*range(max(9, size - 4096), size, step), *rng.integers(9, size, 500 if FUZZ else 50).tolist()})


def test_fuzz_truncation_recovers_exactly_a_prefix(any_clean, tmp_path):
    src, data = any_clean
    raw = src.read_bytes()
    summary_start = struct.unpack_from("<Q", raw, len(raw) - 8 - 20)[0]
    lost_flags = []
    for cut in _cut_points(len(raw)):
        p = tmp_path / "cut.mcap"
        p.write_bytes(raw[:cut])
        lost, got = _check_recover(p, tmp_path, data)
        if cut >= summary_start:  # a cut in the summary or footer loses no data: every chunk is intact
            assert not lost and got is not None, cut
            assert got.tobytes() == data.tobytes()  # the recovered file's read (read_stream refuses damage)
        lost_flags.append(lost)
    assert any(lost_flags) and not all(lost_flags)


def test_a_flipped_chunk_is_named_with_its_samples(clean, tmp_path, gvt_fork):
    src, data = clean
    raw = bytearray(src.read_bytes())
    with open(src, "rb") as f:
        summ = read_summary(f, len(raw))
    ci = summ.chunk_indexes[len(summ.chunk_indexes) // 2]
    mid = ci.chunk_start_offset + ci.chunk_length - 20
    raw[mid] ^= 0x10
    p = tmp_path / "flip.mcap"
    p.write_bytes(bytes(raw))
    plain = log_info(p)
    assert "ok (summary" in plain["health"]  # plain info claims only what it checked: it read no chunk
    assert plain["named_events"]["suspect channels"] == ["c2: channel c2 clipped"] and plain["events"] == {"suspect_channel": 1}
    info = log_info(p, verify=True)
    s = info["streams"][0]
    v = gvt_fork(["log", "info", "--verify", str(p)])[2]
    assert v.returncode == 3 and "DAMAGED: samples" in v.stdout
    assert gvt_fork(["log", "info", "--verify", str(src)])[2].returncode == 0
    assert info["health"].startswith("damaged") and len(s["damaged"]) == 1
    a, b, _why = s["damaged"][0]
    d = LogReader(p).read_stream("dev0", on_damage="skip")
    missing = sorted(set(range(len(data))) - set(d.index.tolist()))
    assert missing == list(range(a, b))  # exactly the samples that are not there
    assert d.data.tobytes() == data[d.index].tobytes()
    # a real ``gvt`` process (the others here are forked): its exit code and its whole stderr as a shell sees them
    proc = subprocess.run([*gvt_command(), "log", "export", str(p), "--out", str(tmp_path / "x.npz")],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 3 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert f"without the damaged samples [{a}, {b}) of stream dev0" in proc.stderr and "left out as a gap" in proc.stderr
    with np.load(tmp_path / "x.npz") as z:  # the export holds the rest, and says where the damage was
        assert z["dev0/damaged"].tolist() == [[a, b]] and [a, b] in z["dev0/gaps"].tolist()
        assert z["dev0/data"].tobytes() == data[d.index].tobytes()
    assert "suspect channels: c2" in __import__("daq.log.tools", fromlist=["x"]).info_text(info)


#: The modules the ``gvt`` verbs run here import lazily (``python -X importtime``): the fork server loads them once.
_PRELOAD = ("daq.log.tools", "daq.log.export", "daq.replay_session", "daq.outputs", "daq.studies.analyze.batch",
            "daq.studies.confirm", "daq.studies.report.build", "analysis.confirm", "analysis.model.config")  # fmt: skip

#: A fork server: it imports ``daq.cli`` and the verbs' modules once, then for each command line read from stdin
#: forks a child that runs it (``daq.cli.run``, the console script's body) with stdin from /dev/null and
#: stdout/stderr into files, and exits with its code. ``os.wait4`` gives that child's own exit status, peak
#: RSS and CPU (its waited-for children included, as RUSAGE_CHILDREN did for a ``gvt`` subprocess); an
#: uncaught exception prints its traceback to the child's stderr; a child still running after 120 s is
#: ended by its own SIGALRM (exit -14).
_FORK_GVT = """
import importlib, json, os, signal, sys, tempfile, traceback
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot
from daq.cli import run
for m in sys.argv[1:]:
    importlib.import_module(m)
for line in sys.stdin:
    argv = json.loads(line)
    out, err = tempfile.TemporaryFile(), tempfile.TemporaryFile()
    sys.stdout.flush(); sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        signal.alarm(120)
        os.dup2(os.open(os.devnull, os.O_RDONLY), 0); os.dup2(out.fileno(), 1); os.dup2(err.fileno(), 2)
        try:
            rc = run(argv)
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 1
        except BaseException:
            traceback.print_exc(); rc = 1
        sys.stdout.flush(); sys.stderr.flush()
        os._exit(rc)
    _pid, status, ru = os.wait4(pid, 0)
    out.seek(0); err.seek(0)
    print(json.dumps([ru.ru_maxrss, ru.ru_utime + ru.ru_stime, os.waitstatus_to_exitcode(status),
                      out.read().decode(errors="replace"), err.read().decode(errors="replace")]), flush=True)
"""


@pytest.fixture(scope="module")
def gvt_fork(tmp_path_factory):
    """``run(argv) -> (peak resident kB, CPU seconds, the process)``: each ``gvt`` command line its own process,
    forked from one that has paid the imports (0.4-2.5 CPU-s a fresh ``gvt``; 14 + 4 + 6 runs here). The time
    bound below is on CPU time (user + system of the child), the work the input made it do: wall time also
    counts whatever else the machine is running (under the suite's own two workers and a busy host, ``gvt
    report`` took 14 s of wall). The child's CPU is the verb's work alone (each ~0.1 s here), and its peak RSS
    counts the parent's pages it started with (~130 MB of libraries), so the 500 MB bound is stricter than for
    a fresh ``gvt`` (which needed at most ~210 MB)."""
    import json

    log = (tmp_path_factory.mktemp("fork") / "server.err").open("w+")
    server = subprocess.Popen([sys.executable, "-c", _FORK_GVT, *_PRELOAD], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=log, text=True)  # fmt: skip

    def run(argv: list[str]) -> tuple[int, float, subprocess.CompletedProcess]:
        server.stdin.write(json.dumps(argv) + "\n")
        server.stdin.flush()
        line = server.stdout.readline()
        log.seek(0)
        assert line, f"the fork server died: {log.read()}"
        kb, secs, rc, out, err = json.loads(line)
        return int(kb), float(secs), subprocess.CompletedProcess(argv, rc, out, err)

    yield run
    server.stdin.close()
    assert server.wait(timeout=60) == 0
    log.seek(0)
    assert "Traceback" not in log.read()


def test_decompression_bombs_stay_bounded(clean, tmp_path, gvt_fork):
    """A chunk declaring 3 GB, and a 1 GB zstd frame in an unindexed log: damage, under 500 MB and 10 s of CPU."""
    src, _data = clean
    raw = bytearray(src.read_bytes())
    with open(src, "rb") as f:
        ci = read_summary(f, len(raw)).chunk_indexes[3]
    declared = tmp_path / "declared.mcap"
    struct.pack_into("<Q", raw, ci.chunk_start_offset + 9 + 16, 3 << 30)
    declared.write_bytes(bytes(raw))
    cz = zstandard.ZstdCompressor(level=3).compressobj()
    frame = b"".join(cz.compress(bytes(16 << 20)) for _ in range(64)) + cz.flush()
    body = struct.pack("<QQQII", 0, 0, 1000, 0, 4) + b"zstd" + struct.pack("<Q", len(frame)) + frame
    first = src.read_bytes()[: ci.chunk_start_offset]
    bomb = tmp_path / "bomb.mcap"
    bomb.write_bytes(first + bytes([6]) + struct.pack("<Q", len(body)) + body)
    verbs = [v for p in (declared, bomb)
             for v in (["log", "info", "--verify", str(p)], ["log", "info", str(p)],
                       ["log", "recover", str(p), str(tmp_path / "r.mcap"), "--overwrite"],
                       ["log", "export", str(p), "--out", str(tmp_path / "x.npz"), "--overwrite"],
                       ["replay", str(p), "--no-analysis"], ["analyze", str(p)],
                       ["report", str(p), "--out", str(tmp_path / "r.html"), "--overwrite"])]  # fmt: skip
    for verb in verbs:
        kb, secs, proc = gvt_fork(verb)
        assert kb < 500 * 1024 and secs < 10, (verb, kb, secs)
        assert "Traceback" not in proc.stderr, proc.stderr


def test_hostile_rig_attachment_is_refused_before_allocating(tmp_path, gvt_fork):
    p = tmp_path / "rig.mcap"
    text = (Path(__file__).resolve().parents[1] / "configs" / "rigs").glob("*.toml")
    rig = next(iter(sorted(text))).read_text()
    import re

    hostile = re.sub(r"elements\s*=\s*\d+", "elements = 5000", rig)
    chans = [ChannelInfo("c0", "force", "N")]
    with LogWriter(p) as w:
        w.add_stream("dev0", chans, 2048.0, t0_ns=0)
        w.add_attachment("rig/hostile.toml", hostile.encode(), "application/toml")
        w.write_block(SampleBlock("dev0", 0, 2048.0, ("c0",), np.zeros((256, 1), np.float32)), wait=True)
    verbs = [["analyze", str(p)], ["confirm", str(p), "--out", str(tmp_path / "c.mcap")],
             ["report", str(p), "--out", str(tmp_path / "r.html")], ["replay", str(p)]]  # fmt: skip
    for verb in verbs:
        kb, secs, proc = gvt_fork(verb)
        assert kb < 500 * 1024 and secs < 10 and "Traceback" not in proc.stderr, (verb, kb, secs, proc.stderr)
        assert "elements" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, (verb, proc.stderr)


def _chunk_spans(raw: bytes) -> list[tuple[int, int]]:
    """(start, end) of each chunk record with the message-index records that follow it."""
    recs = _record_map(raw)
    spans = []
    for i, (a, z, kind) in enumerate(recs):
        if kind == "chunk":
            j = i + 1
            while recs[j][2] == "message_index":
                z = recs[j][1]
                j += 1
            spans.append((a, z))
    return spans


@pytest.mark.parametrize("case", ["duplicated", "missing", "duplicated_no_summary", "missing_no_summary"])
def test_recover_duplicated_and_missing_chunks(clean, tmp_path, case, gvt_fork):
    """A chunk written twice keeps its samples once (nothing lost: exit 0); a chunk that is gone is data lost
    (exit 3) and exactly its samples are missing — with the summary (which then points at wrong offsets) and
    without it (a copy cut before its summary)."""
    src, data = clean
    raw = src.read_bytes()
    spans = _chunk_spans(raw)
    a, z = spans[len(spans) // 2]
    body = raw[:z] + raw[a:z] + raw[z:] if case.startswith("duplicated") else raw[:a] + raw[z:]
    if case.endswith("no_summary"):
        body = body[: next(r for r in _record_map(body) if r[2] == "data_end")[0]]
    p = tmp_path / "in.mcap"
    p.write_bytes(body)
    proc = gvt_fork(["log", "recover", str(p), str(tmp_path / "out.mcap")])[2]
    assert "Traceback" not in proc.stderr
    d = LogReader(tmp_path / "out.mcap").read_stream("dev0")
    assert d.data.tobytes() == data[d.index].tobytes() and len(set(d.index.tolist())) == len(d.index)
    if case.startswith("duplicated"):
        assert len(d.index) == len(data)
        # without a summary nothing proves the file ended where it should: recover says data may be lost
        assert proc.returncode == (3 if case.endswith("no_summary") else 0), proc.stderr
    else:
        assert proc.returncode == 3 and 0 < len(data) - len(d.index) < len(data) // 4, proc.stderr
        missing = sorted(set(range(len(data))) - set(d.index.tolist()))
        assert missing == list(range(missing[0], missing[-1] + 1))  # one contiguous range: that chunk's
