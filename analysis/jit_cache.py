"""Where numba keeps gvtlink's compiled kernels, and whether they are there yet (issue 30, docs/decisions.md D70).

Why one place: ``make`` exported ``NUMBA_CACHE_DIR=.numba_cache`` while ``gvt`` run directly used numba's default, the
``__pycache__`` next to each module: the kernels ``make test`` had compiled were compiled again the first time an
engineer ran ``gvt`` (~5 s for the analysis kernels, ~14 s for the simulator's, ~40 s for the whole set), and the other
way round. Now :func:`configure` (run by
``analysis/__init__.py``, before any module here imports numba) sets ``NUMBA_CACHE_DIR`` when the user has not:

* a source checkout (the editable install ``make`` and the README set up: ``pyproject.toml`` beside the packages,
  writable): its ``.numba_cache`` — the directory ``make clean`` removes;
* an installed package: the user's cache, ``$XDG_CACHE_HOME/gvtlink/numba`` (``~/.cache/gvtlink/numba``).

A ``NUMBA_CACHE_DIR`` the user set always wins. This module imports neither numba nor numpy: ``gvt log info`` and the
record path stay light (tests/test_startup.py).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from pathlib import Path

ENV = "NUMBA_CACHE_DIR"


def default_dir() -> Path:
    """The cache directory when the user set none (see the module's docstring)."""
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file() and os.access(root, os.W_OK):
        return root / ".numba_cache"
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except RuntimeError:  # no home directory (a service account): the temporary directory, still one place
            import tempfile

            base = tempfile.gettempdir()
    return Path(base) / "gvtlink" / "numba"


def configure() -> Path:
    """Set ``NUMBA_CACHE_DIR`` to :func:`default_dir` unless it is set; returns the directory in use. If numba was
    imported before gvtlink (it reads the variable at import), its configuration is set too: the kernels' cache
    locators are chosen when they are defined, which is after this."""
    d = os.environ.get(ENV)
    if d:
        return Path(d)
    d = str(default_dir())
    os.environ[ENV] = d
    numba = sys.modules.get("numba")
    if numba is not None and not getattr(numba.config, "CACHE_DIR", ""):
        numba.config.CACHE_DIR = d
    return Path(d)


def cache_dir() -> Path:
    return Path(os.environ.get(ENV) or default_dir())


def kernels(*modules) -> list:
    """The cached compiled kernels (numba dispatchers defined with ``cache=True``) among the modules' attributes."""
    out = []
    for m in modules:
        for v in vars(m).values():
            if _index_path(v) is not None and v not in out:
                out.append(v)
    return out


def cold(dispatchers: Iterable) -> list:
    """The kernels among ``dispatchers`` that numba's cache holds nothing for yet (no index file): these compile on
    their first call, ~1-10 s each, where a cached one loads in milliseconds."""
    return [d for d in dispatchers if not os.path.exists(_index_path(d) or "")]


def compile_notice(dispatchers: Iterable, what: str = "analysis kernels") -> str | None:
    """The one line to print before the first call when some kernels are not cached yet; None when all are."""
    n = len(cold(dispatchers))
    if not n:
        return None
    return f"compiling {what} once ({n} not cached yet; cached in {cache_dir()}) ..."


def _index_path(obj) -> str | None:
    """The path of a cached dispatcher's index file (numba's ``FunctionCache``), None for anything else and for a kernel
    inlined into its callers (``inline="always"``: never compiled, nor cached, on its own)."""
    if not hasattr(obj, "py_func") or getattr(obj, "targetoptions", {}).get("inline") == "always":
        return None
    cache_file = getattr(getattr(obj, "_cache", None), "_cache_file", None)
    return getattr(cache_file, "_index_path", None)
