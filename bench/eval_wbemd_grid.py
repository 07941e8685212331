"""Seed §3.4.1 (L843–L865, Fig. 3.3): EMD vs EEMD vs WBEMD on two closely spaced tones.

y(t) = A sin(2π k f1 t) + sin(2π f1 t) (eq. 3.12), f1 = 750 Hz, y1 = A sin(2π k f1 t) (high), y2 = sin(2π f1 t) (low).
Grid (the text gives only the ranges): k = 1.05, 1.15, …, 2.15 and 2.20 (13 values), A = 0.1, 0.3, …, 1.9
and 2.0 (11 values) = 143 points (``--full``: k step 0.05, A step 0.1, 480 points); fs = 48 kHz, 0.1 s
(4800 samples). Per point and method: PCC of the component for y1 with y1 and of the
component for y2 with y2.

Which component is scored:
- WBEMD: its two components (char freqs [f1, k f1] given exactly; IMF 2 = high, IMF 1 = residual z_2).
- EMD and EEMD: the seed scores "IMF 1" and "IMF 2" (L853). With EEMD the first IMFs are the added noise, so
  here both get the *best-matching* IMF (max PCC over all rows) — the most favourable choice for the
  competitors. The seed-literal EMD rows 0/1 are recorded too (``emd_literal``).
PCC is on the whole record (primary, like the seed) and on the central 80 % (``*_central``, to show end effects).

    python bench/eval_wbemd_grid.py [--quick] [--workers 2] [--omega0 6.283] [--trim 0] [--delta 0.15]
                                    [--eemd-trials 20] [--full] [--unmasked-candidate 1] [--mirror 0]
                                    [--reuse-baselines OLD.json] [--attach-ceiling CEIL.json] [--json PATH]
    python bench/eval_wbemd_grid.py --ceiling --workers 2 --json CEIL.json   # brute-force mask bound (mask_ceiling)

The results in bench/results/eval_wbemd_grid.json and docs/wbemd.md §5 come from
``--workers 2 --reuse-baselines <previous JSON> --attach-ceiling <--ceiling JSON>``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from analysis.emd import eemd, emd, pcc  # noqa: E402
from analysis.wbemd import WbemdParams, wbemd  # noqa: E402

F1 = 750.0
FS = 48000.0
DURATION = 0.1
K_FULL = np.round(np.arange(1.05, 2.2001, 0.05), 2)
A_FULL = np.round(np.arange(0.1, 2.0001, 0.1), 2)
K_VALUES = np.append(np.round(np.arange(1.05, 2.2, 0.1), 2), 2.2)
A_VALUES = np.append(np.round(np.arange(0.1, 2.0, 0.2), 2), 2.0)
CENTRAL = 0.1  # fraction cut at each end for the *_central scores

_PARAMS: WbemdParams = WbemdParams()
_TRIALS = 50
_BASELINES: dict[tuple[float, float], dict] = {}
"""EMD/EEMD scores per (A, k) from an earlier run's JSON (``--reuse-baselines``): they do not depend on WBEMD."""


