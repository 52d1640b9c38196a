"""ManiSkill's batched form (mimicgen_pipe/backends/maniskill/batch.py) without a GPU: a batch of
one scene on physx_cpu runs ManiSkill's own step, reset and evaluation through the batch protocol,
and makes the same attempts, bit for bit, as the one-at-a-time env with ManiSkill's own step
(maniskill.lean_step: false), through the engine and through the generate loop's blocks;
and every batch the back end cannot run is refused before any work."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest
import torch

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import GenerateParams, Params, data_params
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.batched import replay_batched, run_batched
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.executors import Executor
from mimicgen_pipe.run.runner import (
    AttemptJob,
    AttemptSeeds,
    GenerateJob,
    attempt_seed,
    generate,
    source_demos,
)
from tests.conftest import cli, same_attempt

pytestmark = pytest.mark.sim
TASK, VARIANT, N_SEEDS = "stack_cube", "D1", 3


@pytest.fixture(scope="module")
def sources(pipeline):
    spec = backends.task_spec("maniskill", TASK)
    return spec, source_demos(read_store(pipeline / f"data/parsed/{TASK}.zarr"), spec.objects)


@pytest.fixture(scope="module")
def one_at_a_time(sources):
    """The attempts of the seeds on the one-scene env with ManiSkill's own step."""
    spec, demos = sources
    env = backends.make_env("maniskill", TASK, lean_step=False)
    env.rebuild()
    seeds = [attempt_seed(0, VARIANT, i) for i in range(N_SEEDS)]
    out = [run_attempt(env, demos, spec, GenerationConfig(), VARIANT, s) for s in seeds]
    env.close()
    return seeds, out


def test_a_batch_of_one_on_the_cpu_makes_the_stock_steps_attempts(sources, one_at_a_time):
    spec, demos = sources
    seeds, expected = one_at_a_time
    batch = backends.make_batch_env("maniskill", TASK, "panda", 1, "physx_cpu")
    try:
        got = dict(run_batched(batch, demos, spec, GenerationConfig(), VARIANT, seeds))
        slot = batch.slot(0)
        # the slot's reads are the stock env's, in the stock env's types
        assert slot.eef_pose().shape == (4, 4) and slot.get_state().dtype == np.float32
        assert all(type(v) is bool for v in slot.subtask_signals().values())
        with pytest.raises(RuntimeError, match="stepped by its batch"):
            slot.step(np.zeros(7, np.float32))
    finally:
        batch.close()
    assert sorted(got) == list(range(N_SEEDS))
    assert all(same_attempt(got[i], expected[i]) for i in range(N_SEEDS))
    assert any(a.success for a in expected)  # a check of something that happened


def test_kept_attempts_replay_to_success_on_the_batch(one_at_a_time):
    _, attempts = one_at_a_time
    kept = [(a.initial_state, a.steps["actions"]) for a in attempts if a.success]
    batch = backends.make_batch_env("maniskill", TASK, "panda", 1, "physx_cpu")
    try:
        assert replay_batched(batch, kept) == [True] * len(kept)
        # the last replay left the scene where its episode ended: not where it began
        assert not np.array_equal(batch.slot(0).get_state(), kept[-1][0])
    finally:
        batch.close()


