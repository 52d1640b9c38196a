"""ManiSkill task variants and specs, free of simulator imports.

StackCube (ManiSkill's StackCube-v1): grasp the red cube A (reference: cubeA), place it on
the green cube B (reference: cubeB).

Reset variants (world frame; the table centre is the origin, the Panda base is at x=-0.615):
- D0: the task's own distribution: a shared centre uniform in [-0.1, 0.1]^2 plus, per cube,
  a non-overlapping offset in [-0.1, 0.1] x [-0.2, 0.2]: each cube lies in x in [-0.2, 0.2],
  y in [-0.3, 0.3], concentrated near the centre; yaw uniform.
- D1: each cube independently uniform over x in [-0.35, 0.1], y in [-0.35, 0.35], cut by the
  Panda's top-down reach (at most 0.76 m horizontally from the base; beyond ~0.78 m the arm
  cannot reach the table) and resampled where the cubes would overlap (centres >= 0.06 m
  apart); yaw uniform. Spread per axis is ~1.4x D0's and the two cubes are independent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mimicgen_pipe.taskspec import ObjectBounds, SubtaskSpec, TaskSpec

FULL_YAW = (0.0, 2 * math.pi)
D1_X = (-0.35, 0.1)
D1_Y = (-0.35, 0.35)
D1_MIN_DIST = 0.06
D1_MAX_REACH = 0.76
ROBOT_BASE_XY = (-0.615, 0.0)
ROBOTS = ("panda",)


@dataclass(frozen=True)
class ManiSkillTask:
    """spec: the task spec. env_id: our registered id. objects: spec object name -> env
    attribute holding the actor. signals: spec signal name -> key of env.evaluate()."""

    spec: TaskSpec
    env_id: str
    base_env_id: str
    objects: dict[str, str]
    signals: dict[str, str]


STACK_CUBE = ManiSkillTask(
    spec=TaskSpec(
        name="stack_cube",
        objects=("cubeA", "cubeB"),
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_on_cubeB", "cubeB", None),
        ),
        reset_bounds={
            "D0": {o: ObjectBounds((-0.2, 0.2), (-0.3, 0.3), FULL_YAW) for o in ("cubeA", "cubeB")},
            "D1": {o: ObjectBounds(D1_X, D1_Y, FULL_YAW) for o in ("cubeA", "cubeB")},
        },
        horizon=200,
    ),
    env_id="MimicGenStackCube-v1",
    base_env_id="StackCube-v1",
    objects={"cubeA": "cubeA", "cubeB": "cubeB"},
    signals={"grasp_cubeA": "is_cubeA_grasped", "cubeA_on_cubeB": "is_cubeA_on_cubeB"},
)

TASKS = {"stack_cube": STACK_CUBE}
