"""A stage run by hand touches nothing a pipeline tracks: a default output the committed
dvc.lock records goes under scratch/, an explicit one is refused (unless --replace-tracked),
and DVC's own runs write where the pipeline says. A missing input names what makes it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.data import layout, pipelines
from mimicgen_pipe.data.store import read_store, write_store
from tests.conftest import cli

REPO = Path(__file__).resolve().parents[1]

LOCK = """schema: '2.0'
stages:
  report:
    cmd: mimicgen-pipe report
    outs:
    - path: report
      hash: md5
      md5: 0.dir
  coverage@D0:
    cmd: mimicgen-pipe coverage --variant D0
    outs:
    - path: metrics/coverage_stack_cube_D0.json
      hash: md5
      md5: 0
"""


def tracked_repo(root: Path) -> Path:
    """A DVC repository whose lock tracks report/ and one metrics file of the root pipeline
    and, in sub/ (stages at the root, wdir ..), data/sub_store.zarr."""
    (root / ".dvc").mkdir()
    (root / "dvc.yaml").write_text("stages: {report: {cmd: x}, coverage: {cmd: x}}\n")
    (root / "dvc.lock").write_text(LOCK)
    (root / "sub").mkdir()
    (root / "sub/dvc.yaml").write_text("stages: {gen: {wdir: .., cmd: x}}\n")
    (root / "sub/dvc.lock").write_text(
        "schema: '2.0'\nstages:\n  gen@D0:\n    cmd: x\n    outs:\n"
        "    - path: data/sub_store.zarr\n      md5: 0.dir\n"
    )
    (root / "params.yaml").write_text("task: stack_cube\nsource: {num_demos: 1}\n")
    (root / "metrics").mkdir()
    (root / "reference").mkdir()
    shutil.copy(REPO / "reference/paper_results.yaml", root / "reference")
    return root


def test_owner_of_tracked_paths(tmp_path):
    root = tracked_repo(tmp_path)
    report = pipelines.owner(root / "report")
    assert report == pipelines.Owner("dvc.yaml", "report")
    assert report.repro == "dvc repro report"
    assert pipelines.owner(root / "report/report.html") == report  # inside a tracked folder
    assert pipelines.owner(root / "metrics") == pipelines.Owner("dvc.yaml", "coverage@D0")
    sub = pipelines.owner(root / "data/sub_store.zarr")  # relative to its stage's wdir
    assert sub == pipelines.Owner("sub/dvc.yaml", "gen@D0")
    assert sub.repro == "dvc repro sub/dvc.yaml:gen@D0"
    assert pipelines.owner(root / "sub/data/sub_store.zarr") is None
    assert pipelines.owner(root / "scratch/report") is None
    assert pipelines.owner(root) is None
    assert "made by stage gen@D0 of sub/dvc.yaml" in pipelines.made_by(root / "data/sub_store.zarr")
    (root / ".dvc").rmdir()  # outside any DVC repository nothing is tracked
    assert pipelines.owner(root / "report") is None


def test_hand_run_writes_a_tracked_default_under_scratch(tmp_path):
    root = tracked_repo(tmp_path)
    res = cli("report", cwd=root)
    assert "report is dvc.yaml's (stage report)" in res.stderr
    assert "scratch/report" in res.stderr and "`dvc repro report`" in res.stderr
    assert (root / "scratch/report/report.md").is_file()
    assert not (root / "report").exists()


@pytest.mark.parametrize("how", ["explicit", "replace", "dvc"])
def test_explicit_tracked_output_refused_unless_told(tmp_path, how):
    root = tracked_repo(tmp_path)
    extra = ["--replace-tracked"] if how == "replace" else []
    env = {pipelines.DVC_STAGE_ENV: "report"} if how == "dvc" else None
    res = cli("report", "--out", "report", *extra, cwd=root, check=False, env=env)
    if how == "explicit":
        assert res.returncode == 2
        (line,) = [ln for ln in res.stderr.splitlines() if "error:" in ln]
        assert "report: tracked by dvc.yaml (stage report)" in line
        assert "--replace-tracked" in line and "scratch/" in line
        assert not (root / "report").exists() and not (root / "scratch").exists()
    else:
        assert res.returncode == 0, res.stderr
        assert (root / "report/report.md").is_file()
        assert not (root / "scratch").exists()


def test_missing_input_names_the_stage_that_makes_it(tmp_path):
    root = tracked_repo(tmp_path)
    res = cli(
        "coverage", "--variant", "D0", "--generated", "data/sub_store.zarr",
        "--metrics", "m.json", "--table", "t.csv", "--heatmap", "h.png",
        cwd=root, check=False,
    )  # fmt: skip
    assert res.returncode == 2
    assert "data/sub_store.zarr: store not found; made by stage gen@D0 of sub/dvc.yaml" in (
        res.stderr
    )
    assert "`dvc repro sub/dvc.yaml:gen@D0`" in res.stderr
    res = cli("parse", "--source", "nowhere.zarr", "--out", "p.zarr", cwd=root, check=False)
    assert "nowhere.zarr: store not found; written by `mimicgen-pipe source`" in res.stderr


def test_committed_locks_track_the_default_outputs():
    """The real locks: the default pipeline's export and the suite's stores are tracked, so
    that the docs' hand-run commands go to scratch/."""
    o = pipelines.owner(REPO / "metrics/export_stack_cube_D0.json")
    assert o == pipelines.Owner("dvc.yaml", "export@D0")
    stages = json.dumps(str(pipelines.owner(REPO / "data/generated/stack_cube_D1.zarr")))
    assert "generate@D1" in stages


