"""``gvt simulate``: a simulated session log with ground truth, or one hit as .npz."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, Progress, RigArg, check_output, fail, open_rig, out


def simulate(
    rig: RigArg,
    force: Annotated[
        float | None, typer.Option(min=0.0, help="Peak hammer force, N (one hit; default: the rig's nominal).")
    ] = None,
    duration: Annotated[
        float | None, typer.Option(min=1e-6, help="Seconds to simulate (one hit; default: record length).")
    ] = None,
    out_path: Annotated[Path, typer.Option("--out", help="Output file: .mcap for a session log, .npz for one hit.")] = Path(
        "session.mcap"
    ),
    hits: Annotated[int, typer.Option(min=1, max=1000, help="Hits in a session (.mcap): rising force to the nominal.")] = 1,
    forces: Annotated[str | None, typer.Option(help="Comma-separated peak forces, N, one per hit (overrides --hits).")] = None,
    spacing: Annotated[float | None, typer.Option(min=0.01, help="Seconds between hits (default: record length).")] = None,
    seed: Annotated[int | None, typer.Option(help="Noise seed (default: the rig's).")] = None,
    overwrite: OverwriteOpt = False,
) -> None:
    """Simulate hammer hits: a session log (.mcap) with ground truth, or one hit as .npz."""
    r = open_rig(rig)
    if out_path.suffix not in (".mcap", ".npz"):
        fail(f"--out {out_path}: use .mcap (session log) or .npz (one hit)")
    peaks = _peaks(forces) if forces else None
    _check_flags(r, force, peaks, duration, spacing, one_hit=out_path.suffix == ".npz")
    check_output(out_path, overwrite)
    if out_path.suffix == ".npz":
        from daq.studies.simulate.hit import simulate_to_npz

        out.print(simulate_to_npz(r, out_path, force=force, duration=duration, seed=seed))
        return
    if out_path.suffix != ".mcap":
        fail(f"--out {out_path}: use .mcap (session log) or .npz (one hit)")
    from daq.studies.simulate.session import SessionPlan, default_forces, simulate_session

    if peaks is not None:
        pass
    elif force is not None:
        peaks = (force,) * hits
    else:
        peaks = default_forces(r, hits)
    rec = r.config.daq.record_length
    plan = SessionPlan(forces=peaks, pre_trigger=0.1, spacing=spacing or rec, tail=duration or rec, block_size=1024)
    with Progress(out) as report:
        summary = simulate_session(r, out_path, plan, seed=seed, progress=report, writer_kwargs={"overwrite": overwrite})
    clip = ", ".join(f"{k}: {v}" for k, v in summary["clipped"].items()) or "none"
    out.print(
        f"wrote {out_path}: {summary['hits']} hits, {summary['samples']} samples x {summary['channels']} channels "
        f"({summary['duration_s']:.2f} s); input energies {', '.join(f'{x:.3g}' for x in summary['energies_J'])} J; "
        f"clipped: {clip}",
        markup=False,
    )


def _peaks(forces: str) -> tuple[float, ...]:
    try:
        peaks = tuple(float(x) for x in forces.split(",") if x.strip())
    except ValueError:
        fail(f"--forces {forces!r}: expected comma-separated numbers, e.g. 30,1583")
    if not peaks:
        fail("--forces: give at least one non-negative force")
    return peaks


def _check_flags(r, force, peaks, duration, spacing, one_hit: bool) -> None:
    """The flags meet the limits a config file meets (analysis/model/config.py, daq/config/session.py), before
    any work: a 1e30 N hit took 20 s to give an npz of NaN energies, ``nan`` a log of NaN, and ``--duration 1e9``
    an allocation failure reported as an internal error (issue 30)."""
    import math

    from analysis.model.config import MAX_FORCE_N, MAX_SIMULATED_CHANNEL_SAMPLES
    from daq.config.session import MAX_DURATION_S

    for what, values in (("--force", () if force is None else (force,)), ("--forces", peaks or ())):
        for f in values:
            if not (math.isfinite(f) and 0 <= f <= MAX_FORCE_N):
                fail(f"{what} {f:g}: outside 0 .. {MAX_FORCE_N:g} N (the simulator's cost grows with the force)")
    for what, v in (("--duration", duration), ("--spacing", spacing)):
        if v is not None and not (math.isfinite(v) and v <= MAX_DURATION_S):
            fail(f"{what} {v:g} s: above the limit of {MAX_DURATION_S:g} s (one week)")
    if one_hit and duration is not None:  # one hit is computed whole, in memory: the rig's record limit
        fs, channels = r.sample_rate, len(r.sensor_dofs) + 1
        if duration * fs * channels > MAX_SIMULATED_CHANNEL_SAMPLES:
            fail(f"--duration {duration:g} s: {duration * fs * channels:.3g} channel-samples at {fs:g} Hz x {channels} "
                 f"channels, above the limit of {MAX_SIMULATED_CHANNEL_SAMPLES} (~1 GB to simulate); shorten it, "
                 "or write a session log (.mcap), which is simulated in segments")  # fmt: skip
