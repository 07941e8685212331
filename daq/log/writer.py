"""The session log writer: one dedicated thread per MCAP file, fed by a bounded queue.

Why a thread of its own: the ``mcap`` writer keeps the open chunk in memory, compresses it on the
calling thread and never fsyncs (dependency-notes.md §2). Producers (drivers, the session, analysis)
call ``write_*`` which only enqueue; this thread owns the file.

The queue is a memory budget, not a crash bound (issue 30, D67): blocks are bounded by their bytes
(``buffer_bytes``; a recording session gives 256 MiB, ``writer_buffer_mib``) and optionally by their count
(``queue_size``), so a device's burst after a stall or a busy minute on the host waits in memory instead of
being dropped. Control records (streams, metadata, attachments, events, hits, results) have their own
bound (:data:`MAX_CONTROL_ITEMS`) and never wait for block space: a full block budget cannot starve them.
One FIFO keeps their order with the blocks.

Crash safety: every ``flush_interval`` seconds (0.5 s default) the thread closes the open chunk
(``Writer.flush()``), flushes and ``fsync``s, so a SIGKILL loses at most the open chunk (one flush interval
of data) plus the *backlog* at that moment: what is still queued. The backlog is ~0 while the writer keeps
up; ``backlog()`` says it now and at its peak (bytes and seconds of data), and a live recording
(``note_backlog_s``, :data:`BACKLOG_NOTE_S` for a session) writes a peak above it as a ``writer_backlog``
event when the file is finished. (An offline producer runs ahead of real time: its backlog in seconds of data
says nothing about a crash.)

No silent loss: ``write_block`` never blocks; when the budget is exhausted the block is not recorded, its
exact sample range is remembered, and the thread writes an ``overrun`` event to ``/daq/events`` as
soon as it can.

The output is the user's (docs/log-format.md, "Output and writer failures"): the constructor opens it
on the caller's thread and refuses, with one line, a path it cannot write, an existing file (unless
``overwrite``) and a file another recorder holds (an exclusive ``flock`` for the writer's lifetime,
which the kernel drops when a process dies, SIGKILL included). A failure while running (disk full, an
I/O error, the file deleted or moved) never raises into a producer: the thread stops taking data,
counts every later block as lost with its range, makes what was written readable, and ``failure``
holds the one line the session prints before it stops.

One time base (docs/log-format.md, "Time base"): every message's ``log_time`` is the session's origin
(``origin_ns``: UTC ns of the reference device's sample 0 for a recording, 0 for simulated and other
deterministic logs) plus a time on the session's timeline. Producers pass times *relative* to the origin
(or to a stream's own clock, ``clock=``); the writer adds the origin and each stream's offset. A stream
whose offset is not known yet (a second device before the timeline fixed its clock offset) is held here,
bounded by ``max_hold_s``, and registered (channel metadata ``t0_ns`` = origin + offset) once it is.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import queue
import stat
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mcap.writer
import numpy as np
import zstandard
from mcap.opcode import Opcode
from mcap.writer import CompressionType, Writer

from analysis import records
from analysis.errors import BadInput, DataLost, RuntimeFailure
from daq.log import layout
from daq.log.preview import BUCKET, MAX_PREVIEW_CHANNELS, STATS, PreviewEncoder, bucket_stats, preview_fields, preview_schema
from daq.log.proto import block_schema, encode_block
from daq.log.seal import seal
from drivers.blocks import BlockStatus, SampleBlock

EVENT_SCHEMA = records.Event.SCHEMA  # every JSON topic's schema: analysis/records.py (TOPICS)
HIT_SCHEMA = records.Hit.SCHEMA


#: control records queued at most (events, hits, results, metadata: small, and never waiting for block space)
MAX_CONTROL_ITEMS = 100_000
#: a live recording's backlog peak above this many seconds of data is a ``writer_backlog`` event (and said by the session)
BACKLOG_NOTE_S = 1.0

#: /daq/events kept whole in the closing ``gvtlink.events`` record (a storm beyond it: counts only, and
#: ``gvt log info`` reads the topic instead)
MAX_EVENTS_RECORD = 2000

#: zstd level of the log's chunks (D106): 1, where the mcap library uses zstd's default 3. On the recorded beam logs
#: (replay_logs/) level 3 gives 0.858 of the raw chunk at 156 MB/s, level 1 0.910 at 676 MB/s: at 15 ch x 16384 Hz the
#: writer's compression drops from ~0.009 to ~0.002 core for a file ~6 % larger (sensor noise hardly compresses)
ZSTD_LEVEL = 1


class _Zstd:
    """What ``mcap.writer`` calls as its ``zstandard`` module (it has no level of its own): ``compress`` at ZSTD_LEVEL.
    Every mcap writer of the process uses it (the recorder's, export's, recover's): gvtlink writes one kind of chunk."""

    @staticmethod
    def compress(data: bytes) -> bytes:
        return zstandard.compress(data, ZSTD_LEVEL)


mcap.writer.zstandard = _Zstd  # type: ignore[attr-defined]


class LogWriterError(RuntimeFailure):
    """The log writer failed while running (disk full, an I/O error, the writer stalled): exit 1.

    ``str()`` is the one line for the user. Never raised into a producer: the writer reports it through
    ``LogWriter.failure`` and, if nobody read that, from ``close()``.
    """


class LogOutputError(LogWriterError, BadInput):
    """The output cannot be opened for a new log (missing directory, a directory, no permission, a read-only
    file system): exit 2, raised by the constructor on the caller's thread.

    Why both bases: it is a writer problem (``except LogWriterError`` keeps catching every one of them), but
    the user fixes it with another ``--out``, so its kind is BadInput and its exit code 2. ``exit_code`` is
    set here because the MRO would otherwise find RuntimeFailure's 1 first.
    """

    exit_code = 2


class LogOutputExistsError(LogOutputError):
    """The output exists and the caller did not pass ``overwrite``: the file is the user's, left untouched."""


class LogOutputInUseError(LogOutputError):
    """Another recorder (this process or another) holds the output's lock."""


class LogOutputLostError(LogWriterError, DataLost):
    """The output file was deleted while recording: what it held is gone. Exit 3 (DataLost), not 1: the run
    ran, the data did not survive, and the message says which."""

    exit_code = 3


@dataclass
class WriterStats:
    blocks_written: int = 0
    samples_written: int = 0
    messages_written: int = 0
    overrun_blocks: int = 0
    overrun_samples: int = 0
    flushes: int = 0
    files: list[str] = field(default_factory=list)
    #: after a failure: blocks not recorded (offered after it, queued at it, or in the part of the file it cut off)
    lost_after_failure_blocks: int = 0
    lost_after_failure_samples: int = 0
    #: (stream, start_index, end_index) of those, merged; final after ``close()``
    lost_after_failure_ranges: list[tuple[str, int, int]] = field(default_factory=list)
    #: control records (events, hits, JSON, metadata, attachments, streams) dropped after a failure
    dropped_after_failure: int = 0
    #: the block budget (bytes; None: blocks bounded by count only) and the deepest backlog of blocks waiting for
    #: the writer thread, in bytes and in seconds of data (the slowest stream's): a SIGKILL at that moment would
    #: have lost it plus one flush interval; final after ``close()``
    buffer_bytes: int | None = None
    peak_backlog_bytes: int = 0
    peak_backlog_s: float = 0.0


@dataclass(frozen=True)
class ChannelInfo:
    """Calibration of one channel (SEP005-like): what the numbers in the log mean."""

    name: str
    quantity: str
    unit: str
    sensitivity_mv_per_unit: float | None = None
    position_m: float | None = None
    model_dof: str | None = None
    sensor_model: str | None = None


_STOP = object()


class _Backlog:
    """The writer's queue: one FIFO (a stream's registration stays before its blocks) with two bounds — blocks
    by bytes (``max_bytes``) and count (``max_blocks``), control records by count (``max_control``) — so that
    neither kind waits for the other's space. It measures the backlog of blocks: bytes and, per stream, seconds of
    data (the loss a SIGKILL would add to the open chunk), now and at its peak."""

    def __init__(self, max_blocks: int | None, max_bytes: int | None, max_control: int = MAX_CONTROL_ITEMS) -> None:
        self.max_blocks, self.max_bytes, self.max_control = max_blocks, max_bytes, max_control
        self._items: deque = deque()
        self._cv = threading.Condition()
        self.blocks = self.bytes = self.control = 0
        self._samples: dict[str, int] = {}
        self._rates: dict[str, float] = {}
        self.peak_bytes, self.peak_s = 0, 0.0

    def _fits(self, nbytes: int) -> bool:
        if self.blocks == 0:
            return True  # one block larger than the whole budget still goes through: it could never fit otherwise
        if self.max_blocks is not None and self.blocks >= self.max_blocks:
            return False
        return self.max_bytes is None or self.bytes + nbytes <= self.max_bytes

    def put_block(self, block: SampleBlock, timeout: float | None = None) -> bool:
        """Queue a block if the budget has room (waiting up to ``timeout`` for it; None: not at all)."""
        n = int(block.data.nbytes)
        with self._cv:
            if not self._fits(n) and (not timeout or not self._cv.wait_for(lambda: self._fits(n), timeout)):
                return False
            self._items.append(("block", block))
            self.blocks += 1
            self.bytes += n
            k = self._samples[block.stream] = self._samples.get(block.stream, 0) + block.n_samples
            rate = self._rates[block.stream] = float(block.sample_rate) or 1.0
            self.peak_bytes = max(self.peak_bytes, self.bytes)
            self.peak_s = max(self.peak_s, k / rate)
            self._cv.notify_all()
            return True

    def put_control(self, item: Any, timeout: float | None = None, bounded: bool = True) -> None:
        """Queue a control record, waiting up to ``timeout`` for room among control records; raise queue.Full."""
        with self._cv:
            if bounded and self.control >= self.max_control:
                if not self._cv.wait_for(lambda: self.control < self.max_control, timeout):
                    raise queue.Full
            self._items.append(item)
            self.control += 1
            self._cv.notify_all()

    def put(self, item: Any, timeout: float | None = None) -> None:
        """queue.Queue's ``put`` (tests, older callers): a block by its budget (raises queue.Full), else a control record."""
        if isinstance(item, tuple) and item and item[0] == "block":
            if not self.put_block(item[1], timeout):
                raise queue.Full
        else:
            self.put_control(item, timeout, bounded=item is not _STOP)

    def get(self, timeout: float | None = None) -> Any:
        """The oldest item; raise queue.Empty after ``timeout`` (None: wait for ever)."""
        with self._cv:
            if not self._items and not self._cv.wait_for(lambda: bool(self._items), timeout):
                raise queue.Empty
            item = self._items.popleft()
            if isinstance(item, tuple) and item[0] == "block":
                b = item[1]
                self.blocks -= 1
                self.bytes -= int(b.data.nbytes)
                self._samples[b.stream] -= b.n_samples
            else:
                self.control -= 1
            self._cv.notify_all()
            return item

    def qsize(self) -> int:
        return len(self._items)

    def backlog_s(self) -> float:
        """Seconds of data queued now: the slowest stream's (streams are recorded side by side)."""
        with self._cv:
            return max((k / self._rates[s] for s, k in self._samples.items()), default=0.0)

#: held JSON records (waiting for the origin or a stream's offset) before the writer stops waiting
MAX_HELD_RECORDS = 100_000


def wall_at_sample0(block: SampleBlock) -> int | None:
    """Host UTC (ns) of ``block``'s stream sample 0, from its arrival time (``extra['t_host']``, monotonic):
    the wall clock at arrival minus ``end_index / fs``. Late by that block's link latency (< a few ms); None
    without an arrival time. Why monotonic → wall here: the arrival is noted on the monotonic clock (the
    clock-offset estimate's input); the conversion is done once, now."""
    t_host = block.extra.get("t_host")
    if t_host is None:
        return None
    arrival_ns = time.time_ns() - round((time.monotonic() - float(t_host)) * 1e9)
    return arrival_ns - round(block.end_index * 1e9 / block.sample_rate)


#: what a failed write means, said the way a user can act on it
_IO_WHAT = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EIO: "the disk reported an input/output error",
    errno.EROFS: "the file system became read-only",
    errno.EFBIG: "the file grew too large for the file system",
}


