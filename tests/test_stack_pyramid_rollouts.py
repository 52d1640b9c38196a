"""lab/scripts/stack_pyramid_rollouts.py: its sorting of failed rollouts, and one rollout of the
real task followed cube by cube."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "lab" / "scripts" / "stack_pyramid_rollouts.py"
spec = importlib.util.spec_from_file_location("spr", SCRIPT)
spr = importlib.util.module_from_spec(spec)
spec.loader.exec_module(spr)

SET_DOWN = {"first_grasped": "cubeA", "a_release_height_m": 0.002, "a_upright": 1.0,
            "a_end_distance_m": 0.045, "hand_to_c_min_m": 0.2}  # fmt: skip


@pytest.mark.parametrize(
    ("change", "kind"),
    [
        ({"first_grasped": "cubeC"}, "took C before A"),
        ({"first_grasped": None}, "grasped no cube"),
        ({"a_release_height_m": None}, "never let go of A"),
        ({"a_release_height_m": 0.012}, "dropped A from above 1 cm or tipped it"),
        ({"a_upright": 0.0}, "dropped A from above 1 cm or tipped it"),
        ({"a_end_distance_m": 0.07}, "A set down too far from B"),
        ({}, "A beside B, the hand never at C"),
        ({"hand_to_c_min_m": 0.01}, "C grasped or touched, not set on the pair"),
    ],
)
def test_failure_kinds(change, kind):
    assert spr.failure_kind(SET_DOWN | change) == kind


class HoldStill:
    """Keeps the hand where it is, gripper open."""

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        return np.array([0, 0, 0, 0, 0, 0, 1], np.float32)


def test_episode_follows_the_cubes_of_a_real_rollout():
    import envs
    from mimicgen_pipe.evaluation import evaluation_seed

    task = envs.task_spec("maniskill", "stack_pyramid")
    env = envs.make_env("maniskill", "stack_pyramid")
    seed = evaluation_seed(0, "D0", 0)
    row = spr.episode(env, HoldStill(), seed, "D0", 5, task.objects)
    env.reset(seed=seed, variant="D0")
    poses = env.object_poses()
    env.close()
    assert (row["success"], row["steps"], row["first_grasped"]) == (False, 5, None)
    assert row["a_release_height_m"] is None and row["a_upright"] > 0.99
    ab = poses["cubeA"][:2, 3] - poses["cubeB"][:2, 3]
    assert row["a_end_distance_m"] == pytest.approx(np.hypot(*ab), abs=1e-3)
    assert row["b_pushed_m"] < 1e-3 and row["hand_to_c_min_m"] > 0.05
    assert spr.failure_kind(row) == "grasped no cube"
