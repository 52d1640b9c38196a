"""Generation for a task with two arms (mimicgen_pipe.generation.attempt_actions), on a toy
two-arm env without a simulator (tests/two_arm_toy.py): each arm runs its own subtasks, a
sequential constraint holds in every generated episode, coordinated subtasks start and end
together and keep both end effectors' poses relative to their shared object as in the one
source demo they follow, and kept episodes replay to success."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mimicgen_pipe import poses
from mimicgen_pipe.generation import GenerationConfig, replay_actions, run_attempt
from mimicgen_pipe.segments import check_subtask_ends
from mimicgen_pipe.store import read_store
from tests import two_arm_toy as toy
from tests.conftest import cli

N_INTERP = 5
CONFIG = GenerationConfig(action_noise=0.0, n_interp=N_INTERP)
SUBTASK = {(s.arm, s.name): i for i, s in enumerate(toy.SPEC.subtasks)}


@pytest.fixture(scope="module")
def generated():
    env = toy.ToyTwoArmEnv()
    sources = toy.source_demos(env, [100, 101, 102, 103])
    attempts = [run_attempt(env, sources, toy.SPEC, CONFIG, "D0", seed) for seed in range(12)]
    return env, sources, attempts


def steps_of(attempt, arm: str, subtask: str) -> np.ndarray:
    return np.flatnonzero(attempt.steps[f"subtask/{arm}"] == SUBTASK[(arm, subtask)])


def test_parse_splits_each_arms_track_by_its_own_signals(generated):
    _, sources, _ = generated
    # columns: the subtasks with a term signal in the task's order: right's touch_cube and
    # reach_tray_right, left's reach_tray_left; every toy demo ends them at 15, 25, 25
    assert toy.SPEC.ending_subtasks == (0, 1, 3)
    assert sources.term_index.tolist() == [[15, 25, 25]] * 4
    assert check_subtask_ends(np.array([15, 25, 25]), 35, toy.SPEC) is None
    why = check_subtask_ends(np.array([15, 25, 35]), 35, toy.SPEC)
    assert why is not None and why.startswith("arm left: ")


def test_each_arm_runs_its_own_subtasks_and_the_attempts_succeed(generated):
    _, _, attempts = generated
    for a in attempts:
        assert a.steps["actions"].shape[1] == 14
        for arm in toy.ARMS:
            assert a.steps[f"target_pose/{arm}"].shape == (len(a.steps["actions"]), 4, 4)
            assert np.array_equal(
                a.steps[f"gripper/{arm}"], a.steps["actions"][:, 7 * toy.ARMS.index(arm) + 6]
            )
            ran = [i for i in a.steps[f"subtask/{arm}"] if i >= 0]
            assert ran == sorted(ran) and set(ran) == set(toy.SPEC.arm_indices(arm))
        assert "obs/right_eef_pos" in a.steps and "obs/tray_pos" in a.steps
        assert set(k[4:] for k in a.steps if k.startswith("obs/")) == set(
            toy.SPEC.provided_obs_keys
        )
    assert all(a.success for a in attempts), [a.failed_subtask for a in attempts]


def test_the_sequential_constraint_holds(generated):
    _, _, attempts = generated
    for a in attempts:
        touched = steps_of(a, "right", "touch_cube")
        reach = steps_of(a, "left", "reach_tray_left")
        assert reach[0] > touched[-1]  # the left arm starts once the right arm's subtask ended
        # and holds still before: its target is where it began
        before = a.steps["target_pose/left"][: reach[0]]
        assert np.allclose(before, before[0])


def test_coordinated_subtasks_move_together_relative_to_their_object(generated):
    _, sources, attempts = generated
    starts = sources.episode_starts
    for a in attempts:
        left, right = steps_of(a, "left", "lift_left"), steps_of(a, "right", "lift_right")
        assert np.array_equal(left, right) and len(left) > N_INTERP  # start and end together
        demo = a.source_demo[SUBTASK[("left", "lift_left")]]
        assert demo == a.source_demo[SUBTASK[("right", "lift_right")]]  # one source demo
        tray_now = a.steps["object_poses/tray"][left[0]]
        for arm in toy.ARMS:
            # the segment after the interpolation, in the tray's frame, is the source demo's
            segment = a.steps[f"target_pose/{arm}"][left[N_INTERP:]]
            ends = sources.term_index[demo]
            first = (
                starts[demo]
                + ends[toy.SPEC.ending_subtasks.index(SUBTASK[("right", "reach_tray_right")])]
            )
            src = sources.target_poses[arm][first : first + len(segment)]
            src_tray = sources.object_poses["tray"][first]
            np.testing.assert_allclose(
                poses.pose_inv(tray_now) @ segment, poses.pose_inv(src_tray) @ src, atol=1e-9
            )


def test_kept_episodes_replay_to_success(generated):
    env, _, attempts = generated
    for a in attempts[:4]:
        steps, success = replay_actions(
            env, a.initial_state, a.steps["actions"], toy.OBJECTS, toy.ARMS
        )
        assert success
        np.testing.assert_allclose(
            steps["target_pose/left"], a.steps["target_pose/left"], atol=1e-5
        )


def test_a_failed_subtask_is_attributed_to_its_arm():
    """An arm that never reaches its side of the tray fails that subtask, not another."""
    env = toy.ToyTwoArmEnv()
    sources = toy.source_demos(env, [100, 101])
    # the left arm's demos aim 5 cm beside its handle: its reach never ends at the handle
    off = {"left": sources.target_poses["left"] @ toy.at((0.0, 0.05, 0.0))}
    wrong = dataclasses.replace(sources, target_poses={**sources.target_poses, **off})
    a = run_attempt(env, wrong, toy.SPEC, CONFIG, "D0", 7)
    assert not a.success
    assert a.failed_subtask == SUBTASK[("left", "reach_tray_left")]


# ---- ManiSkill: two_robot_stack_cube, end to end ----

TWO_ROBOT_PARAMS = (
    "task: two_robot_stack_cube\nsource: {num_demos: 3, seed: 0}\ngenerate: {workers: 1}\n"
)


@pytest.fixture(scope="module")
def two_robot(tmp_path_factory):
    """3 scripted source demos, parsed, and 8 generated D0 attempts, by the stages."""
    work = tmp_path_factory.mktemp("two_robot")
    (work / "params.yaml").write_text(TWO_ROBOT_PARAMS)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    cli("pose_noise", cwd=work)
    cli("generate", "--variant", "D0", "--attempts", "8", cwd=work)
    return work


@pytest.mark.sim
def test_two_robot_stack_cube_generates_with_its_constraint(two_robot):
    import envs

    spec = envs.task_spec("maniskill", "two_robot_stack_cube")
    index = {(s.arm, s.name): i for i, s in enumerate(spec.subtasks)}
    parsed = read_store(two_robot / "data/parsed/two_robot_stack_cube.zarr")
    assert parsed.episodes["subtask_term_index"].shape == (3, 4)  # two per arm
    kept = read_store(two_robot / "data/generated/two_robot_stack_cube_D0.zarr")
    failed = read_store(two_robot / "data/generated/two_robot_stack_cube_D0_failed.zarr")
    assert kept.n_episodes >= 4 and kept.data["actions"].shape[1] == 14
    for store in (kept, failed):
        for e in range(store.n_episodes):
            ep = store.episode(e)
            placed = np.flatnonzero(ep["subtask/right"] == index[("right", "place_cubeB")])
            stack = np.flatnonzero(ep["subtask/left"] == index[("left", "stack_cubeA")])
            if len(stack):  # the left arm stacks only after the right arm placed cube B
                assert stack[0] > placed[-1]
    env = envs.make_env("maniskill", "two_robot_stack_cube")
    try:
        for e in range(2):
            ep = kept.episode(e)
            _, ok = replay_actions(
                env, kept.episodes["initial_state"][e], ep["actions"], spec.objects, spec.arms
            )
            assert ok, f"kept episode {e} does not replay to success"
    finally:
        env.close()


@pytest.mark.sim
def test_a_two_arm_store_given_to_a_one_arm_task_is_refused(two_robot):
    parsed = two_robot / "data/pose_noise/two_robot_stack_cube.zarr"
    res = cli("generate", "--task", "stack_cube", "--variant", "D0", "--parsed", str(parsed),
              "--out", str(two_robot / "x.zarr"), cwd=two_robot, check=False)  # fmt: skip
    assert res.returncode == 2
    assert "attrs.task is 'two_robot_stack_cube', expected 'stack_cube'" in res.stderr
    assert not (two_robot / "x.zarr").exists()
