"""Session log: layout, writer thread, readers, recovery, export, replay (issue 3)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer

from daq.fanout import END, FanOut
from daq.log.export import export
from daq.log.proto import BlockDecodeError, decode_block, encode_block
from daq.log.reader import LogReader, LogReadError
from daq.log.tools import log_info, recover
from daq.log.writer import ChannelInfo, LogWriter, LogWriterError
from daq.replay import Replayer
from drivers.blocks import SampleBlock

from .conftest import gvt_command, gvt_in_process
from .crash_recorder import block_data

gvt = gvt_in_process  # (exit code, stdout, stderr) in this process (D123); one real process is left, in
# test_truncated_files_salvage_a_prefix, for what a shell sees


ROOT = Path(__file__).resolve().parents[1]


def _chs(n: int, prefix: str = "c") -> list[ChannelInfo]:
    return [ChannelInfo(f"{prefix}{k}", "acceleration", "m/s^2", 1.02, position_m=0.1 * k, model_dof=f"w{k}") for k in range(n)]


def _write_sample_log(path: Path, n_blocks: int = 40, block: int = 256, n_ch: int = 6, **kw) -> np.ndarray:
    rng = np.random.default_rng(1)
    data = rng.standard_normal((n_blocks * block, n_ch)).astype(np.float32)
    data[0, 0], data[1, 0], data[2, 0] = np.float32(-0.0), np.float32(np.inf), np.float32(1e-42)  # bits must survive
    names = tuple(c.name for c in _chs(n_ch))
    with LogWriter(path, **kw) as w:
        w.add_stream("dev0", _chs(n_ch), 2048.0, t0_ns=1_700_000_000_000_000_000)
        w.add_stream("slow", _chs(2, "s"), 100.0, t0_ns=1_700_000_000_000_000_000)
        w.add_metadata("gvtlink.config", {"session": "test", "operator": "R2"})
        w.add_attachment("rig.toml", b"name = 'x'\n", "application/toml")
        for k in range(n_blocks):
            w.write_block(SampleBlock("dev0", k * block, 2048.0, names, data[k * block : (k + 1) * block]), wait=True)
            if k % 10 == 0:
                w.write_block(SampleBlock("slow", k, 100.0, ("s0", "s1"), np.full((1, 2), k, np.float32)), wait=True)
        w.write_event("note", message="operator note")
        w.write_hit({"hit": 0, "index": 100, "peak_force_N": 12.5})
    return data


def test_round_trip_is_bit_identical(tmp_path):
    p = tmp_path / "rt.mcap"
    data = _write_sample_log(p)
    r = LogReader(p)
    assert r.indexed and r.report.complete and not r.report.data_lost
    d = r.read_stream("dev0")
    assert d.data.tobytes() == data.tobytes()
    assert np.array_equal(d.index, np.arange(len(data)))
    assert d.gaps == []
    assert d.channels == [f"c{k}" for k in range(6)]
    # timestamps: log_time = t0 + first_index / fs, exactly
    t0 = 1_700_000_000_000_000_000
    for _ch, msg in r.iter_messages(["/daq/dev0/samples"]):
        b = decode_block(msg.data)
        assert msg.log_time == t0 + round(b.first_index * 1e9 / 2048.0)
        assert b.t0_ns == t0
    md = r.metadata()
    assert md["gvtlink.config"] == {"session": "test", "operator": "R2"}
    cal = json.loads(md["gvtlink.calibration.dev0"]["channels"])
    assert cal[2] == {
        "name": "c2",
        "quantity": "acceleration",
        "unit": "m/s^2",
        "sensitivity_mv_per_unit": 1.02,
        "position_m": 0.2,
        "model_dof": "w2",
        "sensor_model": None,
    }
    assert "software_version" in md["gvtlink.session"]
    assert r.attachments() == {"rig.toml": ("application/toml", b"name = 'x'\n")}
    assert r.json_messages("/daq/events") == [{"kind": "note", "message": "operator note"}]
    assert r.json_messages("/daq/hits")[0]["peak_force_N"] == 12.5
    slow = r.read_stream("slow")
    assert slow.index.tolist() == [0, 10, 20, 30] and slow.gaps == [(1, 10), (11, 20), (21, 30)]


def test_channel_and_time_selection(tmp_path):
    p = tmp_path / "sel.mcap"
    data = _write_sample_log(p)
    d = LogReader(p).read_stream("dev0", ["c4", "c1"], start=1.0, end=2.5)
    m = (np.arange(len(data)) / 2048.0 >= 1.0) & (np.arange(len(data)) / 2048.0 < 2.5)
    assert np.array_equal(d.data, data[m][:, [4, 1]])
    with pytest.raises(LogReadError, match="no channel"):
        LogReader(p).read_stream("dev0", ["nope"])


def test_blocks_decode_with_the_schema_stored_in_the_file(tmp_path):
    """What Foxglove or any protobuf tool does: build the message class from the file's schema."""
    p = tmp_path / "pb.mcap"
    data = _write_sample_log(p, n_blocks=2)
    with open(p, "rb") as f:
        schema, channel, message = next(make_reader(f).iter_messages(topics=["/daq/dev0/samples"]))
    assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    m = cls.FromString(message.data)
    fields = json.loads(channel.metadata["fields"])  # format 2: one packed field per channel (channel-major)
    got = np.stack([np.array(getattr(m, f), dtype=np.float32) for f in fields], axis=1)
    assert got.tobytes() == data[:256].tobytes() and m.stream == "dev0" and m.sample_rate == 2048.0
    # and our decoder reads what the official encoder writes
    assert decode_block(m.SerializeToString()).data.tobytes() == data[:256].tobytes()


