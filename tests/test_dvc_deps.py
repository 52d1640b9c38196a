"""Every stage's code deps are exact and readable: its dvc.yaml lists the layers of
mimicgen_pipe (folders), its back end's folder and the single files its command runs from,
as scripts/dvc_deps.py finds them from the imports, so that editing a layer re-runs the
stages that import it, and only those."""

from __future__ import annotations

import importlib.util
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


@pytest.fixture(scope="module")
def stages():
    """Every stage of every pipeline as DVC reads it (templates resolved): address -> the
    paths of its deps, from the repository root."""
    from dvc.repo import Repo

    with Repo(str(REPO)) as repo:
        return {
            f"{s.dvcfile.relpath}:{s.name}": {
                Path(d.fs_path).relative_to(REPO).as_posix()
                for d in s.deps
                if not hasattr(d, "params")
            }
            for s in repo.index.stages
        }


def rerun_by_edit(stages: dict[str, set[str]], edited: str) -> set[str]:
    """The stages DVC re-runs after an edit of the file ``edited``: those with a dep that is
    the file or a folder holding it (what follows them downstream is left out)."""
    return {
        name
        for name, deps in stages.items()
        if any(edited == d or edited.startswith(d + "/") for d in deps)
    }


def _kind(name: str) -> str:
    """A stage's name without its dvc.yaml (``generate_suite@stack_tower-D0``)."""
    return name.split(":")[1]


def test_every_pipeline_lists_its_code_deps():
    assert dvc_deps.main(["--check"]) == 0, "run: python scripts/dvc_deps.py --write"


def test_the_check_sees_a_missing_layer_a_needless_file_and_a_wrong_check_stage():
    pipeline = REPO / "quickstart/dvc.yaml"
    doc = yaml.safe_load(pipeline.read_text())
    assert dvc_deps.stage_problems(pipeline, doc) == []
    no_layer = yaml.safe_load(pipeline.read_text())
    no_layer["stages"]["export"]["deps"].remove("mimicgen_pipe/formats")
    needless = yaml.safe_load(pipeline.read_text())
    needless["stages"]["parse"]["deps"].append("mimicgen_pipe/learn")
    no_stamp = yaml.safe_load(pipeline.read_text())
    no_stamp["stages"]["render"]["deps"].remove("quickstart/params.checked")
    no_param = yaml.safe_load(pipeline.read_text())
    no_param["stages"]["check"]["params"] = [{"quickstart/params.yaml": ["task"]}]
    for broken, says in [
        (no_layer, "export: code deps lack ['mimicgen_pipe/formats']"),
        (needless, "parse: code deps lack [] and list ['mimicgen_pipe/learn']"),
        (no_stamp, "render: code deps lack ['quickstart/params.checked']"),
        (no_param, "check: params"),
    ]:
        problems = dvc_deps.stage_problems(pipeline, broken)
        assert len(problems) == 1 and says in problems[0], problems


def test_the_closure_follows_lazy_imports_and_one_back_end():
    files = dvc_deps.closure("mimicgen_pipe.stages.generate", "maniskill")
    assert Path("mimicgen_pipe/backends/maniskill/env.py") in files
    assert not any(str(f).startswith("mimicgen_pipe/backends/pybullet") for f in files)
    assert Path("mimicgen_pipe/data/store.py") in files


def test_a_registry_load_depends_on_every_module_of_its_package(tmp_path):
    user = tmp_path / "user.py"
    user.write_text(
        "from mimicgen_pipe.core import registry\n"
        "def pick(name):\n"
        "    return registry.load('mimicgen_pipe.formats.exporters', name)\n"
    )
    found = dvc_deps.imported_modules(user)
    for module in dvc_deps.package_modules("mimicgen_pipe.formats.exporters"):
        assert module in found


def test_a_stage_depends_on_its_own_back_end_only(stages):
    """The suite's stages on ManiSkill and transfer's on PyBullet: each lists the folder of
    the back end it runs, never the other's."""
    for name, deps in stages.items():
        folders = {d for d in deps if d.startswith("mimicgen_pipe/backends/") and "." not in d}
        assert len(folders) <= 1, (name, folders)
    assert (
        "mimicgen_pipe/backends/maniskill" in stages["suite/dvc.yaml:generate_suite@stack_tower-D0"]
    )
    assert "mimicgen_pipe/backends/pybullet" in stages["transfer/dvc.yaml:parse_transfer@stack"]