def quickstart_repo(root: Path) -> Path:
    """A DVC repository with the committed default and quickstart pipelines (dvc.yaml,
    dvc.lock, params.yaml), the quickstart's source demos in quickstart/data/source/ (one
    short stack_cube demo) and nothing in the default pipeline's data/."""
    (root / ".dvc").mkdir()
    for name in ("dvc.yaml", "dvc.lock", "params.yaml"):
        shutil.copy(REPO / name, root / name)
        (root / "quickstart").mkdir(exist_ok=True)
        shutil.copy(REPO / "quickstart" / name, root / "quickstart" / name)
    t = 80
    eye = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    step = {"actions": np.zeros((t, 7), np.float32), "gripper": np.zeros(t, np.float32),
            "subtask_signals/grasp_cubeA": np.arange(t) > 10}  # fmt: skip
    for key in ("eef_pose", "target_pose", "object_poses/cubeA", "object_poses/cubeB"):
        step[key] = eye
    steps = [step]
    source = root / "quickstart/data/source/stack_cube.zarr"
    write_store(source, "source", steps, {}, {"task": "stack_cube"})
    return root


def test_a_hand_run_follows_its_params_files_pipeline(tmp_path):
    """`parse --params quickstart/params.yaml` and no paths reads the quickstart's source
    demos and writes the quickstart's parsed store, under scratch/ as the quickstart's lock
    tracks it; the default pipeline's data/ is never looked at."""
    root = quickstart_repo(tmp_path)
    res = cli("parse", "--params", "quickstart/params.yaml", cwd=root)
    out = "quickstart/data/parsed/stack_cube.zarr"
    assert f"{out} is quickstart/dvc.yaml's (stage parse)" in res.stderr
    assert "`dvc repro quickstart/dvc.yaml:parse`" in res.stderr
    assert read_store(root / "scratch" / out).n_episodes == 1
    assert not (root / out).exists() and not (root / "data").exists()


@pytest.mark.parametrize(
    ("stage", "missing"),
    [
        ("coverage", "quickstart/data/generated/stack_cube_D0.zarr"),
        ("export", "quickstart/data/generated/stack_cube_D0.zarr"),
        ("generate", "quickstart/data/pose_noise/stack_cube.zarr"),
    ],
)
def test_a_missing_input_names_the_params_files_pipeline(tmp_path, stage, missing):
    """A hand run with the quickstart's params looks for the quickstart's input and names
    the quickstart's stage that makes it."""
    root = quickstart_repo(tmp_path)
    res = cli(stage, "--params", "quickstart/params.yaml", "--variant", "D0", cwd=root,
              check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    (line,) = [ln for ln in res.stderr.splitlines() if "error:" in ln]
    assert f"{missing}: store not found" in line
    assert "of quickstart/dvc.yaml: run `dvc repro quickstart/dvc.yaml:" in line


def test_a_path_two_pipelines_track_is_named_as_the_running_ones(tmp_path, monkeypatch):
    """data/sub_store.zarr in both locks: its owner is the pipeline of the params file's
    folder, and the default pipeline's layout is unchanged."""
    monkeypatch.setattr(pipelines, "_current", None)
    root = tracked_repo(tmp_path)
    lock = LOCK + "  gen@D0:\n    cmd: x\n    outs:\n    - path: data/sub_store.zarr\n"
    (root / "dvc.lock").write_text(lock)
    store = root / "data/sub_store.zarr"
    pipelines.use_pipeline(root / "params.yaml")
    assert pipelines.owner(store) == pipelines.Owner("dvc.yaml", "gen@D0")
    assert pipelines.layout_roots() == {}
    pipelines.use_pipeline(root / "sub/params.yaml")
    assert pipelines.owner(store) == pipelines.Owner("sub/dvc.yaml", "gen@D0")
    assert pipelines.layout_roots() == {}  # sub/ keeps nothing of its own


def test_layout_roots_of_the_committed_pipelines(monkeypatch):
    """Each committed pipeline's default paths, as its dvc.yaml names them."""
    monkeypatch.setattr(pipelines, "_current", None)
    monkeypatch.chdir(REPO)
    pipelines.use_pipeline("quickstart/params.yaml")
    assert layout.generated_store("stack_cube", "D0") == Path(
        "quickstart/data/generated/stack_cube_D0.zarr"
    )
    assert layout.report_dir() == Path("quickstart/report")
    pipelines.use_pipeline("suite/params.yaml")  # stores under data/, metrics under suite/
    assert layout.parsed_store("stack") == Path("data/parsed/stack.zarr")
    assert layout.metrics_file("generate", "stack", "D0") == Path(
        "suite/metrics/generate_stack_D0.json"
    )
    pipelines.use_pipeline("params.yaml")
    assert layout.metrics_file("export", "stack_cube", "D0") == Path(
        "metrics/export_stack_cube_D0.json"
    )
