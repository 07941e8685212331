"""Modal identification speed and agreement: gvtlink's pLSCF beside sdypy-EMA's LSCF on the same FRFs.

FRFs: ``beam_ch4_exp``'s linear model (its FE modes below 5 kHz and its modal damping), accelerance at the
14 sensors for 2 references (the hammer point 0.7 m and sensor a05 at 0.266 m), 0-1 kHz at 0.5 Hz (2001
lines), 1 % proportional complex noise (seed 20) -- the issue's benchmark case.

What is compared (sdypy-EMA is single-reference only, so it gets the first reference's 14 FRFs):

* ``gvtlink plscf``: pLSCF for model orders 1..60 with both references (order p gives 2p poles) plus
  the stabilisation labels -- the stabilisation diagram "up to model order 60".
* ``gvtlink identify``: the whole chain (stabilisation, auto pick, LSFD, shapes, MPC/MPD).
* ``sdypy-EMA lscf p30``: ``Model(pol_order_high=30).get_poles('lscf')``: its loop runs polynomial orders
  2, 4, ..., 60, i.e. up to 60 poles (its documented meaning of "order 60").
* ``sdypy-EMA lscf p60``: ``pol_order_high=60``: orders 2..120, up to 120 poles -- the same largest pole
  count as gvtlink's order 60 with 2 references.
* ``+ select``: sdypy's own stabilisation and pole pick (``select_closest_poles``, f_window = 10 Hz; see
  docs/modal-id.md for why not the default 50) at gvtlink's selected frequencies.

Each timing is the median of ``--repeat`` runs; ``os.getloadavg()`` is printed beside it because the
machine is shared. sdypy is timed twice: with the default BLAS threads and with one BLAS thread (the
setting gvtlink's loop uses internally), so neither side is helped by the thread setting alone.

    .venv/bin/python bench/bench_modal_id.py [--repeat 5] [--json bench/results/bench_modal_id.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from analysis.lsfd import modal_frf  # noqa: E402
from analysis.modal_id import Criteria, fe_modes_at_sensors, identify_arrays, stabilisation  # noqa: E402
from analysis.model.rig import load_rig  # noqa: E402
from analysis.plscf import plscf  # noqa: E402


def beam_frfs(seed: int = 20):
    rig = load_rig(ROOT / "configs/rigs/beam_ch4_exp.toml")
    modes = rig.modes
    keep = modes.frequencies_hz < 5000.0
    zeta = rig.structure.damping.ratios(len(modes))[keep]
    phi = modes.shapes[:, keep]
    refs = [rig.hammer.dof, rig.sensor_dofs[4]]
    freq = np.arange(0.0, 1000.0 + 1e-9, 0.5)
    H = modal_frf(freq, modes.omega[keep], zeta, phi[rig.sensor_dofs], phi[refs], "accelerance")
    rng = np.random.default_rng(seed)
    H = H * (1 + 0.01 / np.sqrt(2) * (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)))
    return rig, freq, H


def timed(fn, repeat: int) -> tuple[float, float, object]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), os.getloadavg()[0], out


def sdypy_run(EMA, freq, H0, poh: int, select_at=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = EMA.Model(frf=H0, freq=freq, lower=2, upper=1000, pol_order_high=poh, frf_form="accelerance")
        m.get_poles("lscf", show_progress=False)
        if select_at is not None:
            m.select_closest_poles(select_at, f_window=10)
    return m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", type=Path, default=ROOT / "bench/results/bench_modal_id.json")
    args = ap.parse_args()
    from sdypy import EMA
    from threadpoolctl import threadpool_limits

    rig, freq, H = beam_frfs()
    rows = []

    def add(name, fn, **extra):
        t, load, out = timed(fn, args.repeat)
        rows.append({"case": name, "seconds": t, "loadavg_1min": load, **extra})
        print(f"{name:<40} {t * 1000:9.1f} ms   load {load:4.2f}")
        return out

    add("gvtlink plscf orders 1..60, 2 refs", lambda: stabilisation(plscf(freq, H, 2, 1000, 60), Criteria()))
    add("gvtlink plscf orders 1..60, 1 ref", lambda: stabilisation(plscf(freq, H[:, :1], 2, 1000, 60), Criteria()))
    res = add("gvtlink identify (2 refs, all steps)", lambda: identify_arrays(freq, H, "accelerance", 2, 1000, driving=[12, 4]))
    res1 = identify_arrays(freq, H[:, :1], "accelerance", 2, 1000, driving=[12])
    H0 = H[:, 0]
    add("sdypy-EMA lscf p30 (orders 2..60)", lambda: sdypy_run(EMA, freq, H0, 30))
    add("sdypy-EMA lscf p60 (orders 2..120)", lambda: sdypy_run(EMA, freq, H0, 60), note="same pole count as 60 x 2 refs")
    with threadpool_limits(1, "blas"):
        add("sdypy-EMA lscf p30, 1 BLAS thread", lambda: sdypy_run(EMA, freq, H0, 30))
        add("sdypy-EMA lscf p60, 1 BLAS thread", lambda: sdypy_run(EMA, freq, H0, 60))
    m = add("sdypy-EMA lscf p30 + select", lambda: sdypy_run(EMA, freq, H0, 30, res.freq_hz))
    add("sdypy-EMA lscf p60 + select", lambda: sdypy_run(EMA, freq, H0, 60, res.freq_hz))
    by = {r["case"]: r["seconds"] for r in rows}
    ratios = {
        "gvt plscf 2 refs / sdypy p60 (same largest pole count)": by["gvtlink plscf orders 1..60, 2 refs"]
        / by["sdypy-EMA lscf p60 (orders 2..120)"],
        "gvt identify 2 refs / sdypy p60 + select (whole chain each)": by["gvtlink identify (2 refs, all steps)"]
        / by["sdypy-EMA lscf p60 + select"],
    }
    print()
    for k, v in ratios.items():
        print(f"{k:<62} {v:5.2f}  ({'faster' if v < 1 else 'slower'})")

    f_fe, z_fe, _ = fe_modes_at_sensors(rig, 6)
    print("\nmode   FE [Hz]   gvt 2ref   gvt 1ref   sdypy    d(sdypy-gvt1) %   zeta FE   gvt 2ref  gvt 1ref  sdypy")
    agree = []
    for k in range(6):
        d = 100 * (m.nat_freq[k] / res1.freq_hz[k] - 1)
        agree.append(
            {
                "mode": k + 1,
                "fe_hz": f_fe[k],
                "gvt_2ref_hz": res.freq_hz[k],
                "gvt_1ref_hz": res1.freq_hz[k],
                "sdypy_hz": float(m.nat_freq[k]),
                "diff_pct": d,
                "zeta_fe": z_fe[k],
                "zeta_gvt_2ref": res.zeta[k],
                "zeta_gvt_1ref": res1.zeta[k],
                "zeta_sdypy": float(m.nat_xi[k]),
            }
        )
        print(
            f"{k + 1:>4} {f_fe[k]:9.3f} {res.freq_hz[k]:10.3f} {res1.freq_hz[k]:10.3f} {m.nat_freq[k]:9.3f} {d:12.4f}"
            f"      {z_fe[k]:.5f}   {res.zeta[k]:.5f}   {res1.zeta[k]:.5f}  {m.nat_xi[k]:.5f}"
        )
    out = {
        "bench": "modal_id",
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "repeat": args.repeat,
        "frfs": {"outputs": 14, "references": 2, "lines": int(freq.size), "band_hz": [2, 1000], "noise": 0.01},
        "timings": rows,
        "ratios": ratios,
        "agreement": agree,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1, default=float))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