@pytest.mark.parametrize("fraction", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
def test_truncated_files_salvage_a_prefix(tmp_path, capsys, fraction):
    p = tmp_path / "full.mcap"
    data = _write_sample_log(p, n_blocks=60, flush_interval=0.0)  # a chunk per item: many small chunks
    raw = p.read_bytes()
    cut = tmp_path / f"cut{int(fraction * 100)}.mcap"
    cut.write_bytes(raw[: int(len(raw) * fraction)])
    r = LogReader(cut)
    assert not r.indexed and r.report.data_lost
    if "dev0" in r.streams():
        d = r.read_stream("dev0")
        n = len(d.index)
        assert d.data.tobytes() == data[:n].tobytes()  # whatever is salvaged is exactly the start
        assert n >= (fraction - 0.2) * len(data)  # loses at most the tail around the cut
    if fraction == 0.5:  # once, a real process: what a shell sees of both verbs on a damaged file
        proc = subprocess.run([*gvt_command(), "log", "info", str(cut)], capture_output=True, text=True, timeout=60)
        code, out, err = proc.returncode, proc.stdout, proc.stderr
    else:
        code, out, err = gvt(capsys, "log", "info", str(cut))
    assert code == 0 and "damaged" in out and "salvaged" in out and "Traceback" not in err
    if fraction == 0.5:
        rec = subprocess.run(
            [*gvt_command(), "log", "recover", str(cut), str(tmp_path / "rec.mcap")], capture_output=True, text=True, timeout=60
        )
        code, err = rec.returncode, rec.stderr
    else:
        code, _out, err = gvt(capsys, "log", "recover", str(cut), str(tmp_path / "rec.mcap"))
    assert code == 3 and "data was lost" in err and "Traceback" not in err
    assert LogReader(tmp_path / "rec.mcap").report.complete


@pytest.mark.parametrize(
    ("content", "text"), [(b"", "empty file"), (b"garbage" * 100, "not an MCAP file"), (b"\x89MCAP0\r\n", "damaged")]
)
def test_bad_files_give_one_clear_line(tmp_path, capsys, content, text):
    p = tmp_path / "bad.mcap"
    p.write_bytes(content)
    code, out, err = gvt(capsys, "log", "info", str(p))
    assert "Traceback" not in err
    lines = [ln for ln in (err + out).splitlines() if ln.strip()]
    assert any(text in ln for ln in lines)
    if code != 0:
        assert code == 2 and len([ln for ln in err.splitlines() if ln.strip()]) == 1


def test_wrong_schema_channel_is_reported_not_crashed(tmp_path, capsys):
    p = tmp_path / "wrong.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel(
            "/daq/dev0/samples",
            "json",
            sid,
            {"stream": "dev0", "sample_rate": "100.0", "t0_ns": "0", "channels": '["a"]', "units": '["m"]'},
        )
        w.add_message(cid, log_time=0, data=b'{"not": "a block"}', publish_time=0)
        w.finish()
    info = log_info(p)
    assert info["streams"][0]["undecodable_blocks"] == 1
    with pytest.raises(LogReadError, match="bad sample block"):
        LogReader(p).read_stream("dev0")
    code, _out, err = gvt(capsys, "log", "export", str(p), "--out", str(tmp_path / "x.npz"))
    assert code == 3 and "bad sample block" in err and "Traceback" not in err  # data lost


