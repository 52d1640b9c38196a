"""Write or check the code deps of every DVC stage: exactly the project files its command
runs from, so that editing a file re-runs the stages that import it and no other.

    python scripts/dvc_deps.py --check   # exit 1 and list the differences (tests run this)
    python scripts/dvc_deps.py --write   # rewrite the code deps in place

A stage ``mimicgen-pipe <stage> ...`` runs from ``stages/<stage>.py``, the CLI's arithmetic
pins (``mimicgen_pipe/arithmetic.py``: they decide the outputs' last bits), every project module
it imports (transitively, imports inside functions included), and every module of a
registry package it loads from by a name known at run time (``registry.load("<package>",
name)``; a literal name: that module only; see
mimicgen_pipe/registry.py). Under ``envs/`` only the stage's back end is followed (the
``--backend`` its command passes, else the pipeline's ``backend`` param). Task files are
looked up by name at run time; each stage lists its own task file as a templated dep
(``envs/<backend>/tasks/${task}.py``), which this script leaves as written, and follows what
those task files import. Only list items that are project ``.py`` files are rewritten;
data, reference files and templated paths stay where they are.
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe", "envs", "stages")
PIPELINES = ("dvc.yaml", "suite/dvc.yaml", "quickstart/dvc.yaml", "transit/dvc.yaml")
CODE_DEP = re.compile(r"^(mimicgen_pipe|envs|stages)/[^$]*\.py$")


def module_file(name: str) -> Path | None:
    """The repository file of a project module (package __init__ or module), else None."""
    if name.split(".")[0] not in PACKAGES:
        return None
    base = REPO / Path(*name.split("."))
    for path in (base / "__init__.py", base.with_suffix(".py")):
        if path.exists():
            return path
    return None


def package_modules(package: str) -> list[str]:
    """Every module of a project package, by listing its folder (what a registry offers)."""
    folder = REPO / Path(*package.split("."))
    return [
        f"{package}.{p.stem if p.suffix == '.py' else p.name}"
        for p in sorted(folder.iterdir())
        if not p.name.startswith("_") and (p.suffix == ".py" or (p / "__init__.py").exists())
    ]


def imported_modules(path: Path) -> set[str]:
    """Project modules ``path`` imports anywhere in its body (``from a import b`` counts
    both a and a.b, since b may be a submodule), and every module of each registry package
    it loads from (``load("<package>", ...)`` with a literal package name)."""
    out: set[str] = set()
    inside = path.is_relative_to(REPO)
    package = ".".join(path.relative_to(REPO).with_suffix("").parts[:-1]) if inside else ""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Call) and _loads_from(node):
            loaded = node.args[0].value  # type: ignore[attr-defined]
            name = node.args[1] if len(node.args) > 1 else None
            if isinstance(name, ast.Constant) and isinstance(name.value, str):
                out.add(f"{loaded}.{name.value}")  # one named module of the registry
            elif not loaded.endswith(".tasks"):  # task files: the stage's templated dep
                out.update(package_modules(loaded))
    return {m for m in out if module_file(m) is not None}


def _loads_from(call: ast.Call) -> bool:
    func = call.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    return (
        name == "load"
        and bool(call.args)
        and isinstance(call.args[0], ast.Constant)
        and isinstance(call.args[0].value, str)
        and call.args[0].value.split(".")[0] in PACKAGES
    )


def closure(stage_module: str, backend: str, tasks: Iterable[str] = ()) -> set[Path]:
    """Files a stage's code runs from: its module, the packages it sits in, what the
    ``tasks`` it runs import, and everything they import, following only ``backend``'s
    package under envs/. The task files themselves are not included."""
    backends = {p.parent.name for p in (REPO / "envs").glob("*/__init__.py")}
    roots = [f"envs.{backend}.tasks.{t}" for t in tasks]
    # the CLI pins the numeric libraries' code paths before any stage runs (cli.py)
    todo = [stage_module, "stages", "mimicgen_pipe.arithmetic", *roots]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        parts = name.split(".")
        other_backend = parts[0] == "envs" and len(parts) > 1 and parts[1] in backends - {backend}
        if name in seen or other_backend:
            continue
        seen.add(name)
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]  # packages run first
        todo += imported_modules(module_file(name))
    return {module_file(m).relative_to(REPO) for m in seen if m not in roots}


def _resolve(text: str, params: dict) -> str:
    """``text`` with ``${a.b}`` params substituted where they are plain values."""

    def value(match: re.Match) -> str:
        node: object = params
        for key in match.group(1).split("."):
            if not isinstance(node, dict) or key not in node:
                return match.group(0)
            node = node[key]
        return str(node) if isinstance(node, (str, int, float)) else match.group(0)

    return re.sub(r"\$\{([\w.]+)\}", value, text)


def _resolve_list(text: str, params: dict) -> list[str]:
    node: object = params
    for key in text.strip("${}").split("."):
        node = node[key]  # type: ignore[index]
    return [str(v) for v in node]  # type: ignore[union-attr]


def pipeline_params(pipeline: Path) -> dict:
    """The params a pipeline's stages read: its first ``vars`` file, else params.yaml
    beside it."""
    doc = yaml.safe_load(pipeline.read_text())
    files = [v for v in doc.get("vars", []) if isinstance(v, str)]
    path = pipeline.parent / (files[0] if files else "params.yaml")
    return yaml.safe_load(path.read_text())


def stage_code(stage: dict, params: dict) -> tuple[str, str, list[str]]:
    """(stage module, back end, task names) that a dvc.yaml stage's command runs."""
    cmd = _resolve(" ".join(stage["cmd"].split()), params)
    words = cmd.split()
    if words[:1] != ["mimicgen-pipe"] or len(words) < 2:
        raise SystemExit(f"a stage command must run mimicgen-pipe: {stage['cmd']!r}")
    backend = words[words.index("--backend") + 1] if "--backend" in words else params["backend"]
    if "${item.task}" in cmd:
        axis = (stage.get("matrix") or {})["task"]
        tasks = _resolve_list(axis, params) if isinstance(axis, str) else [str(t) for t in axis]
    else:
        tasks = [words[words.index("--task") + 1]] if "--task" in words else [params["task"]]
    return f"stages.{words[1]}", backend, tasks


