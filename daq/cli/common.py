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


# --- campaigns: a verb over many logs as one Dask job (daq/studies/campaign/, docs/campaign.md) ----------------------

SchedulerOpt = Annotated[
    str | None, typer.Option("--scheduler", help="Run over many logs on this Dask scheduler (tcp://HOST:PORT).")
]
WorkersOpt = Annotated[
    int | None, typer.Option("--workers", min=1, help="Worker processes of the local Dask cluster (default: the cores).")
]
OutDirOpt = Annotated[
    Path | None, typer.Option("--out-dir", help="Campaign: each log's outputs and its --json document go here.")
]


def is_campaign(logs: Sequence[Path], scheduler: str | None, workers: int | None, out_dir: Path | None) -> bool:
    """Several logs, a directory, or a campaign option: the campaign path; one file alone: the verb as it always was."""
    return len(logs) != 1 or logs[0].is_dir() or scheduler is not None or workers is not None or out_dir is not None


def rig_arg(rig: str | None) -> str | None:
    """A ``--rig`` for the workers: checked here (a bad one is one line before any work), a file as an absolute path."""
    if rig is None:
        return None
    open_rig(rig)
    return str(Path(rig).resolve()) if Path(rig).is_file() else rig


def campaign(verb: str, logs: Sequence[Path], options: dict, outputs: dict, out_dir: Path | None, scheduler: str | None,
             workers: int | None, json_out: bool, overwrite: bool) -> None:  # fmt: skip
    """Plan, check every output, run on Dask with a progress bar, write each log's --json document to ``out_dir``,
    print the summary table (or JSON) and exit with the campaign's code (daq/studies/campaign/table.py)."""
    import json
    import time

    from daq.outputs import atomic_output
    from daq.studies.campaign.plan import check_outputs, find_logs, plan
    from daq.studies.campaign.runner import default_workers, run_campaign
    from daq.studies.campaign.table import document, exit_code, summary_table

    if scheduler is not None and workers is not None:
        fail("--workers sizes the local cluster; with --scheduler the scheduler's own workers run the logs (give one)")
    found = find_logs(logs)
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            fail(f"--out-dir {out_dir}: exists and is not a directory")
        out_dir.mkdir(parents=True, exist_ok=True)
    tasks = plan(verb, found, options, outputs, out_dir)
    check_outputs(tasks, overwrite)
    where = scheduler or f"a local cluster of {workers or default_workers(len(tasks))} worker processes"
    console = err if json_out else out
    console.print(f"gvt {verb}: {len(tasks)} log(s) on {where}", markup=False)
    t0 = time.perf_counter()
    with Progress(console, "logs") as report:
        rows = run_campaign(tasks, scheduler, workers, progress=lambda d, n, _row: report(f"{d}/{n} logs", d / n))
    for t, row in zip(tasks, rows, strict=True):
        if t.document is not None and row["result"] is not None:
            with atomic_output(t.document, "--out-dir") as tmp:
                tmp.write_text(json.dumps(row["result"], indent=1, default=_plain))
            row["outputs"].append(t.document)
    doc = document(verb, rows, time.perf_counter() - t0, where)
    if json_out:
        out.print_json(json.dumps(doc, default=_plain))
    else:
        out.print(summary_table(verb, rows, [str(p) for p in found]))
    if code := exit_code(rows):
        raise typer.Exit(code)


def _plain(x: object) -> object:
    """JSON for numpy values in a row (``json.dumps(default=...)``): arrays as lists, scalars as numbers."""
    tolist = getattr(x, "tolist", None)
    return tolist() if tolist is not None else float(x)  # type: ignore[arg-type]
