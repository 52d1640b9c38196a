"""The code deps of every DVC stage: exactly the project files its command runs from, so
that editing a file re-runs the stages that import it and no other.

Each pipeline's first stage, ``code_deps``, depends on the project's packages as folders and
writes one manifest per stage, ``<pipeline folder>/code_deps/<stage>.txt``: the md5 and path
of every file that stage runs from. Each stage depends on its own manifest. An edit anywhere
re-runs ``code_deps`` (about a second); DVC then re-runs only the stages whose manifest
changed, so the pipelines stay short and the deps stay exact.

    python scripts/dvc_deps.py --manifests suite/dvc.yaml   # the code_deps stage's command
    python scripts/dvc_deps.py --check   # exit 1 naming what differs (tests run this)
    python scripts/dvc_deps.py --write   # write every pipeline's manifests

A stage ``mimicgen-pipe <stage> ...`` runs from ``stages/<stage>.py``, the CLI's arithmetic
pins (``mimicgen_pipe/arithmetic.py``: they decide the outputs' last bits), every project
module it imports (transitively, imports inside functions included), and every module of a
registry package it loads from by a name known at run time (``registry.load("<package>",
name)``; a literal name: that module only; see mimicgen_pipe/registry.py). Under ``envs/``
only the stage's back end is followed (the ``--backend`` its command passes, else the
pipeline's ``backend`` param). Task files are looked up by name at run time; each stage lists
its own task file as a templated dep (``envs/<backend>/tasks/${task}.py``), which stays in
dvc.yaml, and its manifest follows what those task files import.
"""

from __future__ import annotations

import argparse
import ast
import functools
import hashlib
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe", "envs", "stages")
PIPELINES = (
    "dvc.yaml",
    "suite/dvc.yaml",
    "quickstart/dvc.yaml",
    "transit/dvc.yaml",
    "transfer/dvc.yaml",
)
# a project .py file, or a task file by template: what a manifest holds
TASK_OR_CODE = re.compile(
    r"^(\.\./)?((mimicgen_pipe|envs|stages)/[^$]*|envs/[^/]+/tasks/\$\{[\w.]+\})\.py$"
)


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


@functools.cache  # one parse per file: a check walks the same modules for ~100 stages
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


def params_path(pipeline: Path) -> Path:
    """A pipeline's params file: its first ``vars`` file, else params.yaml beside it."""
    doc = yaml.safe_load(pipeline.read_text())
    files = [v for v in doc.get("vars", []) if isinstance(v, str)]
    return pipeline.parent / (files[0] if files else "params.yaml")


def pipeline_params(pipeline: Path) -> dict:
    """The params a pipeline's stages read (params_path)."""
    return yaml.safe_load(params_path(pipeline).read_text())


TASKLESS = ("--suite", "--transit")  # report flags: the command reads no single task's file


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
    elif any(flag in words for flag in TASKLESS):
        tasks = []
    else:
        tasks = [words[words.index("--task") + 1]] if "--task" in words else [params["task"]]
    return f"stages.{words[1]}", backend, tasks


MANIFESTS = "code_deps"  # per pipeline folder: one manifest per stage
CODE_STAGE = "code_deps"


def manifest(files: Iterable[Path]) -> str:
    """``<md5>  <path>`` per file (paths from the repository root), sorted by path."""
    return "".join(
        f"{hashlib.md5((REPO / f).read_bytes()).hexdigest()}  {f.as_posix()}\n"
        for f in sorted(files)
    )


def task_file(backend: str, task: str) -> Path:
    return Path("envs", backend, "tasks", f"{task}.py")


def manifests(pipeline: Path) -> dict[Path, str]:
    """Manifest path -> text, for every stage of ``pipeline`` but the code stage itself. A
    stage with a matrix over tasks has one manifest per task, ``<stage>/<task>.txt``, so that
    editing one task's file re-runs that task's stages only."""
    doc = yaml.safe_load(pipeline.read_text())
    params = pipeline_params(pipeline)
    folder = pipeline.parent / MANIFESTS
    out = {}
    for name, stage in doc["stages"].items():
        if name == CODE_STAGE:
            continue
        module, backend, tasks = stage_code(stage, params)
        if "${item.task}" in stage["cmd"]:
            for task in tasks:
                files = closure(module, backend, [task]) | {task_file(backend, task)}
                out[folder / name / f"{task}.txt"] = manifest(files)
        else:
            files = closure(module, backend, tasks) | {task_file(backend, t) for t in tasks}
            out[folder / f"{name}.txt"] = manifest(files)
    return out


