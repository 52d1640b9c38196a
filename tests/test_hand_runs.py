"""A stage run by hand touches nothing a pipeline tracks: a default output the committed
dvc.lock records goes under scratch/, an explicit one is refused (unless --replace-tracked),
and DVC's own runs write where the pipeline says. A missing input names what makes it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from mimicgen_pipe import pipelines
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
