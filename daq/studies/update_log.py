"""The modes a session log gives ``gvt model update``: linear-regime hits, healthy channels, each frequency's uncertainty.

A linear FE model can only be updated against data a linear structure would give. On a rig with a local
nonlinearity the identified frequencies move with the force (a hardening spring: up), and three parameters absorb
that shift without complaint (issue 29: from 200 N hits the attachment mass came out 7 sigma and the spring 38 sigma
off, silently). And a dead accelerometer's FRF is noise that a modal fit takes as a shape: with one dead channel the
fit of a 20 N log missed mode 1. So, before updating (docs/model-updating.md, "From a log"):

* **Hits**: the FRF study's force levels (daq/studies/frf.py: the lowest level with 2 hits is averaged, the lowest
  and the highest compared by analysis/frf_levels.py ``linearity_check``); when the levels differ and that rule
  averaged another level (the lowest had one hit), the lowest level is used all the same: a nonlinear level biases
  every parameter, one hit only widens the uncertainty. The hits left out and why are said. A log of one level
  cannot be checked: that is said too. ``level`` chooses another level, or ``"all"``.
* **Channels**: a response the hit gate left out of every hit (``excluded_channels``), or that sensor health
  (analysis/sensor_health.py: dead, stuck, clipping) judges bad in the hits' first ``HEALTH_SPAN_S``, is left out of
  the FRFs and the modal fit, and named.
* **Band**: the default is 2 Hz to the FRFs' last line (the FRF grid's last line sits up to one line below the
  band asked for; a band that asks beyond it by less than a line is taken to that line, and said).
* **Uncertainty**: each identified frequency's 1-sigma from the FRFs' coherence at its peak
  (analysis/model/update_quality.py ``frequency_std``), for the fit's chi-square and weighted sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.model.rig import Rig
from analysis.model.updating import MeasuredModes, Progress

LOW_HZ = 2.0  # the lower edge of the band modes are identified in, as `gvt modal`
#: seconds of each hit (from the trigger) that sensor health judges: the response is largest there, and 0.25 s is
#: 16 of sensor health's 15 ms level spans (analysis/sensor_health.py) at any rate
HEALTH_SPAN_S = 0.25
#: at most this many hits are read for sensor health (a dead channel is dead on the first ones too)
HEALTH_HITS = 6
#: sensor-health faults that leave a channel out of the update (drift and noise need longer stretches than hits)
LEAVE_OUT = ("dead", "stuck", "clipping")


@dataclass
class LogModes:
    """The measured modes of a log and what was used to get them (said on screen, kept in the provenance)."""

    measured: MeasuredModes
    band: tuple[float, float]
    hits_used: list[int]
    channels_left_out: dict[str, str]  # channel -> why
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def provenance(self) -> dict[str, str | list[str]]:
        return {
            "band_hz": f"{self.band[0]:g}-{self.band[1]:g}",
            "hits": [str(h) for h in self.hits_used],
            "channels_left_out": [f"{c}: {why}" for c, why in self.channels_left_out.items()],
            "notes": list(self.notes),
        }


def channel_health(source: Path, rig: Rig) -> dict[str, str]:
    """Response channel -> why it is left out: excluded by the hit gate on every accepted hit, or judged dead, stuck
    or clipping by sensor health in the first ``HEALTH_SPAN_S`` of each of the first ``HEALTH_HITS`` accepted hits."""
    from analysis.records import HITS_TOPIC, Hit
    from analysis.sensor_health import SensorHealth
    from daq.log.reader import LogReader, LogReadError
    from daq.studies.frf import layout

    try:
        reader = LogReader(source)
    except LogReadError as exc:
        raise BadInput(str(exc)) from None
    hits = [h for h in (Hit.from_json(m) for m in reader.json_messages(HITS_TOPIC)) if h.verdict == "accepted"]
    if not hits:
        return {}
    out: dict[str, str] = {}
    sources, outs, _units = layout(reader, rig.hammer.name, None)
    gate = [set(h.excluded_channels or ()) for h in hits]
    for c in outs:
        if all(c in g for g in gate):
            out[c] = f"left out by the hit gate on all {len(hits)} accepted hits ({(hits[0].channels or {}).get(c, 'excluded')})"
    infos = reader.streams()
    for src in sources:
        chans = [c for c in src.channels if c in outs and c not in out]
        if len(chans) < 3:  # sensor health judges a channel against the others' median
            continue
        fs = infos[src.stream].sample_rate
        props = {s.name: s.props for s in rig.sensors}
        health = SensorHealth(chans, fs, ranges=[props[c].range if c in props else None for c in chans])
        n = round(HEALTH_SPAN_S * fs)
        for h in hits[:HEALTH_HITS]:
            j0 = h.index - src.offset
            d = reader.read_stream(src.stream, chans, start=j0 / fs, end=(j0 + n) / fs, on_damage="skip")
            health.restart()
            for v in health.feed(d.data):
                if v.fault in LEAVE_OUT:
                    out.setdefault(v.channel, f"sensor health: {v.fault} on hit {h.hit} ({v.reason})")
    return out


def modes_from_log(source: Path, rig: Rig, band: tuple[float, float] | None = None, level: str | int | None = None,
                   progress: Progress | None = None) -> LogModes:  # fmt: skip
    """The log's accepted hits of one force level -> FRFs of the healthy responses -> pLSCF + LSFD modes, as
    ``gvt modal`` identifies them, each with its frequency's 1-sigma (module docstring)."""
    from daq.studies.frf import frf_from_log
    from daq.studies.modal import modal_from_frf, modes_json

    if not source.exists():
        raise BadInput(f"{source}: file not found")
    bad = channel_health(source, rig)
    chans = [s.name for s in rig.sensors if s.name not in bad]
    # the FRF study's default levels: the lowest, and those linear with it (docs/decisions.md D41, D46)
    fr = frf_from_log(source, rig, channels=chans or None, band_hz=None if band is None else band[1], level=level,
                      progress=None if progress is None else (lambda f: progress("hits", f)))  # fmt: skip
    if fr.frf is None:
        refused = sum(h["verdict"] != "accepted" for h in fr.hits)
        raise BadInput(f"{source}: no accepted hit to build FRFs from ({refused} refused; `gvt frf {source}` says why)")
    notes, warnings = _level_lines(fr.hits, fr.frf.quality or {}, level)
    lo, hi = _band(band, fr.band_hz, fr.frf.freq, notes)
    run = modal_from_frf(fr.frf, rig, lo, hi, source=str(source), driving=fr.driving)
    if not run.rows:
        raise BadInput(f"{source}: no mode identified in {lo:g}-{hi:g} Hz; see `gvt modal {source}`")
    measured = MeasuredModes.from_json(modes_json(run), str(source))
    std, n_avg = _frequency_std(run)
    if n_avg < 2:
        notes.append(f"{n_avg} hit averaged: the coherence says nothing of the noise, so each frequency's uncertainty is "
                     "only the identification's floor (1e-4); hit at least twice at the level used")  # fmt: skip
    warnings += [f"FRF: {w}" for w in (fr.frf.quality or {}).get("warnings", [])]
    used = [h["hit"] for h in fr.hits if h["verdict"] == "accepted"]
    return LogModes(MeasuredModes(measured.freq_hz, measured.shapes, measured.outputs, measured.source, std), (lo, hi),
                    used, bad, notes, warnings)  # fmt: skip