def _scores(c_hi: np.ndarray, c_lo: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> dict[str, float]:
    n = y1.size
    m = slice(int(CENTRAL * n), n - int(CENTRAL * n))
    return {"hi": pcc(c_hi, y1), "lo": pcc(c_lo, y2), "hi_central": pcc(c_hi[m], y1[m]), "lo_central": pcc(c_lo[m], y2[m])}


def _best(rows: np.ndarray, y1: np.ndarray, y2: np.ndarray) -> dict[str, float]:
    i_hi = int(np.argmax([pcc(r, y1) for r in rows]))
    i_lo = int(np.argmax([pcc(r, y2) for r in rows]))
    return _scores(rows[i_hi], rows[i_lo], y1, y2)


def point(args: tuple[float, float]) -> dict:
    a, k = args
    t = np.arange(int(DURATION * FS)) / FS
    y1 = a * np.sin(2 * np.pi * k * F1 * t)
    y2 = np.sin(2 * np.pi * F1 * t)
    y = y1 + y2
    out: dict = {"A": a, "k": k}
    if (a, k) in _BASELINES:
        out.update({m: _BASELINES[(a, k)][m] for m in ("emd", "emd_literal", "eemd")})
    else:
        c = emd(y, FS)
        out["emd"] = _best(c, y1, y2)
        out["emd_literal"] = _scores(c[0], c[1] if c.shape[0] > 1 else 0 * y, y1, y2)
        out["eemd"] = _best(eemd(y, FS, trials=_TRIALS, noise_width=0.2, seed=1), y1, y2)
    t0 = time.perf_counter()
    r = wbemd(y, FS, [F1, k * F1], params=_PARAMS)
    out["wbemd_s"] = time.perf_counter() - t0
    out["wbemd"] = _scores(r.imfs[1], r.imfs[0], y1, y2)
    d = r.diagnostics[1]
    out["wbemd_diag"] = {"alpha": d.alpha, "beta": d.beta, "phi": d.phi, "B": d.B, "gain": d.gain_at_freq,
                         "leakage": d.leakage, "emd_calls": d.emd_calls, "converged": d.converged, "mask": d.mask}
    out["wbemd_io"] = r.orthogonality_index
    return out


CEIL_ALPHA = np.geomspace(0.02, 10.0, 20)
CEIL_BETA = np.linspace(0.3, 3.5, 33)


def mask_ceiling(args: tuple[float, float, float]) -> dict:
    """Upper bound on what any stationary sinusoidal mask s = α·max|y|·sin(βω_1 t) (eq. 3.7; α = 0 is plain EMD's
    IMF 1) can give at one grid point: the best min(PCC_hi, PCC_lo) over a 20 × 33 (α, β) box wider than the
    optimiser's (α 0.02–10 geometric, β 0.3–3.5), scored on the whole record and on the central 80 %. No
    constraint and no bound test: the truth picks the mask, so WBEMD's choice can only be worse or equal."""
    a, k, duration = args
    from analysis.emd import first_imf, masked_first_imf

    t = np.arange(round(duration * FS)) / FS
    y1 = a * np.sin(2 * np.pi * k * F1 * t)
    y2 = np.sin(2 * np.pi * F1 * t)
    y = y1 + y2
    zmax = float(np.max(np.abs(y)))
    best = {"whole": (-2.0, 0.0, 0.0), "central": (-2.0, 0.0, 0.0)}
    trials = [(0.0, 1.0)] + [(al, be) for al in CEIL_ALPHA for be in CEIL_BETA]
    for al, be in trials:
        c = first_imf(y) if al == 0 else masked_first_imf(y, FS, zmax * al * np.sin(be * 2 * np.pi * k * F1 * t))
        sc = _scores(c, y - c, y1, y2)
        for key, v in (("whole", min(sc["hi"], sc["lo"])), ("central", min(sc["hi_central"], sc["lo_central"]))):
            if v > best[key][0]:
                best[key] = (v, float(al), float(be))
    found = {key: {"pcc": v[0], "alpha": v[1], "beta": v[2]} for key, v in best.items()}
    return {"A": a, "k": k, "duration_s": duration, **found}


def _init(params: WbemdParams, trials: int, baselines: dict | None = None) -> None:
    global _PARAMS, _TRIALS, _BASELINES
    _PARAMS, _TRIALS, _BASELINES = params, trials, baselines or {}
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def summarise(rows: list[dict], key: str = "") -> dict:
    def mn(r: dict, m: str) -> float:
        return min(r[m]["hi" + key], r[m]["lo" + key])

    n = len(rows)
    s = {"points": n}
    for m in ("emd", "eemd", "wbemd"):
        v = np.array([mn(r, m) for r in rows])
        s[m] = {"mean_min_pcc": float(v.mean()), "ge_0.95": int((v >= 0.95).sum()), "ge_0.9": int((v >= 0.9).sum())}
    tol = 1e-3  # "at least as well": ties within 0.001 count as not worse
    for comp in ("hi", "lo"):
        for m in ("emd", "eemd"):
            worse = [(r["A"], r["k"]) for r in rows if r["wbemd"][comp + key] < r[m][comp + key] - tol]
            s[f"wbemd_worse_than_{m}_{comp}"] = worse
    return s


def table(rows: list[dict], key: str = "") -> str:
    """Compact table: per (A, k) the min of the two PCCs for EMD / EEMD / WBEMD."""
    ks = sorted({r["k"] for r in rows})
    as_ = sorted({r["A"] for r in rows})
    idx = {(r["A"], r["k"]): r for r in rows}
    lines = ["min(PCC_hi, PCC_lo) as EMD/EEMD/WBEMD, x100; rows A, columns k", "A \\ k | " + " | ".join(f"{k:.2f}" for k in ks)]
    lines.append("|".join(["---"] * (len(ks) + 1)))
    for a in as_:
        cells = []
        for k in ks:
            r = idx.get((a, k))
            if r is None:
                cells.append("")
                continue
            v = [100 * min(r[m]["hi" + key], r[m]["lo" + key]) for m in ("emd", "eemd", "wbemd")]
            cells.append("/".join(f"{x:.0f}" for x in v))
        lines.append(f"{a:.1f} | " + " | ".join(cells))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="k step 0.25 and A in {0.1, 0.5, 1, 2}")
    ap.add_argument("--full", action="store_true", help="k step 0.05, A step 0.1 (480 points)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--omega0", type=float, default=2 * np.pi)
    ap.add_argument("--trim", type=float, default=0.0, help="MWT trim_s (s)")
    ap.add_argument("--delta", type=float, default=0.15)
    ap.add_argument("--omega0-spacing", type=float, default=None, help="WbemdParams.omega0_spacing (not in the text)")
    ap.add_argument("--optimizer", default="nelder-mead")
    ap.add_argument("--eemd-trials", type=int, default=20)
    ap.add_argument("--unmasked-candidate", type=int, default=1, help="WbemdParams.unmasked_candidate (1/0)")
    ap.add_argument("--mirror", type=int, default=0, help="WbemdParams.mirror (samples)")
    ap.add_argument("--reuse-baselines", default=None,
                    help="earlier JSON of this script (same fs, duration, EEMD settings): take its EMD/EEMD scores")
    ap.add_argument("--ceiling", action="store_true", help="only the brute-force mask ceiling per point (mask_ceiling)")
    ap.add_argument("--attach-ceiling", default=None, help="JSON of a --ceiling run: stored under 'mask_ceiling' and compared")
    ap.add_argument("--json", default=str(ROOT / "bench/results/eval_wbemd_grid.json"))
    args = ap.parse_args()
    params = WbemdParams(omega0=args.omega0, trim_s=args.trim, delta=args.delta, optimizer=args.optimizer,
                         omega0_spacing=args.omega0_spacing, unmasked_candidate=bool(args.unmasked_candidate),
                         mirror=args.mirror)
    baselines: dict = {}
    if args.reuse_baselines:
        old = json.loads(Path(args.reuse_baselines).read_text())
        same = old["grid"]["fs"] == FS and old["grid"]["duration_s"] == DURATION and old["eemd"]["trials"] == args.eemd_trials
        if not same:
            raise SystemExit(f"--reuse-baselines {args.reuse_baselines}: fs/duration/EEMD trials differ from this run")
        baselines = {(r["A"], r["k"]): r for r in old["rows"]}
    ks, as_ = (K_VALUES, A_VALUES)
    if args.quick:
        ks, as_ = K_FULL[::5], np.array([0.1, 0.5, 1.0, 2.0])
    elif args.full:
        ks, as_ = K_FULL, A_FULL
    grid = [(float(a), float(k)) for a in as_ for k in ks]
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    if args.ceiling:
        with Pool(max(args.workers, 1)) as pool:
            ceil = pool.map(mask_ceiling, [(a, k, DURATION) for a, k in grid], chunksize=2)
        for key in ("whole", "central"):
            v = np.array([c[key]["pcc"] for c in ceil])
            print(f"[ceiling, {key}] mean {v.mean():.3f}  >=0.95: {(v >= 0.95).sum()} / {v.size}")
        out = {"grid": {"k": [float(k) for k in ks], "A": [float(a) for a in as_], "f1_hz": F1, "fs": FS, "duration_s": DURATION},
               "alpha": CEIL_ALPHA.tolist(), "beta": CEIL_BETA.tolist(), "rows": ceil, "wall_s": time.perf_counter() - t0,
               "load_before": load0, "load_after": os.getloadavg()}
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))
        return
    if args.workers > 1:
        with Pool(args.workers, initializer=_init, initargs=(params, args.eemd_trials, baselines)) as pool:
            rows = pool.map(point, grid, chunksize=4)
    else:
        _init(params, args.eemd_trials, baselines)
        rows = [point(g) for g in grid]
    wall = time.perf_counter() - t0
    summ = summarise(rows)
    summ_c = summarise(rows, "_central")
    print(table(rows))
    print()
    for name, s in (("whole record", summ), ("central 80 %", summ_c)):
        print(f"[{name}] points={s['points']}")
        for m in ("emd", "eemd", "wbemd"):
            print(f"  {m:6s} mean min-PCC {s[m]['mean_min_pcc']:.3f}  >=0.95: {s[m]['ge_0.95']}  >=0.9: {s[m]['ge_0.9']}")
        for key, v in s.items():
            if key.startswith("wbemd_worse"):
                print(f"  {key}: {len(v)} {v[:12]}{' ...' if len(v) > 12 else ''}")
    ceiling = None
    if args.attach_ceiling:
        ceiling = json.loads(Path(args.attach_ceiling).read_text())
        cidx = {(c["A"], c["k"]): c for c in ceiling["rows"]}
        for key, sk in (("whole", ""), ("central", "_central")):
            v = np.array([cidx[(r["A"], r["k"])][key]["pcc"] for r in rows])
            w = np.array([min(r["wbemd"]["hi" + sk], r["wbemd"]["lo" + sk]) for r in rows])
            ceiling[f"summary_{key}"] = {"mean": float(v.mean()), "ge_0.95": int((v >= 0.95).sum()),
                                         "ge_0.94": int((v >= 0.94).sum()), "wbemd_gap_mean": float((v - w).mean())}
            print(f"[mask ceiling, {key}] mean {v.mean():.3f}  >=0.95: {(v >= 0.95).sum()}  >=0.94: {(v >= 0.94).sum()}"
                  f"  (WBEMD below it by {(v - w).mean():.3f} on average)")
    print(f"wall {wall:.1f} s, workers {args.workers}, load before {load0}, after {os.getloadavg()}")
    out = {"grid": {"k": [float(k) for k in ks], "A": [float(a) for a in as_], "f1_hz": F1, "fs": FS, "duration_s": DURATION},
           "params": {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.__dict__.items()},
           "eemd": {"trials": args.eemd_trials, "noise_width_std_rel": 0.2, "seed": 1},
           "summary_whole": summ, "summary_central": summ_c, "rows": rows,
           "wall_s": wall, "workers": args.workers, "load_before": load0, "load_after": os.getloadavg(),
           "python": platform.python_version(), "table_whole": table(rows), "table_central": table(rows, "_central"),
           "mask_ceiling": ceiling}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
