"""``gvt demo``: what exists so far, run honestly on the experimental beam rig.

Builds the rig, prints its modes in both energy limits, simulates a strong and a weak hammer hit
through the sensor/DAQ model, and prints how NNM1's frequency moves with energy (ground truth from the
simulator's modal coordinates). Sessions over real transports and MCAP logs arrive with later issues.
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from analysis.model.rig import Rig
from analysis.model.truth import zero_crossing_frequency
from daq.modes_report import modes_report, print_modes
from daq.simulate_cmd import simulate_hit

WEAK_FRACTION = 0.02


def run_demo(console: Console, rig: Rig, duration: float | None = None, session_out: str = "demo_session.mcap",
             overwrite: bool = False) -> dict:  # fmt: skip
    dur = rig.config.daq.record_length if duration is None else duration
    red = rig.simulator.reduced
    console.print(f"[bold]gvt demo[/bold] — rig {rig.name}: {rig.config.description}")
    console.print(
        f"  {rig.structure.n_dof} DOFs, {len(rig.sensors)} sensors, hammer at {rig.hammer.dof_name}, "
        f"{rig.sample_rate:g} Hz, simulator: {red.n_modes} modes <= "
        f"{red.cutoff_hz:g} Hz + {red.n_basis - red.n_modes} residual vector(s)"
    )
    low = modes_report(rig, "low", 6)
    high = modes_report(rig, "high", 6)
    print_modes(console, low)
    print_modes(console, high)
    t0 = time.perf_counter()
    rig.simulator.run(rig.hammer_force(), 4.0 / rig.sample_rate, rig.sample_rate)  # JIT warm-up
    compile_s = time.perf_counter() - t0
    if compile_s > 1.0:
        console.print(f"  compiled the simulator kernels in {compile_s:.1f} s (numba; cached for later runs)")
    strong = rig.config.hammer.peak_force
    hits = {"strong": strong, "weak": strong * WEAK_FRACTION}
    centres = np.array([0.05, 0.25, 0.5, 1.0, 1.5, 1.95]) * dur / 2.0
    table = Table(title=escape(f"NNM1 frequency [Hz] after the hit (ground truth, {dur:g} s records)"))
    table.add_column(escape("t [s]"), justify="right")
    freqs = {}
    energies = {}
    for label, f in hits.items():
        t0 = time.perf_counter()
        res, _models, meas, _ = simulate_hit(rig, f, dur)
        dt = time.perf_counter() - t0
        freqs[label] = zero_crossing_frequency(res.modal_q[0, :, 0], res.t, centres, 0.05 * dur / 2.0)
        energies[label] = float(res.energy.input_work[0, -1])
        clipped = {k: v for k, v in meas.clip_counts.items() if v}
        console.print(
            f"  {label} hit: {f:g} N peak, {energies[label]:.4g} J in, energy budget closes to "
            f"{np.max(np.abs(res.energy.closure_error)):.1e} J, clipped channels: {clipped or 'none'}, "
            f"simulated {dur:g} s in {dt:.2f} s"
        )
        table.add_column(f"{label} ({f:g} N)", justify="right")
    for i, c in enumerate(centres):
        table.add_row(f"{c:.3f}", *(f"{freqs[k][i]:.2f}" for k in hits))
    console.print(table)
    f0 = low["modes"][0]["frequency_hz"]
    console.print(
        f"  linear NNM1 {f0:.2f} Hz; the strong hit starts {freqs['strong'][0] - f0:+.1f} Hz above it and "
        f"relaxes towards it as energy dissipates; the weak hit stays linear ({freqs['weak'][0]:.2f} Hz)."
    )
    session = run_demo_session(console, rig, session_out, overwrite) if rig.name == "beam_ch4_exp" else None
    return {"freqs": {k: v.tolist() for k, v in freqs.items()}, "energies": energies, "session": session}


def run_demo_session(console: Console, rig: Rig, out: str = "demo_session.mcap", overwrite: bool = False) -> dict:
    """A short recorded session: simulated device over a real pty → serial driver → MCAP + hit gate."""
    from pathlib import Path

    from daq.config.session import DeviceSpec, SessionConfig, SimulateSpec, TriggerSpec
    from daq.session import run_session

    forces = [150.0, 400.0, 700.0, 1000.0, 1300.0, 2600.0, 1583.0]
    cfg = SessionConfig(
        name="gvt demo", rig=rig.path, output=out, duration=0.2 + 0.5 * len(forces) + 0.4,
        device=DeviceSpec(driver="serial", simulate=SimulateSpec(forces=forces, double_hits=[2], period=0.5, seed=1)),
        trigger=TriggerSpec(level=20.0, record_length=0.3, force_range=(100.0, 2000.0), driving_point="a13"),
    )  # fmt: skip
    console.print(
        f"\n[bold]Recording a session[/bold]: simulated device over a pseudo-terminal → serial driver → {out} "
        f"({len(forces)} hits at rising force, one double hit, one overload)"
    )
    res = run_session(cfg, rig, Path(out), overwrite=overwrite)
    from daq.terminal import hits_table

    console.print(hits_table(res.hits, f"hits and verdicts ({len(res.hits)} found)"))
    from daq.analyze_cmd import events_table

    console.print(events_table(res.analysis_events, "internal-resonance events flagged near-live"))
    if res.confirmations:
        from daq.confirm_cmd import confirmations_table

        console.print(confirmations_table(sorted(res.confirmations, key=lambda r: r.get("event_id") or 0),
                                          "confirmed in the background (WBEMD + slow flow; seed Ch. 3)"))  # fmt: skip
    lost = "nothing lost" if res.lost_samples == 0 else f"{res.lost_samples} samples lost (reported as gaps)"
    console.print(
        f"  {res.samples} samples x 15 channels recorded in {res.seconds:.1f} s, {lost}; suspect channels: "
        f"{', '.join(res.suspects) or 'none'}. Inspect it: gvt log info {out}  ·  replay: gvt replay {out}"
    )
    console.print(f"  analyse it again (same kernels, batch): gvt analyze {out}")
    rrd = str(Path(out).with_suffix(".rrd"))
    from daq.view.build import build_rrd
    from daq.view.lane import ViewError, rerun_cli

    build_rrd(out, rrd, rig=rig)
    try:
        viewer = rerun_cli()
    except ViewError:
        viewer = "rerun"
    console.print(f"  rerun recording: {rrd} — open it with: {viewer} {rrd}", markup=False)
    console.print(f"  static report: gvt report {out} --out report.html", markup=False)
    events = res.analysis_events
    return {"hits": [h.verdict for h in res.hits], "lost": res.lost_samples, "path": out, "events": events, "rrd": rrd}
