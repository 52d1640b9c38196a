"""How the project's packages depend on each other, read from their source (nothing is
imported): each layer of mimicgen_pipe (a folder) imports only the layers below it, so no
layer but the stages imports the back ends, and a back end imports only the core; no project
modules import each other in a cycle, the source stage runs without the exporters, and
neither the product (mimicgen_pipe, scripts) nor its tests import or run the lab's
investigation scripts (lab/).

The import graph: an edge from a module to each project module it imports anywhere in its
body, imports inside functions included; ``from a import b`` counts a, and a.b where a.b is
a module. Imports under ``if TYPE_CHECKING:`` are no edges (they never run; an annotation
may name a module that imports this one). The closure of a stage adds what running a module
runs: its parent packages, and every module of a registry package it loads from
(``load("<package>", name)``: the named module where the name is a literal)."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator, Mapping
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe",)


def module_name(path: Path, root: Path = REPO) -> str:
    """``mimicgen_pipe/formats/exporters/__init__.py`` -> ``mimicgen_pipe.formats.exporters``."""
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


# Each layer of the package (a folder of mimicgen_pipe/) and the layers it may import besides
# itself; each folder's __init__ docstring says the same in words. The stages compose them all.
LAYERS: dict[str, frozenset[str]] = {
    "core": frozenset(),
    "method": frozenset({"core"}),
    "data": frozenset({"core"}),
    "run": frozenset({"core", "method", "data"}),
    "sources": frozenset({"core", "method", "data", "run"}),
    "learn": frozenset({"core", "method", "data", "run"}),
    "media": frozenset({"core", "method", "data", "run"}),
    "formats": frozenset({"core", "method", "data", "run", "sources"}),
    "report": frozenset({"core", "data"}),
    "backends": frozenset({"core"}),
    "tasks": frozenset({"core", "backends"}),
}
LAYERS["stages"] = frozenset(LAYERS)
# what a layer may load by name through the registry besides what it may import: a back end
# finds its task files (mimicgen_pipe.tasks.<backend>) when asked for one
LOADS: dict[str, frozenset[str]] = {"backends": frozenset({"tasks"})}


def layer(module: str) -> str | None:
    """The layer of a module of mimicgen_pipe (its folder), None for the package itself and
    the command line (mimicgen_pipe.cli), which are no layer."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def layer_breaks(modules: Mapping[str, Path]) -> dict[str, list[str]]:
    """module -> the modules it imports or loads from a layer its own may not import."""
    found = {}
    for name in modules:
        own = layer(name)
        if own is None:
            continue
        allowed = LAYERS[own] | {own, None}
        wrong = sorted(
            {m for m in imported(name, modules) if layer(m) not in allowed}
            | {m for m in loaded(name, modules) if layer(m) not in allowed | LOADS.get(own, set())}
        )
        if wrong:
            found[name] = wrong
    return found


def test_every_module_is_in_a_layer_that_its_folder_names():
    modules = project_modules()
    assert {m for m in modules if layer(m) is None} == {"mimicgen_pipe", "mimicgen_pipe.cli"}
    for folder in LAYERS:
        doc = ast.get_docstring(
            ast.parse((REPO / "mimicgen_pipe" / folder / "__init__.py").read_text())
        )
        assert doc and "Imports" in doc, f"mimicgen_pipe/{folder}/__init__.py: no import rule"


def test_each_layer_imports_only_the_layers_below_it():
    assert layer_breaks(project_modules()) == {}


def test_the_layer_rule_finds_a_wrong_import(tmp_path):
    """A back end that imports the data layer, and a core module that loads a method
    module through the registry, are both found."""
    pkg = tmp_path / "mimicgen_pipe"
    for folder in ("core", "data", "method", "backends", "backends/sim"):
        (pkg / folder).mkdir(parents=True)
        (pkg / folder / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "params.py").write_text("")
    (pkg / "method" / "pick.py").write_text("")
    (pkg / "core" / "poses.py").write_text("")
    (pkg / "backends" / "sim" / "env.py").write_text(
        "from mimicgen_pipe.core import poses\nfrom mimicgen_pipe.data.params import x\n"
    )
    (pkg / "core" / "choose.py").write_text('load("mimicgen_pipe.method", "pick")\n')
    assert layer_breaks(project_modules(tmp_path)) == {
        "mimicgen_pipe.backends.sim.env": ["mimicgen_pipe.data.params"],
        "mimicgen_pipe.core.choose": ["mimicgen_pipe.method.pick"],
    }


def test_no_project_modules_import_each_other_in_a_cycle():
    assert cycles(import_graph(project_modules())) == []


