"""``gvt frf``: FRFs, coherence and hammer checks of a session's hits (daq/studies/frf.py, docs/frf.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import (
    OutDirOpt,
    OverwriteOpt,
    Progress,
    SchedulerOpt,
    WorkersOpt,
    campaign,
    check_output,
    err,
    fail,
    is_campaign,
    open_rig,
    out,
    rig_arg,
)


def frf(
    logs: Annotated[
        list[Path],
        typer.Argument(
            metavar="LOG...",
            help="Session log (.mcap), a UFF 58 FRF file or its import; several logs, or a directory: a campaign.",
        ),
    ],
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
    peaks: Annotated[int, typer.Option(min=1, max=50, help="Peaks in the table (and modes judged).")] = 6,
    level: Annotated[
        str | None,
        typer.Option(help="Force level averaged: a number (1 = lowest) or 'all'; default the lowest with 2 hits."),
    ] = None,
    overwrite: OverwriteOpt = False,
    out_dir: OutDirOpt = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = None,
) -> None:
    """FRFs (H1/H2/Hv) and coherence of the accepted hits, averaged; each hit's hammer checks and verdict.
    Over several logs or a directory: one Dask job, one summary table (docs/campaign.md)."""
    import json

    from daq.log.reader import LogReader
    from daq.log.rig import rig_from_log
    from daq.outputs import atomic_output
    from daq.studies.frf import frf_from_log, plot, summary
    from daq.studies.importing.frfs import frf_file

    if is_campaign(logs, scheduler, workers, out_dir):
        opts = {"rig": rig_arg(rig), "reference": reference, "channels": _channels(channels), "band": band, "kind": kind,
                "quantity": quantity, "peaks": peaks, "level": _level(level), "show": show}  # fmt: skip
        outputs = {"--out": out_path, "--plot": plot_path}
        return campaign("frf", logs, opts, outputs, out_dir, scheduler, workers, json_out, overwrite)
    log = logs[0]
    for p, what in ((plot_path, "--plot"), (out_path, "--out")):
        if p is not None:
            check_output(p, overwrite, what, inputs=[log])
    given = frf_file(log)  # a UFF 58 FRF file, or a log gvt import made of one: the set as it is, judged
    if given is not None:
        _given_set(log, given, json_out, out_path, plot_path, peaks)
        return
    r = open_rig(rig) if rig is not None else rig_from_log(LogReader(log))
    chans = _channels(channels)
    _level(level)
    console = err if json_out else out
    with Progress(console) as report:
        run = frf_from_log(log, r, reference=reference, channels=chans, band_hz=band, kind=kind, quantity=quantity,
                           level=level if level in (None, "all") else int(level), n_peaks=peaks,
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
    if run.frf is None:
        fail(f"{log}: no accepted hit, no FRF ({len(run.hits)} hit(s) refused: the lines above say why)")


def _given_set(log: Path, given: tuple, json_out: bool, out_path: Path | None, plot_path: Path | None, peaks: int) -> None:
    """``gvt frf`` of an FRF set given whole (UFF 58 or its import): the set, its peaks and their coherence judged."""
    import json

    from daq.outputs import atomic_output
    from daq.studies.frf import plot, summary
    from daq.studies.importing.frfs import frf_run

    run = frf_run(log, given[0], given[1], peaks)
    s = summary(run, peaks)
    console = err if json_out else out
    for note in given[1]:
        console.print(f"assumed: {note}", markup=False)
    if json_out:
        out.print_json(json.dumps(s, default=float))
    else:
        _print(s)
    if out_path is not None:
        with atomic_output(out_path) as tmp:
            run.frf.to_npz(tmp)
        console.print(f"wrote {out_path}", markup=False)
    if plot_path is not None:
        with atomic_output(plot_path) as tmp:
            plot(run, tmp)
        console.print(f"wrote {plot_path}", markup=False)


def _channels(channels: str | None) -> list[str] | None:
    return [c.strip() for c in channels.split(",") if c.strip()] if channels else None


def _level(level: str | None) -> str | int | None:
    """``--level``: None, 'all' or a level number (1 = the lowest force); anything else is one line, exit 2."""
    if level is not None and level != "all" and not level.isdigit():
        fail(f"--level {level!r}: give a level number (1 = the lowest force) or 'all'")
    return level if level in (None, "all") else int(level)


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
    q = s.get("quality") or {}
    if len(q.get("levels", [])) > 1:
        out.print("force levels: " + "; ".join(_level_text(lv) for lv in q["levels"]), markup=False)
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
            out.print(f"hit {h['hit']}{at} (t = {h['t_s']:.2f} s): {h['verdict']}: {h['reason']}", markup=False)
    for w in s.get("warnings", []):
        out.print(f"warning: {w}", markup=False)


def _level_text(lv: dict) -> str:
    a, b = lv["force_min_N"], lv["force_max_N"]
    span = f"{a:.0f}" if b <= a * 1.005 else f"{a:.0f}-{b:.0f}"
    return f"{lv['level']}: {span} N, {lv['accepted']} accepted" + (" (averaged)" if lv["averaged"] else "")
