"""An import record (:mod:`daq.studies.importing.data`) as a format-2 gvtlink log, so every verb works on it.

Time histories: one sample stream ``import`` with the channel table (name, quantity, SI unit, position), its
blocks as a recording writes them (``drivers/blocks.py`` SampleBlock, float32 in SI), and the hits the recorder's
own trigger and gate find on the force channel (``daq/hits.py`` HitDetector, as ``daq/lanes/hits.py`` runs it) on
``/daq/hits``. FRFs: the set as the attachment ``frf/matrix.npz`` (``analysis.frf.FRFSet.to_npz``, the name the
roving-hammer FRF lane uses, ``daq/lanes/frf.py``), which ``gvt modal LOG`` and ``gvt model update --from LOG``
take. Both: the provenance (source path, sha256, format, the writing tool, every assumption) in the metadata
record ``gvtlink.import``, the geometry as ``import/geometry.json`` when the file had one.

All or nothing: the log is written to a temporary name beside ``out`` and renamed at the end
(``daq/outputs.py`` atomic_output); an existing ``out`` is refused unless ``overwrite``.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from analysis.model.channels import Channel
from daq.log.writer import ChannelInfo, LogWriter
from daq.studies.importing.data import FrfImport, ImportError_, TimeImport

META_IMPORT = "gvtlink.import"
MATRIX_ATTACHMENT = "frf/matrix.npz"  # daq/lanes/frf.py MATRIX_ATTACHMENT (not imported: a lane is the service's)
GEOMETRY_ATTACHMENT = "import/geometry.json"
MODES_ATTACHMENT = "import/modes.json"  # the file's mode shapes (UFF 55), as gvt modal --modes-out writes them
STREAM = "import"
BLOCK = 4096  # samples per block: a recording's order of size (drivers write 256 .. 8192)
#: Trigger level as a share of the largest force in the record when nothing says otherwise: a hammer test's hits are
#: within 20 dB of each other; 5 % of the largest stays above noise and below the smallest hit.
TRIGGER_SHARE = 0.05


def write_log(data: TimeImport | FrfImport, out: Path, *, overwrite: bool = False) -> dict:
    """Write ``data`` to the log ``out`` atomically; returns the summary ``gvt import`` prints."""
    from daq.outputs import atomic_output

    out = Path(out)
    if out.exists() and not overwrite:
        raise ImportError_(f"{out} exists; give --overwrite to replace it, or another name")
    if out.exists() and Path(data.provenance.path).resolve() == out.resolve():
        raise ImportError_(f"{out}: the output is the file being imported; choose another name")
    with atomic_output(out) as tmp:
        with LogWriter(tmp) as w:
            summary = _write_time(w, data) if isinstance(data, TimeImport) else _write_frf(w, data)
            _write_provenance(w, data, summary)
    return summary


def _infos(channels: list[Channel]) -> list[ChannelInfo]:
    return [ChannelInfo(c.name, c.quantity, c.unit, c.sensitivity_mv_per_unit, position_m=c.xyz[0]) for c in channels]


def _write_provenance(w: LogWriter, data: TimeImport | FrfImport, summary: dict) -> None:
    p = data.provenance
    w.add_metadata(META_IMPORT, {
        "source": p.path, "sha256": p.sha256, "format": p.format, "writer": p.writer, "tool": "gvt import",
        "assumptions": json.dumps(list(p.assumptions)), "summary": json.dumps(summary, default=float),
        "channels": json.dumps([{"name": c.name, "quantity": c.quantity, "unit": c.unit, "node": c.node,
                                 "xyz": list(c.xyz), "direction": c.direction} for c in data.channels]),
    })  # fmt: skip
    if data.modes:
        m = data.modes
        doc = {"source": p.path, "freq_hz": m["freq_hz"], "zeta": m["zeta"], "outputs": m["outputs"],
               "shapes_re": np.real(m["shapes"]).tolist()}  # fmt: skip
        if np.iscomplexobj(m["shapes"]):
            doc["shapes_im"] = np.imag(m["shapes"]).tolist()
        w.add_attachment(MODES_ATTACHMENT, json.dumps(doc).encode(), "application/json")
    if data.geometry is not None:
        g = data.geometry
        doc = {"nodes": [[int(i), *map(float, x)] for i, x in zip(g.ids, g.xyz, strict=True)],
               "lines": np.asarray(g.lines, dtype=int).tolist()}  # fmt: skip
        w.add_attachment(GEOMETRY_ATTACHMENT, json.dumps(doc).encode(), "application/json")


def _write_frf(w: LogWriter, data: FrfImport) -> dict:
    buf = io.BytesIO()
    f = data.frf
    np.savez(buf, freq=f.freq, H=f.H, coherence=f.coherence, n_averages=np.asarray(f.n_averages, dtype=int),
             meta=np.array(json.dumps({"outputs": list(f.outputs), "references": list(f.references), "kind": f.kind,
                                       "quantity": f.quantity, "units": f.units, "window": f.window,
                                       "quality": f.quality})))  # fmt: skip
    w.add_attachment(MATRIX_ATTACHMENT, buf.getvalue(), "application/x-npz")
    return {"kind": "frf", "outputs": list(f.outputs), "references": list(f.references), "lines": int(f.freq.size),
            "band_hz": [float(f.freq[0]), float(f.freq[-1])], "form": f.quantity, "units": f.units,
            "coherence": data.coherence_known}  # fmt: skip


def _write_time(w: LogWriter, data: TimeImport) -> dict:
    from drivers.blocks import SampleBlock

    names = tuple(c.name for c in data.channels)
    w.add_stream(STREAM, _infos(data.channels), data.fs, offset_ns=round(data.t0_s * 1e9))
    x = data.samples  # a channel-major table's transpose from tdms.py/hdf5.py: made float32 rows a block at a time
    detector, level = _detector(data)
    hits = []
    for a in range(0, x.shape[0], BLOCK):
        block = SampleBlock(STREAM, a, data.fs, names, np.ascontiguousarray(x[a : a + BLOCK], dtype=np.float32))
        w.write_block(block, wait=True)
        hits += detector.feed(block) if detector is not None else []
    hits += detector.finish() if detector is not None else []
    for h in hits:
        w.write_hit(h.summary(), log_time_ns=round((data.t0_s + h.index / data.fs) * 1e9))
    note = polarity_note(data)
    return {"kind": "time", "channels": list(names), "units": [c.unit for c in data.channels], "samples": int(x.shape[0]),
            "fs_hz": data.fs, "duration_s": x.shape[0] / data.fs, "hits": len(hits),
            "accepted": sum(h.verdict == "accepted" for h in hits), "trigger_N": level,
            "record_s": detector.s.record_length if detector is not None else None,
            "warnings": [note] if note else []}  # fmt: skip


def polarity_note(data: TimeImport) -> str | None:
    """One line when the force channel swings mostly negative: the gate triggers on positive force (a hammer pushes),
    so an inverted channel (a negative sensitivity, swapped wires, a DAQ that records compression as negative)
    gives no hits or hits on its rebound ripple, and the import would say only "0 hit(s)"."""
    force = next((k for k, c in enumerate(data.channels) if c.quantity == "force"), None)
    if force is None or not data.samples.size:
        return None
    lo, hi = float(np.min(data.samples[:, force])), float(np.max(data.samples[:, force]))
    hi = hi if hi > 0 else 0.0
    if not -lo > 2.0 * hi:
        return None
    name = data.channels[force].name
    return (f"force channel {name} swings to {lo:.4g} N but only to {hi:.4g} N: an inverted hammer? hits are "
            f"found on positive force, so its hits and FRFs are missing or wrong; flip {name}'s sign in the source "
            "and import again")


def _detector(data: TimeImport):
    """The recorder's hit gate on the first force channel, its level :data:`TRIGGER_SHARE` of the largest force."""
    from daq.hits import HitDetector, TriggerSettings

    force = next((k for k, c in enumerate(data.channels) if c.quantity == "force"), None)
    if force is None:
        return None, None
    peak = float(np.max(data.samples[:, force])) if data.samples.size else 0.0
    if not peak > 0:
        return None, None
    level = TRIGGER_SHARE * peak
    record = record_length(data.samples[:, force], level, data.fs)
    settings = TriggerSettings(level=level, channel=data.channels[force].name, record_length=record)
    return HitDetector(settings, tuple(c.name for c in data.channels), data.fs), level


