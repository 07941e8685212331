"""``gvt log`` tools as library functions: info and recover (export: ``daq/log/export.py``).

``log_info`` answers from the summary (the writer's ``gvtlink.streams`` record, the indexes) without reading
sample data, so it takes well under a second for any size; ``verify=True`` (``gvt log info --verify``) reads
and checks every chunk and block instead and says exactly which samples are damaged. ``recover`` follows
``mcap recover``'s contract: it rewrites everything readable into a new, fully indexed file and reports
whether data was lost (exit code 3 in the CLI) or not (0).
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from daq.log import layout
from daq.log.reader import OVERLAP, Damage, DamageRanges, LogReader, LogReadError, SalvageReport, StreamInfo, kept_blocks
from daq.log.seal import seal
from drivers.blocks import BlockStatus

RESTART = int(BlockStatus.RESTART)


def log_info(path: str | Path, verify: bool = False) -> dict[str, Any]:
    """What the log holds per stream, its events named, and its health. Without ``verify`` a complete log is
    described from its summary and the writer's closing records (``gvtlink.streams``, ``gvtlink.events``: no chunk
    is read; bench/bench_log_info.py); an old log without the
    writer's ``gvtlink.streams`` record, or a damaged one, by decoding its blocks (every chunk CRC-checked)."""
    r = LogReader(path)
    r.require_log()
    recs = {} if verify else r.stream_records()
    streams = []
    for name, info in sorted(r.streams().items()):
        s = _from_record(recs[name]) if name in recs else _by_decoding(r, name, info)
        span = (s["end_index"] - s["first_index"]) if s["blocks"] else 0
        missing = int(sum(b - a for a, b in s["gaps"]))
        streams.append(
            {"stream": name, "topic": info.topic, "channels": info.channels, "units": info.units,
             "sample_rate": info.sample_rate, **s, "duration_s": span / info.sample_rate, "missing_samples": missing}
        )  # fmt: skip
    summary_events = _events_record(r) if recs and len(recs) == len(streams) else None
    if summary_events is not None:  # from the summary: no chunk read at all
        events, counts = summary_events
        n_hits = r.message_count(layout.HITS_TOPIC)
    else:
        events = r.json_messages(layout.EVENTS_TOPIC)
        counts = dict(Counter(str(e.get("kind", "?")) for e in events))
        n_hits = len(r.json_messages(layout.HITS_TOPIC))
    for s in streams:  # losses the writer logged: they may sit at the end, where no gap can show them
        over = [e for e in events if e.get("kind") == "overrun" and e.get("stream") == s["stream"]]
        s["overrun_samples"] = int(sum(int(e.get("count", 0)) for e in over if isinstance(e.get("count", 0), int)))
        s["overrun_ranges"] = [(e["start_index"], e["end_index"]) for e in over if "start_index" in e and "end_index" in e]
    held_lost = _held_lost(events, streams)
    meta_names, attachment_names = sorted(r.metadata()), sorted(r.attachments())  # checked: before the health line
    rep = r.report
    damaged = {s["stream"]: s["damaged"] for s in streams if s.get("damaged")}
    checked = "verify" if verify else "summary" if r.indexed and len(recs) == len(streams) else "decoded"
    return {
        "file": str(r.path),
        "size_bytes": r.file_size,
        "health": _health(rep, r, damaged, checked),
        "checked": checked,
        "complete": rep.complete,
        "data_lost": rep.data_lost or bool(r.damage) or bool(damaged),
        "salvage": {
            "messages": rep.messages,
            "chunks_ok": rep.chunks_ok,
            "chunks_bad": rep.chunks_bad,
            "bytes_scanned": rep.bytes_scanned,
            "stopped_because": rep.stopped_because,
            "summary_problem": rep.summary_problem,
            "duplicates": rep.duplicates,
        },
        "damage": [{"offset": d.offset, "reason": d.reason} for d in r.damage.values()],
        "streams": streams,
        "hits": n_hits,
        "events": counts,
        "named_events": _named_events(events),
        "topics": sorted({ch.topic for ch in r.channels()}),
        "metadata": meta_names,
        "attachments": attachment_names,
        "problems": list(dict.fromkeys([*r.problems, *held_lost])),
        "timeline": _timeline(r, counts),
    }


