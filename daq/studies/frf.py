"""``gvt frf LOG``: FRFs and coherence of a session's hits, each hit checked first (analysis/frf.py, hammer.py).

Per hit of ``/daq/hits``: the record ``[index - pre, index - pre + n)`` of the reference (force) channel
and the responses is read (``LogReader.read_stream``); the hit is refused if the log's gate refused it
(its reason is kept), if the record runs past the log, or by the hammer checks (overload, double hit,
bandwidth below the band: :func:`analysis.hammer.check_hit`); accepted hits are averaged linearly into an
:class:`~analysis.frf.FRFAccumulator`.

Record and window (docs/frf.md): ``n`` is the rig's record length, shortened to the smallest spacing
between hits so no record holds the next hit; the exponential response window's ``tau`` makes the rig's
lowest mode decay to ``end_level`` (1e-3, −60 dB) by the record's end (:func:`analysis.frf.choose_tau`),
or no window if the structure does that alone. Its added decay rate ``1 / tau`` goes with the result.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFAccumulator, FRFSet, choose_tau, stack_references
from analysis.frf_setup import PRE_TRIGGER_S, default_band, force_full_scale, lowest_decay_rate
from analysis.hammer import HammerCheck, check_hit
from analysis.model.rig import Rig
from analysis.records import HITS_TOPIC, PLAN_TOPIC, Hit, PlanRecord
from daq.log.reader import LogReader, LogReadError
from daq.studies.frf_judge import Levels, damage_error, judge, linearity, merged, pick_levels

QUANTITY_OF_UNIT = {"m/s^2": "acceleration", "m/s": "velocity", "m": "displacement", "N": "force"}


@dataclass
class FRFRun:
    """What ``gvt frf`` computed: the FRFs, every hit's verdict and the record/window choices.

    ``frf`` has one reference per hit point of a roving-hammer plan (named by the point), else the force
    channel; ``points`` the plan's points with their accepted averages; ``driving`` reference -> the response
    at its DOF (for mass-normalised shapes)."""

    log: str
    rig: str
    stream: str
    frf: FRFSet | None
    record_s: float
    pre_s: float
    tau_s: float | None
    band_hz: float
    hits: list[dict] = field(default_factory=list)  # hit, t_s, verdict, reason, checks (and point)
    spectra: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)  # (hit, freq, |F|) for the plot
    points: list[dict] = field(default_factory=list)
    driving: dict[str, str] = field(default_factory=dict)
    streams: dict[str, int] = field(default_factory=dict)  # stream -> offset on the hit's grid (samples)


@dataclass(frozen=True)
class Source:
    """Some channels of one stream and where its samples lie on the hits' grid: own index = hit index - offset."""

    stream: str
    channels: tuple[str, ...]
    offset: int


def _stream_for(reader: LogReader, reference: str) -> str:
    for name, info in reader.streams().items():
        if reference in info.channels:
            return name
    raise BadInput(f"{reader.path}: no stream has the reference channel {reference!r}; give it with --reference")


def layout(reader: LogReader, ref: str, channels: Sequence[str] | None) -> tuple[list[Source], list[str], dict[str, str]]:
    """Where the reference and the responses are: the reference's stream first, then every stream at its sample
    rate (a second DAQ on the session's timeline: docs/session.md), each with its offset from the log's time base;
    the responses (given, or every channel not in N); their units."""
    from daq.log.export import time_base

    infos = reader.streams()
    ref_stream = _stream_for(reader, ref)
    fs = infos[ref_stream].sample_rate
    names = [ref_stream, *sorted(s for s in infos if s != ref_stream and infos[s].sample_rate == fs)]
    units = {c: u for s in names for c, u in zip(infos[s].channels, infos[s].units, strict=True)}
    if channels:
        other = {c: s for s in infos for c in infos[s].channels if s not in names}
        bad = [c for c in channels if c not in units]
        if bad:
            why = "; ".join(f"{c} is in {other[c]} at another rate" for c in bad if c in other) or f"channels: {list(units)}"
            raise BadInput(f"{reader.path}: no response channel(s) {bad} on the reference's sample grid ({why})")
        outs = list(channels)
    else:
        outs = [c for c, u in units.items() if u != "N" and c != ref]
    if not outs:
        raise BadInput(f"{reader.path}: no channel to respond besides {ref!r} in {', '.join(names)}; give --channels")
    tb = time_base(reader)
    base = tb.offset_samples.get(tb.reference, 0)
    sources = []
    for s in names:
        chans = tuple(c for c in ([ref] if s == ref_stream else []) + outs if c in infos[s].channels)
        if chans:
            sources.append(Source(s, chans, tb.offset_samples.get(s, 0) - base))
    return sources, outs, units


