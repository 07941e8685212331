"""The README's NSI command on the README's sweep, with and without the range chosen from the data (issue 29).

Runs ``gvt sweep beam_ch4_sim --n N`` (the sweep's default P 10 N – 1e12 N; the README says 200 runs, the issue
measured 120) into a temporary directory, then ``gvt identify DIR --rig beam_ch4_sim --frequency pom --law hb`` with
``--auto-range`` and with every point, each with ``--out`` (validated by re-simulation), and prints α, β, R², the fit
range, the quality problems, the exit code and whether the rig was written. Writes
bench/results/bench_identify_readme.json. A 200-run sweep takes ~5 min on 2 cores.

    .venv/bin/python bench/bench_identify_readme.py [--runs 200] [--sweep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ALPHA, BETA = 5e8, 2.0  # beam_ch4_sim's tip spring


def gvt(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daq.cli", *args], capture_output=True, text=True, cwd=ROOT)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--sweep", type=Path, default=None, help="an existing 'gvt sweep beam_ch4_sim' directory")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        sweep = a.sweep or Path(tmp) / "sweep"
        if a.sweep is None:
            p = gvt("sweep", "beam_ch4_sim", "--n", str(a.runs), "--out", str(sweep))
            if p.returncode != 0:
                sys.exit(f"gvt sweep failed: {p.stderr.strip()}")
        rows = []
        for name, extra in (("auto range", ["--auto-range"]), ("every point", [])):
            out = Path(tmp) / f"{name.replace(' ', '_')}.toml"
            p = gvt("identify", str(sweep), "--rig", "beam_ch4_sim", "--frequency", "pom", "--law", "hb", *extra,
                    "--out", str(out), "--json")  # fmt: skip
            doc = json.loads(p.stdout) if p.stdout.strip() else {}
            fit = doc.get("fit", {})
            rows.append({"case": name, "exit": p.returncode, "written": out.exists(), "alpha": fit.get("alpha"),
                         "beta": fit.get("beta"), "r2": fit.get("r2"), "fit_range": doc.get("fit_range"),
                         "validation": (doc.get("validation") or {}).get("rows"), "quality": doc.get("quality"),
                         "stderr": p.stderr.strip().splitlines()[-1:] if p.stderr.strip() else []})  # fmt: skip
    print(f"{'case':<12} {'exit':>4} {'rig':>4} {'alpha err':>10} {'beta err':>9} {'R2':>8}  range / problems")
    for r in rows:
        ae = f"{r['alpha'] / ALPHA - 1:+.1%}" if r["alpha"] else "-"
        be = f"{r['beta'] / BETA - 1:+.2%}" if r["beta"] else "-"
        rng = (r["fit_range"] or {}).get("stopped", "")
        probs = "; ".join((r["quality"] or {}).get("problems", []))
        print(f"{r['case']:<12} {r['exit']:>4} {'yes' if r['written'] else 'no':>4} {ae:>10} {be:>9} "
              f"{r['r2'] or float('nan'):8.4f}  {rng} {probs}")  # fmt: skip
    res = ROOT / "bench" / "results"
    res.mkdir(exist_ok=True)
    (res / "bench_identify_readme.json").write_text(json.dumps({"runs": a.runs, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
