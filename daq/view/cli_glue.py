"""The few lines ``gvt record|replay --view/--connect`` need around :mod:`daq.lanes.view` (kept out of cli.py)."""

from __future__ import annotations

import sys
import time

from rich.console import Console

from daq.lanes.view import ViewLane, ViewTarget, open_view


def open_live_view(console: Console, view: bool, connect: str | None) -> ViewTarget | None:
    """``--connect URL`` wins over ``--view``; None when neither was asked for. Raises ViewError."""
    if connect:
        target = open_view("connect", connect)
        console.print(f"view: streaming to the rerun viewer at {target.url}", markup=False)
        return target
    if not view:
        return None
    target = open_view("serve")
    console.print(f"view: open {target.web_url} in a browser (served on 127.0.0.1 only; gRPC {target.url})", markup=False)
    return target


def close_live_view(console: Console, target: ViewTarget | None, lane: ViewLane | None) -> None:
    """Report what the view dropped; a served viewer keeps running until Ctrl-C when on a terminal."""
    if target is None:
        return
    if lane is not None:
        ev = lane.overrun_event()
        if ev is not None:
            console.print(f"view: {ev['message']}", markup=False)
        if lane.error:
            console.print(f"view: stopped early: {lane.error}", markup=False)
    target.rec.flush()
    if target.process is not None and sys.stdin.isatty():
        console.print(f"view: still serving {target.web_url} — press Ctrl-C to stop the viewer", markup=False)
        try:
            while target.process.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
    target.close()
