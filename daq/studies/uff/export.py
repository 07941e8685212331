"""``gvt export LOG --format uff``: what a session log holds, as one UFF file (datasets in ``daq/studies/uff/datasets.py``).

Written, in this order: units (164, SI), the test geometry (15) and its trace lines (82), FRFs and coherence (58,
function types 4 and 6) from ``--frf FRF.npz`` (``analysis.frf.FRFSet.to_npz``) and mode shapes (55) from
``--modes MODES.json`` when given, then the time history of every channel of every accepted hit (58, type 1).
The FRFs come first because sdypy-EMA's ``Model.read_uff`` takes the FRF form (receptance, mobility,
accelerance) from the ordinate type of the file's *first* dataset 58, whatever its function type.
The channel table (node, direction, quantity of each channel) is the log's attached rig's
(``analysis.model.channels.rig_channels``) or a CSV given with ``--channels``; a log channel the table does not
name is left out and said so. Every device's channels are exported: each stream is placed on the session's
timeline by the offset the log records (``daq.log.export.time_base``; a second DAQ's sample 0 is the hammer's sample
``offset``), so a hit's records of all devices share one time axis; a stream whose samples do not cover a hit's record
is left out of that hit with a warning line. A hit record is ``start_index .. end_index`` of its ``/daq/hits`` record, or for
logs whose hits carry only the trigger (simulated ones) 10 ms before it to the rig's record length after it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis.errors import BadInput
from analysis.model.channels import Channel, by_name, read_channel_csv, rig_channels
from analysis.model.geometry import rig_geometry
from analysis.model.wireframe import Geometry, make_geometry
from analysis.records import HITS_TOPIC, PLAN_TOPIC
from daq.log.reader import LogReader
from daq.studies.uff import datasets as uff

PRE_TRIGGER_S = 0.01  # daq/hits.py TriggerSettings.pre_trigger: what the hit gate keeps before the edge


def channel_geometry(channels: tuple[Channel, ...]) -> Geometry:
    """Nodes of a CSV channel table (its coordinates; the first row of a node wins), without lines."""
    nodes: dict[int, tuple[float, float, float]] = {}
    for c in channels:
        nodes.setdefault(c.node, c.xyz)
    return make_geometry((n, *xyz) for n, xyz in sorted(nodes.items()))


def hit_windows(reader: LogReader, fs: float, record_s: float, n_samples: int) -> list[tuple[int, int, int]]:
    """(hit, start, end) sample ranges of the accepted hits (``/daq/hits``, verdict ``accepted``): the record the hit
    gate logged, else 10 ms before the trigger to ``record_s`` after it or the next hit's pre-trigger, whichever is first."""
    hits = [h for h in reader.json_messages(HITS_TOPIC) if "index" in h]
    edges = sorted(int(h["index"]) for h in hits)
    out = []
    for h in hits:
        if h.get("verdict") != "accepted":
            continue
        start = int(h.get("start_index", int(h["index"]) - round(PRE_TRIGGER_S * fs)))
        later = [e for e in edges if e > int(h["index"])]  # a record without an end stops before the next hit's pre-trigger
        default_end = min([int(h["index"]) + round(record_s * fs)] + [e - round(PRE_TRIGGER_S * fs) for e in later[:1]])
        end = int(h.get("end_index", default_end))
        out.append((int(h.get("hit", len(out))), max(0, start), min(n_samples, end)))
    return out


def load_frf_npz(path: Path) -> Any:
    """What ``FRFSet.to_npz`` wrote, as a namespace with its fields (read here so export does not need analysis.frf)."""
    from types import SimpleNamespace

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            return SimpleNamespace(freq=z["freq"], H=z["H"], coherence=z["coherence"], n_averages=z["n_averages"], **meta)
    except (OSError, KeyError, ValueError) as exc:
        raise BadInput(f"--frf {path}: not an FRF file written by FRFSet.to_npz ({exc})") from None


def load_modes_json(path: Path) -> dict[str, Any]:
    """``{"freq_hz": [...], "zeta": [...], "outputs": [names], "shapes_re": [[n_out x n_modes]], "shapes_im": ...}``
    (``shapes_im`` absent: real normal modes)."""
    try:
        d = json.loads(Path(path).read_text())
        shapes = np.asarray(d["shapes_re"], dtype=float)
        if "shapes_im" in d:
            shapes = shapes + 1j * np.asarray(d["shapes_im"], dtype=float)
        return {"freq_hz": [float(x) for x in d["freq_hz"]], "zeta": [float(x) for x in d["zeta"]],
                "outputs": [str(x) for x in d["outputs"]], "shapes": shapes, "rows": d.get("modes") or []}  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BadInput(f"--modes {path}: not a modes file (freq_hz, zeta, outputs, shapes_re[, shapes_im]): {exc}") from None


