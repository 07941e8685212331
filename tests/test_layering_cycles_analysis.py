"""No import circle in ``analysis/`` or ``drivers/``, and the rig schema imports no behaviour (issue 28, item 2).

The graph is read from the source (tests/_import_graph.py): a lazy import inside a function and an import under
``if TYPE_CHECKING`` are dependencies like any other, so a circle Python happens to tolerate still fails here.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ._import_graph import cycle_edges, cycles, imports_of, module_graph

ROOT = Path(__file__).resolve().parents[1]

#: What the rig schema may import inside the project: the loader and the leaves that convert or check what a rig
#: file writes. The rig, channel table, geometry, updater and export sit above it.
SCHEMA_IMPORTS = {"analysis.model.loader", "analysis.model.units", "analysis.model.update_targets", "analysis.model.wireframe"}


@pytest.mark.parametrize("package", ["analysis", "drivers"])
def test_no_import_circle(package):
    graph = module_graph(ROOT, [package])
    found = cycles(graph)
    assert found == [], "\n".join(f"{' '.join(c)}: {cycle_edges(graph, c)}" for c in found)


def test_the_rig_schema_imports_no_behaviour():
    graph = module_graph(ROOT, ["analysis"])
    assert graph["analysis.model.config"] <= SCHEMA_IMPORTS, graph["analysis.model.config"] - SCHEMA_IMPORTS
    for leaf in SCHEMA_IMPORTS:
        assert "analysis.model.config" not in graph[leaf]


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_the_checker_sees_lazy_type_checking_relative_and_submodule_imports(tmp_path):
    root = _package(
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
