"""Modbus RTU: CRC, framing and device -> ModbusRtuSimServer (pty) -> ModbusDriver (transport = rtu) end to end."""

from __future__ import annotations

import itertools
import os
import select
import struct
import time

import numpy as np
import pytest

from drivers.base import make_driver
from drivers.blocks import BlockStatus
from drivers.modbus.rtu_server import ModbusRtuSimServer, crc16, request_length, with_crc
from drivers.sim.device import HitSchedule, SimulatedDevice
from drivers.sim.faults import Faults

FS = 16384


@pytest.fixture(scope="module")
def device(rigs):
    return SimulatedDevice(rigs("beam_ch4_exp"), HitSchedule.every(2.0, [200.0]), duration=6.0, block_size=256, seed=2)


@pytest.fixture
def rtu(device):
    servers: list[ModbusRtuSimServer] = []

    def make(channels, faults=None, **kw) -> ModbusRtuSimServer:
        srv = ModbusRtuSimServer(device, faults, channels, **kw)
        servers.append(srv)
        line = srv.start()
        assert srv.path.startswith("/dev/") and f"serial_port={srv.path}" in line and "\n" not in line
        return srv

    yield make
    for s in servers:
        s.stop()


def test_crc16_modbus_vector():
    assert crc16(bytes.fromhex("010300000001")) == 0x0A84
    assert with_crc(bytes.fromhex("010300000001")) == bytes.fromhex("01030000000184 0A".replace(" ", ""))
    assert crc16(with_crc(b"\x11\x10\x00\x01\x00\x02\x04\x00\x0a\x01\x02")) == 0  # a frame with its CRC checks to 0


def test_request_length_by_function_code():
    assert request_length(b"\x01") is None
    assert request_length(b"\x01\x03") == request_length(b"\x01\x04") == request_length(b"\x01\x06") == 8
    assert request_length(b"\x01\x10\x00\x00\x00") is None and request_length(b"\x01\x10\x00\x00\x00\x02\x04") == 13
    assert request_length(b"\x01\x17" + bytes(8) + b"\x08") == 21
    assert request_length(b"\x01\x2b") == 0  # unknown: resync


def _exchange(fd: int, frame: bytes, timeout: float) -> bytes:
    os.write(fd, frame)
    out = b""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        r, _, _ = select.select([fd], [], [], left)
        if not r:
            break
        out += os.read(fd, 4096)
        if len(out) >= 5 and len(out) >= (5 if out[1] & 0x80 else 5 + out[2]):
            break
    return out


def test_bad_crc_ignored_next_frame_answered(rtu):
    srv = rtu(["hammer"])
    fd = os.open(srv.path, os.O_RDWR | os.O_NOCTTY)
    try:
        m = srv.map.control.sample_rate  # uint32 at 2 registers
        good = with_crc(struct.pack(">BBHH", 1, 3, m.address, m.n_registers))
        bad = good[:-1] + bytes([good[-1] ^ 0xFF])
        assert _exchange(fd, bad, 0.3) == b""  # silent, like a real slave
        t0 = time.monotonic()
        while srv.bad_crc == 0 and time.monotonic() - t0 < 10.0:  # the server thread counts it when it runs
            time.sleep(0.01)
        assert srv.bad_crc == 1
        # garbage with an unknown function code is skipped byte by byte, then a good frame is answered
        resp = _exchange(fd, b"\x01\x2b\x55" + good, 5.0)  # (returns at the answer's end)
        assert len(resp) == 5 + 2 * m.n_registers and crc16(resp) == 0
        assert resp[:3] == bytes([1, 3, 2 * m.n_registers])
        regs = list(struct.unpack(f">{m.n_registers}H", resp[3:-2]))
        assert m.regs_to_raw(regs, srv.map.device.word_order) == FS
        # a partial frame followed by silence is dropped, the next frame stands alone
        assert _exchange(fd, good[:5], 1.0) == b""  # 1 s of silence: a loaded server thread sees it too
        assert _exchange(fd, good, 5.0)[:3] == bytes([1, 3, 2 * m.n_registers])
        # an exception answer (FC 3 with count 200: illegal data value) comes back framed too
        resp = _exchange(fd, with_crc(struct.pack(">BBHH", 1, 3, 0, 200)), 5.0)
        assert resp == with_crc(bytes([1, 0x83, 3]))
    finally:
        os.close(fd)


def test_fifo_end_to_end_rtu_over_pty(device, rtu):
    ch = ["hammer"]
    srv = rtu(ch)
    n = 3 * FS
    # 8N2 (11 bits a character like 8E1): a pty has no parity, and Linux refuses (EINVAL) a re-configuration of
    # a pty opened with PARENB, which pymodbus does right after opening (inter_byte_timeout)
    cfg = {"transport": "rtu", "serial_port": srv.path, "baudrate": 921600, "parity": "N", "stopbits": 2}
    cfg |= {"channels": ch, "sample_rate": FS, "timeout_s": 2.0}  # no timeout on a healthy link, even loaded
    drv = make_driver("modbus", cfg)
    drv.link_budget().check()  # 1 ch x 16384 Hz at 117 samples/frame = 140 req/s vs 296 req/s at 921600 baud
    blocks = []
    t0 = time.monotonic()
    with drv:
        for b in drv.blocks(timeout=3.0):
            if b.stream == drv.config.stream:
                blocks.append(b)
                if b.end_index >= n:
                    break
            assert time.monotonic() - t0 < 40.0, "driver too slow"
    elapsed = time.monotonic() - t0
    assert 2.5 < elapsed  # the device clock paces the data (loss is what the lines below judge)
    assert blocks[0].first_index == 0
    for a, b in itertools.pairwise(blocks):
        assert b.first_index == a.end_index
    data = np.concatenate([b.data for b in blocks])
    assert data.shape == (blocks[-1].end_index, 1) and data.shape[0] >= n
    ref = device.samples(0, data.shape[0])[:, [device.channels.index("hammer")]]
    scale = srv.map.fifo.channels[srv.map.fifo_channel_index("hammer")].scale
    assert np.abs(data - ref).max() <= scale / 2 + 1e-3  # int16 quantisation
    assert np.abs(ref).max() > 100 * scale  # a hit is in the span: not a trivially flat signal
    assert drv.stats.lost_samples == 0 and drv.stats.gaps == [] and drv.stats.timeouts == 0
    assert srv.bad_crc == 0 and srv.discarded_bytes == 0 and not srv.faults.injected
    assert not srv.running  # the driver sent stop on close


