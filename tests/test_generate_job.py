"""A generate request is resolved once (mimicgen_pipe.stages.generate.resolve) into one frozen
job (mimicgen_pipe.run.runner.GenerateJob), every check done before any work and before any
output is claimed: the job of a small PyBullet run field by field, and refusals, the last
check's included, that leave the working directory as it was and never reach the stage's
claim."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.run.executors import Executor
from mimicgen_pipe.run.runner import attempt_seed
from mimicgen_pipe.stages import generate
from mimicgen_pipe.stages.generate import resolve
from tests.conftest import PYBULLET_STACK, stages_copied_to
from tests.test_imports import imported, project_modules

PARAMS = PYBULLET_STACK + "generate: {workers: 1, seed: 3}\n"


@pytest.fixture(scope="module")
def work(tmp_path_factory, pybullet_stack) -> Path:
    """Three PyBullet source demos of stack, parsed, and a params file that asks for pose
    noise the parsed store does not carry."""
    work = stages_copied_to(tmp_path_factory.mktemp("generate_job"), pybullet_stack)
    (work / "params.yaml").write_text(PARAMS)
    (work / "noisy.yaml").write_text(PARAMS + "pose_noise: {level: L1}\n")
    return work


def generate_args(work: Path, *argv: str, params: str = "params.yaml") -> argparse.Namespace:
    """The generate stage's command line, parsed, with its outputs in data/new/."""
    parser = argparse.ArgumentParser()
    generate.add_arguments(parser)
    return parser.parse_args(
        ["--params", str(work / params), "--variant", "D0",
         "--parsed", str(work / "data/parsed/stack.zarr"),
         "--out", str(work / "data/new/s.zarr"), "--metrics", str(work / "data/new/m.json"),
         *argv]
    )  # fmt: skip


def tree(work: Path) -> list[str]:
    return sorted(p.relative_to(work).as_posix() for p in work.rglob("*"))


def test_a_request_resolves_into_one_checked_frozen_job(work):
    before = tree(work)
    job = resolve(generate_args(work, "--attempts", "5", "--action-noise", "0.02"))
    assert tree(work) == before  # nothing written, nothing claimed
    assert (job.spec.name, job.backend_name, job.robot, job.variant) == (
        "stack",
        "pybullet",
        "panda",
        "D0",
    )
    assert job.backend is backends.backend_package("pybullet")
    assert (job.generate.mode, job.generate.max_attempts, job.num_demos) == (
        "fixed_attempts",
        5,
        None,
    )
    assert (job.config.action_noise, job.note, job.make_batch) == (0.02, None, None)
    assert job.parsed_path == work / "data/parsed/stack.zarr"
    assert (job.out, job.failed_out, job.metrics_path) == (
        work / "data/new/s.zarr",
        work / "data/new/s_failed.zarr",
        work / "data/new/m.json",
    )
    assert job.executor == Executor("local", 1, None)
    assert list(job.seeds) == [attempt_seed(3, "D0", k) for k in range(5)]
    assert job.attempts.block_size == 16 and job.attempts.variant == "D0"
    assert job.attrs["run_id"] == job.run_id and len(job.run_id) == 16
    assert job.attrs["params"]["generate"]["action_noise"] == 0.02
    assert job.identity["purpose"] == "dgr" and job.label == "generate stack D0"
    with pytest.raises(dataclasses.FrozenInstanceError):
        job.variant = "D1"  # type: ignore[misc]


def far_env(backend, task, robot, *_):
    """A PyBullet env whose arm stands 3 m from the table."""
    from mimicgen_pipe.backends.pybullet.env import PyBulletEnv

    return PyBulletEnv(task, robot, (-3.0, 0.0))


@pytest.mark.parametrize(
    ("argv", "params", "far", "expected"),
    [
        (["--variant", "D7"], "params.yaml", False, "variant 'D7': unknown for task stack"),
        (["--transit", "planned"], "params.yaml", False, "generate.transit: planned: no motion"),
        ([], "noisy.yaml", False, "source demos carry no pose noise"),
        (["--attempts", "4"], "params.yaml", True, "robot 'panda' cannot reach the D0"),
    ],
)
def test_a_refused_request_raises_from_resolve_before_any_output(
    work, monkeypatch, argv, params, far, expected
):
    """Early and late refusals (the workspace check is the last) stop the stage before its
    claim: no output folder, no lock, no metrics file."""

    def no_claim(*args, **kwargs):
        raise AssertionError("outputs claimed before every check")

    monkeypatch.setattr(generate, "claim", no_claim)
    if far:
        monkeypatch.setattr(backends, "make_env", far_env)
    before = tree(work)
    with pytest.raises(InputError, match=expected):
        generate.run(resolve(generate_args(work, *argv, params=params)))
    assert tree(work) == before
    assert not (work / "data/new").exists()


def test_the_runner_reads_no_params_and_no_back_end():
    """What a run does is the job's: the runner, which runs it, imports neither params nor
    the back ends (the stage, which resolves it, does)."""
    modules = project_modules()
    assert not imported("mimicgen_pipe.run.runner", modules) & {
        "mimicgen_pipe.data.params",
        "mimicgen_pipe.backends",
    }
    assert {"mimicgen_pipe.data.params", "mimicgen_pipe.backends"} <= imported(
        "mimicgen_pipe.stages.generate", modules
    )
