"""The gvtlink serial wire protocol (docs/protocols/serial.md): binary frames and ASCII lines.

Pure and incremental: :class:`FrameDecoder` and :class:`LineDecoder` take whatever bytes the port
delivered (any split, any garbage) and return what they could decode, keeping counters; nothing here
touches a port or a thread, so the decoders are fuzzed and benchmarked on their own.

Binary frame, all fields little-endian::

    0   sync         2  0xA5 0x5A
    2   version      1  1
    3   stream id    1
    4   sequence     4  u32, +1 per frame sent (wraps)
    8   first index  8  u64, device sample index of the frame's first sample
    16  n_samples    2  u16, >= 1
    18  n_channels   1  u8, >= 1
    19  format       1  0 int16, 1 int24, 2 int32, 3 float32
    20  header CRC   2  CRC-16/CCITT-FALSE of bytes 0..19
    22  scales       4 x n_channels f32 (integer formats only): value = raw * scale
    ..  payload      n_samples x n_channels x width, sample-major (all channels of sample 0 first)
    ..  frame CRC    4  CRC-32 (IEEE 802.3, as zlib.crc32) of every byte before it, sync included
"""

from __future__ import annotations

import binascii
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

SYNC = b"\xa5\x5a"
VERSION = 1
HEADER = struct.Struct("<2sBBIQHBB")  # up to the header CRC: 20 bytes
HEADER_LEN = HEADER.size + 2  # with the header CRC
CRC_LEN = 4
MAX_PAYLOAD = 65535 * 255 * 4

FORMATS: dict[str, int] = {"int16": 0, "int24": 1, "int32": 2, "float32": 3}
FORMAT_NAMES = {v: k for k, v in FORMATS.items()}
WIDTH = {0: 2, 1: 3, 2: 4, 3: 4}
BITS = {0: 16, 1: 24, 2: 32}


