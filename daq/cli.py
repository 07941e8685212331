"""The ``gvt`` command line (typer). Each verb is a thin shell over library functions.

Errors a user can fix (a bad config, a bad path) print one line and exit 2; anything unexpected prints
one line and exits 1 (``GVT_DEBUG=1`` shows the traceback).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from daq.config.loader import ConfigError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="gvtlink: ground-vibration-test data acquisition and nonlinear modal analysis.",
)
model_app = typer.Typer(no_args_is_help=True, help="Structural model of a rig: modes, limits.")
app.add_typer(model_app, name="model")

out = Console(highlight=False)
err = Console(stderr=True, highlight=False)

RigArg = Annotated[str, typer.Argument(help="Rig TOML file, or the name of a rig in configs/rigs (e.g. beam_ch4_exp).")]


def fail(message: str, code: int = 2) -> None:
    err.print(f"gvt: error: {message}", markup=False, soft_wrap=True)
    raise typer.Exit(code)


@model_app.command("modes")
def model_modes(
    rig: RigArg,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    limit: Annotated[str, typer.Option(help="low: the linear structure; high: nonlinear springs pinned (seed L1244).")] = "low",
    count: Annotated[int, typer.Option(min=1, help="How many modes to list.")] = 10,
) -> None:
    """List the rig's natural frequencies (FE, and Guyan-reduced to the sensor DOFs)."""
    from daq.modes_report import modes_report, print_modes

    if limit not in ("low", "high"):
        fail(f"--limit must be 'low' or 'high', got {limit!r}")
    r = _open(rig)
    report = modes_report(r, limit=limit, count=count)
    if json_out:
        out.print_json(json.dumps(report))
    else:
        print_modes(out, report)


@app.command()
def simulate(
    rig: RigArg,
    force: Annotated[float | None, typer.Option(min=0.0, help="Peak hammer force, N (default: the rig's nominal hit).")] = None,
    duration: Annotated[
        float | None, typer.Option(min=1e-6, help="Seconds to simulate (default: the rig's record length).")
    ] = None,
    out_path: Annotated[Path, typer.Option("--out", help="Output .npz file.")] = Path("simulation.npz"),
    seed: Annotated[int | None, typer.Option(help="Noise seed (default: the rig's).")] = None,
) -> None:
    """Simulate one hammer hit and write measured channels plus ground truth to an .npz file."""
    from daq.simulate_cmd import simulate_to_npz

    r = _open(rig)
    if out_path.suffix != ".npz":
        fail(f"--out {out_path}: only .npz is written for now (the log format comes with MCAP sessions)")
    if out_path.parent and not out_path.parent.exists():
        fail(f"--out {out_path}: directory {out_path.parent} does not exist")
    summary = simulate_to_npz(r, out_path, force=force, duration=duration, seed=seed)
    out.print(summary)


@app.command()
def demo(
    rig: RigArg = "beam_ch4_exp",
    duration: Annotated[float | None, typer.Option(min=0.1, help="Seconds per hit (default: the rig's record length).")] = None,
) -> None:
    """Build the experimental beam rig, show its modes, and simulate a strong and a weak hit."""
    from daq.demo import run_demo

    run_demo(out, _open(rig), duration=duration)


def _open(rig: str):
    from daq.rigs import open_rig

    try:
        return open_rig(rig)
    except ConfigError as exc:
        fail(str(exc))


def _click_exceptions():
    """The click exception module typer is using (typer >= 0.2x vendors its own copy of click)."""
    try:
        from typer._click import exceptions
    except ImportError:  # older typer: plain click
        from click import exceptions
    return exceptions


def main() -> None:
    cx = _click_exceptions()
    try:
        code = app(standalone_mode=False)
        sys.exit(code if isinstance(code, int) else 0)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except cx.UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # the help text has been printed already
            sys.exit(2)
        cmd = exc.ctx.command_path if exc.ctx is not None else "gvt"
        err.print(f"gvt: error: {exc.format_message()} (see '{cmd} --help')", markup=False, soft_wrap=True)
        sys.exit(2)
    except typer.Abort:
        err.print("gvt: aborted", markup=False)
        sys.exit(130)
    except ConfigError as exc:
        err.print(f"gvt: error: {exc}", markup=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        err.print("gvt: interrupted", markup=False)
        sys.exit(130)
    except Exception as exc:  # never a traceback to a user
        if os.environ.get("GVT_DEBUG"):
            raise
        err.print(
            f"gvt: internal error: {type(exc).__name__}: {exc} (set GVT_DEBUG=1 for the traceback)", markup=False, soft_wrap=True
        )
        sys.exit(1)


if __name__ == "__main__":
    main()
