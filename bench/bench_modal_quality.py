"""What the quality checks of ``gvt modal`` cost (issue 29: <= 5 % of its CPU), and what they give on the issue's cases.

Same run, same FRFs, two paths:

* ``plain``: what ``gvt modal`` did before issue 29 -- pLSCF + stabilisation, the stable-pole clusters
  (:func:`analysis.modal_id.auto_select`), LSFD and shapes of those, each mode's highest-MAC FE mode;
* ``checked``: :func:`analysis.modal_id.identify_arrays` (candidates, contributions, duplicates, flags) and the
  one-to-one pairing (:func:`analysis.modal_pairing.pair_modes`).

The difference is the checks' CPU (``time.process_time``, one BLAS thread, median of ``--repeat``), printed beside
the CPU of a whole ``gvt modal LOG --json`` process on the weak-hit log (``resource`` of the child): the
cheapest ``gvt modal`` run there is (one hit, one reference), so the share is an upper bound for the others. Cases: the
sim_roving FRF matrix (tests/data), the weak-hit replay log's FRFs, pyuff's measured beam (tests/data).
``--record`` also records ``gvt demo`` and ``configs/sessions/sim_roving.toml`` in a temporary directory (minutes)
and prints ``gvt modal``'s table on each.

    .venv/bin/python bench/bench_modal_quality.py [--repeat 5] [--record] [--json bench/results/bench_modal_quality.json]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: the same thread setting for both paths

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from analysis.frf import FRFSet  # noqa: E402
from analysis.modal_id import (  # noqa: E402
    Criteria,
    auto_select,
    fe_modes_at_sensors,
    identify_arrays,
    modes_from_poles,
    pair_with_fe,
    stabilisation,
)
from analysis.modal_pairing import pair_modes  # noqa: E402
from analysis.model.rigs import open_rig  # noqa: E402
from analysis.plscf import plscf  # noqa: E402

DATA = ROOT / "tests/data"


def roving_case():
    with np.load(DATA / "sim_roving_frf.npz") as z:
        meta = json.loads(str(z["meta"]))
        return "sim_roving FRFs (14 x 5)", z["freq"], z["H"].astype(complex), meta["sigma_added"], open_rig("beam_ch4_exp")


def weak_case():
    from daq.studies.frf import frf_from_log

    rig = open_rig("beam_ch4_exp")
    f: FRFSet = frf_from_log(ROOT / "replay_logs/beam_ch4_exp_weak.mcap", rig).frf
    return "weak-hit log FRFs (14 x 1)", f.freq, f.H, float(f.window["sigma_added"]), rig


def beam_case():
    H = np.array([np.genfromtxt(DATA / "pyuff_meas_points" / f"meas_point_{i}.txt", dtype=complex) for i in (1, 2, 3)])
    return "pyuff measured beam (1 x 3)", np.arange(H.shape[-1], dtype=float), H[None], 0.0, None


def plain(freq, H, sigma, phi):
    table = stabilisation(plscf(freq, H, 2.0, 1000.0, 60), Criteria())
    res = modes_from_poles(freq, H, "accelerance", table, auto_select(table), 2.0, 1000.0, sigma_added=sigma)
    if phi is not None:
        pair_with_fe(res.shapes, phi)
    return res


def checked(freq, H, sigma, phi, f_fe):
    res = identify_arrays(freq, H, "accelerance", 2.0, 1000.0, sigma_added=sigma)
    if phi is not None:
        pair_modes(res.freq_hz, res.shapes, f_fe, phi)
    return res


def cpu(fn, repeat: int):
    out, times = None, []
    for _ in range(repeat):
        t = time.process_time()
        out = fn()
        times.append(time.process_time() - t)
    return float(np.median(times)), out


def gvt_modal_cpu(log: Path) -> float:
    """User + system CPU of one ``gvt modal LOG --json`` process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "daq.cli", "modal", str(log), "--json"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def record_and_show(tmp: Path) -> dict:
    """gvt demo and the sim_roving session recorded, and gvt modal's table on each (text)."""
    out = {}
    run = [sys.executable, "-m", "daq.cli"]
    subprocess.run([*run, "demo", "--out", str(tmp / "demo_session.mcap")], cwd=ROOT, check=True, capture_output=True)
    subprocess.run([*run, "record", "configs/sessions/sim_roving.toml", "--out", str(tmp / "sim_roving.mcap")], cwd=ROOT,
                   check=True, capture_output=True)  # fmt: skip
    for name in ("demo_session", "sim_roving"):
        p = subprocess.run([*run, "modal", str(tmp / f"{name}.mcap")], cwd=ROOT, capture_output=True, text=True)
        out[name] = "\n".join(x for x in p.stdout.splitlines() if not x.startswith("hits:"))
        print(f"\n== gvt modal {name}.mcap\n{out[name]}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--record", action="store_true", help="also record the demo and sim_roving logs (minutes)")
    ap.add_argument("--json", type=Path, default=ROOT / "bench/results/bench_modal_quality.json")
    args = ap.parse_args()
    whole = float(np.median([gvt_modal_cpu(ROOT / "replay_logs/beam_ch4_exp_weak.mcap") for _ in range(3)]))
    print(f"gvt modal replay_logs/beam_ch4_exp_weak.mcap --json: {whole:.2f} s CPU (whole process)\n")
    print(f"{'case':<30} {'plain [ms]':>10} {'checked [ms]':>12} {'checks [ms]':>11} {'% of gvt modal':>14}  "
          "modes plain -> checked")  # fmt: skip
    rows = []
    for name, freq, H, sigma, rig in (roving_case(), weak_case(), beam_case()):
        phi = f_fe = None
        if rig is not None:
            f_fe, _z, phi = fe_modes_at_sensors(rig, 12)
        t0, r0 = cpu(lambda: plain(freq, H, sigma, phi), args.repeat)  # noqa: B023
        t1, r1 = cpu(lambda: checked(freq, H, sigma, phi, f_fe), args.repeat)  # noqa: B023
        row = {"case": name, "plain_s": t0, "checked_s": t1, "checks_s": t1 - t0, "share_of_gvt_modal": (t1 - t0) / whole,
               "modes_plain": np.round(r0.freq_hz, 2).tolist(), "modes_checked": np.round(r1.freq_hz, 2).tolist(),
               "rejected": [(round(x["freq_hz"], 2), x["reason"]) for x in r1.rejected]}  # fmt: skip
        rows.append(row)
        share = 100 * row["share_of_gvt_modal"]
        print(f"{name:<30} {1e3 * t0:>10.1f} {1e3 * t1:>12.1f} {1e3 * (t1 - t0):>11.1f} {share:>13.1f}%  "
              f"{r0.freq_hz.size} -> {r1.freq_hz.size}")  # fmt: skip
    doc = {"gvt_modal_weak_log_cpu_s": whole, "rows": rows, "loadavg_1min": os.getloadavg()[0]}
    if args.record:
        with tempfile.TemporaryDirectory(prefix="gvt_bench_modal_") as tmp:
            doc["recorded"] = record_and_show(Path(tmp))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
