"""Generation for a task with two arms (mimicgen_pipe.method.generation.attempt_actions), on a toy
two-arm env without a simulator (tests/two_arm_toy.py): each arm runs its own subtasks, a
sequential constraint holds in every generated episode, coordinated subtasks start and end
together and keep both end effectors' poses relative to their shared object as in the one
source demo they follow, and kept episodes replay to success."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import GenerationConfig, replay_actions, run_attempt
from mimicgen_pipe.method.segments import check_subtask_ends
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

TWO_ROBOT_PARAMS = """
task: two_robot_stack_cube
source: {num_demos: 3, seed: 0}
generate: {workers: 1}
train:
  num_demos: 8
  cpu: {hidden: 16, layers: 1, seq_len: 10, batch_size: 8, lr: 0.001, epochs: 2,
        steps_per_epoch: 5, checkpoint_every: 1, seeds: [0], threads: 1}
evaluate: {episodes: 2, every_epochs: 2, workers: 1}
render: {episodes: 1, width: 96, height: 72}
"""


def source_to_generate(work, params: str, variant: str, attempts: int):
    """The stages from the scripted source demos to ``attempts`` generated on ``variant``,
    in ``work`` with ``params``."""
    (work / "params.yaml").write_text(params)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    cli("pose_noise", cwd=work)
    cli("generate", "--variant", variant, "--attempts", str(attempts), cwd=work)
    return work


@pytest.fixture(scope="module")
def two_robot(tmp_path_factory):
    """3 scripted source demos, parsed, and 8 generated D0 attempts, by the stages."""
    return source_to_generate(tmp_path_factory.mktemp("two_robot"), TWO_ROBOT_PARAMS, "D0", 8)


@pytest.mark.sim
def test_a_rollout_observes_both_arms_as_the_generator_recorded_them(two_robot):
    """The observation a policy is shown in a rollout is the stored one, key for key."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.learn.evaluation import policy_observation

    spec = backends.task_spec("maniskill", "two_robot_stack_cube")
    kept = read_store(two_robot / "data/generated/two_robot_stack_cube_D0.zarr")
    ep = kept.episode(0)
    env = backends.make_env("maniskill", "two_robot_stack_cube")
    try:
        env.set_state(kept.episodes["initial_state"][0])
        obs = policy_observation(env, spec.objects, spec.arms)
    finally:
        env.close()
    assert set(obs) == set(spec.provided_obs_keys) == {k[4:] for k in ep if k.startswith("obs/")}
    assert {k: v.size for k, v in obs.items()} == spec.observation_dims
    for key, value in obs.items():
        np.testing.assert_allclose(value, ep[f"obs/{key}"][0], atol=1e-6, err_msg=key)
    assert not np.allclose(obs["left_eef_pos"], obs["right_eef_pos"])


@pytest.mark.sim
def test_a_policy_trains_on_two_arm_data_and_is_evaluated(two_robot):
    """Train reads the 14-wide actions and both arms' observations; evaluate rolls the
    checkpoint out in the two-arm env and writes its success rates."""
    import json

    from mimicgen_pipe.learn.training import load_checkpoint

    cli("train", "--data", "D0", "--num-demos", "4", cwd=two_robot)
    ckpts = sorted((two_robot / "data/policies/two_robot_stack_cube_D0").rglob("*.pt"))
    assert ckpts
    model, meta = load_checkpoint(ckpts[-1])
    assert model.config.action_dim == 14 and meta["epoch"] == 2
    assert {"left_eef_pos", "right_eef_pos", "cubeA_pos"} <= set(model.config.obs_keys)
    cli("evaluate", "--data", "D0", "--variant", "D0", cwd=two_robot)
    m = json.loads((two_robot / "metrics/evaluate_two_robot_stack_cube_D0_on_D0.json").read_text())
    assert m["episodes"] == 2 and 0.0 <= m["success_rate_last"] <= 100.0


@pytest.mark.sim
def test_two_robot_stack_cube_generates_with_its_constraint(two_robot):
    from mimicgen_pipe import backends

    spec = backends.task_spec("maniskill", "two_robot_stack_cube")
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
    env = backends.make_env("maniskill", "two_robot_stack_cube")
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


@pytest.mark.sim
def test_two_arm_exports_name_each_arms_actions_and_subtasks(two_robot, tmp_path):
    """robomimic and LeRobot carry the 14-wide actions named per arm, each arm's subtask
    labels, poses and observations; ManiSkill's one-agent trajectory format is refused."""
    import json

    import h5py
    import pyarrow.parquet as pq

    from mimicgen_pipe import backends
    from mimicgen_pipe.core.errors import InputError
    from mimicgen_pipe.formats import exporters

    spec = backends.task_spec("maniskill", "two_robot_stack_cube")
    store = exporters.read(two_robot / "data/generated/two_robot_stack_cube_D0.zarr", spec.name)
    info = exporters.export_info(store.attrs, spec, spec.default_obs_keys, 0.25)
    names = info.action_names
    assert len(names) == 14 and names[0] == "left.dx" and names[13] == "right.gripper"

    path, _ = exporters.write(store, "robomimic", tmp_path, info)
    with h5py.File(path) as f:
        assert json.loads(f["data"].attrs["action_names"]) == names
        assert json.loads(f["data"].attrs["arms"]) == ["left", "right"]
        demo, ep = f["data/demo_1"], store.episode(1)
        assert demo["actions"].shape == (len(ep["actions"]), 14)
        for arm in ("left", "right"):
            np.testing.assert_array_equal(demo[f"subtask_index/{arm}"][:], ep[f"subtask/{arm}"])
            assert set(demo[f"subtask_index/{arm}"][:]) - {-1} <= set(spec.arm_indices(arm))
            np.testing.assert_allclose(
                demo[f"datagen_info/eef_pose/{arm}"][:, :3, 3], ep[f"obs/{arm}_eef_pos"], atol=1e-5
            )
            np.testing.assert_array_equal(
                demo[f"datagen_info/gripper_action/{arm}"][:, 0], ep[f"gripper/{arm}"]
            )

    path, _ = exporters.write(store, "lerobot", tmp_path / "lr", info)
    meta = json.loads((path / "meta/info.json").read_text())["features"]
    assert meta["action"]["names"] == names and meta["action"]["shape"] == [14]
    state = meta["observation.state"]["names"]
    assert "left_eef_pos.x" in state and "right_gripper_qpos.x" in state
    assert not any("_to_" in n for n in state)
    frames = pq.read_table(path / "data/chunk-000/file-000.parquet")
    np.testing.assert_array_equal(
        frames["subtask_index.right"].to_numpy(), store.data["subtask/right"]
    )
    with pytest.raises(InputError, match="arms left, right"):
        exporters.check(store, "maniskill", info)


