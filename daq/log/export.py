"""``gvt log export``: samples to npz or CSV on the session's timeline, every stream on one time axis.

Why a module of its own: an export is what leaves gvtlink for other tools (FRFs in a spreadsheet, a Python
notebook), so it must carry the timeline that gvtlink itself uses. A two-device log used to export each
stream on its own clock, which put the accelerometer response 0.237 s before the hammer hit.

The session's timeline (docs/log-format.md, "Time base"): the reference stream's sample index, with each
other stream placed by its offset in whole samples (``reference index = own index + offset``).

* format 2 logs carry it in the file: ``gvtlink.time`` (the origin, UTC ns) and each samples channel's
  ``t0_ns`` (= origin + offset);
* format 1 logs (before the time base) have ``t0_ns = 0`` everywhere; a two-device one has the offset the
  hit gate applied in the ``gvtlink.timeline`` metadata (or, if the recorder died before writing it, in the
  last ``/daq/timeline`` message). Their absolute start was not recorded.

Several streams at the reference's rate go into one merged table on the reference grid: one row per grid
index any stream has a sample at, NaN (CSV: an empty cell) where a stream has none. A stream at another rate
(a Modbus ``.poll`` stream) cannot share that grid: the npz has it on its own, the CSV leaves it out and says so.
The output is written atomically (a temporary file beside it, then a rename) and never over its input.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import DataLost
from daq.log import layout
from daq.log.reader import OVERLAP, LogReader, LogReadError, StreamData, StreamInfo
from daq.outputs import atomic_output, refuse_own_input

CSV_ROWS = 16384  # rows formatted at a time


@dataclass(frozen=True)
class TimeBase:
    """Where every stream of a log lies on the session's timeline."""

    format_version: str
    origin_ns: int  # log_time of the session start (UTC ns; 0 for simulated logs and format 1)
    start_utc_ns: int | None  # the session start in UTC, None when the log does not say (format 1)
    reference: str
    offset_samples: dict[str, int] = field(default_factory=dict)  # reference index = own index + this
    offset_ns: dict[str, int] = field(default_factory=dict)  # own sample 0 after the session start
    source: str = ""  # where the offsets came from

    def stream_t0_ns(self, stream: str) -> int:
        """log_time of ``stream``'s sample 0 on the session's timeline (what a format 2 writer puts in t0_ns)."""
        return self.origin_ns + self.offset_ns.get(stream, 0)


def time_base(r: LogReader) -> TimeBase:
    """The session's timeline of the log ``r`` (module docstring), for format 1 and format 2 logs."""
    meta = r.metadata()
    version = meta.get(layout.META_SESSION, {}).get("format_version", "1")
    infos = r.streams()
    timeline = meta.get("gvtlink.timeline", {})
    if version == "1":
        return _time_base_v1(r, infos, timeline)
    t0s = {s: i.t0_ns for s, i in infos.items()}
    origin_txt = meta.get(layout.META_TIME, {}).get("origin_unix_ns")
    origin = int(origin_txt) if origin_txt is not None else min(t0s.values(), default=0)
    ref = timeline.get("reference") or next((s for s in sorted(t0s) if t0s[s] == origin), min(t0s, default=""))
    off_ns = {s: t - origin for s, t in t0s.items()}
    off = {s: round(v * infos[s].sample_rate / 1e9) for s, v in off_ns.items()}
    src = "the time base recorded in the log (format 2)"
    return TimeBase(version, origin, origin if origin_txt is not None else None, ref, off, off_ns, src)