def crc16_ccitt(data: bytes | bytearray | memoryview, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0; "123456789" -> 0x29B1."""
    return binascii.crc_hqx(data, init)


def crc32(data: bytes | bytearray | memoryview) -> int:
    """CRC-32 (ISO-HDLC / IEEE 802.3): poly 0x04C11DB7 reflected, init/xorout 0xFFFFFFFF; "123456789" -> 0xCBF43926."""
    return zlib.crc32(data) & 0xFFFFFFFF


def frame_overhead(n_channels: int, fmt: str) -> int:
    """Bytes per frame on top of the payload."""
    return HEADER_LEN + CRC_LEN + (4 * n_channels if FORMATS[fmt] != 3 else 0)


def frame_length(n_samples: int, n_channels: int, fmt: str) -> int:
    return frame_overhead(n_channels, fmt) + n_samples * n_channels * WIDTH[FORMATS[fmt]]


# --- encoding ----------------------------------------------------------------------------------
def quantise(values: np.ndarray, scales: np.ndarray, fmt: str) -> np.ndarray:
    """Raw integer codes for ``values`` (n, ch) at per-channel ``scales`` (rounded, clipped to the format)."""
    bits = BITS[FORMATS[fmt]]
    top = 2 ** (bits - 1) - 1
    codes = np.round(np.asarray(values, np.float64) / np.asarray(scales, np.float64))
    return np.clip(codes, -top - 1, top).astype(np.int64)


def encode_frame(
    first_index: int,
    values: np.ndarray,
    fmt: str = "int24",
    scales: np.ndarray | None = None,
    *,
    seq: int = 0,
    stream_id: int = 0,
) -> bytes:
    """One frame. ``values`` (n, ch): SI values (quantised with ``scales``) for integer formats, or float32."""
    code = FORMATS[fmt]
    values = np.asarray(values)
    n, ch = values.shape
    if not (1 <= n <= 65535 and 1 <= ch <= 255):
        raise ValueError(f"a frame holds 1..65535 samples of 1..255 channels, not {n} x {ch}")
    head = HEADER.pack(SYNC, VERSION, stream_id & 0xFF, seq & 0xFFFFFFFF, first_index, n, ch, code)
    parts = [head, struct.pack("<H", crc16_ccitt(head))]
    if code == 3:
        parts.append(np.ascontiguousarray(values, "<f4").tobytes())
    else:
        if scales is None:
            raise ValueError("integer formats need per-channel scales")
        sc = np.asarray(scales, "<f4").reshape(ch)
        parts.append(sc.tobytes())
        raw = quantise(values, sc, fmt)
        if code == 0:
            parts.append(np.ascontiguousarray(raw, "<i2").tobytes())
        elif code == 2:
            parts.append(np.ascontiguousarray(raw, "<i4").tobytes())
        else:
            parts.append(np.ascontiguousarray(raw, "<i4").view(np.uint8).reshape(n * ch, 4)[:, :3].tobytes())
    body = b"".join(parts)
    return body + struct.pack("<I", crc32(body))


# --- decoding ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    stream_id: int
    seq: int
    first_index: int
    fmt: str
    data: np.ndarray  # float32 (n_samples, n_channels), raw * scale
    at: int = 0  # offset in the decoder's byte stream (bytes fed before it) of the frame's sync word

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[0])


@dataclass
class DecoderStats:
    bytes_in: int = 0
    frames_ok: int = 0
    crc_errors: int = 0  # header valid, frame CRC wrong: the frame was dropped
    header_errors: int = 0  # sync found but the header failed its CRC or is invalid
    garbage_bytes: int = 0  # bytes skipped while hunting for a sync word
    resyncs: int = 0  # times the decoder had to hunt (after garbage or a bad frame)
    seq_jumps: int = 0  # frames missing by sequence number (dropped whole, never seen)

    @property
    def frames_bad(self) -> int:
        return self.crc_errors + self.header_errors


def _decode_payload(buf: bytes | bytearray, off: int, n: int, ch: int, code: int) -> np.ndarray:
    if code == 3:
        return np.frombuffer(buf, "<f4", n * ch, off).reshape(n, ch).astype(np.float32)
    scales = np.frombuffer(buf, "<f4", ch, off)
    off += 4 * ch
    if code == 0:
        raw = np.frombuffer(buf, "<i2", n * ch, off)
    elif code == 2:
        raw = np.frombuffer(buf, "<i4", n * ch, off)
    else:
        b = np.frombuffer(buf, np.uint8, n * ch * 3, off).reshape(n * ch, 3)
        wide = np.zeros((n * ch, 4), np.uint8)
        wide[:, 1:] = b
        raw = wide.view("<i4").reshape(n * ch) >> 8  # arithmetic shift sign-extends the 24-bit code
    return (raw.reshape(n, ch).astype(np.float32)) * scales


def _decode_run(buf: bytes | bytearray, off: int, k: int, stride: int, n: int, ch: int, code: int) -> np.ndarray:
    """The payloads of ``k`` frames of one shape lying back to back (``stride`` bytes apart, the first payload at
    ``off``) as float32 (k, n, ch): :func:`_decode_payload`'s arithmetic, element for element, on strided views, so a
    read of several frames costs one set of array operations instead of one per frame (issue 30 item 5: 256 frames a
    second at 15 ch x 16384 Hz, ~8 numpy calls each, were a third of the serial driver's CPU)."""
    if code == 3:
        return np.ndarray((k, n, ch), "<f4", buf, off, (stride, 4 * ch, 4)).astype(np.float32)
    scales = np.ndarray((k, 1, ch), "<f4", buf, off, (stride, 0, 4)).copy()
    off += 4 * ch
    if code in (0, 2):
        w = WIDTH[code]
        raw = np.ndarray((k, n, ch), "<i2" if code == 0 else "<i4", buf, off, (stride, w * ch, w))
    else:
        b = np.ndarray((k, n * ch, 3), np.uint8, buf, off, (stride, 3, 1))
        wide = np.zeros((k, n * ch, 4), np.uint8)
        wide[:, :, 1:] = b
        raw = (wide.view("<i4") >> 8).reshape(k, n, ch)  # arithmetic shift sign-extends the 24-bit code
    return raw.astype(np.float32) * scales


@dataclass
class FrameDecoder:
    """Incremental binary frame decoder: ``feed(bytes) -> [Frame]``; counters in :attr:`stats`.

    Resync rule: scan for the sync word; accept a header only if its CRC-16 holds and its fields are
    valid; accept a frame only if its CRC-32 holds. On any failure skip one byte past the sync word and
    scan again, so a frame hidden behind garbage or behind a bad frame's bytes is still found.
    ``max_frame`` bounds how long a header may make the decoder wait.
    """

    max_frame: int = 1 << 20
    stats: DecoderStats = field(default_factory=DecoderStats)
    _buf: bytearray = field(default_factory=bytearray, repr=False)
    _last_seq: int | None = field(default=None, repr=False)
    _hunting: bool = field(default=False, repr=False)
    _base: int = field(default=0, repr=False)  # stream offset of _buf[0]: Frame.at, to find the read that began a frame

    def reset(self) -> None:
        """Forget buffered bytes (after a reconnect); counters stay."""
        self._base += len(self._buf)
        self._buf.clear()
        self._last_seq = None
        self._hunting = False

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        st = self.stats
        st.bytes_in += len(data)
        buf = self._buf
        buf += data
        good: list[tuple[int, int, int, int, int, int, int, int]] = []  # (pos, total, n, ch, code, sid, seq, first)
        pos = 0
        n_buf = len(buf)
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                # keep a trailing first sync byte: it may be the start of a sync word split across reads
                keep = 1 if pos < n_buf and buf[-1] == SYNC[0] else 0
                self._skip(n_buf - keep - pos)
                pos = n_buf - keep
                break
            if i > pos:
                self._skip(i - pos)
                pos = i
            if n_buf - pos < HEADER_LEN:
                break
            _, ver, sid, seq, first, n, ch, code = HEADER.unpack_from(buf, pos)
            (hcrc,) = struct.unpack_from("<H", buf, pos + HEADER.size)
            total = 0
            if (
                ver == VERSION
                and n >= 1
                and ch >= 1
                and code in WIDTH
                and hcrc == crc16_ccitt(memoryview(buf)[pos : pos + HEADER.size])
            ):
                total = HEADER_LEN + (4 * ch if code != 3 else 0) + n * ch * WIDTH[code] + CRC_LEN
            if total == 0 or total > self.max_frame:
                st.header_errors += 1
                self._skip(1)
                pos += 1
                continue
            if n_buf - pos < total:
                break
            mv = memoryview(buf)
            (fcrc,) = struct.unpack_from("<I", buf, pos + total - CRC_LEN)
            ok = fcrc == crc32(mv[pos : pos + total - CRC_LEN])
            mv.release()
            if not ok:
                st.crc_errors += 1
                self._skip(1)
                pos += 1
                continue
            if self._last_seq is not None:
                st.seq_jumps += (seq - self._last_seq - 1) & 0xFFFFFFFF
            self._last_seq = seq
            good.append((pos, total, n, ch, code, sid, seq, first))
            st.frames_ok += 1
            self._hunting = False
            pos += total
        out = self._frames(buf, good)
        if pos:
            del buf[:pos]
            self._base += pos
        return out

    def _frames(self, buf: bytearray, good: list[tuple[int, int, int, int, int, int, int, int]]) -> list[Frame]:
        """The checked frames of one feed, their payloads decoded run by run (frames of one shape, back to back)."""
        out: list[Frame] = []
        i = 0
        while i < len(good):
            pos, total, n, ch, code = good[i][:5]
            j = i + 1
            while j < len(good) and good[j][:5] == (pos + (j - i) * total, total, n, ch, code):
                j += 1
            data = _decode_run(buf, pos + HEADER_LEN, j - i, total, n, ch, code)
            for k in range(i, j):
                p, _t, _n, _c, _code, sid, seq, first = good[k]
                out.append(Frame(sid, seq, first, FORMAT_NAMES[code], data[k - i], self._base + p))
            i = j
        return out

    def _skip(self, n: int) -> None:
        if n <= 0:
            return
        self.stats.garbage_bytes += n
        if not self._hunting:
            self.stats.resyncs += 1
            self._hunting = True


# --- ASCII lines -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Line:
    index: int
    values: np.ndarray  # float32 (n_channels,)
    at: int = 0  # offset in the decoder's byte stream of the line's first byte (as Frame.at)


@dataclass
class LineStats:
    bytes_in: int = 0
    lines_ok: int = 0
    lines_bad: int = 0  # did not parse (wrong column count, non-numeric, index not an integer)
    comments: int = 0  # empty lines and lines starting with '#'
    overlong: int = 0  # lines longer than max_line (dropped, counted bad too)


@dataclass
class LineDecoder:
    """Incremental ASCII line decoder: ``feed(bytes) -> [Line]``.

    Each line: ``index<sep>v0<sep>v1...`` terminated by LF (CR LF accepted); ``sep`` is ``,`` or ``;``
    or ``\\t`` or runs of spaces (``delimiter="auto"``), or the one given. ``index_column`` holds the
    device's sample counter (an integer); ``columns[k]`` is the column of channel k; value =
    float(column) * scale[k] + offset[k]. Empty lines and lines starting with ``#`` are skipped.
    """

    columns: tuple[int, ...]
    index_column: int = 0
    delimiter: str = "auto"
    scale: tuple[float, ...] | None = None
    offset: tuple[float, ...] | None = None
    max_line: int = 4096
    stats: LineStats = field(default_factory=LineStats)
    _buf: bytearray = field(default_factory=bytearray, repr=False)
    _base: int = field(default=0, repr=False)  # stream offset of _buf[0]

    def __post_init__(self) -> None:
        n = len(self.columns)
        self._scale = np.asarray(self.scale if self.scale is not None else [1.0] * n, np.float64)
        self._offset = np.asarray(self.offset if self.offset is not None else [0.0] * n, np.float64)
        if self._scale.shape != (n,) or self._offset.shape != (n,):
            raise ValueError("scale and offset need one entry per column")
        self._need = max((*self.columns, self.index_column)) + 1

    def reset(self) -> None:
        self._base += len(self._buf)
        self._buf.clear()

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def _split(self, text: str) -> list[str]:
        d = self.delimiter
        if d == "auto":
            for c in (",", ";", "\t"):
                if c in text:
                    return [s.strip() for s in text.split(c)]
            return text.split()
        if d in ("whitespace", " "):
            return text.split()
        return [s.strip() for s in text.split(d)]

    def parse(self, raw: bytes | bytearray, at: int = 0) -> Line | None:
        """One line without its terminator (``at``: its stream offset); None (and counted) if it is a comment or bad."""
        st = self.stats
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            st.lines_bad += 1
            return None
        if not text or text.startswith("#"):
            st.comments += 1
            return None
        cols = self._split(text)
        try:
            if len(cols) < self._need:
                raise ValueError("too few columns")
            idx_text = cols[self.index_column]
            if not idx_text.isdigit():
                raise ValueError("index is not an unsigned integer")
            vals = np.array([float(cols[c]) for c in self.columns], np.float64)
            if not np.all(np.isfinite(vals)):
                raise ValueError("non-finite value")
        except ValueError:
            st.lines_bad += 1
            return None
        st.lines_ok += 1
        return Line(int(idx_text), (vals * self._scale + self._offset).astype(np.float32), at)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Line]:
        self.stats.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list[Line] = []
        start = 0
        while True:
            j = buf.find(b"\n", start)
            if j < 0:
                break
            if j - start > self.max_line:
                self.stats.overlong += 1
                self.stats.lines_bad += 1
            else:
                line = self.parse(buf[start:j], self._base + start)
                if line is not None:
                    out.append(line)
            start = j + 1
        del buf[:start]
        self._base += start
        if len(buf) > self.max_line:  # no terminator in sight: drop it as one bad line
            self.stats.overlong += 1
            self.stats.lines_bad += 1
            self._base += len(buf)
            buf.clear()
        return out


def encode_lines(first_index: int, values: np.ndarray, sep: str = ",", fmt: str = "%.9g") -> bytes:
    """ASCII lines ``index,v0,v1...\\n`` for ``values`` (n, ch); ``%.9g`` round-trips float32 exactly."""
    values = np.asarray(values, np.float32)
    n, ch = values.shape
    row = sep.join([fmt] * ch)
    return "".join(f"{first_index + i}{sep}{row % tuple(values[i].tolist())}\n" for i in range(n)).encode("ascii")
