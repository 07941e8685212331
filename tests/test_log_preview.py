"""The preview topic (issue 31 item 3): per-channel min/max per bucket beside the sample blocks, plottable in a
viewer. Oracles: the statistics recomputed here bucket by bucket from the samples written (a plain loop, not the
writer's reshape), and what rerun's own MCAP converter and web viewer make of the file."""

from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from daq.log import layout
from daq.log.preview import BUCKET, PreviewEncoder, bucket_stats, preview_schema
from daq.log.reader import LogReader
from daq.log.tools import log_info
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
FS = 8192.0
BLOCK = 1000  # not a multiple of the bucket: blocks start and end off the bucket grid (short buckets at the edges)
NAMES = ("hammer", "a-1", "a 2", "status")  # a name that is not an identifier, and one the block schema renames


def _signals(n: int) -> np.ndarray:
    """Four channels a plot tells apart: a hammer pulse train, two sines of different frequency and size, a ramp."""
    t = np.arange(n) / FS
    d = np.empty((n, len(NAMES)), np.float32)
    d[:, 0] = 300.0 * np.exp(-(((t % 0.5) - 0.05) / 0.002) ** 2)
    d[:, 1] = 2.0 * np.sin(2 * np.pi * 7.0 * t)
    d[:, 2] = 0.5 * np.sin(2 * np.pi * 3.0 * t) + 1.0
    d[:, 3] = t
    return d


def _write(path: Path, data: np.ndarray, preview: bool = True) -> None:
    chans = [ChannelInfo(n, "force" if n == "hammer" else "acceleration", "N" if n == "hammer" else "m/s^2") for n in NAMES]
    with LogWriter(path, preview=preview, fsync=False) as w:
        w.add_stream("dev0", chans, FS)
        for a in range(0, len(data), BLOCK):
            w.write_block(SampleBlock("dev0", a, FS, NAMES, data[a : a + BLOCK]), wait=True)