def test_generate_runs_blocks_on_the_batch(sources, one_at_a_time):
    """The generate loop with a batch per worker: make_batch, blocks of num_envs x 16
    attempts, attempts handed back in seed order."""
    spec, demos = sources
    seeds, expected = one_at_a_time
    job = AttemptJob(
        functools.partial(backends.make_env, "maniskill", TASK, "panda", False),
        demos,
        spec,
        GenerationConfig(),
        VARIANT,
        make_batch=functools.partial(backends.make_batch_env, "maniskill", TASK, "panda", 1, None),
        num_envs=1,
    )
    run = GenerateJob(
        spec=spec,
        backend_name="maniskill",
        backend=backends.backend_package("maniskill"),
        variant=VARIANT,
        generate=GenerateParams(mode="fixed_attempts", max_attempts=N_SEEDS),
        note=None,
        parsed_path=Path("parsed.zarr"),
        out=Path("kept.zarr"),
        failed_out=Path("failed.zarr"),
        metrics_path=Path("m.json"),
        executor=Executor("local", 1),
        attempts=job,
        seeds=AttemptSeeds(0, VARIANT, N_SEEDS),
        run_id="run",
        attrs={},
    )
    assert list(run.seeds) == seeds
    result = generate(run)
    got = result.kept + result.failed
    got.sort(key=lambda a: seeds.index(a.seed))
    assert [a.seed for a in got] == seeds
    assert all(same_attempt(a, b) for a, b in zip(got, expected, strict=True))
    assert result.metrics["attempts"] == N_SEEDS


def test_batch_params_shape_the_data_only_when_set():
    params = Params()
    assert "num_envs" not in data_params(params, "generate")["generate"]
    assert "maniskill" not in data_params(params, "generate")
    g = dataclasses.replace(params.generate, num_envs=256)
    gpu = dataclasses.replace(
        params,
        generate=g,
        maniskill=dataclasses.replace(params.maniskill, sim_backend="physx_cuda"),
    )
    shaped = data_params(gpu, "generate")
    assert shaped["generate"]["num_envs"] == 256
    assert shaped["maniskill"] == {"sim_backend": "physx_cuda"}


@pytest.mark.parametrize(
    "backend, task, robot, num_envs, sim, transit, message",
    [
        ("maniskill", TASK, "panda", 0, "physx_cpu", "linear", "integer >= 1"),
        ("maniskill", TASK, "panda", 4, "physx_cpu", "linear", "one scene per env"),
        ("maniskill", TASK, "panda", 4, "physx_gpu", "linear", "unknown"),
        ("maniskill", TASK, "xarm6", 1, "physx_cpu", "linear", "Panda only"),
        ("maniskill", TASK, "panda", 1, "physx_cpu", "planned", "no motion planner"),
        ("maniskill", "drawer_cleanup", "panda", 1, "physx_cpu", "linear", "no batched form"),
        ("pybullet", "stack", "panda", 4, None, "linear", "backend pybullet has no batched"),
    ],
)
def test_batches_the_back_end_cannot_run_are_refused(
    backend, task, robot, num_envs, sim, transit, message
):
    with pytest.raises(InputError, match=message):
        backends.check_batched(backend, task, robot, num_envs, sim, transit)


@pytest.mark.skipif(torch.cuda.is_available(), reason="the refusal is for machines without CUDA")
def test_physx_cuda_without_cuda_is_refused():
    with pytest.raises(InputError, match="no CUDA device"):
        backends.check_batched("maniskill", TASK, "panda", 256, "physx_cuda", "linear")


@pytest.mark.parametrize(
    "params, message",
    [
        (
            "task: stack_cube\ngenerate: {num_envs: 4}\n",
            "generate.num_envs 4 on maniskill.sim_backend physx_cpu: ManiSkill's CPU simulation "
            "holds one scene per env",
        ),
        (
            "task: stack\nbackend: pybullet\ngenerate: {num_envs: 4}\n",
            "generate.num_envs 4: backend pybullet has no batched form",
        ),
        ("task: stack_cube\ngenerate: {num_envs: 0}\n", "generate.num_envs"),
        ("task: stack_cube\nmaniskill: {sim_backend: physx_gpu}\n", "maniskill.sim_backend"),
    ],
)
def test_the_generate_stage_refuses_a_batch_before_any_work(tmp_path, params, message):
    (tmp_path / "params.yaml").write_text(params)
    res = cli("generate", "--variant", "D0", "--parsed", "missing.zarr", cwd=tmp_path, check=False)
    assert res.returncode == 2, res.stderr[-2000:]
    assert message in res.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "data").exists() and not (tmp_path / "metrics").exists()