def test_a_task_file_edit_reruns_that_tasks_stages_only(stages):
    """Editing one task's file re-runs the stages of that task only, and the suite's stages
    on its stores (the dataset-size policies and the other-object generation): what two
    tasks share lives in their back end (e.g. backends/maniskill/peg_in_hole.py), so that no
    task file imports another and DVC, which gives the cells of one stage the same deps,
    need not list one task's file for every task."""
    suite = yaml.safe_load((REPO / "suite/params.yaml").read_text())["suite"]
    assert suite["scaling"]["task"] == "peg_insertion" and suite["object_transfer"] == [
        "peg_insertion"
    ]
    edited = rerun_by_edit(stages, "mimicgen_pipe/tasks/maniskill/peg_insertion.py")
    for name in edited:
        kind, _, cell = _kind(name).partition("@")
        assert name.startswith("suite/") and (
            cell.startswith("peg_insertion")
            and not cell.startswith("peg_insertion_square")
            or "scaling" in kind
        ), name
    assert "suite/dvc.yaml:generate_suite_policy@peg_insertion-D0" in edited
    assert "suite/dvc.yaml:train_suite@peg_insertion" in edited

    def task_of(name: str) -> str:
        return name.partition("@")[2].partition("-")[0]

    pairs = (("peg_insertion", "peg_insertion_square"), ("stack_pyramid", "stack_tower"))
    for a, b in pairs + tuple((b, a) for a, b in pairs):
        of_b = {n for n in stages if task_of(n) == b}
        assert of_b and not rerun_by_edit(stages, f"mimicgen_pipe/tasks/maniskill/{a}.py") & of_b


def test_a_layer_edit_reruns_only_the_stages_that_import_it(stages):
    """Counted on DVC's own reading of the pipelines: an exporter edit re-runs the export
    stages and the suite's robomimic stages (robomimic's trainer reads our export with the
    exporters' functions), and nothing else; a report edit only the reports."""
    exporter = rerun_by_edit(stages, "mimicgen_pipe/formats/exporters/lerobot.py")
    kinds = {_kind(name).split("@")[0] for name in exporter}
    assert kinds == {
        "export",
        "export_observed",
        "export_suite_robomimic",
        "train_suite_robomimic",
        "evaluate_suite_robomimic",
    }, kinds
    report = rerun_by_edit(stages, "mimicgen_pipe/report/suite.py")
    assert report and {_kind(name).split("@")[0] for name in report} <= {
        "report",
        "report_suite",
        "report_transit",
        "report_transfer",
    }, report
    # the method's edit re-runs generation, and none of our trainings or reports
    method = {
        _kind(n).split("@")[0] for n in rerun_by_edit(stages, "mimicgen_pipe/method/segments.py")
    }
    assert "generate" in method
    assert not method & {"train", "train_source", "train_suite", "report", "report_suite"}, method


def test_a_source_layer_edit_reruns_source_stages_and_the_check(stages):
    """The robomimic file reader is read by the source stages (source.from_file), by the
    params check (which checks that file), and by train_robomimic, which checks the dataset
    it trains on with it; by nothing else."""
    edited = rerun_by_edit(stages, "mimicgen_pipe/sources/robomimic_source.py")
    kinds = {_kind(name).split("@")[0] for name in edited}
    readers = {k for k in kinds if k.startswith("source")}
    assert readers and kinds - readers == {"check", "train_suite_robomimic"}, sorted(kinds)


def test_dvc_reruns_only_the_stages_whose_layers_changed(tmp_path):
    """The mechanism, on DVC itself: after an edit of the formats layer the export stage
    re-runs and parse, which does not import it, is skipped."""
    work = tmp_path / "repo"
    shutil.copytree(
        REPO / "mimicgen_pipe", work / "mimicgen_pipe", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(REPO / ".dvcignore", work / ".dvcignore")
    (work / "params.yaml").write_text("task: stack_cube\nbackend: maniskill\n")
    (work / "params.checked").write_text("checked\n")
    pipeline = {"stages": {}}
    for name in ("export", "parse"):
        stage = {"cmd": f"mimicgen-pipe {name} && echo {name} >> ran.log && touch {name}.out"}
        code = dvc_deps.code_deps(stage, {"task": "stack_cube", "backend": "maniskill"})
        pipeline["stages"][name] = stage | {"deps": code, "outs": [f"{name}.out"]}
    assert "mimicgen_pipe/formats" in pipeline["stages"]["export"]["deps"]
    assert "mimicgen_pipe/formats" not in pipeline["stages"]["parse"]["deps"]
    (work / "dvc.yaml").write_text(yaml.safe_dump(pipeline))
    # the stage commands stand in for mimicgen-pipe: only the deps are real
    (work / "bin").mkdir()
    (work / "bin/mimicgen-pipe").write_text("#!/bin/sh\ntrue\n")
    (work / "bin/mimicgen-pipe").chmod(0o755)
    env = {"PATH": f"{work / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)}

    def run(*args: str) -> None:
        subprocess.run(args, cwd=work, env=env, check=True, capture_output=True)

    run("git", "init", "-q")
    run(str(DVC), "init", "-q")
    run(str(DVC), "repro", "-q")
    assert sorted((work / "ran.log").read_text().split()) == ["export", "parse"]
    with open(work / "mimicgen_pipe/formats/exporters/lerobot.py", "a") as f:
        f.write("\n# an edit\n")
    (work / "ran.log").unlink()
    run(str(DVC), "repro", "-q")
    assert (work / "ran.log").read_text().split() == ["export"]
