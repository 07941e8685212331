"""DBC → channel layout: which CAN frame carries which channel samples, and how to decode them fast.

Convention (docs/protocols/can.md): a *sample message* in the DBC has

* an unsigned ``FrameCounter`` signal (any length up to 32 bits): frames sent by that node for that
  message, modulo ``2**length``. The first sample index of the frame is ``FrameCounter * spf`` (after
  unwrapping), so a dropped frame shows up as an exact index jump;
* signals named ``<channel>_<k>`` for ``k = 0 … spf-1`` (``spf`` = samples per frame): sample ``k`` of the
  frame for that channel, with the DBC's scale/offset/unit giving SI units.

Messages without a ``FrameCounter`` are ignored. The users map their own nodes by writing a DBC in this
convention; nothing else is hard-coded.

Decoding: :meth:`MessageLayout.decode_cantools` decodes with ``cantools`` (the reference); when every
signal is byte-aligned little-endian (8/16/32-bit counter, 8/16-bit samples) a numpy fast path decodes
many frames at once (:meth:`MessageLayout.decode_frames`); tests prove both agree bit for bit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cantools
import numpy as np

COUNTER = "FrameCounter"
_SAMPLE_RE = re.compile(r"^(?P<ch>.+)_(?P<k>\d+)$")


class DbcLayoutError(ValueError):
    """The DBC does not follow the sample-message convention (message says what and where)."""


@dataclass(frozen=True)
class MessageLayout:
    name: str
    frame_id: int
    is_extended: bool
    is_fd: bool
    length: int  # bytes
    counter_bits: int
    spf: int  # samples per frame (per channel)
    channels: tuple[str, ...]
    units: tuple[str, ...]
    scales: np.ndarray  # (n_channels,) float64
    offsets: np.ndarray  # (n_channels,) float64
    message: cantools.database.can.Message  # the cantools message (reference decoder)
    # fast path (None when a signal is not byte aligned little-endian)
    counter_byte: int | None
    sample_bytes: np.ndarray | None  # (spf, n_channels) byte offset of each sample's low byte
    sample_bits: int | None  # 8 or 16
    sample_signed: bool

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def counter_modulus(self) -> int:
        return 1 << self.counter_bits

    @property
    def fast(self) -> bool:
        return self.sample_bytes is not None

    # --- decoding --------------------------------------------------------------------------
    def counter_of(self, data: bytes | bytearray) -> int:
        if self.counter_byte is not None:
            return int.from_bytes(data[self.counter_byte : self.counter_byte + self.counter_bits // 8], "little")
        return int(self.message.decode(bytes(data), decode_choices=False, scaling=False)[COUNTER])

    def accepts(self, msg) -> bool:
        """Does a python-can message have exactly this message's id, kind and length?"""
        return (
            msg.arbitration_id == self.frame_id
            and bool(msg.is_extended_id) == self.is_extended
            and not msg.is_error_frame
            and not msg.is_remote_frame
            and len(msg.data) == self.length
            and (bool(msg.is_fd) == self.is_fd or (not self.is_fd and len(msg.data) <= 8))
        )

    def decode_frames(self, frames: bytes | bytearray, n: int) -> np.ndarray:
        """Samples of ``n`` concatenated frames → float32 (n * spf, n_channels) in SI units."""
        if n == 0:
            return np.empty((0, self.n_channels), np.float32)
        a = np.frombuffer(bytes(frames), np.uint8, count=n * self.length).reshape(n, self.length)
        if self.sample_bytes is None:
            return np.concatenate([self.decode_cantools(bytes(row))[1] for row in a])
        off = self.sample_bytes
        if self.sample_bits == 16:
            raw = a[:, off].astype(np.uint16) | (a[:, off + 1].astype(np.uint16) << 8)
            raw = raw.view(np.int16) if self.sample_signed else raw
        else:
            raw = a[:, off]
            raw = raw.view(np.int8) if self.sample_signed else raw
        out = raw.reshape(n * self.spf, self.n_channels) * self.scales + self.offsets
        return out.astype(np.float32)

    def decode_fast(self, data: bytes | bytearray) -> tuple[int, np.ndarray]:
        return self.counter_of(data), self.decode_frames(data, 1)

    def decode_cantools(self, data: bytes | bytearray) -> tuple[int, np.ndarray]:
        """Reference decode with cantools: (FrameCounter, float32 (spf, n_channels))."""
        sig = self.message.decode(bytes(data), decode_choices=False)
        out = np.empty((self.spf, self.n_channels), np.float32)
        for j, ch in enumerate(self.channels):
            for k in range(self.spf):
                out[k, j] = sig[f"{ch}_{k}"]
        return int(sig[COUNTER]), out

    # --- encoding (the simulated node) -----------------------------------------------------
    def quantise(self, samples: np.ndarray) -> np.ndarray:
        """SI samples (n, n_channels) → raw integers, rounded and clipped to the signal's range."""
        bits = self.sample_bits or 16
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.sample_signed else (0, (1 << bits) - 1)
        raw = np.rint((np.asarray(samples, np.float64) - self.offsets) / self.scales)
        return np.clip(raw, lo, hi).astype(np.int64)

    def encode_frames(self, first_counter: int, raw: np.ndarray) -> np.ndarray:
        """Many consecutive frames at once: raw (n * spf, n_channels) integers → uint8 (n, length)."""
        n = raw.shape[0] // self.spf
        if self.sample_bytes is None:
            rows = [self.encode(first_counter + i, raw[i * self.spf : (i + 1) * self.spf]) for i in range(n)]
            return np.frombuffer(b"".join(rows), np.uint8).reshape(n, self.length)
        assert self.counter_byte is not None and self.sample_bits is not None
        out = np.zeros((n, self.length), np.uint8)
        ctr = (np.arange(first_counter, first_counter + n, dtype=np.uint64) % self.counter_modulus).astype("<u4")
        nb = self.counter_bits // 8
        out[:, self.counter_byte : self.counter_byte + nb] = ctr.view(np.uint8).reshape(n, 4)[:, :nb]
        v = raw[: n * self.spf].reshape(n, self.spf, self.n_channels).astype(np.int64) & ((1 << self.sample_bits) - 1)
        out[:, self.sample_bytes] = (v & 0xFF).astype(np.uint8)
        if self.sample_bits == 16:
            out[:, self.sample_bytes + 1] = (v >> 8).astype(np.uint8)
        return out

    def encode(self, counter: int, raw: np.ndarray) -> bytes:
        """One frame from a counter value and raw (spf, n_channels) integers."""
        if self.sample_bytes is None:
            values = {COUNTER: counter % self.counter_modulus}
            for j, ch in enumerate(self.channels):
                for k in range(self.spf):
                    values[f"{ch}_{k}"] = int(raw[k, j])
            return bytes(self.message.encode(values, scaling=False, strict=False, padding=True))
        buf = bytearray(self.length)
        assert self.counter_byte is not None
        nb = self.counter_bits // 8
        buf[self.counter_byte : self.counter_byte + nb] = (counter % self.counter_modulus).to_bytes(nb, "little")
        w = self.sample_bits // 8  # type: ignore[operator]
        for (k, j), off in np.ndenumerate(self.sample_bytes):
            buf[off : off + w] = int(raw[k, j]).to_bytes(w, "little", signed=self.sample_signed)
        return bytes(buf)


