"""Output files the verbs write: atomically, and never over their own input.

A derived file (an export, a report, a companion log, a recovered log, a simulated log) is written to a
temporary file beside its target and renamed over it only when complete (``os.replace`` is atomic on one file
system): an interrupted verb leaves the user's previous file — or nothing — under the name, never half a file.
The temporary name starts with a dot and has ``.part`` before the target's suffix, so it is easy to spot.
The live recording (``gvt record``) is the exception, by design: it writes in place under its lock so that a
crash leaves the log where the user looks for it (docs/log-format.md, "Writer guarantees").
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from analysis.errors import BadInput


def jsonable(x: object) -> object:
    """``json.dumps(..., default=jsonable)``: numpy scalars and arrays as plain JSON values, anything else refused."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def same_file(a: str | Path, b: str | Path) -> bool:
    """``a`` and ``b`` name one file (a hard link, a symlink or another spelling of the path included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def refuse_own_input(out: str | Path, inputs: Sequence[str | Path], what: str = "--out") -> None:
    """One line (exit 2) when ``out`` is one of ``inputs``: even ``--overwrite`` never replaces what is being read."""
    for src in inputs:
        if Path(out).exists() and same_file(out, src):
            raise BadInput(f"{what} {out}: that is the input file {src}; choose another output name")


def part_path(target: str | Path) -> Path:
    """The temporary file for ``target``: same directory (same file system, so the rename is atomic), and the
    same suffix, because writers pick the format by it (matplotlib's ``savefig``; ``np.savez`` appends
    ``.npz`` to a name without it)."""
    t = Path(target)
    return t.with_name(f".{t.stem}.{os.getpid()}.part{t.suffix}")


@contextlib.contextmanager
def atomic_output(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``target``, on any exception it is removed.

    The caller has already checked ``--overwrite`` and the input (``check_output``); this only makes the
    replacement all-or-nothing.
    """
    tmp = part_path(target)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