def modes_from_set(source: Path, frf, assumed: list[str], rig: Rig, band: tuple[float, float] | None = None) -> LogModes:
    """The modes of an FRF set given whole (a UFF 58 FRF file, or its ``gvt import``): identified as ``gvt modal``
    does, no hits to choose; a set without averages counts one (the identification's floor as uncertainty)."""
    from dataclasses import replace

    from daq.studies.modal import modal_from_frf, modes_json

    if np.size(frf.n_averages) != len(frf.references):
        frf = replace(frf, n_averages=np.ones(len(frf.references), dtype=int))
        assumed = [*assumed, "averages not stated in the FRF file: taken as 1"]
    notes = list(assumed)
    lo, hi = _band(band, float(frf.freq[-1]), frf.freq, notes)
    run = modal_from_frf(frf, rig, lo, hi, source=str(source))
    if not run.rows:
        raise BadInput(f"{source}: no mode identified in {lo:g}-{hi:g} Hz; see `gvt modal {source}`")
    measured = MeasuredModes.from_json(modes_json(run), str(source))
    std, _n = _frequency_std(run)
    warnings = [f"FRF: {w}" for w in (frf.quality or {}).get("warnings", [])]
    return LogModes(MeasuredModes(measured.freq_hz, measured.shapes, measured.outputs, measured.source, std), (lo, hi),
                    [], {}, notes, warnings)  # fmt: skip