# --- opening the output ----------------------------------------------------------------------------
def open_output(path: Path, overwrite: bool) -> int:
    """Open ``path`` for a new log and return its descriptor, locked and empty; raise :class:`LogOutputError`.

    Order matters: open *without* truncating, take the lock, and only then check ``overwrite`` and
    truncate — a file that another recorder is writing is never cut, and "in use" is said before
    "exists" (``--overwrite`` would not help). ``flock`` rather than a pid file: the kernel releases it
    when the holder dies, SIGKILL included, so there are no stale locks to clean up.
    """
    for _attempt in range(3):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
            created = True
            break
        except FileExistsError:
            pass
        except OSError as exc:
            raise _open_error(path, exc) from None
        try:
            fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)
            created = False
            break
        except FileNotFoundError:
            if path.is_symlink():
                raise LogOutputError(f"{path}: a symbolic link to a missing file; remove it or choose another --out") from None
            continue  # removed between the two opens: try again
        except OSError as exc:
            raise _open_error(path, exc) from None
    else:
        raise LogOutputError(f"{path}: keeps appearing and disappearing; choose another --out")
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise LogOutputError(f"{path}: not a regular file; give a file name for --out")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise LogOutputInUseError(_in_use(path, st)) from None
        except OSError as exc:  # a file system without locks (some network mounts): write, unprotected
            if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP):
                raise _open_error(path, exc) from None
        if not created:
            if not overwrite:
                raise LogOutputExistsError(f"{path}: exists; pass --overwrite to replace it")
            os.ftruncate(fd, 0)
    except OSError as exc:
        os.close(fd)
        raise _open_error(path, exc) from None
    except BaseException:
        os.close(fd)
        raise
    return fd


def _open_error(path: Path, exc: OSError) -> LogOutputError:
    e = exc.errno
    if e == errno.ENOENT:
        missing = path.parent
        while not missing.parent.exists() and missing.parent != missing:
            missing = missing.parent
        return LogOutputError(f"{path}: directory {missing} does not exist; create it or choose another --out")
    if e == errno.ENOTDIR:
        return LogOutputError(f"{path}: a part of the path is a file, not a directory; choose another --out")
    if e == errno.EISDIR:
        return LogOutputError(f"{path}: is a directory; give a file name, e.g. {path / 'session.mcap'}")
    if e in (errno.EACCES, errno.EPERM):
        return LogOutputError(f"{path}: permission denied; choose a location you can write to")
    if e == errno.EROFS:
        return LogOutputError(f"{path}: read-only file system; choose a writable location for --out")
    if e in (errno.ENOSPC, errno.EDQUOT):
        return LogOutputError(f"{path}: no space left on the device; free some or choose another disk")
    return LogOutputError(f"{path}: cannot open for writing: {exc.strerror or exc}")


def _in_use(path: Path, st: os.stat_result) -> str:
    pid = _lock_holder(st)
    if pid is None:
        who = "another recorder"
    elif pid == os.getpid():
        who = f"another writer in this process (pid {pid})"
    else:
        who = f"another recorder (pid {pid})"
    return f"{path}: in use by {who}; stop it or choose another --out"


def _lock_holder(st: os.stat_result) -> int | None:
    """The pid holding the flock on this inode, from /proc/locks (Linux); None when it cannot tell."""
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for ln in lines:
        parts = ln.split()
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == key:  # waiters ("->") have parts[1] == "->"
            try:
                return int(parts[4])
            except ValueError:
                return None
    return None


