"""Interoperability: a gvtlink MCAP log is read by the TypeScript MCAP implementation (``@mcap/core`` under node).

The node side (``tests/interop/read_block.mjs``) decompresses the zstd chunks with ``fzstd`` and decodes every
sample block with ``protobufjs``, using only the FileDescriptorSet stored in the log — no hand-written .proto —
and resolves one channel by the Foxglove-style message path ``<topic>.<field>``. Needs ``node`` and ``npm``;
the npm packages (pinned in ``tests/interop/package-lock.json``) are installed once into
``tests/interop/node_modules``. Skipped when node/npm are missing or the registry is unreachable.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from daq.log.proto import block_schema_name, field_names
from daq.log.writer import ChannelInfo, LogWriter
from drivers.blocks import SampleBlock

INTEROP = Path(__file__).resolve().parent / "interop"
NODE_MODULES = INTEROP / "node_modules"
NPM_TIMEOUT = 180
NODE_TIMEOUT = 60
_NETWORK_ERRORS = (
    "ENOTFOUND",
    "EAI_AGAIN",
    "ECONNREFUSED",
    "ECONNRESET",
    "ETIMEDOUT",
    "ENETUNREACH",
    "EHOSTUNREACH",
    "network",
    "proxy",
    "socket hang up",
)

N_SAMPLES, N_CHANNELS = 100, 3
FIRST_INDEX = 2**33 + 7  # exercises int64 beyond 32 bits
SAMPLE_RATE = 1651.5


def _block_data(k: int) -> np.ndarray:
    """A deterministic float32 block (not exactly representable decimals, non-zero mean)."""
    i = np.arange(N_SAMPLES * N_CHANNELS, dtype=np.float64).reshape(N_SAMPLES, N_CHANNELS)
    return (1.5 + np.sin(0.037 * i + k) + 0.01 * (k + 1) * np.arange(N_CHANNELS)).astype(np.float32)


def _installed() -> bool:
    deps = json.loads((INTEROP / "package.json").read_text())["dependencies"]
    return all((NODE_MODULES / name / "package.json").is_file() for name in deps)


@pytest.fixture(scope="module")
def node_reader() -> list[str]:
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip(f"interop test needs node and npm on PATH (node={node}, npm={npm})")
    if not _installed():
        cmd = [
            npm,
            "ci" if (INTEROP / "package-lock.json").is_file() else "install",
            "--no-audit",
            "--no-fund",
            "--no-update-notifier",
            "--loglevel=error",
        ]
        try:
            res = subprocess.run(cmd, cwd=INTEROP, capture_output=True, text=True, timeout=NPM_TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.skip(f"`npm {cmd[1]}` timed out after {NPM_TIMEOUT} s (npm registry unreachable?)")
        out = res.stdout + res.stderr
        if res.returncode != 0:
            hits = [ln.strip() for ln in out.splitlines() if any(e.lower() in ln.lower() for e in _NETWORK_ERRORS)]
            if hits:
                pytest.skip(f"npm registry unreachable, cannot install tests/interop packages: {hits[0][:300]}")
            pytest.fail(f"{' '.join(cmd)} failed (exit {res.returncode}):\n{out[-4000:]}")
        assert _installed(), f"npm finished but packages are missing in {NODE_MODULES}:\n{out[-2000:]}"
    return [node, str(INTEROP / "read_block.mjs")]


@pytest.mark.interop
def test_node_mcap_reads_one_channel_by_message_path(node_reader: list[str], tmp_path: Path) -> None:
    """@mcap/core + protobufjs resolve ``/daq/dev0/samples.<field>`` in every block: one channel's samples,
    contiguous, equal over the whole log to what was written (a Foxglove-style path: no stride, no nesting)."""
    path = tmp_path / "interop.mcap"
    names = ("hammer", "acc-3", "1st")  # not all protobuf identifiers: the fields are acc_3 and ch_1st
    chs = [ChannelInfo(n, "acceleration", "m/s^2", 1.02) for n in names]
    blocks = [_block_data(0), _block_data(1), _block_data(2)]
    with LogWriter(path) as w:
        w.add_stream("dev0", chs, SAMPLE_RATE, t0_ns=0)
        for k, d in enumerate(blocks):
            assert w.write_block(SampleBlock("dev0", FIRST_INDEX + k * N_SAMPLES, SAMPLE_RATE, names, d))

    topic = "/daq/dev0/samples"
    fields = field_names(names)
    res = subprocess.run([*node_reader, str(path), topic, fields[1]], capture_output=True, text=True, timeout=NODE_TIMEOUT)
    assert res.returncode == 0, f"node reader failed (exit {res.returncode}):\n{res.stderr[-4000:]}"
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 1, res.stdout
    got = json.loads(lines[0])

    assert got["schema"] == block_schema_name("dev0")
    assert got["schema_encoding"] == "protobuf"
    assert got["encoding"] == "protobuf"
    assert "zstd" in got["chunk_compression"]  # the node side really decompressed zstd chunks
    assert got["messages"] == len(blocks)
    assert json.loads(got["metadata"]["fields"]) == fields == ["hammer", "acc_3", "ch_1st"]

    first = got["first"]
    assert first["stream"] == "dev0"
    assert int(first["first_index"]) == FIRST_INDEX
    assert first["sample_rate"] == SAMPLE_RATE
    assert first["n_channels"] == N_CHANNELS
    assert first["n_samples"] == N_SAMPLES
    assert first["fields"][-N_CHANNELS:] == fields
    # each message gives one block of the channel; float32 widened to double is exact: compare bit for bit
    assert got["series_lengths"] == [N_SAMPLES] * len(blocks)
    want = np.concatenate([d[:, 1] for d in blocks])
    assert np.array(got["series"], dtype=np.float64).astype(np.float32).tobytes() == want.tobytes()
    assert got["series"] == [float(x) for x in want]
