"""The seed's computational study end to end (issue 6, item 5): ``gvt sweep beam_ch4_sim`` at full size.

P = logspace(1, 12, 1000) (L1215), 1 s per run, 100 translational outputs at 16384 Hz, order 4, Dask local
cluster with 2 single-threaded workers; then POD + RQ of the first four POMs, asymptote errors against the
fixed-free / fixed-pinned frequencies, the flagged NNM1–NNM2 interactions with their 1 ppm re-check (labelled by
the per-run modal ratio f2/f1 of linear modes 1–2, RQ label beside it), the modal-ratio locks, and the slow-flow
captures of the second stage (``analysis.sweep_capture``: re-simulated runs at the candidate passages; its run count
and wall time are printed, the extra cost over the sweep).
Prints a table, writes bench/results/bench_sweep.json and bench/results/sweep/{rqfep.csv,rqfep.png,sweep.json}.

    python bench/bench_sweep.py [--runs 1000] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
from pathlib import Path

from rich.console import Console

from analysis.model.rigs import open_rig
from daq.outputs import jsonable
from daq.studies.sweep import SweepSpec, print_report, run_sweep, write_outputs

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=1000, help="amplitudes (the seed: 1000)")
    ap.add_argument("--duration", type=float, default=1.0, help="seconds per run (the seed: 1)")
    ap.add_argument("--workers", type=int, default=2, help="local Dask workers (1 on a shared machine)")
    args = ap.parse_args()
    rig = open_rig("beam_ch4_sim")
    spec = SweepSpec(n=args.runs, duration=args.duration, workers=args.workers)
    last = [-1.0]

    def progress(stage: str, frac: float) -> None:
        if frac - last[0] >= 0.1 or frac >= 1.0 > last[0]:
            print(f"  {stage}: {100 * frac:.0f} %", flush=True)
            last[0] = frac

    print(f"gvt sweep beam_ch4_sim: {args.runs} runs x {args.duration:g} s, {args.workers} workers", flush=True)
    rep = run_sweep(rig, spec, progress=progress)
    paths = write_outputs(rep, RESULTS / "sweep")
    print_report(Console(highlight=False, width=140), rep, paths)
    summary = rep.summary()
    summary["peak_rss_largest_worker_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    summary["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count(), "load_avg_1min": os.getloadavg()[0]}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "bench_sweep.json").write_text(json.dumps(summary, indent=2, default=jsonable))
    worst_low = max(abs(a["error_median"]) for a in rep.asymptotes if a["end"] == "low")
    print(
        f"\nwall {rep.wall_s:.0f} s (target <= 300 s on 2 idle cores), peak RSS client {rep.peak_rss_mb:.0f} MB / "
        f"largest worker {summary['peak_rss_largest_worker_mb']:.0f} MB; worst low-end asymptote error "
        f"{100 * worst_low:.2f} %; {len(rep.flags)} flags ({sum(rep.robust)} robust to 1 ppm of P); "
        f"{len(rep.locks)} modal-ratio locks ({', '.join(f'{lk.label} at {lk.p_lo:.4g}–{lk.p_hi:.4g} N' for lk in rep.locks)})"
    )
    if rep.capture is not None:
        c = rep.capture
        print(
            f"slow-flow stage: {c.runs} runs re-simulated at {len(c.passages)} passages ({len(c.untested)} untested) in "
            f"{c.wall_s:.1f} s ({100 * c.wall_s / rep.wall_s:.1f} % of the wall); {len(c.captures)} captures: "
            + ", ".join(f"{cp.label} at {cp.p_lo:.4g}–{cp.p_hi:.4g} N ({cp.n_confirmed}/{cp.n_tested})" for cp in c.captures)
        )
    print(f"wrote {RESULTS / 'bench_sweep.json'}")


if __name__ == "__main__":
    main()
