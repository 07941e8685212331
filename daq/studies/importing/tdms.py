"""NI TDMS time histories (LabVIEW, DAQmx, FlexLogger, DIAdem; read with npTDMS) into a :class:`TimeImport`.

What is read, in NI's own property names (https://www.ni.com/docs, "TDMS file format"; npTDMS's ``time_track``
reads the same ones): each channel's samples (npTDMS applies DAQmx scaling), its unit ``unit_string``, its rate
``wf_increment`` (s per sample) and start ``wf_start_offset`` (s), or, in a group without ``wf_increment``, a
channel named ``time`` or ``t`` (or in a time unit) that is the group's time track. ``NI_ChannelName`` and
``wf_start_time`` are shown in the assumptions when present.

Groups: the channels of the one group with data are one import. Several groups on the same grid (rate, length and
start) are imported together (a name two groups share becomes ``group/channel``); several groups on different
grids are refused, naming each with its rate, unless ``group`` picks one (``gvt import --group NAME``), and then the
others are named as not imported. Why refuse rather than take the first: nothing is dropped without the user's word.

A group with no time information (no ``wf_increment`` and no time channel) is one line, exit 2, unless the user
states the rate (``fs``); a channel without ``unit_string`` is one line too (never a guessed unit).

The samples are returned as the transpose of a channel-major (n_ch, n) array: (n, n_ch) as TimeImport says, each
channel contiguous (a row-major table written a column at a time was 12 x slower, 1.6 s for 32 M samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from daq.studies.importing._common import channel_list, hash_in_background, load_table, rate_from_time, si_factors
from daq.studies.importing.data import ImportError_, Provenance, TimeImport

TIME_NAMES = ("time", "t")


@dataclass
class _Grid:
    """One group's channels on one grid."""

    group: str
    names: list[str]
    units: list[str]
    data: list[np.ndarray]
    fs: float
    t0: float
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return self.data[0].size

    def label(self) -> str:
        return f"{self.group!r} ({len(self.names)} ch, {self.fs:.9g} Hz, {self.n} samples from {self.t0:g} s)"


def _open(where: str, path: Path):
    from nptdms import TdmsFile

    try:
        return TdmsFile.read(path)
    except OSError as exc:
        raise ImportError_(f"{where}: cannot read ({exc.strerror or exc})") from None
    except Exception as exc:  # npTDMS raises ValueError, KeyError, struct.error ... on a file that is not TDMS
        raise ImportError_(f"{where}: not a readable TDMS file ({type(exc).__name__}: {str(exc)[:80]}); "
                           "export it again from the NI tool") from None  # fmt: skip


def _rate_from_increment(inc: float) -> float:
    """1 / wf_increment, as the round rate it was written from when one reproduces the increment exactly
    (1 / 51200 Hz is stored as 1.953125e-05; 1 / 3e-4 s is 3333.33... Hz and stays so)."""
    raw = 1.0 / inc
    for digits in range(10):
        c = round(raw, digits)
        if c > 0 and abs(1.0 / c - inc) <= 4 * np.finfo(float).eps * inc:
            return c
    return raw


def _is_time(ch) -> bool:
    unit = str(ch.properties.get("unit_string", "")).strip()
    if getattr(ch.dtype, "kind", "") == "M":  # NI timestamps, whatever the channel's name
        return True
    return unit in ("s", "ms") or (not unit and ch.name.strip().lower() in TIME_NAMES)  # "T" in degC is a temperature


def _seconds(ch, notes: list[str]) -> np.ndarray:
    """A time channel in seconds: numbers in s or ms, or NI timestamps (datetime64, as DAQmx logs them), taken
    relative to the first one (which is said)."""
    raw = ch[:]
    if raw.dtype.kind == "M":
        notes.append(f"time channel {ch.name!r} starts at {raw[0]} (a timestamp); times taken from it")
        return (raw - raw[0]).astype("timedelta64[ns]").astype(np.int64) / 1e9
    if raw.dtype.kind not in "fiu":
        raise ImportError_(f"time channel {ch.group_name}/{ch.name} holds {raw.dtype}, not times")
    return raw.astype(np.float64) * (1e-3 if str(ch.properties.get("unit_string", "")).strip() == "ms" else 1.0)