@dataclass(frozen=True)
class _Placed:
    """The channel-table channels of one stream and where its samples lie on the hits' grid (the force stream's):
    own index = hit index - ``offset`` at the same rate (exact), or own time = hit time - ``shift_s`` at another."""

    stream: str
    channels: tuple[str, ...]
    fs: float
    offset: int
    shift_s: float


def _placed_streams(reader: LogReader, force_stream: str, table: dict[str, Channel]) -> tuple[list[_Placed], list[str]]:
    """Every stream with a channel of the table, placed on the session's timeline (``daq.log.export.time_base``: the
    offsets the log records, a second device's included), the force stream first; and the log channels left out
    because the table does not name them."""
    from daq.log.export import time_base

    infos = reader.streams()
    tb = time_base(reader)
    fs_ref = infos[force_stream].sample_rate
    base_n, base_ns = tb.offset_samples.get(force_stream, 0), tb.offset_ns.get(force_stream, 0)
    placed, skipped = [], []
    for s in [force_stream, *sorted(x for x in infos if x != force_stream)]:
        info = infos[s]
        for c, unit in zip(info.channels, info.units, strict=True):
            if c in table and unit and unit != table[c].unit:
                raise BadInput(f"{reader.path}: channel {c} is recorded in {unit!r} but the channel table says {table[c].unit!r}")
        skipped += [c for c in info.channels if c not in table]
        names = tuple(c for c in info.channels if c in table)
        if names:
            shift = (tb.offset_ns.get(s, 0) - base_ns) / 1e9
            placed.append(_Placed(s, names, info.sample_rate, tb.offset_samples.get(s, 0) - base_n, shift))
    assert placed and placed[0].stream == force_stream and fs_ref > 0
    return placed, skipped


def _own_window(p: _Placed, a: int, b: int, fs_ref: float) -> tuple[int, int, float]:
    """Own sample range [j0, j1) of stream ``p`` for the hit record [a, b) of the force stream, and its session time."""
    if p.fs == fs_ref:
        return a - p.offset, b - p.offset, a / fs_ref
    j0, j1 = (int(np.ceil((x / fs_ref - p.shift_s) * p.fs - 1e-9)) for x in (a, b))
    return j0, j1, j0 / p.fs + p.shift_s


def _hit_sets(reader: LogReader, stream: str, table: dict[str, Channel], record_s: float, binary: bool):
    """Datasets 58 of every accepted hit, every stream's channels on the session's timeline; the names of the log
    channels left out of the table; and one line per stream whose samples do not cover a hit's record (left out)."""
    placed, skipped = _placed_streams(reader, stream, table)
    ref = table["hammer"] if "hammer" in table else next(
        (table[c] for p in placed for c in p.channels if table[c].quantity == "force"), None)  # fmt: skip
    if ref is None:
        raise BadInput(f"{reader.path}: no force channel in the channel table; the hits need their reference DOF")
    fs = placed[0].fs
    n_total = int(reader.stream_records().get(stream, {}).get("end_index") or 2**62)
    sets, hits, fid, uncovered = [], [], 1, {}
    for hit, a, b in hit_windows(reader, fs, record_s, n_total):
        for k, p in enumerate(placed):
            j0, j1, t0 = _own_window(p, a, b, fs)
            sd = reader.read_stream(p.stream, list(p.channels), start=(j0 - 0.5) / p.fs, end=(j1 - 0.5) / p.fs)
            keep = (sd.index >= j0) & (sd.index < j1)
            if int(keep.sum()) != j1 - j0:
                if k == 0:  # the force itself: no hit without it
                    raise BadInput(f"{reader.path}: hit {hit} needs samples [{a}, {b}) of {stream}; the log has "
                                   f"{int(keep.sum())} of them")  # fmt: skip
                uncovered.setdefault(p.stream, []).append(hit)
                continue
            chans = [table[c] for c in p.channels]
            sets += uff.time_sets(sd.data[keep], p.fs, chans, ref, t0=t0, hit=hit, binary=binary, first_id=fid)
            fid += len(chans)
        hits.append(hit)
    chans = {p.stream: ", ".join(p.channels) for p in placed}
    notes = [f"{s} ({chans[s]}) left out of hit(s) {', '.join(map(str, h))}: the log has not all its samples of those records"
             for s, h in uncovered.items()]  # fmt: skip
    return sets, hits, skipped, notes, placed


