"""FRF + coherence update after a hit: gvtlink's FRFAccumulator against pyFRF on the same data (issue 20).

Target: <= 50 ms per hit at 15 channels (hammer + 14 accelerometers) x 16384 Hz, 2 s records. The records
are real simulated hits of ``beam_ch4_exp`` (the project's simulator and sensor model; 10 hits, each its own
noise). Per hit, each side does what a live view needs after a hit: add the record to the average, then
H1 and coherence of every pair over 0-1 kHz. gvtlink: force + exponential windows, one real FFT of the
15 x 32768 record, running sums. pyFRF 1.5.0: ``add_data`` of the same (already windowed) record with
``window="none"``, then ``get_FRF("H1")`` and ``get_coherence()``. Median and max over the hits, with
``os.getloadavg()`` beside each figure; JSON to bench/results/bench_frf.json.

    .venv/bin/python bench/bench_frf.py [--hits 10]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from analysis.frf import FRFAccumulator, choose_tau, exponential_window, force_window
from analysis.model.rig import channel_signals, load_rig
from drivers.sim.sensor_model import AdcModel, channel_models_for, measure

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parents[1]


def hits(n_hits: int):
    rig = load_rig(ROOT / "configs/rigs/beam_ch4_exp.toml")
    fs = rig.sample_rate
    res = rig.simulator.run(rig.hammer_force(300.0), 2.0, fs)
    placed, phys = channel_signals(rig, res)
    adc = AdcModel(rig.config.daq.adc_bits, rig.config.daq.input_range_volts)
    models = channel_models_for(placed)
    recs = [measure(phys, models, adc, np.random.default_rng(k)).data.astype(float) for k in range(n_hits)]
    sigma1 = rig.structure.damping.modal_coefficients(rig.modes.omega)[0] / 2
    return rig, fs, recs, choose_tau(sigma1, 2.0)


def timed(fn) -> tuple[float, float]:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0, os.getloadavg()[0]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hits", type=int, default=10)
    args = ap.parse_args()
    import pyFRF

    rig, fs, recs, tau = hits(args.hits)
    n = recs[0].shape[0]
    outs = [s.name for s in rig.sensors]
    acc = FRFAccumulator(fs, n, outs, "hammer", tau=tau, f_max=1000.0)
    ours = [timed(lambda r=r: (acc.add(r[:, 0], r[:, 1:]), acc.frf("H1"))) for r in recs]
    w = exponential_window(n, fs, tau)
    warnings.simplefilter("ignore")
    p = None
    theirs = []
    for r in recs:
        exc = (r[:, 0] * force_window(r[:, 0], fs) * w)[None, None, :]
        resp = (r[:, 1:] * w[:, None]).T[None]

        def step(exc=exc, resp=resp):
            nonlocal p
            if p is None:
                p = pyFRF.FRF(int(fs), exc=exc, resp=resp, window="none", resp_type="a")
            else:
                p.add_data(exc, resp)
            p.get_FRF("H1", frf_form="accelerance")
            p.get_coherence()

        theirs.append(timed(step))
    nf = acc.n_f
    diff = float(np.nanmax(np.abs(p.get_FRF("H1", frf_form="accelerance")[:, 0, 1:nf] / acc.frf("H1").H[:, 0, 1:] - 1)))
    rows = {"gvtlink FRFAccumulator": ours, "pyFRF 1.5.0 FRF": theirs}
    print(f"FRF + coherence update per hit: {len(outs) + 1} ch x {fs:g} Hz, {n / fs:g} s records, {args.hits} hits")
    print(f"{'implementation':28s} {'median ms':>10s} {'max ms':>8s} {'loadavg':>8s}")
    out = {"channels": len(outs) + 1, "fs": fs, "record_s": n / fs, "hits": args.hits, "max_rel_diff_h1": diff, "rows": {}}
    for name, t in rows.items():
        ms = np.array([x[0] for x in t]) * 1e3
        load = [x[1] for x in t]
        print(f"{name:28s} {np.median(ms):10.1f} {ms.max():8.1f} {np.median(load):8.2f}")
        out["rows"][name] = {"median_ms": float(np.median(ms)), "max_ms": float(ms.max()), "loadavg": load, "ms": ms.tolist()}
    print(f"H1 agreement (0-1 kHz, DC excluded): max relative difference {diff:.1e}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bench_frf.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
