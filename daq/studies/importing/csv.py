"""CSV time histories into a :class:`TimeImport`: the table ``gvt log export --format csv`` writes, exactly, and a
generic CSV with units in its header and a channel table.

Two layouts, told apart by the header (one row, comma-separated):

* ``gvt log export``'s (daq/log/export.py): ``t [s] since <UTC start>``, ``index`` (the session's sample grid),
  then ``name [unit]`` per channel in SI units. Its values are the log's float32 samples printed with 9
  significant digits, which is enough to give back every float32 exactly, so they are read back as those float32
  values; the rate comes from the ``t`` and ``index`` columns (``t`` is printed to the nanosecond).
* any other: ``name [unit]`` per channel (``g``, ``m/s^2``, ``mm``, ``N``, ``lbf``, ``V`` with a sensitivity in
  the channel table ...), and a time column ``t`` or ``time`` (``[s]``, ``[ms]``; no unit: seconds, said) or a
  rate the user states (``fs``).

Bad input is one line naming ``file:line`` and the fix (exit 2): a row with more or fewer fields than the header,
a cell that is not a number, a time column that breaks (a missing sample, a jump: gvtlink does not resample), an
index that jumps (a gap in the exported log), an empty cell inside the record (a gap in one channel). Empty cells
at the start or end (a two-device export's streams that began or ended apart) are left out, and said.

Memory: rows are parsed CHUNK_ROWS at a time (numpy's C parser; a chunk it refuses is parsed again by the csv
module to name the line) and converted to SI per chunk into a table allocated once from the file's line count,
so a CSV needs its samples as float64 (8 bytes a cell, plus 24 a row) and one chunk, not the text in Python
objects (bench/bench_import_formats.py measures the peak).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path

import numpy as np

from analysis.model.units import _unit_text, _units
from daq.studies.importing._common import channel_list, hash_in_background, load_table, rate_from_time, si_factors
from daq.studies.importing.data import ImportError_, Provenance, TimeImport

CHUNK_ROWS = 65536
_GVTLINK_T = re.compile(r"^t \[s\] since (.+)$")
_NAME_UNIT = re.compile(r"^(.*?)\s*\[([^\[\]]*)\]\s*$")
TIME_NAMES = ("t", "time")
#: gvt log export prints t with 9 decimals: a stamp is within 0.5 ns of index / fs, a step within 1 ns
GVTLINK_TIME_TOL_S = 3e-9
EMPTY = "no sample"
FIX_ROW = "every row needs one value per header column; correct the row or the header"


@dataclass
class _Header:
    names: list[str]  # data columns
    units: list[str]
    data_cols: list[int]
    ncols: int
    time_col: int | None = None
    time_factor: float = 1.0
    index_col: int | None = None
    start_utc: str = ""  # gvt log export's session start
    notes: list[str] = field(default_factory=list)

    @property
    def gvtlink(self) -> bool:
        return self.index_col is not None


def _header(where: str, row: list[str]) -> _Header:
    """The header row: gvt log export's (``t [s] since ...``, ``index``) or names with ``[unit]`` and a time column."""
    cells = [c.strip() for c in row]
    if len(cells) == 1 and (sep := next((c for c in ";\t" if c in cells[0]), None)):
        what = "semicolons" if sep == ";" else "tabs"
        raise ImportError_(f"{where}:1: the columns are separated by {what}, not commas; save the CSV comma-separated "
                           "with a decimal point (Excel: CSV UTF-8 in an English locale)")  # fmt: skip
    if len(cells) >= 2 and (m := _GVTLINK_T.match(cells[0])) and cells[1] == "index":
        h = _Header([], [], [], len(cells), time_col=0, index_col=1, start_utc=m.group(1))
        first = 2
    else:
        h = _Header([], [], [], len(cells))
        first = 0
    for j in range(first, len(cells)):
        m = _NAME_UNIT.match(cells[j])
        name, unit = (m.group(1), m.group(2).strip()) if m else (cells[j], "")
        if h.time_col is None and name.lower() in TIME_NAMES:
            h.time_col, h.time_factor = j, _time_factor(where, name, unit, h.notes)
            continue
        if not name:
            raise ImportError_(f"{where}:1: column {j + 1} has no name; name every column in the header as name [unit]")
        if name in h.names:
            raise ImportError_(f"{where}:1: column {name!r} appears twice; name each channel once")
        h.names.append(name)
        h.units.append(unit)
        h.data_cols.append(j)
    if not h.names:
        raise ImportError_(f"{where}:1: no channel columns; the header is e.g. t [s],a1 [m/s^2],hammer [N]")
    return h


def _time_factor(where: str, name: str, unit: str, notes: list[str]) -> float:
    if not unit:
        notes.append(f"time column {name!r} has no unit: read as seconds")
        return 1.0
    try:
        q = _units().Quantity(1.0, _unit_text(unit))
        return float(q.to("s").magnitude)
    except Exception:  # pint's UndefinedUnitError, DimensionalityError, ...
        raise ImportError_(f"{where}:1: time column {name!r} has unit {unit!r}, not a time; write [s] or [ms]") from None


