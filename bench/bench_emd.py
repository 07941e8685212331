"""Full EMD: gvtlink's ``emd()`` against PyEMD's defaults and the ``emd`` package on the same stop rule (issue 28).

Every sifter gets the same input, the record divided by its standard deviation (what ``analysis.emd.emd`` sifts
internally), so absolute thresholds mean the same thing to all of them. Rows per record:

- ``gvtlink emd()``: emd.m's per-IMF test (Rilling, [0.05, 0.5, 0.05], 2000 iterations, |#zeros − #extrema| ≤ 1)
  and PyEMD's default end of decomposition (range_thr 0.001, total_power_thr 0.005) — the configuration now.
- ``gvtlink emd(), end test 0``: the configuration before issue 28 (``end_thresholds=NO_END_THRESHOLDS``).
- ``PyEMD EMD() defaults``: PyEMD's own per-IMF test (scaled variance 0.001, SD 0.2, energy ratio 0.2) and end test.
- ``emd.sift.sift, same rule``: the ``emd`` package (A. Quinn) with ``stop_method="rilling"``, the same
  thresholds and 2000 iterations, ``sift_thresh`` 0.005 (its Σ|residual| test, PyEMD's total_power_thr) and no
  energy test. It has no range test and no zero-crossing condition: the nearest its options come to our rule.
- ``emd.sift.sift defaults``: for reference only (SD 0.1 per IMF, 50 "dB" energy end): a different rule.

Records: two clean two-tone signals (tests/test_emd.py's 1000 + 100 Hz; the seed's eq. 3.12 pair at k = 2.2,
A = 0.5), one whose tones do not fit the record (723.46 + 83.08 Hz: end effects), a tone on an offset (100 Hz +
0.3: the residual after IMF 1 is a constant plus rounding noise) and a realistic record, bench_wbemd's
beam_ch4_exp displacement (2 s at 16384 Hz), clean and with 1 % white sensor noise (seed 0).

A last table sifts one IMF of the beam record from the same input with both Rilling-rule sifters (IMF 1, and IMF 3
where the long end-effect sifts start): same input, same rule, so the iteration counts should agree and the time
ratio is the cost per iteration.

Counts come from one instrumented run (sifting iterations = envelope evaluations); times are the best of
``--repeats`` un-instrumented runs, interleaved. A run that has not ended after ``--cap`` seconds is stopped and
reported as such. Speed ratios are within this run: ``vs emd pkg`` = t(emd package, same rule) / t(gvtlink emd())
(≥ 1: gvtlink at least as fast), ``vs PyEMD`` = t(gvtlink emd()) / t(PyEMD defaults).

    OPENBLAS_NUM_THREADS=1 python bench/bench_emd.py [--repeats 3] [--cap 20] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import signal
import sys
import time
import warnings
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import analysis.emd as gemd  # noqa: E402
from analysis.emd import MAX_ITERATION, NO_END_THRESHOLDS, PYEMD_END_THRESHOLDS, RILLING_STOP  # noqa: E402

EMD = gemd.EMD  # PyEMD's class, imported by analysis.emd without pylab

try:
    import emd as quinn  # the `emd` package (dev extra)
except ImportError:  # pragma: no cover - said on the command line
    sys.exit("bench_emd: the `emd` package is missing: pip install -e '.[dev]' (or pip install emd)")

logging.getLogger("emd").setLevel(logging.ERROR)

Sifter = Callable[[np.ndarray], int]
"""Runs one decomposition of a standardised record and returns its IMF count (residual not counted)."""


def _gvt(end: tuple[float, float]) -> Sifter:
    def run(xs: np.ndarray) -> int:
        return int(gemd.emd(xs, 1.0, end_thresholds=end).shape[0] - 1)
    return run


def _pyemd(xs: np.ndarray) -> int:
    sifter = EMD()
    sifter.emd(xs)
    return int(sifter.get_imfs_and_residue()[0].shape[0])


_QUINN_SAME = {"sift_thresh": PYEMD_END_THRESHOLDS[1], "energy_thresh": None, "rilling_thresh": None,
               "imf_opts": {"stop_method": "rilling", "rilling_thresh": RILLING_STOP, "max_iters": MAX_ITERATION}}


def _quinn(kwargs: dict) -> Sifter:
    def run(xs: np.ndarray) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its energy test's np.log10(where=...) warning
            imf = quinn.sift.sift(xs, **kwargs)
        return int(imf.shape[1] - 1)  # it appends the residual unless that is exactly 0; _Counter counts its IMFs
    return run


SIFTERS: list[tuple[str, Sifter]] = [
    ("gvtlink emd()", _gvt(PYEMD_END_THRESHOLDS)),
    ("gvtlink emd(), end test 0", _gvt(NO_END_THRESHOLDS)),
    ("PyEMD EMD() defaults", _pyemd),
    ("emd.sift.sift, same rule", _quinn(_QUINN_SAME)),
    ("emd.sift.sift defaults", _quinn({})),
]


class _Counter:
    """Counts sifting iterations (envelope evaluations) by wrapping each library's envelope function, and the
    ``emd`` package's IMFs (calls of its ``get_next_imf``)."""

    def __init__(self) -> None:
        self.n = 0
        self.quinn_imfs = 0

    def __enter__(self) -> _Counter:
        self._pyemd = EMD.extract_max_min_spline
        self._quinn = quinn.sift.interp_envelope
        self._quinn_next = quinn.sift.get_next_imf
        counter = self
        pyemd_orig, quinn_orig, quinn_next = self._pyemd, self._quinn, self._quinn_next

        def next_imf(*a, **k):
            counter.quinn_imfs += 1
            return quinn_next(*a, **k)

        def pyemd_env(sifter, T, S):  # PyEMD's signature; _RillingEMD reaches it through super()
            counter.n += 1
            return pyemd_orig(sifter, T, S)

        def quinn_env(*a, **k):  # only get_next_imf calls it when rilling_thresh is None
            counter.n += 1
            return quinn_orig(*a, **k)

        EMD.extract_max_min_spline = pyemd_env
        quinn.sift.interp_envelope = quinn_env
        quinn.sift.get_next_imf = next_imf
        return self

    def __exit__(self, *exc: object) -> None:
        EMD.extract_max_min_spline = self._pyemd
        quinn.sift.interp_envelope = self._quinn
        quinn.sift.get_next_imf = self._quinn_next


