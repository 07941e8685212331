"""``gvt sweep``: the seed's computational study (§4.2, L1195–L1315) on a rig.

Force amplitudes P = logspace(pmin, pmax, n) (L1215), one impact each; per run the 1/n covariance of the
output displacements (whole record, eq. 2.12) → POMs (eq. 2.13) → RQ frequency of every POM with the
rig's Guyan-reduced M, K at the output DOFs (eqs. 2.17–2.18), the lowest four kept (L1251) → the RQ-FEP
against input energy, its low/high-energy asymptotes checked against the fixed-free and fixed-pinned
(springs pinned, L1244) frequencies, and the partnered spikes flagged (L1253–L1259, L1393).

Every flag is re-checked by replacing its peak run with runs at P·(1 ± 1e-6): in the strongly nonlinear
band a 1 ppm change of P can move RQ2 by 60 % (docs/simulator.md §3), so a spike that such a change
removes is a property of that one trajectory, not of the structure; the flag says which it is.

Per run the sweep also measures the mean frequencies of the two lowest linear modes from their modal phase
advance (``analysis.model.sweep.ModalProbe``): the RQ uses the linear K, without the tip spring, so the RQ
ratio is not the NNMs' frequency ratio (docs/sweep.md). Every flag carries the label from that modal ratio
beside the RQ one, and plateaus of the modal ratio at an m:n are reported as locks (``analysis.rqfep.find_locks``).

A second stage (``analysis.sweep_capture``) re-simulates a few runs where the modal ratio passes within a
tolerance of a seed ratio m:n and runs the seed's slow-flow test on them (Φ_{m:n} non-time-like, its
neighbours bracketing it, L1296–L1298); a confirmed one is reported as ``kind = "capture"``. It runs in this
process after the Dask cluster has closed: a handful of runs at ~0.25 s each (docs/sweep.md has the cost).
"""

from __future__ import annotations

import csv
import json
import resource
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.model.modal import structure_modes
from analysis.model.rig import Rig
from analysis.model.rig_sim import output_dofs, rig_simulator
from analysis.model.simulate import ImpactSimulator, MomentResult
from analysis.model.sweep import (
    MODAL_WINDOW_NAMES,
    ModalProbe,
    NsiProbe,
    SweepMoments,
    run_modal_phases,
    run_with_modal_phase,
    sweep_moments,
)
from analysis.rqfep import (
    RatioLock,
    SpikeSettings,
    SweepInteraction,
    find_locks,
    flag_interactions,
    pod_from_covariance,
    pov_gaps,
    rq_fep,
)
from analysis.sweep_capture import CaptureReport, CaptureSettings, confirm_captures
from daq.outputs import atomic_output, jsonable

N_KEEP = 4  # "the RQ-FEP for the first four POMs" (L1251)
JITTER = 1e-6  # relative change of P for the robustness re-check (docs/simulator.md §3: "1 ppm")
ASYMPTOTE_TOL = 0.02  # the acceptance: asymptotes within 2 %


@dataclass(frozen=True)
class SweepSpec:
    pmin: float = 1e1
    pmax: float = 1e12
    n: int = 200
    duration: float = 1.0
    outputs: str = "translational"  # or "sensors"
    order: int | None = None  # None: the rig's simulation.order
    scheduler: str | None = None
    workers: int = 2
    edge_fraction: float = 0.05  # runs at each end of the sweep used for the asymptote check
    settings: SpikeSettings = field(default_factory=SpikeSettings)
    capture: CaptureSettings = field(default_factory=CaptureSettings)

    def validate(self) -> None:
        """Raise ValueError with one line for anything a user can fix."""
        if not (np.isfinite(self.pmin) and np.isfinite(self.pmax)) or self.pmin <= 0:
            raise ValueError(f"--pmin must be a positive number of newtons, got {self.pmin:g}")
        if self.pmin >= self.pmax:
            raise ValueError(f"--pmin ({self.pmin:g}) must be smaller than --pmax ({self.pmax:g})")
        if self.n < 2:
            raise ValueError(f"--n must be at least 2, got {self.n}")
        if self.duration <= 0:
            raise ValueError(f"--duration must be positive, got {self.duration:g}")
        if self.outputs not in ("translational", "sensors"):
            raise ValueError(f"--outputs must be 'translational' or 'sensors', got {self.outputs!r}")
        if self.order not in (None, 2, 4):
            raise ValueError(f"--order must be 2 or 4, got {self.order}")
        if self.workers < 1:
            raise ValueError(f"--workers must be at least 1, got {self.workers}")

    @property
    def amplitudes(self) -> np.ndarray:
        return np.logspace(np.log10(self.pmin), np.log10(self.pmax), self.n)


