"""stack_cube (ManiSkill StackCube-v1; paper: Stack): grasp the red cube A, place it on the
green cube B. Cubes are 4 cm.

Reset variants (world frame; the table centre is the origin, the Panda base is at x=-0.615):
- D0: ManiSkill's own distribution: a shared centre uniform in [-0.1, 0.1]^2 plus, per cube,
  a non-overlapping offset in [-0.1, 0.1] x [-0.2, 0.2]: each cube lies in x in [-0.2, 0.2],
  y in [-0.3, 0.3], concentrated near the centre; yaw uniform.
- D1: each cube independently uniform over x in [-0.35, 0.1], y in [-0.35, 0.35], cut by the
  Panda's top-down reach (at most 0.76 m horizontally from the base) and redrawn where the
  cubes would overlap (centres >= 0.06 m apart); yaw uniform. Spread per axis is ~1.4x D0's
  and the two cubes are independent.
"""

from __future__ import annotations

from envs.maniskill.tasks import (
    FULL_YAW,
    PANDA_REACH,
    ManiSkillTask,
    cube_on_cube_evaluate,
    cube_on_cube_signals,
)
from mimicgen_pipe.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB")
CUBE_HALF = 0.02


def initialize(env, env_idx, variant: ResetVariant) -> None:
    from envs.maniskill.env import draw_planar, set_planar_poses

    env.table_scene.initialize(env_idx)
    xy, yaw = draw_planar(variant, OBJECTS, len(env_idx), TASK.robot_base_xy)
    set_planar_poses([env.cubeA, env.cubeB], xy, yaw, [CUBE_HALF, CUBE_HALF])


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="stack_cube",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_on_cubeB", "cubeB", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {o: ObjectBounds((-0.2, 0.2), (-0.3, 0.3), FULL_YAW) for o in OBJECTS},
                native=True,
            ),
            "D1": ResetVariant(
                {o: ObjectBounds((-0.35, 0.1), (-0.35, 0.35), FULL_YAW) for o in OBJECTS},
                min_distance=0.06,
                max_reach=PANDA_REACH,
            ),
        },
        horizon=200,
        paper_task="Stack",
        obs_keys=(
            "eef_pos",
            "eef_quat",
            "gripper_qpos",
            "cubeA_pos",
            "cubeA_quat",
            "cubeB_pos",
            "cubeB_quat",
            "eef_to_cubeA_pos",
            "eef_to_cubeB_pos",
            "cubeA_to_cubeB_pos",
        ),
    ),
    base_env_id="StackCube-v1",
    objects={"cubeA": "cubeA", "cubeB": "cubeB"},
    signals=cube_on_cube_signals,
    evaluate=cube_on_cube_evaluate,
    initialize=initialize,
    batched=True,
)