class _Cap(Exception):
    pass


def _capped(fn: Callable[[], int], cap_s: float) -> tuple[int | None, float]:
    """(IMF count or None if stopped at the cap, wall seconds)."""
    def stop(*_: object) -> None:
        raise _Cap
    old = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, cap_s)
    t0 = time.perf_counter()
    try:
        n: int | None = fn()
    except _Cap:
        n = None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    return n, time.perf_counter() - t0


def records() -> list[tuple[str, np.ndarray]]:
    from bench.bench_wbemd import beam_signal

    t8 = np.arange(int(0.5 * 8000)) / 8000.0
    t48 = np.arange(4800) / 48000.0
    t8l = np.arange(2 * 8000) / 8000.0
    t1 = np.arange(8000) / 8000.0
    beam, sensor = beam_signal()
    noisy = beam + 0.01 * np.std(beam) * np.random.default_rng(0).standard_normal(beam.size)
    return [
        ("two-tone 1000 + 100 Hz, 8 kHz, 0.5 s", np.sin(2 * np.pi * 1000 * t8) + np.sin(2 * np.pi * 100 * t8)),
        ("seed eq. 3.12, k 2.2, A 0.5, 48 kHz, 0.1 s",
         0.5 * np.sin(2 * np.pi * 2.2 * 750 * t48) + np.sin(2 * np.pi * 750 * t48)),
        ("two-tone 723.46 + 83.08 Hz, 8 kHz, 2 s",
         np.sin(2 * np.pi * 723.46 * t8l) + np.sin(2 * np.pi * 83.08 * t8l)),
        ("tone on an offset, 100 Hz + 0.3, 8 kHz, 1 s", np.sin(2 * np.pi * 100 * t1) + 0.3),
        (f"beam_ch4_exp {sensor}, 16384 Hz, 2 s", beam),
        (f"beam_ch4_exp {sensor} + 1 % noise", noisy),
    ]


def run(repeats: int, cap_s: float) -> list[dict]:
    rows = []
    for name, x in records():
        xs = x / np.std(x)
        res: dict[str, dict] = {}
        for label, fn in SIFTERS:
            with _Counter() as c:
                n_imf, t_first = _capped(lambda fn=fn, xs=xs: fn(xs), cap_s)
            if label.startswith("emd.sift") and n_imf is not None:
                n_imf = c.quinn_imfs
            res[label] = {"n_imf": n_imf, "iterations": c.n, "ended": n_imf is not None, "times_s": [t_first]}
        for _ in range(max(repeats - 1, 0)):  # interleaved, un-instrumented; runs that hit the cap are not repeated
            for label, fn in SIFTERS:
                if res[label]["ended"]:
                    res[label]["times_s"].append(_capped(lambda fn=fn, xs=xs: fn(xs), cap_s)[1])
        for r in res.values():
            # The first run is instrumented; with repeats, time only the plain runs after it.
            r["time_s"] = min(r["times_s"][1:]) if len(r["times_s"]) > 1 else r["times_s"][0]
        g, q, p = res["gvtlink emd()"], res["emd.sift.sift, same rule"], res["PyEMD EMD() defaults"]
        rows.append({"record": name, "n": int(x.size), "results": res,
                     "speed_vs_emd_pkg_same_rule": (q["time_s"] / g["time_s"]) if q["ended"] else None,
                     "time_vs_pyemd_defaults": g["time_s"] / p["time_s"]})
    return rows


