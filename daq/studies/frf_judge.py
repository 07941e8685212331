"""How far ``gvt frf``'s FRFs can be trusted: force levels, linearity, coherence at the modes, hammer pulses, damage.

The FRF study (daq/studies/frf.py) accumulates each accepted hit into the accumulator of its hit point and force
level; this module decides which levels are averaged (the lowest and those linear with it, or the user's
``--level``), compares the lowest and the highest level (``linearity_check``), judges the coherence at every mode
(analysis/frf_quality.py) and turns the findings into one-line warnings that say what to do. Every finding also
goes into ``FRFSet.quality``, so modal identification, model updating and UFF export read the same verdict.
Damage met while reading (a hit's record, or the chunk holding hit records) ends the study with exit 3 and the
damaged samples named, as ``gvt log export`` does (docs/decisions.md D40).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFAccumulator, FRFSet
from analysis.frf_levels import LEVEL_RATIO, MIN_LEVEL_HITS, choose_level, level_groups, linearity_check
from analysis.frf_quality import coherence_warning, mode_coherence
from daq.log.reader import LogDamagedError, LogReader


@dataclass(frozen=True)
class Levels:
    """The force levels of a log's hits: ``of_hit`` hit number -> level (0-based, ascending force), ``ranges`` per
    level (min, max) peak force in N, from the hit gate's accepted hits."""

    of_hit: dict[int, int]
    ranges: list[tuple[float, float]]

    @classmethod
    def of(cls, hits: Sequence, ratio: float = LEVEL_RATIO) -> Levels:
        ok = [h for h in hits if h.verdict == "accepted" and h.peak_force_N and h.peak_force_N > 0]
        f = np.array([h.peak_force_N for h in ok], dtype=float)
        groups = level_groups(f, ratio)
        of_hit = {ok[i].hit: lv for lv, g in enumerate(groups) for i in g}
        return cls(of_hit, [(float(f[g].min()), float(f[g].max())) for g in groups])

    def label(self, lv: int) -> str:
        lo, hi = self.ranges[lv]
        return f"level {lv + 1} ({lo:.0f} N)" if round(lo) == round(hi) else f"level {lv + 1} ({lo:.0f}-{hi:.0f} N)"


def pick_levels(levels: Levels, counts: list[int], asked: str | int | None, linear_to=None) -> list[int]:
    """The levels averaged: ``asked`` "all", a level number (1-based), or None for the default rule: the lowest
    level with hits, and the levels above it for as long as each passes the linearity check against it
    (``linear_to(lowest, lv)`` -> bool; without it, the lowest level with ``MIN_LEVEL_HITS`` hits, analysis/
    frf_levels.py ``choose_level``).

    Why this rule (docs/decisions.md D41): the FRF a model is compared with is the linear structure's, and the
    lowest force is the nearest to it; levels that give the same FRF (a linear structure, or a nonlinear one
    below where its springs engage) are averaged too, so a linear test keeps every hit's average and its
    coherence, and a nonlinear one stops at the first level whose peaks move."""
    n = len(levels.ranges)
    if asked == "all":
        return [lv for lv in range(n) if counts[lv]]
    if asked is not None:
        k = int(asked)
        if not 1 <= k <= n:
            raise BadInput(f"--level {k}: the log's hits form {n} force level(s): " +
                           ", ".join(levels.label(lv) for lv in range(n)))  # fmt: skip
        return [k - 1]
    used = [lv for lv in range(n) if counts[lv]]
    if not used:
        return []
    if linear_to is None:
        return [choose_level([np.zeros(c) for c in counts], MIN_LEVEL_HITS)]
    chosen = [used[0]]
    for lv in used[1:]:
        if not linear_to(used[0], lv):
            break
        chosen.append(lv)
    return chosen


def merged(accs: dict[tuple[str, int], FRFAccumulator], ref: str, lvs: Sequence[int]) -> FRFAccumulator | None:
    """The accumulator of hit point ``ref`` over levels ``lvs`` (None: no accepted hit there)."""
    got = [accs[(ref, lv)] for lv in lvs if (ref, lv) in accs and accs[(ref, lv)].count]
    if not got:
        return None
    m = got[0]
    for a in got[1:]:
        m = m.merge(a)
    return m