def test_the_source_stage_runs_without_the_exporters():
    modules = project_modules()
    reached = closure("mimicgen_pipe.stages.source", modules)
    assert (
        "mimicgen_pipe.sources.robomimic_source" in reached
    )  # the closure follows the stage's imports
    assert sorted(m for m in reached if m.startswith("mimicgen_pipe.formats.exporters")) == []


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
        "from mimicgen_pipe.core.registry import load\nload('mimicgen_pipe.choices', name)\n"
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


PRODUCT = ("mimicgen_pipe", "scripts")
LAB_MODULE = re.compile(r"lab(\.\w+)+")  # "lab.scripts.x": a module of the lab by name


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstrings of ``tree``'s module, classes and functions (prose, which
    may name a lab script)."""
    kinds = ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef
    return {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, kinds) and node.body and isinstance(node.body[0], ast.Expr)
    }


def path_parts(node: ast.AST) -> list[str] | None:
    """The components of the path ``node`` spells: a string (``"lab/scripts/x.py"``) or a
    chain of ``/`` (``REPO / "lab" / "x.py"``), whose other parts count as "?"; None for
    anything else."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value.split("/")
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
        return (path_parts(node.left) or ["?"]) + (path_parts(node.right) or ["?"])
    return None


def names_lab_code(parts: list[str]) -> bool:
    """Whether a path names the lab's code: "lab", then "scripts" or a .py file (the lab's
    README and notes are documents, which the docs' link check reads)."""
    after = parts[parts.index("lab") + 1 :] if "lab" in parts else []
    return any(p == "scripts" or p.endswith(".py") for p in after)


def names_the_lab(node: ast.AST, prose: set[int]) -> bool:
    """Whether ``node`` imports a module of the lab, or names one by its dotted name or a
    path to the lab's code (to load or run it); ``prose``: the ids of docstrings, skipped."""
    if isinstance(node, ast.Import):
        return any(a.name.split(".")[0] == "lab" for a in node.names)
    if isinstance(node, ast.ImportFrom):
        return not node.level and (node.module or "").split(".")[0] == "lab"
    if id(node) in prose:
        return False
    if isinstance(node, ast.Constant) and LAB_MODULE.fullmatch(str(node.value)):
        return True
    parts = path_parts(node)
    return parts is not None and names_lab_code(parts)


def lab_uses(path: Path) -> list[int]:
    """The lines of ``path`` that import or name the lab's code (:func:`names_the_lab`)."""
    tree = ast.parse(path.read_text(), str(path))
    prose = _docstrings(tree)
    return sorted({getattr(n, "lineno", 0) for n in ast.walk(tree) if names_the_lab(n, prose)})


def checked_by_the_lab_rule(root: Path = REPO) -> list[Path]:
    """Every Python file of the product's packages and scripts, and of its tests."""
    return [p for d in (*PRODUCT, "tests") for p in sorted((root / d).rglob("*.py"))]


def test_neither_the_product_nor_its_tests_import_or_run_the_lab():
    """The lab (investigation scripts) builds on the product, never the other way: no
    product module depends on a lab script, and no product test covers one."""
    files = {p.relative_to(REPO).as_posix(): p for p in checked_by_the_lab_rule()}
    assert {"mimicgen_pipe/learn/evaluation.py", "scripts/dvc_deps.py", "tests/conftest.py"} <= set(
        files
    )
    uses = {name: lab_uses(p) for name, p in files.items()}
    assert {name: lines for name, lines in uses.items() if lines} == {}


def test_the_lab_rule_finds_imports_and_paths_of_lab_code(tmp_path):
    """The reading itself: imports of the lab, its modules by name, and paths to its scripts
    are found; a path to the lab's README, a docstring and other names of "lab" are not."""
    source = tmp_path / "m.py"
    source.write_text(
        '"""Reads lab/scripts/x.py."""\n'  # 1: a docstring
        "import lab.scripts.x\n"  # 2
        "from lab.scripts import x\n"  # 3
        'importlib.import_module("lab.scripts.x")\n'  # 4
        'SCRIPT = REPO / "lab" / "scripts" / "x.py"\n'  # 5
        'runpy.run_path("lab/scripts/x.py")\n'  # 6
        'sys.path.insert(0, str(ROOT / "lab/scripts"))\n'  # 7
        'PAGES = [REPO / "lab" / "README.md", "lab", "a lab.", "labels.py"]\n'  # 8
        "import labels\n"  # 9
        "def f():\n"  # 10
        '    """Like lab/scripts/x.py."""\n'  # 11
    )
    assert lab_uses(source) == [2, 3, 4, 5, 6, 7]
