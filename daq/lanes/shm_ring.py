"""A byte ring of sample blocks between two processes: one copy in, a zero-copy view out.

The recorder hands the lanes that may fall behind (near-live analysis, confirmation) to a worker process
(:mod:`daq.lanes.host`). Each block of the analysed stream is copied once into this ring by the recorder's
forwarding thread; the worker reads it in place as a numpy view and releases it when its operator has consumed
it. The ring knows nothing of pipes or processes (the memory is any writable buffer: a ``SharedMemory`` in a
session, a ``bytearray`` in the tests):

* a **header** of two 64-bit positions, counted in bytes since the start and never wrapped: ``write`` (advanced
  only by the writer) and ``read`` (advanced only by the reader). Each side writes only its own word, so no lock
  is shared between the processes; the writer announces a record (a small descriptor through a pipe) only after
  its bytes are in place, and the pipe orders the two;
* **records** stored contiguously (a record that would cross the end starts at the beginning again; the tail
  it skips counts as used until the reader passes it), each rounded up to 8 bytes;
* a writer that never waits: when the ring has no room the record is **shed** and :class:`ShedLog` counts its
  sample range exactly (architecture.md: a lane that falls behind loses its own input and says which).

Why a byte ring and not a queue of pickled arrays: a ``multiprocessing.Queue`` pickles every block (a copy, a
feeder thread and an allocation per block in the recording process); here the recording process does one
``memcpy`` per block and sends ~60 bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

HEADER = 64  # bytes before the data: write position (u64 at 0), read position (u64 at 8), the rest reserved
ALIGN = 8


@dataclass(frozen=True)
class Slot:
    """Where one record lies: ``start`` and ``end`` are positions (bytes since the start, unwrapped)."""

    start: int
    end: int


class ByteRing:
    """Single-writer, single-reader ring of records over ``buf`` (``HEADER`` + capacity bytes)."""

    def __init__(self, buf, capacity: int | None = None) -> None:
        mv = memoryview(buf).cast("B")
        self.capacity = (len(mv) - HEADER if capacity is None else capacity) // ALIGN * ALIGN
        if self.capacity <= 0 or HEADER + self.capacity > len(mv):
            raise ValueError(f"ring buffer of {len(mv)} bytes has no room for its header and data")
        self._mv = mv
        self._head = mv[:16]
        self._pos = np.ndarray((2,), np.uint64, buffer=self._head)
        self._data = mv[HEADER: HEADER + self.capacity]

    def close(self) -> None:
        """Drop every view of the memory (a ``SharedMemory`` cannot close while one is exported)."""
        self._pos = np.zeros(2, np.uint64)  # a closed ring reads as empty
        for v in (self._data, self._head, self._mv):
            v.release()

    @staticmethod
    def size_for(capacity: int) -> int:
        """Bytes of memory a ring of ``capacity`` data bytes needs."""
        return HEADER + capacity // ALIGN * ALIGN

    # --- positions (each process writes only its own) ----------------------------------------------
    @property
    def write_pos(self) -> int:
        return int(self._pos[0])

    @property
    def read_pos(self) -> int:
        return int(self._pos[1])

    def used(self) -> int:
        return self.write_pos - self.read_pos

    def reset(self) -> None:
        """Empty the ring (only when no reader is attached: a restarted worker starts from an empty ring)."""
        self._pos[1] = 0
        self._pos[0] = 0

    # --- writer ------------------------------------------------------------------------------------
    def reserve(self, nbytes: int) -> Slot | None:
        """The slot ``nbytes`` would take now, or None when the ring has no room (nothing changes)."""
        size = -(-nbytes // ALIGN) * ALIGN
        w, r = self.write_pos, self.read_pos
        off = w % self.capacity
        start = w + (self.capacity - off if off + size > self.capacity else 0)  # never split a record
        if size > self.capacity or start + size - r > self.capacity:
            return None
        return Slot(start, start + size)

    def put(self, arr: np.ndarray) -> Slot | None:
        """Copy ``arr`` into the ring (the one copy) and publish it; None (nothing written) when full."""
        slot = self.reserve(arr.nbytes)
        if slot is None:
            return None
        dst = np.ndarray(arr.shape, arr.dtype, buffer=self._data, offset=slot.start % self.capacity)
        dst[...] = arr
        self._pos[0] = slot.end
        return slot

    # --- reader ------------------------------------------------------------------------------------
    def view(self, start: int, shape: tuple[int, ...], dtype=np.float32) -> np.ndarray:
        """The record at ``start`` in place (valid until released: copy what must outlive that)."""
        return np.ndarray(shape, dtype, buffer=self._data, offset=start % self.capacity)

    def release(self, end: int) -> None:
        """Every record before position ``end`` is consumed: the writer may reuse its bytes."""
        if end > self.read_pos:
            self._pos[1] = end


@dataclass
class ShedLog:
    """Exactly which sample ranges were not handed on (per stream, contiguous ranges merged)."""

    blocks: int = 0
    samples: int = 0
    ranges: list[tuple[str, int, int]] = field(default_factory=list)

    def add(self, stream: str, first: int, end: int) -> None:
        if end <= first:
            return
        self.blocks += 1
        self.samples += end - first
        if self.ranges and self.ranges[-1][0] == stream and self.ranges[-1][2] == first:
            self.ranges[-1] = (stream, self.ranges[-1][1], end)
        else:
            self.ranges.append((stream, first, end))