def _oracle(data: np.ndarray) -> tuple[list[int], np.ndarray]:
    """First sample and (min, max) per channel of every bucket the writer makes: the bucket grid cut at block edges,
    each computed on its own."""
    firsts, stats = [], []
    for a in range(0, len(data), BLOCK):
        b = min(a + BLOCK, len(data))
        edges = sorted({a, b, *range((a // BUCKET + 1) * BUCKET, b, BUCKET)})
        for lo, hi in itertools.pairwise(edges):
            seg = data[lo:hi]
            firsts.append(lo)
            stats.append(np.stack([seg.min(0), seg.max(0)], axis=1))
    return firsts, np.array(stats)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("preview")
    data = _signals(int(2 * FS) + 123)  # 2 s and a bit: the last block is short
    _write(d / "with.mcap", data)
    _write(d / "without.mcap", data, preview=False)
    return d, data


def test_bucket_stats_and_encoding_match_an_independent_computation():
    rng = np.random.default_rng(3)
    data = rng.normal(size=(1000, 5)).astype(np.float32)
    b = bucket_stats(100, data)
    assert b.first.tolist() == [100, *range(256, 1100, 256)] and b.count.sum() == 1000
    assert b.count[0] == 156 and b.count[-1] == 1100 - 1024  # the short buckets at the block's edges
    name, fds = preview_schema("dev0", [f"c{k}" for k in range(5)])
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    for raw, first, n in zip(PreviewEncoder(5).encode(b), b.first, b.count, strict=True):
        m = cls.FromString(raw)  # decoded by protobuf's own library from the schema, not by our encoder's layout
        seg = data[first - 100 : first - 100 + n]
        assert (m.first_index, m.n_samples) == (first, n)
        for k in range(5):
            assert getattr(m, f"c{k}_min") == seg[:, k].min() and getattr(m, f"c{k}_max") == seg[:, k].max()


def test_readers_ignore_the_preview_and_old_logs_still_read(logs):
    d, data = logs
    for name in ("with.mcap", "without.mcap"):
        r = LogReader(d / name)
        assert list(r.streams()) == ["dev0"]
        np.testing.assert_array_equal(r.read_stream("dev0").data, data)
    info = log_info(d / "with.mcap")
    assert layout.preview_topic("dev0") in info["topics"] and info["health"].startswith("ok")
    assert layout.preview_topic("dev0") not in log_info(d / "without.mcap")["topics"]
    assert log_info(d / "with.mcap", verify=True)["health"].startswith("ok")


def _rerun() -> str:
    from daq.lanes.view import _server_binary

    return _server_binary()


def _convert(log: Path, out: Path) -> Path:
    p = subprocess.run([_rerun(), "mcap", "convert", str(log), "--application-id", "gvtlink", "-o", str(out)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert p.returncode == 0, p.stderr[-2000:]
    return out


def test_rerun_mcap_convert_gives_one_scalar_series_per_channel(logs, tmp_path):
    from rerun.chunk import RrdReader

    d, data = logs
    rrd = _convert(d / "with.mcap", tmp_path / "with.rrd")
    rows, times = [], []
    for ch in RrdReader(rrd).stream():
        rb = ch.to_record_batch()
        col = "gvtlink.Preview_dev0:message"
        if ch.entity_path == "/preview/dev0" and col in rb.schema.names:
            times += rb.column("message_log_time").cast("int64").to_pylist()
            rows += [v[0] for v in rb.column(col).to_pylist()]
    order = np.argsort(times, kind="stable")
    rows = [rows[i] for i in order]
    firsts, want = _oracle(data)
    assert [r["first_index"] for r in rows] == firsts
    # log time of a bucket = its first sample's time (origin 0 here)
    assert np.allclose(np.sort(times), np.array(firsts) * 1e9 / FS, atol=1)
    fields = {"hammer": "hammer", "a-1": "a_1", "a 2": "a_2", "status": "ch_status"}
    for k, name in enumerate(NAMES):
        for j, stat in enumerate(("min", "max")):
            got = np.array([r[f"{fields[name]}_{stat}"] for r in rows], np.float32)  # a float per message: a series
            np.testing.assert_array_equal(got, want[:, k, j], err_msg=f"{name} {stat}")  # samples: exact
    assert not [c for c in RrdReader(_convert(d / "without.mcap", tmp_path / "without.rrd")).stream()
                if c.entity_path.startswith("/preview")]  # fmt: skip


# --- the picture: rerun's web viewer in headless Chromium ---------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Cdp:
    """Chromium's DevTools protocol over ``--remote-debugging-pipe`` (fd 3 in, fd 4 out, NUL-terminated JSON): the
    test polls screenshots until the viewer has drawn, instead of guessing how long its WebAssembly takes to start."""

    def __init__(self, profile: Path, size: tuple[int, int]) -> None:
        r_in, self._w = os.pipe()
        self._r, w_out = os.pipe()

        def fds() -> None:
            os.dup2(r_in, 3)
            os.dup2(w_out, 4)

        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--use-angle=swiftshader",
               "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
               f"--window-size={size[0]},{size[1]}"]  # fmt: skip
        self.proc = subprocess.Popen(cmd, preexec_fn=fds, close_fds=False, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        os.close(r_in)
        os.close(w_out)
        self._buf, self._id = b"", 0

    def call(self, method: str, session: str | None = None, **params) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params, **({"sessionId": session} if session else {})}
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" not in self._buf:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"Chromium closed the DevTools pipe (exit {self.proc.poll()})")
                self._buf += chunk
            raw, self._buf = self._buf.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def close(self) -> None:
        try:
            os.killpg(self.proc.pid, 15)
        except ProcessLookupError:
            pass
        self.proc.wait(timeout=10)
        os.close(self._w)
        os.close(self._r)


def _coloured(png: bytes, box: tuple[int, int, int, int]) -> tuple[int, int]:
    """(pixels, distinct hues) of saturated colour inside ``box`` (x0, y0, x1, y1): rerun's chrome is grey, its
    plot lines are coloured."""
    from io import BytesIO

    from matplotlib.image import imread

    img = (imread(BytesIO(png), format="png")[..., :3] * 255).astype(int)
    x0, y0, x1, y1 = box
    px = img[y0:y1, x0:x1].reshape(-1, 3)
    sat = px[(px.max(1) - px.min(1)) > 80]
    hues = {tuple(c) for c in (sat // 64)}
    return len(sat), len(hues)


@pytest.mark.browser
@pytest.mark.alone
@pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (Debian: apt-get install chromium)")
def test_rerun_web_viewer_plots_the_preview_in_headless_chromium(logs, tmp_path):
    from daq.view.preview import preview_blueprint

    d, _data = logs
    rrd = _convert(d / "with.mcap", tmp_path / "with.rrd")
    rbl = tmp_path / "preview.rbl"
    preview_blueprint(d / "with.mcap", rbl)
    web, grpc = _free_port(), _free_port()
    server = subprocess.Popen([_rerun(), str(rrd), str(rbl), "--web-viewer", "--web-viewer-port", str(web), "--port",
                               str(grpc), "--bind", "127.0.0.1", "--renderer", "webgl"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    size = (1400, 900)
    cdp = None
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:  # the web viewer's HTTP server is up
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", web)) == 0:
                    break
            time.sleep(0.2)
        cdp = _Cdp(tmp_path / "chromium-profile", size)
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy&renderer=webgl"
        target = cdp.call("Target.createTarget", url=url)["targetId"]
        session = cdp.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        plot = (260, 80, size[0] - 40, size[1] - 80)  # right of the side panel, below the top bar, above the time panel
        found, deadline = (0, 0), time.monotonic() + 90  # WebAssembly start-up on a software rasterizer: ~5-20 s here
        while time.monotonic() < deadline:
            png = base64.b64decode(cdp.call("Page.captureScreenshot", session, format="png")["data"])
            found = _coloured(png, plot)
            if found[0] > 3000 and found[1] >= 3:
                break
            time.sleep(1.0)
        (tmp_path / "viewer.png").write_bytes(png)
        # the lines of 4 channels x (min, max) over 2 s: thousands of coloured pixels in several hues; an empty
        # viewport (no blueprint, or no preview) has none there
        assert found[0] > 3000 and found[1] >= 3, f"no plotted signals in the viewer: {found} ({tmp_path / 'viewer.png'})"
    finally:
        if cdp is not None:
            cdp.close()
        os.killpg(server.pid, 15)
        server.wait(timeout=10)


def test_a_session_log_has_a_preview_per_stream_and_log_preview_false_leaves_it_out(tmp_path):
    from mcap.reader import make_reader

    from analysis.model.rigs import open_rig
    from daq.config.session import AnalysisSpec, DeviceSpec, LogSpec, SessionConfig, TriggerSpec
    from daq.session import run_session

    def cfg(preview: bool) -> SessionConfig:
        return SessionConfig(
            name="preview", rig="beam_ch4_exp", duration=1.0, log=LogSpec(preview=preview),
            device=DeviceSpec(driver="sim", config={"paced": False, "block_size": 512, "forces": [700.0], "period": 0.6,
                                                    "physics_seconds": 1.2, "seed": 3}),
            trigger=TriggerSpec(level=20.0, record_length=0.3), analysis=AnalysisSpec(enabled=False),
        )  # fmt: skip

    rig = open_rig("beam_ch4_exp")
    for preview in (True, False):
        out = tmp_path / f"session-{preview}.mcap"
        res = run_session(cfg(preview), rig, out)
        assert res.lost_samples == 0
        s = LogReader(out).read_stream("dev0")
        with open(out, "rb") as f:
            msgs = [(m.log_time, m.data) for _s, c, m in make_reader(f).iter_messages() if c.topic == "/preview/dev0"]
        if not preview:
            assert msgs == []
            continue
        name, fds = preview_schema("dev0", s.channels)
        pool = descriptor_pool.DescriptorPool()
        for fd in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
        got = [cls.FromString(raw) for _t, raw in msgs]
        assert sum(m.n_samples for m in got) == len(s.index) and len(got) == -(-len(s.index) // BUCKET)
        hammer = s.channels.index("hammer")
        peak = max(m.hammer_max for m in got)
        assert peak == s.data[:, hammer].max() > 20.0  # the hit is in the envelope, to the sample
        for m in got[::7]:
            seg = s.data[m.first_index - s.index[0] : m.first_index - s.index[0] + m.n_samples, hammer]
            assert (m.hammer_min, m.hammer_max) == (seg.min(), seg.max())