class _Sink:
    """The file as the mcap Writer sees it: ``write`` never raises and never leaves half a record on disk.

    Why: mcap's Writer updates its indexes and statistics around each write; an exception from inside it
    leaves them out of step with the file (a chunk half written, its messages counted, the chunk builder not
    reset) and a later ``finish()`` would write a summary that lies. So the first failed write (ENOSPC, EIO)
    is remembered in ``error``, the file is cut back to where that write began — the end of the last record
    that reached the disk whole — and that write and every later one are kept in memory (at most the open
    chunk and the summary: the writer takes no data after a failure). ``retry()`` tries once to put that tail
    on disk, which gives a complete file; if it fails too, the file stays cut at ``complete``, which the
    tolerant reader and ``gvt log recover`` read to the end.

    ``on_chunk`` is told the logical end offset of every Chunk record, so the writer knows which blocks a
    cut removed.
    """

    def __init__(self, fd: int, path: Path, on_chunk: Callable[[int], None]) -> None:
        self.fd = fd
        self.path = path
        self._on_chunk = on_chunk
        self._pos = 0  # logical end: what mcap's offsets count
        self.complete = 0  # end of the last write that reached the file whole (a record boundary)
        self.synced = 0  # end of what the last successful fsync covered
        self.error: OSError | None = None
        self._tail: bytearray | None = None  # writes since the first failure, from ``complete`` on
        self._retryable = True
        self.cut_failed = False

    def write(self, data: bytes | bytearray | memoryview) -> int:
        n = len(data)
        if n == 0:
            return 0
        start = self._pos
        self._pos += n
        if self._tail is None:
            try:
                _pwrite_all(self.fd, data, start)
                self.complete = self._pos
            except OSError as exc:
                self.error = exc
                self._tail = bytearray(data)
                self._cut()
        else:
            self._tail += data
        if data[0] == Opcode.CHUNK:  # mcap writes each Chunk record with one write of its own
            self._on_chunk(self._pos)
        return n

    def tell(self) -> int:
        return self._pos

    @property
    def whole(self) -> bool:
        """Everything written so far is on disk (no failure, or a retry that succeeded)."""
        return self._tail is None

    def flush(self) -> None:
        """Nothing buffered here: every ``write`` went to the kernel (or, after a failure, to the tail)."""

    def fileno(self) -> int:
        return self.fd

    def sync(self, fsync: bool) -> None:
        """fsync; a failure means the pages since the last good fsync may be gone: cut back to it, no retry."""
        if self._tail is not None:
            return
        if fsync:
            try:
                os.fsync(self.fd)
            except OSError as exc:
                self.error = exc
                self._tail = bytearray()
                self._retryable = False
                self.complete = self.synced
                self._cut()
                return
        self.synced = self._pos

    def retry(self, fsync: bool) -> bool:
        """Put the tail on disk after a failure; True when the whole file is there (or nothing was pending)."""
        if self._tail is None:
            return True
        if not self._retryable:
            return False
        try:
            _pwrite_all(self.fd, self._tail, self.complete)
            if fsync:
                os.fsync(self.fd)
        except OSError:
            self._cut()
            return False
        self.complete = self.synced = self._pos
        self._tail = None
        return True

    def _cut(self) -> None:
        try:
            os.ftruncate(self.fd, self.complete)
        except OSError:
            self.cut_failed = True

    def close(self) -> None:
        """Close the descriptor, which releases the lock."""
        try:
            os.close(self.fd)
        except OSError:
            pass


def _pwrite_all(fd: int, data: bytes | bytearray | memoryview, offset: int) -> None:
    """``pwrite`` until all of ``data`` is written: a short write is how a full disk starts."""
    view = memoryview(data)
    while view:
        n = os.pwrite(fd, view, offset)
        if n <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view = view[n:]
        offset += n


@dataclass
class _Failure:
    """What stopped the writer; ``LogWriter.failure`` builds the line from it and the final counts."""

    kind: str  # "io", "deleted", "moved", "stalled", "error"
    what: str
    file: Path
    moved_to: str | None = None
    outcome: str = "pending"  # "complete", "cut", "cut_failed", "none" (nothing open), "gone" (deleted)
    cut_at: int = 0
    earlier_parts: int = 0


def _io_failure(exc: OSError, file: Path) -> _Failure:
    what = _IO_WHAT.get(exc.errno or 0, "writing failed")
    return _Failure("io", f"the log writer stopped: {what} ({exc.strerror or exc})", file)


class _Stop(Exception):
    """Internal: the writer thread stops with this failure."""

    def __init__(self, failure: _Failure) -> None:
        super().__init__(failure.what)
        self.failure = failure