def test_sigkill_loses_at_most_about_one_second(tmp_path, capsys):
    out = tmp_path / "crash.mcap"
    fs, n_ch, block = 8192.0, 8, 512
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "crash_recorder.py"), str(out), str(fs), str(n_ch), str(block)],
        stdout=subprocess.PIPE,
        text=True,
    )
    last = 0
    t_end = time.monotonic() + 60.0  # the recorder's own start-up (imports) took over 2 s on a loaded host
    try:
        while time.monotonic() < t_end and last < 2.5 * fs:  # killed once 2.5 s of data were written, however late
            line = proc.stdout.readline()
            if not line:
                break
            last = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    for line in proc.stdout.read().split():  # what it printed before the kill that this test had not read yet
        last = int(line)
    assert last >= 2 * fs  # it really ran
    rec = tmp_path / "recovered.mcap"
    code, _out, err = gvt(capsys, "log", "recover", str(out), str(rec))  # the killed process is the crash recorder
    assert code == 3, err
    d = LogReader(rec).read_stream("dev0")
    n = len(d.index)
    # lost at most ~1 s: the queue (16 x 512 samples = 1 s) plus one flush interval (0.25 s), against the last block
    # the recorder handed its writer (every line it printed, read to the end after the kill)
    assert last - 1.25 * fs - block <= n <= last, (n, last)
    assert d.gaps == [] and np.array_equal(d.index, np.arange(n))
    assert d.data.tobytes() == block_data(0, n, n_ch).tobytes()
    info = json.loads(gvt(capsys, "log", "info", str(rec), "--json")[1])
    assert info["complete"] and info["streams"][0]["samples"] == n and info["streams"][0]["gaps"] == []


def test_overruns_are_counted_and_logged_exactly(tmp_path):
    p = tmp_path / "over.mcap"
    names = ("a",)
    w = LogWriter(p, queue_size=2)
    w.add_stream("dev0", _chs(1, "a"), 1000.0, t0_ns=0)
    gate = threading.Event()
    w._queue.put(("json", "/gate", {}))
    accepted = 0
    for k in range(50):
        ok = w.write_block(SampleBlock("dev0", k * 10, 1000.0, names, np.full((10, 1), k, np.float32)))
        accepted += ok
    gate.set()
    stats = w.close()
    assert stats.overrun_blocks == 50 - accepted and stats.overrun_blocks > 0
    r = LogReader(p)
    events = [e for e in r.json_messages("/daq/events") if e["kind"] == "overrun"]
    assert sum(e["count"] for e in events) == stats.overrun_samples
    d = r.read_stream("dev0")
    info = log_info(p)["streams"][0]
    assert info["overrun_samples"] == stats.overrun_samples  # including a loss at the end, which no gap shows
    assert len(d.index) + stats.overrun_samples == 500
    assert (
        sum(b - a for a, b in d.gaps) + (500 - d.index[-1] - 1 if len(d.index) else 500) + (d.index[0] if len(d.index) else 0)
        == stats.overrun_samples
    )


