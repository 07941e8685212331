"""``gvt log`` tools as library functions: info, recover, export.

``recover`` follows ``mcap recover``'s contract: it rewrites everything readable into a new, fully
indexed file and reports whether data was lost (exit code 3 in the CLI) or not (0).
"""

from __future__ import annotations

import csv
import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from daq.log import layout
from daq.log.proto import BlockDecodeError, decode_block
from daq.log.reader import LogReader, LogReadError, SalvageReport
from drivers.blocks import BlockStatus

RESTART = int(BlockStatus.RESTART)


def log_info(path: str | Path) -> dict[str, Any]:
    r = LogReader(path)
    streams = []
    for name, info in sorted(r.streams().items()):
        firsts, counts, bad, statuses, restarts = [], [], 0, 0, []
        for _ch, msg in r.iter_messages([info.topic], time_order=True):
            try:
                b = decode_block(msg.data)
            except BlockDecodeError:
                bad += 1
                continue
            firsts.append(b.first_index)
            counts.append(b.data.shape[0])
            statuses |= b.status
            if b.status & RESTART:
                restarts.append(b.first_index)
        order = np.argsort(firsts) if firsts else []
        f = np.asarray(firsts, np.int64)[order] if firsts else np.zeros(0, np.int64)
        n = np.asarray(counts, np.int64)[order] if counts else np.zeros(0, np.int64)
        gaps = [(int(f[i] + n[i]), int(f[i + 1])) for i in range(len(f) - 1) if f[i + 1] > f[i] + n[i]]
        total = int(n.sum())
        span = int(f[-1] + n[-1] - f[0]) if len(f) else 0
        cuts = [int(f[0]), *sorted(restarts)] if len(f) else []
        ends = [*cuts[1:], int(f[-1] + n[-1])] if len(f) else []
        segments = [(a, b) for a, b in zip(cuts, ends, strict=True)]
        streams.append(
            {
                "stream": name,
                "topic": info.topic,
                "channels": info.channels,
                "units": info.units,
                "sample_rate": info.sample_rate,
                "blocks": len(f),
                "samples": total,
                "duration_s": span / info.sample_rate,
                "first_index": int(f[0]) if len(f) else None,
                "end_index": int(f[-1] + n[-1]) if len(f) else None,
                "gaps": gaps,
                "missing_samples": int(sum(b - a for a, b in gaps)),
                # a device restart starts a new segment (BlockStatus.RESTART); the gap before it is estimated
                "segments": segments,
                "undecodable_blocks": bad,
                "status_flags": int(statuses),
            }
        )
    events = r.json_messages(layout.EVENTS_TOPIC)
    hits = r.json_messages(layout.HITS_TOPIC)
    for s in streams:  # losses the writer logged: they may sit at the end, where no gap can show them
        over = [e for e in events if e.get("kind") == "overrun" and e.get("stream") == s["stream"]]
        s["overrun_samples"] = int(sum(int(e.get("count", 0)) for e in over))
        s["overrun_ranges"] = [(int(e["start_index"]), int(e["end_index"])) for e in over if "start_index" in e]
    rep = r.report
    return {
        "file": str(r.path),
        "size_bytes": r.file_size,
        "health": _health(rep),
        "complete": rep.complete,
        "data_lost": rep.data_lost,
        "salvage": {
            "messages": rep.messages,
            "chunks_ok": rep.chunks_ok,
            "chunks_bad": rep.chunks_bad,
            "bytes_scanned": rep.bytes_scanned,
            "stopped_because": rep.stopped_because,
        },
        "streams": streams,
        "hits": len(hits),
        "events": dict(Counter(e.get("kind", "?") for e in events)),
        "topics": sorted({ch.topic for ch in r.channels()}),
        "metadata": sorted(r.metadata()),
        "attachments": sorted(r.attachments()),
    }


def _health(rep: SalvageReport) -> str:
    if rep.complete:
        return "ok: footer and summary intact"
    why = f" ({rep.stopped_because})" if rep.stopped_because else ""
    return (
        f"damaged{why}: salvaged {rep.messages} messages from {rep.chunks_ok} complete chunks"
        + (f", {rep.chunks_bad} corrupt chunks skipped" if rep.chunks_bad else "")
        + f"; read {rep.bytes_scanned} of {rep.file_size} bytes — run `gvt log recover`"
    )


