"""``gvt identify``: the seed's NSI of a rig's nonlinear attachment (eq. 5.8 fit on the RQ-FDP), or its RFS (eq. 5.11).

One verb, three branches by what SOURCE is and ``--method``: a sweep directory (the NSI of re-simulated runs,
:mod:`daq.studies.identify.sweep`), a session LOG (windowed δ̄ as in the seed's Ch. 5 experiment,
:mod:`daq.studies.identify.log`), or a LOG with ``--method rfs`` (:mod:`daq.studies.identify.rfs`). Each branch
checks its options and outputs, calls its study, and prints; validation by re-simulation of the identified rig
is :mod:`daq.studies.identify.validate`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from analysis.errors import BadInput
from daq.cli.common import OverwriteOpt, Progress, check_output, err, fail, open_rig, out


def identify(
    source: Annotated[Path, typer.Argument(help="A 'gvt sweep' output directory, or a session LOG (.mcap) with hits.")],
    rig: Annotated[str, typer.Option("--rig", help="Rig TOML file or name in configs/rigs (the sweep's rig).")],
    frequency: Annotated[str, typer.Option(help="rq: the POM's RQ (seed eq. 2.18); pom: its temporal frequency.")] = "rq",
    law: Annotated[
        str,
        typer.Option(
            help="seed: eq. 5.8 as printed; hb: harmonic-balance factor; exact: the one-mass backbone; "
            "modal / modal-exact: the attachment's mode of the rig's lowest modes + the spring (two-parameter)."
        ),
    ] = "seed",
    max_ratio: Annotated[float | None, typer.Option(help="Fit only points with f <= ratio x f_n (default: all).")] = None,
    auto_range: Annotated[
        bool, typer.Option("--auto-range", help="Fit the range the data give: stop where the law misses the next points.")
    ] = False,
    force: Annotated[
        bool, typer.Option("--force", help="Write --out even when the fit or its validation is poor (marked in the file).")
    ] = False,
    smooth: Annotated[int, typer.Option(help="Running-median window (points, odd) of the RQ-FDP.")] = 5,
    boot: Annotated[int, typer.Option(help="Bootstrap replicates for the uncertainty (0: none).")] = 200,
    no_intersection: Annotated[bool, typer.Option("--no-intersection", help="Fit α and β together (no eq. 5.9).")] = False,
    method: Annotated[str, typer.Option(help="nsi: the RQ-FDP fit; rfs: eq. 5.11 of a grounded attachment from a LOG.")] = "nsi",
    hit: Annotated[int | None, typer.Option(help="rfs: the identification hit (default: the first accepted).")] = None,
    quantity: Annotated[
        str | None, typer.Option(help="rfs: velocity|displacement compared (default: velocity for a rotational [nsi]).")
    ] = None,
    validate: Annotated[
        str | None, typer.Option(help="LOG: validation hits, e.g. 1,2,3 (rfs default: the others; nsi: lowest, middle, highest).")
    ] = None,
    out_toml: Annotated[
        Path | None, typer.Option("--out", help="Write the rig with the identified law (then validate it).")
    ] = None,
    validate_forces: Annotated[
        str | None, typer.Option(help="Sweep: validation forces F,F,F in N (default: 3 log-spaced, off the sweep's grid).")
    ] = None,
    validation_png: Annotated[Path | None, typer.Option(help="Write the validation overlays (δ, δ') as PNG.")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write the RQ-FDP with the fit as PNG.")] = None,
    csv_out: Annotated[Path | None, typer.Option("--csv", help="LOG: per-window table (default LOG.nsi-windows.csv).")] = None,
    window: Annotated[float | None, typer.Option(help="LOG: window length, s (default ~T/2 of the fundamental, Ch. 5).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON summary instead of tables.")] = False,
    overwrite: OverwriteOpt = False,
) -> None:
    """Identify α|δ|^β δ of the rig's attachment from a force sweep: whole-run δ̄, RQ-FDP, eq. 5.8 fit."""
    if method != "nsi":  # --method rfs: the grounded attachment's eq. 5.11 from a session log (daq/studies/identify/rfs.py)
        return _identify_rfs(method, source, rig, hit, validate, png, out_toml, json_out, overwrite, quantity, force)
    if quantity is not None:
        fail("--quantity is for --method rfs")
    from daq.studies.identify.sweep import IdentifyOptions

    if auto_range and max_ratio is not None:
        fail("--auto-range and --max-ratio both choose the fit range; give one")
    opts = IdentifyOptions(frequency=frequency, law=law, max_ratio=max_ratio, smooth=smooth, n_boot=boot,
                           intersection=not no_intersection, auto_range=auto_range)  # fmt: skip
    opts.validate()
    if not source.exists():
        fail(f"{source}: no such file or directory")
    outs = [(p, w) for p, w in ((png, "--png"), (out_toml, "--out"), (validation_png, "--validation-png")) if p is not None]
    if len({p.resolve() for p, _ in outs}) < len(outs):
        fail(f"{', '.join(w for _, w in outs)} must name different files")
    if not source.is_dir():  # a session LOG: windowed δ̄ as in the seed's Ch. 5 experiment (daq/studies/identify/log.py)
        if validate_forces is not None:
            fail("--validate-forces is for a sweep; a LOG validates on its hits (--validate 1,2,3)")
        return _identify_log(source, rig, opts, png, csv_out, window, json_out, overwrite, out_toml, validation_png, validate,
                             force)  # fmt: skip
    if validate is not None:
        fail("--validate names hits of a LOG; a sweep validates at forces (--validate-forces F,F,F)")
    return _identify_sweep(source, rig, opts, outs, png, out_toml, validation_png, validate_forces, json_out, overwrite, force)