def test_rotation_by_size_keeps_every_sample(tmp_path):
    p = tmp_path / "rot.mcap"
    names = tuple(f"c{k}" for k in range(4))
    with LogWriter(p, flush_interval=0.0, rotate_bytes=20_000) as w:
        w.add_stream("dev0", _chs(4), 1000.0, t0_ns=0)
        for k in range(100):
            w.write_block(SampleBlock("dev0", k * 100, 1000.0, names, block_data(k * 100, 100, 4)), wait=True)
    files = w.stats.files
    assert len(files) > 2
    idx = np.concatenate([LogReader(f).read_stream("dev0").index for f in files])
    assert np.array_equal(np.sort(idx), np.arange(10_000))
    assert all(LogReader(f).report.complete for f in files)


def test_writer_failure_is_reported_to_the_producer(tmp_path):
    """An output that cannot be written is refused by the constructor, on the caller's thread, as bad input."""
    with pytest.raises(LogWriterError, match="does not exist") as exc:
        LogWriter(tmp_path / "missing-dir" / "x.mcap")
    assert exc.value.exit_code == 2 and "\n" not in str(exc.value)


def test_replay_keeps_blocks_and_indices_and_paces(tmp_path):
    p = tmp_path / "rp.mcap"
    data = _write_sample_log(p, n_blocks=16)
    fan = FanOut()
    sub = fan.subscribe("t", maxsize=1000)
    stats = Replayer(p, fan).run()
    got = [b for b in iter(sub)]
    dev = [b for b in got if b.stream == "dev0"]
    assert [b.first_index for b in dev] == [k * 256 for k in range(16)]
    assert np.concatenate([b.data for b in dev]).tobytes() == data.tobytes()
    assert stats.samples["dev0"] == len(data)
    times = [b.first_index / b.sample_rate for b in got]
    assert times == sorted(times)  # streams interleaved in time order
    fan2 = FanOut()
    t0 = time.monotonic()
    Replayer(p, fan2, speed=8.0).run()  # 2 s of data at 8x
    assert time.monotonic() - t0 >= 0.2


def test_slow_subscriber_drops_its_own_input_and_counts_it():
    fan = FanOut()
    sub = fan.subscribe("slow", maxsize=3)
    for k in range(10):
        fan.publish(SampleBlock("d", k * 5, 10.0, ("a",), np.zeros((5, 1), np.float32)))
    assert sub.dropped_blocks == 7 and sub.dropped_samples == 35
    assert sub.dropped_ranges[0] == ("d", 15, 20)
    fan.close()  # the queue is full and nobody reads: close must not block, END must still arrive
    assert [b.first_index for b in iter(sub)] == [5, 10]
    assert sub.dropped_blocks == 8 and ("d", 0, 5) in sub.dropped_ranges


def test_export_npz_and_csv(tmp_path, capsys):
    p = tmp_path / "ex.mcap"
    data = _write_sample_log(p, n_blocks=8)
    export(p, tmp_path / "x.npz", "npz", ["c3"], 0.25, 0.5)
    with np.load(tmp_path / "x.npz") as z:
        sel = (np.arange(len(data)) >= 512) & (np.arange(len(data)) < 1024)
        assert np.array_equal(z["dev0/data"], data[sel][:, [3]])
        assert z["dev0/index"][0] == 512
    argv = ["--format", "csv", "--stream", "dev0", "--channels", "c0,c5", "--out", str(tmp_path / "x.csv")]
    code, _out, err = gvt(capsys, "log", "export", str(p), *argv)
    assert code == 0, err
    rows = (tmp_path / "x.csv").read_text().splitlines()
    assert rows[0] == "t [s] since 2023-11-14T22:13:20.000000000Z,index,c0 [m/s^2],c5 [m/s^2]" and len(rows) == len(data) + 1
    assert float(rows[5].split(",")[3]) == pytest.approx(float(data[4, 5]), rel=1e-6)


