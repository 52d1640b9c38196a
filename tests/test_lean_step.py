"""The lean ManiSkill step (mimicgen_pipe/backends/maniskill/lean.py, ``maniskill.lean_step``) is
ManiSkill's ``env.step``: from the same state and the same actions, the stock step and the lean step
set the same joint drive targets and reach the same simulation state, bit for bit, with the same
subtask signals and success; generation on either gives the same attempts; and episodes
generated on the lean path succeed when replayed through plain ManiSkill (``gym.make``,
``env.step``). Needs SAPIEN; marked ``sim`` (the 200-episode replay also ``slow``)."""

from __future__ import annotations

import numpy as np
import pytest

from mimicgen_pipe.data.store import read_store
from tests.conftest import cli

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def stock_and_lean():
    from mimicgen_pipe.backends import make_env

    pair = [make_env("maniskill", "stack_cube", lean_step=lean) for lean in (False, True)]
    yield pair
    for env in pair:
        env.close()


def drive_targets(env) -> np.ndarray:
    """Every active joint's drive target [rad or m] as SAPIEN holds it."""
    joints = env.unwrapped.agent.robot.active_joints
    return np.concatenate([j._objs[0].drive_target for j in joints])


def step_in_lockstep(stock, lean, state: np.ndarray, actions: np.ndarray, what: str) -> None:
    """Both envs from ``state``, the same ``actions``: equal drive targets, state, signals and
    success after every step (bitwise)."""
    stock.set_state(state)
    lean.set_state(state)
    for t, action in enumerate(np.asarray(actions, np.float32)):
        stock.step(action)
        lean.step(action)
        where = f"{what}, step {t}"
        np.testing.assert_array_equal(drive_targets(lean), drive_targets(stock), err_msg=where)
        np.testing.assert_array_equal(lean.get_state(), stock.get_state(), err_msg=where)
        assert lean.subtask_signals() == stock.subtask_signals(), where
        assert lean.is_success() == stock.is_success(), where
    assert lean.is_success(), f"{what}: the episode no longer succeeds"


def test_source_demos_step_the_same(pipeline, stock_and_lean):
    src = read_store(pipeline / "data/source/stack_cube.zarr")
    for ep in range(src.n_episodes):
        demo = src.episode(ep)
        step_in_lockstep(*stock_and_lean, demo["env_state"][0], demo["actions"], f"source {ep}")


def test_generated_episodes_with_action_noise_step_the_same(pipeline, stock_and_lean):
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    for ep in range(gen.n_episodes):
        episode = gen.episode(ep)
        what = f"generated {ep}"
        step_in_lockstep(*stock_and_lean, episode["env_state"][0], episode["actions"], what)


def test_generation_makes_the_same_attempts_on_either_step(pipeline, stock_and_lean):
    from mimicgen_pipe import backends
    from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
    from mimicgen_pipe.run.runner import attempt_seed, source_demos

    spec = backends.task_spec("maniskill", "stack_cube")
    sources = source_demos(read_store(pipeline / "data/parsed/stack_cube.zarr"), spec.objects)
    for env in stock_and_lean:
        env.rebuild()  # both from a fresh scene, as a block of attempts starts
    for variant in ("D0", "D1"):
        for i in range(2):
            seed = attempt_seed(3, variant, i)
            stock, lean = (
                run_attempt(env, sources, spec, GenerationConfig(), variant, seed)
                for env in stock_and_lean
            )
            assert (lean.success, lean.failed_subtask) == (stock.success, stock.failed_subtask)
            assert lean.steps.keys() == stock.steps.keys()
            for key in stock.steps:
                np.testing.assert_array_equal(lean.steps[key], stock.steps[key], err_msg=key)


def replay_in_stock_maniskill(store, episodes: range) -> list[bool]:
    """Success of each episode of a generated stack_cube store, replayed in plain ManiSkill:
    ``gym.make`` with pd_ee_delta_pose, ``set_state`` from the stored initial state, then
    ``env.step`` with the stored actions."""
    import gymnasium as gym
    import torch

    from mimicgen_pipe.backends import load_task
    from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv

    env = gym.make(
        ManiSkillEnv.env_id_for(load_task("maniskill", "stack_cube")),
        obs_mode="state",
        control_mode="pd_ee_delta_pose",
        robot_uids="panda",
        sim_backend="physx_cpu",
        render_backend="none",
    )
    out = []
    try:
        env.reset(seed=0)
        for ep in episodes:
            episode = store.episode(ep)
            env.unwrapped.set_state(torch.as_tensor(episode["env_state"][0])[None])
            info = {}
            for action in episode["actions"]:
                info = env.step(action)[4]
            out.append(bool(info["success"]))
    finally:
        env.close()
    return out


def test_lean_episodes_replay_in_stock_maniskill(pipeline):
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    assert all(replay_in_stock_maniskill(gen, range(gen.n_episodes)))


@pytest.mark.slow
def test_200_lean_episodes_replay_in_stock_maniskill(pipeline):
    """At least 99 % of 200 episodes generated on the lean path (two workers, D0) succeed
    when replayed step by step in plain ManiSkill from their stored initial state."""
    out = "data/lean200/stack_cube_D0.zarr"
    (pipeline / "params_lean200.yaml").write_text(
        "task: stack_cube\ngenerate: {num_demos: 200, max_attempts: 600, workers: 2, seed: 11}\n"
    )
    cli("generate", "--params", "params_lean200.yaml", "--variant", "D0", "--out", out,
        "--metrics", "metrics/lean200.json", cwd=pipeline)  # fmt: skip
    gen = read_store(pipeline / out)
    assert gen.n_episodes == 200
    ok = replay_in_stock_maniskill(gen, range(gen.n_episodes))
    assert sum(ok) >= 198, f"{200 - sum(ok)} of 200 failed on replay in stock ManiSkill"
