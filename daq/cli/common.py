"""What every ``gvt`` verb shares: the consoles, one-line failures, rig arguments, outputs, progress.

The verb modules import this and nothing of each other (tests/test_layering.py); ``daq/cli/__init__.py``
assembles them into the app. Imports here stay light (typer, rich, pathlib): ``gvt --help`` loads every
verb module, so anything heavy is imported inside the verb that uses it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console

from analysis.errors import BadInput

#: Control characters a log (or any file) may carry in a name or a message, each shown as its escape (``\x1b``):
#: a channel named ``"\x1b]0;...\x07"`` or ``"\x1b[2J"`` retitled or cleared the user's terminal through
#: ``gvt log info`` (issue 30). Tab and newline stay; the consoles' own styling is rendered after this.
_CONTROL = {c: f"\\x{c:02x}" for c in (*range(0x20), 0x7F, *range(0x80, 0xA0)) if c not in (0x09, 0x0A)}


def printable(text: str) -> str:
    """``text`` with every control character but tab and newline written as ``\\xNN``."""
    return text.translate(_CONTROL)


class _Console(Console):
    """A rich console that never hands a control character from the data to the terminal: every string given
    to ``print`` is passed through :func:`printable` first (renderables such as tables are built by the verbs
    from strings they print, and rich's own escape codes come after this)."""

    def print(self, *objects, **kwargs) -> None:
        super().print(*(printable(o) if isinstance(o, str) else o for o in objects), **kwargs)


out = _Console(highlight=False, soft_wrap=True)
err = _Console(stderr=True, highlight=False, soft_wrap=True)

RigArg = Annotated[str, typer.Argument(help="Rig TOML file, or the name of a rig in configs/rigs (e.g. beam_ch4_exp).")]
OverwriteOpt = Annotated[bool, typer.Option("--overwrite", help="Replace an existing output file.")]


def fail(message: str, code: int = 2) -> NoReturn:
    """Print ``gvt: error: <message>`` (one line, to stderr) and exit with ``code`` (2: bad input)."""
    err.print(f"gvt: error: {message}", markup=False, soft_wrap=True)
    raise typer.Exit(code)


def note(message: str) -> None:
    err.print(f"gvt: note: {message}", markup=False, soft_wrap=True)


def open_rig(rig: str):
    """The rig named or given as a TOML path (a bad one raises the one-line ConfigError, exit 2)."""
    from analysis.model.rigs import open_rig as _open

    return _open(rig)


def check_output(path: Path, overwrite: bool, what: str = "--out", inputs: Sequence[Path] = ()) -> None:
    """A new output file: its directory exists, it is not a directory, it is none of the verb's ``inputs``
    (not even with ``--overwrite``), no running recorder is writing it (not even with ``--overwrite``), and an
    existing file is replaced only when the user said so (``--overwrite``). Raises :class:`BadInput` (exit 2)
    with the fix."""
    from daq.outputs import refuse_live, refuse_own_input, refuse_unwritable

    path = Path(path)
    refuse_own_input(path, inputs, what)
    refuse_live(path, what)
    if path.is_dir():
        raise BadInput(f"{what} {path}: is a directory; give a file name inside it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise BadInput(f"{what} {path}: directory {parent} does not exist (create it first)")
    if not parent.is_dir():
        raise BadInput(f"{what} {path}: {parent} is not a directory")
    refuse_unwritable(path, what)
    if path.exists() and not overwrite:
        raise BadInput(f"{what} {path}: the file exists; pass --overwrite to replace it, or choose another name")


def rerun_hint() -> str:
    exe = Path(sys.executable).parent / "rerun"
    return str(exe) if exe.exists() else "rerun"


class Progress:
    """Rich progress bar on a terminal, plain lines otherwise (architecture.md, CLI verbs).

    ``with Progress(console) as report: report("stage", fraction)``."""

    def __init__(self, console: Console, first: str = "working") -> None:
        self.console = console
        self.first = first
        self.last = ("", -1.0)
        self.bar = None

    def __enter__(self):
        if self.console.is_terminal:
            from rich.progress import Progress as Bar

            self.bar = Bar(console=self.console, transient=True)
            self.bar.start()
            self.task = self.bar.add_task(self.first, total=1.0)
        return self.report

    def report(self, stage: str, fraction: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, description=stage, completed=fraction)
        elif stage != self.last[0] or fraction - self.last[1] >= 0.25 or fraction >= 1.0 > self.last[1]:
            self.console.print(f"{stage}: {100 * fraction:.0f} %", markup=False)
            self.last = (stage, fraction)

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()
