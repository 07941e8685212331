"""The floors of the house (docs/architecture.md, "Floors"), and no import circles anywhere.

Between packages imports run one way: ``analysis`` < ``drivers`` < ``daq``. Inside ``daq``: the service at
its root (recording and replay: the Recorder, sources, lanes, fan-out, timeline, hit gate, log, config,
outputs, terminal, view) < the offline studies (``daq/studies/``) < the command line (``daq/cli/``). So the
service never imports a study or the CLI, a study never imports the CLI, and nothing outside ``daq/cli/``
imports it. And no two modules import each other, directly or round a longer circle.

Every import statement counts, at module level or inside a function (a lazy import is still a dependency),
under ``if TYPE_CHECKING:`` too, and so do ``importlib.import_module("...")`` calls with a literal name.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ._import_graph import cycle_edges, cycles, imports_of, module_graph

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("analysis", "drivers", "daq")


def floor(module: str) -> tuple[int, str]:
    """(height, name) of a module's floor: a module may import only from its own floor or below."""
    top = module.split(".")[0]
    if top == "analysis":
        return 0, "analysis"
    if top == "drivers":
        return 1, "drivers"
    if module == "daq.cli" or module.startswith("daq.cli."):
        return 4, "cli"
    if module == "daq.studies" or module.startswith("daq.studies."):
        return 3, "studies"
    return 2, "service"


def floor_violations(graph: dict[str, set[str]]) -> list[str]:
    """Every edge that climbs a floor (the service importing a study, a study the CLI, analysis daq, ...)."""
    bad = []
    for mod, deps in sorted(graph.items()):
        for dep in sorted(deps):
            (h, name), (hd, dname) = floor(mod), floor(dep)
            if hd > h:
                bad.append(f"{mod} ({name}) imports {dep} ({dname})")
    return bad


#: What the rig schema may import inside the project: the loader and the leaves that convert or check what a rig
#: file writes. The rig, channel table, geometry, updater and export sit above it (the schema is data).
SCHEMA_IMPORTS = {"analysis.model.loader", "analysis.model.units", "analysis.model.update_targets", "analysis.model.wireframe"}


def test_every_import_runs_down_the_floors():
    assert floor_violations(module_graph(ROOT, PACKAGES)) == []


def test_no_import_circles():
    graph = module_graph(ROOT, PACKAGES)
    found = cycles(graph)
    assert found == [], "\n".join(f"{' '.join(c)}: {cycle_edges(graph, c)}" for c in found)


def test_the_rig_schema_imports_no_behaviour():
    graph = module_graph(ROOT, ["analysis"])
    assert graph["analysis.model.config"] <= SCHEMA_IMPORTS, graph["analysis.model.config"] - SCHEMA_IMPORTS
    for leaf in SCHEMA_IMPORTS:
        assert "analysis.model.config" not in graph[leaf]


def test_the_checker_sees_function_level_and_dynamic_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        "import os\n"
        "def f():\n"
        "    from daq.fanout import FanOut\n"
        "    import drivers.base\n"
        "    return importlib.import_module('daq.cli')\n"
    )
    assert imports_of(src) == ["os", "daq.fanout", "drivers.base", "daq.cli"]


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def test_the_checkers_catch_a_planted_circle_and_planted_floor_breaks(tmp_path):
    """Both rules fail on a tree built to break them: a three-module circle (one lazy, one under
    TYPE_CHECKING), the service importing a study, a study importing the CLI, analysis importing daq."""
    root = _tree(tmp_path, {
        "analysis/__init__.py": "",
        "analysis/a.py": "from analysis import b\n",
        "analysis/b.py": "def f():\n    import analysis.c\n",
        "analysis/c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from analysis.a import X\n",
        "analysis/d.py": "from daq.session import S\n",
        "drivers/__init__.py": "",
        "daq/__init__.py": "",
        "daq/session.py": "from daq.studies.frf import run\n",
        "daq/studies/__init__.py": "",
        "daq/studies/frf.py": "from daq.cli.common import fail\n",
        "daq/cli/__init__.py": "",
        "daq/cli/common.py": "from analysis import a\n",
    })  # fmt: skip
    graph = module_graph(root, PACKAGES)
    assert cycles(graph) == [["analysis.a", "analysis.b", "analysis.c"]]
    bad = floor_violations(graph)
    assert any(b.startswith("analysis.d (analysis) imports daq.session (service)") for b in bad)
    assert any(b.startswith("daq.session (service) imports daq.studies.frf (studies)") for b in bad)
    assert any(b.startswith("daq.studies.frf (studies) imports daq.cli.common (cli)") for b in bad)
    assert not any(b.startswith("daq.cli.common") for b in bad)  # the CLI may use anything below it


def test_cli_verb_modules_do_not_import_each_other():
    """A thin CLI package: verbs import the shared helpers (``common``), never another verb module."""
    cli = ROOT / "daq" / "cli"
    verbs = {p.stem for p in cli.glob("*.py")} - {"__init__", "common", "__main__"}
    bad = []
    for path in sorted(cli.glob("*.py")):
        if path.stem in ("__init__", "__main__"):
            continue
        for mod in imports_of(path):
            parts = mod.split(".")
            if parts[:2] == ["daq", "cli"] and len(parts) > 2 and parts[2] in verbs:
                bad.append(f"{path.relative_to(ROOT)} imports {mod}")
    assert bad == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_is_walked(package):
    """The graph covers each package (a renamed package would otherwise pass every rule by having no edges)."""
    assert any(m.split(".")[0] == package for m in module_graph(ROOT, PACKAGES))


def test_the_checker_sees_lazy_type_checking_relative_and_submodule_imports(tmp_path):
    root = _tree(
        tmp_path,
        {
            "p/__init__.py": "",
            "p/a.py": "def f():\n    from p.b import g\n",
            "p/b.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p import c\n",
            "p/c.py": "from . import a\nimport numpy\n",
            "p/d.py": "import importlib\nimportlib.import_module('p.e')\n",
            "p/e.py": "from .d import x\n",
            "p/f.py": "from p.a import f\n",
        },
    )
    graph = module_graph(root, ["p"])
    assert graph["p.a"] == {"p.b"} and graph["p.b"] == {"p.c"} and graph["p.c"] == {"p.a"}
    assert graph["p.f"] == {"p.a"} and graph["p"] == set()
    assert cycles(graph) == [["p.a", "p.b", "p.c"], ["p.d", "p.e"]]
    assert cycle_edges(graph, ["p.d", "p.e"]) == [("p.d", "p.e"), ("p.e", "p.d")]
    assert imports_of(root / "p" / "c.py") == ["numpy"]  # without its module name a relative import is skipped


def test_a_chain_is_not_a_circle_and_a_self_import_is():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert cycles({"a": {"a"}}) == [["a"]]