def plan_of_hits(reader: LogReader, hits: Sequence[Hit]) -> tuple[list[dict], dict[int, str]]:
    """A roving-hammer log's points (the ``plan`` record of ``/daq/plan``) and the point each hit was made at:
    the FRF lane's ``progress`` record for that hit (what the operator was told), else the point a
    :class:`~daq.roving.PlanTracker` fed the gate's verdicts in order was at (a log recorded with --no-frf).
    No plan: ``([], {})``."""
    recs = [PlanRecord.from_json(m) for m in reader.json_messages(PLAN_TOPIC)]
    plan = next((r for r in recs if r.event == "plan" and r.points), None)
    if plan is None:
        return [], {}
    points = [dict(p) for p in plan.points or ()]
    told = {r.hit: r.point for r in recs if r.event in ("progress", "complete") and r.hit is not None and r.point}
    return points, assign_points(points, hits, told)


def assign_points(points: Sequence[dict], hits: Sequence[Hit], told: dict[int, str]) -> dict[int, str]:
    """Hit number -> hit point: ``told`` where the log says, else where the operator was then (the plan's order,
    each point until its accepted averages are in, counting the gate's accepted hits)."""
    names = [p["name"] for p in points]
    done, at = [0] * len(points), {}
    for h in hits:
        k = next((i for i in range(len(points)) if done[i] < points[i]["averages"]), len(points) - 1)
        at[h.hit] = told.get(h.hit, names[k])
        if h.verdict == "accepted" and at[h.hit] in names:
            done[names.index(at[h.hit])] += 1
    return at


def _record_samples(rig: Rig, hits: Sequence[Hit], fs: float) -> int:
    n = round(rig.config.daq.record_length * fs)
    gaps = np.diff(sorted(h.index for h in hits))
    return int(min(n, gaps.min())) if gaps.size else n


