"""dvc.yaml's code deps cannot drift: every project module a stage's code imports
(transitively, including imports inside functions) is covered by a declared dep, so that
editing it re-runs the stage instead of serving stale data."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("mimicgen_pipe", "envs", "stages")
BACKENDS = ("maniskill", "pybullet")


def module_file(name: str) -> Path | None:
    """The repository file of a project module (package __init__ or module), else None."""
    if name.split(".")[0] not in PACKAGES:
        return None
    base = REPO / Path(*name.split("."))
    for path in (base / "__init__.py", base.with_suffix(".py")):
        if path.exists():
            return path
    return None


def imported_modules(path: Path) -> set[str]:
    """Project modules ``path`` imports anywhere in its body (``from a import b`` counts
    both a and a.b, since b may be a submodule)."""
    out: set[str] = set()
    package = ".".join(path.relative_to(REPO).with_suffix("").parts[:-1])
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
    return {m for m in out if module_file(m) is not None}


def closure(stage_module: str, backend: str, tasks: tuple[str, ...] = ()) -> set[Path]:
    """Files a stage's code runs from: its module, the packages it sits in, the files of
    the ``tasks`` it runs (looked up by name at run time), and everything they import,
    following only the chosen back end's package under envs/."""
    todo = [stage_module, "stages"] + [f"envs.{backend}.tasks.{t}" for t in tasks]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        parts = name.split(".")
        if name in seen or (
            len(parts) > 1 and parts[0] == "envs" and parts[1] in BACKENDS and parts[1] != backend
        ):
            continue
        seen.add(name)
        # a submodule import runs its packages' __init__ first
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += imported_modules(module_file(name))
    return {module_file(m).relative_to(REPO) for m in seen}


PIPELINES = ("dvc.yaml", "suite/dvc.yaml")  # the suite's stages run at the root (wdir ..)


def stages() -> list[tuple[str, dict]]:
    out = []
    for pipeline in PIPELINES:
        doc = yaml.safe_load((REPO / pipeline).read_text())
        out += list(doc["stages"].items())
    return out


def tasks_of(stage: dict) -> dict[str, str]:
    """The task names a stage's command runs, by the dvc.yaml variable that names them."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    if "${item.task}" in stage["cmd"]:
        section = "suite" if "${suite.backend}" in stage["cmd"] else "transfer"
        return {t: "${item.task}" for t in params[section]["tasks"]}
    return {params["task"]: "${task}"}


def backend_of(stage: dict) -> str:
    """The back end a stage runs on: transfer.backend where its command says so, else the
    main pipeline's."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    cmd = stage["cmd"]
    for section in ("transfer", "suite"):
        if "${" + section + ".backend}" in cmd:
            return params[section]["backend"]
    return params["backend"]


@pytest.mark.parametrize("name,stage", stages(), ids=[n for n, _ in stages()])
def test_stage_code_deps_cover_every_module_it_imports(name, stage):
    words = stage["cmd"].split()
    assert words[0] == "mimicgen-pipe", f"{name}: cmd does not run mimicgen-pipe"
    tasks = tasks_of(stage)
    backend = backend_of(stage)
    deps = [d.replace("${suite.backend}", backend) for d in stage["deps"]]
    deps = [d for d in deps if "$" not in d] + [
        d.replace(var, t) for d in deps for t, var in tasks.items() if var in d
    ]
    files = closure(f"stages.{words[1]}", backend_of(stage), tuple(tasks))
    uncovered = sorted(
        str(f) for f in files if not any(f == Path(d) or Path(d) in f.parents for d in deps)
    )
    assert not uncovered, f"dvc.yaml stage {name}: add to deps: {uncovered}"


def test_a_task_file_is_a_dep_of_its_own_stages_only():
    """Adding or editing one task's file re-runs that task's stages, not every task's."""
    for name, stage in stages():
        backend = backend_of(stage)
        assert f"envs/{backend}" not in stage["deps"], f"{name}: depends on every task file"
        files = closure(f"stages.{stage['cmd'].split()[1]}", backend)
        assert not any(f.parent.name == "tasks" and f.name != "__init__.py" for f in files), (
            f"{name}: a task file is imported statically"
        )


def test_the_closure_follows_lazy_imports():
    """The check sees an import inside a function (envs picks its back end lazily)."""
    files = closure("stages.generate", "maniskill")
    assert Path("envs/maniskill/env.py") in files
    assert not any(str(f).startswith("envs/pybullet") for f in files)
    assert Path("mimicgen_pipe/store.py") in files
