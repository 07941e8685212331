"""``gvt identify LOG --rig RIG``: the seed's experimental-style NSI (Ch. 5 §5.3.4–5.3.5) from a session's recorded hits.

Per accepted hit of ``/daq/hits`` the record of the rig's sensors is read from ``PRE_TRIGGER_S`` before the pulse
for the rig's record length (shortened to the next hit's), one hit at a time (memory: one record), on one DAQ or
two (the sensors on the hammer's sample grid through the session's time base, as ``gvt frf`` reads them); each is
turned into displacement, cut into windows and reduced to one (δ̄, f) pair per window
(``analysis.nsi_windows``). All windows then go through the sweep path's RQ-FDP and fit
(``daq.studies.identify.sweep.identify_runs``), so the tables, JSON and PNG are the sweep's; the per-window table is
written as CSV (default ``LOG.nsi-windows.csv`` beside the log; never over an existing file without
``--overwrite``).
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis import nsi_windows as nw
from analysis.errors import BadInput
from analysis.model.rig import Rig
from analysis.nsi_target import resolve_target
from analysis.records import HITS_TOPIC, Hit
from daq.studies.identify.sweep import Identification, IdentifyOptions, identify_runs
from daq.studies.nsi_table import NsiRuns

#: Record read before each hit's index: the pulse's rising edge precedes a real trigger (``gvt frf``'s 0.01 s).
PRE_TRIGGER_S = 0.01
WINDOW_COLUMNS = ("hit", "peak_force_N", "t_start_s", "t_stop_s", "dbar_m", "f_rq_hz", "f_pom_hz", "mac", "capture",
                  "pom_index")  # fmt: skip
#: Record read on each side of a hit's record for the integration chain, in periods of its high-pass corner: the
#: zero-phase filters' start-up and end effects then fall outside the record (a 1 s hit record is shorter than
#: the 0.9 Hz 3rd-order Butterworth's settling; the seed's records were 8 s for a 2 Hz corner, L1664). The
#: integration is linear, so the neighbouring hits inside the span do no harm.
INTEGRATION_PAD_PERIODS = 2.0
QUANTITY_OF_UNIT = {"m/s^2": "acceleration", "m/s": "velocity", "m": "displacement"}


def windows_csv_path(log: Path) -> Path:
    """The per-window table's default place: beside the log, ``<log name>.nsi-windows.csv``."""
    return log.with_name(log.name + ".nsi-windows.csv")


@dataclass
class LogIdentification:
    """What ``gvt identify LOG`` found: the sweep-path identification of all windows, and how they were made."""

    ident: Identification
    settings: nw.WindowSettings
    window_hit: np.ndarray  # (k,) hit number of each window
    window_t: np.ndarray  # (k, 2) window start/stop, s from the hit's pulse start
    hits: list[dict] = field(default_factory=list)  # per hit: hit, peak force, windows, or why it was skipped
    channels: tuple[str, ...] = ()
    streams: dict[str, int] = field(default_factory=dict)
    elapsed_s: float = 0.0

    def summary(self) -> dict[str, Any]:
        s = self.ident.summary()
        s.update({
            "source_kind": "session log (windowed dbar, seed Ch. 5)",
            "windows": int(self.window_hit.size),
            "capture_windows": int(self.ident.runs.capture.sum()),
            "window_settings": self.settings.to_dict(),
            "channels": list(self.channels),
            "streams": self.streams,
            "hits": self.hits,
            "elapsed_s": self.elapsed_s,
        })  # fmt: skip
        return s


def _read_span(reader, sources: list, cols: list[str], lo: int, hi: int, need: int, n: int, fs: float):
    """``cols`` over as much of ``[lo, hi)`` of the hits' grid as every stream holds without a gap, each stream read
    on its own clock (``daq.studies.frf._read_record`` reads exactly a record); None unless that covers the record
    ``[need, need + n)``. Returns (samples, first index)."""
    a, b, got = lo, hi, []
    for src in sources:
        d = reader.read_stream(src.stream, list(src.channels), start=max(lo - src.offset, 0) / fs, end=(hi - src.offset) / fs,
                               on_damage="skip")  # fmt: skip
        if d.index.size == 0:
            return None
        idx = d.index.astype(np.int64) + src.offset
        breaks = np.flatnonzero(np.diff(idx) != 1)
        seg = np.split(np.arange(idx.size), breaks + 1)  # contiguous runs; keep the one holding the record
        run = next((r for r in seg if idx[r[0]] <= need and idx[r[-1]] >= need + n - 1), None)
        if run is None:
            return None
        a, b = max(a, int(idx[run[0]])), min(b, int(idx[run[-1]]) + 1)
        got.append((src, int(idx[run[0]]), d.data[run]))
    parts = {c: data[a - first : b - first, src.channels.index(c)] for src, first, data in got for c in src.channels}
    return np.stack([parts[c] for c in cols], axis=1).astype(float), a