def frf_from_log(path: str | Path, rig: Rig, *, reference: str | None = None, channels: Sequence[str] | None = None,
                 band_hz: float | None = None, kind: str = "H1", quantity: str = "accelerance", end_level: float = 1e-3,
                 level: str | int | None = None, n_peaks: int = 6,
                 progress: Callable[[float], None] | None = None) -> FRFRun:  # fmt: skip
    """FRFs of the accepted hits of the log at ``path``: the force channel against every response, on one DAQ
    or two (the responses read on the hits' grid through the time base), one reference per hit point of a
    roving-hammer plan; averaged within one force ``level`` (daq/studies/frf_judge.py says which and why) and
    judged (``FRFSet.quality``). Damage met in the hits' records: :class:`LogDamagedError` (exit 3)."""
    try:
        reader = LogReader(path)
    except LogReadError as exc:
        raise BadInput(str(exc)) from None
    ref = reference or rig.hammer.name
    sources, outs, units = layout(reader, ref, channels)
    fs = reader.streams()[sources[0].stream].sample_rate
    band_hz = default_band(fs) if band_hz is None else band_hz
    quantities = [QUANTITY_OF_UNIT.get(units[c], "acceleration") for c in outs]
    hits = [Hit.from_json(h) for h in reader.json_messages(HITS_TOPIC)]
    if not hits and not reader.damage:
        raise BadInput(f"{path}: the log has no hits ({HITS_TOPIC}); record or simulate a session with hits")
    points, at = plan_of_hits(reader, hits)
    n, pre = _record_samples(rig, hits, fs), round(PRE_TRIGGER_S * fs)
    tau = choose_tau(lowest_decay_rate(rig), n / fs, end_level)
    names = [p["name"] for p in points] or [ref]
    levels = Levels.of(hits)

    def acc(r: str) -> FRFAccumulator:
        return FRFAccumulator(fs, n, outs, r, tau=tau, t0=pre / fs, f_max=band_hz, quantities=quantities, end_level=end_level)

    accs: dict[tuple[str, int], FRFAccumulator] = {}
    run = FRFRun(str(path), rig.name, sources[0].stream, None, n / fs, pre / fs, tau, band_hz, points=points,
                 streams={s.stream: s.offset for s in sources})  # fmt: skip
    full_scale, notes, damaged = force_full_scale(rig), [], []
    for k, hit in enumerate(hits):
        verdict, reason, chk = _judge(reader, sources, [ref, *outs], hit, n, pre, fs, band_hz, full_scale, run, damaged)
        row = {"hit": hit.hit, "t_s": hit.t_s, "peak_force_N": hit.peak_force_N, "verdict": verdict, "reason": reason,
               "checks": chk[0].as_dict() if chk[0] is not None else None, "level": _level_no(levels, hit.hit)}  # fmt: skip
        if verdict == "accepted":
            d, key = chk[1], (at.get(hit.hit, ref), levels.of_hit[hit.hit])
            accs.setdefault(key, acc(key[0])).add(d[:, 0], d[:, 1:], use=[o not in (hit.excluded_channels or ()) for o in outs])
        if chk[0] is not None and chk[0].note:
            notes.append((hit.hit, chk[0].note))
        if points:
            row["point"] = at.get(hit.hit)
        run.hits.append(row)
        if progress:
            progress((k + 1) / len(hits))
    if damaged or reader.damage:
        lost = sorted({h for *_x, h in damaged if h is not None})
        what = f"the record of hit(s) {', '.join(map(str, lost))} lies in them" if lost else "hit records may be lost with them"
        raise damage_error(reader, [d[:4] for d in damaged], what)
    gaps = np.diff(sorted(h.index for h in hits)) / fs
    ring = (float(gaps.min()) if gaps.size else np.inf, float(np.log(1e3) / lowest_decay_rate(rig)))
    _average(run, accs, names, levels, level, band_hz, n_peaks, notes, kind, quantity, ring)
    run.driving = _driving(rig, ref, points, outs)
    return run


def _level_no(levels: Levels, hit: int) -> int | None:
    lv = levels.of_hit.get(hit)
    return None if lv is None else lv + 1


def _average(run: FRFRun, accs: dict, names: list[str], levels: Levels, level: str | int | None, band: float,
             n_peaks: int, notes: list[tuple[int, str]], kind: str, quantity: str,
             ring: tuple[float, float] = (np.inf, 0.0)) -> None:  # fmt: skip
    """The FRFs of the levels averaged (one set per hit point), their quality, and why each other hit was left out."""
    counts = [sum(a.count for (_r, lv), a in accs.items() if lv == k) for k in range(len(levels.ranges))]
    def linear_to(lo: int, lv: int) -> bool:
        lin = linearity(accs, names, lo, lv, band, n_peaks, kind, quantity)
        return lin is None or lin.linear

    chosen = pick_levels(levels, counts, level, linear_to)
    for p in run.points:
        m = merged(accs, p["name"], chosen)
        p["accepted"] = m.count if m is not None else 0
    sets = [m.frf(kind, quantity) for r in names if (m := merged(accs, r, chosen)) is not None]
    if not sets:
        return
    frf = stack_references(sets)
    q = judge(frf, accs, names, levels, chosen, counts, band, n_peaks, notes, kind, quantity, *ring)
    run.frf = replace(frf, quality=q)
    for row in run.hits:
        if row["verdict"] == "accepted" and row["level"] is not None and row["level"] - 1 not in chosen:
            row["verdict"] = "left out"
            row["reason"] = (f"force {levels.label(row['level'] - 1)}: averaged "
                             f"{', '.join(levels.label(lv) for lv in chosen)} (--level all averages every level)")  # fmt: skip


