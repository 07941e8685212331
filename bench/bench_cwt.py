"""CWT benchmark (issue 7): gvtlink's Morlet CWT (eq. 3.2, FFT form of eq. 2.29) against PyWavelets' ``cwt``
(method="fft") in the same run. Prints a table, writes bench/results/bench_cwt.json.

Case: 2^16 samples at 16384 Hz, 100 log-spaced frequencies 50 Hz–4 kHz, one thread for both (PyWavelets
has no threads; ``workers=1`` for scipy.fft). Timings are medians of repeated warm calls.

"Same result" is judged against an independent oracle, the direct time-domain integral of eq. 3.1 with
the eq. 3.2 wavelet (analysis/_cwt_reference.py), at 12 rows x 40 instants (edges included): the error is
|Z − Z_ref| relative to the row's peak |Z_ref|. PyWavelets is run with its Morlet of the same shape
(``cmor2.0-1.0``: bandwidth B = ω0²/(2π²C²) = 2 for ω0 = 2π, C = 1), each row scaled by the one complex
factor that best fits the oracle (its normalisation and phase convention differ from eq. 3.2) — what is
left is PyWavelets' own discretisation error (it convolves with a sampled, integrated and differenced
wavelet table), reported at its default ``precision=12`` and at 16.

    python bench/bench_cwt.py [--repeat 5]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import pywt

from analysis._cwt_reference import cwt_direct
from analysis.wavelet import morlet_cwt

ROOT = Path(__file__).resolve().parents[1]
FS = 16384.0
N = 2**16


def _median_time(fn, repeat: int) -> tuple[float, object]:
    out = fn()  # warm-up (page faults, plan caches)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def _fit_error(z: np.ndarray, ref: np.ndarray) -> float:
    """Max over rows of |k·z − ref| / max|ref| with k the least-squares complex factor of that row."""
    worst = 0.0
    for zi, ri in zip(z, ref, strict=True):
        k = np.vdot(zi, ri) / np.vdot(zi, zi)
        worst = max(worst, float(np.max(np.abs(k * zi - ri)) / np.max(np.abs(ri))))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    t = np.arange(N) / FS
    x = np.sin(2 * np.pi * 23 * t * (1 + 0.5 * t)) + 0.3 * np.sin(2 * np.pi * 410 * t) + 0.05 * rng.standard_normal(N)
    freqs = np.geomspace(50.0, 4000.0, 100)
    wav = pywt.ContinuousWavelet("cmor2.0-1.0")
    scales = pywt.frequency2scale(wav, freqs / FS)

    rows = np.linspace(0, 99, 12).astype(int)
    idx = np.unique(np.concatenate([np.arange(0, 40, 8), np.linspace(0, N - 1, 30).astype(int), N - 1 - np.arange(0, 40, 8)]))
    ref = cwt_direct(x, FS, freqs[rows], idx)

    cases: list[dict] = []

    def ours(dtype):
        return lambda: morlet_cwt(x, FS, freqs, normalization="literal", dtype=dtype, workers=1)

    for dtype in (np.complex128, np.complex64):
        name, fn = f"gvtlink morlet_cwt {np.dtype(dtype).name}", ours(dtype)
        sec, z = _median_time(fn, args.repeat)
        sub = z[rows][:, idx]
        err = float(np.max(np.abs(sub - ref) / np.abs(ref).max(axis=1, keepdims=True)))
        cases.append({"case": name, "seconds": sec, "max_rel_error": err, "scale_fitted": False})
        del z
    for prec in (12, 16):
        def fn(p=prec):
            return pywt.cwt(x, scales, wav, sampling_period=1 / FS, method="fft", precision=p)[0]

        sec, z = _median_time(fn, args.repeat)
        cases.append({"case": f"pywt.cwt fft cmor2.0-1.0 precision={prec}", "seconds": sec,
                      "max_rel_error": _fit_error(z[rows][:, idx], ref), "scale_fitted": True})  # fmt: skip
        del z
    base = next(c["seconds"] for c in cases if c["case"].endswith("precision=12"))
    for c in cases:
        c["speed_vs_pywt"] = base / c["seconds"]

    print(f"CWT of {N} samples x {freqs.size} frequencies, one thread, median of {args.repeat}")
    print(f"{'case':<44} {'s':>8} {'x pywt':>8} {'max rel err vs eq. 3.2 integral':>33}")
    for c in cases:
        note = " (after per-row complex fit)" if c["scale_fitted"] else ""
        print(f"{c['case']:<44} {c['seconds']:8.3f} {c['speed_vs_pywt']:8.1f} {c['max_rel_error']:20.2e}{note}")
    ok = cases[0]["speed_vs_pywt"] > 1 and cases[0]["max_rel_error"] < 1e-6
    print(f"target (faster than pywt, within 1e-6 of the oracle): {'met' if ok else 'NOT met'}")
    out = ROOT / "bench" / "results" / "bench_cwt.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"n": N, "fs": FS, "n_freq": int(freqs.size), "repeat": args.repeat, "python": platform.python_version(),
            "pywt": pywt.__version__, "loadavg": os.getloadavg(), "target_met": ok}  # fmt: skip
    out.write_text(json.dumps({"meta": meta, "cases": cases}, indent=2))
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