def test_simulated_session_log(tmp_path, capsys):
    out = tmp_path / "s.mcap"
    argv = ["simulate", "beam_ch4_exp", "--forces", "30,800", "--spacing", "0.5", "--duration", "0.5", "--out", str(out)]
    code, _out, err = gvt(capsys, *argv)
    assert code == 0, err
    info = log_info(out)
    s = info["streams"][0]
    assert info["complete"] and info["hits"] == 2 and s["gaps"] == []
    assert s["samples"] == round((0.1 + 0.5 + 0.5) * 16384) and len(s["channels"]) == 15
    r = LogReader(out)
    hits = r.json_messages("/sim/hits")
    assert [h["peak_force_N"] for h in hits] == [30.0, 800.0]
    d = r.read_stream("dev0", ["hammer"])
    i = hits[1]["index"]
    assert np.max(d.data[i : i + 40, 0]) == pytest.approx(800.0, rel=0.02)
    assert "rig/beam_ch4_exp.toml" in r.attachments()
    energy = r.json_messages("/sim/energy")
    assert len(energy) == s["blocks"] and energy[-1]["input_work_J"] > hits[1]["input_energy_J"] * 0.9


# --- fuzz the block decoder: any bytes give a block or a BlockDecodeError -----------------------------


@given(st.binary(max_size=512))
def test_fuzz_decode_block_never_crashes(raw):
    try:
        b = decode_block(raw)
    except BlockDecodeError:
        return
    assert b.data.dtype == np.float32 and b.data.ndim == 2


@given(st.integers(0, 20), st.integers(1, 8), st.integers(-(2**62), 2**62), st.floats(1e-3, 1e6), st.integers(0, 2**31))
def test_property_encode_decode_round_trip(n, c, first, fs, status):
    data = np.arange(n * c, dtype=np.float32).reshape(n, c)
    b = decode_block(encode_block("s", first, fs, data, status, -5))
    assert b.first_index == first and b.sample_rate == fs and b.status == status and b.t0_ns == -5
    assert b.data.shape == (n, c) and np.array_equal(b.data, data)


@given(st.binary(min_size=1, max_size=64), st.integers(0, 200))
def test_fuzz_mutated_block_never_crashes(noise, pos):
    raw = bytearray(encode_block("dev0", 7, 100.0, np.ones((4, 3), np.float32)))
    p = pos % len(raw)
    raw[p : p + len(noise)] = noise
    try:
        decode_block(bytes(raw))
    except BlockDecodeError:
        pass


def test_end_marker_reaches_subscribers():
    fan = FanOut()
    sub = fan.subscribe("x")
    fan.close()
    assert sub.get(timeout=1) is END


def test_recover_of_a_healthy_file_loses_nothing(tmp_path):
    p = tmp_path / "h.mcap"
    data = _write_sample_log(p, n_blocks=5)
    rep = recover(p, tmp_path / "h2.mcap")
    assert not rep.data_lost
    assert LogReader(tmp_path / "h2.mcap").read_stream("dev0").data.tobytes() == data.tobytes()
    assert os.path.getsize(tmp_path / "h2.mcap") > 0


def _raw_log(path: Path, firsts: list[int], bad_at: set[int] = frozenset(), block: int = 64, n_ch: int = 2) -> np.ndarray:
    """A log written record by record (mcap Writer): blocks in the order ``firsts``, logged at their write
    position (so log-time order is not sample order); positions in ``bad_at`` hold bytes that do not decode."""
    rng = np.random.default_rng(3)
    data = rng.standard_normal((max(firsts) + block, n_ch)).astype(np.float32)
    names = [f"c{k}" for k in range(n_ch)]
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        md = {"stream": "dev0", "sample_rate": "1000.0", "t0_ns": "0", "channels": json.dumps(names), "units": '["m","m"]'}
        cid = w.register_channel("/daq/dev0/samples", "protobuf", sid, md)
        for pos, first in enumerate(firsts):
            raw = b"\xff\xff not a block" if pos in bad_at else encode_block("dev0", first, 1000.0, data[first : first + block])
            w.add_message(cid, log_time=pos * 1_000_000, data=raw, publish_time=0, sequence=pos)  # log time: write order
        w.finish()
    return data


