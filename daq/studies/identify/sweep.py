"""``gvt identify``: the seed's NSI (§5.1) on a force sweep of a rig — whole-run δ̄ and RQ-FDP, eq. 5.8 fit.

A sweep directory written by ``gvt sweep`` holds each run's P, input energy and RQ frequencies but not δ̄ nor
the POMs (``daq/studies/sweep.py`` keeps moments only). The NSI needs both, so the sweep's runs (its rig, P grid,
duration and outputs from ``sweep.json``) are re-simulated here, one at a time in bounded memory, each reduced
to δ̄ (eq. 5.2), its whole-record POD (eq. 2.12–2.13), the attachment's POM by MAC (eq. 5.6), its RQ frequency
(eq. 2.18) and the frequency of its temporal coefficient; the per-run table is written beside the sweep as
``nsi.csv`` and read back on the next call instead of simulating again.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis import nsi
from analysis.errors import BadInput
from analysis.model.rig import Rig
from analysis.nsi_quality import MIN_POINTS, FitRange, choose_fit_range, judge
from analysis.nsi_target import Target, resolve_target
from daq.studies.nsi_table import NSI_CSV, NsiRuns, read_runs, write_runs


def simulate_runs(
    rig: Rig,
    amplitudes: np.ndarray,
    duration: float,
    output_dofs: list[int],
    target: Target,
    M: np.ndarray,
    K: np.ndarray,
    order: int | None = None,
    n_poms: int = 8,
    progress: Callable[[str, float], None] | None = None,
) -> NsiRuns:
    """Simulate each amplitude (the sweep's own integrator, ``analysis.model.sweep._run_record``) and reduce it.

    Everything is computed in the simulator's reduced coordinates q (x = P q at the outputs): the 1/n output
    covariance P cov(q) Pᵀ (eq. 2.12) for the POD, δ = (row_att − mean rows_refs) q for δ̄, the POM's temporal
    coefficient (q − q̄) Pᵀψ for its frequency. Memory: one run's q, q̇ (~6 MB for 1 s of beam_ch4_sim)."""
    from analysis.model.rig_sim import rig_simulator
    from analysis.model.sweep import NsiProbe, _run_record

    t0 = time.perf_counter()
    sim = rig_simulator(rig, output_dofs, order)
    force = rig.hammer_force()
    fs = rig.sample_rate
    n, model, fdesc, stepping, amps = sim._prepare(force, duration, fs, amplitudes)
    n_r = model[0].shape[0]
    bufs = (np.empty((n, n_r)), np.empty((n, n_r)), np.empty((n, model[3].shape[0])), np.empty(n), np.empty(n))
    probe = NsiProbe.build(sim, target.attachment, target.relative_to, target.model.shape, M, K, n_poms)
    B = amps.size
    out = {k: np.zeros(B) for k in ("energy", "dbar", "f_rq", "f_pom", "mac")}
    cap = np.zeros(B, bool)
    pidx = np.zeros(B, np.int64)
    for b in range(B):
        work, _, _, _ = _run_record(float(amps[b]), model, fdesc, stepping, *bufs)
        r = probe.reduce(bufs[0], fs)  # the sweep's own reduction (analysis.model.sweep.NSI_FIELDS)
        out["energy"][b] = work
        out["dbar"][b], out["f_rq"][b], out["f_pom"][b], out["mac"][b] = r[0], r[1], r[2], r[3]
        cap[b] = r[4] > 0
        pidx[b] = int(r[5])
        if progress:
            progress("simulating the sweep's runs for δ̄", (b + 1) / B)
    return NsiRuns(amps, out["energy"], out["dbar"], out["f_rq"], out["f_pom"], out["mac"], cap, pidx,
                   time.perf_counter() - t0)  # fmt: skip


def read_sweep_spec(sweep_dir: Path) -> dict[str, Any]:
    p = sweep_dir / "sweep.json"
    try:
        s = json.loads(p.read_text())
        return {k: s[k] for k in ("rig", "runs", "pmin_N", "pmax_N", "duration_s", "outputs", "order")}
    except FileNotFoundError:
        raise BadInput(f"{sweep_dir}: no sweep.json; give a directory written by 'gvt sweep'") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BadInput(f"{p}: not a gvt sweep summary ({exc})") from None


@dataclass
class IdentifyOptions:
    frequency: str = "rq"  # "rq" (the seed's, eq. 2.18) or "pom" (the POM's temporal coefficient)
    law: str = "seed"  # eq. 5.8 as printed ("seed"), with the harmonic-balance factor ("hb"), the exact backbone ("exact")
    max_ratio: float | None = None  # fit only points with f <= max_ratio * f_n (None: the range the data give)
    auto_range: bool = False  # with max_ratio None: analysis.nsi_quality.choose_fit_range (opt-in: D49); else every point
    smooth: int = 5
    intersection: bool = True
    n_boot: int = 200
    seed: int = 0

    def validate(self) -> None:
        if self.frequency not in ("rq", "pom"):
            raise BadInput(f"--frequency must be 'rq' or 'pom', got {self.frequency!r}")
        if self.law not in ("seed", "hb", "exact", *nsi.MODAL_KINDS):
            raise BadInput(f"--law must be 'seed' (eq. 5.8), 'hb', 'exact', 'modal' or 'modal-exact', got {self.law!r}")
        if self.max_ratio is not None and not self.max_ratio > 1:
            raise BadInput(f"--max-ratio must exceed 1 (a frequency above the linear one), got {self.max_ratio:g}")
        if self.smooth < 1 or self.smooth % 2 == 0:
            raise BadInput(f"--smooth must be a positive odd number of points, got {self.smooth}")
        if self.n_boot < 0:
            raise BadInput(f"--boot must be >= 0, got {self.n_boot}")


_LAW_TEXT = {
    "modal": "attachment mode of the rig's lowest linear modes + one-harmonic k_eq = kappa_hb alpha dbar^beta across the spring",
    "modal-exact": "as modal, k_eq times the one-mass exact/HB backbone ratio at the same k_eq/k",
}


@dataclass
class Identification:
    rig: str
    target: Target
    runs: NsiRuns
    fdp: nsi.RqFdp
    fit: nsi.PowerLawFit
    options: IdentifyOptions
    excluded_above: int
    source: str
    fit_range: FitRange | None = None
    fitted: np.ndarray | None = None  # (points,) bool over the δ̄-sorted RQ-FDP: the points the law was fitted on

    def fitted_forces(self) -> np.ndarray:
        """The peak forces of the runs (or windows' hits) the law was fitted on: where it may be validated."""
        mask = self.fitted if self.fitted is not None else self.fdp.fit_mask
        return np.asarray(self.runs.P, float)[self.fdp.order[mask]]

    def problems(self) -> list[str]:
        """What makes this fit poor (``analysis.nsi_quality.judge``); validation is judged where it runs."""
        return judge(self.fit)

    def summary(self) -> dict[str, Any]:
        t = self.target
        f = self.fit
        return {
            "rig": self.rig,
            "source": self.source,
            "attachment": t.description,
            "linear_mode": t.model.mode + 1,
            "f_n_hz": t.model.omega_n / (2 * np.pi),
            "mass_kg": t.model.mass,
            "mass_source": t.model.mass_source,
            "frequency": self.options.frequency,
            "law": _LAW_TEXT.get(
                self.options.law,
                "f = sqrt(w_n^2 + kappa (alpha/m) dbar^beta) / 2pi, kappa = "
                + {"seed": "1 (seed eq. 5.8)", "hb": "HB factor"}.get(self.options.law, "exact one-DOF backbone (no kappa)"),
            ),
            "smoothing": f"running median of {self.fdp.smooth_window} points on the dbar-sorted, capture-free curve",
            "runs": int(self.runs.P.size),
            "capture_runs": int(self.runs.capture.sum()),
            "excluded_above_max_ratio": self.excluded_above,
            "fit_range": None if self.fit_range is None else self.fit_range.to_dict(),
            "fit": f.to_dict(),
            "rotational": t.model.rotational(t.model.mass * f.omega_n**2, f.alpha, f.beta),  # eq. 6.13 form, or None
        }


def identify_runs(rig: Rig, target: Target, runs: NsiRuns, options: IdentifyOptions, source: str) -> Identification:
    """RQ-FDP of the runs (capture marked) → eq. 5.8 fit (intersection when the curve crosses a linear mode)."""
    options.validate()
    freq = runs.f_rq if options.frequency == "rq" else runs.f_pom
    fdp = nsi.rq_fdp(runs.dbar, freq, runs.mac, runs.capture, options.smooth)
    keep = fdp.fit_mask
    modal = target.model.modal_basis() if options.law in nsi.MODAL_KINDS else None
    settings = nsi.FitSettings(kappa=options.law, use_intersection=options.intersection, n_boot=options.n_boot,  # type: ignore[arg-type]
                               seed=options.seed, modal=modal)  # fmt: skip
    keep, rng = _fit_range(fdp, keep, target, options, settings)
    fit = nsi.fit_power_law(fdp.dbar[keep], fdp.smooth[keep], target.model.omega_n, target.model.mass,
                            target.model.f_linear_hz, settings)  # fmt: skip
    return Identification(rig.name, target, runs, fdp, fit, options, rng.n_total - rng.n_points, source, rng, keep)


def _fit_range(fdp: nsi.RqFdp, keep: np.ndarray, target: Target, options: IdentifyOptions,
               settings: nsi.FitSettings) -> tuple[np.ndarray, FitRange]:  # fmt: skip
    """The points fitted: those below ``--max-ratio`` when given, else the range the data give
    (``analysis.nsi_quality.choose_fit_range``), else (``--all-points``) every capture-free point."""
    m = target.model
    f_n = m.omega_n / (2 * np.pi)
    idx = np.flatnonzero(keep)  # δ̄-sorted
    d, f = fdp.dbar[idx], fdp.smooth[idx]
    sel = np.ones(idx.size, bool)
    if options.max_ratio is not None:
        sel = f <= options.max_ratio * f_n
        how, why = "max-ratio", f"points above --max-ratio {options.max_ratio:g} left out"
    elif options.auto_range and idx.size > MIN_POINTS:
        r = choose_fit_range(d, f, m.omega_n, m.mass, settings)
        sel[r.n_points :] = False
        how, why = r.how, r.stopped
    else:
        how, why = "all", "every capture-free point (--auto-range or --max-ratio choose a range)"
    top = float(f[sel].max()) if sel.any() else 0.0
    rng = FitRange(int(sel.sum()), int(idx.size), float(d[sel].max()) if sel.any() else 0.0, top, top / f_n, how, why)
    out = np.zeros(keep.size, bool)
    out[idx[sel]] = True
    return out, rng


def identify_sweep(
    rig: Rig, sweep_dir: Path, options: IdentifyOptions, progress: Callable[[str, float], None] | None = None
) -> Identification:
    """``gvt identify SWEEP_DIR``: the sweep's runs (``nsi.csv`` if present, else simulated and cached)."""
    from analysis.model.rig_sim import output_dofs

    spec = read_sweep_spec(sweep_dir)
    if spec["rig"] != rig.name:
        raise BadInput(f"{sweep_dir}: the sweep is of rig {spec['rig']!r}, not {rig.name!r}")
    dofs = output_dofs(rig, spec["outputs"])
    g = rig.guyan(dofs)
    target = resolve_target(rig, dofs, g.M, g.K)
    cache = sweep_dir / NSI_CSV
    if cache.exists():
        runs = read_runs(cache)
        source = f"{cache} ({runs.P.size} runs)"
    else:
        amps = np.logspace(np.log10(spec["pmin_N"]), np.log10(spec["pmax_N"]), int(spec["runs"]))
        runs = simulate_runs(rig, amps, float(spec["duration_s"]), dofs, target, g.M, g.K, spec["order"], progress=progress)
        write_runs(runs, cache)
        source = f"{sweep_dir}: {runs.P.size} runs re-simulated in {runs.wall_s:.1f} s, cached in {cache}"
    return identify_runs(rig, target, runs, options, source)


def plot_fdp(ident: Identification, path: Path) -> None:
    """The RQ-FDP like seed Fig. 5.5: raw points (capture in gray), the smoothed curve, the fit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from daq.outputs import atomic_output

    fdp, fit = ident.fdp, ident.fit
    fig, ax = plt.subplots(figsize=(7.5, 5), dpi=110)
    c = fdp.capture
    ax.plot(fdp.dbar[~c], fdp.freq_hz[~c], ".", color="k", ms=4, label="runs or windows")
    if c.any():
        ax.plot(fdp.dbar[c], fdp.freq_hz[c], ".", color="0.6", ms=4, label="1:1 capture (excluded)")
    ax.plot(fdp.dbar, fdp.smooth, "-", color="tab:blue", lw=1, label=f"running median ({fdp.smooth_window})")
    d = np.geomspace(max(fdp.dbar[fdp.dbar > 0].min(), 1e-12), fdp.dbar.max(), 200)
    ax.plot(d, fit.predict_hz(d), "-", color="tab:red", lw=1.5,
            label=f"fit: α = {fit.alpha:.4g}, β = {fit.beta:.4f}, R² = {fit.r2:.4f}")  # fmt: skip
    for f in ident.target.model.f_linear_hz[:2]:
        ax.axhline(f, color="tab:green", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("characteristic displacement δ̄ [m]")
    ax.set_ylabel(f"{'RQ' if ident.options.frequency == 'rq' else 'POM'} frequency [Hz]")
    ax.set_title(f"{ident.rig}: RQ frequency–displacement plot, attachment {ident.target.description}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def summary_json(ident: Identification) -> str:
    from daq.outputs import jsonable

    return json.dumps(ident.summary(), default=jsonable)


def print_report(console, ident: Identification) -> None:
    from rich.table import Table

    f = ident.fit
    m = ident.target.model
    t = Table(title=f"{ident.rig}: identified attachment law α|δ|^β δ ({f.mode}, {f.n_points} points)")
    for col in ("parameter", "value", "95 % bootstrap", "sd"):
        t.add_column(col, justify="right")
    t.add_row("α [N/m^(β+1)]", f"{f.alpha:.5g}", f"{f.alpha_ci[0]:.4g} – {f.alpha_ci[1]:.4g}", f"{f.alpha_sd:.3g}")
    t.add_row("β", f"{f.beta:.5f}", f"{f.beta_ci[0]:.4f} – {f.beta_ci[1]:.4f}", f"{f.beta_sd:.3g}")
    t.add_row("R²", f"{f.r2:.5f}", "", "")
    console.print(t)
    console.print(
        f"attachment {ident.target.description}: linear mode {m.mode + 1}, f_n = {m.omega_n / (2 * np.pi):.4f} Hz, "
        + (
            f"m = {m.mass:.5g} kg ({m.mass_source}); "
            if ident.options.law not in nsi.MODAL_KINDS
            else "the rig's modes carry the mass (modal law); "
        )
        + f"frequency: {ident.options.frequency}, law: {ident.options.law}; "
        f"{int(ident.runs.capture.sum())} capture runs excluded; source {ident.source}",
        markup=False,
    )
    if ident.fit_range is not None:
        console.print(ident.fit_range.line(), markup=False)