@dataclass
class SweepReport:
    rig: str
    spec: SweepSpec
    output_dofs: list[int]
    result: MomentResult
    freqs: np.ndarray  # (runs, N_KEEP) Hz
    fixed_free_hz: np.ndarray
    fixed_pinned_hz: np.ndarray
    asymptotes: list[dict[str, Any]]
    flags: list[SweepInteraction]
    robust: list[bool]
    wall_s: float
    peak_rss_mb: float
    locks: list[RatioLock] = field(default_factory=list)
    capture: CaptureReport | None = None  # the slow-flow stage (None: not run, or no modal ratio)

    @property
    def captures(self) -> list:
        """Confirmed slow-flow captures (``analysis.sweep_capture.SweepCapture``, ``kind = "capture"``)."""
        return [] if self.capture is None else self.capture.captures

    @property
    def modal_hz(self) -> np.ndarray | None:
        """(runs, n_windows, 2) mean frequencies of linear modes 1–2 from their phase advance, or None."""
        return getattr(self.result, "modal_freq_hz", None)

    @property
    def modal_ratio(self) -> np.ndarray | None:
        """Per-run f2/f1 of the modal phase advance over the whole-record window (``MODAL_WINDOWS_S[0]``)."""
        return _modal_ratio(self.result)

    def summary(self) -> dict[str, Any]:
        s = self.spec
        return {
            "rig": self.rig,
            "runs": s.n,
            "pmin_N": s.pmin,
            "pmax_N": s.pmax,
            "duration_s": s.duration,
            "outputs": s.outputs,
            "n_outputs": len(self.output_dofs),
            "order": s.order,
            "workers": s.workers,
            "scheduler": s.scheduler or "local",
            "wall_s": self.wall_s,
            "peak_rss_client_mb": self.peak_rss_mb,
            "input_energy_range_J": [float(self.result.input_work.min()), float(self.result.input_work.max())],
            "substep_cap_hits_total": int(self.result.substep_cap_hits.sum()),
            "fixed_free_hz": self.fixed_free_hz.tolist(),
            "fixed_pinned_hz": self.fixed_pinned_hz.tolist(),
            "asymptotes": self.asymptotes,
            "asymptote_warnings": asymptote_warnings(self.asymptotes),
            "spike_settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(s.settings).items()},
            "interactions": [dict(f.to_dict(), robust_1ppm=r) for f, r in zip(self.flags, self.robust, strict=True)],
            "modal_windows_s": dict(
                zip(MODAL_WINDOW_NAMES, map(list, getattr(self.result, "modal_windows_s", ())), strict=False)
            ),
            "locks": [lk.to_dict() for lk in self.locks],
            "capture_settings": asdict(s.capture),
            "captures": [c.to_dict() for c in self.captures],
            "capture_stage": None if self.capture is None else {
                k: v for k, v in self.capture.to_dict().items() if k != "captures"},
        }


