"""The code deps of every DVC stage: the layers of mimicgen_pipe (folders) and the files
its command runs from, so that editing a layer re-runs the stages that import it and no
other, and a reader of dvc.yaml sees what each stage runs from.

    python scripts/dvc_deps.py --check   # exit 1 naming each stage whose deps differ
    python scripts/dvc_deps.py --write   # rewrite the code deps in every dvc.yaml

A stage ``mimicgen-pipe <stage> ...`` runs from ``mimicgen_pipe/stages/<stage>.py``, the CLI's
arithmetic pins (``mimicgen_pipe/run/arithmetic.py``: they decide the outputs' last bits),
every project module it imports (transitively, imports inside functions included), and every
module of a registry package it loads from by a name known at run time
(``registry.load("<package>", name)``; a literal name: that module only; see
mimicgen_pipe/core/registry.py). Under ``mimicgen_pipe/backends/`` only the stage's back end is
followed (the ``--backend`` its command passes, else the pipeline's ``backend`` param), and
under ``mimicgen_pipe/tasks/`` only the task files the stage runs (its ``--task``, else the
``task`` param; each task of its matrix) and what they import. Its code deps are then: each
layer folder holding one of those modules (``mimicgen_pipe/core``, ...), its back end's
folder, its task's file by template (``mimicgen_pipe/tasks/${backend}/${task}.py``), and the
other files one by one (the stage modules, the packages' ``__init__.py``, the file of a task
that its task is made from), so that editing one task's file re-runs that task's stages.

Each pipeline's first stage, ``check``, validates the whole params file (``mimicgen-pipe
check``) and writes ``<params file>.checked``, a constant line, on which every other stage
depends: DVC runs it first, so that a bad value stops ``dvc repro`` before any stage's
outputs are removed, and its unchanged line re-runs nothing.
"""

from __future__ import annotations

