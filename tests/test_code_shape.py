"""The package's code stays readable in pieces: no function (or method, or function inside
one) in mimicgen_pipe/ (stages and back ends included) is over MAX_LINES lines, docstring
included. A task's scripted demonstrator (mimicgen_pipe/tasks/<backend>/) is one long
motion script and is left out. Read from the source: nothing is imported."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_LINES = 80


def checked_files(root: Path = REPO) -> list[Path]:
    """Every Python file of mimicgen_pipe/ but the task files under mimicgen_pipe/tasks/."""
    files = []
    for path in sorted((root / "mimicgen_pipe").rglob("*.py")):
        parts = path.relative_to(root / "mimicgen_pipe").parts
        if parts[0] != "tasks":  # a task's scripted demonstrator is one long recipe
            files.append(path)
    return files


def function_lengths(path: Path) -> Iterator[tuple[str, int, int]]:
    """(qualified name, first line, lines from ``def`` to the body's end) of every function
    in ``path``, nested ones included."""

    def walk(node: ast.AST, prefix: str) -> Iterator[tuple[str, int, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                assert child.end_lineno is not None
                yield name, child.lineno, child.end_lineno - child.lineno + 1
                yield from walk(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                yield from walk(child, f"{prefix}{child.name}.")
            else:
                yield from walk(child, prefix)

    yield from walk(ast.parse(path.read_text(), str(path)), "")


def test_the_checked_files_are_the_library_and_back_ends_without_task_scripts():
    files = {p.relative_to(REPO).as_posix() for p in checked_files()}
    assert (
        "mimicgen_pipe/method/generation.py" in files
        and "mimicgen_pipe/backends/__init__.py" in files
    )
    assert not [f for f in files if f.startswith("mimicgen_pipe/tasks/")]


def test_no_function_is_over_80_lines():
    long = [
        f"{path.relative_to(REPO).as_posix()}:{line} {name} ({n} lines)"
        for path in checked_files()
        for name, line, n in function_lengths(path)
        if n > MAX_LINES
    ]
    assert not long, f"functions over {MAX_LINES} lines:\n" + "\n".join(long)


def test_a_long_nested_function_is_found(tmp_path):
    body = "\n".join(f"            x{k} = {k}" for k in range(MAX_LINES))
    source = tmp_path / "m.py"
    source.write_text(f"class A:\n    def f(self):\n        def g():\n{body}\n")
    lengths = {name: n for name, _, n in function_lengths(source)}
    assert lengths["A.f"] == MAX_LINES + 2 and lengths["A.f.g"] == MAX_LINES + 1
