"""stack_cube_wall: ManiSkill's StackCube-v1 with a wall; no paper task (the paper's Stack
with an obstacle).

**Task Description:**
stack_cube's task, grasp the red cube A and place it on the green cube B, in a scene with a
wall that the variant ``wall`` stands between the cubes. A task for planned transit
(generate.transit: planned): the straight interpolation and the source demos' own motion,
moved with cube B, pass through the wall; a planned transit goes over it.

The wall is a kinematic box 40 cm long, 2 cm thick and 14 cm tall, a task object like the
cubes (its pose is recorded and observed) that no subtask refers to.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres, yaw about world z. Every object uniform in its box, with no distance or reach cut;
the cubes' yaw uniform over a full turn, cube A on the right (y < 0), cube B on the left:
- D0 (the source demos'): cube A in x in [-0.15, 0.1], y in [-0.25, -0.1]; cube B in
  x in [-0.15, 0.1], y in [0.1, 0.25]; the wall out of the way, across the far end of the
  table (its centre in x in [0.37, 0.38], y in [-0.005, 0.005], yaw pi/2 rad: along y).
- wall: D0's cubes, the wall between them, its centre in x in [-0.1, 0.0],
  y in [-0.005, 0.005], yaw 0: along x.

**Success Conditions:**
stack_cube's, by the same check (``cube_on_cube_evaluate``, ManiSkill's StackCube-v1 test;
its conditions are listed in stack_cube.py), reported by the task's own env.

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (ManiSkill's
  ``is_cubeA_grasped``) turns true.
- ``place_on_cubeB``, reference ``cubeB``: ends with the demo.
"""

from __future__ import annotations

import math

from mimicgen_pipe.backends.maniskill.tasks import (
    ManiSkillTask,
    cube_on_cube_evaluate,
    cube_on_cube_signals,
)
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB", "wall")
CUBE_HALF = 0.02
WALL_HALF = (0.2, 0.01, 0.07)  # [m] half extents along its own x, y, z (below the TCP at home)
CUBE_A = ObjectBounds((-0.15, 0.1), (-0.25, -0.1), (0.0, 2 * math.pi))
CUBE_B = ObjectBounds((-0.15, 0.1), (0.1, 0.25), (0.0, 2 * math.pi))


def load_scene(env) -> None:
    """Add the wall to StackCube-v1's scene (after its table and cubes)."""
    import sapien

    builder = env.scene.create_actor_builder()
    builder.add_box_collision(half_size=WALL_HALF)
    builder.add_box_visual(
        half_size=WALL_HALF,
        material=sapien.render.RenderMaterial(base_color=[0.55, 0.55, 0.6, 1.0]),
    )
    builder.initial_pose = sapien.Pose(p=[0.38, 0.0, WALL_HALF[2]])
    env.wall = builder.build_kinematic(name="wall")


def initialize(env, env_idx, variant: ResetVariant) -> None:
    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

    env.table_scene.initialize(env_idx)
    xy, yaw = draw_planar(variant, OBJECTS, len(env_idx), TASK.robot_base_xy)
    actors = [env.cubeA, env.cubeB, env.wall]
    set_planar_poses(actors, xy, yaw, [CUBE_HALF, CUBE_HALF, WALL_HALF[2]])


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="stack_cube_wall",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_on_cubeB", "cubeB", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {
                    "cubeA": CUBE_A,
                    "cubeB": CUBE_B,
                    "wall": ObjectBounds((0.37, 0.38), (-0.005, 0.005), (math.pi / 2, math.pi / 2)),
                }
            ),
            "wall": ResetVariant(
                {
                    "cubeA": CUBE_A,
                    "cubeB": CUBE_B,
                    "wall": ObjectBounds((-0.1, 0.0), (-0.005, 0.005), (0.0, 0.0)),
                }
            ),
        },
        horizon=250,
        paper_task="Stack",  # Stack with an obstacle; the paper has no such variant
        obs_keys=(
            "eef_pos",
            "eef_quat",
            "gripper_qpos",
            "cubeA_pos",
            "cubeA_quat",
            "cubeB_pos",
            "cubeB_quat",
            "wall_pos",
            "eef_to_cubeA_pos",
            "eef_to_cubeB_pos",
            "cubeA_to_cubeB_pos",
        ),
    ),
    base_env_id="StackCube-v1",
    objects={"cubeA": "cubeA", "cubeB": "cubeB", "wall": "wall"},
    signals=cube_on_cube_signals,
    evaluate=cube_on_cube_evaluate,
    initialize=initialize,
    load_scene=load_scene,
)
