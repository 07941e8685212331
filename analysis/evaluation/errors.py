"""Errors every real test has, applied to simulated hits as a DAQ and a test campaign would see them (issue 21, item 7).

The grid of :mod:`analysis.evaluation.grid` gives a detector clean physics plus 1 % noise and a
perfect model. A lab gives it more: noisier sensors, sensitivities off by a few percent, a dead
channel, sensors a few mm from where the model puts them, a model whose stiffness and attachment are
off by several percent. Each error is a small pure function of a :class:`CaseData` (or of its rig),
seeded, returning a new case (``dataclasses.replace``): the truth (modal coordinates, exchanges)
never changes, only what the detector sees (``acc``) or the model it is handed (``model_rig``).

Order of the measurement chain (as a DAQ sees it): the physical acceleration at the sensor's real
position, plus the sensor's noise, times the channel's sensitivity error (a gain error scales the
noise too, it is downstream of the transducer); a dead channel replaces the whole chain.

* **Noise** (:func:`with_noise`): per channel Gaussian, standard deviation ``level`` times the clean
  channel's RMS over the first ``ref_s`` seconds (2 s, the seed's record length L1320). For a 2 s
  record this is exactly the grid's noise (same generator, same draws); for longer records the noise
  stays a property of the sensor and the hit, not of the record length (``ref_s=None`` takes the
  whole record, the grid's rule, which makes a long record's noise *smaller*).
* **Sensitivity errors** (:func:`sensitivity_gains`): per channel, gain ``1 + u``, ``u`` uniform in
  ``±pct %``; the detector divides by the nominal sensitivity, so it sees the channel scaled by the gain.
* **Dead channel** (:func:`kill_channels`): a disconnected IEPE input reads the ADC's own noise only:
  zero plus Gaussian noise at ``DEAD_NOISE_REL`` of the live channel's noise standard deviation.
* **Sensor position offsets** (:func:`simulate_offset_cases`): the data come from sensors moved by a
  few mm while the detector's model keeps the nominal nodes. The FE displacement field inside a beam
  element *is* the Hermite-cubic interpolation of its nodal ``w, theta`` (analysis/model/beam.py), so
  the simulator is asked for ``w`` and ``theta`` at the two nodes of the element holding each moved
  position and the response there is interpolated with the shape functions: exact for the FE model,
  no remeshing (a remesh would snap a few-mm move back onto the 7 mm mesh's node).
* **FE model errors** (:func:`model_error_rig`): the detector's model built from the case's rig with
  Young's modulus, the attachment's linear spring and the attachment's point mass scaled; the data
  come from the true rig. The detectors take it as ``model_rig`` (analysis/evaluation/detectors.py).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from analysis.evaluation.grid import (
    DEFAULT_CACHE_DIR,
    DEFAULT_DURATION_S,
    CaseData,
    GridCase,
    _assemble,
    _code_hash,
    cached_raws,
    case_rig,
    rig_data,
    rig_toml,
)
from analysis.evaluation.truth import DEFAULT_WINDOW_S
from analysis.model.config import RigConfig
from analysis.model.loader import validate
from analysis.model.rig import Rig, build_rig

DEAD_NOISE_REL = 1e-3  # a dead channel's noise / the live channel's noise: the ADC's floor
NOISE_REF_S = DEFAULT_DURATION_S
ATTACHMENT_CHANNEL = "a13"  # beam_ch4_exp's accelerometer at the attachment (0.700 m, L69)
AWAY_CHANNEL = "a07"  # mid-beam (0.378 m), far from the attachment


def _rng(case: CaseData, stream: int) -> np.random.Generator:
    """A generator per case and error kind; stream 0 is the grid's own noise generator."""
    return np.random.default_rng(case.case.seed if stream == 0 else [case.case.seed, stream])


def noise_std(clean: np.ndarray, level: float, fs: float, ref_s: float | None = NOISE_REF_S) -> np.ndarray:
    """Per-channel noise standard deviation: ``level`` x the clean RMS over the first ``ref_s`` s (None: all)."""
    x = np.asarray(clean, dtype=float)
    if ref_s is not None:
        x = x[: max(1, round(ref_s * fs))]
    return level * np.sqrt(np.mean(x**2, axis=0))


def with_noise(case: CaseData, level: float, ref_s: float | None = NOISE_REF_S) -> CaseData:
    """``acc`` = clean acceleration + Gaussian noise of ``level`` (see the module docstring), seeded by the case."""
    if level < 0:
        raise ValueError("noise level must be >= 0")
    std = noise_std(case.acc_clean, level, case.fs, ref_s)
    rng = _rng(case, 0)
    acc = (case.acc_clean + rng.standard_normal(case.acc_clean.shape) * std).astype(np.float32)
    return replace(case, acc=acc, noise=float(level), noise_std=std)