def _grid(where: str, group, fs_stated: float | None) -> _Grid | None:
    """The group's data channels on one grid, or None for a group without data; one line when they disagree."""
    chans = [c for c in group.channels() if len(c) > 0]
    times = [c for c in chans if _is_time(c) and "wf_increment" not in c.properties]
    data = [c for c in chans if c not in times]
    if not data:
        return None
    notes = [f"empty channel(s) {[c.name for c in group.channels() if len(c) == 0]} of group {group.name!r} not imported"]
    notes = notes if len(chans) < len(group.channels()) else []
    lengths = {c.name: len(c) for c in data}
    if len(set(lengths.values())) > 1:
        counts = {n: sum(v == n for v in lengths.values()) for n in sorted(set(lengths.values()))}
        said = ", ".join(f"{k} of {n} samples" for n, k in counts.items())
        raise ImportError_(f"{where}: group {group.name!r} has channels of different lengths ({said}); import channels "
                           "of one length (re-export, or --group on a group that has them)")  # fmt: skip
    for c in data:
        if c.dtype is None or c.dtype.kind not in "fiub":
            raise ImportError_(f"{where}: channel {group.name}/{c.name} holds {c.dtype}, not numbers; remove it from the file")
    incs = {c.name: c.properties.get("wf_increment") for c in data}
    if all(v is not None for v in incs.values()):
        if len({float(v) for v in incs.values()}) > 1:
            raise ImportError_(f"{where}: group {group.name!r} mixes rates (wf_increment {incs}); import one rate at a time")
        fs = _rate_from_increment(float(next(iter(incs.values()))))
        t0 = float(data[0].properties.get("wf_start_offset", 0.0))
        notes.append(f"group {group.name!r}: {fs:.9g} Hz from wf_increment, t0 = {t0:g} s (wf_start_offset)")
        notes += [f"time channel {c.name!r} of group {group.name!r} not imported (wf_increment gives the rate)" for c in times]
    elif times:
        t = _seconds(times[0], notes)
        if t.size != data[0].__len__():
            raise ImportError_(f"{where}: group {group.name!r}: time channel {times[0].name!r} has {t.size} samples, the "
                               f"channels {len(data[0])}; give them one length")  # fmt: skip
        fs, dev, bad = rate_from_time(t)
        if bad >= 0:
            raise ImportError_(f"{where}: group {group.name!r}: time channel {times[0].name!r} breaks at sample {bad} "
                               f"(t = {t[bad]:.9g} s); gvtlink does not resample: split the record there")  # fmt: skip
        t0 = float(t[0])
        notes.append(f"group {group.name!r}: {fs:.9g} Hz from time channel {times[0].name!r} (within {dev * fs:.2g} of a period)")
    elif fs_stated is not None:
        fs, t0 = float(fs_stated), 0.0
        notes.append(f"group {group.name!r}: {fs:g} Hz as stated (no wf_increment, no time channel), t0 = 0")
    else:
        raise ImportError_(f"{where}: group {group.name!r} has no time information (no wf_increment on its channels, "
                           "no time channel); write wf_increment or a time channel, or state the rate (gvt import --rate HZ)")
    for c in data:
        ni = c.properties.get("NI_ChannelName")
        if ni is not None and str(ni) != c.name:
            notes.append(f"channel {c.name!r} is NI_ChannelName {str(ni)!r}")
    if "wf_start_time" in data[0].properties:
        notes.append(f"group {group.name!r} starts at {data[0].properties['wf_start_time']} (wf_start_time)")
    units = [str(c.properties.get("unit_string", "")).strip() for c in data]
    return _Grid(group.name, [c.name for c in data], units, [c[:] for c in data], fs, t0, notes)


def _choose(where: str, f, group: str | None, fs: float | None) -> tuple[list[_Grid], list[str]]:
    """The groups to import: ``group`` alone (the others named), else every group with data, which must share one
    grid; a group that cannot be read (mixed lengths or rates, no time) refuses the file naming it and ``--group``."""
    groups = [g for g in f.groups() if any(len(c) for c in g.channels())]
    names = ", ".join(repr(g.name) for g in groups)
    if group is not None:
        picked = [g for g in groups if g.name == group]
        grid = _grid(where, picked[0], fs) if picked else None
        if grid is None:
            raise ImportError_(f"{where}: no group {group!r} with data channels; groups with data: {names}")
        rest = [f"{g.name!r} ({len(g.channels())} ch)" for g in groups if g.name != group]
        return [grid], [f"group(s) not imported (--group {group}): {', '.join(rest)}"] if rest else []
    grids = []
    for g in groups:
        try:
            grids += [x] if (x := _grid(where, g, fs)) is not None else []
        except ImportError_ as exc:
            if len(groups) == 1:
                raise
            why = str(exc).removeprefix(f"{where}: ").split(";")[0]
            raise ImportError_(f"{where}: {why}; import one group at a time (gvt import --group NAME; groups: {names})") from None
    if not grids:
        raise ImportError_(f"{where}: no channel holds samples")
    if len({(g.fs, g.n, g.t0) for g in grids}) > 1:
        raise ImportError_(f"{where}: groups on different grids: {'; '.join(g.label() for g in grids)}; import one at a "
                           "time (gvt import --group NAME)")  # fmt: skip
    return grids, []


def read(path: Path, channels: Path | None = None, fs: float | None = None, group: str | None = None) -> TimeImport:
    """Read the TDMS file ``path`` (module docstring); ``channels`` a channel table, ``fs`` a stated rate for a file
    without time information, ``group`` the one group to import. ImportError_ (one line, exit 2) on bad input."""
    path = Path(path)
    where = str(path)
    table = load_table(channels)
    if not path.is_file():
        raise ImportError_(f"{where}: no such file")
    sha = hash_in_background(path)  # beside npTDMS's read, not after it
    f = _open(where, path)
    grids, notes = _choose(where, f, group, fs)
    seen: dict[str, int] = {}
    for g in grids:
        for n in g.names:
            seen[n] = seen.get(n, 0) + 1
    names = [n if seen[n] == 1 else f"{g.group}/{n}" for g in grids for n in g.names]
    units = [u for g in grids for u in g.units]
    factors, quantities, conv = si_factors(where, names, units, table)
    cols = [d for g in grids for d in g.data]
    by_channel = np.empty((len(cols), cols[0].size), np.float64)  # channel-major: each channel written in one pass
    for k, d in enumerate(cols):
        np.multiply(d, factors[k], out=by_channel[k], dtype=np.float64)  # float32 -> float64 exactly, then the factor
    chans, more = channel_list(where, names, quantities, table)
    writer = str(f.properties.get("author") or f.properties.get("Author") or "")  # the root's "name" is the file's title
    said = (*(n for g in grids for n in g.notes), *notes, *conv, *more)
    prov = Provenance(where, sha(), "tdms", writer, said)
    return TimeImport(by_channel.T, grids[0].fs, chans, prov, source_units=units, t0_s=grids[0].t0)