def limit_frequencies(rig: Rig, count: int = N_KEEP) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-free (linear structure) and fixed-pinned (springs pinned) natural frequencies, Hz (L1244)."""
    lo = structure_modes(rig.limit_structure("low")).frequencies_hz[:count]
    hi = structure_modes(rig.limit_structure("high")).frequencies_hz[:count]
    return np.asarray(lo), np.asarray(hi)


def asymptote_errors(
    freqs: np.ndarray, ref_low: np.ndarray, ref_high: np.ndarray, edge_fraction: float, gaps: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """Median RQ of the lowest- and highest-P ``edge_fraction`` of the runs against the limit frequencies.

    The median (not the last point): in the high band the lowest RQs scatter upward whenever two POVs
    nearly coincide and the POD mixes the modes (docs/sweep.md), and the median is robust to that.
    The minimum is reported beside it: contamination by higher modes only raises an RQ (Rayleigh's
    principle), so the lower envelope is what approaches the pinned frequency.

    How far to trust the verdict: the edge runs' interquartile range relative to the median (``spread``). Where it is
    wider than the pass band itself (±``ASYMPTOTE_TOL``: 4 %), which runs the sweep happened to draw decides the
    verdict, not the structure (``decided`` False; :func:`asymptote_warnings` says so in one line). ``gaps`` (runs,
    k): the POV separation behind each RQ (:func:`analysis.rqfep.pov_gaps`), whose smallest over the edge runs is
    reported as why (``pov_gap_min``). Measured: ``beam_ch4_sim``'s high-end NNM3 on 24 runs was 113 Hz on one BLAS
    thread and 181 Hz on two (its 3 edge runs 112.5 / 181.2 / 190.9 Hz, IQR 21 %, smallest POV gap 0.9 %): a rounding
    difference grows on those strongly nonlinear records, and the POD mixes the modes of nearly equal POVs.
    """
    runs, k = freqs.shape
    m = max(2, int(np.rint(edge_fraction * runs)))
    rows = []
    for end, ref, sl in (("low", ref_low, slice(0, m)), ("high", ref_high, slice(runs - m, runs))):
        for j in range(min(k, len(ref))):
            f = freqs[sl, j]
            med = float(np.median(f))
            mn = float(np.min(f))
            q25, q75 = (float(v) for v in np.percentile(f, [25, 75]))
            spread = (q75 - q25) / med if med > 0 else float("inf")
            rows.append(
                {
                    "end": end,
                    "nnm": j + 1,
                    "runs": m,
                    "reference_hz": float(ref[j]),
                    "median_hz": med,
                    "min_hz": mn,
                    "max_hz": float(np.max(f)),
                    "error_median": med / float(ref[j]) - 1.0,
                    "error_min": mn / float(ref[j]) - 1.0,
                    "pass": abs(med / float(ref[j]) - 1.0) <= ASYMPTOTE_TOL,
                    "spread": spread,
                    "decided": bool(spread <= 2 * ASYMPTOTE_TOL),
                    "pov_gap_min": None if gaps is None else float(np.min(gaps[sl, j])),
                }
            )
    return rows


def asymptote_warnings(rows: list[dict[str, Any]]) -> list[str]:
    """One line per asymptote whose edge runs disagree by more than the pass band (:func:`asymptote_errors`)."""
    out = []
    for a in rows:
        if a.get("decided", True):
            continue
        why = "" if a.get("pov_gap_min") is None else (
            f"; the smallest POV gap behind them is {100 * a['pov_gap_min']:.1f} %, and the POD mixes modes of nearly "
            "equal POVs")  # fmt: skip
        out.append(
            f"{a['end']}-energy NNM{a['nnm']}: its {a['runs']} edge runs' RQs span "
            f"{a['min_hz']:.2f}-{a['max_hz']:.2f} Hz (interquartile {100 * a['spread']:.0f} % of the median, wider than "
            f"the +-{100 * ASYMPTOTE_TOL:.0f} % check){why}: the median {a['median_hz']:.2f} Hz and its verdict are one "
            "draw, not the structure's (docs/sweep.md)"
        )
    return out


def run_sweep(
    rig: Rig, spec: SweepSpec, progress: Callable[[str, float], None] | None = None
) -> SweepReport:
    """Simulate, POD + RQ per run, asymptotes, flags with their 1 ppm re-check."""
    spec.validate()
    dofs = output_dofs(rig, spec.outputs)
    if len(dofs) < N_KEEP:
        raise ValueError(f"{rig.name}: {len(dofs)} output DOFs, the RQ-FEP needs at least {N_KEEP} POMs")
    sim = rig_simulator(rig, dofs, spec.order)
    spec = SweepSpec(**{**vars(spec), "order": sim.order})
    force = rig.hammer_force()
    g = rig.guyan(dofs)
    probe = ModalProbe.from_guyan(g.M, g.K, 2)  # linear modes 1–2 at the outputs (eq. 2.15)
    nsi_probe = _nsi_probe(rig, sim, dofs, g)
    t0 = time.perf_counter()
    with warnings.catch_warnings():  # distributed's "port 8787 in use" for a dashboard we do not use
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        res = _sweep(sim, force, spec, rig.sample_rate, progress, probe, nsi_probe)
    poms, povs = pod_from_covariance(res.covariance)
    freqs = rq_fep(poms, g.M, g.K, N_KEEP)
    gaps = pov_gaps(povs, poms, g.M, g.K, N_KEEP)
    mratio = _modal_ratio(res)
    flags = flag_interactions(res.input_work, freqs, spec.settings, res.amplitudes, mratio)
    locks = find_locks(res.input_work, mratio, spec.settings, res.amplitudes) if spec.settings.lock and mratio is not None else []
    robust = []
    for k, fl in enumerate(flags):
        if progress:
            progress("re-checking flags at P (1 ± 1 ppm)", k / len(flags))
        robust.append(_survives_jitter(sim, force, spec, rig.sample_rate, g, res, freqs, fl, probe))
    cap = None
    if spec.capture.capture and mratio is not None:
        def phases(p: float) -> tuple[float, np.ndarray]:
            return run_modal_phases(sim, force, spec.duration, rig.sample_rate, p, probe)

        cap = confirm_captures(res.input_work, mratio, res.amplitudes, phases, rig.sample_rate, spec.capture,
                               progress=(lambda d, t: progress("slow-flow test at candidate passages", d / t)) if progress
                               else None)  # fmt: skip
    wall = time.perf_counter() - t0
    lo, hi = limit_frequencies(rig)
    return SweepReport(
        rig=rig.name,
        spec=spec,
        output_dofs=dofs,
        result=res,
        freqs=freqs,
        fixed_free_hz=lo,
        fixed_pinned_hz=hi,
        asymptotes=asymptote_errors(freqs, lo, hi, spec.edge_fraction, gaps),
        flags=flags,
        robust=robust,
        wall_s=wall,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        locks=locks,
        capture=cap,
    )


def _modal_ratio(res: MomentResult) -> np.ndarray | None:
    """Per-run f2/f1 of the modal phase advance over the whole-record window, or None without a probe."""
    m = getattr(res, "modal_freq_hz", None)
    return None if m is None else m[:, 0, 1] / m[:, 0, 0]


def _nsi_probe(rig: Rig, sim: ImpactSimulator, dofs: list[int], g) -> NsiProbe | None:
    """The per-run NSI reduction ``gvt identify`` reads (nsi.csv) when the rig has an attachment ([nsi] or a
    nonlinear spring at the outputs); None otherwise (the sweep is then as before)."""
    from analysis.errors import BadInput
    from analysis.nsi_target import resolve_target

    try:
        t = resolve_target(rig, dofs, g.M, g.K)
    except BadInput:
        return None
    return NsiProbe.build(sim, t.attachment, t.relative_to, t.model.shape, g.M, g.K)


def _sweep(sim: ImpactSimulator, force, spec: SweepSpec, fs: float, progress, probe: ModalProbe | None = None,
           nsi_probe: NsiProbe | None = None) -> SweepMoments:  # fmt: skip
    return sweep_moments(
        sim,
        force,
        spec.amplitudes,
        spec.duration,
        fs,
        scheduler=spec.scheduler,
        n_workers=spec.workers,
        chunk_size=max(1, min(20, spec.n // (4 * spec.workers))),
        progress=(lambda d, t: progress("simulating", d / t)) if progress else None,
        probe=probe,
        nsi_probe=nsi_probe,
    )


def _survives_jitter(
    sim, force, spec: SweepSpec, fs: float, g, res: MomentResult, freqs: np.ndarray, fl, probe: ModalProbe | None = None
) -> bool:
    """Replace the flag's peak run by P·(1 − 1e-6) and by P·(1 + 1e-6): is the point still flagged both times?"""
    i = fl.i_peak
    p = float(res.amplitudes[i])
    amps = [p * (1 - JITTER), p * (1 + JITTER)]
    jit = run_with_modal_phase(sim, force, spec.duration, fs, np.asarray(amps), probe) if probe else \
        sim.run_moments(force, spec.duration, fs, amps)  # fmt: skip
    fj = rq_fep(pod_from_covariance(jit.covariance)[0], g.M, g.K, N_KEEP)
    mr, mj = _modal_ratio(res), _modal_ratio(jit)
    for r in range(2):
        f2 = freqs.copy()
        e2 = res.input_work.copy()
        f2[i] = fj[r]
        e2[i] = jit.input_work[r]
        m2 = None
        if mr is not None and mj is not None:
            m2 = mr.copy()
            m2[i] = mj[r]
        again = flag_interactions(e2, f2, spec.settings, res.amplitudes, m2)
        if not any(a.energy_lo <= e2[i] <= a.energy_hi for a in again):  # events are contiguous in energy
            return False
    return True