def _parse_hits(text: str | None, what: str) -> list[int] | None:
    """``--validate 1,2,3``: hit numbers of a LOG (None when not given)."""
    if text is None:
        return None
    try:
        hits = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise BadInput(f"{what} {text!r}: expected comma-separated hit numbers, e.g. 1,2,3") from None
    if not hits or min(hits) < 0:
        raise BadInput(f"{what}: give at least one hit number >= 0")
    return hits


def _not_the_rig(r, out_toml: Path | None) -> None:
    if out_toml is not None and Path(r.path).resolve() == out_toml.resolve():
        fail(f"--out {out_toml}: is the rig itself; give a new file name")


#: What to try when an NSI fit is poor (the one line of the warning or refusal).
NSI_HINT = ("check the fit range (--auto-range or --max-ratio), the frequency estimator (--frequency pom) and the law "
            "(--law hb for a spring on a continuous structure, exact for a discrete attachment)")  # fmt: skip
RFS_HINT = "identify on another hit (--hit N) or check the hammer and accelerometer channels"


def _verdict(problems: list[str], res, out_toml: Path | None, hint: str) -> None:
    """The quality verdict, after the results are printed: one warning line when the identification is poor, and
    when ``--out`` was refused for it a one-line failure with exit 1 (the run worked; its result failed its own
    checks, so the rig asked for is not produced: docs/decisions.md D50)."""
    if not problems:
        return
    what = "; ".join(problems)
    if res is not None and res.refused:
        fail(f"--out {out_toml} not written: poor identification ({what}); {hint}, or give --force to write it anyway",
             code=1)  # fmt: skip
    err.print(f"gvt: warning: poor identification ({what}); {hint}", markup=False, soft_wrap=True)


def _print_validation_and_files(res, files: tuple[tuple[Path | None, str], ...]) -> None:
    """The validation table (when the identified rig was re-simulated), then one line per file written."""
    if res is not None and res.validation is not None:
        from daq.studies.identify import validate as iv

        iv.print_validation(out, res.validation)
    for path, what in files:
        if path is not None and not (what == "identified rig" and res is not None and res.refused):
            out.print(f"wrote {what}: {path}", markup=False)