def _time_base_v1(r: LogReader, infos: dict[str, StreamInfo], timeline: dict[str, str]) -> TimeBase:
    """Format 1: every t0_ns is 0; the applied offsets are in ``gvtlink.timeline`` (or the last ``/daq/timeline``)."""
    applied: dict[str, int] = {}
    src = "format 1 log: no clock offsets (one device)"
    if timeline.get("fixed"):
        applied = {s: int(d["applied_samples"]) for s, d in json.loads(timeline["fixed"]).items()}
        src = "format 1 log: the offsets the hit gate applied (gvtlink.timeline)"
    elif len(infos) > 1 and layout.TIMELINE_TOPIC in {c.topic for c in r.channels()}:
        for m in r.json_messages(layout.TIMELINE_TOPIC):
            if m.get("applied_samples") is not None and m.get("stream"):
                applied[m["stream"]] = int(m["applied_samples"])
                timeline = {**timeline, "reference": m.get("reference", "")}
        src = "format 1 log: the offsets the hit gate applied (last /daq/timeline messages)"
    ref = timeline.get("reference") or min(infos, default="")
    for s in list(applied):
        if f"{s}.poll" in infos:  # a device's polled stream shares its clock (the offset in seconds)
            applied[f"{s}.poll"] = round(applied[s] / infos[s].sample_rate * infos[f"{s}.poll"].sample_rate)
    off = {s: applied.get(s, 0) for s in infos}
    off_ns = {s: round(v * 1e9 / infos[s].sample_rate) for s, v in off.items()}
    return TimeBase("1", 0, None, ref, off, off_ns, src)


def utc_text(ns: int | None) -> str:
    """ISO 8601 UTC with nanoseconds, or a note when the log does not say."""
    if ns is None:
        return "start not recorded (format 1 log)"
    import datetime as dt

    sec, frac = divmod(int(ns), 1_000_000_000)
    return f"{dt.datetime.fromtimestamp(sec, dt.UTC):%Y-%m-%dT%H:%M:%S}.{frac:09d}Z"


@dataclass
class _Part:
    stream: str
    data: StreamData
    offset: int  # samples

    @property
    def grid(self) -> np.ndarray:
        return self.data.index + self.offset


def _select(path: Path, infos: dict[str, StreamInfo], tb: TimeBase, stream: str | None,
            channels: Sequence[str] | None) -> dict[str, list[str] | None]:  # fmt: skip
    """Stream → channels to export (None: all), the reference first; one line for a name that does not exist."""
    if stream is not None and stream not in infos:
        raise LogReadError(f"{path}: no stream {stream!r}; streams: {sorted(infos)}")
    names = [stream] if stream else sorted(infos, key=lambda s: (s != tb.reference, s))
    if not channels:
        return dict.fromkeys(names)
    known = {c for s in names for c in infos[s].channels}
    missing = [c for c in channels if c not in known]
    if missing:
        raise LogReadError(f"{path}: no channel(s) {missing} in {', '.join(names)}; --channels takes names from `gvt log info`")
    sel = {s: [c for c in channels if c in infos[s].channels] for s in names}
    return {s: c for s, c in sel.items() if c}


def _read(r: LogReader, tb: TimeBase, sel: dict[str, list[str] | None], start: float | None, end: float | None) -> list[_Part]:
    """Each stream's samples in [start, end) seconds of session time (each read on its own clock). Damaged samples
    are left out and listed (``StreamData.damaged``: the export carries them, then exits 3); samples two blocks
    disagree about refuse the export (:data:`OVERLAP`: the file would have to choose one of them)."""
    infos = r.streams()
    parts = []
    for s, chans in sel.items():
        shift = tb.offset_samples.get(s, 0) / infos[s].sample_rate
        a = None if start is None or start - shift <= 0 else start - shift  # own time < 0 holds no samples
        b = None if end is None else end - shift
        d = r.read_stream(s, chans, a, b, on_damage="skip")
        if conflicts := [x for x in d.damaged if x[2] == OVERLAP]:
            raise r.damaged_error(infos[s], conflicts)
        parts.append(_Part(s, d, tb.offset_samples.get(s, 0)))
    return parts