def summary_json(rep: SweepReport) -> str:
    return json.dumps(rep.summary(), default=jsonable)


def write_outputs(rep: SweepReport, out_dir: Path) -> dict[str, Path]:
    """DIR/rqfep.csv, DIR/rqfep.png, DIR/sweep.json (each written to a temporary file, then renamed: a full disk
    leaves the previous file and no temporary one, :func:`daq.outputs.atomic_output`), and DIR/nsi.csv
    (the per-run NSI columns ``gvt identify`` reads instead of re-simulating) when the rig has an attachment."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out_dir / "rqfep.csv", "png": out_dir / "rqfep.png", "json": out_dir / "sweep.json"}
    res = rep.result
    cols = getattr(res, "nsi", None)
    if cols is not None:
        from daq.studies.nsi_table import NSI_CSV, NsiRuns, write_runs

        paths["nsi"] = out_dir / NSI_CSV
        write_runs(NsiRuns(res.amplitudes, res.input_work, cols[:, 0], cols[:, 1], cols[:, 2], cols[:, 3], cols[:, 4] > 0,
                           cols[:, 5].astype(np.int64)), paths["nsi"])  # fmt: skip
    mod, mratio = rep.modal_hz, rep.modal_ratio
    mcols = [] if mod is None else [f"f{j + 1}_modal{'' if w == 'whole' else '_' + w}_hz"
                                    for w in MODAL_WINDOW_NAMES[: mod.shape[1]] for j in range(2)] + ["modal_ratio"]  # fmt: skip
    with atomic_output(paths["csv"]) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["P_N", "input_energy_J", *[f"f{j + 1}_hz" for j in range(rep.freqs.shape[1])], "substep_cap_hits", *mcols])
        for k in range(res.amplitudes.size):
            extra = [] if mod is None else [*[f"{x:.6f}" for x in mod[k].ravel()], f"{mratio[k]:.6f}"]
            w.writerow(
                [
                    f"{res.amplitudes[k]:.9g}",
                    f"{res.input_work[k]:.9g}",
                    *[f"{x:.6f}" for x in rep.freqs[k]],
                    int(res.substep_cap_hits[k]),
                    *extra,
                ]
            )
    plot_rqfep(rep, paths["png"])
    with atomic_output(paths["json"]) as tmp:
        tmp.write_text(json.dumps(rep.summary(), indent=2, default=jsonable))
    return paths


def plot_rqfep(rep: SweepReport, path: Path) -> None:
    """The RQ-FEP like seed Fig. 4.4: RQ of the first four POMs against log input energy, fixed-free
    (black dashed) and fixed-pinned (gray dashed) frequencies, flagged interactions circled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = rep.result.input_work
    order = np.argsort(e)
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=110)
    for f in rep.fixed_free_hz:
        ax.axhline(f, color="black", ls="--", lw=0.8)
    for f in rep.fixed_pinned_hz:
        ax.axhline(f, color="0.6", ls="--", lw=0.8)
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:purple"]
    for j in range(rep.freqs.shape[1]):
        ax.plot(e[order], rep.freqs[order, j], ".", ms=2.5, color=colors[j % 4], label=f"POM {j + 1}")
    for fl, ok in zip(rep.flags, rep.robust, strict=True):
        i = fl.i_peak
        ax.plot([e[i], e[i]], rep.freqs[i, :2], "o", mfc="none", mec="red" if ok else "salmon", ms=8)
        text = fl.label + ("" if fl.modal_label is None else f" (RQ {fl.rq_label})")
        ax.annotate(text + (" band" if fl.kind == "band" else "") + ("" if ok else "?"), (e[i], rep.freqs[i, 1]),
                    color="red", fontsize=8,
                    xytext=(3, 6), textcoords="offset points")
    for lk in rep.locks:
        ax.axvspan(lk.energy_lo, lk.energy_hi, color="tab:green", alpha=0.15, lw=0)
        ax.annotate(f"{lk.label} lock", (lk.energy_lo, 2.0), color="darkgreen", fontsize=8, rotation=90, va="bottom")
    for cp in rep.captures:  # slow-flow captures: a magenta diamond on POM 1 at every confirmed run
        idx = cp.confirmed_indices
        ax.plot(e[idx], rep.freqs[idx, 0], "D", mfc="none", mec="magenta", ms=7, mew=1.2)
        ax.annotate(cp.label, (e[cp.i_peak], rep.freqs[cp.i_peak, 0]), color="darkmagenta", fontsize=7,
                    rotation=90, xytext=(0, 8), textcoords="offset points", va="bottom", ha="center")  # fmt: skip
    ax.set_xscale("log")
    top = max(float(np.max(rep.fixed_pinned_hz)), float(np.max(rep.fixed_free_hz))) * 1.25
    ax.set_ylim(0, top)
    ax.set_xlabel("input energy [J]")
    ax.set_ylabel("RQ frequency [Hz]")
    ax.set_title(
        f"{rep.rig}: RQ-FEP, {rep.spec.n} runs, P = {rep.spec.pmin:g} … {rep.spec.pmax:g} N\n"
        "black: fixed-free, gray: fixed-pinned; green: modal-ratio lock; magenta \u25c7: slow-flow capture (on POM 1)\n"
        "red: flagged NNM1–NNM2 interaction, m:n from the modal ratio, RQ label in brackets (? = not robust to 1 ppm of P)",
        fontsize=9,
    )
    ax.legend(loc="upper left", fontsize=8, markerscale=3)
    fig.tight_layout()
    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)


