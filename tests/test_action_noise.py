"""Action noise spared near a subtask's reference object (SubtaskSpec.noise_free_radius): a
step whose target is within the radius is exactly the controller's action towards its
target, one farther away is not, and an attempt with the radius everywhere is the
noise-free attempt bit for bit (the noise draws go on, so nothing after them shifts)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mimicgen_pipe.core.controller import clip_actions, target_poses_to_actions
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import attempt_seed, source_demos

RADIUS = 0.06  # [m]


def around_cube_b(spec, radius: float):
    """StackCube's spec with both subtasks relative to cube B (which stays put until cube A
    lands on it) and noise spared within ``radius`` of it."""
    subtasks = tuple(
        dataclasses.replace(s, reference_object="cubeB", noise_free_radius=radius)
        for s in spec.subtasks
    )
    return dataclasses.replace(spec, subtasks=subtasks)


@pytest.fixture(scope="module")
def setting(pipeline):
    from mimicgen_pipe import backends

    env = backends.make_env("maniskill", "stack_cube")
    spec = env.spec
    sources = source_demos(read_store(pipeline / "data/parsed/stack_cube.zarr"), spec.objects)
    env.rebuild()
    yield env, spec, sources
    env.close()


@pytest.mark.sim
def test_steps_near_the_reference_object_carry_no_noise(setting):
    env, spec, sources = setting
    config = GenerationConfig(action_noise=0.05)
    near_steps = far_steps = 0
    for i in range(3):
        seed = attempt_seed(2, "D0", i)
        steps = run_attempt(env, sources, around_cube_b(spec, RADIUS), config, "D0", seed).steps
        clean = clip_actions(
            target_poses_to_actions(
                steps["eef_pose"], steps["target_pose"], steps["actions"][:, -1], env.controller
            )
        ).astype(np.float32)
        cube_b = steps["object_poses/cubeB"][0][:3, 3]
        d = np.linalg.norm(steps["target_pose"][:, :3, 3] - cube_b, axis=-1)
        near, far = d < RADIUS - 1e-3, d > RADIUS + 1e-3  # cube B may settle by micrometres
        noisy = np.any(steps["actions"] != clean, axis=-1)
        assert not noisy[near].any()
        assert noisy[far].mean() > 0.9  # a noise draw can be clipped away, on a saturated axis
        near_steps, far_steps = near_steps + near.sum(), far_steps + far.sum()
    assert near_steps > 20 and far_steps > 100


@pytest.mark.sim
def test_a_radius_over_everything_is_the_noise_free_attempt(setting):
    env, spec, sources = setting
    seed = attempt_seed(2, "D0", 0)
    env.rebuild()  # each on a fresh scene: PhysX carries contact history between resets
    spared = run_attempt(
        env, sources, around_cube_b(spec, 1e9), GenerationConfig(action_noise=0.05), "D0", seed
    )
    env.rebuild()
    clean = run_attempt(
        env, sources, around_cube_b(spec, None), GenerationConfig(action_noise=0.0), "D0", seed
    )
    assert spared.steps.keys() == clean.steps.keys()
    assert all(np.array_equal(spared.steps[k], clean.steps[k]) for k in clean.steps)


@pytest.mark.parametrize("radius", [-0.01, float("nan")])
def test_a_radius_that_is_no_distance_is_refused(radius):
    from mimicgen_pipe import backends

    spec = backends.task_spec("maniskill", "stack_cube")
    bad = dataclasses.replace(spec.subtasks[0], noise_free_radius=radius)
    with pytest.raises(ValueError, match=r"noise_free_radius .* not a distance >= 0 \[m\]"):
        dataclasses.replace(spec, subtasks=(bad, *spec.subtasks[1:]))
