"""Which reader takes a file: by ``--format``, else by suffix, else (UFF) by content.

Each format is a module of this package exposing ``read(path, channels=None) -> TimeImport | FrfImport``; it is
imported only when its format is asked for, so a missing optional reader is one line, not a failed start.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from daq.studies.importing.data import FrfImport, ImportError_, TimeImport

#: format -> (module, suffixes)
FORMATS = {
    "uff": ("daq.studies.importing.uff", (".uff", ".unv", ".58", ".bunv")),
    "csv": ("daq.studies.importing.csv", (".csv",)),
    "tdms": ("daq.studies.importing.tdms", (".tdms",)),
    "hdf5": ("daq.studies.importing.hdf5", (".h5", ".hdf5")),
}


def format_of(path: Path, fmt: str = "auto") -> str:
    """The format of ``path``: ``fmt`` when given, else by suffix, else a UFF by its content; ImportError_ else."""
    if fmt != "auto":
        if fmt not in FORMATS:
            raise ImportError_(f"--format {fmt}: use one of auto, {', '.join(FORMATS)}")
        return fmt
    suffix = Path(path).suffix.lower()
    for name, (_mod, suffixes) in FORMATS.items():
        if suffix in suffixes:
            return name
    from daq.studies.importing.uff import is_uff

    if is_uff(Path(path)):
        return "uff"
    known = ", ".join(s for _m, ss in FORMATS.values() for s in ss)
    raise ImportError_(f"{path}: format not known by its suffix ({known}); give --format")


def read_any(path: Path, fmt: str = "auto", channels: Path | None = None, *, rate: float | None = None,
             group: str | None = None) -> TimeImport | FrfImport:  # fmt: skip
    """The file at ``path`` read by its format's module; ``rate`` (Hz, ``fs`` of the csv and tdms readers) and
    ``group`` (tdms) go to a reader that takes them, and are refused by name for one that does not."""
    path = Path(path)
    if not path.is_file():
        raise ImportError_(f"{path}: no such file")
    name = format_of(path, fmt)
    try:
        module = importlib.import_module(FORMATS[name][0])
    except ModuleNotFoundError as exc:
        if exc.name != FORMATS[name][0]:
            raise
        raise ImportError_(f"{path}: format {name} not available in this gvtlink") from None
    import inspect

    options = {k: v for k, v in (("fs", rate), ("group", group)) if v is not None}
    takes = inspect.signature(module.read).parameters
    if bad := [k for k in options if k not in takes]:
        flags = ", ".join("--rate" if k == "fs" else f"--{k}" for k in bad)
        raise ImportError_(f"{path}: {flags} does not apply to a {name} file; leave it out")
    return module.read(path, channels, **options)


__all__ = ["FORMATS", "format_of", "read_any"]
