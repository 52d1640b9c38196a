"""stack_cube: ManiSkill's StackCube-v1; the paper's Stack.

**Task Description:**
Grasp the red cube A and place it on the green cube B, then let go. Cubes are 4 cm.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres; each cube's yaw about world z uniform over a full turn.
- D0: ManiSkill's own distribution: a shared centre uniform in [-0.1, 0.1]^2 plus, per
  cube, a non-overlapping offset in [-0.1, 0.1] x [-0.2, 0.2]: each cube lies in x in
  [-0.2, 0.2], y in [-0.3, 0.3], concentrated near the centre.
- D1: each cube independently uniform over x in [-0.35, 0.1], y in [-0.35, 0.35], cut by the
  Panda's top-down reach (at most 0.76 m horizontally from the base) and redrawn where the
  cubes would overlap (centres >= 0.06 m apart). Spread per axis is ~1.4x D0's and the two
  cubes are independent.

**Success Conditions:**
ManiSkill's:
- cube A is on cube B: centres within the cubes' half diagonal + 5 mm (3.3 cm) in xy and
  4 cm +- 5 mm apart in z;
- cube A is static (below 1 cm/s and 0.5 rad/s);
- cube A is not grasped.

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (ManiSkill's
  ``is_cubeA_grasped``) turns true.
- ``place_on_cubeB``, reference ``cubeB``: ends with the demo.
"""

from __future__ import annotations

from mimicgen_pipe.backends.maniskill.tasks import (
    FULL_YAW,
    PANDA_REACH,
    ManiSkillTask,
    cube_on_cube_evaluate,
    cube_on_cube_signals,
)
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB")
CUBE_HALF = 0.02


def initialize(env, env_idx, variant: ResetVariant) -> None:
    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

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