def judge(frf: FRFSet, accs: dict[tuple[str, int], FRFAccumulator], refs: list[str], levels: Levels,
          averaged: list[int], counts: list[int], band: float, n_peaks: int, pulse_notes: list[tuple[int, str]],
          kind: str, quantity: str, spacing_s: float = np.inf, decay_s: float = 0.0) -> dict:  # fmt: skip
    """The ``quality`` dict of an FRF set: levels, linearity, coherence per mode, pulse notes, warnings.
    ``spacing_s`` the shortest time between hits, ``decay_s`` the time the lowest mode takes to decay 60 dB: a
    hit sooner than that finds the structure still ringing from the one before, which lowers the coherence."""
    warnings: list[str] = []
    used = [lv for lv in range(len(levels.ranges)) if counts[lv]]
    lin = None
    if len(used) >= 2:
        lin = linearity(accs, refs, used[0], used[-1], band, n_peaks, kind, quantity)
    if lin is not None and not lin.linear:
        what = ", ".join(levels.label(lv) for lv in averaged)
        fix = ("--level 1 averages the lowest level only" if averaged != [0] else
               "more hits at this force or below show whether it is in the linear range")  # fmt: skip
        warnings.append(f"force levels: {levels.label(used[0])} vs {levels.label(used[-1])} {lin.reason}; averaged "
                        f"{what} only; the FRF depends on the force: {fix}, --level all to mix them")  # fmt: skip
    peaks = frf.peaks(n_peaks)
    modes = mode_coherence(frf.coherence, frf.H, frf.freq, peaks, frf.outputs, frf.references)
    if int(np.min(frf.n_averages)) < 2:
        warnings.append(f"{int(np.min(frf.n_averages))} average(s): coherence is 1 by construction and says nothing; "
                        "hit at least 3 times per point at one force level")  # fmt: skip
    else:
        hint = _coherence_hint(lin, averaged, int(np.min(frf.n_averages)), spacing_s, decay_s)
        warnings += [coherence_warning(m, hint) for m in modes if not m.ok]
    if pulse_notes:
        hits = [h for h, _ in pulse_notes]
        warnings.append(f"hit(s) {_hit_list(hits)}: {pulse_notes[0][1]}")
    return {
        "levels": [{"level": lv + 1, "force_min_N": a, "force_max_N": b, "accepted": counts[lv], "averaged": lv in averaged}
                   for lv, (a, b) in enumerate(levels.ranges)],
        "level_rule": f"hits grouped by peak force, each level within {LEVEL_RATIO:g}x; the lowest level is averaged, "
                      "with the levels above it that pass the linearity check against it, unless --level says otherwise",
        "linearity": None if lin is None else {**lin.as_dict(), "low": levels.label(used[0]), "high": levels.label(used[-1])},
        "mode_coherence": [m.as_dict() for m in modes],
        "pulse": [{"hit": h, "note": n} for h, n in pulse_notes],
        "warnings": warnings,
    }  # fmt: skip


def linearity(accs, refs, lo: int, hi: int, band: float, n_peaks: int, kind: str, quantity: str):
    """linearity_check of the lowest and the highest level on the hit points both have (None: none in common)."""
    pairs = [(merged(accs, r, [lo]), merged(accs, r, [hi])) for r in refs]
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
    if not pairs:
        return None
    H_lo = np.concatenate([a.frf(kind, quantity).H for a, _ in pairs], axis=1)
    H_hi = np.concatenate([b.frf(kind, quantity).H for _, b in pairs], axis=1)
    return linearity_check(pairs[0][0].freq, H_lo, H_hi, band=(1.0, band), n_peaks=n_peaks)


def _coherence_hint(lin, averaged: list[int], n_avg: int, spacing_s: float, decay_s: float) -> str:
    """What to do about a low coherence at a mode, the likeliest cause the data show first."""
    if len(averaged) > 1 and lin is not None and not lin.linear:
        return "hits of different force levels averaged on a force-dependent structure: average one level (--level N)"
    if spacing_s < decay_s:
        return (f"hits {spacing_s:.2f} s apart while the lowest mode needs {decay_s:.1f} s to decay 60 dB: each record "
                "starts with the last hit still ringing; space the hits further apart")  # fmt: skip
    if n_avg < 5:
        return f"only {n_avg} averages: add hits, check for double hits and a loose sensor"
    return "check the hits' force spectra (tip), double hits, a loose sensor or a record too short for the decay"


def _hit_list(hits: list[int]) -> str:
    return ", ".join(str(h) for h in hits) if len(hits) <= 5 else f"{hits[0]}..{hits[-1]} ({len(hits)} hits)"


def damage_error(reader: LogReader, met: list[tuple[str, int, int, str]], what: str) -> LogDamagedError:
    """Exit 3 naming the damaged samples met (``(stream, start, end, why)``); when only a chunk of other records
    was damaged (the hit records'), its samples are found by reading the streams around it."""
    ranges = list(met)
    if not ranges:
        for name, info in reader.streams().items():  # one channel: the damage is per block, the same for each
            ranges += [(name, a, b, why) for a, b, why in reader.read_stream(name, info.channels[:1], on_damage="skip").damaged]
    if not ranges:
        d = next(iter(reader.damage.values()))
        where = f"records of log time {d.start_ns / 1e9:.3f}-{d.end_ns / 1e9:.3f} s"
    else:
        s, a, b, why = ranges[0]
        fs = reader.streams()[s].sample_rate
        more = f" and {len(ranges) - 1} more range(s)" if len(ranges) > 1 else ""
        where = f"samples [{a}, {b}) of stream {s} (t = {a / fs:.3f}-{b / fs:.3f} s){more} ({why})"
    return LogDamagedError(f"{reader.path}: {where} are damaged; {what}; `gvt log recover {reader.path} FIXED.mcap` "
                           "keeps the rest, the damage as a gap, and the study runs on FIXED.mcap")  # fmt: skip


__all__ = ["Levels", "damage_error", "judge", "merged", "pick_levels"]