def _identify_sweep(source: Path, rig_name: str, opts, outs: list[tuple[Path, str]], png: Path | None,
                    out_toml: Path | None, validation_png: Path | None, validate_forces: str | None, json_out: bool,
                    overwrite: bool, force: bool = False) -> None:  # fmt: skip
    """The NSI of a ``gvt sweep`` directory, with validation at ``--validate-forces`` when asked."""
    for p, w in outs:
        check_output(p, overwrite, w)
    from daq.studies.identify import validate as iv

    forces = iv.parse_forces(validate_forces) if validate_forces is not None else None
    r = open_rig(rig_name)
    _not_the_rig(r, out_toml)
    from daq.studies.identify.sweep import identify_sweep, plot_fdp, print_report

    with Progress(err if json_out else out) as report:
        ident = identify_sweep(r, source, opts, progress=report)
    if png is not None:
        plot_fdp(ident, png)
    res = None
    if out_toml is not None or validation_png is not None or forces is not None:
        dofs, validator = iv.sweep_validator(ident, r, source, forces)
        res = iv.finish(ident, r, dofs, out_toml, validation_png, validator, force)
    problems = res.problems if res is not None else ident.problems()
    if json_out:
        doc = ident.summary()
        doc["png"] = str(png) if png is not None else None
        doc["quality"] = {"ok": not problems, "problems": problems, "identified_toml_refused": False}
        if res is not None:
            doc.update(res.to_dict())
        out.print_json(iv.dumps(doc))
    else:
        print_report(out, ident)
        _print_validation_and_files(res, ((png, "RQ-FDP"), (out_toml, "identified rig"), (validation_png, "validation overlays")))
    _verdict(problems, res, out_toml, NSI_HINT)


def _identify_log(source: Path, rig_name: str, options, png: Path | None, csv_out: Path | None, window_s: float | None,
                  json_out: bool, overwrite: bool, out_toml: Path | None, validation_png: Path | None,
                  validate: str | None, force: bool = False) -> None:  # fmt: skip
    """``gvt identify LOG``: windowed δ̄ of each accepted hit; with ``--out``, ``--validation-png`` or ``--validate``
    the identified rig is re-simulated against the logged hits (``daq.studies.identify.validate.validate_log``)."""
    from daq.studies.identify import validate as iv
    from daq.studies.identify.log import identify_log, windows_csv_path, write_windows
    from daq.studies.identify.sweep import plot_fdp

    val_hits = _parse_hits(validate, "--validate")
    for p, what in ((out_toml, "--out"), (validation_png, "--validation-png")):
        if p is not None:
            check_output(p, overwrite, what, inputs=[source])
    if window_s is not None and not window_s > 0:
        fail(f"--window {window_s:g}: give a positive length in seconds")
    csv_path = csv_out if csv_out is not None else windows_csv_path(source)
    check_output(csv_path, overwrite, "--csv", inputs=[source])
    if png is not None:
        check_output(png, overwrite, "--png", inputs=[source])
        if png.resolve() == csv_path.resolve():
            fail("--png and --csv name the same file")
    r = open_rig(rig_name)
    _not_the_rig(r, out_toml)
    with Progress(err if json_out else out) as report:
        run = identify_log(r, source, options, window_s=window_s, progress=report)
    write_windows(run, csv_path)
    if png is not None:
        plot_fdp(run.ident, png)
    res = None
    if out_toml is not None or validation_png is not None or val_hits is not None:
        with Progress(err if json_out else out) as report:
            res = iv.finish(run.ident, r, iv.log_dofs(run, r), out_toml, validation_png,
                            lambda idr: iv.validate_log(run, r, idr, source, val_hits, progress=report), force)  # fmt: skip
    problems = res.problems if res is not None else run.ident.problems()
    if json_out:
        _print_log_json(run, csv_path, png, res, problems)
    else:
        _print_log_report(run, csv_path, png)
        _print_validation_and_files(res, ((out_toml, "identified rig"), (validation_png, "validation overlays")))
    _verdict(problems, res, out_toml, NSI_HINT)


