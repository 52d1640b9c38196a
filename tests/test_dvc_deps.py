"""Every stage's code deps are exact: its manifest (``<pipeline>/code_deps/<stage>.txt``,
written by scripts/dvc_deps.py from the imports) lists the project files its command runs
from, so that editing a file re-runs the stages that import it, and only those."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("dvc_deps", REPO / "scripts/dvc_deps.py")
dvc_deps = importlib.util.module_from_spec(spec)
spec.loader.exec_module(dvc_deps)

PIPELINES = [REPO / p for p in dvc_deps.PIPELINES if (REPO / p).exists()]
DVC = Path(sys.executable).parent / "dvc"


def manifest_files() -> dict[Path, set[str]]:
    """Manifest -> the files it lists, over every pipeline."""
    return {
        path: {line.split()[1] for line in text.splitlines()}
        for pipeline in PIPELINES
        for path, text in dvc_deps.manifests(pipeline).items()
    }


def rerun_by_edit(edited: str) -> set[str]:
    """The manifests (paths from the repository root) of every stage an edit of the file
    ``edited`` re-runs: those that list it (the code stage re-runs on any edit, and is left
    out)."""
    return {
        path.relative_to(REPO).as_posix()
        for path, files in manifest_files().items()
        if edited in files
    }


def test_every_pipeline_lists_its_manifests_and_they_are_fresh():
    assert dvc_deps.main(["--check"]) == 0, "run: python scripts/dvc_deps.py --write"


def test_the_check_sees_a_missing_manifest_a_code_file_and_a_wrong_code_stage():
    pipeline = REPO / "quickstart/dvc.yaml"
    doc = yaml.safe_load(pipeline.read_text())
    assert dvc_deps.stage_problems(pipeline, doc) == []
    no_manifest = yaml.safe_load(pipeline.read_text())
    no_manifest["stages"]["export"]["deps"].pop(0)
    code_file = yaml.safe_load(pipeline.read_text())
    code_file["stages"]["parse"]["deps"].append("mimicgen_pipe/store.py")
    no_param = yaml.safe_load(pipeline.read_text())
    no_param["stages"]["code_deps"]["params"] = [{"quickstart/params.yaml": ["task"]}]
    no_folder = yaml.safe_load(pipeline.read_text())
    no_folder["stages"]["code_deps"]["deps"].remove("envs")
    for broken, says in [
        (no_manifest, "export: does not list quickstart/code_deps/export.txt"),
        (code_file, "parse: lists code files"),
        (no_param, "code_deps: params"),
        (no_folder, "code_deps: deps"),
    ]:
        problems = dvc_deps.stage_problems(pipeline, broken)
        assert len(problems) == 1 and says in problems[0], problems


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


def _bases(task_file: str) -> set[str]:
    """The task files a task file imports (a task made from another, e.g.
    peg_insertion_square from peg_insertion)."""
    text = (REPO / task_file).read_text()
    folder = Path(task_file).parent
    found = re.findall(rf"^from {re.escape('.'.join(folder.parts))}\.(\w+) import", text, re.M)
    return {str(folder / f"{name}.py") for name in found}


def test_a_task_file_is_in_its_own_stages_manifests_only():
    """Editing one task's file re-runs that task's stages and those of tasks made from it,
    not every task's."""
    for path, files in manifest_files().items():
        tasks = {f for f in files if "/tasks/" in f and not f.endswith("__init__.py")}
        own = [f for f in tasks if Path(f).stem == path.stem]
        if path.stem in ("report_suite", "report_transit"):  # read metrics and specs by name
            assert not tasks, path
        elif path.parent.name != "code_deps":  # <stage>/<task>.txt
            assert len(own) == 1 and tasks == {own[0], *_bases(own[0])}, (path, tasks)
        else:
            assert len(tasks - set().union(*map(_bases, tasks))) == 1, (path, tasks)
    # one task of the suite: its stages, those of the task made from it, and the
    # dataset-size stages, which run it
    edited = rerun_by_edit("envs/maniskill/tasks/peg_insertion.py")
    scaling = yaml.safe_load((REPO / "suite/params.yaml").read_text())["suite"]["scaling"]["task"]
    assert scaling == "peg_insertion"
    assert edited and all(
        s.startswith("suite/")
        and Path(s).name in ("peg_insertion.txt", "peg_insertion_square.txt")
        or "_scaling.txt" in s
        for s in edited
    ), sorted(edited)
    assert any(s.endswith("/peg_insertion_square.txt") for s in edited)