def _missing(d: StreamData) -> list[tuple[int, int]]:
    """The stream's missing sample ranges: its gaps and its damaged ranges (a damaged first or last chunk leaves
    no gap between blocks), merged."""
    out: list[tuple[int, int]] = []
    for a, b in sorted([*d.gaps, *((a, b) for a, b, _w in d.damaged)]):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _damage_line(out: Path, parts: list[_Part], fmt: str) -> str:
    """The one line (exit 3) after an export that left damaged samples out: which, and where the file says so."""
    dmg = [(p, a, b, why) for p in parts for a, b, why in p.data.damaged]
    p, a, b, why = dmg[0]
    rate = p.data.info.sample_rate
    more = f" and {len(dmg) - 1} more range(s)" if len(dmg) > 1 else ""
    where = f"{p.stream}/gaps and {p.stream}/damaged in it" if fmt == "npz" else "no rows for them"
    return (f"wrote {out} without the damaged samples [{a}, {b}) of stream {p.stream} (t = {a / rate:.3f}–{b / rate:.3f} "
            f"s){more} ({why}): left out as a gap ({where}); the rest is exact")  # fmt: skip


def _merge(parts: list[_Part]) -> tuple[np.ndarray, np.ndarray]:
    """(grid index, data) on the reference grid: rows where any stream has a sample, NaN where one has none."""
    grid = np.unique(np.concatenate([p.grid for p in parts])) if parts else np.zeros(0, np.int64)
    width = sum(len(p.data.channels) for p in parts)
    data = np.full((grid.size, width), np.nan, np.float32)
    col = 0
    for p in parts:
        k = len(p.data.channels)
        rows = np.searchsorted(grid, p.grid)
        data[rows, col : col + k] = p.data.data
        col += k
    return grid, data


def _units(p: _Part) -> list[str]:
    units = dict(zip(p.data.info.channels, p.data.info.units, strict=False))
    return [units.get(c, "") for c in p.data.channels]


#: The farthest --start/--end (s) a log can reach: log times are int64 ns (292 years); a week is the longest
#: session (daq/config/session.py), so a value beyond 1e9 s (31 years) can only be a typo.
MAX_TIME_S = 1e9


def _check_range(start: float | None, end: float | None) -> None:
    """--start/--end are finite seconds within :data:`MAX_TIME_S`: ``nan`` and ``1e300`` reached an int
    conversion and ended as an internal error (issue 30)."""
    for what, v in (("--start", start), ("--end", end)):
        if v is not None and not (math.isfinite(v) and abs(v) <= MAX_TIME_S):
            raise LogReadError(f"{what} {v:g}: give seconds since the session start, within ±{MAX_TIME_S:g} s")
    if start is not None and end is not None and end <= start:
        raise LogReadError(f"--end {end:g} s must be after --start {start:g} s")


def export(
    path: str | Path, out: str | Path, fmt: str, channels: Sequence[str] | None = None, start: float | None = None,
    end: float | None = None, stream: str | None = None,
) -> str:  # fmt: skip
    """Export ``path``'s samples (all streams, or ``stream``) to ``out`` as npz or csv on the session's timeline;
    ``start``/``end``: seconds since the session start. Returns the one line to print; raises LogReadError."""
    if fmt not in ("npz", "csv"):
        raise LogReadError(f"unknown export format {fmt!r}; use npz or csv")
    path, out = Path(path), Path(out)
    _check_range(start, end)
    refuse_own_input(out, [path])
    r = LogReader(path)
    infos = r.streams()
    if not infos:
        raise LogReadError(f"{path}: no sample streams to export")
    tb = time_base(r)
    sel = _select(path, infos, tb, stream, channels)
    ref = tb.reference if tb.reference in sel else next(iter(sel))
    fs = infos[ref].sample_rate
    parts = _read(r, tb, sel, start, end)
    if (start is not None or end is not None) and not any(p.data.index.size for p in parts):
        span = f"from {start:g} s" if end is None else f"before {end:g} s" if start is None else f"in [{start:g}, {end:g}) s"
        raise LogReadError(f"{path}: no samples {span} of session time; `gvt log info {path}` shows each stream's span")
    merged = [p for p in parts if p.data.info.sample_rate == fs]
    apart = [p for p in parts if p.data.info.sample_rate != fs]
    grid, data = _merge(merged)
    if fmt == "npz":
        _write_npz(out, tb, fs, ref, merged, apart, grid, data)
    else:
        _write_csv(out, tb, fs, merged, grid, data)
    if any(p.data.damaged for p in parts):
        raise DataLost(_damage_line(out, merged + apart, fmt))
    holes = int(np.isnan(data).any(axis=1).sum())
    notes = [f"{holes} rows lack some stream's samples (NaN{'' if fmt == 'npz' else ': empty cells'})"] if holes else []
    if apart:
        where = "kept apart in the npz" if fmt == "npz" else "not in the table: export each with --stream"
        notes.append(f"{', '.join(p.stream for p in apart)} at another rate than {fs:g} Hz ({where})")
    shown = ", ".join(f"{p.stream} ({p.offset:+d} samples)" if p.offset else p.stream for p in merged)
    return (f"wrote {out}: {grid.size} rows x {data.shape[1]} channels of {shown} on {ref}'s timeline from "
            f"{utc_text(tb.start_utc_ns)}" + (f"; {'; '.join(notes)}" if notes else ""))  # fmt: skip