def _force_stream(reader: LogReader, table: dict[str, Channel]) -> str:
    streams = reader.streams()
    for name, info in streams.items():
        if any(c in table and table[c].quantity == "force" for c in info.channels):
            return name
    raise BadInput(f"{reader.path}: no stream carries a force channel of the channel table; streams: {sorted(streams)}")


def _stream_text(p: _Placed) -> str:
    if p.offset == 0 and p.shift_s == 0:
        return p.stream
    return f"{p.stream} at {p.offset:+d} samples" if round(p.shift_s * p.fs) == p.offset else f"{p.stream} at {p.shift_s:+.6f} s"


def _plan_references(reader: LogReader, chans: dict[str, Channel]) -> dict[str, Channel]:
    """A roving-hammer log's hit points (its ``/daq/plan`` record) as channels: the FRF matrix's references."""
    from daq.roving import plan_channels

    plans = [p for p in reader.json_messages(PLAN_TOPIC) if p.get("event") == "plan"]
    return plan_channels(plans[0]["points"], chans["hammer"]) if plans and "hammer" in chans else {}


def export_uff(log: Path, out: Path, *, channels_csv: Path | None = None, frf: Path | None = None,
               modes: Path | None = None, binary: bool = False) -> str:  # fmt: skip
    """Write ``out`` (the caller made it a temporary path) and return the one-line summary (and a ``warning:`` line
    when the FRFs carry an exponential window, :func:`daq.studies.uff.datasets.window_note`)."""
    from daq.log.rig import rig_from_log

    reader = LogReader(log)
    try:
        rig = rig_from_log(reader)
    except BadInput:
        if channels_csv is None:
            raise
        rig = None  # the CSV gives the channels; hits then need their own start/end (or 2 s records)
    if channels_csv is not None:
        table = read_channel_csv(channels_csv)
        geometry = channel_geometry(table)
    else:
        assert rig is not None
        table, geometry = rig_channels(rig), rig_geometry(rig)
    chans = by_name(table)
    chans.update(_plan_references(reader, chans))
    record_s = rig.config.daq.record_length if rig is not None else 2.0
    stream = _force_stream(reader, chans)
    hit_sets, hits, skipped, uncovered, placed = _hit_sets(reader, stream, chans, record_s, binary)
    if reader.damage:  # a chunk of hit records (or samples) failed: hits may be missing, as gvt frf says (exit 3)
        from daq.studies.frf_judge import damage_error

        raise damage_error(reader, [], "hit records may be lost with them")
    if not hits:
        raise BadInput(f"{log}: no accepted hit in the log ({HITS_TOPIC}); a UFF of the geometry alone is not a test: "
                       "record or simulate a session with hits")  # fmt: skip
    sets = [uff.units_set(), *uff.geometry_sets(geometry), *uff.trace_line_sets(geometry)]
    parts = [
        f"{geometry.ids.size} nodes",
        f"{len(geometry.lines)} lines",
        f"{len(hits)} accepted hit(s) x {sum(len(p.channels) for p in placed)} channels"
        + (f" of {len(placed)} streams ({', '.join(_stream_text(p) for p in placed)})" if len(placed) > 1 else ""),
    ]
    note = None
    if frf is not None:
        f = load_frf_npz(frf)
        sets += uff.frfset_sets(f, chans, binary=binary)
        parts.append(f"{f.H.shape[0]}x{f.H.shape[1]} {f.kind} FRFs + coherence, {f.freq.size} lines")
        note = uff.window_note(f)
    if modes is not None:
        m = load_modes_json(modes)
        missing = [n for n in m["outputs"] if n not in chans]
        if missing:
            raise BadInput(f"--modes {modes}: outputs {missing} are not in the channel table")
        notes = [uff.mode_quality_id(r) for r in m["rows"]] if len(m["rows"]) == len(m["freq_hz"]) else None
        sets += uff.mode_shape_sets(m["freq_hz"], m["zeta"], m["shapes"], [chans[n] for n in m["outputs"]], notes=notes)
        parts.append(f"{len(m['freq_hz'])} mode shapes")
    sets += hit_sets  # after the FRFs: sdypy-EMA's read_uff takes the FRF form from the file's first dataset 58
    uff.write_uff(out, sets)
    left = f"; left out (not in the channel table): {', '.join(skipped)}" if skipped else ""
    warn = "".join(f"\nwarning: {x}" for x in [*uncovered, *([note] if note else [])])
    return f"{len(sets)} UFF datasets: {', '.join(parts)}{left}{warn}"


__all__ = ["channel_geometry", "export_uff", "hit_windows", "load_frf_npz", "load_modes_json"]
