"""A Modbus register map, described in TOML (``configs/modbus/*.toml``) and validated with pydantic.

One map describes one device: its control registers (start/stop, sample rate, range…), its block FIFO
(ack register, data window, channel scales) and the slow channels the driver polls. A register has an
address (protocol address, 0-based), a type (``int16``, ``uint16``, ``int32``, ``uint32``, ``uint64``,
``float32``), a scale and offset (SI value = raw * scale + offset) and, for 32/64-bit types, a word order
(``big``: high word at the lower address, the Modbus convention; ``little``: low word first). The same
model encodes (the simulated server) and decodes (the driver), so both sides agree by construction.
"""

from __future__ import annotations

import itertools
import struct
import tomllib
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

RegType = Literal["int16", "uint16", "int32", "uint32", "uint64", "float32"]
WordOrder = Literal["big", "little"]

_WORDS = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2, "uint64": 4}
_FMT = {"int16": ">h", "uint16": ">H", "int32": ">i", "uint32": ">I", "float32": ">f", "uint64": ">Q"}
MAX_READ = 125  # registers per read request (Modbus spec)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)  # a NaN scale would decode to NaN


class Register(_Model):
    address: int = Field(ge=0, le=65535)
    type: RegType = "uint16"
    scale: float = 1.0
    offset: float = 0.0
    word_order: WordOrder | None = None  # None: the map's default
    unit: str = ""
    access: Literal["r", "w", "rw"] = "r"
    doc: str = ""

    @property
    def n_registers(self) -> int:
        return _WORDS[self.type]

    @property
    def end(self) -> int:
        return self.address + self.n_registers

    def raw_to_regs(self, raw: int | float, word_order: WordOrder = "big") -> list[int]:
        """A raw (unscaled) value as registers, in the register's word order."""
        if self.type != "float32":
            raw = int(raw)
        b = struct.pack(_FMT[self.type], raw)
        words = [int.from_bytes(b[i : i + 2], "big") for i in range(0, len(b), 2)]
        return words[::-1] if (self.word_order or word_order) == "little" else words

    def regs_to_raw(self, regs: list[int], word_order: WordOrder = "big") -> int | float:
        words = list(regs[: self.n_registers])
        if len(words) != self.n_registers:
            raise ValueError(f"{self.type} needs {self.n_registers} registers, got {len(words)}")
        if (self.word_order or word_order) == "little":
            words = words[::-1]
        return struct.unpack(_FMT[self.type], b"".join(w.to_bytes(2, "big") for w in words))[0]

    def encode(self, value: float, word_order: WordOrder = "big") -> list[int]:
        """An SI value as registers (rounded to the register's resolution)."""
        raw = (value - self.offset) / self.scale
        return self.raw_to_regs(raw if self.type == "float32" else round(raw), word_order)

    def decode(self, regs: list[int], word_order: WordOrder = "big") -> float:
        return float(self.regs_to_raw(regs, word_order)) * self.scale + self.offset


class FifoChannel(_Model):
    name: str
    unit: str = ""
    scale: float = Field(gt=0)  # SI units per int16 count


class Fifo(_Model):
    """Block FIFO: one read/write request (FC 23) acknowledges and reads a frame (docs/protocols/modbus.md)."""

    ack: Register  # uint64: the next sample index the reader wants (everything before it is released)
    window_address: int = Field(ge=0, le=65535)
    window_registers: int = Field(default=MAX_READ, ge=10, le=MAX_READ)
    header_registers: int = 8  # first_index u64, n_samples u16, buffered u32, flags u16
    channels: tuple[FifoChannel, ...]

    def samples_per_frame(self, n_channels: int) -> int:
        return (self.window_registers - self.header_registers) // max(1, n_channels)


class Control(_Model):
    command: Register  # write 1 = start, 0 = stop
    status: Register  # bit 0 running, bit 1 FIFO overflowed since start
    sample_rate: Register
    range: Register
    channel_mask: Register  # bit k: FIFO channel k is acquired
    sample_counter: Register  # samples produced since start


class DeviceInfo(_Model):
    name: str = ""
    unit_id: int = Field(default=1, ge=0, le=255)
    word_order: WordOrder = "big"


class PollChannel(Register):
    name: str


class RegisterMap(_Model):
    device: DeviceInfo = DeviceInfo()
    control: Control
    fifo: Fifo | None = None
    poll: tuple[PollChannel, ...] = ()

    @model_validator(mode="after")
    def _no_overlap(self) -> RegisterMap:
        spans = [(r.address, r.end, n) for n, r in self.control.__dict__.items()]
        spans += [(p.address, p.end, p.name) for p in self.poll]
        if self.fifo:
            spans += [(self.fifo.ack.address, self.fifo.ack.end, "fifo.ack")]
            spans += [(self.fifo.window_address, self.fifo.window_address + self.fifo.window_registers, "fifo.window")]
        spans.sort()
        for (a0, a1, n0), (b0, _b1, n1) in itertools.pairwise(spans):
            if b0 < a1:
                raise ValueError(f"register map: {n0} [{a0}, {a1}) overlaps {n1} at {b0}")
        names = [p.name for p in self.poll]
        if len(set(names)) != len(names):
            raise ValueError("register map: duplicate poll channel names")
        return self

    def poll_channel(self, name: str) -> PollChannel:
        for p in self.poll:
            if p.name == name:
                return p
        raise KeyError(f"register map has no poll channel {name!r}; it has {[p.name for p in self.poll]}")

    def fifo_channel_index(self, name: str) -> int:
        assert self.fifo is not None
        names = [c.name for c in self.fifo.channels]
        if name not in names:
            raise KeyError(f"register map has no FIFO channel {name!r}; it has {names}")
        return names.index(name)


def load_register_map(path: str | Path) -> RegisterMap:
    with open(path, "rb") as f:
        return RegisterMap.model_validate(tomllib.load(f))