import argparse
import ast
import functools
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe",)
PIPELINES = (
    "dvc.yaml",
    "suite/dvc.yaml",
    "suite/robomimic/dvc.yaml",
    "suite/scaling/dvc.yaml",
    "suite/ablations/dvc.yaml",
    "quickstart/dvc.yaml",
    "transit/dvc.yaml",
    "transfer/dvc.yaml",
    "images/dvc.yaml",
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
            elif not loaded.startswith("mimicgen_pipe.tasks."):  # tasks: the stage's own dep
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
    package under mimicgen_pipe/backends/. The task files themselves are not included."""
    backends = {p.parent.name for p in (REPO / "mimicgen_pipe/backends").glob("*/__init__.py")}
    roots = [f"mimicgen_pipe.tasks.{backend}.{t}" for t in tasks]
    # the CLI pins the numeric libraries' code paths before any stage runs (cli.py)
    todo = [stage_module, "mimicgen_pipe.stages", "mimicgen_pipe.run.arithmetic", *roots]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        parts = name.split(".")
        other_backend = parts[:2] == ["mimicgen_pipe", "backends"] and (
            len(parts) > 2 and parts[2] in backends - {backend}
        )
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


def _resolve_value(text: str, params: dict) -> Any:
    """The params value that ``text``, one ``${a.b}``, names."""
    node: Any = params
    for key in text.strip("${}").split("."):
        node = node[key]
    return node


def _resolve_list(text: str, params: dict) -> list[str]:
    return [str(v) for v in _resolve_value(text, params)]


def params_path(pipeline: Path) -> Path:
    """A pipeline's params file: its first ``vars`` file, else params.yaml beside it."""
    doc = yaml.safe_load(pipeline.read_text())
    files = [v for v in doc.get("vars", []) if isinstance(v, str)]
    return pipeline.parent / (files[0] if files else "params.yaml")


def pipeline_params(pipeline: Path) -> dict:
    """The params a pipeline's stages read (params_path)."""
    return yaml.safe_load(params_path(pipeline).read_text())


TASKLESS = ("--suite", "--transit")  # report flags: the command reads no single task's file


def _words(stage: dict) -> list[str]:
    """The words of a dvc.yaml stage's command, as written (templates not resolved)."""
    return str(body(stage)["cmd"]).split()


def body(stage: dict) -> dict:
    """A dvc.yaml stage's body: its ``do`` for a ``foreach`` stage, else the stage."""
    return stage["do"] if "foreach" in stage else stage


def stage_code(stage: dict, params: dict) -> tuple[str, str, list[str]]:
    """(stage module, back end, task names) that a dvc.yaml stage's command runs."""
    cmd = _resolve(" ".join(_words(stage)), params)
    words = cmd.split()
    if words[:1] != ["mimicgen-pipe"] or len(words) < 2:
        raise SystemExit(f"a stage command must run mimicgen-pipe: {body(stage)['cmd']!r}")
    backend = words[words.index("--backend") + 1] if "--backend" in words else params["backend"]
    if "foreach" in stage:  # over named cells of params, each with its task, or written out
        cells = stage["foreach"]
        cells = _resolve_value(cells, params) if isinstance(cells, str) else cells
        items = cells.values() if isinstance(cells, dict) else cells
        named = [c["task"] for c in items if isinstance(c, dict) and "task" in c]
        tasks = sorted({str(t) for t in named}) if named else [params["task"]]
    elif "${item.task}" in cmd:
        axis = (stage.get("matrix") or {})["task"]
        tasks = _resolve_list(axis, params) if isinstance(axis, str) else [str(t) for t in axis]
    elif any(flag in words for flag in TASKLESS):
        tasks = []
    else:
        tasks = [words[words.index("--task") + 1]] if "--task" in words else [params["task"]]
    return f"mimicgen_pipe.stages.{words[1]}", backend, tasks


LAYERS = ("core", "method", "data", "run", "sources", "learn", "media", "formats", "report")
# (the back ends and the tasks are folders per back end and files per task: see dep_of)
CHECK_STAGE = "check"


def task_file(backend: str, task: str) -> Path:
    return Path("mimicgen_pipe", "tasks", backend, f"{task}.py")


def backend_token(stage: dict) -> str:
    """The back end as the stage's command names it (``${suite.backend}``, ``pybullet``), else
    the pipeline's ``backend`` param."""
    words = _words(stage)
    return words[words.index("--backend") + 1] if "--backend" in words else "${backend}"


def task_token(stage: dict) -> str:
    """The task as the stage's command names it (``${item.task}``, ``${task}``, a name)."""
    words = _words(stage)
    if any("${item.task}" in w for w in words):
        return "${item.task}"
    return words[words.index("--task") + 1] if "--task" in words else "${task}"


def dep_of(path: Path, backend: str) -> str:
    """The code dep that covers the project file ``path``: its layer's folder, its back end's
    folder, or the file itself (a task's file under the back end as dvc.yaml names it)."""
    parts = path.parts
    if len(parts) > 2 and parts[1] in LAYERS:
        return f"mimicgen_pipe/{parts[1]}"
    if len(parts) > 3 and parts[1] == "backends":
        return f"mimicgen_pipe/backends/{backend}"
    if len(parts) > 3 and parts[1] == "tasks":
        return f"mimicgen_pipe/tasks/{backend}/{parts[3]}"
    return path.as_posix()


@functools.cache
def docstring_only(path: Path) -> bool:
    """Whether a project file runs no code (a package's ``__init__.py`` holding only its
    docstring): no dep, since no edit of it can change what a stage does."""
    body = ast.parse((REPO / path).read_text()).body
    return (
        len(body) == 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
    )


def code_deps(stage: dict, params: dict) -> list[str]:
    """The code deps a dvc.yaml stage must list (paths from the repository root): layers in
    their order, then the back end's folder and single files: its own task's file by
    template, and the file of each task that one of its tasks is made from."""
    module, backend, tasks = stage_code(stage, params)
    # one closure per task (its own file left out): what a task imports of another is there
    files = set().union(*(closure(module, backend, one) for one in [[t] for t in tasks] or [[]]))
    token = backend_token(stage)
    deps = {dep_of(f, token) for f in files if not docstring_only(f)}
    if tasks:
        deps.add(f"mimicgen_pipe/tasks/{token}/{task_token(stage)}.py")
    order = {f"mimicgen_pipe/{layer}": i for i, layer in enumerate(LAYERS)}
    return sorted(deps, key=lambda d: (order.get(d, 99), d))


def is_code(dep: object) -> bool:
    """Whether a dep is project code (a layer, a back end or a file of mimicgen_pipe)."""
    return isinstance(dep, str) and dep.lstrip("./").startswith("mimicgen_pipe")


def _rel(path: str, pipeline: Path, stage: dict) -> str:
    """``path`` (from the repository root) as the stage, run in its wdir, names it."""
    wdir = (pipeline.parent / stage.get("wdir", ".")).resolve()
    return Path(os.path.relpath(REPO / path, wdir)).as_posix()


def stamp(pipeline: Path) -> str:
    """The file the check stage writes, from the repository root: ``<params file>.checked``
    with the params file's suffix dropped."""
    return params_path(pipeline).resolve().relative_to(REPO).with_suffix(".checked").as_posix()


def wanted_deps(pipeline: Path, name: str, stage: dict, params: dict) -> list[str]:
    """The code deps and, but for the check stage, the check's stamp, as ``stage`` names them."""
    own = [] if name == CHECK_STAGE else [stamp(pipeline)]
    return [_rel(d, pipeline, body(stage)) for d in own + code_deps(stage, params)]


def listed_here(dep: object, pipeline: Path, stage: dict) -> bool:
    """Whether a dep of ``stage`` is one these lists hold: project code or the check's stamp."""
    return is_code(dep) or dep == _rel(stamp(pipeline), pipeline, stage)


def params_dep(pipeline: Path, stage: dict) -> str:
    """The pipeline's params file as ``stage`` names it."""
    return _rel(params_path(pipeline).resolve().relative_to(REPO).as_posix(), pipeline, stage)


def check_cmd(pipeline: Path, stage: dict) -> str:
    out = _rel(stamp(pipeline), pipeline, stage)
    return f"mimicgen-pipe check --params {params_dep(pipeline, stage)} --stamp {out}"


def check_stage_problems(pipeline: Path, check: dict) -> list[str]:
    """What is wrong with a pipeline's check stage: it must run ``mimicgen-pipe check`` on
    the whole params file and write the stamp."""
    rel = os.path.relpath(pipeline, REPO)
    out = []
    if " ".join(str(check.get("cmd", "")).split()) != check_cmd(pipeline, check):
        out.append(f"{rel}: {CHECK_STAGE}: cmd {check.get('cmd')!r}, should be "
                   f"{check_cmd(pipeline, check)!r}")  # fmt: skip
    params_file = params_dep(pipeline, check)
    if check.get("params") != [{params_file: None}]:
        out.append(f"{rel}: {CHECK_STAGE}: params {check.get('params')}, should be the whole "
                   f"params file: [{params_file}:]")  # fmt: skip
    return out


def stage_problems(pipeline: Path, doc: dict | None = None) -> list[str]:
    """What is wrong with the code deps of ``pipeline``'s stages (``doc``: its parsed text,
    read from the file by default): the check stage must run ``mimicgen-pipe check`` on the
    whole params file and write the stamp; every stage must list exactly its code deps, and
    every other stage the stamp."""
    doc = doc if doc is not None else yaml.safe_load(pipeline.read_text())
    params = pipeline_params(pipeline)
    rel = os.path.relpath(pipeline, REPO)
    check = doc["stages"].get(CHECK_STAGE)
    out = []
    if check is not None:
        out += check_stage_problems(pipeline, check)
    elif params_path(pipeline).resolve().parent == pipeline.parent.resolve():
        return [f"{rel}: no {CHECK_STAGE} stage"]
    # else a study's pipeline on another's params file, checked by that pipeline's check stage
    for name, stage in doc["stages"].items():
        deps = body(stage).get("deps") or []
        wanted = wanted_deps(pipeline, name, stage, params)
        have = [d for d in deps if listed_here(d, pipeline, body(stage))]
        if sorted(have) != sorted(wanted):
            missing = sorted(set(wanted) - set(have))
            extra = sorted(set(have) - set(wanted))
            out.append(f"{rel}: {name}: code deps lack {missing} and list {extra} too")
    return out


def _flow(items: list[str], indent: str) -> list[str]:
    """``deps: [...]`` lines, wrapped at 100 characters."""
    words = [f'"{i}"' if re.search(r"[${}:,]", i) else i for i in items]
    lines, line = [], f"{indent}deps: ["
    for k, w in enumerate(words):
        piece = w + ("]" if k == len(words) - 1 else ",")
        if len(line) + len(piece) + 1 > 100 and not line.endswith("["):
            lines.append(line)
            line = f"{indent}  {piece}"
        else:
            line += ("" if line.endswith("[") else " ") + piece
    lines.append(line)
    return lines


def write_deps(pipeline: Path) -> bool:
    """Rewrite every stage's deps in ``pipeline`` (its text, comments kept): the stamp, the
    code deps, then its other deps as they were. True where the file changed."""
    text = pipeline.read_text()
    doc = yaml.safe_load(text)
    params = pipeline_params(pipeline)
    lines = text.split("\n")
    starts = [i for i, line in enumerate(lines) if re.match(r"^  [\w-]+:", line)]
    for k, start in reversed(list(enumerate(starts))):
        name = lines[start].strip().split(":")[0]
        if name not in doc["stages"]:
            continue
        stage = doc["stages"][name]
        end = starts[k + 1] if k + 1 < len(starts) else len(lines)
        at = next((i for i in range(start, end) if re.match(r"^ +deps:", lines[i])), None)
        wanted = wanted_deps(pipeline, name, stage, params)
        inner = body(stage)
        rest = [d for d in inner.get("deps") or [] if not listed_here(d, pipeline, inner)]
        indent = lines[at][: len(lines[at]) - len(lines[at].lstrip())] if at is not None else ""
        new = _flow(wanted + rest, indent)
        if at is None:
            raise SystemExit(f"{pipeline}: {name}: no deps: line to rewrite")
        stop = at + 1
        depth = lines[at].count("[") - lines[at].count("]")
        while depth > 0:
            depth += lines[stop].count("[") - lines[stop].count("]")
            stop += 1
        lines[at:stop] = new
    out = "\n".join(lines)
    if out != text:
        pipeline.write_text(out)
    return out != text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="exit 1 when something differs")
    mode.add_argument("--write", action="store_true", help="rewrite the code deps in dvc.yaml")
    args = p.parse_args(argv)
    problems = []
    for name in PIPELINES:
        path = REPO / name
        if args.write and write_deps(path):
            print(f"{name}: code deps written")
        problems += stage_problems(path)
    for line in problems:
        print(line, file=sys.stderr)
    if problems:
        print("run: python scripts/dvc_deps.py --write", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
