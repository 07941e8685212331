"""Model updating speed and accuracy (issue 21, "Speed": beam_ch4_exp with four parameters, <= 60 s on 2 cores).

Four parameters of ``beam_ch4_exp``: E, the attachment spring and mass at 0.7 m, and a boundary spring at the
free end (nominal 2000 N/m, added for the bench). Why a boundary spring and not the density: from frequencies
and MAC alone, scaling E, density, attachment mass and spring together changes nothing (K and M scale alike),
so {E, rho, m, k} has a flat direction; a fourth parameter must act somewhere else on the beam
(docs/model-updating.md, "Identifiability").

True rig: each parameter 2-5 % off the nominal (seeded). Measured: its first 8 FE modes (frequencies with
``--noise`` relative noise, shapes at the 14 sensors with 1 % noise), eq45+mac objective, modes 1-6.
Both optimisers are timed (wall time of ``update``: model set-up, search, refinement, Jacobian); the load
average is printed because the machine is shared.

    .venv/bin/python bench/bench_model_update.py [--json bench/results/bench_model_update.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from analysis.model.config import RigConfig, UpdateParameter  # noqa: E402
from analysis.model.rig import build_rig  # noqa: E402
from analysis.model.rigs import open_rig  # noqa: E402
from analysis.model.updating import MeasuredModes, update  # noqa: E402

K_TIP = 2000.0  # N/m at the free end: ~1/5 of the 3EI/L^3 tip stiffness, moves mode 1 by ~3 %


def rig_with_tip_spring(base: RigConfig, factors: dict[str, float] | None = None) -> RigConfig:
    d = base.model_dump()
    d["springs"].append({"x": d["structure"]["length"], "dof": None, "k": K_TIP})
    if factors:
        d["structure"]["youngs_modulus"] *= factors["E"]
        d["springs"][0]["k"] *= factors["k_att"]
        d["point_masses"][0]["mass"] *= factors["m_att"]
        d["springs"][1]["k"] *= factors["k_tip"]
    return RigConfig.model_validate(d)


def params(cfg: RigConfig) -> list[UpdateParameter]:
    return [
        UpdateParameter(name="E", target="structure.youngs_modulus", bounds=(150e9, 230e9)),
        UpdateParameter(name="k_att", target="springs[0].k", bounds=(5000.0, 20000.0)),
        UpdateParameter(name="m_att", target="point_masses[0].mass", bounds=(0.1, 0.3)),
        UpdateParameter(name="k_tip", target="springs[1].k", bounds=(500.0, 8000.0)),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--noise", type=float, default=1e-4, help="relative frequency noise of the 'measured' modes")
    ap.add_argument("--objective", default="eq45", help="eq45 or eq45+mac")
    ap.add_argument("--json", type=Path, default=ROOT / "bench/results/bench_model_update.json")
    a = ap.parse_args()
    base = open_rig("beam_ch4_exp").config
    nominal = rig_with_tip_spring(base)
    rng = np.random.default_rng(2104)
    factors = {k: 1.0 + float(rng.choice([-1.0, 1.0]) * rng.uniform(0.02, 0.05)) for k in ("E", "k_att", "m_att", "k_tip")}
    true = build_rig(rig_with_tip_spring(base, factors))
    f = true.modes.frequencies_hz[:8] * (1 + a.noise * rng.standard_normal(8))
    phi = true.modes.shapes[true.sensor_dofs, :8] * (1 + 0.01 * rng.standard_normal((len(true.sensors), 8)))
    measured = MeasuredModes(f, phi.astype(complex), tuple(s.name for s in true.sensors), "true FE modes + noise")
    truth = np.array([190e9 * factors["E"], 10854.0 * factors["k_att"], 0.171 * factors["m_att"], K_TIP * factors["k_tip"]])
    rows = []
    for optimiser in ("de", "multistart"):
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        res = update(nominal, measured, params(nominal), objective=a.objective, optimiser=optimiser)
        wall = time.perf_counter() - t0
        err = res.values / truth - 1
        sig = res.sigma if res.sigma is not None else np.full(len(res.params), np.nan)
        rows.append({"optimiser": optimiser, "wall_s": wall, "evaluations": res.evaluations,
                     "ms_per_solve": 1e3 * wall / res.evaluations, "objective": res.objective_value,
                     "max_abs_error_pct": float(100 * np.abs(err).max()),
                     "errors_pct": {p.name: float(100 * e) for p, e in zip(res.params, err, strict=True)},
                     "sigma_pct": {p.name: float(100 * s / v) for p, s, v in zip(res.params, sig, res.values, strict=True)},
                     "load_avg": load})  # fmt: skip
    print(f"beam_ch4_exp + tip spring, 4 parameters, {a.objective} on modes 1-6, frequency noise {a.noise:g}, "
          f"{os.cpu_count()} cores, true factors " + ", ".join(f"{k} {v:.4f}" for k, v in factors.items()))  # fmt: skip
    head = f"{'optimiser':<11} {'wall [s]':>9} {'solves':>7} {'ms/solve':>9} {'objective':>10} {'max |err| %':>12}"
    print(head + "  errors % (E, k_att, m_att, k_tip) | 1-sigma %  load")
    for r in rows:
        errs = " ".join(f"{v:+.3f}" for v in r["errors_pct"].values())
        errs += " | " + " ".join(f"{v:.3g}" for v in r["sigma_pct"].values())
        line = (
            f"{r['optimiser']:<11} {r['wall_s']:>9.2f} {r['evaluations']:>7d} {r['ms_per_solve']:>9.2f} {r['objective']:>10.3g}"
        )
        print(line + f" {r['max_abs_error_pct']:>12.3f}  {errs}  {r['load_avg']:.1f}")
    doc = {"bench": "model_update", "python": platform.python_version(), "cores": os.cpu_count(), "noise": a.noise,
           "factors": factors, "target_s": 60.0, "rows": rows}  # fmt: skip
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(doc, indent=1))
    print(f"wrote {a.json}")


if __name__ == "__main__":
    main()
