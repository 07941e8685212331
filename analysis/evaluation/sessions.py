"""Sessions: several hits on one continuous record, every 2-6 s (issue 21, item 7).

A lab session does not reset the structure between hits: each hit lands on what is left of the
previous ones, and a streaming detector runs through the whole record (the analysis lane of ``gvt
record``), so its thresholds meet decays longer than the seed's 2 s records (L1320). A
:class:`SessionCase` is one such record: half-sine pulses (seed eq. 4.1) of the grid's hammer at
``hit_times_s`` with ``forces_n``, one simulation of the whole train
(:func:`analysis.model.forces.pulse_train`), on the grid's rig with the case's damping and (no)
cubic spring.

**Truth per hit** (:func:`session_exchanges`): the record is cut at the hits; the segment of hit k
runs from its pulse start to the next hit (or the record's end) and its major exchanges are those of
:func:`analysis.evaluation.truth.major_exchanges` on that segment, with the pulse end of hit k and
the floor set by hit k's own input work. An exchange is therefore attributed to the last hit before
it; exchanges never straddle a hit (the smoothing window keeps clear of both ends of a segment).

Stored per session (``.cache/evaluation``): the clean accelerations (float32) and the modal
coordinates of modes 1-4; ``disp_true``/``vel_true`` are left empty (no detector on the realistic
grid reads them) to keep a 25 s session at ~50 MB instead of ~110 MB.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from analysis.evaluation.grid import (
    DEFAULT_CACHE_DIR,
    DEFAULT_FORCES_N,
    DEFAULT_ZETAS,
    N_MODES_KEPT,
    ZETA_REST_CAP,
    CaseData,
    GridCase,
    _code_hash,
    _load,
    _store,
    case_rig,
)
from analysis.evaluation.truth import DEFAULT_WINDOW_S, Exchange, major_exchanges
from analysis.model.forces import pulse_train

SESSION_TAIL_S = 2.0  # the record goes on this long after the last hit


@dataclass(frozen=True)
class SessionCase:
    """Hits at ``hit_times_s`` (s) with ``forces_n`` (N) on one record of ``duration`` s; ``cubic=False`` is the linear twin."""

    forces_n: tuple[float, ...]
    hit_times_s: tuple[float, ...]
    duration: float
    zeta: float
    cubic: bool = True
    seed: int = 0
    rig: str = ""

    def __post_init__(self) -> None:
        if len(self.forces_n) != len(self.hit_times_s) or not self.forces_n:
            raise ValueError("a session needs one force per hit and at least one hit")
        if any(b <= a for a, b in zip(self.hit_times_s, self.hit_times_s[1:], strict=False)):
            raise ValueError("hit times must increase")
        if self.duration <= self.hit_times_s[-1]:
            raise ValueError("the record must end after the last hit")

    @property
    def zeta_rest(self) -> float:
        return min(self.zeta, ZETA_REST_CAP)

    @property
    def n_hits(self) -> int:
        return len(self.forces_n)

    @property
    def grid_case(self) -> GridCase:
        """The single-hit grid case with the same rig, damping and cubic term (for the rig and the model)."""
        return GridCase(1.0, self.zeta, self.cubic, self.seed, self.rig)

    @property
    def name(self) -> str:
        return f"{'nl' if self.cubic else 'lin'}-session{self.seed}-z{self.zeta:g}-{self.n_hits}hits"

    def linear_twin(self) -> SessionCase:
        return replace(self, cubic=False)


def session_grid(
    per_zeta: int = 2,
    hits: int = 5,
    gap_s: tuple[float, float] = (2.0, 6.0),
    zetas: Sequence[float] = DEFAULT_ZETAS,
    forces_n: Sequence[float] = DEFAULT_FORCES_N,
    rig: str = "",
    seed: int = 100,
) -> tuple[SessionCase, ...]:
    """``per_zeta`` sessions per damping of ``hits`` hits (forces drawn from the grid's, gaps uniform in ``gap_s``),
    then their linear twins. The first hit is at 0.5 s (a pre-trigger, as a session records one)."""
    out = []
    for z in zetas:
        for _ in range(per_zeta):
            rng = np.random.default_rng([seed, len(out)])
            gaps = rng.uniform(*gap_s, hits - 1)
            times = 0.5 + np.concatenate([[0.0], np.cumsum(gaps)])
            f = rng.choice(np.asarray(forces_n, float), hits)
            end = float(np.round(times[-1] + SESSION_TAIL_S, 4))
            out.append(
                SessionCase(
                    tuple(map(float, f)), tuple(map(float, np.round(times, 4))), end, float(z), True, seed + len(out), rig
                )
            )
    return (*out, *(s.linear_twin() for s in out))


def session_exchanges(
    modal_q: np.ndarray,
    modal_energy: np.ndarray,
    fs: float,
    hit_times_s: Sequence[float],
    pulse_s: float,
    work_per_hit: Sequence[float],
    window_s: float = DEFAULT_WINDOW_S,
) -> list[tuple[int, Exchange]]:
    """Major exchanges of a multi-hit record, each with the index of the hit it follows (absolute times)."""
    n = modal_q.shape[0]
    out: list[tuple[int, Exchange]] = []
    for k, h in enumerate(hit_times_s):
        i0 = round(h * fs)
        i1 = round(hit_times_s[k + 1] * fs) if k + 1 < len(hit_times_s) else n
        ex = major_exchanges(modal_q[i0:i1], modal_energy[i0:i1], fs, pulse_s, window_s, input_work=work_per_hit[k])
        off = i0 / fs
        out += [(k, replace(e, start_s=e.start_s + off, end_s=e.end_s + off)) for e in ex]
    return out


def _simulate(s: SessionCase) -> dict[str, np.ndarray]:
    rig = case_rig(s.grid_case)
    pulse = rig.config.hammer.pulse_duration
    force = pulse_train(s.hit_times_s, s.forces_n, pulse)
    res = rig.simulator.run(force, s.duration, rig.sample_rate)
    w = res.energy.input_work[0]
    idx = [min(round((h + pulse) * res.sample_rate) + 1, w.size - 1) for h in s.hit_times_s]
    cum = w[idx]
    return {
        "fs": np.array(res.sample_rate),
        "acc_clean": res.acceleration[0].astype(np.float32),
        "modal_q": np.ascontiguousarray(res.modal_q[0, :, :N_MODES_KEPT]),
        "modal_v": np.ascontiguousarray(res.modal_v[0, :, :N_MODES_KEPT]),
        "mode_frequencies_hz": res.mode_frequencies_hz[:N_MODES_KEPT].copy(),
        "work_per_hit": np.diff(np.concatenate([[0.0], cum])),
    }


def _assemble(s: SessionCase, raw: dict[str, np.ndarray], window_s: float) -> CaseData:
    rig = case_rig(s.grid_case)
    fs = float(raw["fs"])
    clean = np.asarray(raw["acc_clean"], np.float32)
    q, v = np.asarray(raw["modal_q"], float), np.asarray(raw["modal_v"], float)
    fhz = np.asarray(raw["mode_frequencies_hz"], float)
    E = 0.5 * (v**2 + (2 * np.pi * fhz) ** 2 * q**2)
    pulse = float(rig.config.hammer.pulse_duration)
    work = np.asarray(raw["work_per_hit"], float)
    ex = session_exchanges(q, E, fs, s.hit_times_s, pulse, work, window_s)
    empty = np.zeros((clean.shape[0], 0), np.float32)
    return CaseData(
        case=s,  # type: ignore[arg-type]  # duck-types GridCase (zeta, cubic, seed, rig, zeta_rest, name)
        fs=fs,
        t=np.arange(clean.shape[0]) / fs,
        acc=clean.copy(),
        acc_clean=clean,
        disp_true=empty,
        vel_true=empty,
        modal_q=q,
        modal_v=v,
        mode_frequencies_hz=fhz,
        input_work=float(work.sum()),
        pulse_end_s=s.hit_times_s[0] + pulse,
        sensor_x=np.array([c.x_model if c.x_model is not None else np.nan for c in rig.sensors]),
        sensor_names=tuple(c.name for c in rig.sensors),
        noise=0.0,
        window_s=float(window_s),
        exchanges=tuple(e for _, e in ex),
        hit_times_s=tuple(s.hit_times_s),
    )


def hit_of(case: CaseData, t: float) -> int:
    """Index of the last hit at or before ``t`` (-1 before the first)."""
    return int(np.searchsorted(np.asarray(case.hit_times_s), t, side="right")) - 1


def simulate_sessions(
    sessions: Iterable[SessionCase], window_s: float = DEFAULT_WINDOW_S, cache_dir: Path | str | None = DEFAULT_CACHE_DIR
) -> list[CaseData]:
    """Simulate (or load) each session; ``acc`` is the clean record (apply :mod:`errors` for noise)."""
    out = []
    for s in sessions:
        key = f"{s!r}|{_code_hash(s.rig)}|session"
        path = None if cache_dir is None else Path(cache_dir) / f"{s.name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
        raw = _load(path) if path is not None and path.exists() else None
        if raw is None:
            raw = _simulate(s)
            if path is not None:
                _store(path, raw)
        out.append(_assemble(s, raw, window_s))
    return out


def segment(case: CaseData, k: int) -> CaseData:
    """Hit ``k`` of a session as a single-hit record (from its pulse to the next hit), times from the hit."""
    fs = case.fs
    i0 = round(case.hit_times_s[k] * fs)
    i1 = round(case.hit_times_s[k + 1] * fs) if k + 1 < len(case.hit_times_s) else case.t.size
    pulse = case.pulse_end_s - case.hit_times_s[0]
    sl = slice(i0, i1)
    return replace(case, t=np.arange(i1 - i0) / fs, acc=case.acc[sl], acc_clean=case.acc_clean[sl],
                   disp_true=case.disp_true[sl], vel_true=case.vel_true[sl], modal_q=case.modal_q[sl],
                   modal_v=case.modal_v[sl], pulse_end_s=pulse, hit_times_s=(0.0,), exchanges=())  # fmt: skip


def per_hit(detector):
    """A single-hit detector run on each hit's segment of a session (the seed analysed one record per hit, L1320);
    event times moved back onto the session's clock."""

    def run(case: CaseData, **kw) -> list:
        out = []
        for k, h in enumerate(case.hit_times_s):
            for e in detector(segment(case, k), **kw):
                out.append(replace(e, start_s=e.start_s + h, end_s=e.end_s + h))
        return out

    return run
