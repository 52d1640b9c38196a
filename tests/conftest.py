"""Shared fixtures. Simulator tests are marked ``sim``; they share one small end-to-end run
of the real pipeline (source -> parse -> pose_noise -> generate) made once per session."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mimicgen_pipe import arithmetic

arithmetic.pin()  # as the CLI does, before a test imports numpy or torch
os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
REPO = Path(__file__).resolve().parents[1]


def same_attempt(a, b) -> bool:
    """Whether two generation attempts are the same: seed, outcome, source demos, initial
    state, and every step array (names in order, dtypes, values) bit for bit."""
    import numpy as np

    return (
        a.seed == b.seed
        and a.success == b.success
        and a.failed_subtask == b.failed_subtask
        and np.array_equal(a.source_demo, b.source_demo)
        and np.array_equal(a.initial_state, b.initial_state)
        and list(a.steps) == list(b.steps)
        and all(
            a.steps[k].dtype == b.steps[k].dtype and np.array_equal(a.steps[k], b.steps[k])
            for k in a.steps
        )
    )


def cli(
    *args: str, cwd: Path, check: bool = True, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """Run ``mimicgen-pipe`` as a user would, in ``cwd`` (``env``: extra variables)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore") | (env or {})
    res = subprocess.run(
        [sys.executable, "-m", "mimicgen_pipe.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
    )
    if check and res.returncode != 0:
        raise AssertionError(f"mimicgen-pipe {' '.join(args)} failed:\n{res.stderr[-3000:]}")
    return res


SMALL_PARAMS = """
task: stack_cube
source: {num_demos: 3, seed: 0}
generate: {num_demos: 4, max_attempts: 12, workers: 1, seed: 7}
"""


@pytest.fixture(scope="session")
def pipeline(tmp_path_factory) -> Path:
    """A working directory with a small real run: 3 source demos, parsed, 4 generated demos
    on D1 (workers=1) and the same run again with workers=2 for the determinism check."""
    work = tmp_path_factory.mktemp("pipeline")
    (work / "params.yaml").write_text(SMALL_PARAMS)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    cli("pose_noise", cwd=work)
    cli("generate", "--variant", "D1", cwd=work)
    (work / "params2.yaml").write_text(SMALL_PARAMS.replace("workers: 1", "workers: 2"))
    cli(
        "generate",
        "--params",
        "params2.yaml",
        "--variant",
        "D1",
        "--out",
        "data/again/stack_cube_D1.zarr",
        "--metrics",
        "metrics/again.json",
        cwd=work,
    )
    return work


PYBULLET_STACK = "task: stack\nbackend: pybullet\nsource: {num_demos: 3, seed: 0}\n"


@pytest.fixture(scope="session")
def pybullet_stack(tmp_path_factory) -> Path:
    """A working directory where ``source`` and ``parse`` ran once with PYBULLET_STACK:
    three PyBullet source demos of stack, parsed. Several modules start from these; each
    takes its own copy (stages_copied_to) and leaves this one as it is."""
    work = tmp_path_factory.mktemp("pybullet_stack")
    (work / "params.yaml").write_text(PYBULLET_STACK)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    return work


def stages_copied_to(work: Path, built: Path) -> Path:
    """``work`` holding a copy of what the stages wrote in ``built`` (all but its params
    file), as if they had run there; returns ``work``."""
    for item in built.iterdir():
        if item.is_dir():
            shutil.copytree(item, work / item.name)
        elif item.name != "params.yaml":
            shutil.copy2(item, work / item.name)
    return work


def replay_first_episodes(store, env, count: int) -> list[bool]:
    """Task success of the first ``count`` episodes of a generated ``store`` (an
    EpisodeStore), each replayed on ``env`` from its stored initial state."""
    import numpy as np

    from mimicgen_pipe.generation import replay_actions

    starts = np.concatenate([[0], store.episode_ends[:-1]])
    out = []
    for k in range(min(count, len(starts))):
        actions = np.asarray(store.data["actions"][starts[k] : store.episode_ends[k]])
        state = np.asarray(store.episodes["initial_state"][k])
        out.append(replay_actions(env, state, actions, env.spec.objects, env.spec.arms)[1])
    return out