def _print_log_json(run, csv_path: Path, png: Path | None, res, problems: list[str]) -> None:
    import json

    from daq.outputs import jsonable

    doc = run.summary()
    doc["windows_csv"] = str(csv_path)
    doc["png"] = str(png) if png is not None else None
    doc["quality"] = {"ok": not problems, "problems": problems, "identified_toml_refused": False}
    if res is not None:
        doc.update(res.to_dict())
    out.print_json(json.dumps(doc, default=jsonable))


def _print_log_report(run, csv_path: Path, png: Path | None) -> None:
    """The fit, the windows it used (settings, hits skipped) and the files written."""
    from daq.studies.identify.sweep import print_report

    print_report(out, run.ident)
    s = run.settings
    dc = "none" if s.delta_corner_hz is None else f"{s.delta_corner_hz:.3g} Hz"
    n_hits = sum("windows" in h for h in run.hits)
    shape = f">= {s.window_s:.4g} s, whole half-cycles of delta" if s.snap else f"{s.window_s:.4g} s"
    out.print(f"{run.window_hit.size} windows of {shape} from {n_hits} hits "
              f"({int(run.ident.runs.capture.sum())} in capture, excluded); start drop {s.skip_s:.4g} s, "
              f"tail {s.tail_s:.4g} s, integration high-pass {s.integration_corner_hz or 0:.3g} Hz, "
              f"delta high-pass {dc}; {run.elapsed_s:.1f} s", markup=False)  # fmt: skip
    for h in run.hits:
        if "skipped" in h:
            out.print(f"hit {h['hit']} skipped: {h['skipped']}", markup=False)
    out.print(f"wrote per-window table: {csv_path}" + (f"; plot: {png}" if png is not None else ""), markup=False)


def _identify_rfs(method: str, source: Path, rig_name: str, hit: int | None, validate: str | None, png: Path | None,
                  out_toml: Path | None, json_out: bool, overwrite: bool, quantity: str | None = None,
                  force: bool = False) -> None:  # fmt: skip
    """``gvt identify LOG --method rfs``: the grounded attachment's eq. 5.11 by RFS + time-series fit."""
    from analysis.rfs import QUANTITIES

    if method != "rfs":
        fail(f"--method {method!r}: use 'nsi' (RQ-FDP fit of a sweep) or 'rfs' (eq. 5.11 from a session log)")
    if not source.exists():
        fail(f"{source}: no such file")
    if source.is_dir():
        fail(f"{source}: --method rfs reads a session LOG (.mcap), not a directory")
    if quantity is not None and quantity not in QUANTITIES:
        fail(f"--quantity {quantity!r}: use 'velocity' or 'displacement' (default per rig)")
    vals = _parse_hits(validate, "--validate")
    if hit is not None and hit < 0:
        fail(f"--hit {hit}: hit numbers start at 0")
    for path, what in ((png, "--png"), (out_toml, "--out")):
        if path is not None:
            check_output(path, overwrite, what, inputs=[source])
    if png is not None and out_toml is not None and png.resolve() == out_toml.resolve():
        fail("--png and --out name the same file")
    r = open_rig(rig_name)
    _not_the_rig(r, out_toml)
    from daq.studies.identify.rfs import identify_rfs, plot, print_report, problems_of, summary_json, write_identified

    with Progress(err if json_out else out) as report:
        run = identify_rfs(source, r, hit, vals, progress=report, quantity=quantity)
    if png is not None:
        plot(run, png)
    problems = problems_of(run)
    refused = out_toml is not None and bool(problems) and not force
    if out_toml is not None and not refused:
        write_identified(run, r, out_toml, problems)
    if json_out:  # the plot's path goes with the summary, so `gvt report --identify` can embed it
        import json

        quality = {"ok": not problems, "problems": problems, "identified_toml_refused": refused}
        out.print_json(json.dumps({**json.loads(summary_json(run)), "png": None if png is None else str(png),
                                   "quality": quality}))  # fmt: skip
    else:
        print_report(out, run)
        for path, what in ((png, "plot"), (None if refused else out_toml, "identified rig")):
            if path is not None:
                out.print(f"wrote {what}: {path}", markup=False)
    from types import SimpleNamespace

    _verdict(problems, SimpleNamespace(refused=refused), out_toml, RFS_HINT)