def _held_lost(events: list[dict[str, Any]], streams: list[dict[str, Any]]) -> list[str]:
    """A second device's stream waits in the writer for its clock offset; the recorder logs where each began
    (``stream_held``). A held start the log's data does not reach was lost with the recorder (issue 30)."""
    firsts = {s["stream"]: s.get("first_index") for s in streams if s.get("blocks")}
    out = []
    for e in events:
        if e.get("kind") != "stream_held" or not isinstance(e.get("first_index"), int):
            continue
        name, first = str(e.get("stream", "?")), int(e["first_index"])
        have = firsts.get(name)
        if have is None or have > first:
            upto = "on" if have is None else f"to {have}"
            out.append(f"{name}: samples from {first} {upto} were held in memory for the clock offset and never "
                       "written (the recorder ended before the offset was fixed)")
    return out


def _timeline(r: LogReader, counts: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Per placed stream: the offset the session applied and its final estimate with their uncertainties
    (``gvtlink.timeline``), and how often the estimate moved (``timeline_moved`` events)."""
    rec = r.metadata().get("gvtlink.timeline") or {}
    try:
        fixed, final = json.loads(rec.get("fixed", "{}")), json.loads(rec.get("final", "{}"))
    except ValueError:
        return {}
    out = {}
    for name, f in fixed.items() if isinstance(fixed, dict) else ():
        last = final.get(name, {}) if isinstance(final, dict) else {}
        out[name] = {"reference": rec.get("reference", ""), "applied_samples": f.get("applied_samples"),
                     "offset_s": f.get("offset_s"), "uncertainty_s": f.get("uncertainty_s"), "method": f.get("method"),
                     "final_offset_s": last.get("offset_s"), "final_uncertainty_s": last.get("uncertainty_s"),
                     "moved": counts.get("timeline_moved", 0)}  # fmt: skip
    return out


def _from_record(rec: dict[str, Any]) -> dict[str, Any]:
    """A stream's entry from the writer's ``gvtlink.streams`` record (no data read)."""
    return {
        "blocks": int(rec["blocks"]), "samples": int(rec["samples"]),
        "first_index": int(rec["first_index"]) if rec["blocks"] else None,
        "end_index": int(rec["end_index"]) if rec["blocks"] else None,
        "gaps": [(int(a), int(b)) for a, b in rec["gaps"]], "segments": [(int(a), int(b)) for a, b in rec["segments"]],
        "undecodable_blocks": 0, "status_flags": int(rec["status_flags"]), "damaged": [],
    }  # fmt: skip


def _by_decoding(r: LogReader, name: str, info: StreamInfo) -> dict[str, Any]:
    """A stream's entry from its blocks, each chunk CRC-checked and each block checked (``block_problem``);
    damage is given as exact sample ranges, and left out of the gaps (which are the device's)."""
    firsts, counts, statuses, restarts, bad = [], [], 0, [], 0
    tracker = DamageRanges(info, {ch.id for ch in r.channels() if ch.topic == info.topic},
                           r.stream_records().get(name, {}).get("first_index"))  # fmt: skip
    for item in r.iter_blocks(name):
        if isinstance(item, Damage):
            bad += item.offset < 0
            tracker.damage(item)
            continue
        b = item[1]
        tracker.block(b.first_index, b.first_index + b.data.shape[0])
        firsts.append(b.first_index)
        counts.append(b.data.shape[0])
        statuses |= b.status
        if b.status & RESTART:
            restarts.append(b.first_index)
    # damage at the end reaches the stream's end, which the writer's sealed closing record says (when it is there)
    damaged = tracker.finish(r.stream_records().get(name, {}).get("end_index")) + r.recovered_damage(name)
    # a duplicated block is counted once; blocks that disagree about samples are damage (read_stream compares them)
    keep, dropped = kept_blocks(np.asarray(firsts, np.int64), np.asarray(counts, np.int64))
    if dropped:
        damaged = sorted(damaged + [d for d in r.read_stream(name, on_damage="skip").damaged if d[2] == OVERLAP])
    f, n = np.asarray(firsts, np.int64)[keep], np.asarray(counts, np.int64)[keep]
    holes = [(int(f[i] + n[i]), int(f[i + 1])) for i in range(len(f) - 1) if f[i + 1] > f[i] + n[i]]
    gaps = [g for g in holes if not any(a <= g[0] and g[1] <= b for a, b, _w in damaged)]
    cuts = [int(f[0]), *sorted(restarts)] if len(f) else []
    ends = [*cuts[1:], int(f[-1] + n[-1])] if len(f) else []
    return {
        "blocks": len(f), "samples": int(n.sum()), "first_index": int(f[0]) if len(f) else None,
        "end_index": int(f[-1] + n[-1]) if len(f) else None, "gaps": gaps,
        # a device restart starts a new segment (BlockStatus.RESTART); the gap before it is estimated
        "segments": list(zip(cuts, ends, strict=True)), "undecodable_blocks": bad, "status_flags": int(statuses),
        "damaged": [(a, b, why) for a, b, why in damaged],
    }  # fmt: skip


def _events_record(r: LogReader) -> tuple[list[dict[str, Any]], dict[str, int]] | None:
    """The writer's closing ``gvtlink.events`` record (events and counts by kind), or None: an older log, a
    damaged one, or an event storm the record kept only the counts of."""
    rec = r.metadata().get(layout.META_EVENTS)
    if not rec or rec.get("complete") != "1":
        return None
    try:
        events, counts = json.loads(rec["events"]), json.loads(rec["counts"])
    except (KeyError, ValueError):
        return None
    if not isinstance(events, list) or not isinstance(counts, dict):
        return None
    return [e for e in events if isinstance(e, dict)], {str(k): int(v) for k, v in counts.items()}


def _named_events(events: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Suspect channels, device restarts, silences, host stalls, a writer that fell behind and a confirmation worker
    that died, one line each (``gvt log info`` names them)."""
    out: dict[str, list[str]] = {}
    for e in events:
        kind = e.get("kind")
        if kind == "suspect_channel":
            out.setdefault("suspect channels", []).append(f"{e.get('channel', '?')}: {e.get('message', '')}".strip())
        elif kind == "restart":
            out.setdefault("device restarts", []).append(str(e.get("message") or e))
        elif kind == "silence":
            where = f"{e.get('stream', '?')} samples [{e.get('start_index', '?')}, {e.get('end_index', '?')})"
            out.setdefault("silences", []).append(f"{where}: {e.get('message', '')}".strip())
        elif kind == "host_stall":  # the recording process did not run (daq/recorder.py StallWatch)
            out.setdefault("host stalls", []).append(str(e.get("message") or e))
        elif kind == "writer_backlog":  # how far the writer fell behind: what a crash then would have lost (D67)
            out.setdefault("log writer", []).append(str(e.get("message") or e))
        elif kind in ("confirm_restarted", "confirm_off", "confirm_abandoned"):  # D68
            out.setdefault("confirmation worker", []).append(str(e.get("message") or e))
    return out


def _health(rep: SalvageReport, r: LogReader, damaged: dict[str, list], checked: str) -> str:
    """One line. It claims no more than was checked: "ok (summary)" has read no chunk."""
    if r.damage:
        where = "; ".join(f"{s} samples " + ", ".join(f"[{a}, {b})" for a, b, _w in rs) for s, rs in damaged.items())
        first = next(iter(r.damage.values()))
        return (f"damaged: {len(r.damage)} chunk(s) or block(s) fail their checks (first: {first.reason})"
                + (f"; lost: {where}" if where else "") + " — run `gvt log recover`")  # fmt: skip
    if damaged:  # no chunk or block failed, but two blocks disagree about samples
        where = "; ".join(f"{s} samples " + ", ".join(f"[{a}, {b})" for a, b, _w in rs) for s, rs in damaged.items())
        return f"damaged: {where}: {next(iter(damaged.values()))[0][2]}"
    if r.problems:
        return f"damaged: {r.problems[0]}" + (f" (and {len(r.problems) - 1} more)" if len(r.problems) > 1 else "") + (
            "; the samples are intact — `gvt log recover` rewrites the rest" if rep.complete else " — run `gvt log recover`"
        )
    if rep.complete:
        if checked == "verify":
            return "ok: every chunk's CRC and every sample block checked (--verify)"
        if checked == "decoded":
            return "ok: footer and summary intact; every chunk read was CRC-checked"
        return "ok (summary; --verify checks every chunk)"
    why = f" ({rep.stopped_because or rep.summary_problem})" if rep.stopped_because or rep.summary_problem else ""
    lost = "data section read to its end; " if rep.stopped_because is None else ""
    return (
        f"damaged{why}: {lost}salvaged {rep.messages} messages from {rep.chunks_ok} complete chunks"
        + (f", {rep.chunks_bad} corrupt chunks skipped" if rep.chunks_bad else "")
        + f"; read {rep.bytes_scanned} of {rep.file_size} bytes — run `gvt log recover`"
    )


def recover(src: str | Path, dst: str | Path, chunk_size: int = 1 << 20) -> SalvageReport:
    """Rewrite every readable record of ``src`` into a new indexed file ``dst`` (``chunk_size``: uncompressed
    bytes per output chunk). Every chunk is verified; a damaged one is skipped (``data_lost``), a duplicated
    message kept once. Reads and writes a chunk at a time: memory does not grow with the log."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise LogReadError(f"{dst}: output must differ from the input")
    r = LogReader(src)
    schemas = r.schemas()
    from daq.outputs import atomic_output

    seen: set[tuple[int, int, int, int]] = set()
    sequences: dict[int, set[int]] = {}  # per channel: the writer numbers each channel's messages 0, 1, 2, ...
    with atomic_output(dst, "DST") as tmp, open(tmp, "wb") as f:  # a disk that fills: one line, no .part left
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        w.start(profile=layout.PROFILE, library="gvtlink recover")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for sid, s in schemas.items():
            schema_ids[sid] = w.register_schema(s.name, s.encoding, s.data)
        for name, (media, data) in r.attachments().items():
            w.add_attachment(create_time=0, log_time=0, name=name, media_type=media, data=data)
        for ch, msg in r.iter_messages(salvage=True):
            key = (ch.id, msg.sequence, msg.log_time, hash(msg.data))
            if key in seen:  # a chunk the index lists twice: its messages once
                r.report.duplicates += 1
                continue
            seen.add(key)
            sequences.setdefault(ch.id, set()).add(msg.sequence)
            if ch.id not in channel_ids:
                channel_ids[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, schema_ids.get(ch.schema_id, 0), dict(ch.metadata)
                )
            w.add_message(
                channel_ids[ch.id], log_time=msg.log_time, data=msg.data, publish_time=msg.publish_time, sequence=msg.sequence
            )
        r.report.missing_by_sequence = sum(max(s) + 1 - len(s) for s in sequences.values())
        r.report.messages = len(seen)  # what the new file holds
        lost = _lost_ranges(r) if r.report.data_lost else {}
        for name, data in r.metadata().items():  # after the data: the writer's per-stream record only if it holds
            if name == layout.META_RECOVERED and lost:
                continue  # replaced below (it holds these ranges too)
            if name != layout.META_STREAMS or not (r.report.data_lost or r.report.duplicates):
                w.add_metadata(name, data)
        if lost:  # the samples' place: without the streams record a damaged first chunk left no trace
            w.add_metadata(layout.META_RECOVERED, seal(layout.META_RECOVERED, {s: json.dumps(v) for s, v in lost.items()}))
        w.finish()
    return r.report


def _lost_ranges(r: LogReader) -> dict[str, list[list[Any]]]:
    """Per stream, the sample ranges of ``r`` that damage took (those it had lost before a recover included), as
    ``gvt log info --verify`` finds them, each reason saying it was the original's; a second pass over the blocks,
    paid only when data was lost. Overlapping blocks are not among them: recover copies both, its file says so."""
    out = {}
    for name, info in r.streams().items():
        try:
            ranges = _by_decoding(r, name, info)["damaged"]
        except LogReadError:
            continue
        ranges = [[a, b, why if why.startswith(_LOST) else f"{_LOST} ({why})"] for a, b, why in ranges if why != OVERLAP]
        if ranges:
            out[name] = ranges
    return out


#: the reason a recovered file gives for samples its original had lost
_LOST = "lost before `gvt log recover` rewrote the log"


def info_text(info: dict[str, Any]) -> str:
    lines = [f"{info['file']}  {info['size_bytes']} bytes  health: {info['health']}"]
    for s in info["streams"]:
        lines.append(
            f"  stream {s['stream']}: {len(s['channels'])} ch @ {s['sample_rate']:g} Hz, {s['samples']} samples "
            f"({s['duration_s']:.3f} s) in {s['blocks']} blocks, gaps: {len(s['gaps'])} ({s['missing_samples']} samples)"
            + (f", {s['undecodable_blocks']} undecodable blocks" if s["undecodable_blocks"] else "")
            + (f", NOT RECORDED (writer overrun): {s['overrun_samples']} samples" if s["overrun_samples"] else "")
        )
        if s.get("damaged"):
            lines.append("    DAMAGED: " + "; ".join(f"samples [{a}, {b}): {why}" for a, b, why in s["damaged"]))
        if len(s.get("segments", ())) > 1:
            segs = ", ".join(f"[{a}, {b})" for a, b in s["segments"])
            lines.append(f"    segments (the device restarted; each gap before a segment is estimated): {segs}")
        lines.append(f"    channels: {', '.join(f'{c} [{u}]' for c, u in zip(s['channels'], s['units'], strict=False))}")
    for name, t in info.get("timeline", {}).items():
        lines.append("  " + _timeline_text(name, t))
    ev = ", ".join(f"{k}: {v}" for k, v in sorted(info["events"].items())) or "none"
    lines.append(f"  hits: {info['hits']}  events: {ev}")
    for what, items in info.get("named_events", {}).items():
        lines.append(f"  {what}: " + "; ".join(items[:10]) + (f"; … {len(items) - 10} more" if len(items) > 10 else ""))
    lines.append(f"  topics: {', '.join(info['topics'])}")
    lines.append(f"  metadata: {', '.join(info['metadata']) or 'none'}  attachments: {', '.join(info['attachments']) or 'none'}")
    for p in info.get("problems", []):
        lines.append(f"  problem: {p}")
    return "\n".join(lines)


def _timeline_text(name: str, t: dict[str, Any]) -> str:
    def ms(v: Any) -> str:
        return f"± {float(v) * 1e3:.3f} ms" if isinstance(v, (int, float)) else "± ?"

    def sec(v: Any) -> str:
        return f"{float(v):.5f} s" if isinstance(v, (int, float)) else "?"

    line = (f"timeline: {name} placed {t.get('applied_samples')} samples after {t.get('reference')} ({sec(t.get('offset_s'))} "
            f"{ms(t.get('uncertainty_s'))}, {t.get('method')}); final estimate {sec(t.get('final_offset_s'))} "
            f"{ms(t.get('final_uncertainty_s'))}")
    return line + (f"; MOVED {t['moved']}x" if t.get("moved") else "")


def info_json(info: dict[str, Any]) -> str:
    return json.dumps(info, indent=2)
