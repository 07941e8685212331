"""The campaign's plan: which logs, and for each the task a worker runs (verb, options, the files it writes).

Why a plan of its own: every check a user can fail (no such log, an empty directory, two logs whose outputs would
land on one file, an output that exists without ``--overwrite``) is made here, before a cluster is started or a log
opened, so a campaign of hundreds of logs never stops at log 37 because of a name (architecture.md, "Bad input").

Output names: the single-log verb writes each output where its option says (``--modes-out modes.json``). Over many
logs one name cannot hold them all, so the option's file name is kept and each log's stem put before it:
``run07.modes.json``, in the option's directory, or in ``--out-dir`` when one is given. ``--out-dir`` also receives
each log's ``--json`` document as ``<stem>.<verb>.json``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from analysis.errors import BadInput

VERBS = ("analyze", "frf", "modal")
#: What a directory contributes: its session logs (not its subdirectories; a ``.npz`` of FRFs is given by name).
LOG_SUFFIX = ".mcap"


@dataclass(frozen=True)
class Task:
    """One log's work: ``verb`` over ``log`` with the single-log verb's ``options`` (by their parameter names);
    ``outputs`` maps an output option (``--modes-out``) to this log's file; ``index`` is its row in the table."""

    verb: str
    log: str
    index: int
    options: Mapping[str, Any] = field(default_factory=dict)
    outputs: Mapping[str, str] = field(default_factory=dict)
    document: str | None = None  # where the log's --json document goes (``--out-dir``), or nowhere


def find_logs(paths: Sequence[str | Path]) -> list[Path]:
    """The logs named: each file as given, each directory's ``.mcap`` files in name order; each once (the same file
    named twice, or through a directory and by name, is one log). :class:`BadInput` for a missing path or a
    directory without a log."""
    found: list[Path] = []
    seen: set[Path] = set()
    for p in map(Path, paths):
        if not p.exists():
            raise BadInput(f"{p}: no such file or directory")
        if p.is_dir():
            logs = sorted(q for q in p.iterdir() if q.suffix == LOG_SUFFIX and q.is_file())
            if not logs:
                raise BadInput(f"{p}: no {LOG_SUFFIX} log in this directory (subdirectories are not searched)")
        else:
            logs = [p]
        for q in logs:
            key = q.resolve()
            if key not in seen:
                seen.add(key)
                found.append(q)
    if not found:
        raise BadInput("no log given")
    return found


def output_for(log: Path, template: Path, out_dir: Path | None) -> Path:
    """``log``'s file for an output option given as ``template``: ``<stem>.<template's name>`` in ``out_dir``, else
    in ``template``'s directory (module docstring)."""
    where = out_dir if out_dir is not None else template.parent
    return where / f"{log.stem}.{template.name}"


def plan(verb: str, logs: Sequence[Path], options: Mapping[str, Any], outputs: Mapping[str, Path | None],
         out_dir: Path | None = None) -> list[Task]:  # fmt: skip
    """One task per log, in order; ``outputs``: output option -> the path the user gave (None: not asked).
    Refuses two logs whose outputs would be one file (the second would silently replace the first)."""
    if verb not in VERBS:
        raise ValueError(f"verb {verb!r}: one of {VERBS}")
    tasks, owner = [], {}
    for i, log in enumerate(logs):
        mine = {opt: output_for(log, p, out_dir) for opt, p in outputs.items() if p is not None}
        doc = out_dir / f"{log.stem}.{verb}.json" if out_dir is not None else None
        for what, path in [*mine.items(), *([("--out-dir", doc)] if doc is not None else [])]:
            key = str(path.resolve())
            if key in owner:
                raise BadInput(f"{what} {path}: both {owner[key]} and {log} would write it (logs with one name in "
                               "different directories): give --out-dir per directory, or rename one")  # fmt: skip
            owner[key] = str(log)
        tasks.append(Task(verb, str(log.resolve()), i, dict(options), {k: str(v.resolve()) for k, v in mine.items()},
                          str(doc.resolve()) if doc is not None else None))  # fmt: skip
    return tasks


def written(tasks: Sequence[Task]) -> list[tuple[str, str, str]]:
    """Every file the campaign writes: (option, path, the log it belongs to)."""
    rows = [(opt, p, t.log) for t in tasks for opt, p in t.outputs.items()]
    return rows + [("--out-dir", t.document, t.log) for t in tasks if t.document is not None]


def check_outputs(tasks: Sequence[Task], overwrite: bool) -> None:
    """Before anything runs: no output is a log of the campaign, none is a log a recorder holds, every directory
    exists and can be written, and no file is replaced without ``--overwrite`` (one line naming the first and how
    many; architecture.md: a user's file is never overwritten without it)."""
    from daq.outputs import refuse_live, refuse_own_input, refuse_unwritable

    files = written(tasks)
    logs = [t.log for t in tasks]
    for opt, path, _log in files:
        refuse_own_input(path, logs, opt)
        refuse_live(path, opt)
        parent = Path(path).parent
        if not parent.is_dir():
            raise BadInput(f"{opt} {path}: directory {parent} does not exist (create it first)")
        refuse_unwritable(path, opt)
    exist = [(opt, p) for opt, p, _log in files if Path(p).exists()]
    if exist and not overwrite:
        more = f" (and {len(exist) - 1} more of the campaign's outputs)" if len(exist) > 1 else ""
        raise BadInput(f"{exist[0][0]} {exist[0][1]}: the file exists{more}; pass --overwrite to replace them, "
                       "or choose another name or --out-dir")  # fmt: skip