def same_input(repeats: int) -> list[dict]:
    """One IMF sifted from the same input by both Rilling-rule sifters: the beam record's IMF 1 (input = the record)
    and IMF 3 (input = the record minus gvtlink's first two IMFs, where the long end-effect sifts start). With the
    same input and rule the two should count the same iterations, so the time ratio is the cost per iteration."""
    from bench.bench_wbemd import beam_signal

    beam = beam_signal()[0]
    xs = beam / np.std(beam)
    c = gemd.emd(xs, 1.0)
    opts = _QUINN_SAME["imf_opts"]
    out = []
    for k in (0, 2):
        r = xs - c[:k].sum(axis=0)

        def ours(r: np.ndarray = r) -> int:
            return int(gemd.first_imf(r).size)

        def theirs(r: np.ndarray = r) -> int:
            return int(quinn.sift.get_next_imf(r[:, None], **opts)[0].size)

        row: dict = {"imf": k + 1}
        for label, fn in (("gvtlink first_imf", ours), ("emd.sift.get_next_imf", theirs)):
            with _Counter() as cnt:
                fn()
            times = []
            for _ in range(max(repeats, 1)):
                t0 = time.perf_counter()
                fn()
                times.append(time.perf_counter() - t0)
            row[label] = {"iterations": cnt.n, "time_s": min(times)}
        row["speed_vs_emd_pkg"] = row["emd.sift.get_next_imf"]["time_s"] / row["gvtlink first_imf"]["time_s"]
        out.append(row)
    return out


def print_table(rows: list[dict], cap_s: float) -> None:
    for row in rows:
        print(f"\n{row['record']} (n = {row['n']})")
        print(f"  {'sifter':28s} {'IMFs':>5s} {'iterations':>11s} {'time [s]':>10s}")
        for label, r in row["results"].items():
            imfs = str(r["n_imf"]) if r["ended"] else "-"
            t = f"{r['time_s']:.3f}" if r["ended"] else f"> {cap_s:.0f} (not ended)"
            print(f"  {label:28s} {imfs:>5s} {r['iterations']:>11d} {t:>10s}")
        s = row["speed_vs_emd_pkg_same_rule"]
        same = f"x{s:.2f}" if s is not None else "emd package did not end"
        print(f"  gvtlink vs emd package, same rule: {same}"
              f" | gvtlink / PyEMD defaults time: x{row['time_vs_pyemd_defaults']:.1f}")


def print_same_input(rows: list[dict]) -> None:
    print("\nbeam_ch4_exp, one IMF from the same input, same rule (Rilling, 2000 iterations)")
    print(f"  {'IMF':>3s} {'gvtlink it':>10s} {'time [s]':>9s} {'emd pkg it':>10s} {'time [s]':>9s} {'speed':>7s}")
    for r in rows:
        g, q = r["gvtlink first_imf"], r["emd.sift.get_next_imf"]
        print(f"  {r['imf']:>3d} {g['iterations']:>10d} {g['time_s']:>9.3f} {q['iterations']:>10d} {q['time_s']:>9.3f} "
              f"{'x' + format(r['speed_vs_emd_pkg'], '.2f'):>7s}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per sifter and record (best is kept)")
    ap.add_argument("--cap", type=float, default=20.0, help="seconds after which a decomposition is stopped")
    ap.add_argument("--json", default=str(ROOT / "bench/results/bench_emd.json"))
    args = ap.parse_args()
    load0 = os.getloadavg()
    rows = run(args.repeats, args.cap)
    same = same_input(args.repeats)
    load1 = os.getloadavg()
    print_table(rows, args.cap)
    print_same_input(same)
    print(f"\nload before {load0}, after {load1}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}; "
          f"EMD-signal {version('EMD-signal')}, emd {version('emd')}")
    out = {"rows": rows, "same_input": same, "repeats": args.repeats, "cap_s": args.cap, "load_before": load0,
           "load_after": load1,
           "python": platform.python_version(), "EMD-signal": version("EMD-signal"), "emd": version("emd"),
           "rilling_stop": list(RILLING_STOP), "pyemd_end_thresholds": list(PYEMD_END_THRESHOLDS)}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