def _driving(rig: Rig, ref: str, points: list[dict], outs: list[str]) -> dict[str, str]:
    """Reference -> the response on its DOF: each hit point's sensor, or the sensor at the hammer's DOF."""
    if points:
        return {p["name"]: p["sensor"] for p in points if p.get("sensor") in outs}
    at = next((s.name for s in rig.sensors if s.dof == rig.hammer.dof and s.name in outs), None)
    return {ref: at} if at else {}


def _read_record(reader: LogReader, sources: list[Source], cols: list[str], i0: int, n: int, fs: float,
                 damaged: list | None = None, hit: int | None = None) -> np.ndarray | None:  # fmt: skip
    """``cols`` over ``[i0, i0 + n)`` of the hits' grid, each stream read on its own clock; None if any stream
    lacks a sample there (end of log, gap, restart, damage: its ranges go to ``damaged`` with ``hit``)."""
    parts: dict[str, np.ndarray] = {}
    for src in sources:
        j0 = i0 - src.offset
        d = reader.read_stream(src.stream, list(src.channels), start=j0 / fs, end=(j0 + n) / fs, on_damage="skip")
        if d.damaged and damaged is not None:
            damaged += [(src.stream, a, b, why, hit) for a, b, why in d.damaged]
        if d.data.shape[0] != n or d.gaps or d.damaged or (n and (d.index[0] != j0 or d.index[-1] != j0 + n - 1)):
            return None
        parts.update({c: d.data[:, k] for k, c in enumerate(src.channels)})
    return np.stack([parts[c] for c in cols], axis=1).astype(float)


def _judge(reader: LogReader, sources: list[Source], cols: list[str], hit: Hit, n: int, pre: int, fs: float, band: float,
           full_scale: float, run: FRFRun,
           damaged: list) -> tuple[str, str, tuple[HammerCheck | None, np.ndarray | None]]:  # fmt: skip
    """Verdict, reason and (checks, record) of one hit; damage met in its record is added to ``damaged``."""
    if hit.verdict != "accepted":
        return "refused", f"hit gate: {hit.reason or hit.verdict}", (None, None)
    data = _read_record(reader, sources, cols, hit.index - pre, n, fs, damaged, hit.hit)
    if data is None:
        why = f"record incomplete: not all {n} samples of every stream (end of log, gap, restart or damage)"
        return "refused", why, (None, None)
    chk = check_hit(data[:, 0], fs, band, full_scale)
    run.spectra.append((hit.hit, *_spectrum(data[:, 0], fs, band)))
    return chk.verdict, chk.reason, (chk, data)


def _spectrum(force: np.ndarray, fs: float, band: float) -> tuple[np.ndarray, np.ndarray]:
    from analysis.hammer import force_spectrum

    f, m = force_spectrum(force, fs)
    k = np.searchsorted(f, 2.0 * band)
    return f[:k], m[:k]


def peak_rows(frf: FRFSet, n_peaks: int = 6) -> list[dict]:
    """Per peak of the mode indicator (:meth:`FRFSet.peaks`), reference and response: frequency, |H|, phase,
    coherence."""
    rows = []
    for k in frf.peaks(n_peaks):
        for r, ref in enumerate(frf.references):
            for o, name in enumerate(frf.outputs):
                h = frf.H[o, r, k]
                rows.append({"freq_hz": float(frf.freq[k]), "reference": ref, "response": name, "mag": float(abs(h)),
                             "phase_deg": float(np.degrees(np.angle(h))),
                             "coherence": float(frf.coherence[o, r, k])})  # fmt: skip
    return rows


