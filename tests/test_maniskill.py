"""The ManiSkill back end and the pipeline on it (needs SAPIEN; marked ``sim``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.controller import actions_to_target_poses
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import replay_actions

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def env():
    from mimicgen_pipe.backends import make_env

    e = make_env("maniskill", "stack_cube")
    yield e
    e.close()


def test_action_to_target_matches_the_simulators_controller():
    """Our conversion against ManiSkill's own: the arm controller's target pose after an
    action equals actions_to_target_poses (including the inverted rotation sign)."""
    from mimicgen_pipe.backends import make_env

    env = make_env("maniskill", "stack_cube", lean_step=False)  # the controller's own state
    rng = np.random.default_rng(0)
    arm = env.unwrapped.agent.controller.controllers["arm"]
    env.reset(seed=3, variant="D0")
    for _ in range(10):
        action = np.concatenate([rng.uniform(-1, 1, 3), rng.uniform(-0.5, 0.5, 3), [1.0]])
        ours = env.action_to_target_pose(action)
        env.step(action)
        pq = arm._target_pose.raw_pose[0].numpy().astype(np.float64)
        theirs = env.controller.root_pose @ poses.pose_from_pq(pq[:3], pq[3:])
        np.testing.assert_allclose(ours[:3, 3], theirs[:3, 3], atol=1e-5)
        assert poses.rotation_angle(ours[:3, :3], theirs[:3, :3]) < 1e-4
    # +1 on the z rotation turns the target by -0.1 rad about z (ManiSkill's sign)
    eef = env.eef_pose()
    t = actions_to_target_poses(eef, np.array([0, 0, 0, 0, 0, 1.0, 1]), env.controller)
    yaw = poses.matrix_to_axis_angle(t[:3, :3] @ eef[:3, :3].T)
    np.testing.assert_allclose(yaw, [0, 0, -0.1], atol=1e-9)


def test_closed_loop_tracking_converges(env):
    env.reset(seed=4, variant="D0")
    target = env.eef_pose().copy()
    target[:3, 3] += [0.08, -0.05, -0.04]
    target[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, 0.4])) @ target[:3, :3]
    for _ in range(40):
        env.step(env.target_pose_to_action(target, 1.0))
    e = env.eef_pose()
    assert np.linalg.norm(e[:3, 3] - target[:3, 3]) < 2e-3
    assert poses.rotation_angle(e[:3, :3], target[:3, :3]) < np.radians(1.0)


def test_variants_sample_inside_their_bounds(env):
    for variant in ("D0", "D1"):
        bounds = env.spec.reset_variants[variant].bounds
        xs = []
        for seed in range(30):
            env.reset(seed=seed, variant=variant)
            for name, pose in env.object_poses().items():
                b = bounds[name]
                assert b.x[0] - 1e-6 <= pose[0, 3] <= b.x[1] + 1e-6
                assert b.y[0] - 1e-6 <= pose[1, 3] <= b.y[1] + 1e-6
                xs.append(pose[:2, 3])
        spread = np.std(xs, axis=0)
        if variant == "D0":
            d0_spread = spread
    assert np.all(spread > d0_spread)  # D1 is the larger region


def test_pipeline_outputs_follow_the_data_contract(pipeline):
    src = read_store(pipeline / "data/source/stack_cube.zarr")
    assert src.n_episodes == 3
    parsed = read_store(pipeline / "data/parsed/stack_cube.zarr")
    assert parsed.episodes["subtask_term_index"].shape == (3, 1)
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    assert gen.n_episodes == 4 and gen.attrs["variant"] == "D1"
    for key in (
        "actions",
        "eef_pose",
        "target_pose",
        "gripper",
        "env_state",
        "object_poses/cubeA",
        "object_poses/cubeB",
        "subtask_signals/grasp_cubeA",
    ):
        assert key in gen.data and len(gen.data[key]) == gen.episode_ends[-1], key
    for key in ("seed", "success", "source_demo", "initial_object_poses", "failure_reason"):
        assert len(gen.episodes[key]) == 4, key
    assert gen.episodes["success"].all()
    assert (gen.episodes["failure_reason"] == -1).all()
    metrics = json.loads((pipeline / "metrics/generate_stack_cube_D1.json").read_text())
    assert metrics["successes"] == 4
    assert (
        metrics["attempts"]
        == 4 + metrics["failures_grasp_cubeA"] + metrics["failures_place_on_cubeB"]
    )
    failed = read_store(pipeline / "data/generated/stack_cube_D1_failed.zarr")
    assert failed.n_episodes == metrics["attempts"] - 4
    assert (failed.episodes["failure_reason"] >= 0).all()


def test_generated_segments_follow_the_new_object(pipeline):
    """Inside a generated episode, the executed targets of the grasp segment keep their pose
    relative to cube A as in the chosen source demo (up to the action noise's absence in
    targets: targets are noise-free)."""
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    src = read_store(pipeline / "data/parsed/stack_cube.zarr")
    ep = 0
    demo = int(gen.episodes["source_demo"][ep, 0])
    s0 = src.episode_starts[demo]
    src_rel = poses.pose_inv(src.poses("object_poses/cubeA")[s0]) @ src.poses("target_pose")[s0]
    g0 = gen.episode_starts[ep] + 5  # after n_interp=5 interpolation poses
    cube0 = gen.poses("initial_object_poses")[ep, 0]
    gen_rel = poses.pose_inv(cube0) @ gen.poses("target_pose")[g0]
    np.testing.assert_allclose(gen_rel, src_rel, atol=1e-6)


def test_same_seed_same_dataset_on_one_or_two_workers(pipeline):
    a = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    b = read_store(pipeline / "data/again/stack_cube_D1.zarr")
    assert a.data["actions"].tobytes() == b.data["actions"].tobytes()
    np.testing.assert_array_equal(a.episodes["seed"], b.episodes["seed"])


def test_replaying_generated_episodes_reproduces_success(pipeline, env):
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    for ep in range(gen.n_episodes):
        steps, success = replay_actions(
            env, gen.episodes["initial_state"][ep], gen.episode(ep)["actions"], env.spec.objects
        )
        assert success, f"episode {ep} did not succeed on replay"
        # contact caches differ between the generating and the replaying process, so the
        # trajectory matches to millimetres, not bits
        np.testing.assert_allclose(
            steps["eef_pose"][:, :3, 3],
            gen.poses("eef_pose")[gen.episode_starts[ep] : gen.episode_ends[ep]][:, :3, 3],
            atol=5e-3,
        )


def test_fast_state_and_pose_reads_match_maniskill(env):
    """The adapter reads state and poses straight from SAPIEN; they must equal ManiSkill's
    own batched accessors, including after a scene rebuild."""
    rng = np.random.default_rng(1)
    for rebuild in (False, True):
        if rebuild:
            env.rebuild()
        env.reset(seed=5, variant="D1")
        for _ in range(20):
            env.step(rng.uniform(-1, 1, 7))
        np.testing.assert_array_equal(env.get_state(), env.unwrapped.get_state()[0].numpy())
        pq = env.unwrapped.cubeB.pose.raw_pose[0].numpy().astype(np.float64)
        np.testing.assert_allclose(
            env.object_poses()["cubeB"], poses.pose_from_pq(pq[:3], pq[3:]), atol=1e-12
        )


def test_a_converted_demo_that_starts_from_another_plan_is_dropped(env, tmp_path, monkeypatch):
    """ManiSkill's converter can join failed conversions onto the next plan's episode; the
    joined episode (its seed's name, another plan's initial state) is not kept as a demo,
    and counts as a dropped plan."""
    import h5py

    from mimicgen_pipe.backends.maniskill import source

    def state_rows(seed: int, steps: int) -> dict:
        env.reset(seed, "D0")
        state = env.unwrapped.get_state_dict()
        return {k: {n: np.repeat(v.numpy(), steps + 1, 0) for n, v in d.items()}
                for k, d in state.items()}  # fmt: skip

    def write(name: str, mode: str, episodes: list[tuple[int, dict, int]]) -> Path:
        path = tmp_path / f"{name}.h5"
        with h5py.File(path, "w") as f:
            for i, (_, states, steps) in enumerate(episodes):
                f[f"traj_{i}/actions"] = np.zeros((steps, 7 if mode != "pd_joint_pos" else 8))
                for kind, arrays in states.items():
                    for n, a in arrays.items():
                        f[f"traj_{i}/env_states/{kind}/{n}"] = a[: steps + 1]
        meta = {
            "env_info": {"env_id": "StackCube-v1", "env_kwargs": {"control_mode": mode}},
            "episodes": [
                {"episode_id": i, "episode_seed": seed} for i, (seed, _, _) in enumerate(episodes)
            ],
        }
        path.with_suffix(".json").write_text(json.dumps(meta))
        return path

    plans = [(s, state_rows(s, 4), 4) for s in (0, 1, 2)]
    write("planned", "pd_joint_pos", plans)
    # seed 1 failed to convert: the converter put its steps before seed 2's
    joined = (2, state_rows(1, 8), 8)
    converted = write("planned.pd_ee_delta_pose", "pd_ee_delta_pose", [plans[0], joined])
    monkeypatch.setattr(source, "run_motion_planner", lambda *a: (converted, 3, 4))
    episodes, dropped, tried = source.source_episodes(env, 3, 0, None, tmp_path)
    assert [ep.seed for ep in episodes] == [0]
    assert (dropped, tried) == (6, 7)  # 4 failed plans, seed 1's conversion, seed 2's join


def test_poses_and_observation_derived_after_the_attempt_equal_reads_at_every_step(
    pipeline, env, monkeypatch
):
    """The recorder reads the object poses and the fingers from the stored states after an
    attempt (the env's state_layout), and the observation from them, all steps at once.
    Recorded the old way, read from the env before every step, the attempt must be the same
    bit for bit; and the layout must point at what object_poses() and gripper_state() read."""
    from mimicgen_pipe.backends import task_spec
    from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
    from mimicgen_pipe.run.runner import attempt_seed, source_demos
    from tests.conftest import same_attempt

    spec = task_spec("maniskill", "stack_cube")
    sources = source_demos(read_store(pipeline / "data/parsed/stack_cube.zarr"), spec.objects)
    layout = env.state_layout()
    assert layout is not None and set(layout.objects) == set(spec.objects)
    env.reset(seed=4, variant="D1")
    rng = np.random.default_rng(0)
    for _ in range(15):
        env.step(rng.uniform(-1, 1, 7))
        state = env.get_state()[None]
        for name, pose in env.object_poses().items():
            assert layout.object_poses(state)[name][0].tobytes() == pose.tobytes()
        assert layout.gripper_states(state)[0].tobytes() == env.gripper_state().tobytes()
    seeds = [attempt_seed(0, "D1", i) for i in range(3)]
    env.rebuild()  # each run of attempts on a new scene, as a block of them runs
    derived = [run_attempt(env, sources, spec, GenerationConfig(), "D1", s) for s in seeds]
    monkeypatch.setattr(env, "state_layout", lambda: None)
    env.rebuild()
    read = [run_attempt(env, sources, spec, GenerationConfig(), "D1", s) for s in seeds]
    assert all(same_attempt(a, b) for a, b in zip(derived, read, strict=True))
    assert "obs/cubeA_quat" in derived[0].steps and len(derived[0].steps["actions"]) > 50
