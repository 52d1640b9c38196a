"""Planned transit (generate.transit: planned): the joint-space search on a toy world, the
failure class and params it adds, the refusals, and on ManiSkill's stack_cube_wall a planned
transit that goes over the wall the straight line runs into."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core.transit import PlannerSettings, approach_start, densify, joint_path
from mimicgen_pipe.data.metrics import generation_metrics
from mimicgen_pipe.data.params import Params, data_params, load_params
from mimicgen_pipe.data.store import read_store
from tests.conftest import cli

# ---- the search (no simulator) ----

LOWER, UPPER = np.array([-1.0, -1.0]), np.array([1.0, 1.0])


def _wall_with_gap(q: np.ndarray) -> bool:
    """A 2-D world: a wall at x in [-0.05, 0.05] except a gap at y > 0.7."""
    return not (abs(q[0]) <= 0.05 and q[1] < 0.7)


def test_a_path_goes_around_the_wall_in_small_steps_and_the_same_seed_gives_it_again():
    start, goal = np.array([-0.6, -0.5]), np.array([0.6, -0.5])
    settings = PlannerSettings(max_joint_step=0.02, max_iterations=5000)
    path = joint_path(start, goal, _wall_with_gap, settings, np.random.default_rng(3), LOWER, UPPER)
    assert path is not None
    np.testing.assert_array_equal(path[-1], goal)
    steps = np.abs(np.diff(np.vstack([start, path]), axis=0)).max(axis=1)
    assert steps.max() <= 0.02 + 1e-12
    # every point free, and the path went through the gap (the only way across)
    assert all(_wall_with_gap(q) for q in path)
    crossing = path[np.abs(path[:, 0]) <= 0.05]
    assert len(crossing) and (crossing[:, 1] >= 0.7).all()
    again = joint_path(
        start, goal, _wall_with_gap, settings, np.random.default_rng(3), LOWER, UPPER
    )
    np.testing.assert_array_equal(path, again)


def test_a_free_straight_edge_is_taken_and_a_closed_wall_is_a_failure():
    start, goal = np.array([-0.6, 0.0]), np.array([-0.2, 0.4])
    path = joint_path(start, goal, _wall_with_gap, PlannerSettings(max_joint_step=0.1),
                      np.random.default_rng(0), LOWER, UPPER)  # fmt: skip
    assert path is not None and len(path) == 4  # 0.4 rad in steps of 0.1
    np.testing.assert_allclose(path, [start + (goal - start) * k / 4 for k in (1, 2, 3, 4)])
    closed = lambda q: abs(q[0]) > 0.05  # noqa: E731  no gap: the two sides never meet
    settings = PlannerSettings(max_iterations=300)
    got = joint_path(np.array([-0.6, 0.0]), np.array([0.6, 0.0]), closed, settings,
                     np.random.default_rng(0), LOWER, UPPER)  # fmt: skip
    assert got is None


def test_densify_leaves_out_the_start_and_keeps_every_waypoint():
    out = densify([np.zeros(2), np.array([0.1, 0.0]), np.array([0.1, 0.25])], 0.05)
    assert len(out) == 2 + 5
    np.testing.assert_allclose(out[1], [0.1, 0.0])
    np.testing.assert_allclose(out[-1], [0.1, 0.25])


def test_the_approach_is_the_first_target_near_the_reference_object():
    targets = np.tile(np.eye(4), (5, 1, 1))
    targets[:, 0, 3] = [0.5, 0.3, 0.12, 0.08, 0.2]
    assert approach_start(targets, np.eye(4), 0.1) == 3
    assert approach_start(targets, np.eye(4), 0.01) == 0  # none that close: the whole segment


# ---- what it adds to metrics, params and stores ----


def test_planner_failures_are_counted_apart_from_task_and_ik_failures():
    success = np.array([True, False, False, False, False])
    failed = np.array([-1, 0, 1, 1, 0])
    ik = np.array([False, False, False, True, False])
    planner = np.array([False, True, False, False, False])
    m = generation_metrics(success, failed, np.ones(5), ["grasp", "place"], ik, planner)
    assert m["planner_failures"] == 1 and m["planner_failures_grasp"] == 1
    assert m["failures_grasp"] == 1 and m["failures_place"] == 1
    assert m["ik_failures_place"] == 1
    linear = generation_metrics(success, failed, np.ones(5), ["grasp", "place"], ik)
    assert not [k for k in linear if "planner" in k]


def test_linear_transit_records_the_generate_params_it_always_did():
    params = Params()
    linear = data_params(params, "generate")["generate"]
    assert "transit" not in linear and "planner" not in linear
    g = dataclasses.replace(params.generate, transit="planned")
    planned = data_params(dataclasses.replace(params, generate=g), "generate")["generate"]
    assert planned["transit"] == "planned" and planned["planner"]["clearance"] == 0.02


def test_a_planner_setting_out_of_range_is_one_error(tmp_path):
    p = tmp_path / "params.yaml"
    p.write_text("generate:\n  transit: planned\n  planner: {max_joint_step: 2.0}\n")
    with pytest.raises(Exception, match=r"generate\.planner\.max_joint_step: expected a value "
                       r"in \[0\.001, 0\.5\], got 2\.0"):  # fmt: skip
        load_params(p)
    p.write_text("generate:\n  transit: curved\n")
    with pytest.raises(Exception, match=r"generate\.transit: expected one of 'linear', "
                       "'planned'"):  # fmt: skip
        load_params(p)


@pytest.mark.sim
def test_planned_transit_without_a_planner_is_refused_before_any_work(tmp_path):
    (tmp_path / "params.yaml").write_text(
        "task: stack\nbackend: pybullet\ngenerate: {transit: planned}\n"
    )
    res = cli("generate", "--variant", "D0", "--parsed", "missing.zarr", cwd=tmp_path,
              check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1] == (
        "mimicgen-pipe generate: error: generate.transit: planned: no motion planner for robot "
        "'panda' (backend pybullet has no motion planner); use transit: linear"
    )
    assert not (tmp_path / "data").exists() and not (tmp_path / "metrics").exists()


# ---- ManiSkill: over the wall ----

WALL_PARAMS = (
    "task: stack_cube_wall\nbackend: maniskill\nsource: {num_demos: 3, seed: 0}\n"
    "generate: {variants: [D0, wall], workers: 1}\n"
)


@pytest.fixture(scope="module")
def wall_task(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("wall")
    (work / "params.yaml").write_text(WALL_PARAMS)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    return work


def wall_contacts(env) -> list[str]:
    """Robot links (and the cube they hold) touching the wall now."""
    u = env.unwrapped
    wall = u.wall._bodies[0]
    out = []
    for contact in u.scene.px.get_contacts():
        b0, b1 = contact.bodies
        if wall in (b0, b1) and any(p.separation < -1e-3 for p in contact.points):
            other = b1 if b0 is wall else b0
            out.append(other.entity.name)
    return out


@pytest.mark.sim
def test_a_planned_transit_goes_over_the_wall_the_straight_line_hits(wall_task):
    from mimicgen_pipe.backends import make_env
    from mimicgen_pipe.method.generation import GenerationConfig, replay_actions, run_attempt
    from mimicgen_pipe.run.runner import attempt_seed, source_demos

    env = make_env("maniskill", "stack_cube_wall")
    store = read_store(wall_task / "data/parsed/stack_cube_wall.zarr")
    sources = source_demos(store, env.spec.objects)
    planned = GenerationConfig(transit="planned")
    kept = 0
    for k in range(4):
        seed = attempt_seed(0, "wall", k)
        env.rebuild()  # as the runner does before each block: PhysX keeps contact caches
        attempt = run_attempt(env, sources, env.spec, planned, "wall", seed)
        if not attempt.success:
            continue
        kept += 1
        # executed again step by step: nothing of the arm ever pushes into the wall, and
        # the episode's actions replay to success
        env.set_state(attempt.initial_state)
        touched = []
        for action in attempt.steps["actions"]:
            env.step(action)
            touched += wall_contacts(env)
        assert touched == [], f"attempt {k} touched the wall: {sorted(set(touched))}"
        _, replayed = replay_actions(env, attempt.initial_state, attempt.steps["actions"],
                                     env.spec.objects)  # fmt: skip
        assert replayed, f"attempt {k} does not replay to success"
        # the same seed plans the same path: the same actions to the last bit
        env.rebuild()
        again = run_attempt(env, sources, env.spec, planned, "wall", seed)
        np.testing.assert_array_equal(again.steps["actions"], attempt.steps["actions"])
        # the straight line from the same scene fails, into the wall
        linear = run_attempt(env, sources, env.spec, GenerationConfig(), "wall", seed)
        assert not linear.success
        env.set_state(linear.initial_state)
        for action in linear.steps["actions"]:
            env.step(action)
            touched += wall_contacts(env)
        assert touched, "the straight line never touched the wall"
        break
    assert kept, "no planned attempt of 4 succeeded"
    env.close()


@pytest.mark.sim
def test_a_planned_generate_run_records_planner_failures_apart(wall_task):
    (wall_task / "planned.yaml").write_text(
        WALL_PARAMS.replace("workers: 1}", "workers: 1, transit: planned, "
                            "planner: {max_iterations: 1}}")
    )  # fmt: skip
    cli("generate", "--params", "planned.yaml", "--variant", "wall", "--attempts", "6",
        "--parsed", "data/parsed/stack_cube_wall.zarr", "--out", "data/plan/wall.zarr",
        "--metrics", "metrics/plan_wall.json", cwd=wall_task)  # fmt: skip
    m = json.loads((wall_task / "metrics/plan_wall.json").read_text())
    per_subtask = m["planner_failures_grasp_cubeA"] + m["planner_failures_place_on_cubeB"]
    # one RRT extension finds no way over the wall: the place transit fails in the planner
    assert m["planner_failures"] == per_subtask > 0
    counted = [m["successes"], m["planner_failures"], m["ik_failures"],
               m["failures_grasp_cubeA"], m["failures_place_on_cubeB"]]  # fmt: skip
    assert m["attempts"] == sum(counted) == 6
    failed = read_store(wall_task / "data/plan/wall_failed.zarr")
    assert "planner_failure" in failed.episodes
    assert failed.attrs["params"]["generate"]["transit"] == "planned"


def test_a_policy_trained_on_a_named_store_takes_a_plain_name(tmp_path):
    """train --data names the policy of each --store: any plain name, as the transit
    pipeline's wall_linear and wall_planned; a name that is no plain word is refused first."""
    (tmp_path / "params.yaml").write_text("task: stack\nbackend: pybullet\ntrain: {workers: 1}\n")
    res = cli("train", "--data", "wall/planned", "--store", "missing.zarr", cwd=tmp_path,
              check=False)  # fmt: skip
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1] == (
        "mimicgen-pipe train: error: --data 'wall/planned': expected letters, digits, _ and - only"
    )
    res = cli("train", "--data", "wall_planned", "--store", "missing.zarr", cwd=tmp_path,
              check=False)  # fmt: skip
    assert res.returncode == 2 and "missing.zarr" in res.stderr.strip().splitlines()[-1]
    res = cli("train", "--data", "wall_planned", cwd=tmp_path, check=False)  # no store: a variant
    assert "--data 'wall_planned': expected \"source\" or a reset variant of" in res.stderr