def test_stop_is_prompt_and_releases_the_pty(device):
    srv = ModbusRtuSimServer(device, None, ["hammer"])
    srv.start()
    t0 = time.monotonic()
    srv.stop()
    assert time.monotonic() - t0 < 5.0  # no 30 s read timeout waited out
    assert srv._master is None and srv._slave is None and srv._rtu_thread is None
    srv.stop()  # idempotent


def _rtu_driver(srv, **kw):
    cfg = {"transport": "rtu", "serial_port": srv.path, "baudrate": 921600, "parity": "N", "stopbits": 2}
    return make_driver("modbus", cfg | {"channels": ["hammer"], "sample_rate": FS, "timeout_s": 0.1} | kw)


def _read_until(drv, n):
    blocks = []
    with drv:
        for b in drv.blocks(timeout=3.0):
            blocks.append(b)
            if b.end_index >= n:
                break
    return blocks


def _check_device(device, srv, drv, blocks):
    ref_idx = [device.channels.index("hammer")]
    scale = srv.map.fifo.channels[srv.map.fifo_channel_index("hammer")].scale
    for b in blocks:
        d = drv.stats.device_index(b.stream, b.first_index)
        assert np.abs(b.data - device.samples(d, d + b.n_samples)[:, ref_idx]).max() <= scale / 2 + 1e-3


def test_rtu_device_restart_is_a_new_segment(device, rtu):
    faults = Faults(restart_at_s=1.0, restart_down_s=0.5)
    srv = rtu(["hammer"], faults)
    drv = _rtu_driver(srv)
    blocks = _read_until(drv, int(2.6 * FS))
    (rec,) = faults.restarts
    assert drv.stats.restarts == 1 and drv.stats.rejected_blocks == 0 and srv.unanswered > 0
    k = next(i for i, b in enumerate(blocks) if b.status & BlockStatus.RESTART)
    old, new = blocks[:k], blocks[k:]
    seg = drv.stats.segments[-1]
    assert old[0].first_index == 0 and (seg.device_first, seg.stream_first) == (0, new[0].first_index)
    assert abs(seg.stream_first - rec.stream_index(0, FS)) <= 0.2 * FS  # the host clock: as tests/test_serial.py
    for part in (old, new):
        assert all(b.first_index == a.end_index for a, b in itertools.pairwise(part))
    _check_device(device, srv, drv, blocks)


def test_rtu_stall_loses_nothing(device, rtu):
    faults = Faults(stall_at_s=0.5, stall_for_s=0.5)
    srv = rtu(["hammer"], faults)
    drv = _rtu_driver(srv)
    blocks = _read_until(drv, int(1.6 * FS))
    assert srv.unanswered > 0 and drv.stats.timeouts > 0
    assert drv.stats.lost_samples == 0 and drv.stats.gaps == [] and drv.stats.restarts == 0
    assert blocks[0].first_index == 0 and all(b.first_index == a.end_index for a, b in itertools.pairwise(blocks))
    _check_device(device, srv, drv, blocks)


class _LateAnswerServer(ModbusRtuSimServer):
    """A device that answered a FIFO read after the driver gave up on it: that answer reaches the line just before
    the answer to the driver's next request (what a busy host sees when it reads the port late)."""

    late_before_next = False
    last_fifo = b""

    def _write(self, data: bytes) -> None:
        if self.late_before_next:
            self.late_before_next = False
            data = self.last_fifo + data
        elif data[1] == 23:
            self.last_fifo = data
        super()._write(data)


def test_a_late_fifo_answer_is_not_taken_for_the_status_after_a_reconnect(device):
    """Issue 30, the modbus-rtu disconnect cell under load: a FIFO frame that arrived late was taken by pymodbus for
    the answer to the status read of the reconnect's check (RTU has no transaction id); its first register (the
    index's high word, 0) read as "stopped", and a device that never stopped got a new segment 1-3 samples on."""
    srv = _LateAnswerServer(device, None, ["hammer"])
    srv.start()
    try:
        drv = _rtu_driver(srv, timeout_s=2.0)  # only the injected late answer is stale, not a loaded host's slow one
        drv._connect()  # on this thread, no reading thread: the exchange below is the whole test
        time.sleep(0.05)
        for _ in range(3):
            drv._fifo_step()
        assert drv._next and srv.last_fifo
        srv.late_before_next = True
        drv._check_device()  # what the reading thread does after every reconnect, before its first ack
        assert drv._restart_cause is None and drv._next is not None  # still the same run
        assert drv.stale_responses == 1 and srv.running
    finally:
        drv._client.close()
        srv.stop()