def write_manifests(pipeline: Path, wanted: dict[Path, str]) -> list[Path]:
    """Write ``pipeline``'s manifests ``wanted`` (see manifests; only those whose text
    changed) and delete the folder's other files. Returns the written ones."""
    folder = pipeline.parent / MANIFESTS
    for old in sorted(folder.rglob("*"), reverse=True) if folder.exists() else []:
        if old.is_file() and old not in wanted:
            old.unlink()
        elif old.is_dir() and not any(w.is_relative_to(old) for w in wanted):
            old.rmdir()
    written = []
    for path, text in wanted.items():
        if not path.exists() or path.read_text() != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            written.append(path)
    return written


def manifest_dep(pipeline: Path, name: str, stage: dict) -> str:
    """The dep a stage lists for its manifest, relative to its wdir."""
    wdir = (pipeline.parent / stage.get("wdir", ".")).resolve()
    folder = Path(os.path.relpath((pipeline.parent / MANIFESTS).resolve(), wdir)).as_posix()
    if "${item.task}" in stage["cmd"]:
        return f"{folder}/{name}/${{item.task}}.txt"
    return f"{folder}/{name}.txt"


CODE_FOLDERS = ["mimicgen_pipe", "envs", "stages", "scripts/dvc_deps.py"]
# the code stage's command after its params check (mimicgen-pipe check)
MANIFESTS_CMD = "python scripts/dvc_deps.py --manifests"


def stage_problems(pipeline: Path, doc: dict | None = None) -> list[str]:
    """What is wrong with the code deps of ``pipeline``'s stages (``doc``: its parsed text,
    read from the file by default). The pipeline must have the code stage, depending on the
    project's code folders and on the params that pick back ends and tasks; every other stage
    must list its own manifest, and no project .py file or task file of its own."""
    doc = doc if doc is not None else yaml.safe_load(pipeline.read_text())
    rel = os.path.relpath(pipeline, REPO)
    code = doc["stages"].get(CODE_STAGE)
    if code is None:
        return [f"{rel}: no {CODE_STAGE} stage"]
    out = []
    wdir = (pipeline.parent / code.get("wdir", ".")).resolve()
    folders = [Path(os.path.relpath(REPO / f, wdir)).as_posix() for f in CODE_FOLDERS]
    if sorted(code.get("deps") or []) != sorted(folders):
        out.append(f"{rel}: {CODE_STAGE}: deps {code.get('deps')}, should be {folders}")
    params_file = Path(os.path.relpath(params_path(pipeline), wdir)).as_posix()
    if code.get("params") != [{params_file: None}]:
        out.append(f"{rel}: {CODE_STAGE}: params {code.get('params')}, should be the whole "
                   f"params file: [{params_file}:]")  # fmt: skip
    manifests_cmd = Path(os.path.relpath(pipeline, wdir)).as_posix()
    cmd = f"mimicgen-pipe check --params {params_file} && {MANIFESTS_CMD} {manifests_cmd}"
    if " ".join(str(code.get("cmd", "")).split()) != cmd:
        out.append(f"{rel}: {CODE_STAGE}: cmd {code.get('cmd')!r}, should be {cmd!r}")
    for name, stage in doc["stages"].items():
        if name == CODE_STAGE:
            continue
        deps = stage.get("deps") or []
        if manifest_dep(pipeline, name, stage) not in deps:
            out.append(f"{rel}: {name}: does not list {manifest_dep(pipeline, name, stage)}")
        files = [d for d in deps if isinstance(d, str) and TASK_OR_CODE.match(d)]
        if files:
            out.append(f"{rel}: {name}: lists code files its manifest holds: {files}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--manifests", metavar="DVC_YAML", help="write one pipeline's manifests")
    mode.add_argument("--check", action="store_true", help="exit 1 when something differs")
    mode.add_argument("--write", action="store_true", help="write every pipeline's manifests")
    args = p.parse_args(argv)
    if args.manifests:
        pipeline = (Path.cwd() / args.manifests).resolve()
        for path in write_manifests(pipeline, manifests(pipeline)):
            print(f"{path.relative_to(REPO)}: written")
        return 0
    problems = []
    for name in PIPELINES:
        path = REPO / name
        if not path.exists():
            continue
        wanted = manifests(path)
        if args.write:
            for written in write_manifests(path, wanted):
                print(f"{written.relative_to(REPO)}: written")
        problems += stage_problems(path)
        for manifest_path, text in wanted.items():
            if not manifest_path.exists() or manifest_path.read_text() != text:
                problems.append(f"{manifest_path.relative_to(REPO)}: stale")
    for line in problems:
        print(line, file=sys.stderr)
    if problems:
        print("run: python scripts/dvc_deps.py --write", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