@pytest.mark.sim
def test_two_arm_frames_are_captioned_with_both_arms_subtasks(two_robot, monkeypatch):
    """A two-arm store's episode gives a frame per step, each captioned with what each arm
    does (a blank picture stands in for the renderer)."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.media import video

    kept = read_store(two_robot / "data/generated/two_robot_stack_cube_D0.zarr")
    spec = backends.task_spec("maniskill", "two_robot_stack_cube")
    arms = tuple(dict.fromkeys(s.arm for s in spec.subtasks))
    captions: list = []
    monkeypatch.setattr(video, "caption", lambda f, lines, ok=None: captions.append(lines) or f)
    blank = np.zeros((72, 96, 3), np.uint8)
    frames = video.episode_frames(lambda s: blank, kept, 0, spec.subtasks, "t", True, "x")
    assert len(frames) == len(captions) == len(kept.episode(0)["actions"])
    assert len(arms) == 2 and all(all(f"{a}: " in lines[1] for a in arms) for lines in captions)
    assert captions[-1][2] == "kept (success)"


@pytest.mark.sim
@pytest.mark.slow
def test_two_arm_episodes_render_with_the_render_stage(two_robot):
    """The render stage draws a two-arm store's first kept and failed episodes, a frame per
    step, into videos."""
    import json

    kept = read_store(two_robot / "data/generated/two_robot_stack_cube_D0.zarr")
    failed = read_store(two_robot / "data/generated/two_robot_stack_cube_D0_failed.zarr")
    cli("render", "--variant", "D0", cwd=two_robot)
    m = json.loads((two_robot / "metrics/render_two_robot_stack_cube_D0.json").read_text())
    firsts = [len(s.episode(0)["actions"]) for s in (kept, failed) if s.n_episodes]
    assert m["frames"] == sum(firsts)
    assert (two_robot / "media/two_robot_stack_cube_D0/kept_0.mp4").stat().st_size > 0


@pytest.fixture(scope="module")
def lift_bar(tmp_path_factory):
    """3 scripted source demos of two_robot_lift_bar, parsed, and 6 generated D1 attempts."""
    params = "task: two_robot_lift_bar\nsource: {num_demos: 3, seed: 0}\ngenerate: {workers: 1}\n"
    return source_to_generate(tmp_path_factory.mktemp("lift_bar"), params, "D1", 6)


@pytest.mark.sim
def test_two_robot_lift_bar_lifts_the_bar_with_both_arms_as_one(lift_bar):
    """The coordinated lifts start at one step in every episode and end with the two hands'
    targets placed relative to each other as in the one source demo both follow; kept
    episodes replay to success."""
    from mimicgen_pipe import backends

    spec = backends.task_spec("maniskill", "two_robot_lift_bar")
    lift = {a: spec.subtasks.index(spec.arm_subtasks(a)[-1]) for a in ("left", "right")}
    parsed = read_store(lift_bar / "data/parsed/two_robot_lift_bar.zarr")
    kept = read_store(lift_bar / "data/generated/two_robot_lift_bar_D1.zarr")
    assert kept.n_episodes >= 4
    src_targets = {a: parsed.poses(f"target_pose/{a}") for a in lift}
    targets = {a: kept.poses(f"target_pose/{a}") for a in lift}
    for e in range(kept.n_episodes):
        ep = kept.episode(e)
        starts = {a: np.flatnonzero(ep[f"subtask/{a}"] == lift[a])[0] for a in lift}
        assert starts["left"] == starts["right"]
        demo = kept.episodes["source_demo"][e]
        assert demo[lift["left"]] == demo[lift["right"]]
        last = parsed.episode_ends[int(demo[lift["left"]])] - 1
        want = poses.pose_inv(src_targets["left"][last]) @ src_targets["right"][last]
        end = kept.episode_ends[e] - 1
        got = poses.pose_inv(targets["left"][end]) @ targets["right"][end]
        np.testing.assert_allclose(got, want, atol=1e-5)
    env = backends.make_env("maniskill", "two_robot_lift_bar")
    try:
        _, ok = replay_actions(
            env,
            kept.episodes["initial_state"][0],
            kept.episode(0)["actions"],
            spec.objects,
            spec.arms,
        )
        assert ok
    finally:
        env.close()
