"""How the project's packages depend on each other, read from their source (nothing is
imported): the library (mimicgen_pipe) never imports the simulator back ends (envs), no
project modules import each other in a cycle, and the source stage runs without the
exporters.

The import graph: an edge from a module to each project module it imports anywhere in its
body, imports inside functions included; ``from a import b`` counts a, and a.b where a.b is
a module. Imports under ``if TYPE_CHECKING:`` are no edges (they never run; an annotation
may name a module that imports this one). The closure of a stage adds what running a module
runs: its parent packages, and every module of a registry package it loads from
(``load("<package>", name)``: the named module where the name is a literal)."""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe", "envs", "stages")


def module_name(path: Path, root: Path = REPO) -> str:
    """``mimicgen_pipe/exporters/__init__.py`` -> ``mimicgen_pipe.exporters``."""
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules(root: Path = REPO) -> dict[str, Path]:
    """Module name -> file, for every module of the project's packages."""
    return {
        module_name(p, root): p
        for package in PACKAGES
        for p in sorted((root / package).rglob("*.py"))
    }


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    name = test.attr if isinstance(test, ast.Attribute) else getattr(test, "id", None)
    return name == "TYPE_CHECKING"


def _nodes(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree`` but those under ``if TYPE_CHECKING:``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                todo.extend(child.orelse)
            else:
                todo.append(child)


def _registry_package(node: ast.AST) -> tuple[str, str | None] | None:
    """(package, literal name or None) of a ``load("<package>", name)`` call; else None."""
    if not isinstance(node, ast.Call) or not node.args:
        return None
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    first = node.args[0]
    if name != "load" or not (isinstance(first, ast.Constant) and isinstance(first.value, str)):
        return None
    second = node.args[1] if len(node.args) > 1 else None
    literal = second.value if isinstance(second, ast.Constant) else None
    return first.value, literal if isinstance(literal, str) else None


def imported(name: str, modules: Mapping[str, Path]) -> set[str]:
    """The project modules module ``name`` imports (its edges in the import graph)."""
    path = modules[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in _nodes(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return {m for m in out if m in modules and m != name}


def loaded(name: str, modules: Mapping[str, Path]) -> set[str]:
    """The project modules module ``name`` may load through the registry."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(modules[name].read_text())):
        found = _registry_package(node)
        if found is None:
            continue
        package, literal = found
        if literal is not None:
            out.add(f"{package}.{literal}")
        else:
            depth = package.count(".") + 1
            out.update(
                m
                for m in modules
                if m.startswith(package + ".")
                and m.count(".") == depth
                and not m.rpartition(".")[2].startswith("_")
            )
    return {m for m in out if m in modules}


def import_graph(modules: Mapping[str, Path]) -> dict[str, set[str]]:
    return {name: imported(name, modules) for name in modules}


def cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The graph's strongly connected components of more than one module (each a set of
    modules that import each other, directly or not), sorted (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        # iterative depth-first search: (node, its neighbours still to visit)
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, rest = work[-1]
            nxt = next(rest, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def closure(start: str, modules: Mapping[str, Path]) -> set[str]:
    """Every project module that running ``start`` may run: what it imports, its parent
    packages and what it loads through the registry, transitively."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        name = todo.pop()
        if name in seen or name not in modules:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += imported(name, modules) | loaded(name, modules)
    return seen


def test_the_library_never_imports_the_back_ends():
    modules = project_modules()
    offenders = {
        name: sorted(
            m for m in imported(name, modules) | loaded(name, modules) if m.split(".")[0] == "envs"
        )
        for name in modules
        if name.split(".")[0] == "mimicgen_pipe"
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_no_project_modules_import_each_other_in_a_cycle():
    assert cycles(import_graph(project_modules())) == []


def test_the_source_stage_runs_without_the_exporters():
    modules = project_modules()
    reached = closure("stages.source", modules)
    assert "mimicgen_pipe.robomimic_source" in reached  # the closure follows the stage's imports
    assert sorted(m for m in reached if m.startswith("mimicgen_pipe.exporters")) == []


def test_the_graph_sees_imports_inside_functions_and_skips_type_checking(tmp_path):
    """The reading itself, on a small package: a function's import is an edge, an import
    under ``if TYPE_CHECKING:`` is none, a cycle is found, a registry load is followed."""
    pkg = tmp_path / "mimicgen_pipe"
    (pkg / "choices").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "choices" / "__init__.py").write_text("")
    (pkg / "choices" / "one.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from mimicgen_pipe import b\n")
    (pkg / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from mimicgen_pipe import c\n"
        "from . import a\n"
    )
    (pkg / "c.py").write_text(
        "from mimicgen_pipe.registry import load\nload('mimicgen_pipe.choices', name)\n"
        "import mimicgen_pipe.b\n"
    )
    for package in PACKAGES[1:]:
        (tmp_path / package).mkdir()
    modules = project_modules(tmp_path)
    graph = import_graph(modules)
    assert graph["mimicgen_pipe.a"] == {"mimicgen_pipe", "mimicgen_pipe.b"}
    assert graph["mimicgen_pipe.b"] == {"mimicgen_pipe", "mimicgen_pipe.a"}
    assert cycles(graph) == [["mimicgen_pipe.a", "mimicgen_pipe.b"]]
    assert closure("mimicgen_pipe.c", modules) == {
        "mimicgen_pipe",
        "mimicgen_pipe.a",
        "mimicgen_pipe.b",
        "mimicgen_pipe.c",
        "mimicgen_pipe.choices.one",
        "mimicgen_pipe.choices",
    }