def _layout(reader, rig: Rig) -> tuple[list, list[str], list[int], tuple[str, ...]]:
    """The rig's sensors found in the log on the hammer's sample grid (``daq.studies.frf.layout``), one per model DOF,
    with their model DOFs and quantities."""
    from daq.studies.frf import layout

    infos = reader.streams()
    in_log = {c for i in infos.values() for c in i.channels}
    seen: set[int] = set()
    names: list[str] = []
    for s in rig.sensors:
        if s.name in in_log and s.dof not in seen:
            seen.add(s.dof)
            names.append(s.name)
    if len(names) < 2:
        raise BadInput(f"{reader.path}: {len(names)} of the rig {rig.name!r}'s sensors are in the log; the POD needs >= 2")
    sources, outs, units = layout(reader, rig.hammer.name, names)
    quantity = []
    for c in outs:
        q = QUANTITY_OF_UNIT.get(units[c])
        if q is None:
            raise BadInput(
                f"{reader.path}: channel {c!r} is in {units[c]!r}; the NSI needs acceleration, velocity or displacement"
            )
        quantity.append(q)
    by_name = {s.name: s.dof for s in rig.sensors}
    return sources, outs, [by_name[c] for c in outs], tuple(quantity)


def _window_settings(rig: Rig, g, dofs, model, window_s: float | None) -> nw.WindowSettings:
    """:func:`analysis.nsi_windows.default_settings` of the rig's linear modes at the sensors; ``window_s`` overrides the
    window length, and with it the start drop and the tail."""
    import scipy.linalg

    k = min(model.mode + 2, len(dofs))
    f_lin = np.sqrt(np.maximum(scipy.linalg.eigh(g.K, g.M, eigvals_only=True, subset_by_index=[0, k - 1]), 0.0)) / (2 * np.pi)
    spec = rig.config.nsi
    settings = nw.default_settings(f_lin, model.mode, rig.config.hammer.pulse_duration,
                                   spec.delta_highpass_hz if spec is not None else None)  # fmt: skip
    if window_s is not None:
        settings = nw.WindowSettings(window_s, rig.config.hammer.pulse_duration + window_s, window_s,
                                     settings.integration_corner_hz, settings.delta_corner_hz)  # fmt: skip
    return settings


def _hit_windows(h: Hit, n: int, read: Callable[[], Any], ctx: dict) -> tuple[dict[str, Any], list[tuple]]:
    """One hit: its report row and its windows' table rows (none if skipped; the reason in the row). ``read`` gives the
    hit's padded span ``(data, first)`` or None."""
    row: dict[str, Any] = {"hit": h.hit, "peak_force_N": h.peak_force_N}
    left_out = set(ctx["outs"]) & set(h.excluded_channels or ())
    if h.verdict != "accepted":
        row["skipped"] = f"hit gate: {h.reason or h.verdict}"
        return row, []
    if left_out:
        row["skipped"] = f"channel(s) {sorted(left_out)} left out of this hit by the gate"
        return row, []
    data = read()
    if data is None:
        row["skipped"] = f"record incomplete: not all {n} samples of every stream (end of log, gap or damage)"
        return row, []
    data, first = data
    fs, pre, settings, target, g = ctx["fs"], ctx["pre"], ctx["settings"], ctx["target"], ctx["g"]
    at = h.index - pre - first  # the hit's record [at, at + n) within the padded span
    r0, r1 = nw.hit_region(n, fs, pre, settings)
    disp = nw.to_displacement(data, fs, ctx["quantity"], settings)
    w = nw.analyse_hit(disp, fs, (r0 + at, r1 + at), target.attachment, target.relative_to, target.model.shape, g.M, g.K,
                       settings, (at, at + n))  # fmt: skip
    b = w.bounds - at
    if b.shape[0] == 0:
        row["skipped"] = f"record of {n / fs:.3g} s holds no window after the start drop and the tail"
        return row, []
    e = h.input_energy_J if h.input_energy_J is not None else np.nan
    rows = [(h.hit, h.peak_force_N, e, (b[i, 0] - pre) / fs, (b[i, 1] - pre) / fs, w.dbar[i], w.f_rq[i], w.f_pom[i],
             w.mac[i], w.capture[i], w.pom_index[i]) for i in range(b.shape[0])]  # fmt: skip
    row["windows"] = int(b.shape[0])
    row["capture_windows"] = int(w.capture.sum())
    return row, rows