def _span(lo: float, hi: float, fmt: str) -> str:
    return f"{lo:{fmt}}" + ("" if hi == lo else f"–{hi:{fmt}}")


def report_tables(rep: SweepReport, width: int | None = None) -> list:
    """The terminal tables of a sweep (asymptotes, flags, locks, captures), each fitting ``width`` (default:
    the console's): wide ones continue in a second part that repeats their key columns."""
    tables = [_asymptote_table(rep, width), _flag_table(rep, width)]
    if rep.modal_hz is not None:  # the locks are plateaus of the modal ratio: none without the modal probe
        tables.append(_lock_table(rep, width))
    if rep.capture is not None:
        tables.append(_capture_table(rep, width))
    return tables


def _asymptote_table(rep: SweepReport, width: int | None):
    """The RQ at each end of the sweep against the fixed-free and fixed-pinned frequencies (L1244)."""
    from daq.terminal import Col, FitTable

    t = FitTable(
        f"{rep.rig}: RQ asymptotes (median of {rep.asymptotes[0]['runs']} runs at each end)",
        [Col("end", key=True), Col("NNM", "right", key=True), Col("limit [Hz]", "right"), Col("RQ median [Hz]", "right"),
         Col("error", "right"), Col("RQ min [Hz]", "right"), Col("within 2 %", "right"), Col("runs agree", "right")],
        width=width,
    )  # fmt: skip
    for a in rep.asymptotes:
        t.add_row(
            "fixed-free" if a["end"] == "low" else "fixed-pinned",
            a["nnm"],
            f"{a['reference_hz']:.3f}",
            f"{a['median_hz']:.3f}",
            f"{100 * a['error_median']:+.2f} %",
            f"{a['min_hz']:.3f}",
            "yes" if a["pass"] else "NO",
            "yes" if a.get("decided", True) else f"NO (IQR {100 * a['spread']:.0f} %)",
        )
    return t


