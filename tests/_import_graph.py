"""The project's import graph and its circles, from the source text alone (``ast``, nothing imported).

Why a graph and not a try-import: a circle that Python tolerates today (a lazy import inside a function,
or a ``from x import y`` that happens to run after ``y`` is defined) is still two modules that cannot be
read, tested or moved one without the other (issue 28, item 2). So every import statement counts — at
module level or inside a function, under ``if TYPE_CHECKING`` or not — and so does
``importlib.import_module("...")`` with a literal name.

An edge goes to the most specific module the import names: ``from analysis.model import config`` is an
edge to ``analysis.model.config`` (a module), ``from analysis.model.config import RigConfig`` an edge to
``analysis.model.config``. The implicit import of parent packages (``analysis/model/__init__.py`` runs
before ``analysis.model.config``) is not an edge; an ``__init__`` that itself imports is, like any module.

Plain functions, so ``tests/test_layering.py`` and a command line can share them::

    python tests/_import_graph.py analysis drivers
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path


def _resolve_relative(module: str | None, level: int, importer: str, is_package: bool) -> str:
    """The absolute name of ``from <level dots><module> import …`` written in module ``importer``."""
    parts = importer.split(".")
    base = parts if is_package else parts[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def imports_of(path: Path | str, module_name: str | None = None, known: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """Every module ``path`` imports, in source order of the walk, at any depth of the file.

    ``import a.b`` gives ``a.b``; ``from a.b import c`` gives ``a.b.c`` when that is a module in ``known``
    (``from analysis.model import config``) and ``a.b`` otherwise (``c`` is a name defined in ``a.b``);
    ``importlib.import_module("a.b")`` gives ``a.b``. Relative imports are resolved when ``module_name``
    (the dotted name of ``path``) is given, and skipped otherwise.
    """
    path = Path(path)
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if module_name is None:
                    continue
                base = _resolve_relative(node.module, node.level, module_name, path.name == "__init__.py")
            else:
                base = node.module or ""
            subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known]
            if len(subs) < len(node.names):
                out.append(base)
            out += subs
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                out.append(node.args[0].value)
    return [m for m in out if m]


def _module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def module_graph(root: Path | str, packages: list[str] | tuple[str, ...]) -> dict[str, set[str]]:
    """``{module: {modules it imports}}`` over every ``.py`` file of ``packages`` under ``root``.

    Only edges between modules of the graph are kept (numpy, the standard library and packages outside
    ``packages`` are not nodes). An import of ``a.b.c`` where ``c`` is a name, not a module, is an edge to
    ``a.b``: the longest prefix that is a module of the graph.
    """
    root = Path(root)
    files = {_module_name(root, p): p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))}
    known = frozenset(files)
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        deps: set[str] = set()
        for mod in imports_of(path, name, known):
            parts = mod.split(".")
            while parts and ".".join(parts) not in known:
                parts.pop()
            if parts and ".".join(parts) != name:
                deps.add(".".join(parts))
        graph[name] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (and modules that import themselves).

    Tarjan's algorithm, iterative (no recursion limit on deep graphs); each circle is sorted, the list is
    sorted, so the output is stable and readable in an assertion message.
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work: list[tuple[str, list[str]]] = [(start, sorted(graph.get(start, ())))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, todo = work[-1]
            if todo:
                nxt = todo.pop(0)
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, sorted(graph.get(nxt, ()))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    comp.append(top)
                    if top == node:
                        break
                if len(comp) > 1 or node in graph.get(node, ()):
                    found.append(sorted(comp))
    return sorted(found)


def cycle_edges(graph: dict[str, set[str]], cycle: list[str]) -> list[tuple[str, str]]:
    """The edges inside one circle, to say which imports close it."""
    members = set(cycle)
    return sorted((a, b) for a in cycle for b in graph.get(a, ()) if b in members)


def main(argv: list[str]) -> int:
    root = Path(__file__).resolve().parents[1]
    packages = argv or ["analysis", "drivers"]
    graph = module_graph(root, packages)
    found = cycles(graph)
    print(f"{len(graph)} modules in {', '.join(packages)}; {len(found)} import circle(s)")
    for cyc in found:
        print(f"circle of {len(cyc)}: {' '.join(cyc)}")
        for a, b in cycle_edges(graph, cyc):
            print(f"    {a} -> {b}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
