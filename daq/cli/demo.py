"""``gvt demo``: the whole chain on the simulated device."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from daq.cli.common import OverwriteOpt, RigArg, check_output, open_rig, out


def demo(
    rig: RigArg = "beam_ch4_exp",
    duration: Annotated[float | None, typer.Option(min=0.1, help="Seconds per hit (default: the rig's record length).")] = None,
    session_out: Annotated[Path, typer.Option("--out", help="Where the demo session log goes.")] = Path("demo_session.mcap"),
    overwrite: OverwriteOpt = False,
) -> None:
    """The experimental beam rig: modes, a strong and a weak hit, then a recorded session over a real pty.

    Writes the session log (--out) and a rerun recording beside it (.rrd); existing ones only with --overwrite."""
    from daq.studies.demo import run_demo

    check_output(session_out, overwrite)
    check_output(session_out.with_suffix(".rrd"), overwrite)
    run_demo(out, open_rig(rig), duration=duration, session_out=str(session_out), overwrite=overwrite)