def test_an_exporter_edit_reruns_export_stages_only():
    """Only the export stages, and the suite's robomimic stages: its export, and the
    training and rollouts of robomimic's policies, which build their observations with the
    exporters' own functions (mimicgen_pipe.external)."""
    edited = rerun_by_edit("mimicgen_pipe/exporters/lerobot.py")
    tasks = yaml.safe_load((REPO / "suite/params.yaml").read_text())["suite"]["robomimic_tasks"]
    assert tasks
    outside = {
        f"suite/code_deps/{stage}_suite_robomimic/{task}.txt"
        for stage in ("export", "train", "evaluate")
        for task in tasks
    }
    assert edited == {
        "code_deps/export.txt",
        "code_deps/export_observed.txt",
        "quickstart/code_deps/export.txt",
        "quickstart/code_deps/export_observed.txt",
        *outside,
    }, sorted(edited)


def test_an_edit_of_the_robomimic_reader_reruns_source_stages_only():
    """The robomimic file reader is read by the source stages (source.from_file) and by
    train_robomimic, which checks the dataset it trains on with it; by nothing else."""
    reader = "mimicgen_pipe/robomimic_source.py"
    edited = rerun_by_edit(reader)
    commands = {s.split("code_deps/")[1].split("/")[0].removesuffix(".txt") for s in edited}
    readers = {c for c in commands if c.startswith("source")}
    assert readers and commands - readers == {"train_suite_robomimic"}, sorted(edited)
    sources = [s for p in PIPELINES for s in yaml.safe_load(p.read_text())["stages"]
               if s.startswith("source")]  # fmt: skip
    assert len(readers) == len(set(sources)), (readers, sources)


@pytest.mark.parametrize("package", ["exporters", "executors"])
def test_an_exporter_or_executor_is_a_dep_only_where_it_runs(package):
    """An exporter is in export stages' manifests only; an executor only in those of the
    stages that run their work through one."""
    users = {
        "exporters": {"export"},
        # train: seeds side by side; observe: blocks of episodes pictured
        "executors": {"generate", "evaluate", "export", "train", "observe"},
    }
    for pipeline in PIPELINES:
        doc = yaml.safe_load(pipeline.read_text())
        params = dvc_deps.pipeline_params(pipeline)
        for path, files in dvc_deps.manifests(pipeline).items():
            name = path.stem if path.parent.name == "code_deps" else path.parent.name
            command = dvc_deps.stage_code(doc["stages"][name], params)[0].split(".")[1]
            modules = [
                f
                for f in files
                if f.startswith(f"mimicgen_pipe/{package}/") and not f.endswith("__init__.py")
            ]
            if command not in users[package]:
                assert not modules, f"{path}: ({command}) depends on {modules}"


def test_dvc_reruns_only_the_stages_whose_manifest_changed(tmp_path):
    """The mechanism, on DVC itself: after an edit the code stage re-runs, and a stage whose
    manifest came out the same is skipped."""
    work = tmp_path / "repo"
    for name in ("mimicgen_pipe", "envs", "stages", "scripts"):
        shutil.copytree(REPO / name, work / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / ".dvcignore", work / ".dvcignore")
    (work / "params.yaml").write_text("task: stack_cube\nbackend: maniskill\n")
    log = "echo {0} >> ran.log && touch {0}.out"
    (work / "dvc.yaml").write_text(
        yaml.safe_dump(
            {
                "stages": {
                    "code_deps": {
                        "cmd": f"{sys.executable} scripts/dvc_deps.py --manifests dvc.yaml",
                        "deps": dvc_deps.CODE_FOLDERS,
                        "params": ["backend", "task"],
                        "outs": [{"code_deps": {"cache": False}}],
                    },
                    **{
                        name: {
                            "cmd": f"mimicgen-pipe {name} && " + log.format(name),
                            "deps": [f"code_deps/{name}.txt"],
                            "outs": [f"{name}.out"],
                        }
                        for name in ("export", "parse")
                    },
                }
            }
        )
    )
    # the stage commands stand in for mimicgen-pipe: only the manifests are real
    (work / "bin").mkdir()
    (work / "bin/mimicgen-pipe").write_text("#!/bin/sh\ntrue\n")
    (work / "bin/mimicgen-pipe").chmod(0o755)
    env = {"PATH": f"{work / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)}

    def run(*args: str) -> None:
        subprocess.run(args, cwd=work, env=env, check=True, capture_output=True)

    run("git", "init", "-q")
    run(str(DVC), "init", "-q")
    run(str(DVC), "repro", "-q")
    assert (work / "ran.log").read_text().split() == ["export", "parse"]
    with open(work / "mimicgen_pipe/exporters/lerobot.py", "a") as f:
        f.write("\n# an edit\n")
    run(str(DVC), "repro", "-q")
    assert (work / "ran.log").read_text().split() == ["export", "parse", "export"]
