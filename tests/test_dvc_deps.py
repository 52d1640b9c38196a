"""dvc.yaml's code deps are exact: every stage lists the project files its command runs
from (written by scripts/dvc_deps.py), so that editing a file re-runs the stages that import
it, and only those."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("dvc_deps", REPO / "scripts/dvc_deps.py")
dvc_deps = importlib.util.module_from_spec(spec)
spec.loader.exec_module(dvc_deps)

PIPELINES = [p for p in dvc_deps.PIPELINES if (REPO / p).exists()]


def all_stages() -> list[tuple[str, str, dict]]:
    return [
        (pipeline, name, stage)
        for pipeline in PIPELINES
        for name, stage in yaml.safe_load((REPO / pipeline).read_text())["stages"].items()
    ]


def test_every_pipeline_lists_exactly_the_code_its_stages_import():
    assert dvc_deps.main(["--check"]) == 0, "run: python scripts/dvc_deps.py --write"


def test_the_check_sees_a_dropped_and_an_extra_dep():
    text = (REPO / "dvc.yaml").read_text()
    wanted = dvc_deps.wanted_deps(REPO / "dvc.yaml")
    dropped = text.replace("      - mimicgen_pipe/store.py\n", "", 1)
    extra = text.replace(
        "      - stages/__init__.py\n", "      - stages/__init__.py\n      - stages/report.py\n", 1
    )
    for broken in (dropped, extra):
        assert broken != text
        assert dvc_deps.rewrite(broken, wanted) == text


def test_the_closure_follows_lazy_imports_and_one_back_end():
    files = dvc_deps.closure("stages.generate", "maniskill")
    assert Path("envs/maniskill/env.py") in files
    assert not any(str(f).startswith("envs/pybullet") for f in files)
    assert Path("mimicgen_pipe/store.py") in files


def test_a_registry_load_depends_on_every_module_of_its_package(tmp_path):
    user = tmp_path / "user.py"
    user.write_text(
        "from mimicgen_pipe import registry\n"
        "def pick(name):\n"
        "    return registry.load('mimicgen_pipe.exporters', name)\n"
    )
    found = dvc_deps.imported_modules(user)
    for module in dvc_deps.package_modules("mimicgen_pipe.exporters"):
        assert module in found


def test_a_task_file_is_a_dep_of_its_own_stages_only():
    """Editing one task's file re-runs that task's stages, not every task's."""
    for pipeline, name, stage in all_stages():
        module, backend, tasks = dvc_deps.stage_code(
            stage, dvc_deps.pipeline_params(REPO / pipeline)
        )
        if "--suite" in stage["cmd"]:  # the suite's report reads every suite task's spec
            assert "envs/${suite.backend}/tasks" in stage["deps"], name
            continue
        if "report --transit" in stage["cmd"]:  # the transit report reads metrics files only
            assert not any("tasks/${" in d for d in stage["deps"]), name
            continue
        assert f"envs/{backend}" not in stage["deps"], f"{name}: depends on every task file"
        files = dvc_deps.closure(module, backend, tasks)
        assert not any(f.parent.name == "tasks" and f.name != "__init__.py" for f in files), (
            f"{pipeline}: {name}: a task file is imported statically"
        )
        assert any("tasks/${" in d for d in stage["deps"]), f"{name}: its task file is no dep"


@pytest.mark.parametrize("package", ["exporters", "executors"])
def test_an_exporter_or_executor_is_a_dep_only_where_it_runs(package):
    """Editing an exporter re-runs only export stages (and source, which reads robomimic
    files); an executor only the stages that run their work through one."""
    users = {
        "exporters": {"export", "source"},
        # train: seeds side by side; observe: blocks of episodes pictured
        "executors": {"generate", "evaluate", "export", "train", "observe"},
    }
    for pipeline, name, stage in all_stages():
        command = stage["cmd"].split()[1]
        modules = [
            d
            for d in stage["deps"]
            if d.startswith(f"mimicgen_pipe/{package}/") and not d.endswith("__init__.py")
        ]
        if command not in users[package]:
            assert not modules, f"{pipeline}: {name} ({command}) depends on {modules}"
