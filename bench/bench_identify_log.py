"""``gvt identify LOG``: experimental-style NSI (windowed δ̄, seed Ch. 5) on simulated sessions, accuracy and time.

    .venv/bin/python bench/bench_identify_log.py [--hits 20] [--rigs beam_ch4_sim,beam_nes_ch5,lo_store_ch6]

Per rig: the rig with its sensors made accelerometers (beam_ch4_sim: 20 of them, every 5th node, at 4096 Hz),
each channel's noise 1 % of the rms of its noise-free response to the session's weakest hit over one record
(so every hit's records carry at most 1 % noise); a session of ``--hits`` hits at log-spaced forces recorded by
the project's simulator and sensor model into a real MCAP log (``daq.studies.simulate.session``); then ``gvt identify LOG``'s
kernel (``daq.studies.identify.log.identify_log``) with each frequency estimator / law, timed. Prints a table and
writes bench/results/bench_identify_log.json. The test (tests/test_nsi_log.py) uses the same helpers.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: Each rig's truth (α, β of its nonlinear spring), its session's force range and hit spacing (s), and the
#: sample rate the accelerometer variant records at.
CASES: dict[str, dict] = {
    "beam_ch4_sim": {"alpha": 5e8, "beta": 2.0, "forces": (10.0, 150.0), "spacing": 6.0, "record": 5.0, "fs": 4096.0},
    "beam_nes_ch5": {"alpha": 3e9, "beta": 2.0, "forces": (0.3, 300.0), "spacing": 8.0, "record": 7.5, "fs": 4096.0},
    "lo_store_ch6": {
        "alpha": 1.058e10,
        "beta": 2.0,
        "forces": (0.1, 20.0),
        "spacing": 2.0,
        "record": 2.0,
        "fs": 4096.0,
        "hammer_dof": "store",
    },
}
ACC_SENSITIVITY = 0.1  # mV/(m/s^2): a ±1e5 m/s^2 range at 10 V, no hit of these sessions clips


def accelerometer_rig(name: str, tmp: Path, noise: float, ref_force: float, hammer_dof: str | None = None):
    """The rig ``name`` with its displacement sensors made accelerometers (beam_ch4_sim: 20, every 5th node), at
    ``CASES[name]['fs']``, each channel's ``noise_rms`` = ``noise`` × the rms of its noise-free acceleration over
    one record after a ``ref_force`` hit from rest. ``hammer_dof``: move the hammer to that DOF (lumped rigs)."""
    from analysis.model.rig import channel_signals, load_rig

    txt = (ROOT / f"configs/rigs/{name}.toml").read_text()
    if name == "beam_ch4_sim":
        txt = txt.replace("start = 0.01311", "start = 0.06555").replace("count = 100", "count = 20")
    txt = txt.replace('quantity = "displacement"', 'quantity = "acceleration"')
    txt = txt.replace("sensitivity_mv_per_unit = 1000.0", f"sensitivity_mv_per_unit = {ACC_SENSITIVITY}")
    txt = re.sub(r"sample_rate = [0-9.]+", f"sample_rate = {CASES[name]['fs']}", txt)
    # no mode above fs/2.56 (the band an anti-aliased DAQ keeps): the simulator samples without an anti-alias
    # filter, and a 4090 Hz mode's acceleration sampled at 4096 Hz lands at 6 Hz, where the double integration
    # amplifies it (4090/6)^2 = 5e5 times
    txt = re.sub(r"modal_cutoff_hz = [0-9.e]+", f"modal_cutoff_hz = {CASES[name]['fs'] / 2.56:.6g}", txt)
    if "record" in CASES[name]:
        txt = re.sub(r"record_length = [0-9.]+", f"record_length = {CASES[name]['record']}", txt)
    if hammer_dof is not None:
        txt = re.sub(r'(\[hammer\]\n)dof = "\w+"', rf'\1dof = "{hammer_dof}"', txt)
    path = tmp / f"{name}_acc.toml"
    path.write_text(txt)
    rig = load_rig(path)
    if noise > 0:
        res = rig.simulator.run(rig.hammer_force(ref_force), rig.config.daq.record_length, rig.sample_rate)
        rms = np.sqrt((channel_signals(rig, res)[1] ** 2).mean(axis=0))  # hammer first, then the sensors
        names = [s.name for s in rig.sensors]
        out, table = [], ""
        for ln in _expand_arrays(txt, rig).split("\n"):  # one [[sensors]] table per sensor, each with its noise
            table = ln.strip() if ln.startswith("[") else table
            out.append(ln)
            m = re.match(r'name = "(\w+)"', ln)
            if m and table == "[[sensors]]" and m.group(1) in names:
                out.append(f"noise_rms = {noise * rms[names.index(m.group(1)) + 1]:.6g}")
        path.write_text("\n".join(out))
        rig = load_rig(path)
    return rig


def _expand_arrays(txt: str, rig) -> str:
    """``[[sensor_arrays]]`` written out as one ``[[sensors]]`` table per sensor (same props), so that each
    sensor can carry its own noise."""
    m = re.search(r"\[\[sensor_arrays\]\].*?(?=\n\[)", txt, flags=re.S)
    if m is None:
        return txt
    props = {k: v for k, v in re.findall(r"^(quantity|sensitivity_mv_per_unit|model) = (.+)$", m.group(0), flags=re.M)}
    prefix = re.search(r'prefix = "(\w+)"', m.group(0)).group(1)  # type: ignore[union-attr]
    tabs = []
    for s in rig.sensors:
        if s.name.startswith(prefix) and s.x_model is not None:
            body = "\n".join(f"{k} = {v}" for k, v in props.items())
            tabs.append(f'[[sensors]]\nname = "{s.name}"\nx = {s.x_model!r}\n{body}\n')
    return txt[: m.start()] + "\n".join(tabs) + txt[m.end() :]


def record_session(rig, log: Path, forces: tuple[float, ...], spacing: float, seed: int = 1) -> dict:
    """The hits at ``forces`` (N, in this order) ``spacing`` s apart, recorded into the MCAP log at ``log``."""
    from daq.studies.simulate.session import SessionPlan, simulate_session

    plan = SessionPlan(
        forces=tuple(float(f) for f in forces), pre_trigger=0.1, spacing=spacing, tail=spacing + 2.0, block_size=1024
    )
    return simulate_session(rig, log, plan, seed=seed)


def session_forces(name: str, n_hits: int) -> tuple[float, ...]:
    lo, hi = CASES[name]["forces"]
    return tuple(float(f) for f in np.geomspace(lo, hi, n_hits))


def run_case(name: str, n_hits: int, tmp: Path, noise: float = 0.01, variants=(("pom", "exact"), ("pom", "hb"), ("rq", "seed")),
             window_s: float | None = None, n_boot: int = 200, seed: int = 1,
             max_ratios: tuple[float | None, ...] = (None, 1.5)) -> list[dict]:  # fmt: skip
    """Record the session, run ``gvt identify LOG``'s kernel once (timed, with the CLI's default bootstrap, on the
    first variant), then refit its windows for the other variants and ``--max-ratio`` values."""
    from analysis.errors import BadInput
    from daq.studies.identify.log import identify_log
    from daq.studies.identify.sweep import IdentifyOptions, identify_runs

    c = CASES[name]
    forces = session_forces(name, n_hits)
    t0 = time.perf_counter()
    rig = accelerometer_rig(name, tmp, noise, min(forces), c.get("hammer_dof"))
    log = tmp / f"{name}-{seed}.mcap"
    record_session(rig, log, forces, c["spacing"], seed)
    sim_s = time.perf_counter() - t0
    t = time.perf_counter()
    freq, law = variants[0]
    run = identify_log(rig, log, IdentifyOptions(frequency=freq, law=law, n_boot=n_boot), window_s=window_s)
    id_s = time.perf_counter() - t
    rows = []
    for mr in max_ratios:
        for freq, law in variants:
            opts = IdentifyOptions(frequency=freq, law=law, n_boot=0, max_ratio=mr)
            try:
                f = (
                    run.ident.fit
                    if (freq, law) == variants[0] and mr is None
                    else identify_runs(rig, run.ident.target, run.ident.runs, opts, "").fit
                )
            except BadInput as exc:  # e.g. --max-ratio leaves no point of the RQ curve
                rows.append({"rig": name, "seed": seed, "max_ratio": mr, "frequency": freq, "law": law, "error": str(exc)})
                continue
            rows.append({
                "rig": name, "hits": n_hits, "noise": noise, "seed": seed, "max_ratio": mr, "frequency": freq, "law": law,
                "windows": int(run.window_hit.size), "capture": int(run.ident.runs.capture.sum()), "fit": f.mode,
                "n_points": f.n_points, "alpha": f.alpha, "beta": f.beta, "alpha_err": f.alpha / c["alpha"] - 1,
                "beta_err": f.beta / c["beta"] - 1, "r2": f.r2, "alpha_ci": list(f.alpha_ci), "beta_ci": list(f.beta_ci),
                "window_s": run.settings.window_s, "identify_s": id_s, "session_s": sim_s,
                "dbar_range": [float(run.ident.runs.dbar.min()), float(run.ident.runs.dbar.max())],
            })  # fmt: skip
    return rows


def main() -> None:
    import tempfile

    ap = argparse.ArgumentParser()
    ap.add_argument("--hits", type=int, default=20)
    ap.add_argument("--rigs", default="beam_ch4_sim,beam_nes_ch5,lo_store_ch6")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--seeds", default="1,2", help="noise seeds, one session each")
    ap.add_argument("--laws", default="exact,hb", help="the POM-frequency laws refitted (the first is timed); rq/seed is added")
    ap.add_argument("--out", default="bench/results/bench_identify_log.json")
    a = ap.parse_args()
    variants = (*(("pom", law) for law in a.laws.split(",")), ("rq", "seed"))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name in a.rigs.split(","):
            for seed in (int(x) for x in a.seeds.split(",")):
                new = run_case(name, a.hits, Path(d), a.noise, variants=variants, seed=seed)
                rows += new
                r = new[0]
                print(
                    f"{name} seed {seed}: session {r['session_s']:.1f} s, gvt identify {r['identify_s']:.1f} s, "
                    f"{r['windows']} windows",
                    flush=True,
                )
    print(f"\n{'rig':13s} {'seed':>4s} {'freq':4s} {'law':11s} {'maxr':>4s} {'win':>4s} {'pts':>4s} {'fit':13s} {'alpha':>10s} "
          f"{'a err':>8s} {'beta':>7s} {'b err':>7s} {'R2':>6s} {'id s':>5s}")  # fmt: skip
    for r in rows:
        mr = "-" if r["max_ratio"] is None else f"{r['max_ratio']:g}"
        if "error" in r:
            print(f"{r['rig']:13s} {r['seed']:4d} {r['frequency']:4s} {r['law']:11s} {mr:>4s} {r['error']}")
            continue
        print(f"{r['rig']:13s} {r['seed']:4d} {r['frequency']:4s} {r['law']:11s} {mr:>4s} {r['windows']:4d} {r['n_points']:4d} "
              f"{r['fit']:13s} {r['alpha']:10.4g} {100 * r['alpha_err']:+7.1f}% {r['beta']:7.4f} {100 * r['beta_err']:+6.1f}% "
              f"{r['r2']:6.3f} {r['identify_s']:5.1f}")  # fmt: skip
    out = ROOT / a.out
    out.write_text(json.dumps({"hits": a.hits, "noise": a.noise, "cases": CASES, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
