"""One numba cache for make, the tests and ``gvt`` run directly, and the line when kernels compile (issue 30, D70)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _env(**kw: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    return {**env, "PYTHONPATH": str(ROOT), **kw}


def test_gvt_run_directly_uses_the_cache_make_uses(tmp_path):
    """Before issue 30 the Makefile exported ``NUMBA_CACHE_DIR=$(CURDIR)/.numba_cache`` and ``gvt`` run directly used
    numba's ``__pycache__`` default, so each compiled what the other had. Now the Makefile sets nothing and every
    process that imports the analysis (``gvt``, pytest, tests/warm_numba.py) picks this checkout's ``.numba_cache``,
    the directory ``make clean`` removes. Oracle: numba's own configuration in a fresh ``gvt`` interpreter started
    elsewhere without the variable."""
    make = (ROOT / "Makefile").read_text()
    assert not re.search(r"^\s*(export\s+)?NUMBA_CACHE_DIR\s*[:?]?=", make, re.M)  # nothing overrides the package
    assert re.search(r"^clean:.*\n\trm -rf .*\.numba_cache", make, re.M)
    code = "import daq.cli, numba; print(numba.config.CACHE_DIR)"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=_env())
    assert p.returncode == 0, p.stderr
    assert Path(p.stdout.strip()) == ROOT / ".numba_cache"


def test_a_cache_directory_the_user_sets_wins(tmp_path, monkeypatch):
    from analysis.jit_cache import cache_dir, configure

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert configure() == tmp_path == cache_dir() and os.environ["NUMBA_CACHE_DIR"] == str(tmp_path)


def test_a_cold_cache_is_announced_once_and_a_warm_one_is_silent(tmp_path):
    """The line ``compiling analysis kernels once (... cached in DIR)`` comes only while a kernel has no entry in the
    cache. One small kernel (the modal energy), in a fresh cache directory: announced, compiled by its first call
    (written to that directory), then silent."""
    code = (
        "import numpy as np\n"
        "from analysis import jit_cache, modal_filter\n"
        "ks = jit_cache.kernels(modal_filter)\n"
        "print([k.py_func.__name__ for k in ks])\n"
        "print(jit_cache.compile_notice(ks))\n"
        "modal_filter._modal_energy(np.ones((2, 2)), np.ones((2, 2)), np.ones(2))\n"
        "print(jit_cache.compile_notice(ks))\n"
    )
    cache = tmp_path / "cache"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path,
                       env=_env(NUMBA_CACHE_DIR=str(cache)))  # fmt: skip
    assert p.returncode == 0, p.stderr
    names, cold, warm = p.stdout.strip().splitlines()
    assert names == "['_modal_energy']"
    assert cold == f"compiling analysis kernels once (1 not cached yet; cached in {cache}) ..."
    assert warm == "None"
    assert list(cache.rglob("modal_filter._modal_energy-*.nbi"))
