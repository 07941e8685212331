"""Simulator benchmark (issue: foundation). Prints a table, writes bench/results/bench_simulator.json.

1. One hit on ``beam_ch4_exp``: 1 s of response at 16384 Hz on one core (target <= 0.1 s).
2. Baseline in the same run: scipy ``solve_ivp`` (LSODA) on the same reduced model, a few amplitudes
   from linear to strongly nonlinear; ratio of times and maximum difference of the responses.
3. The seed's sweep: ``beam_ch4_sim``, P = logspace(1, 12, 1000), 1 s each, 100 displacement outputs at
   16384 Hz, keeping per run only the 100x100 covariance, mean and input work; Dask local cluster with
   2 single-threaded workers (target <= 300 s), peak memory of the client and the workers.

    python bench/bench_simulator.py [--runs 1000] [--quick]
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import time
from pathlib import Path

import numba
import numpy as np

from analysis.model.reference import reference_reduced
from analysis.model.rig import load_rig
from analysis.model.simulate import ImpactSimulator
from analysis.model.sweep import sweep_moments
from analysis.rayleigh import rayleigh_quotient_hz

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"


def timeit(fn, repeat: int = 5) -> float:
    fn()  # warm-up (compilation, caches)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_single(rig, repeat: int) -> dict:
    numba.set_num_threads(1)
    sim = rig.simulator
    force = rig.hammer_force()
    t_full = timeit(lambda: sim.run(force, 1.0, rig.sample_rate), repeat)
    t_mom = timeit(lambda: sim.run_moments(force, 1.0, rig.sample_rate, [force.peak]), repeat)
    sim4 = ImpactSimulator(rig.structure, rig.hammer.dof, rig.sensor_dofs, order=4, modes=rig.modes)
    t_o4 = timeit(lambda: sim4.run(force, 1.0, rig.sample_rate), repeat)
    return {
        "rig": rig.name,
        "duration_s": 1.0,
        "sample_rate": rig.sample_rate,
        "n_basis": sim.reduced.n_basis,
        "steps_per_sample": sim.steps_per_sample(rig.sample_rate),
        "time_full_outputs_s": t_full,
        "time_order4_s": t_o4,
        "time_moments_only_s": t_mom,
        "target_s": 0.1,
        "realtime_factor": 1.0 / t_full,
        "pass": t_full <= 0.1,
    }


def _rq4(cov, guyan) -> np.ndarray:
    """RQ frequencies (Hz) of the 4 lowest-RQ POMs of a displacement covariance (seed eqs. 2.13, 2.17-2.18)."""
    _, U = np.linalg.eigh(cov)
    return np.sort(rayleigh_quotient_hz(U, guyan.K, guyan.M))[:4]


def bench_baseline(rig, amplitudes, duration: float) -> list[dict]:
    """Ours against solve_ivp (LSODA, rtol 1e-10) on the same reduced model, same process."""
    numba.set_num_threads(1)
    sim = rig.simulator
    guyan = rig.guyan()
    rows = []
    for a in amplitudes:
        force = rig.hammer_force(a)
        ours = timeit(lambda f=force: sim.run(f, duration, rig.sample_rate), 3)
        res = sim.run(force, duration, rig.sample_rate)
        d = res.displacement[0]
        t0 = time.perf_counter()
        ref = reference_reduced(sim, force, duration, rig.sample_rate, method="LSODA", rtol=1e-10)
        t_ref = time.perf_counter() - t0
        row = {
            "rig": rig.name,
            "peak_force_N": float(a),
            "duration_s": duration,
            "order": sim.order,
            "steps_per_sample": float(res.steps_per_sample[0]),
            "time_ours_s": ours,
            "time_solve_ivp_lsoda_s": t_ref,
            "speedup": t_ref / ours,
            "max_abs_diff_m": float(np.max(np.abs(d - ref))),
            "max_rel_diff": float(np.max(np.abs(d - ref)) / np.max(np.abs(ref))),
        }
        if len(rig.sensors) >= 8:  # enough DOFs for POD + RQ: compare what the sweep is for
            f_ours = _rq4(np.cov(d.T, bias=True), guyan)
            f_ref = _rq4(np.cov(ref.T, bias=True), guyan)
            row["rq4_ref_hz"] = f_ref.tolist()
            row["rq4_max_rel_diff"] = float(np.max(np.abs(f_ours / f_ref - 1)))
        rows.append(row)
    return rows


def bench_sweep(rig, n_runs: int) -> dict:
    sim = rig.simulator
    amps = np.logspace(1, 12, n_runs)
    last = [0.0]
    t0 = time.perf_counter()

    def progress(done: int, total: int) -> None:
        now = time.perf_counter() - t0
        if now - last[0] > 10 or done == total:
            print(f"  sweep: {done}/{total} runs, {now:.0f} s", flush=True)
            last[0] = now

    res = sweep_moments(
        sim,
        rig.hammer_force(),
        amps,
        rig.config.daq.record_length,
        rig.sample_rate,
        n_workers=2,
        chunk_size=max(1, n_runs // 40),
        progress=progress,
    )
    wall = time.perf_counter() - t0
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    main = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {
        "rig": rig.name,
        "runs": n_runs,
        "duration_s": rig.config.daq.record_length,
        "sample_rate": rig.sample_rate,
        "outputs": len(res.output_names),
        "wall_s": wall,
        "target_s": 300.0,
        "pass": wall <= 300.0,
        "per_run_ms_per_worker": 2 * 1000 * wall / n_runs,
        "peak_rss_client_mb": main,
        "peak_rss_largest_worker_mb": children,
        "result_bytes": int(res.covariance.nbytes + res.mean.nbytes + res.input_work.nbytes),
        "input_work_range_J": [float(res.input_work.min()), float(res.input_work.max())],
        "order": sim.order,
        "steps_per_sample_median_max": [float(np.median(res.steps_per_sample)), float(res.steps_per_sample.max())],
        "substep_cap_hits_total": int(res.substep_cap_hits.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=1000, help="amplitudes in the sweep")
    ap.add_argument("--quick", action="store_true", help="fewer repeats and a 100-run sweep")
    args = ap.parse_args()
    n_runs = 100 if args.quick else args.runs
    exp = load_rig(ROOT / "configs/rigs/beam_ch4_exp.toml")
    sim4 = load_rig(ROOT / "configs/rigs/beam_ch4_sim.toml")
    print("1) one hit, beam_ch4_exp, 1 s at 16384 Hz, one core", flush=True)
    single = bench_single(exp, 3 if args.quick else 7)
    print("2) baseline: solve_ivp LSODA on the same reduced model", flush=True)
    base = bench_baseline(exp, [30.0, 500.0, exp.config.hammer.peak_force], 1.0)
    base += bench_baseline(sim4, [1e2, 1e4, 1e5, 1e8], 0.25 if args.quick else 1.0)
    print(f"3) sweep, beam_ch4_sim, {n_runs} amplitudes x 1 s, Dask 2 workers", flush=True)
    sweep = bench_sweep(sim4, n_runs)

    print()
    print(f"{'case':58s} {'value':>12s} {'target':>10s}")
    print(f"{'1 s beam_ch4_exp @16384 Hz, 1 core, full outputs [s]':58s} {single['time_full_outputs_s']:12.4f} {'<= 0.1':>10s}")
    print(f"{'  same, moments only [s]':58s} {single['time_moments_only_s']:12.4f}")
    print(f"{'  same, order 4 (100x smaller error) [s]':58s} {single['time_order4_s']:12.4f}")
    print(f"{'  faster than real time [x]':58s} {single['realtime_factor']:12.1f} {'>= 10':>10s}")
    for r in base:
        label = f"solve_ivp/ours, {r['rig']} P={r['peak_force_N']:g} N, {r['duration_s']:g} s"
        extra = f", RQ1-4 {100 * r['rq4_max_rel_diff']:.2g} %" if "rq4_max_rel_diff" in r else ""
        print(f"{label:58s} {r['speedup']:12.1f}   max diff {r['max_rel_diff']:.2e} of peak{extra}")
    label = f"sweep {n_runs} x 1 s, 100 outputs, 2 workers [s]"
    print(f"{label:58s} {sweep['wall_s']:12.1f} {'<= 300':>10s}")
    rss = f"{sweep['peak_rss_client_mb']:.0f} / {sweep['peak_rss_largest_worker_mb']:.0f}"
    print(f"{'  peak RSS client / largest worker [MB]':58s} {rss:>12s}")
    med, mx = sweep["steps_per_sample_median_max"]
    print(f"{'  steps per sample, median / max; cap hits':58s} {med:7.0f} / {mx:.0f}; {sweep['substep_cap_hits_total']}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count(), "numba": numba.__version__},
        "single": single,
        "baseline": base,
        "sweep": sweep,
    }
    (RESULTS / "bench_simulator.json").write_text(json.dumps(out, indent=2))
    print(f"\nwrote {RESULTS / 'bench_simulator.json'}")


if __name__ == "__main__":
    main()
