"""Imports run one way (architecture.md): ``analysis`` < ``drivers`` < ``daq``.

``drivers`` imports nothing of ``daq``; ``analysis`` imports neither ``daq`` nor ``drivers``. Every import
statement counts, at module level or inside a function (a lazy import is still a dependency), and so do
``importlib.import_module("...")`` calls with a literal name. The CLI package has no import cycle
between its verb modules (they share ``daq/cli/common.py``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {"drivers": ("daq",), "analysis": ("daq", "drivers")}


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in ``path``: ``import a.b``, ``from a.b import c``, ``import_module('a.b')``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                out.append((node.lineno, node.args[0].value))
    return out


def violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, mod in imported_modules(path):
            top = mod.split(".")[0]
            if top in FORBIDDEN[package]:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    return bad


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_lower_floors_do_not_import_upper_ones(package):
    assert violations(package) == []


def test_the_checker_sees_function_level_and_dynamic_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        "import os\n"
        "def f():\n"
        "    from daq.fanout import FanOut\n"
        "    import drivers.base\n"
        "    return importlib.import_module('daq.cli')\n"
    )
    mods = [m for _, m in imported_modules(src)]
    assert mods == ["os", "daq.fanout", "drivers.base", "daq.cli"]


def test_cli_verb_modules_do_not_import_each_other():
    """A thin CLI package: verbs import the shared helpers (``common``), never another verb module."""
    cli = ROOT / "daq" / "cli"
    verbs = {p.stem for p in cli.glob("*.py")} - {"__init__", "common", "__main__"}
    bad = []
    for path in sorted(cli.glob("*.py")):
        if path.stem in ("__init__", "__main__"):
            continue
        for line, mod in imported_modules(path):
            parts = mod.split(".")
            if parts[:2] == ["daq", "cli"] and len(parts) > 2 and parts[2] in verbs:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    assert bad == []