def sensitivity_gains(n_channels: int, pct: float, rng: np.random.Generator) -> np.ndarray:
    """Per-channel gains ``1 + u``, ``u ~ U(-pct, +pct) %``: measured / true sensitivity of each channel."""
    return 1.0 + rng.uniform(-pct, pct, n_channels) / 100.0


def with_gains(case: CaseData, gains: Sequence[float] | np.ndarray) -> CaseData:
    """Every channel of ``acc`` (signal and noise) times its gain."""
    g = np.asarray(gains, dtype=float)
    if g.shape != (case.acc.shape[1],):
        raise ValueError(f"one gain per channel ({case.acc.shape[1]}), got {g.shape}")
    return replace(case, acc=(case.acc * g).astype(np.float32), noise_std=case.noise_std * np.abs(g))


def with_gain_errors(case: CaseData, pct: float) -> CaseData:
    """Seeded ``±pct %`` sensitivity errors (a new draw per case: the grid samples many calibrations)."""
    return with_gains(case, sensitivity_gains(case.acc.shape[1], pct, _rng(case, 1)))


def kill_channels(case: CaseData, names: Iterable[str]) -> CaseData:
    """The named channels dead: zero plus the ADC's noise (``DEAD_NOISE_REL`` of the live noise)."""
    names = list(names)
    unknown = [n for n in names if n not in case.sensor_names]
    if unknown:
        raise ValueError(f"no channel {unknown[0]!r}; channels are {', '.join(case.sensor_names)}")
    acc = case.acc.copy()
    rng = _rng(case, 2)
    std = case.noise_std if case.noise_std.size else np.full(acc.shape[1], 1e-3)
    for n in names:
        k = case.sensor_names.index(n)
        acc[:, k] = (rng.standard_normal(acc.shape[0]) * DEAD_NOISE_REL * max(float(std[k]), 1e-12)).astype(np.float32)
    return replace(case, acc=acc)


@dataclass(frozen=True)
class Measured:
    """One realistic measurement of a case: noise, sensitivity errors, dead channels (applied in that order)."""

    noise: float = 0.01
    gain_pct: float = 0.0
    dead: tuple[str, ...] = ()
    noise_ref_s: float | None = NOISE_REF_S

    def __call__(self, case: CaseData) -> CaseData:
        c = with_noise(case, self.noise, self.noise_ref_s)
        if self.gain_pct:
            c = with_gain_errors(c, self.gain_pct)
        if self.dead:
            c = kill_channels(c, self.dead)
        return c


# --- sensor position offsets ------------------------------------------------------------------------


def hermite(xi: float, le: float) -> np.ndarray:
    """Hermite-cubic shape functions at ``xi`` in [0, 1] of an element of length ``le``: weights of (w1, th1, w2, th2)."""
    return np.array([1 - 3 * xi**2 + 2 * xi**3, le * (xi - 2 * xi**2 + xi**3), 3 * xi**2 - 2 * xi**3, le * (xi**3 - xi**2)])


def position_offsets(rig: Rig, max_mm: float, seed: int = 0) -> np.ndarray:
    """Seeded offsets (m), uniform in ``±max_mm``, one per sensor; kept on the beam (a sensor at an end moves inward)."""
    rng = np.random.default_rng([seed, 3])
    dx = rng.uniform(-max_mm, max_mm, len(rig.sensors)) * 1e-3
    mesh = rig.structure.mesh
    if mesh is None:
        raise ValueError("position offsets need a beam rig")
    x = np.array([s.x_model for s in rig.sensors], float)
    return np.where(x + dx > mesh.length, -np.abs(dx), np.where(x + dx < 0, np.abs(dx), dx))


def interpolation_matrix(rig: Rig, offsets_m: Sequence[float]) -> tuple[list[int], np.ndarray]:
    """Output DOFs and the matrix ``T`` (n_sensors, n_dofs) with response at the moved sensors = ``T @ dof response``.

    A constrained DOF (a clamp) has zero response and is left out.
    """
    mesh = rig.structure.mesh
    if mesh is None:
        raise ValueError("position offsets need a beam rig")
    le = mesh.element_length
    names = {d.name: i for i, d in enumerate(rig.structure.dofs)}
    rows: list[dict[int, float]] = []
    for s, dx in zip(rig.sensors, offsets_m, strict=True):
        x = float(np.clip(s.x_model + dx, 0.0, mesh.length))
        e = int(min(np.floor(x / le), mesh.n_elements - 1))
        w = hermite((x - e * le) / le, le)
        row: dict[int, float] = {}
        for wt, name in zip(w, (f"w{e}", f"theta{e}", f"w{e + 1}", f"theta{e + 1}"), strict=True):
            if name in names:
                row[names[name]] = row.get(names[name], 0.0) + float(wt)
        rows.append(row)
    dofs = sorted({d for r in rows for d in r})
    T = np.zeros((len(rows), len(dofs)))
    for i, r in enumerate(rows):
        for d, wt in r.items():
            T[i, dofs.index(d)] = wt
    return dofs, T