def _slow(where: str, lines: list[str], first_line: int, ncols: int, header: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """A chunk numpy refused, row by row: empty cells are NaN; the first bad row is one line naming it."""
    rows, nums = [], []
    for i, row in enumerate(csv.reader(lines)):
        line = first_line + i
        if not any(c.strip() for c in row):
            continue  # a blank line
        if len(row) != ncols:
            raise ImportError_(f"{where}:{line}: {len(row)} fields but the header has {ncols} columns; {FIX_ROW}")
        vals = []
        for j, c in enumerate(row):
            c = c.strip()
            try:
                vals.append(float(c) if c else np.nan)
            except ValueError:
                raise ImportError_(f"{where}:{line}: column {header[j]!r}: {c!r} is not a number; write a number (decimal "
                                   f"point, no thousands separator) or leave the cell empty ({EMPTY})") from None  # fmt: skip
        rows.append(vals)
        nums.append(line)
    return np.array(rows, np.float64).reshape(-1, ncols), np.array(nums, np.int64)


def _rows(where: str, fh, h: _Header, header: list[str]):
    """(values (m, ncols) float64, file line of each row) per chunk of CHUNK_ROWS lines."""
    line = 2
    while lines := list(islice(fh, CHUNK_ROWS)):
        try:
            arr = np.loadtxt(lines, delimiter=",", dtype=np.float64, ndmin=2, comments=None)
            if arr.shape != (len(lines), h.ncols):
                raise ValueError("blank lines or another column count")
            nums = np.arange(line, line + len(lines))
        except ValueError:
            arr, nums = _slow(where, lines, line, h.ncols, header)
        line += len(lines)
        yield arr, nums


def _count_rows(path: Path) -> int:
    """Lines after the header: the rows to allocate for (blank lines make it an upper bound), counted in 8 MiB
    pieces so that the table is allocated once instead of gathered in chunks and copied (half the peak memory)."""
    n, last = 0, b"\n"
    with open(path, "rb") as fb:
        while buf := fb.read(1 << 23):
            n += buf.count(b"\n")
            last = buf[-1:]
    return max(n + (last != b"\n") - 1, 0)


class _Table:
    """The samples, time and index columns and each row's file line, filled chunk by chunk into arrays allocated
    once (grown, by copy, only if the line count was short: a file with bare CR line ends)."""

    def __init__(self, rows: int, n_ch: int) -> None:
        self.n = 0
        self.samples, self.t, self.k = np.empty((rows, n_ch)), np.empty(rows), np.empty(rows)
        self.lines = np.empty(rows, np.int64)

    def _grow(self, need: int) -> None:
        for name in ("samples", "t", "k", "lines"):
            a = getattr(self, name)
            b = np.empty((max(need, 2 * a.shape[0]), *a.shape[1:]), a.dtype)
            b[: self.n] = a[: self.n]
            setattr(self, name, b)

    def add(self, d: np.ndarray, arr: np.ndarray, lines: np.ndarray, h: _Header) -> None:
        a, b = self.n, self.n + d.shape[0]
        if b > self.samples.shape[0]:
            self._grow(b)
        self.samples[a:b] = d
        self.t[a:b] = arr[:, h.time_col] if h.time_col is not None else np.nan
        self.k[a:b] = arr[:, h.index_col] if h.index_col is not None else np.nan
        self.lines[a:b] = lines
        self.n = b

    def done(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = self.n
        return self.samples[:n], self.t[:n], self.k[:n], self.lines[:n]


def read(path: Path, channels: Path | None = None, fs: float | None = None) -> TimeImport:
    """Read ``path`` (either layout, module docstring) with an optional channel table ``channels`` and a stated rate
    ``fs`` (Hz; needed when the CSV has no time column). ImportError_ (one line, exit 2) on bad input."""
    path = Path(path)
    where = str(path)
    table = load_table(channels)
    try:
        fh = open(path, newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise ImportError_(f"{where}: cannot read ({exc.strerror or exc})") from None
    sha = hash_in_background(path)
    with fh:
        try:
            first = next(csv.reader([fh.readline()]), [])
            h = _header(where, first)
            factors, quantities, notes = si_factors(where, h.names, h.units, table)
            acc = _Table(_count_rows(path), len(h.names))
            for arr, lines in _rows(where, fh, h, first):
                d = arr[:, h.data_cols]
                if h.gvtlink:
                    d = d.astype(np.float32).astype(np.float64)  # the log's float32 values, exactly
                acc.add(d * factors if (factors != 1).any() else d, arr, lines, h)
        except UnicodeDecodeError:
            raise ImportError_(f"{where}: not UTF-8 text; save the CSV as UTF-8") from None
    samples, t, k, lines = acc.done()
    samples, t, k, lines, edges = _full_rows(where, h, samples, t, k, lines)
    rate, t0, how = _time(where, h, t, k, lines, fs)
    chans, more = channel_list(where, h.names, quantities, table)
    assumptions = [*h.notes, how, *edges, *notes, *more]
    if h.gvtlink:
        start = f"started {h.start_utc}" if h.start_utc[:1].isdigit() else f"({h.start_utc})"
        assumptions.insert(0, f"gvt log export CSV of a session {start}: 9-digit values read back as the log's float32 "
                              "samples")  # fmt: skip
    prov = Provenance(where, sha(), "csv", "gvtlink (gvt log export)" if h.gvtlink else "", tuple(assumptions))
    return TimeImport(samples, rate, chans, prov, source_units=h.units, t0_s=t0)


def _full_rows(where: str, h: _Header, samples: np.ndarray, t: np.ndarray, k: np.ndarray, lines: np.ndarray):
    """The rows where every channel has a sample. Empty cells at the start or end (streams of a two-device export
    that began or ended apart: the export's NaN) are left out and said; an empty cell inside the record is a gap in
    that channel, refused at its line (one uniform grid, no invented samples: D84)."""
    gap = np.isnan(samples).any(axis=1)
    full = np.flatnonzero(~gap)
    if full.size < 2:
        raise ImportError_(f"{where}: {full.size} row(s) with a value in every channel; a time history needs at least two")
    a, b = int(full[0]), int(full[-1]) + 1
    if inner := np.flatnonzero(gap[a:b]).tolist():
        r = a + inner[0]
        name = h.names[int(np.flatnonzero(np.isnan(samples[r]))[0])]
        raise ImportError_(f"{where}:{lines[r]}: column {name!r} is empty inside the record (a gap in that channel); "
                           "gvtlink imports one uniform grid: import the part before or after it, or fill the gap")  # fmt: skip
    def lacking(rows: slice) -> str:
        cols = [h.names[j] for j in np.flatnonzero(np.isnan(samples[rows]).any(axis=0))]
        return ", ".join(cols) if len(cols) <= 4 else f"{cols[0]} .. {cols[-1]} ({len(cols)} channels)"

    said = [f"{a} row(s) before line {lines[a]} lack {lacking(slice(0, a))} (empty cells): not imported"] if a else []
    if b < gap.size:
        said.append(f"{gap.size - b} row(s) after line {lines[b - 1]} lack {lacking(slice(b, None))} (empty cells): not imported")
    return samples[a:b], t[a:b], k[a:b], lines[a:b], said


def _time(where: str, h: _Header, t: np.ndarray, k: np.ndarray, lines: np.ndarray, fs: float | None) -> tuple[float, float, str]:
    """(rate, t0, what was assumed) from the time (and index) column, or the stated rate; one line where it breaks."""
    if h.time_col is None:
        if fs is None:
            raise ImportError_(f"{where}: no time column (t [s] or time [s]) and no sample rate; add the column or "
                               "state the rate (gvt import --rate HZ)")  # fmt: skip
        if not (np.isfinite(fs) and fs > 0):
            raise ImportError_(f"{where}: sample rate {fs!r} Hz is not a positive number")
        return float(fs), 0.0, f"sample rate {fs:g} Hz as stated (the CSV has no time column), t0 = 0"
    t = t * h.time_factor
    if np.isnan(t).any():
        r = int(np.flatnonzero(np.isnan(t))[0])
        raise ImportError_(f"{where}:{lines[r]}: the time column is empty; every row needs its time")
    if not h.gvtlink:
        k = None
    else:
        jumps = np.flatnonzero(np.diff(k) != 1)
        if jumps.size or (k != np.round(k)).any():
            r = int(jumps[0]) + 1 if jumps.size else int(np.flatnonzero(k != np.round(k))[0])
            raise ImportError_(f"{where}:{lines[r]}: index goes from {k[r - 1]:.0f} to {k[r]:g}, a gap in the exported "
                               "log; gvtlink imports one uniform grid: export the part before or after it (--start, --end)")
    rate, dev, bad = rate_from_time(t, k, GVTLINK_TIME_TOL_S if h.gvtlink else None)
    if bad >= 0:
        raise ImportError_(f"{where}:{lines[bad]}: the time column breaks at t = {t[bad]:.9g} s (the rows before step "
                           f"{1 / rate:.6g} s); gvtlink does not resample: split the file there or resample it first")
    if fs is not None and abs(rate - fs) > 1e-6 * fs:
        raise ImportError_(f"{where}: the time column's rate is {rate:.9g} Hz, not the {fs:g} Hz stated; drop one of them")
    t0 = float(k[0] / rate) if k is not None else float(t[0])
    return rate, t0, f"sample rate {rate:.9g} Hz from the time column (its stamps within {dev * rate:.2g} of a period)"
