"""Shared fixtures. Simulator tests are marked ``sim``; they share one small end-to-end run
of the real pipeline (source -> parse -> pose_noise -> generate) made once per test run,
also when pytest-xdist spreads the tests over several processes (:func:`made_once`)."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from mimicgen_pipe.run import arithmetic

arithmetic.pin()  # as the CLI does, before a test imports numpy or torch
os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
REPO = Path(__file__).resolve().parents[1]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist's ``--dist loadgroup`` (the README's test command), the tests of a
    module run in one process, which makes its module fixtures once; the tests of a module
    that sets ``SPREAD_TESTS = True`` (they share nothing and each takes minutes) are spread
    over the processes one by one. Runs before xdist reads the groups."""
    for item in items:
        module = getattr(item, "module", None)
        if module is None or getattr(module, "SPREAD_TESTS", False):
            continue
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(module.__name__))


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


def made_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder ``build`` filled once per test run. Under pytest-xdist the workers of one run
    share it: the first to ask builds it under a lock, the others wait for it and reuse it,
    so that the simulator work is not repeated per process. Callers must not change it."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        work = tmp_path_factory.mktemp(name)
        build(work)
        return work
    shared = tmp_path_factory.getbasetemp().parent  # the run's folder, above each worker's
    work, done = shared / name, shared / f"{name}.done"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir()
            build(work)
            done.touch()
    return work


def build_small_run(work: Path) -> None:
    """SMALL_PARAMS' run in ``work``: 3 source demos, parsed, 4 generated demos on D1
    (workers=1), and the same run again with workers=2 for the determinism check."""
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


@pytest.fixture(scope="session")
def pipeline(tmp_path_factory) -> Path:
    """A working directory with a small real run (:func:`build_small_run`), this process's
    own copy: tests may add outputs to it."""
    work = tmp_path_factory.mktemp("pipeline")
    shutil.copytree(made_once(tmp_path_factory, "small_run", build_small_run), work,
                    dirs_exist_ok=True)  # fmt: skip
    return work


PYBULLET_STACK = "task: stack\nbackend: pybullet\nsource: {num_demos: 3, seed: 0}\n"


def build_pybullet_stack(work: Path) -> None:
    """``source`` and ``parse`` with PYBULLET_STACK in ``work``."""
    (work / "params.yaml").write_text(PYBULLET_STACK)
    cli("source", cwd=work)
    cli("parse", cwd=work)


@pytest.fixture(scope="session")
def pybullet_stack(tmp_path_factory) -> Path:
    """A working directory where ``source`` and ``parse`` ran once with PYBULLET_STACK:
    three PyBullet source demos of stack, parsed. Several modules start from these; each
    takes its own copy (stages_copied_to) and leaves this one as it is."""
    return made_once(tmp_path_factory, "pybullet_stack", build_pybullet_stack)


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

    from mimicgen_pipe.method.generation import replay_actions

    starts = np.concatenate([[0], store.episode_ends[:-1]])
    out = []
    for k in range(min(count, len(starts))):
        actions = np.asarray(store.data["actions"][starts[k] : store.episode_ends[k]])
        state = np.asarray(store.episodes["initial_state"][k])
        out.append(replay_actions(env, state, actions, env.spec.objects, env.spec.arms)[1])
    return out
