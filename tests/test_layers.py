"""The package's shape: the layers contract (pyproject.toml) and no import circles."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: The one loop the layers allow: the registry loads the algorithms, which register themselves.
ALLOWED_LOOP = "magbench.methods"


def test_layers_contract_is_kept():
    lint = pytest.importorskip("importlinter.cli")
    cwd = os.getcwd()
    os.chdir(REPO)
    try:
        assert lint.lint_imports(config_filename=str(REPO / "pyproject.toml"), no_cache=True,
                                 no_logo=True) == 0, "a module imports from a layer above it"
    finally:
        os.chdir(cwd)


def strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's strongly connected components with more than one module (import circles)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_circle_finder_finds_a_circle():
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [
        {"a", "b", "c"}]
    assert strongly_connected({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_outside_the_registry():
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("magbench")
    edges = {m: set(graph.find_modules_directly_imported_by(m)) - {"magbench"}
             for m in graph.modules}
    circles = [c for c in strongly_connected(edges)
               if not all(m.startswith(ALLOWED_LOOP + ".") for m in c)]
    assert circles == [], f"import circles: {circles}"
