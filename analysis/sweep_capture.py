"""Second stage of ``gvt sweep``: confirm internal resonances with the seed's slow-flow test at candidate passages.

Why: the sweep's per-run modal ratio f2/f1 (``analysis.model.sweep.ModalProbe``) is a *record mean*. A phase
capture that holds Φ_{m:n} = m·θ1 − n·θ2 non-time-like over most of a 1 s record shows in that mean only as a
slowed passage through m/n, not as a plateau (docs/sweep.md, "Locks": the 4:1 at 136–163 N is 0.78× its
sides' slope, so ``find_locks`` does not report it). The seed does not label an IR from a ratio either: it
tests the slow phase — Φ_{m:n} non-time-like (loops about Φ̇ = 0), the neighbours (m∓1):n drifting in opposite
directions (L1296–L1298). This module runs that test on a few re-simulated runs of the sweep itself.

1. **Candidate passages** (:func:`candidate_passages`): with the runs ordered by input energy (the RQ-FEP's
   axis, L1251), for each ratio m:n of ``CaptureSettings.ratios`` (the seed's set, L67, L1255, L1389) every
   maximal run of consecutive points with |f2/f1 − m/n| ≤ ``passage_tol``·m/n is one passage — plateau or
   not: the test decides, not the shape of the mean ratio. A ratio that jumps over m/n between two points
   with neither within the tolerance has no run near m/n to test and gives no passage.
2. **Runs to test** (:func:`runs_to_test`): per passage at most ``max_runs_per_passage`` runs — the one nearest
   m/n, then points spread evenly over the passage (all of a short passage). Each is re-simulated and tested;
   the capture's P range is the span of the runs that were *tested and confirmed*, never an extrapolation
   ("k of j runs" says how much of the passage that is). All passages share the budget ``max_runs``; a
   passage that does not fit is reported as untested.
3. **The test at one run** (:func:`capture_test`), as ``bench/eval_sweep_band.py`` does it: the unwrapped
   phases of linear modes 1–2 (the modal filter at the outputs) → unit phasors cos θ, decimated ×``decimate``
   → ``analysis.slowflow.test_ratios`` for m:n with ``span`` neighbours each side (the seed's (m−2 … m+2):n,
   L1296), a ``lowpass_hz`` cut-off and the seed's ``end_guard_s`` (L1426): the strongest trusted
   non-time-like candidate, with the bracketing rule ((m−1):n drifting with Φ̇ < 0 and (m+1):n with Φ̇ > 0
   inside its interval, L1298). A run confirms m:n when test_ratios confirms *and* its strongest candidate is
   m:n itself. The whole-record chain that holds the trusted interval (it may reach into the guards) and the
   neighbours' mean Φ̇ are kept as evidence. This relies on slowflow judging a chain that reaches into the
   guard by its reversals outside it: the seed accepts a capture spanning "almost the entire simulation"
   (L1298), and a rule that discards any chain touching a guard cannot confirm one (docs/sweep.md).

The re-simulation is injected (``simulate(p) -> (input work J, phases (2, n))``): ``daq.studies.sweep`` passes the
sweep's own simulator (``analysis.model.sweep.run_modal_phases``), which reproduces the sweep's run bit for bit.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

import analysis.slowflow as sf
from analysis.model.beam import FloatArray
from analysis.rqfep import DEFAULT_RATIOS
from analysis.runs import true_runs


@dataclass(frozen=True)
class CaptureSettings:
    """Thresholds of the capture stage (the seed gives none for a sweep; each is argued here).

    * ``capture``: run the stage at all.
    * ``ratios``: the m:n to look for, default the labeller's seed set {2, 5/2, 3, 7/2, 4, 9/2, 5} (L67, L1255).
    * ``passage_tol``: a run is near m:n when |f2/f1 − m/n| ≤ ``passage_tol``·m/n. 0.03, the lock detector's
      ``lock_tol`` (``analysis.rqfep.SpikeSettings``): at the sweep's spacing (P × 1.026 per point) the mean
      ratio moves ≤ ~3 % per point below 1 kN (measured: 1–2 %), so every steady passage puts ≥ 1 point inside.
      Not chosen to find 4:1: the 4:1 passage (136–163 N, 8 points) is inside at any tolerance ≥ 0.5 %.
    * ``max_runs_per_passage``: re-simulated runs per passage at most (:func:`runs_to_test`). 4: enough to see
      whether a capture holds over the passage or at one point of it, at a bounded cost.
    * ``max_runs``: re-simulated runs over the whole sweep at most; passages that do not fit are listed as
      untested. 60: ~0.27 s a run on one core (simulation + test), ≤ 16 s, a few % of a 1000-run sweep
      (docs/sweep.md has the measured cost and count).
    * ``lowpass_hz``: cut-off of the instantaneous frequencies and of Φ. 4 Hz, as in ``bench/eval_sweep_band.py``:
      its 0.25 s transient fits inside the 0.3 s guard and it lies below NNM1 (≥ 5 Hz wherever the ratio is ≤ 5
      on ``beam_ch4_sim``); slowflow's default (0.2·f1) gives a ≥ 0.5 s guard that leaves nothing of a 1 s record.
    * ``end_guard_s``: the seed's end guard (L1426): reversals closer than this to a record end are not trusted.
    * ``min_interior_s``: a record whose interior [guard, T − guard] is shorter than this is not tested (the
      detector needs a few slow periods: 0.4 s is the interior of the seed's 1 s runs, L1215).
    * ``decimate``: phases are taken every ``decimate``-th sample (16384 → 2048 Hz; Φ lives below 10 Hz).
    * ``span``: neighbours (m−span … m+span):n scanned for the strongest non-time-like candidate (L1296).
    * ``detector``: the slow-flow detector's own thresholds (``analysis.slowflow.DetectorParams`` defaults,
      calibrated in docs/slowflow.md); its ``end_guard_s`` is replaced by ``end_guard_s``.
    """

    capture: bool = True
    ratios: tuple[tuple[int, int], ...] = DEFAULT_RATIOS
    passage_tol: float = 0.03
    max_runs_per_passage: int = 4
    max_runs: int = 60
    lowpass_hz: float = 4.0
    end_guard_s: float = 0.3
    min_interior_s: float = 0.3
    decimate: int = 8
    span: int = 2
    detector: sf.DetectorParams = field(default_factory=sf.DetectorParams)

    def __post_init__(self) -> None:
        if not 0 < self.passage_tol < 1 or self.max_runs_per_passage < 1 or self.max_runs < 0:
            raise ValueError("CaptureSettings: passage_tol in (0, 1), max_runs_per_passage >= 1, max_runs >= 0")
        if self.lowpass_hz <= 0 or self.end_guard_s < 0 or self.decimate < 1 or self.span < 1:
            raise ValueError("CaptureSettings: lowpass_hz > 0, end_guard_s >= 0, decimate >= 1, span >= 1")


@dataclass(frozen=True)
class Passage:
    """Consecutive sweep points (by energy) with the modal ratio within ``passage_tol`` of m:n.

    ``indices`` are input-order indices, ordered by energy.
    """

    ratio: tuple[int, int]
    indices: tuple[int, ...]
    p_lo: float
    p_hi: float
    energy_lo: float
    energy_hi: float
    ratio_min: float
    ratio_max: float

    @property
    def label(self) -> str:
        return f"{self.ratio[0]}:{self.ratio[1]}"

    @property
    def crosses(self) -> bool:
        """The mean ratio lies on both sides of m/n inside the passage."""
        t = self.ratio[0] / self.ratio[1]
        return self.ratio_min <= t <= self.ratio_max


@dataclass(frozen=True)
class RunTest:
    """The slow-flow test of one m:n at one re-simulated run (:func:`capture_test`).

    ``confirmed``: ``slowflow.test_ratios`` confirms and its strongest candidate (``best``) is m:n.
    ``interval_s`` is the best candidate's trusted interval (NaN when none); ``chain_s`` the whole chain that
    holds it (it may reach into the guards: ``chain_end_effect``). ``bracket`` maps (best∓1):n to the mean Φ̇
    (rad/s) over ``interval_s``; ``drift`` every scanned candidate to its median Φ̇ over [guard, T − guard].
    """

    index: int
    p: float
    energy: float
    modal_ratio: float
    ratio: tuple[int, int]
    confirmed: bool
    reason: str
    best: str
    interval_s: tuple[float, float]
    strength: float
    sign_changes: int
    phase_range: float
    net_drift: float
    captured_fraction: float
    chain_s: tuple[float, float]
    chain_sign_changes: int
    chain_end_effect: bool
    bracket: dict[str, float]
    drift: dict[str, float]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ratio"] = f"{self.ratio[0]}:{self.ratio[1]}"
        return d


@dataclass(frozen=True)
class SweepCapture:
    """A capture at m:n confirmed by the slow-flow test on ≥ 1 run of one passage (``kind = "capture"``).

    ``p_lo``…``p_hi`` / ``energy_lo``…``energy_hi`` span the *confirmed* runs; ``passage_*`` the passage they
    came from; ``interval_s`` / ``chain_s`` / ``strength`` / ``sign_changes`` / ``phase_range`` / ``bracket``
    are the strongest confirmed run's evidence; ``runs`` every run tested in the passage.
    """

    ratio: tuple[int, int]
    p_lo: float
    p_hi: float
    energy_lo: float
    energy_hi: float
    n_confirmed: int
    n_tested: int
    passage_p: tuple[float, float]
    passage_energy: tuple[float, float]
    passage_points: int
    passage_ratio: tuple[float, float]
    i_peak: int
    interval_s: tuple[float, float]
    chain_s: tuple[float, float]
    strength: float
    sign_changes: int
    phase_range: float
    bracket: dict[str, float]
    runs: tuple[RunTest, ...]
    kind: str = "capture"

    @property
    def label(self) -> str:
        return f"{self.ratio[0]}:{self.ratio[1]}"

    @property
    def confirmed_indices(self) -> list[int]:
        return [r.index for r in self.runs if r.confirmed]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ratio"] = self.label
        d["runs"] = [r.to_dict() for r in self.runs]
        return d


@dataclass
class CaptureReport:
    """Everything the stage did: the confirmed captures, every passage with its tests, the cost."""

    captures: list[SweepCapture]
    passages: list[Passage]
    tests: dict[int, list[RunTest]]  # passage number → its run tests (empty: untested, see ``untested``)
    untested: list[int]  # passages left out by ``max_runs``
    runs: int
    wall_s: float

    def to_dict(self) -> dict:
        return {
            "captures": [c.to_dict() for c in self.captures],
            "passages": [
                dict(asdict(p), ratio=p.label, tested=[t.to_dict() for t in self.tests.get(k, [])], untested=k in self.untested)
                for k, p in enumerate(self.passages)
            ],
            "runs": self.runs,
            "wall_s": self.wall_s,
        }


def candidate_passages(
    energy: FloatArray, modal_ratio: FloatArray, amplitudes: FloatArray, settings: CaptureSettings = CaptureSettings()
) -> list[Passage]:
    """Every maximal run of consecutive points (by energy) with |ratio − m/n| ≤ ``passage_tol``·m/n, per m:n.

    NaN ratios break runs. Ordered by energy, then by m/n.
    """
    e = np.asarray(energy, dtype=float)
    r0 = np.asarray(modal_ratio, dtype=float)
    p0 = np.asarray(amplitudes, dtype=float)
    if e.ndim != 1 or r0.shape != e.shape or p0.shape != e.shape:
        raise ValueError("energy, modal_ratio and amplitudes must all be (runs,)")
    order = np.argsort(e, kind="stable")
    r = r0[order]
    out: list[Passage] = []
    for m, n in settings.ratios:
        t = m / n
        inside = np.isfinite(r) & (np.abs(r - t) <= settings.passage_tol * t)
        for lo, hi in true_runs(inside):
            idx = order[lo : hi + 1]
            ps = Passage((m, n), tuple(int(i) for i in idx), float(p0[idx].min()), float(p0[idx].max()),
                         float(e[idx].min()), float(e[idx].max()), float(r0[idx].min()), float(r0[idx].max()))  # fmt: skip
            out.append(ps)
    out.sort(key=lambda ps: (ps.energy_lo, ps.ratio[0] / ps.ratio[1]))
    return out


def capture_test(
    theta: FloatArray, fs: float, m: int, n: int, settings: CaptureSettings = CaptureSettings()
) -> dict:
    """The seed's slow-flow test of m:n on one run's unwrapped modal phases ``theta`` (2, n_samples) at ``fs``.

    The verdict is ``analysis.slowflow.test_ratios`` on the whole record (module docstring, step 3): confirmed
    when it confirms and its strongest candidate is m:n itself. Returns the :class:`RunTest` fields that do not
    depend on the sweep: ``confirmed``, ``reason`` (test_ratios' own), ``best``, the trusted interval's
    evidence, the whole chain it belongs to, ``bracket`` (mean Φ̇ of (m∓1):n over the interval) and ``drift``
    (median Φ̇ of every scanned candidate over [guard, T − guard]).
    """
    th = np.asarray(theta, dtype=float)
    if th.ndim != 2 or th.shape[0] != 2:
        raise ValueError(f"theta must be (2, n_samples), got {th.shape}")
    a, b = np.cos(th[0, :: settings.decimate]), np.cos(th[1, :: settings.decimate])
    fsd = fs / settings.decimate
    t_end = (a.size - 1) / fsd
    g = settings.end_guard_s
    nan2 = (math.nan, math.nan)
    out = {"confirmed": False, "best": "-", "interval_s": nan2, "strength": 0.0, "sign_changes": 0,
           "phase_range": math.nan, "net_drift": math.nan, "captured_fraction": 0.0, "chain_s": nan2,
           "chain_sign_changes": 0, "chain_end_effect": False, "bracket": {}, "drift": {}}  # fmt: skip
    if t_end - 2 * g < settings.min_interior_s:
        return {**out, "reason": f"record interior {t_end - 2 * g:.2f} s < {settings.min_interior_s} s: not tested"}
    params = replace(settings.detector, end_guard_s=g)
    ratios = sf.candidate_ratios(m, n, settings.span)
    trajs = {r: sf.trajectory(a, b, fsd, r[0], r[1], settings.lowpass_hz, params) for r in ratios}  # computed once
    c = sf.test_ratios(a, b, fsd, m, n, settings.span, settings.lowpass_hz, params, trajectories=trajs)
    out["drift"] = {f"{k}:{nn}": float(np.median(tr.phi_dot[(tr.t >= g) & (tr.t <= t_end - g)])) for (k, nn), tr in trajs.items()}
    if not math.isfinite(c.start_s):
        return {**out, "reason": c.reason}
    rt = next(x for x in c.candidates if (x.m, x.n) == (c.m, c.n))
    iv = next(x for x in rt.trusted if x.start_s == c.start_s and x.end_s == c.end_s)
    chain = [x for x in rt.intervals if x.end_effect and x.start_s <= iv.end_s and iv.start_s <= x.end_s]
    ch = max(chain, key=lambda x: x.end_s - x.start_s) if chain else iv
    bracket = {}
    for k in (c.m - 1, c.m + 1):
        if k >= 1:
            tr = trajs.get((k, c.n)) or sf.trajectory(a, b, fsd, k, c.n, settings.lowpass_hz, params)
            bracket[f"{k}:{c.n}"] = float(np.mean(tr.phi_dot[(tr.t >= iv.start_s) & (tr.t <= iv.end_s)]))
    confirmed = c.confirmed and (c.m, c.n) == (m, n)
    reason = c.reason if (c.m, c.n) == (m, n) else f"strongest candidate is {c.m}:{c.n}, not {m}:{n} ({c.reason})"
    return {
        **out, "confirmed": confirmed, "reason": reason, "best": f"{c.m}:{c.n}", "interval_s": (iv.start_s, iv.end_s),
        "strength": iv.strength, "sign_changes": iv.sign_changes, "phase_range": iv.phase_range,
        "net_drift": iv.net_drift, "captured_fraction": rt.captured_fraction,
        "chain_s": (ch.start_s, ch.end_s), "chain_sign_changes": ch.sign_changes, "chain_end_effect": ch.end_effect,
        "bracket": bracket,
    }  # fmt: skip


def runs_to_test(ps: Passage, ratio: FloatArray, k: int) -> list[int]:
    """Up to ``k`` runs of a passage: the one nearest m/n, then ``k − 1`` points spread evenly over the passage
    from its first to its last point (when the nearest is one of them, the next from a finer even spacing).

    Why spread, not the k nearest: the record-mean ratio cannot say where in a passage a capture sits (a
    capture over part of the record moves the mean only a little: docs/sweep.md), so nearness to m/n is a
    poor guide beyond the first pick, and a plateau's points are all equally near. A passage of ≤ k points
    is tested whole.
    """
    idx = list(ps.indices)
    if len(idx) <= k:
        return idx
    t = ps.ratio[0] / ps.ratio[1]
    first = min(idx, key=lambda i: abs(ratio[i] - t))
    picks = [first]
    for q in (k - 1, k, k + 1):  # k − 1 evenly spaced (both ends when k >= 3); finer when one was the nearest
        for j in np.linspace(0, len(idx) - 1, max(q, 1)).round().astype(int):
            if len(picks) < k and idx[j] not in picks:
                picks.append(idx[j])
    return picks


def confirm_captures(
    energy: FloatArray,
    modal_ratio: FloatArray,
    amplitudes: FloatArray,
    simulate: Callable[[float], tuple[float, FloatArray]],
    fs: float,
    settings: CaptureSettings = CaptureSettings(),
    progress: Callable[[int, int], None] | None = None,
) -> CaptureReport:
    """Candidate passages → re-simulated runs → slow-flow test → captures (module docstring, steps 1–3).

    ``simulate(p)`` returns (input work J, unwrapped phases (2, n_samples) of linear modes 1–2 at ``fs``)
    for the sweep's run at amplitude ``p``. ``progress`` gets (passages done, passages).
    """
    t0 = time.perf_counter()
    e = np.asarray(energy, dtype=float)
    r = np.asarray(modal_ratio, dtype=float)
    p = np.asarray(amplitudes, dtype=float)
    passages = candidate_passages(e, r, p, settings) if settings.capture else []
    tests: dict[int, list[RunTest]] = {}
    untested: list[int] = []
    captures: list[SweepCapture] = []

    n_runs = 0
    for k, ps in enumerate(passages):
        if progress:
            progress(k, len(passages))
        pick = runs_to_test(ps, r, settings.max_runs_per_passage)
        if n_runs + len(pick) > settings.max_runs:
            untested.append(k)
            continue
        done = []
        for i in pick:
            work, theta = simulate(float(p[i]))
            res = capture_test(theta, fs, ps.ratio[0], ps.ratio[1], settings)
            done.append(RunTest(index=i, p=float(p[i]), energy=work, modal_ratio=float(r[i]), ratio=ps.ratio, **res))
        n_runs += len(pick)
        done.sort(key=lambda t: t.energy)
        tests[k] = done
        good = [t for t in done if t.confirmed]
        if good:
            top = max(good, key=lambda t: t.strength)
            cp = SweepCapture(
                ratio=ps.ratio, p_lo=min(t.p for t in good), p_hi=max(t.p for t in good),
                energy_lo=min(t.energy for t in good), energy_hi=max(t.energy for t in good),
                n_confirmed=len(good), n_tested=len(done), passage_p=(ps.p_lo, ps.p_hi),
                passage_energy=(ps.energy_lo, ps.energy_hi), passage_points=len(ps.indices),
                passage_ratio=(ps.ratio_min, ps.ratio_max), i_peak=top.index, interval_s=top.interval_s,
                chain_s=top.chain_s, strength=top.strength, sign_changes=top.sign_changes,
                phase_range=top.phase_range, bracket=top.bracket,
                runs=tuple(done),
            )  # fmt: skip
            captures.append(cp)
    return CaptureReport(captures, passages, tests, untested, n_runs, time.perf_counter() - t0)