def _offset_simulate(cases: Sequence[GridCase], duration: float, offsets: np.ndarray) -> list[dict[str, np.ndarray]]:
    from analysis.model.simulate import ImpactSimulator

    rig = case_rig(cases[0])
    dofs, T = interpolation_matrix(rig, offsets)
    sim = rig.config.simulation
    simulator = ImpactSimulator(rig.structure, rig.hammer.dof, dofs, cutoff_hz=sim.modal_cutoff_hz,
                                residual_vectors=sim.residual_vectors, max_omega_dt=sim.max_omega_dt, order=sim.order,
                                modes=rig.modes)  # fmt: skip
    res = simulator.run(rig.hammer_force(1.0), duration, rig.sample_rate, amplitudes=[c.force_n for c in cases])
    out = []
    for b in range(len(cases)):
        out.append(
            {
                "fs": np.array(res.sample_rate),
                "acc_clean": (res.acceleration[b] @ T.T).astype(np.float32),
                "disp_true": (res.displacement[b] @ T.T).astype(np.float32),
                "vel_true": (res.velocity[b] @ T.T).astype(np.float32),
                "modal_q": np.ascontiguousarray(res.modal_q[b, :, :4]),
                "modal_v": np.ascontiguousarray(res.modal_v[b, :, :4]),
                "mode_frequencies_hz": res.mode_frequencies_hz[:4].copy(),
                "input_work": np.array(res.energy.input_work[b, -1]),
            }
        )
    return out


def simulate_offset_cases(
    cases: Iterable[GridCase],
    offsets_m: Sequence[float] | np.ndarray,
    duration: float = DEFAULT_DURATION_S,
    window_s: float = DEFAULT_WINDOW_S,
    cache_dir: Path | str | None = DEFAULT_CACHE_DIR,
    batch: int = 6,
) -> list[CaseData]:
    """Cases whose sensors sit ``offsets_m`` (one per sensor) from their nominal nodes; 1 % noise as the grid.

    ``sensor_x`` stays nominal (what the detector's model assumes); the truth is the same as the
    nominal case's (the modal coordinates do not depend on where the response is read).
    """
    cases = list(cases)
    off = np.asarray(offsets_m, dtype=float)
    cdir = None if cache_dir is None else Path(cache_dir)

    def path(c: GridCase) -> Path:
        key = f"{c.force_n!r}|{c.zeta!r}|{c.cubic}|{duration!r}|{_code_hash(c.rig)}|{off.tobytes().hex()}|offsets"
        return cdir / f"{c.name}-pos-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"  # type: ignore[operator]

    def simulate(group: list[GridCase]) -> tuple[list[dict[str, np.ndarray]], float]:
        return _offset_simulate(group, duration, off), float("nan")

    raws, _ = cached_raws(cases, None if cdir is None else path, simulate, batch)
    return [_assemble(c, raws[i], 0.01, window_s, float("nan"), True) for i, c in enumerate(cases)]


# --- FE model errors ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelError:
    """Relative errors of the detector's model: Young's modulus, the attachment's linear spring and point mass."""

    E: float = 0.0
    k: float = 0.0
    m: float = 0.0

    @classmethod
    def draw(cls, pct: float, seed: int) -> ModelError:
        """Each parameter off by ``u ~ U(-pct, +pct) %`` (seeded)."""
        u = np.random.default_rng([seed, 4]).uniform(-pct, pct, 3) / 100.0
        return cls(float(u[0]), float(u[1]), float(u[2]))


def model_error_rig(case: GridCase, err: ModelError) -> Rig:
    """The case's rig (same damping, same cubic spring) with ``E``, every linear spring and point mass scaled.

    This is the model a detector is handed (``model_rig``); the data still come from :func:`case_rig`.
    """
    data = rig_data(case.zeta, case.cubic, case.rig)
    data["structure"] = {**data["structure"], "youngs_modulus": data["structure"]["youngs_modulus"] * (1 + err.E)}
    data["springs"] = [{**s, "k": s["k"] * (1 + err.k)} for s in data.get("springs", [])]
    data["point_masses"] = [{**p, "mass": p["mass"] * (1 + err.m)} for p in data.get("point_masses", [])]
    path = rig_toml(case.rig)
    return build_rig(validate(RigConfig, data, path), path)