def _aligned(sig) -> bool:
    return sig.byte_order == "little_endian" and sig.start % 8 == 0 and sig.length in (8, 16, 32)


def layout_of(msg: cantools.database.can.Message) -> MessageLayout:
    by_name = {s.name: s for s in msg.signals}
    if COUNTER not in by_name:
        raise DbcLayoutError(f"message {msg.name}: no {COUNTER} signal")
    ctr = by_name[COUNTER]
    if ctr.is_signed or ctr.length > 32 or ctr.scale != 1 or ctr.offset != 0:
        raise DbcLayoutError(f"message {msg.name}: {COUNTER} must be an unsigned raw integer of <= 32 bits")
    chans: dict[str, dict[int, object]] = {}
    for s in msg.signals:
        if s.name == COUNTER:
            continue
        m = _SAMPLE_RE.match(s.name)
        if m is None:
            raise DbcLayoutError(f"message {msg.name}: signal {s.name} is not named <channel>_<k>")
        chans.setdefault(m["ch"], {})[int(m["k"])] = s
    if not chans:
        raise DbcLayoutError(f"message {msg.name}: no sample signals")
    names = tuple(chans)
    spf = len(chans[names[0]])
    for ch in names:
        if sorted(chans[ch]) != list(range(spf)):
            raise DbcLayoutError(f"message {msg.name}: channel {ch} must have samples {ch}_0 … {ch}_{spf - 1}")
        sigs = list(chans[ch].values())
        if any(
            (s.scale, s.offset, s.unit, s.length, s.is_signed)
            != (sigs[0].scale, sigs[0].offset, sigs[0].unit, sigs[0].length, sigs[0].is_signed)
            for s in sigs
        ):
            raise DbcLayoutError(f"message {msg.name}: samples of channel {ch} differ in scale/offset/unit/length")
    first = [chans[ch][0] for ch in names]
    all_samples = [chans[ch][k] for ch in names for k in range(spf)]
    fast = _aligned(ctr) and all(_aligned(s) and s.length in (8, 16) for s in all_samples)
    bits = {s.length for s in all_samples}
    signed = {s.is_signed for s in all_samples}
    if fast and (len(bits) != 1 or len(signed) != 1):
        fast = False
    sample_bytes = np.array([[chans[ch][k].start // 8 for ch in names] for k in range(spf)], np.intp) if fast else None
    return MessageLayout(
        name=msg.name,
        frame_id=msg.frame_id,
        is_extended=bool(msg.is_extended_frame),
        is_fd=bool(msg.is_fd),
        length=int(msg.length),
        counter_bits=int(ctr.length),
        spf=spf,
        channels=names,
        units=tuple(s.unit or "" for s in first),
        scales=np.array([float(s.scale) for s in first]),
        offsets=np.array([float(s.offset) for s in first]),
        message=msg,
        counter_byte=ctr.start // 8 if fast else None,
        sample_bytes=sample_bytes,
        sample_bits=next(iter(bits)) if fast else (first[0].length if len(bits) == 1 else None),
        sample_signed=bool(first[0].is_signed),
    )


def load_layouts(dbc: str | Path, messages: list[str] | None = None) -> list[MessageLayout]:
    """Sample-message layouts of a DBC file; ``messages`` selects by name (default: every message with a
    ``FrameCounter``)."""
    db = cantools.database.load_file(str(dbc), strict=True)
    if messages is None:
        return [layout_of(m) for m in db.messages if any(s.name == COUNTER for s in m.signals)]
    out = []
    for name in messages:
        try:
            out.append(layout_of(db.get_message_by_name(name)))
        except KeyError:
            known = [m.name for m in db.messages]
            raise DbcLayoutError(f"message {name!r} is not in {dbc} (it has {known})") from None
    return out