def _band(band: tuple[float, float] | None, band_hz: float, freq: np.ndarray, notes: list[str]) -> tuple[float, float]:
    """The band modes are identified in: default 2 Hz to the FRFs' last line; an asked top within one line above the
    last line is taken to it (the FRF grid's lines fall where the record length puts them), and said."""
    top = float(freq[-1])
    if band is None:
        return LOW_HZ, min(band_hz, top)
    lo, hi = band
    if top < hi <= top + float(freq[1] - freq[0]):
        notes.append(f"--band {lo:g} {hi:g}: the FRFs' last line is {top:.3f} Hz; identified up to it")
        hi = top
    return lo, hi


def _level_lines(hits: list[dict], quality: dict, asked: str | int | None) -> tuple[list[str], list[str]]:
    """What the force levels decided, in one line each: the hits left out and why, or that linearity was not checked
    (one level); a warning when the level used is not the lowest and the levels differ."""
    notes: list[str] = []
    warnings: list[str] = []
    levels = quality.get("levels") or []
    lin = quality.get("linearity")
    used = [lv for lv in levels if lv.get("averaged")]
    left = [h for h in hits if h["verdict"] == "left out"]
    if len(levels) <= 1:
        force = f" ({levels[0]['force_min_N']:.0f}-{levels[0]['force_max_N']:.0f} N)" if levels else ""
        notes.append(f"one force level{force}: linearity across force levels not checked; hits at a second level "
                     "(x0.3 or lower) show whether these are in the linear range")  # fmt: skip
    if left:
        why = f"not linear: {lin['reason'].removeprefix('not linear: ')}" if lin and not lin["linear"] else (
            "linear within the bounds, but the lowest level is nearest the linear model")  # fmt: skip
        notes.append(f"hit(s) {', '.join(str(h['hit']) for h in left)} left out ({left[0]['reason'].split(':')[0]}"
                     f"{'' if len(left) == 1 else ', ...'}): levels compared, {why}")  # fmt: skip
    if lin and not lin["linear"] and used and used[0]["level"] == 1 and used[0]["accepted"] < 2 and asked is None:
        notes.append("the levels differ and the lowest has one accepted hit: it is used alone (the other levels are "
                     "nonlinear); hit at least twice at the lowest level")  # fmt: skip
    if lin and not lin["linear"] and used and used[0]["level"] != 1 and asked != "all":
        warnings.append(f"the hits used (level {used[0]['level']}) are not the lowest force level and the levels differ "
                        f"({lin['reason']}): the update sees the nonlinearity; hit twice at the lowest level "
                        "or --level 1")  # fmt: skip
    if asked == "all" and lin and not lin["linear"]:
        warnings.append(f"--level all mixes force levels that differ ({lin['reason']}): the update sees the nonlinearity")
    return notes, warnings


def _frequency_std(run) -> tuple[np.ndarray, int]:
    """Each identified mode's frequency 1-sigma from the FRFs' coherence at its line (update_quality.frequency_std),
    and the fewest averages any response rests on."""
    from analysis.model.update_quality import REL_STD_FLOOR, frequency_std

    frf = run.frf
    f = np.array([r["freq_hz"] for r in run.rows])
    zeta = np.array([r["zeta"] for r in run.rows]) + run.result.sigma_added / (2 * np.pi * f)  # as the FRF shows it
    k = np.clip(np.searchsorted(frf.freq, f), 0, frf.freq.size - 1)
    coh = np.moveaxis(frf.coherence[:, :, k], -1, 0).reshape(f.size, -1)  # (modes, outputs x references)
    per_out = frf.window.get("averages_per_output")
    n_out = np.asarray(per_out if per_out else [int(np.min(frf.n_averages))] * frf.H.shape[0], float)
    n = np.repeat(n_out[:, None], frf.H.shape[1], axis=1).ravel()
    ok = n >= 2
    if not ok.any():
        return REL_STD_FLOOR * f, int(n.min())
    return frequency_std(f, zeta, coh[:, ok], n[ok], float(frf.freq[1] - frf.freq[0])), int(n.min())
