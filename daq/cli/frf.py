"""``gvt frf``: FRFs, coherence and hammer checks of a session's hits (daq/studies/frf.py, docs/frf.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, Progress, check_output, err, open_rig, out


def frf(
    log: Annotated[Path, typer.Argument(help="Session log (.mcap).")],
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    plot_path: Annotated[Path | None, typer.Option("--plot", help="Write FRF, coherence and hammer spectra to this PNG.")] = None,
    out_path: Annotated[Path | None, typer.Option("--out", help="Write the FRFs (FRFSet) to this .npz.")] = None,
    reference: Annotated[str | None, typer.Option(help="Force channel (default: the rig's hammer).")] = None,
    channels: Annotated[str | None, typer.Option(help="Comma-separated response channels (default: all).")] = None,
    show: Annotated[str | None, typer.Option(help="Response drawn beside the first one in --plot (default: the last).")] = None,
    rig: Annotated[str | None, typer.Option(help="Rig name or TOML (default: the rig attached to the log).")] = None,
    band: Annotated[
        float | None,
        typer.Option(min=1.0, help="Band of interest, Hz (a hit's -10 dB must reach it); default 1000 or fs/2.56."),
    ] = None,
    kind: Annotated[str, typer.Option(help="Estimator: H1, H2 or Hv.")] = "H1",
    quantity: Annotated[str, typer.Option(help="accelerance, mobility or receptance.")] = "accelerance",
    peaks: Annotated[int, typer.Option(min=1, max=50, help="Peaks in the table.")] = 6,
    overwrite: OverwriteOpt = False,
) -> None:
    """FRFs (H1/H2/Hv) and coherence of the accepted hits, averaged; each hit's hammer checks and verdict."""
    import json

    from daq.log.reader import LogReader
    from daq.log.rig import rig_from_log
    from daq.outputs import atomic_output
    from daq.studies.frf import frf_from_log, plot, summary

    for p, what in ((plot_path, "--plot"), (out_path, "--out")):
        if p is not None:
            check_output(p, overwrite, what, inputs=[log])
    r = open_rig(rig) if rig is not None else rig_from_log(LogReader(log))
    chans = [c.strip() for c in channels.split(",") if c.strip()] if channels else None
    console = err if json_out else out
    with Progress(console) as report:
        run = frf_from_log(log, r, reference=reference, channels=chans, band_hz=band, kind=kind, quantity=quantity,
                           progress=lambda f: report("hits", f))  # fmt: skip
    s = summary(run, peaks)
    if json_out:
        out.print_json(json.dumps(s, default=float))
    else:
        _print(s)
    if out_path is not None and run.frf is not None:
        with atomic_output(out_path) as tmp:
            run.frf.to_npz(tmp)
        console.print(f"wrote {out_path}", markup=False)
    if plot_path is not None:
        with atomic_output(plot_path) as tmp:
            plot(run, tmp, show)
        console.print(f"wrote {plot_path}", markup=False)


def _print(s: dict) -> None:
    from daq.terminal import Col, FitTable

    w = s["window"]
    tau = f"tau {w['tau_s']:.3f} s (adds {w['sigma_added']:.2f} 1/s to every pole's decay)" if w.get("tau_s") else "none"
    refs = s["references"]
    if not refs:
        out.print(f"{s['rig']} · {s['log']}: no accepted hit, no FRF", markup=False)
    else:
        each = ", ".join(f"{r['name']} {r['averages']}" for r in refs)
        who = f"{len(refs)} hit points ({each} averages)"
        if len(refs) == 1:
            who = f"reference {s['reference']}, {s['averages']} averages"
        out.print(f"{s['rig']} · {s['log']}: {s['kind']} {s['quantity']} [{s['units']}], {who}; record {s['record_s']:.3f} s "
                  f"(df {s['df_hz']:.3f} Hz), exponential window {tau}", markup=False)  # fmt: skip
    for p in s.get("plan_points", []):
        if p.get("accepted", 0) < p["averages"]:
            out.print(f"hit point {p['name']}: {p.get('accepted', 0)} of {p['averages']} averages", markup=False)
    many = len(refs) > 1
    cols = [Col("f [Hz]", "right", key=True), *([Col("point", key=True)] if many else []), Col("response", key=True),
            Col("|H|", "right"), Col("phase [deg]", "right"), Col("coherence", "right")]  # fmt: skip
    t = FitTable("peaks", cols)
    for p in s["peaks"]:
        t.add_row(f"{p['freq_hz']:.2f}", *([p["reference"]] if many else []), p["response"], f"{p['mag']:.4g}",
                  f"{p['phase_deg']:.1f}", f"{p['coherence']:.4f}")  # fmt: skip
    out.print(t)
    for o, c in s.get("fewer_averages", {}).items():
        out.print(f"{o}: {c} of {s['averages']} averages (left out of the hits where the gate found it clipped or dead)",
                  markup=False)  # fmt: skip
    for h in s["hits"]:
        if h["verdict"] != "accepted":
            at = f" at {h['point']}" if h.get("point") else ""
            out.print(f"hit {h['hit']}{at} (t = {h['t_s']:.2f} s): refused: {h['reason']}", markup=False)