def _flag_table(rep: SweepReport, width: int | None):
    """The flagged NNM1–NNM2 interactions, with both labels (RQ and modal ratio) and the 1 ppm re-check."""
    from daq.terminal import Col, FitTable

    t = FitTable(
        f"flagged NNM1–NNM2 interactions ({len(rep.flags)})",
        [Col("kind", key=True), Col("P [N]", "right", key=True), Col("energy [J]", "right"), Col("points", "right"),
         Col("RQ f1 / f2 at peak [Hz]", "right"), Col("RQ f2/f1 below / above", "right"), Col("m:n RQ", "right"),
         Col("modal f2/f1 below / peak / above", "right"), Col("m:n modal", "right"), Col("gap closed", "right"),
         Col("1 ppm", "right")],
        width=width,
    )  # fmt: skip
    for f, ok in zip(rep.flags, rep.robust, strict=True):
        t.add_row(
            f.kind,
            _span(f.p_lo, f.p_hi, ".4g"),
            _span(f.energy_lo, f.energy_hi, ".3g"),
            f.n_points,
            f"{f.f1_hz:.2f} / {f.f2_hz:.2f}",
            f"{f.ratio_left:.2f} / {f.ratio_right:.2f}",
            f.rq_label + ("" if f.bracketed else " (nearest)"),
            None if f.modal_label is None else f"{f.modal_ratio_left:.2f} / {f.modal_ratio_peak:.2f} / {f.modal_ratio_right:.2f}",
            None if f.modal_label is None else f.modal_label + ("" if f.modal_bracketed else " (nearest)"),
            f"{100 * f.score:.0f} %",
            "robust" if ok else "not robust",
        )
    return t