def recover(src: str | Path, dst: str | Path, chunk_size: int = 1 << 20) -> SalvageReport:
    """Rewrite every readable record of ``src`` into a new indexed file ``dst`` (``chunk_size``: uncompressed
    bytes per output chunk). Reads and writes a chunk at a time: memory does not grow with the log."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise LogReadError(f"{dst}: output must differ from the input")
    r = LogReader(src)
    schemas = r.schemas()
    tmp = dst.with_name(dst.name + ".part")
    with open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        w.start(profile=layout.PROFILE, library="gvtlink recover")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for sid, s in schemas.items():
            schema_ids[sid] = w.register_schema(s.name, s.encoding, s.data)
        for name, data in r.metadata().items():
            w.add_metadata(name, data)
        for name, (media, data) in r.attachments().items():
            w.add_attachment(create_time=0, log_time=0, name=name, media_type=media, data=data)
        for ch, msg in r.iter_messages(salvage=True):
            if ch.id not in channel_ids:
                channel_ids[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, schema_ids.get(ch.schema_id, 0), dict(ch.metadata)
                )
            w.add_message(
                channel_ids[ch.id], log_time=msg.log_time, data=msg.data, publish_time=msg.publish_time, sequence=msg.sequence
            )
        w.finish()
    tmp.replace(dst)
    return r.report


def export(
    path: str | Path,
    out: str | Path,
    fmt: str,
    channels: Sequence[str] | None = None,
    start: float | None = None,
    end: float | None = None,
    stream: str | None = None,
) -> str:
    r = LogReader(path)
    streams = r.streams()
    if not streams:
        raise LogReadError(f"{path}: no sample streams to export")
    names = [stream] if stream else sorted(streams)
    if stream and stream not in streams:
        raise LogReadError(f"{path}: no stream {stream!r}; streams: {sorted(streams)}")
    out = Path(out)
    if fmt == "npz":
        arrays: dict[str, np.ndarray] = {}
        for s in names:
            chans = [c for c in (channels or []) if c in streams[s].channels] or None
            if channels and not chans:
                continue
            d = r.read_stream(s, chans, start, end)
            arrays[f"{s}/t"] = d.t
            arrays[f"{s}/index"] = d.index
            arrays[f"{s}/data"] = d.data
            arrays[f"{s}/channels"] = np.array(d.channels)
            arrays[f"{s}/gaps"] = np.array(d.gaps, dtype=np.int64).reshape(-1, 2)
        if not arrays:
            raise LogReadError(f"{path}: none of the channels {list(channels or [])} exist")
        with open(out, "wb") as fh:
            np.savez(fh, **arrays)
        return f"wrote {out}: {', '.join(names)}"
    if fmt == "csv":
        if len(names) > 1:
            raise LogReadError(f"{path}: {len(names)} streams; choose one with --stream ({', '.join(names)})")
        d = r.read_stream(names[0], channels, start, end)
        with open(out, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["t_s", "index", *d.channels])
            for t, i, row in zip(d.t, d.index, d.data, strict=True):
                wr.writerow([f"{t:.9f}", int(i), *(f"{v:.9g}" for v in row)])
        return f"wrote {out}: {len(d.index)} rows x {len(d.channels)} channels"
    raise LogReadError(f"unknown export format {fmt!r}; use npz or csv")


def info_text(info: dict[str, Any]) -> str:
    lines = [f"{info['file']}  {info['size_bytes']} bytes  health: {info['health']}"]
    for s in info["streams"]:
        lines.append(
            f"  stream {s['stream']}: {len(s['channels'])} ch @ {s['sample_rate']:g} Hz, {s['samples']} samples "
            f"({s['duration_s']:.3f} s) in {s['blocks']} blocks, gaps: {len(s['gaps'])} ({s['missing_samples']} samples)"
            + (f", {s['undecodable_blocks']} undecodable blocks" if s["undecodable_blocks"] else "")
            + (f", NOT RECORDED (writer overrun): {s['overrun_samples']} samples" if s["overrun_samples"] else "")
        )
        if len(s.get("segments", ())) > 1:
            segs = ", ".join(f"[{a}, {b})" for a, b in s["segments"])
            lines.append(f"    segments (the device restarted; each gap before a segment is estimated): {segs}")
        lines.append(f"    channels: {', '.join(f'{c} [{u}]' for c, u in zip(s['channels'], s['units'], strict=False))}")
    ev = ", ".join(f"{k}: {v}" for k, v in sorted(info["events"].items())) or "none"
    lines.append(f"  hits: {info['hits']}  events: {ev}")
    lines.append(f"  topics: {', '.join(info['topics'])}")
    lines.append(f"  metadata: {', '.join(info['metadata']) or 'none'}  attachments: {', '.join(info['attachments']) or 'none'}")
    return "\n".join(lines)


def info_json(info: dict[str, Any]) -> str:
    return json.dumps(info, indent=2)