def test_replay_reader_streams_restores_order_and_skips_bad_blocks(tmp_path):
    from daq.replay import iter_log_blocks

    p = tmp_path / "ooo.mcap"
    firsts = [k * 64 for k in range(200)]
    firsts[10], firsts[12] = firsts[12], firsts[10]  # two blocks swapped: within the reorder window
    _raw_log(p, firsts)
    got = [b.first_index for b in iter_log_blocks(LogReader(p), reorder=4)]
    assert got == sorted(firsts)
    # memory: the reader holds at most `reorder` decoded blocks — a block 10 places late is yielded where found
    late = [k * 64 for k in range(200)]
    late.insert(20, late.pop(5))
    _raw_log(p, late)
    got = [b.first_index for b in iter_log_blocks(LogReader(p), reorder=4)]
    assert got.index(5 * 64) > 5 and sorted(got) == sorted(late)
    # an undecodable block: skipped and described when asked, else one clear error
    _raw_log(p, [k * 64 for k in range(20)], bad_at={7})
    bad: list[str] = []
    got = [b.first_index for b in iter_log_blocks(LogReader(p), bad=bad)]
    assert got == [k * 64 for k in range(20) if k != 7] and len(bad) == 1 and "sequence 7" in bad[0]
    with pytest.raises(LogReadError, match="bad sample block"):
        list(iter_log_blocks(LogReader(p)))


def test_replay_of_a_log_with_a_bad_block_replays_the_rest(tmp_path, capsys):
    p = tmp_path / "bad.mcap"
    _raw_log(p, [k * 64 for k in range(20)], bad_at={7})
    fan = FanOut()
    sub = fan.subscribe("t", maxsize=1000)
    stats = Replayer(p, fan).run()
    assert stats.samples["dev0"] == 19 * 64 and stats.gaps["dev0"] == [(7 * 64, 8 * 64)] and len(stats.bad_blocks) == 1
    assert len(list(iter(sub))) == 19
    code, _out, err = gvt(capsys, "replay", str(p), "--no-analysis")
    assert code == 3 and "skipped 1 undecodable sample block" in err and "Traceback" not in err


def _chunked_log(path: Path, n: int) -> np.ndarray:
    """A log of ``n`` 256-sample blocks of 6 channels at 2048 Hz in 64 kB chunks (6 kB a block); returns the data."""
    data = np.random.default_rng(n).standard_normal((n * 256, 6)).astype(np.float32)
    names = tuple(c.name for c in _chs(6))
    with LogWriter(path, chunk_size=64 * 1024) as w:
        w.add_stream("dev0", _chs(6), 2048.0, t0_ns=1_700_000_000_000_000_000)
        for k in range(n):
            w.write_block(SampleBlock("dev0", k * 256, 2048.0, names, data[k * 256 : (k + 1) * 256]), wait=True)
    return data


def test_replay_reader_memory_does_not_grow_with_the_log(tmp_path):
    """Blocks are decoded a chunk at a time (time-ordered mcap iteration): holding a whole stream, as file-order
    iteration in mcap 1.6 does, would make the peak grow 4x from the short log to the long one."""
    import tracemalloc

    from daq.replay import iter_log_blocks

    peaks = []
    for n in (40, 160):  # 240 kB and 960 kB of samples in 64 kB chunks
        p = tmp_path / f"m{n}.mcap"
        _chunked_log(p, n)
        r = LogReader(p)
        tracemalloc.start()
        count = sum(1 for _ in iter_log_blocks(r, ["dev0"], reorder=4))
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert count == n
    assert peaks[1] < 1.5 * peaks[0], peaks