def _lock_table(rep: SweepReport, width: int | None):
    """The plateaus of the modal ratio at an m:n, with the rule that found them in the title."""
    from daq.terminal import Col, FitTable

    s = rep.spec.settings
    t = FitTable(
        f"modal-ratio locks ({len(rep.locks)}): |f2/f1 − m/n| ≤ {100 * s.lock_tol:g} % over ≥ {s.lock_min_points} "
        f"points, slope ≤ {s.lock_flatness:g} × each side's",
        [Col("kind", key=True), Col("m:n", key=True), Col("P [N]", "right"), Col("energy [J]", "right"),
         Col("points", "right"), Col("modal f2/f1 mean (min–max)", "right"),
         Col("slope in / below / above [per decade of E]", "right")],
        width=width,
    )  # fmt: skip
    for lk in rep.locks:
        t.add_row(lk.kind, lk.label, f"{lk.p_lo:.4g}–{lk.p_hi:.4g}", f"{lk.energy_lo:.3g}–{lk.energy_hi:.3g}",
                  lk.n_points, f"{lk.ratio_mean:.3f} ({lk.ratio_min:.3f}–{lk.ratio_max:.3f})",
                  f"{lk.slope_in:.3f} / {lk.slope_below:.3f} / {lk.slope_above:.3f}")  # fmt: skip
    return t


def _capture_table(rep: SweepReport, width: int | None):
    """The slow-flow stage's confirmed captures, with what it tested (and left untested) in the title."""
    from daq.terminal import Col, FitTable

    c = rep.capture
    g = rep.spec.capture.end_guard_s
    t = FitTable(
        f"slow-flow captures ({len(c.captures)}): Φ_m:n non-time-like (reversals ≥ {g:g} s from the record ends), "
        f"(m∓1):n bracketing (slowflow.test_ratios); {c.runs} runs re-simulated at {len(c.passages)} passages "
        f"within {100 * rep.spec.capture.passage_tol:g} % of m:n, {len(c.untested)} untested, {c.wall_s:.1f} s",
        [Col("kind", key=True), Col("m:n", key=True), Col("P [N] confirmed", "right", key=True),
         Col("energy [J]", "right"), Col("runs ok / tested", "right"), Col("passage P [N]", "right"),
         Col("passage f2/f1", "right"), Col("interval [s]", "right"), Col("chain [s]", "right"),
         Col("strength", "right"), Col("reversals", "right"), Col("Φ range [rad]", "right"),
         Col("Φ̇ (m−1) / (m+1) [rad/s]", "right")],
        width=width,
    )  # fmt: skip
    for cp in c.captures:
        br = list(cp.bracket.values())
        t.add_row(cp.kind, cp.label, _span(cp.p_lo, cp.p_hi, ".4g"), _span(cp.energy_lo, cp.energy_hi, ".3g"),
                  f"{cp.n_confirmed} / {cp.n_tested}", f"{cp.passage_p[0]:.4g}–{cp.passage_p[1]:.4g}",
                  f"{cp.passage_ratio[0]:.3f}–{cp.passage_ratio[1]:.3f}",
                  f"{cp.interval_s[0]:.2f}–{cp.interval_s[1]:.2f}", f"{cp.chain_s[0]:.2f}–{cp.chain_s[1]:.2f}",
                  f"{cp.strength:.2f}", cp.sign_changes, f"{cp.phase_range:.2f}",
                  " / ".join(f"{v:+.0f}" for v in br))  # fmt: skip
    return t


def print_report(console, rep: SweepReport, paths: dict[str, Path], width: int | None = None) -> None:
    for t in report_tables(rep, width):
        console.print(t)
    caps = int(rep.result.substep_cap_hits.sum())
    console.print(
        f"{rep.spec.n} runs x {rep.spec.duration:g} s, {len(rep.output_dofs)} outputs, order {rep.spec.order}, "
        f"in {rep.wall_s:.1f} s; sub-step cap hit in {caps} output intervals; wrote {paths['csv']}, {paths['png']}, "
        f"{paths['json']}",
        markup=False,
    )