def summary(run: FRFRun, n_peaks: int = 6) -> dict:
    """The ``--json`` document (``reference``/``averages``: the first reference; ``references``: all of them)."""
    f = run.frf
    refs = [{"name": r, "averages": int(c)} for r, c in zip(f.references, f.n_averages, strict=True)] if f else []
    return {
        "log": run.log, "rig": run.rig, "stream": run.stream, "streams": run.streams, "band_hz": run.band_hz,
        "record_s": run.record_s, "pre_trigger_s": run.pre_s, "df_hz": 1.0 / run.record_s,
        "window": f.window if f is not None else {"tau_s": run.tau_s, "sigma_added": 1.0 / run.tau_s if run.tau_s else 0.0},
        "kind": f.kind if f else None, "quantity": f.quantity if f else None, "units": f.units if f else None,
        "reference": f.references[0] if f else None, "averages": int(f.n_averages[0]) if f else 0, "references": refs,
        "plan_points": run.points, "driving_points": run.driving,
        "hits": run.hits, "peaks": peak_rows(f, n_peaks) if f is not None else [],
        # responses the hit gate left out of some hits (clipped, dead): averaged over the hits they were good on
        "fewer_averages": {o: int(c) for o, c in zip(f.outputs, f.window.get("averages_per_output", []), strict=False)
                           if c < f.n_averages[0]} if f is not None and f.n_averages.size == 1 else {},
        # how far to trust it (daq/studies/frf_judge.py): levels, linearity, coherence per mode, pulses, warnings
        "quality": f.quality if f is not None else {}, "warnings": f.quality.get("warnings", []) if f is not None else [],
    }  # fmt: skip


def plot(run: FRFRun, path: Path, channel: str | None = None) -> None:
    """Magnitude, phase and coherence of the driving point (the output nearest the reference: the first
    of the rig's order if unknown) and ``channel``, and every checked hit's force spectrum, into a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = run.frf
    fig, ax = plt.subplots(4, 1, figsize=(9, 11), sharex=False)
    if f is not None:
        show = [o for o in dict.fromkeys([channel or f.outputs[-1], f.outputs[0]]) if o in f.outputs]
        for name in show:
            o = f.outputs.index(name)
            ax[0].semilogy(f.freq, np.abs(f.H[o, 0]), label=name)
            ax[1].plot(f.freq, np.degrees(np.angle(f.H[o, 0])), label=name)
            ax[2].plot(f.freq, f.coherence[o, 0], label=name)
        ax[0].set_ylabel(f"|{f.kind}| [{f.units}]")
        ax[0].set_title(f"{run.log}: {f.kind} {f.quantity}, {int(f.n_averages[0])} averages, reference {f.references[0]}")
        ax[1].set_ylabel("phase [deg]")
        ax[2].set_ylabel("coherence")
        ax[2].set_ylim(0, 1.05)
        for a in ax[:3]:
            a.legend(loc="best", fontsize=8)
            a.set_xlabel("frequency [Hz]")
    for hit, fr, mag in run.spectra:
        ax[3].plot(fr, 20 * np.log10(np.maximum(mag, 1e-300) / max(mag[0], 1e-300)), lw=0.8, label=f"hit {hit}")
    ax[3].axvline(run.band_hz, color="k", ls="--", lw=0.8)
    ax[3].axhline(-10, color="grey", ls=":", lw=0.8)
    ax[3].axhline(-20, color="grey", ls=":", lw=0.8)
    ax[3].set_ylim(-40, 5)
    ax[3].set_ylabel("force spectrum [dB re DC]")
    ax[3].set_xlabel("frequency [Hz]")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=90)
    plt.close(fig)


__all__ = [
    "FRFRun",
    "Source",
    "assign_points",
    "frf_from_log",
    "layout",
    "peak_rows",
    "plan_of_hits",
    "plot",
    "summary",
]
