"""Computational NSI on beam_ch4_sim's tip spring (β = 2, α = 5e8): every estimator/law, and grid sensitivity.

    .venv/bin/python bench/eval_nsi.py [--runs 40] [--pmax 3000]

Simulates ``--runs`` impacts P = logspace(10, pmax) N, 1 s each, all 100 nodes (analysis of the seed, L1251),
reduces each to whole-run δ̄ at the tip and the attachment POM's RQ and temporal frequency
(daq/studies/identify/sweep.py), and fits eq. 5.8: the seed's RQ estimator and the POM frequency, κ = 1 (eq. 5.8 as
printed) and the harmonic-balance κ(β), all points and the weakly nonlinear part (f <= 1.25 f_n); then the
recommended variant on interleaved sub-grids, to show how much α depends on the grid. Prints a table and
writes bench/results/eval_nsi.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from analysis.model.rigs import open_rig
from analysis.nsi_target import resolve_target
from daq.studies.identify.sweep import IdentifyOptions, identify_runs, simulate_runs
from daq.studies.nsi_table import NsiRuns

TRUE_ALPHA, TRUE_BETA = 5e8, 2.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--pmax", type=float, default=3000.0)
    ap.add_argument("--seed-rigs", action="store_true", help="the seed's own rigs (beam_nes_ch5, lo_store_ch6) instead")
    ap.add_argument("--table", action="store_true", help="issue 22's three rigs: frequency x law x fit, errors, R2, time")
    ap.add_argument("--laws", default="seed,hb,exact,modal,modal-exact", help="--table: the laws (comma-separated)")
    ap.add_argument("--freqs", default="rq,pom", help="--table: the frequency estimators (comma-separated)")
    ap.add_argument("--boot", type=int, default=100, help="--table: bootstrap replicates of the POM fits")
    ap.add_argument("--speed", type=int, default=0, metavar="N",
                    help="gvt identify on an N-run sweep's recorded columns against the re-simulating path")  # fmt: skip
    a = ap.parse_args()
    if a.seed_rigs:
        seed_rigs(a.runs)
        return
    if a.table:
        table(a.runs, tuple(a.laws.split(",")), tuple(a.freqs.split(",")), a.boot)
        return
    if a.speed:
        speed(a.speed)
        return
    rig = open_rig("beam_ch4_sim")
    dofs = rig.structure.translational_dofs()
    g = rig.guyan(dofs)
    target = resolve_target(rig, dofs, g.M, g.K)
    t0 = time.perf_counter()
    runs = simulate_runs(rig, np.logspace(1, np.log10(a.pmax), a.runs), 1.0, dofs, target, g.M, g.K)
    sim_s = time.perf_counter() - t0
    rows = []

    def fit(label: str, r: NsiRuns, **kw) -> None:
        t = time.perf_counter()
        f = identify_runs(rig, target, r, IdentifyOptions(n_boot=100, **kw), "bench").fit
        rows.append({"case": label, **kw, "n": f.n_points, "alpha": f.alpha, "beta": f.beta, "r2": f.r2,
                     "alpha_err": f.alpha / TRUE_ALPHA - 1, "beta_err": f.beta / TRUE_BETA - 1,
                     "alpha_ci": f.alpha_ci, "beta_ci": f.beta_ci, "fit_s": time.perf_counter() - t})  # fmt: skip

    for fr in ("rq", "pom"):
        for law in ("seed", "hb"):
            for mr in (None, 1.25):
                fit("all runs", runs, frequency=fr, law=law, max_ratio=mr)
    keys = ("P", "energy", "dbar", "f_rq", "f_pom", "mac", "capture", "pom_index")
    for name, sel in (("every 2nd (0::2)", slice(0, None, 2)), ("every 2nd (1::2)", slice(1, None, 2)),
                      ("every 3rd (0::3)", slice(0, None, 3)), ("every 3rd (1::3)", slice(1, None, 3))):  # fmt: skip
        fit(name, NsiRuns(*(getattr(runs, k)[sel] for k in keys)), frequency="pom", law="hb")
    print(f"{a.runs} runs simulated in {sim_s:.1f} s ({sim_s / a.runs:.2f} s/run); truth alpha 5e8, beta 2")
    print(f"{'case':18} {'freq':4} {'law':4} {'max f/fn':8} {'n':>3} {'alpha':>10} {'err':>8} {'beta':>7} {'err':>7} "
          f"{'R2':>7}  alpha 95% CI")  # fmt: skip
    for r in rows:
        print(f"{r['case']:18} {r['frequency']:4} {r['law']:4} {r.get('max_ratio') or '-'!s:8} {r['n']:3d} "
              f"{r['alpha']:10.4g} {100 * r['alpha_err']:+7.1f}% {r['beta']:7.4f} {100 * r['beta_err']:+6.1f}% "
              f"{r['r2']:7.4f}  {r['alpha_ci'][0]:.3g}-{r['alpha_ci'][1]:.3g}")  # fmt: skip
    out = Path(__file__).parent / "results" / "eval_nsi.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"runs": a.runs, "pmax_N": a.pmax, "simulate_s": sim_s, "fits": rows}, indent=2))
    print(f"wrote {out}")


def seed_rigs(n_runs: int) -> None:
    """Computational NSI on the seed's identification rigs, every estimator/law, and the LO–store capture study.

    beam_nes_ch5 (NES 0.25 kg, α 3e9, β 2; P 0.3–300 N) and lo_store_ch6 hit on the store (α 1.058e10, β 2;
    P 0.1–20 N: up to where its frequency meets the LO's); whole-run δ̄ of 1 s runs. Then the impulse study of
    seed §6.2.2 on the LO: capture onset per force (nsi.capture_track, 0.1 s windows, ratio within 5 %, RMS
    of δ at least 3x the LO's). Writes bench/results/eval_nsi_seed_rigs.json."""
    from analysis import nsi
    from analysis.model.rig import build_rig

    lo = open_rig("lo_store_ch6")
    lo_store_hit = build_rig(lo.config.model_copy(update={"hammer": lo.config.hammer.model_copy(update={"dof": "store"})}))
    cases = (("beam_nes_ch5", open_rig("beam_nes_ch5"), (0.3, 300.0), 3e9), ("lo_store_ch6 (hit on store)", lo_store_hit,
             (0.1, 20.0), 1.058e10))  # fmt: skip
    rows = []
    for label, rig, (p0, p1), alpha in cases:
        dofs = rig.structure.translational_dofs()
        g = rig.guyan(dofs)
        target = resolve_target(rig, dofs, g.M, g.K)
        t0 = time.perf_counter()
        runs = simulate_runs(rig, np.logspace(np.log10(p0), np.log10(p1), n_runs), 1.0, dofs, target, g.M, g.K)
        sim_s = time.perf_counter() - t0
        for fr in ("rq", "pom"):
            for law in ("seed", "hb"):
                f = identify_runs(rig, target, runs, IdentifyOptions(frequency=fr, law=law, n_boot=100), "bench").fit
                rows.append({"rig": label, "frequency": fr, "law": law, "n": f.n_points, "mode": f.mode, "alpha": f.alpha,
                             "beta": f.beta, "r2": f.r2, "alpha_err": f.alpha / alpha - 1, "beta_err": f.beta / 2 - 1,
                             "alpha_ci": f.alpha_ci, "beta_ci": f.beta_ci, "simulate_s": sim_s,
                             "rq_range_hz": [float(np.nanmin(runs.f_rq)), float(np.nanmax(runs.f_rq))],
                             "pom_range_hz": [float(np.nanmin(runs.f_pom)), float(np.nanmax(runs.f_pom))]})  # fmt: skip
    print(f"{n_runs} runs per rig, whole-run dbar, 1 s each")
    print(f"{'rig':28} {'freq':4} {'law':4} {'n':>3} {'mode':13} {'alpha':>10} {'err':>8} {'beta':>7} {'err':>7} {'R2':>7}")
    for r in rows:
        print(f"{r['rig']:28} {r['frequency']:4} {r['law']:4} {r['n']:3d} {r['mode']:13} {r['alpha']:10.4g} "
              f"{100 * r['alpha_err']:+7.1f}% {r['beta']:7.4f} {100 * r['beta_err']:+6.1f}% {r['r2']:7.4f}")  # fmt: skip
    seed_onset = {100.0: None, 600.0: 0.0, 1000.0: 0.5, 3000.0: 1.0}
    forces = [100.0, 300.0, 600.0, 1000.0, 2000.0, 3000.0]
    res = lo.simulator.run(lo.hammer_force(), 3.0, lo.sample_rate, forces)
    i_lo, i_s = res.output_names.index("lo"), res.output_names.index("store")
    cap = []
    print("LO-store impulse on the LO (0.6 ms half-sine): 1:1 capture onset")
    for b, P in enumerate(forces):
        x = res.displacement[b, :, i_lo]
        d = res.displacement[b, :, i_s] - x
        c = nsi.capture_track(d, x, lo.sample_rate, 0.1, 0.05, 3.0)
        peak = float(np.abs(d).max() / np.abs(x).max())
        cap.append({"P_N": P, "onset_s": c.onset_s, "captured_s": float(c.captured.sum() * 0.1),
                    "seed_onset_s": seed_onset.get(P), "peak_store_over_lo": peak})  # fmt: skip
        print(
            f"  {P:6.0f} N: onset {c.onset_s:5.2f} s, captured {c.captured.sum() * 0.1:4.1f} s of 3 s, "
            f"seed {seed_onset.get(P)!s:5}, peak |delta|/|x| {cap[-1]['peak_store_over_lo']:.1f}"
        )
    out = Path(__file__).parent / "results" / "eval_nsi_seed_rigs.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"runs": n_runs, "fits": rows, "capture": cap}, indent=2, default=float))
    print(f"wrote {out}")


RIGS = (  # label, rig (or the LO-store hit on the store), P range [N], true alpha, max f/f_n of the fit (None: all), run s
    ("beam_nes_ch5", "beam_nes_ch5", (0.3, 300.0), 3e9, None, 1.0),
    ("beam_nes_ch5, 4 s runs", "beam_nes_ch5", (0.3, 300.0), 3e9, None, 4.0),
    ("lo_store_ch6 (hit on store)", "lo_store_hit", (0.1, 20.0), 1.058e10, None, 1.0),
    ("beam_ch4_sim", "beam_ch4_sim", (10.0, 3000.0), 5e8, None, 1.0),
    ("beam_ch4_sim, f <= 1.8 f_n", "beam_ch4_sim", (10.0, 3000.0), 5e8, 1.8, 1.0),
)


def _rig(name: str):
    from analysis.model.rig import build_rig

    if name == "lo_store_hit":
        lo = open_rig("lo_store_ch6")
        return build_rig(lo.config.model_copy(update={"hammer": lo.config.hammer.model_copy(update={"dof": "store"})}))
    return open_rig(name)


def table(n_runs: int, laws: tuple[str, ...] = ("seed", "hb", "exact", "modal", "modal-exact"),
          freqs: tuple[str, ...] = ("rq", "pom"), n_boot: int = 100) -> None:  # fmt: skip
    """Issue 22's acceptance table: per rig, frequency (seed RQ / POM) x law (seed eq. 5.8 / HB / exact backbone)
    x fit (intersection eqs. 5.9-5.10 / two-parameter; the modal laws are two-parameter only), whole-run dbar of 1 s
    runs (and 4 s on the NES: ~4 cycles of its 1 Hz mode instead of 1); alpha/beta errors with their bootstrap 95 %
    intervals, R2, fit time. Writes bench/results/eval_nsi_table_RUNS.json (…_RUNS_LAWS.json for a subset of laws)."""
    rows, sims = [], {}
    for label, name, (p0, p1), alpha, mr, dur in RIGS:
        rig = _rig(name)
        dofs = rig.structure.translational_dofs()
        g = rig.guyan(dofs)
        target = resolve_target(rig, dofs, g.M, g.K)
        if (name, dur) not in sims:
            t0 = time.perf_counter()
            sims[name, dur] = (simulate_runs(rig, np.logspace(np.log10(p0), np.log10(p1), n_runs), dur, dofs, target, g.M,
                                             g.K), time.perf_counter() - t0)  # fmt: skip
        runs, sim_s = sims[name, dur]
        for fr in freqs:
            for law in laws:
                for inter in (True, False) if law not in ("modal", "modal-exact") else (False,):
                    t = time.perf_counter()
                    opts = IdentifyOptions(frequency=fr, law=law, intersection=inter, n_boot=n_boot if fr == "pom" else 0,
                                           max_ratio=mr)  # fmt: skip
                    try:
                        f = identify_runs(rig, target, runs, opts, "bench").fit
                    except Exception as exc:  # a failed fit is a table entry
                        rows.append({"rig": label, "frequency": fr, "law": law, "fit": "error", "error": str(exc)})
                        continue
                    if inter and f.mode != "intersection":
                        continue  # no crossing: the same as the two-parameter row
                    rows.append({"rig": label, "frequency": fr, "law": law, "fit": f.mode, "n": f.n_points, "alpha": f.alpha,
                                 "beta": f.beta, "alpha_err": f.alpha / alpha - 1, "beta_err": f.beta / 2 - 1, "r2": f.r2,
                                 "fit_s": time.perf_counter() - t, "simulate_s": sim_s, "runs": n_runs, "run_s": dur,
                                 "alpha_ci": f.alpha_ci, "beta_ci": f.beta_ci})  # fmt: skip
    print(f"{n_runs} runs per rig, whole-run dbar; truth beta = 2")
    print(f"{'rig':30} {'freq':4} {'law':11} {'fit':13} {'n':>3} {'alpha err':>10} {'beta err':>9} {'R2':>7} {'fit s':>6}"
          "  alpha err 95% / beta err 95%")  # fmt: skip
    for r in rows:
        if r["fit"] == "error":
            print(f"{r['rig']:30} {r['frequency']:4} {r['law']:11} error: {r['error']}")
            continue
        a0, a1 = (100 * (x / r["alpha"] * (1 + r["alpha_err"]) - 1) for x in r["alpha_ci"])
        b0, b1 = (100 * (x / 2 - 1) for x in r["beta_ci"])
        print(f"{r['rig']:30} {r['frequency']:4} {r['law']:11} {r['fit']:13} {r['n']:3d} {100 * r['alpha_err']:+9.1f}% "
              f"{100 * r['beta_err']:+8.2f}% {r['r2']:7.4f} {r['fit_s']:6.2f}  [{a0:+.1f}, {a1:+.1f}] / "
              f"[{b0:+.2f}, {b1:+.2f}]")  # fmt: skip
    tag = "" if set(laws) >= {"seed", "hb", "exact"} and set(freqs) == {"rq", "pom"} else "_" + "_".join(laws)
    out = Path(__file__).parent / "results" / f"eval_nsi_table_{n_runs}{tag}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"runs": n_runs, "rows": rows}, indent=2, default=float))
    print(f"wrote {out}")


def speed(n_runs: int) -> None:
    """``gvt identify SWEEP_DIR`` on an ``n_runs`` sweep of beam_nes_ch5 (P 0.3-300 N, 1 s) whose nsi.csv the sweep
    wrote, against the re-simulating path (no nsi.csv, as an old sweep) on a 40-run sweep in the same process.
    Writes bench/results/eval_nsi_speed.json."""
    import os
    import subprocess
    import tempfile

    gvt = str(Path(__file__).resolve().parents[1] / ".venv" / "bin" / "gvt")
    res: dict = {"runs": n_runs, "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        for n, key in ((n_runs, "big"), (40, "small")):
            d = Path(tmp) / key
            t0 = time.perf_counter()
            subprocess.run([gvt, "sweep", "beam_nes_ch5", "--out", str(d), "--n", str(n), "--pmin", "0.3", "--pmax", "300"],
                           check=True, capture_output=True)  # fmt: skip
            res[f"{key}_sweep_s"] = time.perf_counter() - t0
            if key == "small":
                (d / "nsi.csv").unlink()  # an old sweep: identify re-simulates
            t0 = time.perf_counter()
            p = subprocess.run([gvt, "identify", str(d), "--rig", "beam_nes_ch5", "--frequency", "pom", "--law", "exact",
                                "--json"], check=True, capture_output=True, text=True)  # fmt: skip
            res[f"{key}_identify_s"] = time.perf_counter() - t0
            res[f"{key}_source"] = json.loads(p.stdout)["source"]
    print(json.dumps(res, indent=2))
    out = Path(__file__).parent / "results" / "eval_nsi_speed.json"
    out.write_text(json.dumps(res, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