# --- interference and wiring faults (issue 29, item 6) --------------------------------------------------------

#: relative amplitudes of the mains fundamental and its harmonics 2-4 (odd-dominated pickup has the 3rd strong too;
#: the split matters little: each line is found and removed on its own)
HUM_PROFILE = (1.0, 0.5, 0.35, 0.25)


def hum_amplitudes(rms: float, profile: Sequence[float] = HUM_PROFILE) -> np.ndarray:
    """Amplitudes of the lines in ``profile``'s proportions whose sum has the RMS ``rms``."""
    p = np.asarray(profile, float)
    return p * rms / np.sqrt(0.5 * np.sum(p**2))


def with_hum(
    case: CaseData, level: float, f0: float = 50.0, channels: Iterable[str] | None = None,
    profile: Sequence[float] = HUM_PROFILE, ref_s: float | None = NOISE_REF_S,
) -> CaseData:  # fmt: skip
    """Mains hum added to ``acc``: ``f0`` and its harmonics (``profile``), RMS = ``level`` x the clean channel's RMS over
    the first ``ref_s`` s (as :func:`with_noise`), on ``channels`` (None: all), a seeded phase per channel and line
    (pickup through each cable differs in phase). The generator is the simulated DAQ's (analysis/lines.py)."""
    from analysis.lines import hum_waveform

    names = case.sensor_names if channels is None else list(channels)
    unknown = [n for n in names if n not in case.sensor_names]
    if unknown:
        raise ValueError(f"no channel {unknown[0]!r}; channels are {', '.join(case.sensor_names)}")
    first = round(case.hit_times_s[0] * case.fs)  # the RMS of the response, not of a quiet pre-trigger
    rms = noise_std(case.acc_clean[first:], 1.0, case.fs, ref_s)
    rng = _rng(case, 5)
    acc = case.acc.astype(np.float64)
    for name in names:
        k = case.sensor_names.index(name)
        amps = hum_amplitudes(level * float(rms[k]), profile)
        acc[:, k] += hum_waveform(acc.shape[0], case.fs, f0, amps, rng.uniform(0, 2 * np.pi, len(amps)))
    return replace(case, acc=acc.astype(np.float32))


def flip_polarity(case: CaseData, names: Iterable[str]) -> CaseData:
    """The named channels read with their sign reversed (a sensor mounted upside down, a swapped cable pair)."""
    acc = case.acc.copy()
    for n in names:
        acc[:, case.sensor_names.index(n)] *= -1
    return replace(case, acc=acc)


def stick_channels(case: CaseData, names: Iterable[str], value: float = 0.37) -> CaseData:
    """The named channels frozen at ``value`` (SI), a constant non-zero reading (a hung ADC or IEPE bias fault)."""
    acc = case.acc.copy()
    for n in names:
        acc[:, case.sensor_names.index(n)] = np.float32(value)
    return replace(case, acc=acc)


def with_pretrigger(case: CaseData, seconds: float) -> CaseData:
    """``seconds`` of the structure at rest before the hit: what the analysis lane of a session sees before its first hit
    (a session streams from its start; the grid's records start at the pulse). The rest reads the sensors' noise
    (``noise_std``, a draw of its own); every time (hits, pulse end, truth intervals) moves by ``seconds``. Apply after
    the noise and before interference that runs through the whole record (:func:`with_hum`)."""
    n = round(seconds * case.fs)
    if n <= 0:
        return case
    pre = (_rng(case, 6).standard_normal((n, case.acc.shape[1])) * case.noise_std).astype(np.float32)

    def rest(a: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros((n, *a.shape[1:]), a.dtype), a]) if a.size else a

    dt = n / case.fs
    return replace(
        case, t=np.arange(case.t.size + n) / case.fs, acc=np.concatenate([pre, case.acc]), acc_clean=rest(case.acc_clean),
        disp_true=rest(case.disp_true), vel_true=rest(case.vel_true), modal_q=rest(case.modal_q), modal_v=rest(case.modal_v),
        pulse_end_s=case.pulse_end_s + dt, hit_times_s=tuple(h + dt for h in case.hit_times_s),
        exchanges=tuple(replace(e, start_s=e.start_s + dt, end_s=e.end_s + dt) for e in case.exchanges),
    )  # fmt: skip
