"""``gvt demo``: what exists so far, run honestly on the experimental beam rig.

Builds the rig, prints its modes in both energy limits, the FRF peaks and identified modes of a few weak
(linear) hits against the FE modes, simulates a strong and a weak hammer hit
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
from daq.studies.modes import modes_report, print_modes
from daq.studies.simulate.hit import simulate_hit

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
    linear = run_demo_linear(console, rig, hits["weak"])
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
    return {"freqs": {k: v.tolist() for k, v in freqs.items()}, "energies": energies, "session": session, "linear": linear}


#: N, the demo session's first three hits: at 30 N the cubic spring moves mode 1 by (30/150)^2 of its +1.5 % at
#: 150 N, ~0.06 %, and the peak clears the 20 N trigger with the ADC's noise far below
DEMO_WEAK_N = 30.0
LINEAR_HITS = 3  # averages: enough for a coherence that means something, few enough to keep the demo's time
LINEAR_SPACING_S = 3.0  # s between the weak hits: the FRF record is the rig's record length or this, the shorter


def run_demo_linear(console: Console, rig: Rig, force: float) -> dict:
    """FRFs and modes of a few weak (linear) hits, before the nonlinear part of the demo: the test an impact
    hammer exists for (issue 20), with ``gvt frf`` / ``gvt modal``'s code on a simulated log (deleted after).

    Weak: at ``WEAK_FRACTION`` of the nominal force the cubic spring hardly acts (the weak hit's NNM1 stays at
    the linear frequency, printed below), so the rig's linear FE modes are the right oracle."""
    import tempfile
    from pathlib import Path

    from analysis.errors import BadInput
    from daq.studies.frf import frf_from_log, peak_rows
    from daq.studies.modal import driving_points, modal_from_frf, table_text
    from daq.studies.simulate.session import SessionPlan, simulate_session

    t0 = time.perf_counter()
    plan = SessionPlan(forces=(force,) * LINEAR_HITS, pre_trigger=0.1, spacing=LINEAR_SPACING_S, tail=LINEAR_SPACING_S,
                       block_size=1024)  # fmt: skip
    try:
        with tempfile.TemporaryDirectory(prefix="gvt_demo_") as tmp:
            log = Path(tmp) / "linear.mcap"
            simulate_session(rig, log, plan)
            run = frf_from_log(log, rig)
            if run.frf is None:
                raise BadInput(f"no weak hit was accepted: {'; '.join(h['reason'] for h in run.hits)}")
            modal = modal_from_frf(run.frf, rig, 2.0, min(run.band_hz, float(run.frf.freq[-1])), source="demo")
    except BadInput as exc:
        console.print(f"  FRFs of weak hits: not available on this rig ({exc})", markup=False)
        return {}
    f = run.frf
    dp = driving_points(rig, f).get(f.references[0], f.outputs[0])
    console.print(
        f"\n[bold]Linear (weak) hits first[/bold]: {LINEAR_HITS} hits of {force:g} N, {f.kind} {escape(f.quantity)} "
        f"averaged over {int(f.n_averages[0])}, record {run.record_s:g} s (Δf {1 / run.record_s:g} Hz), "
        f"exponential window τ {run.tau_s or 0:.3f} s (its damping removed below)"
    )
    table = Table(title=escape(f"FRF peaks at the driving point {dp} (reference {f.references[0]}) [{f.units}]"))
    for c in ("f [Hz]", "|H|", "phase [°]", "coherence", "lowest coherence, all responses"):
        table.add_column(escape(c), justify="right")
    rows = [r for r in peak_rows(f) if r["response"] == dp]
    for r in rows:
        k = int(abs(f.freq - r["freq_hz"]).argmin())
        table.add_row(f"{r['freq_hz']:.2f}", f"{r['mag']:.4g}", f"{r['phase_deg']:.1f}", f"{r['coherence']:.4f}",
                      f"{f.coherence[:, 0, k].min():.4f}")  # fmt: skip
    console.print(table)
    console.print("  modes identified (pLSCF + LSFD) against the rig's FE modes:", markup=False)
    console.print(table_text(modal), markup=False)
    console.print(f"  FRFs and modes of the weak hits in {time.perf_counter() - t0:.1f} s; the same from any log: "
                  "gvt frf LOG, gvt modal LOG, gvt report LOG", markup=False)  # fmt: skip
    return {"averages": int(f.n_averages[0]), "peaks_hz": [r["freq_hz"] for r in rows], "modes": modal.rows}


