"""Every committed report is what its pipeline's report stage makes of the committed metrics:
each report stage's own command, run again with its --out beside the committed report (the
same depth, so that its links to plots and videos are the same), gives report.md,
report.html and summary.json byte for byte. A change to the report code (or to a metrics
file) that moves a report fails here until the report stage is run again."""

from __future__ import annotations

import os
import shlex
import shutil

import pytest

from tests.conftest import REPO, cli

FILES = ("report.md", "report.html", "summary.json")


PIPELINES = sorted(p.relative_to(REPO).as_posix()
                   for p in (REPO / "dvc.yaml", *REPO.glob("*/dvc.yaml")))  # fmt: skip


@pytest.fixture(scope="module")
def commands() -> dict[str, list[str]]:
    """Each pipeline's report stage: its dvc.yaml's name -> the stage's command's arguments
    (after ``mimicgen-pipe``), as DVC resolves them; read once, when a test asks."""
    from dvc.repo import Repo

    with Repo(str(REPO)) as repo:
        return {
            s.dvcfile.relpath: shlex.split(s.cmd)[1:]
            for s in repo.index.stages
            if isinstance(s.cmd, str) and s.cmd.startswith("mimicgen-pipe report")
        }


def test_every_pipeline_has_one_report_stage(commands):
    assert sorted(commands) == PIPELINES


@pytest.mark.parametrize("pipeline", PIPELINES)
def test_a_committed_report_is_its_stage_run_on_the_committed_metrics(pipeline, commands):
    args = list(commands[pipeline])
    i = args.index("--out")
    committed = REPO / args[i + 1]
    if not (committed / "report.md").is_file():
        pytest.skip(f"{pipeline}: no committed report yet")
    again = committed.with_name(f".report-test-{os.getpid()}")  # ignored by git
    args[i + 1] = str(again.relative_to(REPO))
    try:
        cli(*args, cwd=REPO)
        for name in FILES:
            kept = committed / name
            assert (again / name).read_bytes() == kept.read_bytes(), f"{kept} moved"
    finally:
        shutil.rmtree(again, ignore_errors=True)