def test_recover_and_damaged_reads_hold_a_chunk_not_the_log(tmp_path):
    """`gvt log recover` of an intact log and every read of a damaged one go through the file a chunk at a
    time: their peak memory must not grow with the log (holding the messages, as both did, grew it 2.6–3×
    from the short log to the long one)."""
    import tracemalloc

    peaks: dict[str, list[int]] = {"recover intact": [], "recover damaged": [], "open damaged": []}
    for n in (40, 160):  # 240 kB and 960 kB of samples in 64 kB chunks
        p = tmp_path / f"r{n}.mcap"
        data = _chunked_log(p, n)
        cut = tmp_path / f"cut{n}.mcap"
        raw = p.read_bytes()
        cut.write_bytes(raw[: int(0.9 * len(raw))])
        for key, fn in (
            ("recover intact", lambda p=p, n=n: recover(p, tmp_path / f"ok{n}.mcap", chunk_size=64 * 1024)),
            ("recover damaged", lambda cut=cut, n=n: recover(cut, tmp_path / f"fixed{n}.mcap", chunk_size=64 * 1024)),
            ("open damaged", lambda cut=cut: LogReader(cut).message_count("/daq/dev0/samples")),
        ):
            tracemalloc.start()
            fn()
            peaks[key].append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
        assert LogReader(tmp_path / f"ok{n}.mcap").read_stream("dev0").data.tobytes() == data.tobytes()
        salvaged = LogReader(tmp_path / f"fixed{n}.mcap").read_stream("dev0")
        assert salvaged.data.tobytes() == data[: len(salvaged.index)].tobytes() and len(salvaged.index) >= 0.7 * len(data)
    for key, (short, long) in peaks.items():
        assert long < 1.5 * short, (key, peaks)


def test_fanout_wakes_a_subscriber_at_its_high_water():
    """A subscriber that lets blocks pile up on purpose (the view's frames) is woken when its queue reaches
    ``high_water`` or the source ends — not by a timer, which a burst can outrun."""
    fan = FanOut()
    sub = fan.subscribe("frames", maxsize=8)
    sub.high_water = 3
    blk = SampleBlock("dev0", 0, 1000.0, ("a",), np.zeros((4, 1), np.float32))
    fan.publish(blk)
    fan.publish(blk)
    assert not sub.wake.is_set()
    fan.publish(blk)
    assert sub.wake.is_set()
    sub.wake.clear()
    fan.close()
    assert sub.wake.is_set()


def test_recover_skips_a_corrupt_chunk_of_an_indexed_log_and_says_data_was_lost(tmp_path, capsys):
    """A log whose footer and index are intact but one chunk's bytes are damaged (a bad sector, a bit flip):
    recover rewrites every other chunk and exits 3; a plain whole-log read is one clear error."""
    p = tmp_path / "flip.mcap"
    data = _chunked_log(p, 40)
    with open(p, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 4
    raw = bytearray(p.read_bytes())
    mid = chunks[2].chunk_start_offset + chunks[2].chunk_length // 2
    raw[mid : mid + 64] = bytes(64)
    p.write_bytes(bytes(raw))
    r = LogReader(p)
    assert r.indexed
    with pytest.raises(LogReadError, match="gvt log recover"):
        list(r.iter_messages())
    code, _out, err = gvt(capsys, "log", "recover", str(p), str(tmp_path / "fixed.mcap"))
    assert code == 3 and "data was lost" in err and "Traceback" not in err
    got = LogReader(tmp_path / "fixed.mcap").read_stream("dev0")
    assert 0 < len(got.index) < len(data) and got.gaps  # the damaged chunk's blocks are a gap, the rest is there
    assert got.data.tobytes() == data[got.index].tobytes()
