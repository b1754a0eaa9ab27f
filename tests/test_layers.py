"""The layer order of the packages (README "Design"), checked on the source of every module.

Lowest first: config -> net -> (agents, simulator, hinf, ident: peers) -> coload. A module may import
its own package and any lower layer, never a peer or a higher one; and no two files import each
other, directly or round a longer loop. Every import counts, also one inside a function: a lazy
import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYER = {"config": 0, "net": 1, "agents": 2, "simulator": 2, "hinf": 2, "ident": 2, "coload": 3}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in LAYER for p in sorted((ROOT / pkg).rglob("*.py"))}


MODULES = _modules()


def _typing_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under ``if TYPE_CHECKING:`` (annotations only: nothing is imported at run time)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            out.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return out


def _imports(name: str, path: Path, *, typing: bool = True) -> set[str]:
    """Project modules that ``name`` imports (resolved to the deepest module that exists); without
    ``typing``, those imported for annotations only are left out."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    skip = set() if typing else _typing_only(tree)
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" for a in node.names] + [mod]
        for t in targets:
            while t and t not in MODULES:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}
RUNTIME_GRAPH = {name: _imports(name, path, typing=False) for name, path in MODULES.items()}


def test_every_package_is_checked():
    assert {n.split(".")[0] for n in MODULES} == set(LAYER)
    assert len(MODULES) > 60  # the walk found the tree, not an empty folder


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_follow_the_layer_order(name):
    pkg = name.split(".")[0]
    bad = []
    for dep in sorted(GRAPH[name]):
        dpkg = dep.split(".")[0]
        if dpkg != pkg and LAYER[dpkg] >= LAYER[pkg]:
            bad.append(f"{dep} ({'peer' if LAYER[dpkg] == LAYER[pkg] else 'higher layer'})")
    assert not bad, f"{MODULES[name].relative_to(ROOT)} imports {', '.join(bad)}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_cycle_between_files():
    # a package's __init__ importing its own modules is how a package exports names, not a cycle;
    # an annotation-only import (a hook typed with its caller's class) is no run-time dependency
    graph = {n: {d for d in deps if not (MODULES[d].name == "__init__.py" and n.startswith(d + "."))}
             for n, deps in RUNTIME_GRAPH.items()}
    assert _cycles(graph) == []


def test_the_checker_sees_a_violation_and_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert "coload.cli" in GRAPH["coload.__main__"]