def run_demo_session(console: Console, rig: Rig, out: str = "demo_session.mcap", overwrite: bool = False) -> dict:
    """A short recorded session: simulated device over a real pty → serial driver → MCAP + hit gate."""
    from pathlib import Path

    from daq.config.session import DeviceSpec, SessionConfig, SimulateSpec, TriggerSpec
    from daq.session import run_session

    # A GVT's linearity check first: three weak hits (the FRFs `gvt frf` / `gvt modal` average by default, the
    # cubic spring barely engaged: mode 1 within 0.05 % of the linear FE model), then the rising forces whose
    # internal resonances the live analysis flags, with one double hit and one overload for the hit gate.
    forces = [*(DEMO_WEAK_N,) * 3, 150.0, 400.0, 700.0, 1000.0, 1300.0, 2600.0, 1583.0]
    cfg = SessionConfig(
        name="gvt demo", rig=rig.path, output=out, duration=0.2 + 0.5 * len(forces) + 0.4,
        device=DeviceSpec(driver="serial", simulate=SimulateSpec(forces=forces, double_hits=[5], period=0.5, seed=1)),
        trigger=TriggerSpec(level=20.0, record_length=0.3, force_range=(20.0, 2000.0), driving_point="a13"),
    )  # fmt: skip
    console.print(
        f"\n[bold]Recording a session[/bold]: simulated device over a pseudo-terminal → serial driver → {out} "
        f"(3 weak hits of {DEMO_WEAK_N:g} N for the linear FRFs, then {len(forces) - 3} at rising force, one double "
        "hit, one overload)"
    )
    res = run_session(cfg, rig, Path(out), overwrite=overwrite)
    from daq.terminal import hits_table

    console.print(hits_table(res.hits, f"hits and verdicts ({len(res.hits)} found)"))
    from daq.studies.analyze.tables import events_table

    console.print(events_table(res.analysis_events, "internal-resonance events flagged near-live"))
    if res.confirmations:
        from daq.studies.confirm import confirmations_table

        console.print(confirmations_table(sorted(res.confirmations, key=lambda r: r.get("event_id") or 0),
                                          "confirmed in the background (WBEMD + slow flow; seed Ch. 3)"))  # fmt: skip
    lost = "nothing lost" if res.lost_samples == 0 else f"{res.lost_samples} samples lost (reported as gaps)"
    console.print(
        f"  {res.samples} samples x 15 channels recorded in {res.seconds:.1f} s, {lost}; suspect channels: "
        f"{', '.join(res.suspects) or 'none'}. Inspect it: gvt log info {out}  ·  replay: gvt replay {out}"
    )
    console.print(f"  analyse it again (same kernels, batch): gvt analyze {out}")
    rrd = str(Path(out).with_suffix(".rrd"))
    from daq.lanes.view import ViewError, rerun_cli
    from daq.studies.analyze.rrd import build_rrd

    build_rrd(out, rrd, rig=rig)
    try:
        viewer = rerun_cli()
    except ViewError:
        viewer = "rerun"
    console.print(f"  rerun recording: {rrd} — open it with: {viewer} {rrd}", markup=False)
    console.print(f"  static report: gvt report {out} --out report.html", markup=False)
    events = res.analysis_events
    return {"hits": [h.verdict for h in res.hits], "lost": res.lost_samples, "path": out, "events": events, "rrd": rrd}