class LogWriter:
    """Write a session log. Use as a context manager; ``close()`` finalises the file.

    Raises from the constructor only (one line each): :class:`LogOutputError` (exit 2) when ``path`` cannot
    be written, :class:`LogOutputExistsError` (exit 2) when it exists and ``overwrite`` is false,
    :class:`LogOutputInUseError` (exit 2) when another recorder holds it. After that nothing raises into a
    producer: a failure sets ``failed``, ``failure`` is its one line and ``failure_error`` the exception to
    raise (:class:`LogWriterError`, exit 1, or :class:`LogOutputLostError`, exit 3, when the file was
    deleted). ``close()`` raises ``failure_error`` only when nobody read ``failure`` or ``failure_error``.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        queue_size: int | None = 64,
        buffer_bytes: int | None = None,
        chunk_size: int = 4 * 1024 * 1024,
        flush_interval: float = 0.5,
        fsync: bool = True,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        session_metadata: Mapping[str, str] | None = None,
        control_timeout: float = 10.0,
        overwrite: bool = False,
        origin_ns: int | None = 0,
        max_hold_s: float = 5.0,
        note_backlog_s: float | None = None,
        preview: bool = True,
        preview_bucket: int = BUCKET,
    ) -> None:
        self.path = Path(path)
        #: write ``/preview/<stream>`` beside each stream's blocks (daq/log/preview.py), ``preview_bucket`` samples a
        #: message (the benchmark compares others); encoders by stream
        self._preview = bool(preview)
        self._bucket = max(1, int(preview_bucket))
        self._previews: dict[str, PreviewEncoder] = {}
        self._note_backlog_s = note_backlog_s
        self._overwrite = overwrite
        self._queue = _Backlog(None if queue_size is None else max(2, queue_size), buffer_bytes)
        self._chunk_size = chunk_size
        self._flush_interval = flush_interval
        self._fsync = fsync
        self._rotate_bytes = rotate_bytes
        self._rotate_seconds = rotate_seconds
        self._control_timeout = control_timeout
        self._session_meta = {
            "format_version": layout.FORMAT_VERSION,
            "software": "gvtlink",
            "software_version": _version(),
            "created_unix_ns": str(time.time_ns()),
            **dict(session_metadata or {}),
        }
        self.stats = WriterStats(buffer_bytes=buffer_bytes)
        # the time base: origin (None until set_origin) and per-stream offsets (ns after the origin); items
        # that need one not yet known wait in ``_held`` (the writer thread's), at most ``max_hold_s`` per stream
        self._time_lock = threading.Lock()
        self._origin_ns: int | None = None if origin_ns is None else int(origin_ns)
        self._origin_source = "" if origin_ns is None else "default" if origin_ns == 0 else "given"
        self._offsets: dict[str, tuple[int, str]] = {}
        self._time_version = 0  # bumped by set_origin/set_offset: held items are looked at again only then
        self._released_at = -1
        self._max_hold_s = float(max_hold_s)
        self._held: list[tuple] = []
        self._held_samples: dict[str, int] = {}
        self._time_noted = False
        self._data_end_ns: int | None = None  # log time just past the newest sample written (data time reached)
        self._part_stats: dict[str, dict[str, Any]] = {}  # per stream, this part: the gvtlink.streams record
        #: set once the writer has failed (and finalised what it could); the session stops on it
        self.failed = threading.Event()
        self._failure: _Failure | None = None
        self._failure_seen = False
        self._overruns: list[tuple[str, int, int]] = []
        self._overrun_lock = threading.Lock()
        self._acct_lock = threading.Lock()  # durable/lost accounting: read by ``failure`` on other threads
        self._streams: dict[str, dict[str, Any]] = {}  # registered in the thread, replayed on rotation
        self._attachments: list[tuple[str, bytes, str]] = []
        self._metadata: list[tuple[str, dict[str, str]]] = []
        self._rates: dict[str, float] = {}
        # which blocks are where: the open chunk, chunks written since the last fsync (offset, blocks), and
        # per stream [first, end, samples] of everything fsynced; the current part's ranges (for a deletion)
        self._open_blocks: list[tuple[str, int, int]] = []
        self._unsynced: list[tuple[int, list[tuple[str, int, int]]]] = []
        self._durable: dict[str, list[int]] = {}
        self._durable_at_part: dict[str, list[int]] = {}
        self._part_ranges: dict[str, list[list[int]]] = {}
        self._lost: dict[str, list[list[int]]] = {}
        self._closed = False
        self._sink: _Sink | None = None
        self._mcap: Writer | None = None
        if (rotate_bytes is not None or rotate_seconds is not None) and not overwrite:
            self._refuse_existing_parts()
        fd = open_output(self.path, overwrite)  # on the caller's thread: the error is the caller's to report
        self._first_fd: int | None = fd
        self._thread = threading.Thread(target=self._run, name=f"mcap-writer:{self.path.name}", daemon=True)
        self._thread.start()

    # --- producer side -----------------------------------------------------------------------
    @property
    def queue_depth(self) -> int:
        """Items waiting for the writer thread now (for live status and benchmarks)."""
        return self._queue.qsize()

    @property
    def queue_size(self) -> int | None:
        """The most blocks queued at once (None: bounded by ``buffer_bytes`` only)."""
        return self._queue.max_blocks

    def backlog(self) -> dict[str, float]:
        """Blocks waiting for the writer thread, now and at the peak: ``bytes``, ``seconds`` (of data, the slowest
        stream's), ``peak_bytes``, ``peak_seconds``. A SIGKILL loses the backlog at that moment plus at most one
        ``flush_interval`` (the open chunk)."""
        q = self._queue
        return {"bytes": q.bytes, "seconds": q.backlog_s(), "peak_bytes": q.peak_bytes, "peak_seconds": q.peak_s}

    @property
    def failure(self) -> str | None:
        """One line: what stopped the writer, what the log holds (per stream, to which sample and time), how
        many samples from when were not recorded, and whether the file is complete or needs ``gvt log recover``.
        None while all is well. Reading it counts as reporting it (``close()`` then does not raise); its
        counts are final after ``close()``."""
        if self._failure is None:
            return None
        self._failure_seen = True
        return self._failure_line()

    @property
    def failure_error(self) -> LogWriterError | None:
        """``failure`` as the exception of its kind, to raise: LogWriterError (exit 1) or, for a deleted output,
        LogOutputLostError (exit 3). Reading it counts as reporting it."""
        line = self.failure
        if line is None:
            return None
        assert self._failure is not None
        return (LogOutputLostError if self._failure.kind == "deleted" else LogWriterError)(line)

    @property
    def failure_exit_code(self) -> int:
        """The exit code of the failure's kind: 3 (DataLost) for a deleted output, 1 for any other, 0 for none.
        Does not count as reporting it (that is ``failure``'s job)."""
        if self._failure is None:
            return 0
        return LogOutputLostError.exit_code if self._failure.kind == "deleted" else LogWriterError.exit_code

    @property
    def lost_ranges(self) -> list[tuple[str, int, int]]:
        """(stream, start, end) not recorded because of a failure, merged; grows until ``close()``."""
        with self._acct_lock:
            return _merge([(s, a, b) for s, rs in self._lost.items() for a, b in rs])

    def add_stream(
        self, stream: str, channels: Sequence[ChannelInfo], sample_rate: float, t0_ns: int | None = None,
        *, offset_ns: int | None = 0, offset_method: str = "",
    ) -> None:  # fmt: skip
        """Register a stream. ``offset_ns``: its sample 0 on the session's timeline (ns after the origin); None
        when not known yet (``set_offset`` later: its blocks wait here until then). ``t0_ns`` (older callers):
        the stream's absolute start instead, i.e. ``offset_ns = t0_ns - origin``."""
        if t0_ns is not None:
            offset_ns, offset_method = None, offset_method or "t0_ns"
            with self._time_lock:  # no origin of its own: the first stream's absolute start is the session's
                if self._origin_source == "default":
                    self._origin_ns, self._origin_source = int(t0_ns), "first stream's t0_ns"
                    self._time_version += 1
        spec = {
            "stream": stream,
            "channels": [c.__dict__ for c in channels],
            "sample_rate": float(sample_rate),
            "t0_ns": None,  # origin + offset, once both are known (then the channel is registered)
            "abs_t0_ns": None if t0_ns is None else int(t0_ns),
        }
        if offset_ns is not None:
            self.set_offset(stream, offset_ns, offset_method or "given")
        self._control(("stream", spec))

    def set_origin(self, origin_ns: int, source: str = "set") -> None:
        """The session's start (UTC ns of the reference's sample 0); the first call wins. Never blocks."""
        with self._time_lock:
            if self._origin_ns is None:
                self._origin_ns, self._origin_source = int(origin_ns), source
                self._time_version += 1

    def set_offset(self, stream: str, offset_ns: int, method: str = "set") -> None:
        """Where ``stream``'s sample 0 lies on the session's timeline (ns after the origin); the first call
        wins (a fixed offset never changes: it would tear the stream). Never blocks."""
        with self._time_lock:
            if stream not in self._offsets:
                self._offsets[stream] = (int(offset_ns), method)
                self._time_version += 1

    @property
    def origin_ns(self) -> int | None:
        return self._origin_ns

    def write_block(self, block: SampleBlock, wait: bool = False) -> bool:
        """Queue a block; False if it was not taken. Never raises, and never blocks unless ``wait``.

        A full queue (its block budget, ``buffer_bytes`` / ``queue_size``, exhausted) counts the block as an
        overrun (logged as an event with its exact range); after a failure it counts as lost
        (``stats.lost_after_failure_*``, ``lost_ranges``). Live producers never wait. Offline producers
        (simulation, replay into a new log, recovery) pass ``wait=True`` and get back-pressure instead: they
        wait for space, up to the control timeout, and only then count an overrun.
        """
        if self.failed.is_set():
            self._lose(block.stream, block.first_index, block.end_index, block.sample_rate, written=False)
            return False
        if self._queue.put_block(block, self._control_timeout if wait else None):
            return True
        with self._overrun_lock:
            self._overruns.append((block.stream, block.first_index, block.end_index))
            self.stats.overrun_blocks += 1
            self.stats.overrun_samples += block.n_samples
        return False

    def write_event(self, kind: str, log_time_ns: int | None = None, **fields: Any) -> None:
        """An event; ``log_time_ns`` relative to the origin, or None: at its ``stream``'s ``start_index`` when
        it has them, else at the data time reached when it is written."""
        self._control(("json", layout.EVENTS_TOPIC, {"kind": kind, **fields}, log_time_ns, None))

    def write_hit(self, hit: Mapping[str, Any], log_time_ns: int | None = None) -> None:
        """A hit; ``log_time_ns`` relative to the origin (None: its ``t_s``, else the data time reached)."""
        if log_time_ns is None and isinstance(hit.get("t_s"), (int, float)):
            log_time_ns = round(float(hit["t_s"]) * 1e9)
        self._control(("json", layout.HITS_TOPIC, dict(hit), log_time_ns, None))

    def write_json(self, topic: str, obj: Mapping[str, Any], log_time_ns: int | None = None, clock: str | None = None) -> None:
        """A JSON record at ``log_time_ns`` relative to the origin — on stream ``clock``'s own timeline when
        given (its offset is added; the record waits for it) — or, None, at the data time reached."""
        self._control(("json", topic, dict(obj), log_time_ns, clock))

    def write_json_encoded(self, items: Sequence[tuple[str, bytes, int | None, str | None]]) -> None:
        """JSON records already encoded (``json.dumps(dict(obj), separators=(",", ":")).encode()``, the bytes
        :meth:`write_json` would write), as ``(topic, bytes, log_time_ns, clock)``: one queued item for the lot, each
        still its own message, timed as :meth:`write_json` times it. Why: the lane worker sends ~140 window records a
        second; encoded there and queued in batches they cost this process a pickle load and a queue turn per batch
        instead of per record, and no JSON encoding (D107). Not for ``/daq/events`` (the writer reads their fields)."""
        if items:
            self._control(("jsons", list(items)))

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._control(("meta", name, {str(k): str(v) for k, v in data.items()}))

    def add_attachment(self, name: str, data: bytes, media_type: str = "application/octet-stream") -> None:
        self._control(("attach", name, bytes(data), media_type))

    def close(self) -> WriterStats:
        """Finish the file (summary, indexes, footer), release the lock, return the stats.

        After a failure the file was finalised (or cut back) when it happened; ``close()`` then raises
        ``failure_error`` — once — only if nobody read ``failure`` or ``failure_error``: a caller that checks
        ``failure`` prints it itself, and one that never looks cannot lose it.
        """
        if not self._closed:
            self._closed = True
            self._queue.put_control(_STOP, bounded=False)
            self._thread.join()
            self.stats.peak_backlog_bytes, self.stats.peak_backlog_s = self._queue.peak_bytes, self._queue.peak_s
            with self._acct_lock:
                self.stats.lost_after_failure_ranges = _merge([(s, a, b) for s, rs in self._lost.items() for a, b in rs])
        if self._failure is not None and not self._failure_seen:
            err = self.failure_error
            assert err is not None
            raise err
        return self.stats

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
            return
        try:
            self.close()
        except LogWriterError:
            pass  # the exception already on its way out is the one to report

    def _control(self, item: tuple) -> None:
        """Queue a control record. After a failure it is dropped and counted; a writer that takes nothing for
        ``control_timeout`` seconds (a disk that stopped answering) is a failure too — never a traceback."""
        if self._closed:
            raise LogWriterError(f"{self.path}: writer is closed")  # a programming error, not a run-time one
        if not self.failed.is_set():
            try:
                self._queue.put_control(item, timeout=self._control_timeout)
                return
            except queue.Full:
                self._set_failure(
                    _Failure("stalled", f"the log writer took nothing for {self._control_timeout:g} s (is the disk answering?)",
                             self._current_file()),
                    now=True,
                )  # fmt: skip
        with self._acct_lock:
            self.stats.dropped_after_failure += 1

    def _current_file(self) -> Path:
        return Path(self.stats.files[-1]) if self.stats.files else self.path

    def _refuse_existing_parts(self) -> None:
        """With rotation, a later part (``name-0001.mcap``...) must not overwrite an earlier log's part either;
        checked up front, since refusing in the middle of a recording would lose data."""
        parts = sorted(self.path.parent.glob(f"{self.path.stem}-[0-9][0-9][0-9][0-9]{self.path.suffix}"))
        if parts:
            raise LogOutputExistsError(f"{parts[0]}: exists (a part of an earlier rotated log); pass --overwrite to replace it")

    # --- accounting ----------------------------------------------------------------------------
    def _lose(self, stream: str, first: int, end: int, rate: float, *, written: bool, blocks: int = 1) -> None:
        """Count ``blocks`` blocks [first, end) that a failure kept out of the log; ``written``: they had been
        counted as written (they were in a part of the file that is gone)."""
        with self._acct_lock:
            ranges = self._lost.setdefault(stream, [])
            if ranges and ranges[-1][1] == first:
                ranges[-1][1] = end
            else:
                ranges.append([first, end])
            self._rates.setdefault(stream, rate)
            self.stats.lost_after_failure_blocks += blocks
            self.stats.lost_after_failure_samples += end - first
            if written:
                self.stats.blocks_written -= blocks
                self.stats.samples_written -= end - first

    def _chunk_written(self, end_offset: int) -> None:
        """The sink wrote (or holds) a Chunk ending at ``end_offset``: the open blocks are in it."""
        self._unsynced.append((end_offset, self._open_blocks))
        self._open_blocks = []

    def _commit(self, upto: int | None = None) -> None:
        """Blocks in chunks ending at or before ``upto`` (all, if None) are in the file for good; a cut
        removed the others, and the blocks of the still-open chunk: count those as lost."""
        keep, lose = [], []
        for end, blocks in self._unsynced:
            (keep if upto is None or end <= upto else lose).extend(blocks)
        self._unsynced = []
        if upto is not None:
            lose.extend(self._open_blocks)
            self._open_blocks = []
        with self._acct_lock:
            for s, a, b in keep:
                d = self._durable.setdefault(s, [a, b, 0])
                d[0], d[1], d[2] = min(d[0], a), max(d[1], b), d[2] + (b - a)
        for s, a, b in lose:
            self._lose(s, a, b, self._rates.get(s, 1.0), written=True)

    # --- writer thread -----------------------------------------------------------------------
    def _start_file(self, path: Path) -> None:
        fd, self._first_fd = self._first_fd, None
        if fd is None:
            fd = open_output(path, self._overwrite)
        self._sink = _Sink(fd, path, self._chunk_written)
        self.stats.files.append(str(path))
        with self._acct_lock:
            self._durable_at_part = {s: list(v) for s, v in self._durable.items()}
        self._part_ranges = {}
        self._finish_started = False
        self._mcap = Writer(self._sink, chunk_size=self._chunk_size, compression=CompressionType.ZSTD)
        self._mcap.start(profile=layout.PROFILE, library=f"gvtlink {_version()}")
        self._file_started = time.monotonic()
        self._channel_ids: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._json_schemas: dict[str, int] = {}
        self._add_meta(layout.META_SESSION, self._session_meta)
        self._part_stats = {}
        self._part_events: list[dict] = []  # this part's /daq/events, for the gvtlink.events record at close
        self._part_event_counts: dict[str, int] = {}
        for spec in self._streams.values():
            if spec["t0_ns"] is not None:  # a stream still waiting for its offset is registered when it comes
                self._register_stream(spec)
        for name, data in self._metadata:
            self._add_meta(name, data)
        for name, data, media in self._attachments:
            self._attach(name, data, media)
        self._check_sink()

    def _rotated_path(self) -> Path:
        n = len(self.stats.files)
        return self.path.with_name(f"{self.path.stem}-{n:04d}{self.path.suffix}")

    def _register_stream(self, spec: dict[str, Any]) -> None:
        assert self._mcap is not None
        topic = layout.samples_topic(spec["stream"])
        meta = {
            "stream": spec["stream"],
            "sample_rate": repr(spec["sample_rate"]),
            "t0_ns": str(spec["t0_ns"]),
            "channels": json.dumps([c["name"] for c in spec["channels"]]),
            "units": json.dumps([c["unit"] for c in spec["channels"]]),
        }
        # format 2: one channel-major schema per stream; "fields" maps channels to protobuf field names (D30)
        name, fds, fields = block_schema(spec["stream"], [c["name"] for c in spec["channels"]])
        meta.update(layout="channel-major", fields=json.dumps(fields))
        schema_id = self._mcap.register_schema(name, "protobuf", fds)
        self._channel_ids[topic] = self._mcap.register_channel(topic, "protobuf", schema_id, meta)
        self._add_meta(
            layout.META_CALIBRATION.format(stream=spec["stream"]),
            {"sample_rate": repr(spec["sample_rate"]), "t0_ns": str(spec["t0_ns"]), "channels": json.dumps(spec["channels"])},
        )
        if self._preview and len(spec["channels"]) <= MAX_PREVIEW_CHANNELS:
            self._register_preview(spec)

    def _register_preview(self, spec: dict[str, Any]) -> None:
        """The stream's ``/preview/<stream>`` channel: its own schema, the bucket and the field names in its metadata."""
        assert self._mcap is not None
        chans = [c["name"] for c in spec["channels"]]
        name, fds = preview_schema(spec["stream"], chans)
        meta = {"stream": spec["stream"], "bucket_samples": str(self._bucket), "stats": ",".join(STATS),
                "channels": json.dumps(chans), "fields": json.dumps(preview_fields(chans))}  # fmt: skip
        schema_id = self._mcap.register_schema(name, "protobuf", fds)
        self._channel_ids[layout.preview_topic(spec["stream"])] = self._mcap.register_channel(
            layout.preview_topic(spec["stream"]), "protobuf", schema_id, meta
        )
        self._previews.setdefault(spec["stream"], PreviewEncoder(len(chans)))

    def _preview_messages(self, b: SampleBlock, t0: int) -> list[tuple[int, bytes]]:
        """(log time, message) per bucket of the block on ``/preview/<stream>``, each at its first sample's time:
        vectorised, no per-sample Python (daq/log/preview.py); none for a stream without a preview."""
        if b.stream not in self._previews:
            return []
        bk = bucket_stats(b.first_index, b.data, self._bucket)
        # int64 before adding t0: a UTC origin (~1.8e18 ns) in float64 is only good to 256 ns (the preview came 113 ns
        # before its own block, and before the session's origin)
        times = (t0 + np.round(bk.first * 1e9 / b.sample_rate).astype(np.int64)).tolist()
        return list(zip(times, self._previews[b.stream].encode(bk), strict=True))

    def _json_channel(self, topic: str) -> int:
        assert self._mcap is not None
        if topic not in self._channel_ids:
            schema = records.schema_for(topic)  # a topic without a record: permissive, still titled
            title = schema["title"]
            if title not in self._json_schemas:
                self._json_schemas[title] = self._mcap.register_schema(title, "jsonschema", json.dumps(schema).encode())
            self._channel_ids[topic] = self._mcap.register_channel(topic, "json", self._json_schemas[title])
        return self._channel_ids[topic]

    def _add_meta(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record, sealed with its CRC (``daq/log/seal.py``: MCAP gives metadata none)."""
        assert self._mcap is not None
        self._mcap.add_metadata(name, seal(name, data))

    def _attach(self, name: str, data: bytes, media: str) -> None:
        assert self._mcap is not None
        now = time.time_ns()
        self._mcap.add_attachment(create_time=now, log_time=now, name=name, media_type=media, data=data)

    def _message(self, channel_id: int, log_time: int, data: bytes) -> None:
        assert self._mcap is not None
        seq = self._seq.get(channel_id, 0)
        self._seq[channel_id] = seq + 1
        self._mcap.add_message(channel_id, log_time=log_time, data=data, publish_time=time.time_ns(), sequence=seq)
        self.stats.messages_written += 1

    def _handle(self, item: tuple) -> None:
        """One queued item: written now when its time is known, else held (module docstring)."""
        kind = item[0]
        if kind == "jsons":  # a batch of encoded records: each is handled (written or held) as a record of its own
            for topic, raw, log_time, clock in item[1]:
                self._handle(("json", topic, raw, log_time, clock))
            return
        if kind == "json" and len(item) < 5:
            item = (*item, None, None)[:5]  # (json, topic, obj[, log_time[, clock]])
        if kind in ("block", "json"):
            if self._held:
                self._release()
            if not self._ready(item):
                self._hold(item)
                return
            self._write_timed(item)
        elif kind == "stream":
            spec = item[1]
            self._streams[spec["stream"]] = spec
            self._rates[spec["stream"]] = spec["sample_rate"]
            self._register_ready()
        elif kind == "meta":
            self._metadata.append((item[1], item[2]))
            assert self._mcap is not None
            self._add_meta(item[1], item[2])
        elif kind == "attach":
            self._attachments.append((item[1], item[2], item[3]))
            self._attach(item[1], item[2], item[3])

    # --- the time base (writer thread) ---------------------------------------------------------------
    def _offset(self, stream: str) -> int | None:
        """The stream's offset (ns after the origin), once origin and offset are known."""
        with self._time_lock:
            origin = self._origin_ns
            off = self._offsets.get(stream)
        if origin is None:
            return None
        if off is None:
            spec = self._streams.get(stream)
            if spec is None or spec["abs_t0_ns"] is None:
                return None
            self.set_offset(stream, spec["abs_t0_ns"] - origin, "t0_ns")
            return spec["abs_t0_ns"] - origin
        return off[0]

    def _event_clock(self, obj: Mapping[str, Any]) -> tuple[str, int] | None:
        """(stream, index) an event is about, when it names a registered stream and a start index."""
        s, i = obj.get("stream"), obj.get("start_index")
        if isinstance(s, str) and s in self._streams and isinstance(i, int) and not isinstance(i, bool):
            return s, i
        return None

    def _ready(self, item: tuple) -> bool:
        if self._origin_ns is None:
            return False
        if item[0] == "block":
            return self._offset(item[1].stream) is not None
        topic, obj, log_time, clock = item[1], item[2], item[3], item[4]
        if clock is not None:
            return clock not in self._streams or self._offset(clock) is not None
        if log_time is None and topic == layout.EVENTS_TOPIC and (ev := self._event_clock(obj)) is not None:
            return self._offset(ev[0]) is not None
        return True

    def _hold(self, item: tuple) -> None:
        self._held.append(item)
        if item[0] == "block":
            b = item[1]
            self._held_samples[b.stream] = self._held_samples.get(b.stream, 0) + b.n_samples
        self._check_hold()

    def _check_hold(self) -> None:
        """Bounded: a stream held longer than ``max_hold_s`` (or too many held records) stops the waiting."""
        over = [s for s, n in self._held_samples.items() if n > self._max_hold_s * self._rates.get(s, 1.0)]
        if over or len(self._held) > MAX_HELD_RECORDS:
            self._release(force=over if over else True)

    def _release(self, force: list[str] | bool = False) -> None:
        """Write the held items whose time is now known (in arrival order). ``force`` (True: all; a list: those
        streams): stop waiting — the origin from the first held block, an offset from its first block's arrival."""
        if force:
            self._fallback_times(None if force is True else force)
        elif self._time_version == self._released_at:
            return  # nothing new is known: every held item still waits (keeps a long hold O(n), not O(n²))
        self._released_at = self._time_version
        self._register_ready()
        held, self._held = self._held, []
        for item in held:
            if self._ready(item):
                if item[0] == "block":
                    self._held_samples[item[1].stream] -= item[1].n_samples
                self._write_timed(item)
            else:
                self._held.append(item)

    def _fallback_times(self, streams: list[str] | None) -> None:
        """What the session did not say in time: the origin (the first held block's sample 0 on the host clock,
        else the writer's start) and the offsets of ``streams`` (None: all pending) from their first block."""
        first: dict[str, SampleBlock] = {}
        for it in self._held:
            if it[0] == "block":
                first.setdefault(it[1].stream, it[1])
        if self._origin_ns is None:
            guess = next((w for b in first.values() if (w := wall_at_sample0(b)) is not None), None)
            self.set_origin(guess if guess is not None else int(self._session_meta["created_unix_ns"]),
                            "first-block-fallback" if guess is not None else "writer-start-fallback")  # fmt: skip
        origin = self._origin_ns
        assert origin is not None
        for s in streams if streams is not None else list(self._streams):
            if self._offset(s) is not None:
                continue
            b = first.get(s)
            w = wall_at_sample0(b) if b is not None else None
            fs = self._rates.get(s, 1.0)
            off = 0 if w is None else round(round((w - origin) * fs / 1e9) * 1e9 / fs)  # whole samples
            self.set_offset(s, off, "first-arrival-fallback" if w is not None else "unknown-fallback")

    def _register_ready(self) -> None:
        """Register every stream whose origin and offset are known (channel metadata ``t0_ns``)."""
        self._note_origin()
        for name, spec in self._streams.items():
            if spec["t0_ns"] is None and (off := self._offset(name)) is not None:
                assert self._origin_ns is not None
                spec["t0_ns"] = self._origin_ns + off
                self._register_stream(spec)

    def _note_origin(self) -> None:
        """The ``gvtlink.time`` record, once the origin is known (repeated in rotated parts)."""
        if self._time_noted or self._origin_ns is None:
            return
        self._time_noted = True
        rec = {"origin_unix_ns": str(self._origin_ns), "origin_source": self._origin_source}
        self._metadata.append((layout.META_TIME, rec))
        assert self._mcap is not None
        self._add_meta(layout.META_TIME, rec)

    def _json_time(self, topic: str, obj: Mapping[str, Any], log_time: int | None, clock: str | None) -> int:
        """Absolute log time of a JSON record (see ``write_json``/``write_event``); never before 0."""
        origin = self._origin_ns
        assert origin is not None
        if clock is not None and log_time is not None:
            return max(0, origin + (self._offset(clock) or 0) + int(log_time))
        if log_time is not None:
            return max(0, origin + int(log_time))
        if topic == layout.EVENTS_TOPIC and (ev := self._event_clock(obj)) is not None:
            s, i = ev
            return max(0, origin + (self._offset(s) or 0) + round(i * 1e9 / self._rates.get(s, 1.0)))
        return max(origin, self._data_end_ns or origin)

    def _write_timed(self, item: tuple) -> None:
        if item[0] == "json":
            topic, obj = item[1], item[2]
            log_time = self._json_time(topic, obj, item[3], item[4])
            raw = obj if isinstance(obj, bytes) else json.dumps(obj, separators=(",", ":")).encode()
            self._message(self._json_channel(topic), log_time, raw)
            if topic == layout.EVENTS_TOPIC:
                self._note_event(obj)
            return
        b: SampleBlock = item[1]
        spec = self._streams.get(b.stream)
        if spec is None:
            raise LogWriterError(f"block for unregistered stream {b.stream!r}; call add_stream first")
        if spec["t0_ns"] is None:
            self._register_ready()
        t0 = spec["t0_ns"]
        log_time = t0 + round(b.first_index * 1e9 / b.sample_rate)
        raw = encode_block(b.stream, b.first_index, b.sample_rate, b.data, int(b.status), t0)
        # the preview now, while the block is in the cache: adding the block may compress a whole chunk first
        preview = self._preview_messages(b, t0) if self._preview else []
        self._rates[b.stream] = b.sample_rate
        self._open_blocks.append((b.stream, b.first_index, b.end_index))  # before add_message: it may close the chunk
        ranges = self._part_ranges.setdefault(b.stream, [])  # [first, end, blocks], contiguous runs
        if ranges and ranges[-1][1] == b.first_index:
            ranges[-1][1] = b.end_index
            ranges[-1][2] += 1
        else:
            ranges.append([b.first_index, b.end_index, 1])
        self._count_block(b)
        self._message(self._channel_ids[layout.samples_topic(b.stream)], log_time, raw)
        if (cid := self._channel_ids.get(layout.preview_topic(b.stream))) is not None:
            for t, msg in preview:
                self._message(cid, t, msg)
        end_ns = t0 + round(b.end_index * 1e9 / b.sample_rate)
        self._data_end_ns = end_ns if self._data_end_ns is None else max(self._data_end_ns, end_ns)
        self.stats.blocks_written += 1
        self.stats.samples_written += b.n_samples

    def _count_block(self, b: SampleBlock) -> None:
        """This part's ``gvtlink.streams`` record: counts, gaps, segments (a RESTART block starts one), flags."""
        st = self._part_stats.get(b.stream)
        if st is None:
            self._part_stats[b.stream] = {
                "blocks": 1, "samples": b.n_samples, "first_index": b.first_index, "end_index": b.end_index, "gaps": [],
                "segments": [[b.first_index, b.end_index]], "status_flags": int(b.status),
            }  # fmt: skip
            return
        if b.first_index > st["end_index"]:
            st["gaps"].append([st["end_index"], b.first_index])
        if b.status & BlockStatus.RESTART:
            st["segments"][-1][1] = b.first_index  # a segment runs to the next one's start (as gvt log info had it)
            st["segments"].append([b.first_index, b.end_index])
        else:
            st["segments"][-1][1] = max(st["segments"][-1][1], b.end_index)
        st["blocks"] += 1
        st["samples"] += b.n_samples
        st["first_index"] = min(st["first_index"], b.first_index)
        st["end_index"] = max(st["end_index"], b.end_index)
        st["status_flags"] |= int(b.status)

    def _streams_record(self) -> dict[str, str]:
        """``gvtlink.streams``: one key per stream, a JSON summary of what this file holds of it."""
        out = {}
        for name, spec in self._streams.items():
            st = self._part_stats.get(name) or {
                "blocks": 0, "samples": 0, "first_index": 0, "end_index": 0, "gaps": [], "segments": [], "status_flags": 0,
            }  # fmt: skip
            off = self._offsets.get(name, (0, ""))
            rec = {**st, "t0_ns": spec["t0_ns"], "offset_ns": off[0], "offset_method": off[1]}
            out[name] = json.dumps(rec, separators=(",", ":"))
        return out

    def _emit_overruns(self) -> None:
        with self._overrun_lock:
            pending, self._overruns = self._overruns, []
        for stream, start, end in _merge(pending):
            obj = {
                "kind": "overrun",
                "stream": stream,
                "start_index": start,
                "end_index": end,
                "count": end - start,
                "message": "log writer buffer full: these samples were not recorded",
            }
            t = self._json_time(layout.EVENTS_TOPIC, obj, None, None) if self._offset(stream) is not None else None
            t = t if t is not None else max(self._origin_ns or 0, self._data_end_ns or 0)
            self._message(self._json_channel(layout.EVENTS_TOPIC), t, json.dumps(obj).encode())
            self._note_event(obj)

    def _note_backlog(self) -> None:
        """A ``writer_backlog`` event when the writer fell more than BACKLOG_NOTE_S behind: how far, and so what a
        crash at that moment would have lost (docs/log-format.md, "Writer guarantees")."""
        q = self._queue
        if self._note_backlog_s is None or q.peak_s <= self._note_backlog_s or self._origin_ns is None:
            return
        obj = {"kind": "writer_backlog", "peak_s": round(q.peak_s, 3), "peak_bytes": q.peak_bytes,
               "buffer_bytes": q.max_bytes, "message": backlog_line(q.peak_s, q.peak_bytes, self._flush_interval)}  # fmt: skip
        self._message(self._json_channel(layout.EVENTS_TOPIC), max(self._origin_ns, self._data_end_ns or 0),
                      json.dumps(obj).encode())  # fmt: skip
        self._note_event(obj)

    def _note_event(self, obj: Mapping[str, Any]) -> None:
        """Count an event written to this part (and keep it, up to MAX_EVENTS_RECORD) for ``gvtlink.events``."""
        kind = str(obj.get("kind", "?"))
        self._part_event_counts[kind] = self._part_event_counts.get(kind, 0) + 1
        if len(self._part_events) <= MAX_EVENTS_RECORD:
            self._part_events.append(dict(obj))

    def _check_sink(self) -> None:
        assert self._sink is not None
        if self._sink.error is not None:
            raise _Stop(_io_failure(self._sink.error, self._sink.path))

    def _check_output(self) -> None:
        """Is the file we write still the one at its path? Deleted (no links left) or moved/replaced (the path
        names another inode, or nothing): writing on would record into a file the user cannot find."""
        sink = self._sink
        assert sink is not None
        try:
            ours = os.fstat(sink.fd)
        except OSError:
            return
        if ours.st_nlink == 0:
            raise _Stop(_Failure("deleted", "the output file was deleted while recording", sink.path))
        try:
            now = os.stat(sink.path)
        except FileNotFoundError:
            now = None
        except OSError:
            return
        if now is None or (now.st_ino, now.st_dev) != (ours.st_ino, ours.st_dev):
            try:
                where = os.readlink(f"/proc/self/fd/{sink.fd}")
            except OSError:
                where = None
            raise _Stop(_Failure("moved", "the output file was moved or replaced while recording", sink.path, moved_to=where))

    def _sync(self) -> None:
        assert self._mcap is not None and self._sink is not None
        self._mcap.flush()  # closes the open chunk and writes it out
        self._sink.sync(self._fsync)
        self._check_sink()
        self._commit()
        self.stats.flushes += 1

    def _finish_file(self, last: bool = False) -> None:
        assert self._mcap is not None and self._sink is not None
        if last and (self._held or self._origin_ns is None):
            self._release(force=True)  # the session did not say in time: stop waiting (module docstring)
        self._emit_overruns()
        if last:
            self._note_backlog()
        self._register_ready()
        self._add_meta(layout.META_STREAMS, self._streams_record())
        complete = len(self._part_events) <= MAX_EVENTS_RECORD
        self._add_meta(layout.META_EVENTS, {  # gvt log info answers from this without reading a chunk
            "counts": json.dumps(self._part_event_counts), "complete": "1" if complete else "0",
            "events": json.dumps(self._part_events if complete else [], default=str),
        })  # fmt: skip
        self._finish_started = True  # a failure from here on must not finish it again
        self._mcap.finish()
        self._sink.sync(self._fsync)
        self._check_sink()
        self._commit()
        self._sink.close()
        self._sink, self._mcap = None, None

    def _run(self) -> None:
        stop_seen = False
        try:
            self._start_file(self.path)
            next_flush = time.monotonic() + self._flush_interval
            while not self.failed.is_set():
                timeout = max(0.0, next_flush - time.monotonic())
                try:
                    item = self._queue.get(timeout=timeout)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    stop_seen = True
                    break
                if item is not None:
                    self._handle(item)
                elif self._held:
                    self._release()
                if self._overruns and self._origin_ns is not None:
                    self._emit_overruns()
                self._check_sink()
                now = time.monotonic()
                if now >= next_flush:
                    self._sync()
                    self._check_output()
                    next_flush = now + self._flush_interval
                    if self._should_rotate(now):
                        self._finish_file()
                        self._start_file(self._rotated_path())
            if not self.failed.is_set():
                self._check_output()
                self._finish_file(last=True)
        except _Stop as stop:
            self._set_failure(stop.failure)
        except LogOutputError as exc:  # the next rotated part could not be opened
            self._set_failure(_Failure("error", f"could not start the next part: {exc}", self._current_file()))
        except OSError as exc:
            self._set_failure(_io_failure(exc, self._current_file()))
        except BaseException as exc:  # a bug or a bad item: reported as the failure, never a thread traceback
            self._set_failure(_Failure("error", f"the log writer failed: {_describe(exc)}", self._current_file()))
        if self._failure is not None:
            self._lose_held()
            try:
                self._finalise_after_failure()
            except BaseException as exc:  # never leave producers without a line
                assert self._failure is not None
                self._failure.outcome = "cut_failed"
                self._failure.what += f"; finalising failed: {_describe(exc)}"
            self.failed.set()
            while not stop_seen:  # keep taking items so nobody blocks on a dead writer; count what is lost
                item = self._queue.get()
                if item is _STOP:
                    break
                if item[0] == "block":
                    b = item[1]
                    self._lose(b.stream, b.first_index, b.end_index, b.sample_rate, written=False)
                else:
                    with self._acct_lock:
                        self.stats.dropped_after_failure += len(item[1]) if item[0] == "jsons" else 1
        if self._sink is not None:
            self._sink.close()  # releases the lock; held until close() even after a failure
            self._sink = None

    def _lose_held(self) -> None:
        """After a failure: held blocks were never written (counted lost, with their ranges), held records dropped."""
        held, self._held = self._held, []
        for it in held:
            if it[0] == "block":
                b = it[1]
                self._lose(b.stream, b.first_index, b.end_index, b.sample_rate, written=False)
            else:
                with self._acct_lock:
                    self.stats.dropped_after_failure += 1

    def _set_failure(self, failure: _Failure, now: bool = False) -> None:
        """The first failure wins. ``now``: set ``failed`` at once (a producer saw the writer stall; the thread
        may never come back to do it); the thread sets it itself after finalising."""
        with self._acct_lock:
            if self._failure is None:
                failure.earlier_parts = max(0, len(self.stats.files) - 1)
                self._failure = failure
        if now:
            self.failed.set()

    def _finalise_after_failure(self) -> None:
        """Make what was written usable: finish the file (summary, footer) if the disk takes it, else leave it
        cut at its last complete record; count everything that did not make it as lost, with its range."""
        f = self._failure
        assert f is not None
        sink = self._sink
        if sink is None:  # between rotated parts: every earlier part is complete
            f.outcome = "none"
            return
        if f.kind == "deleted":  # everything this part held went with it
            f.outcome = "gone"
            self._unsynced, self._open_blocks = [], []
            with self._acct_lock:
                self._durable = {s: list(v) for s, v in self._durable_at_part.items()}
            for s, ranges in self._part_ranges.items():
                for a, b, n in ranges:
                    self._lose(s, a, b, self._rates.get(s, 1.0), written=True, blocks=n)
            return
        ok = False
        try:
            if not self._finish_started:
                assert self._mcap is not None
                self._finish_started = True
                self._emit_overruns()
                note = {"kind": "writer_failure", "message": f.what}
                t = max(self._origin_ns or 0, self._data_end_ns or 0)  # the data time reached, never the wall clock
                self._message(self._json_channel(layout.EVENTS_TOPIC), t, json.dumps(note).encode())
                self._mcap.finish()
            ok = sink.retry(self._fsync)
            if ok:
                sink.sync(self._fsync)
                ok = sink.whole
        except Exception:
            ok = False
        if ok:
            f.outcome = "complete"
            self._commit()
        else:
            f.outcome = "cut_failed" if sink.cut_failed else "cut"
            f.cut_at = sink.complete
            self._commit(upto=sink.complete)

    def _should_rotate(self, now: float) -> bool:
        assert self._sink is not None
        if self._rotate_seconds is not None and now - self._file_started >= self._rotate_seconds:
            return True
        return self._rotate_bytes is not None and self._sink.tell() >= self._rotate_bytes

    # --- the failure line ------------------------------------------------------------------------
    def _failure_line(self) -> str:
        f = self._failure
        assert f is not None
        with self._acct_lock:
            durable = {s: list(v) for s, v in self._durable.items()}
            lost = _merge([(s, a, b) for s, rs in self._lost.items() for a, b in rs])
            n_lost = self.stats.lost_after_failure_samples
        rates = dict(self._rates)

        def t(stream: str, index: int) -> float:
            return index / rates.get(stream, 1.0)

        lost_from = min((t(s, a) for s, a, _b in lost), default=None)
        lost_txt = (
            f"{n_lost} samples from t={lost_from:.3f} s on were not recorded" if n_lost and lost_from is not None
            else "no samples were lost"
        )  # fmt: skip
        if f.kind == "deleted":
            earlier = f"; the {f.earlier_parts} earlier part(s) are complete" if f.earlier_parts else ""
            return f"{f.file}: {f.what}; {lost_txt}{earlier}"
        holds = ", ".join(f"{s} samples {a}-{b - 1} (to t={t(s, b):.3f} s)" for s, (a, b, _n) in sorted(durable.items()) if b > a)
        holds_txt = f"the log holds {holds}" if holds else "the log holds no samples"
        recover = f"`gvt log recover {f.file} FIXED.mcap`"
        outcome = {
            "complete": "the file is complete",
            "none": "every part written is complete",
            "cut": (
                "the file is empty" if f.cut_at == 0
                else f"the file ends at its last complete chunk (byte {f.cut_at}): {recover} restores its index"
            ),
            "cut_failed": f"the file could not be cut back to its last complete chunk: {recover} rewrites what is readable",
            "pending": "finishing the file",
        }.get(f.outcome, "")  # fmt: skip
        moved = f" (it is now {f.moved_to})" if f.moved_to else ""
        return f"{f.file}: {f.what}{moved}; {holds_txt}; {lost_txt}; {outcome}"


def backlog_line(peak_s: float, peak_bytes: int, flush_interval: float = 0.5) -> str:
    """The one line for a writer that fell behind: how far, and what a crash then would have lost."""
    return (f"the log writer fell up to {peak_s:.1f} s behind ({peak_bytes / 2**20:.0f} MiB queued); a crash then would "
            f"have lost up to {peak_s + flush_interval:.1f} s")  # fmt: skip


def _describe(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}"[:200] if text else type(exc).__name__


def _merge(ranges: list[tuple[str, int, int]]) -> list[tuple[str, int, int]]:
    out: list[tuple[str, int, int]] = []
    for stream, a, b in sorted(ranges):
        if out and out[-1][0] == stream and out[-1][2] >= a:
            out[-1] = (stream, out[-1][1], max(out[-1][2], b))
        else:
            out.append((stream, a, b))
    return out


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gvtlink")
    except Exception:
        return "0+unknown"