def _write_npz(out: Path, tb: TimeBase, fs: float, ref: str, merged: list[_Part], apart: list[_Part],
               grid: np.ndarray, data: np.ndarray) -> None:  # fmt: skip
    arrays: dict[str, np.ndarray] = {
        "t": grid / fs, "index": grid, "data": data,
        "channels": np.array([c for p in merged for c in p.data.channels]),
        "units": np.array([u for p in merged for u in _units(p)]),
        "column_stream": np.array([p.stream for p in merged for _c in p.data.channels]),
        "sample_rate": np.float64(fs), "reference": np.array(ref), "format_version": np.array(tb.format_version),
        "start_utc_ns": np.int64(-1 if tb.start_utc_ns is None else tb.start_utc_ns),
        "start_utc": np.array(utc_text(tb.start_utc_ns)), "time_base": np.array(tb.source),
        "streams": np.array([p.stream for p in merged + apart]),
        "offset_samples": np.array([p.offset for p in merged + apart], np.int64),
    }  # fmt: skip
    for p in merged + apart:  # each stream as recorded: its own index, and its samples' session time
        d, rate = p.data, p.data.info.sample_rate
        arrays[f"{p.stream}/t"] = d.index / rate + tb.offset_ns.get(p.stream, 0) / 1e9
        arrays[f"{p.stream}/index"] = d.index
        arrays[f"{p.stream}/data"] = d.data
        arrays[f"{p.stream}/channels"] = np.array(d.channels)
        arrays[f"{p.stream}/units"] = np.array(_units(p))
        arrays[f"{p.stream}/gaps"] = np.array(_missing(d), dtype=np.int64).reshape(-1, 2)
        arrays[f"{p.stream}/damaged"] = np.array([(a, b) for a, b, _w in d.damaged], dtype=np.int64).reshape(-1, 2)
        arrays[f"{p.stream}/damaged_why"] = np.array([w for _a, _b, w in d.damaged], dtype=str)
    with atomic_output(out) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _write_csv(out: Path, tb: TimeBase, fs: float, merged: list[_Part], grid: np.ndarray, data: np.ndarray) -> None:
    """One header row — ``t [s] since <UTC start>``, ``index`` (the reference grid), ``name [unit]`` — then a row
    per grid index; an empty cell where a stream has no sample there."""
    names = [c for p in merged for c in p.data.channels]
    units = [u for p in merged for u in _units(p)]
    header = [
        f"t [s] since {utc_text(tb.start_utc_ns)}",
        "index",
        *(f"{c} [{u}]" if u else c for c, u in zip(names, units, strict=True)),
    ]
    with atomic_output(out) as tmp, open(tmp, "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(header)
        for a in range(0, grid.size, CSV_ROWS):  # formatted a slice at a time: memory stays bounded
            text = np.char.mod("%.9g", data[a : a + CSV_ROWS].astype(np.float64))
            text[np.isnan(data[a : a + CSV_ROWS])] = ""
            for k, row in enumerate(text.tolist(), start=a):
                wr.writerow([f"{grid[k] / fs:.9f}", int(grid[k]), *row])
