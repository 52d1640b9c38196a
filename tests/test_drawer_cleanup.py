"""drawer_cleanup, the suite's long task: six subtasks, three of them on an articulated drawer.
Its spec, the drawer's joint, its demonstrator's demos (parsed into six segments in the
task's order), generated episodes that replay to success, and the lean step reading the same
signals as ManiSkill's own step on a link."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.data.store import read_store
from tests.conftest import cli

TASK = "drawer_cleanup"
PARAMS = (
    f"task: {TASK}\nbackend: maniskill\nsource: {{num_demos: 2, seed: 0}}\n"
    "generate: {variants: [D0], workers: 1, action_noise: 0.025}\n"
)
ORDER = ["drawer_open", "grasp_cubeA", "cubeA_in_drawer", "drawer_closed", "grasp_cubeB"]


def test_the_spec_chains_six_subtasks_the_drawer_ones_relative_to_the_drawer():
    spec = backends.task_spec("maniskill", TASK)
    assert [s.reference_object for s in spec.subtasks] == [
        "drawer", "cubeA", "drawer", "drawer", "cubeB", "cubeC",
    ]  # fmt: skip
    assert [s.term_signal for s in spec.subtasks] == [*ORDER, None]
    assert set(spec.reset_variants) == {"D0", "D1", "D2"}


def test_the_drawer_signals_wait_for_the_hand_to_leave_the_handle():
    """drawer_open and drawer_closed hold only with the handle let go and the hand CLEAR from
    it, so that the straight transit to the next subtask starts away from the drawer."""
    from mimicgen_pipe.tasks.maniskill import drawer_cleanup as task

    turned = np.array([np.cos(0.15), 0.0, 0.0, np.sin(0.15)], np.float32)  # yaw 0.3 rad
    drawer = (np.array([0.02, 0.2, 0.0], np.float32), turned)
    handle = drawer[0] + np.array(
        [[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]], np.float32
    ) @ task.HANDLE.astype(np.float32)
    cube = np.array([0.0, -0.1, 0.02], np.float32)
    let_go = {"drawer": False, "cubeA": False, "cubeB": False}
    for opening, name in ((0.1, "drawer_open"), (0.0, "drawer_closed")):
        for rise, clear in ((0.0, False), (0.03, False), (0.049, False), (0.051, True)):
            p = {"cubeA": cube, "cubeB": cube, "cubeC": cube, "drawer": drawer,
                 "tcp": handle + np.array([0, 0, rise], np.float32)}  # fmt: skip
            assert task._signals(opening, p, let_go)[name] is clear, (name, rise)
        p["tcp"] = handle + np.array([0, 0, 0.2], np.float32)
        held = dict(let_go, drawer=True)
        assert not task._signals(opening, p, held)[name]


@pytest.fixture(scope="module")
def drawer_task(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("drawer")
    (work / "params.yaml").write_text(PARAMS)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    return work


@pytest.mark.sim
def test_the_drawer_slides_out_along_its_axis_and_stays_where_it_is_let_go():
    import torch

    env = backends.make_env("maniskill", TASK)
    try:
        env.reset(seed=1, variant="D1")
        shut = env.object_poses()["drawer"]
        assert env.subtask_signals()["drawer_closed"] and not env.is_success()
        u = env.unwrapped
        u.cabinet.set_qpos(torch.tensor([[0.1]]))
        hold = np.array([0, 0, 0, 0, 0, 0, 1], np.float32)  # the arm keeps its pose
        for _ in range(20):
            env.step(hold)
        out = env.object_poses()["drawer"]
        assert float(u.cabinet.qpos[0, 0]) == pytest.approx(0.1, abs=1e-3)
        # out along the drawer's -x (towards the robot's side of the cabinet), turned as shut
        np.testing.assert_allclose(out[:3, 3], shut[:3, 3] - 0.1 * shut[:3, 0], atol=1e-3)
        np.testing.assert_allclose(out[:3, :3], shut[:3, :3], atol=1e-5)
        signals = env.subtask_signals()
        assert signals["drawer_open"] and not signals["drawer_closed"]
    finally:
        env.close()


@pytest.mark.sim
def test_source_demos_parse_into_six_segments_in_the_tasks_order(drawer_task):
    store = read_store(drawer_task / f"data/parsed/{TASK}.zarr")
    ends = np.asarray(store.episodes["subtask_term_index"])
    lengths = np.diff(np.concatenate([[0], store.episode_ends]))
    assert ends.shape == (2, 5)  # five ends: six segments per demo
    for demo_ends, length in zip(ends, lengths, strict=True):
        assert np.all(np.diff(demo_ends) > 0) and 0 < demo_ends[0] and demo_ends[-1] < length


@pytest.mark.sim
def test_kept_episodes_replay_to_success_with_their_subtasks_in_order(drawer_task):
    from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv
    from mimicgen_pipe.method.generation import GenerationConfig, replay_actions, run_attempt
    from mimicgen_pipe.run.runner import attempt_seed, source_demos

    env = backends.make_env("maniskill", TASK)
    stock_env = ManiSkillEnv(TASK, lean_step=False)
    try:
        store = read_store(drawer_task / f"data/parsed/{TASK}.zarr")
        sources = source_demos(store, env.spec.objects)
        config = GenerationConfig(action_noise=0.025)
        for k in range(6):
            env.rebuild()
            attempt = run_attempt(env, sources, env.spec, config, "D0", attempt_seed(0, "D0", k))
            if attempt.success:
                break
        assert attempt.success, "no attempt of 6 succeeded"
        actions = attempt.steps["actions"]
        _, replayed = replay_actions(env, attempt.initial_state, actions, env.spec.objects)
        assert replayed
        # ManiSkill's own step from the same state: the same signals (grasps of a link
        # included) at every step, each first raised in the task's order, and success
        first: dict[str, int] = {}
        # both from a rebuilt scene: the replay above left contacts in env's PhysX caches,
        # enough to move a signal that sits at its threshold (the hand 5 cm from the handle)
        for e in (env, stock_env):
            e.rebuild()
            e.set_state(attempt.initial_state)
        for t, action in enumerate(actions):
            env.step(action)
            stock_env.step(action)
            lean, own = env.subtask_signals(), stock_env.subtask_signals()
            assert lean == own, f"step {t}"
            for name in ORDER:
                if lean[name] and name not in first and (name != "drawer_closed" or first):
                    first[name] = t
        assert stock_env.is_success() and env.is_success()
        assert sorted(first, key=first.get) == ORDER
    finally:
        env.close()
        stock_env.close()


def test_a_suite_task_with_policies_must_be_a_suite_task_listed_once(tmp_path):
    base = "task: stack\nbackend: pybullet\nsuite: {tasks: [pull_cube_tool, place_sphere], "
    d0 = "{task: pull_cube_tool, variant: D0}"
    for extra, why in (
        ("policy_tasks: [pull_cube_tool, plug_charger]", "suite.policy_tasks: 'plug_charger' "
         "is not in suite.tasks"),
        ("policy_tasks: [place_sphere], d0_policy_tasks: [place_sphere]",
         "suite.d0_policy_tasks: 'place_sphere' is listed twice"),
        ("policy_tasks: [pull_cube_tool], seeded_policy_tasks: [place_sphere, pull_cube_tool]",
         "suite.seeded_policy_tasks: 'pull_cube_tool' is listed twice"),
        ("d0_policy_tasks: [pull_cube_tool]",
         "suite.policy_data: no pull_cube_tool-D0, the store of pull_cube_tool's D0 policy"),
        (f"d0_policy_tasks: [pull_cube_tool], policy_data: {{pull_cube_tool-D1: {d0}}}",
         "suite.policy_data.pull_cube_tool-D1: expected the key 'pull_cube_tool-D0', which "
         "its fields name"),
        (f"d0_policy_tasks: [pull_cube_tool], policy_data: {{pull_cube_tool-D0: {d0}}}, "
         "evaluations: {pull_cube_tool-D1-on-D1: {task: pull_cube_tool, data: D1, variant: D1}}",
         "suite.evaluations.pull_cube_tool-D1-on-D1: the suite trains no D1 policy of "
         "pull_cube_tool"),
        (f"policy_data: {{pull_cube_tool-D0: {d0}}}, robomimic_tasks: [place_sphere]",
         "suite.robomimic_tasks: 'place_sphere' has no D0 policy data (place_sphere-D0 in "
         "suite.policy_data)"),
    ):  # fmt: skip
        (tmp_path / "params.yaml").write_text(base + extra + "}\n")
        res = cli("check", cwd=tmp_path, check=False)  # the suite's rules: its check only
        assert res.returncode == 2
        assert res.stderr.strip().splitlines()[-1] == (
            f"mimicgen-pipe check: error: params.yaml: {why}"
        )