def identify_log(
    rig: Rig,
    path: Path,
    options: IdentifyOptions,
    settings: nw.WindowSettings | None = None,
    window_s: float | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> LogIdentification:
    """Windowed NSI of every accepted hit of the log at ``path`` (module docstring). ``settings`` default to
    :func:`analysis.nsi_windows.default_settings` of the rig's linear modes at the sensors (``window_s``
    overriding the window length, and with it the start drop and tail)."""
    from daq.log.reader import LogReader, LogReadError

    t0 = time.perf_counter()
    options.validate()
    try:
        reader = LogReader(path)
        infos = reader.streams()
    except LogReadError as exc:
        raise BadInput(str(exc)) from None
    sources, outs, dofs, quantity = _layout(reader, rig)
    fs = infos[sources[0].stream].sample_rate
    g = rig.guyan(dofs)
    target = resolve_target(rig, dofs, g.M, g.K)
    settings = settings if settings is not None else _window_settings(rig, g, dofs, target.model, window_s)
    settings.validate(fs)
    hits = sorted((Hit.from_json(h) for h in reader.json_messages(HITS_TOPIC)), key=lambda h: h.index)
    if not hits:
        raise BadInput(f"{path}: the log has no hits ({HITS_TOPIC}); record or simulate a session with hits")
    pre, n_rec = round(PRE_TRIGGER_S * fs), round(rig.config.daq.record_length * fs)
    fc = settings.integration_corner_hz
    pad = round(INTEGRATION_PAD_PERIODS / fc * fs) if fc else 0
    ctx = {"outs": outs, "fs": fs, "pre": pre, "settings": settings, "target": target, "g": g, "quantity": quantity}
    rows: list[tuple] = []
    report: list[dict] = []
    for k, h in enumerate(hits):
        n = n_rec + pre if k + 1 == len(hits) else min(n_rec + pre, hits[k + 1].index - h.index)
        i0 = h.index - pre

        def read(i0: int = i0, n: int = n):  # only for a hit that is analysed
            return _read_span(reader, sources, outs, i0 - pad, i0 + n + pad, i0, n, fs)

        row, got = _hit_windows(h, n, read, ctx)
        rows += got
        report.append(row)
        if progress:
            progress("windowed NSI of the hits", (k + 1) / len(hits))
    if not rows:
        why = "; ".join(f"hit {r['hit']}: {r['skipped']}" for r in report[:3])
        raise BadInput(f"{path}: no hit gave a window ({why})")
    a = np.array([r[:9] for r in rows], float)
    runs = NsiRuns(a[:, 1], a[:, 2], a[:, 5], a[:, 6], a[:, 7], a[:, 8], np.array([r[9] for r in rows], bool),
                   np.array([r[10] for r in rows], np.int64), time.perf_counter() - t0)  # fmt: skip
    n_acc = sum(1 for r in report if "windows" in r)
    ident = identify_runs(rig, target, runs, options, f"{path}: {runs.P.size} windows of {n_acc} hits")
    return LogIdentification(ident, settings, a[:, 0].astype(np.int64), a[:, 3:5], report, tuple(outs),
                             {s.stream: s.offset for s in sources}, time.perf_counter() - t0)  # fmt: skip


def write_windows(run: LogIdentification, path: Path) -> None:
    """The per-window table (:data:`WINDOW_COLUMNS`), written atomically (``daq.outputs.atomic_output``)."""
    from daq.outputs import atomic_output

    r = run.ident.runs
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(WINDOW_COLUMNS)
        for k in range(r.P.size):
            w.writerow([int(run.window_hit[k]), f"{r.P[k]:.9g}", f"{run.window_t[k, 0]:.6f}", f"{run.window_t[k, 1]:.6f}",
                        f"{r.dbar[k]:.9g}", f"{r.f_rq[k]:.9g}", f"{r.f_pom[k]:.9g}", f"{r.mac[k]:.6f}", int(r.capture[k]),
                        int(r.pom_index[k])])  # fmt: skip


__all__ = ["WINDOW_COLUMNS", "LogIdentification", "identify_log", "windows_csv_path", "write_windows"]