def wanted_deps(pipeline: Path) -> dict[str, list[str]]:
    """Stage name -> the sorted code deps it should list, paths relative to its wdir."""
    doc = yaml.safe_load(pipeline.read_text())
    params = pipeline_params(pipeline)
    out = {}
    for name, stage in doc["stages"].items():
        module, backend, tasks = stage_code(stage, params)
        wdir = (pipeline.parent / stage.get("wdir", ".")).resolve()
        files = sorted(closure(module, backend, tasks))
        out[name] = [Path(os.path.relpath(REPO / f, wdir)).as_posix() for f in files]
    return out


def rewrite(text: str, wanted: dict[str, list[str]]) -> str:
    """``text`` (a dvc.yaml) with each stage's project .py deps replaced by ``wanted``,
    placed where its first one was (at the top of ``deps`` when it had none); comments,
    order and every other line kept."""
    out: list[str] = []
    top = stage = None
    in_deps = placed = False

    def place() -> None:
        nonlocal placed
        if stage in wanted and not placed:
            out.extend(f"      - {d}\n" for d in wanted[stage])
            placed = True

    for line in text.splitlines(keepends=True):
        if m := re.match(r"^(\w+):", line):
            top, stage, in_deps = m.group(1), None, False
        elif top == "stages" and (m := re.match(r"^  ([\w-]+):", line)):
            stage, in_deps = m.group(1), False
        elif stage and re.match(r"^    deps:\s*$", line):
            in_deps, placed = True, False
            out.append(line)
            continue
        elif in_deps and not re.match(r"^      (- |#)", line):
            place()
            in_deps = False
        if in_deps and (m := re.match(r"^      - (\S+)\s*$", line)):
            dep = m.group(1).removeprefix("../")
            if CODE_DEP.match(dep):
                place()
                continue
            if not placed and not line.lstrip().startswith("#"):
                place()
        out.append(line)
    return "".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="exit 1 when a deps list differs")
    mode.add_argument("--write", action="store_true", help="rewrite the deps lists in place")
    args = p.parse_args(argv)
    stale = []
    for name in PIPELINES:
        path = REPO / name
        if not path.exists():
            continue
        text = path.read_text()
        new = rewrite(text, wanted_deps(path))
        if new == text:
            continue
        if args.write:
            path.write_text(new)
            print(f"{name}: code deps rewritten")
        else:
            old_deps = _code_deps(text)
            new_deps = _code_deps(new)
            differ = []
            for stage in sorted(set(old_deps) | set(new_deps)):
                extra = sorted(set(old_deps.get(stage, ())) - set(new_deps.get(stage, ())))
                missing = sorted(set(new_deps.get(stage, ())) - set(old_deps.get(stage, ())))
                if extra or missing:
                    differ.append(f"{name}: {stage}: missing {missing}, not imported {extra}")
            stale += differ or [f"{name}: code deps out of order"]
    for line in stale:
        print(line, file=sys.stderr)
    if stale:
        print("run: python scripts/dvc_deps.py --write", file=sys.stderr)
    return 1 if stale else 0


def _code_deps(text: str) -> dict[str, list[str]]:
    doc = yaml.safe_load(text)
    return {
        name: [d for d in stage.get("deps", []) if CODE_DEP.match(d.removeprefix("../"))]
        for name, stage in doc["stages"].items()
    }


if __name__ == "__main__":
    sys.exit(main())
