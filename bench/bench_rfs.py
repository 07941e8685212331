"""Time and accuracy of the RFS + time-series identification of eq. 5.11 (``gvt identify --method rfs``).

Simulates a session on ``configs/rigs/nes_grounded_ch5.toml`` (the seed's grounded NES with its RFS-model values,
L1653; 1 % acceleration and force noise from the rig) with the seed's identification hit (236 N) and validation
hits (114.7, 189.7, 305.5 N; L1656–1660), for several noise seeds, and times the time-series optimisation against
the hit it reads (target <= 5 min on 2 cores, issue 22). Prints a table and writes bench/results/bench_rfs.json.

    .venv/bin/python bench/bench_rfs.py [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from analysis import rfs  # noqa: E402
from analysis.model.rig import load_rig  # noqa: E402
from daq.studies.identify.rfs import identify_rfs  # noqa: E402
from daq.studies.simulate.session import SessionPlan, simulate_session  # noqa: E402

RIG = ROOT / "configs" / "rigs" / "nes_grounded_ch5.toml"
FORCES = (236.0, 114.7, 189.7, 305.5)
TRUTH = {"k": 75.0, "alpha": 9.22e8, "beta": 2.499, "d": 0.35, "mu": 0.0285 / (0.0908 * rfs.G)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    rig = load_rig(RIG)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            log = Path(tmp) / f"nes{seed}.mcap"
            plan = SessionPlan(forces=FORCES, pre_trigger=0.1, spacing=3.0, tail=2.0, block_size=1024)
            simulate_session(rig, log, plan, seed=100 + seed)
            t0 = time.perf_counter()
            run = identify_rfs(log, rig, hit=0, validate=[1, 2, 3])
            total = time.perf_counter() - t0
            s = run.summary()
            est = {r["parameter"]: r["rfs"] for r in s["parameters"]}
            got = {r["parameter"]: r["optimised"] for r in s["parameters"]}
            rows.append({
                "seed": 100 + seed,
                "hit_N": s["peak_force_N"],
                "record_s": run.processed.record.duration,
                "samples": int(run.processed.record.force.size),
                "optimiser_s": run.result.elapsed_s,
                "model_runs": run.result.n_runs,
                "identify_total_s": total,
                "rfs_err_pct": {k: 100 * (est[k] / v - 1) for k, v in TRUTH.items()},
                "err_pct": {k: 100 * (got[k] / v - 1) for k, v in TRUTH.items()},
                "r2_id": s["identification"]["r2"],
                "r2_validation": [v["r2"] for v in s["validation"]],
            })  # fmt: skip
    print(f"{'seed':>4} {'hit N':>6} {'opt s':>6} {'runs':>5} | " + " ".join(f"{k:>13}" for k in TRUTH) + " | R² id, validation")
    for r in rows:
        errs = " ".join(f"{r['rfs_err_pct'][k]:+6.2f}/{r['err_pct'][k]:+5.2f}%" for k in TRUTH)
        print(f"{r['seed']:>4} {r['hit_N']:6.1f} {r['optimiser_s']:6.1f} {r['model_runs']:5d} | {errs} | "
              f"{r['r2_id']:.4f}, {', '.join(f'{x:.4f}' for x in r['r2_validation'])}")  # fmt: skip
    worst = {k: max(abs(r["err_pct"][k]) for r in rows) for k in TRUTH}
    print("worst |error| %: " + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()))
    out = ROOT / "bench" / "results" / "bench_rfs.json"
    doc = {"rig": str(RIG.relative_to(ROOT)), "forces_N": FORCES, "cpus": os.cpu_count(), "rows": rows, "worst_err_pct": worst,
           "target": "optimisation <= 300 s on 2 cores; each parameter within 5 %; validation R² >= 0.95"}  # fmt: skip
    out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