#: Edges closer than this belong to one hit: a hammer does not strike twice within 20 ms (a rebound's double hit is
#: within a few ms and is the hit checks' finding, not a hit of its own). Without it, the ringing of a band-limited
#: pulse (pyFRF's measured hits cut at 6.4 kHz) crossed the level again and again: 7 "hits" 2 samples apart with
#: records of 0.16 ms, all accepted.
HOLDOFF_S = 0.02


def record_length(force: np.ndarray, level: float, fs: float, longest: float = 1.0, pre: float = 0.01) -> float:
    """Seconds the gate keeps after each edge: ``longest`` (the gate's default), shortened so that no record holds
    the next hit's pre-trigger and the last one ends with the data -- an exported file keeps each hit's record and
    no more (gvtlink's own UFF export: 10 ms before the edge to the next hit's pre-trigger). Edges within
    :data:`HOLDOFF_S` of a kept one are the same hit."""
    above = force >= level
    edges = np.flatnonzero(above[1:] & ~above[:-1]) + 1
    low = force < 0.5 * level  # the gate re-arms below half the level (TriggerSettings.hysteresis)
    hold = round(HOLDOFF_S * fs)
    kept: list[int] = []
    armed_from = 0
    for e in edges:
        if e >= armed_from and (not kept or e - kept[-1] >= hold):
            kept.append(int(e))
            later = np.flatnonzero(low[e:])
            armed_from = e + (int(later[0]) if later.size else force.size)
    ends = [b - round(pre * fs) for b in kept[1:]] + [force.size]
    room = min(b - a for a, b in zip(kept, ends, strict=True)) / fs if kept else longest
    return float(max(min(longest, room - 1.0 / fs), 1.0 / fs))


__all__ = ["GEOMETRY_ATTACHMENT", "MATRIX_ATTACHMENT", "META_IMPORT", "MODES_ATTACHMENT", "STREAM", "write_log"]
