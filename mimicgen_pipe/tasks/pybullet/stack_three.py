"""stack_three: PyBullet; the paper's Stack Three.

**Task Description:**
Stack cube A on cube B, then cube C on A. Cubes are 4 cm, 50 g.

**Randomizations:**
World frame: the table centre is the origin, the robot base at x = -0.5 m; positions in
metres. Each cube uniform in its box, its yaw about world z uniform over a full turn, cube
centres at least 0.07 m apart.
- D0: all cubes in x, y in [-0.1, 0.1], the demonstrator's distribution.
- D1: x, y in [-0.2, 0.2], 2x wider.

**Success Conditions:**
- cube A is on cube B and cube C on cube A: centres within 2 cm horizontally and
  4 cm +- 1 cm apart vertically;
- cube C is not grasped (not touched by both fingers).

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (both fingers touch
  cube A) turns true.
- ``place_on_cubeB``, reference ``cubeB``: ends when ``cubeA_on_cubeB`` turns true: A on B
  as the success test has it (held or not).
- ``grasp_cubeC``, reference ``cubeC``: ends when ``grasp_cubeC`` turns true.
- ``place_on_cubeA``, reference ``cubeA``: ends with the demo.
"""

from __future__ import annotations

from mimicgen_pipe.backends.pybullet.demos import pick, place
from mimicgen_pipe.backends.pybullet.tasks import (
    BLUE,
    GREEN,
    RED,
    PyBulletTask,
    bounds,
    cube,
    on,
    on_top,
)
from mimicgen_pipe.core.taskspec import ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB", "cubeC")


def signals(env) -> dict[str, bool]:
    obj = env.object_poses()
    return {
        "grasp_cubeA": env.grasped("cubeA"),
        "cubeA_on_cubeB": on_top(obj["cubeA"], obj["cubeB"]),
        "grasp_cubeC": env.grasped("cubeC"),
        "cubeC_on_cubeA": on_top(obj["cubeC"], obj["cubeA"]),
    }


def success(s: dict[str, bool]) -> bool:
    return s["cubeA_on_cubeB"] and s["cubeC_on_cubeA"] and not s["grasp_cubeC"]


def demonstrate(op, env) -> None:
    pick(op, env.object_poses()["cubeA"], 0.0)
    place(op, "cubeA", on(env.object_poses()["cubeB"], 0.004), 0.12, 0.03, 0.006)
    pick(op, env.object_poses()["cubeC"], 0.0)
    place(op, "cubeC", on(env.object_poses()["cubeA"], 0.004), 0.16, 0.03, 0.006)


TASK = PyBulletTask(
    spec=TaskSpec(
        name="stack_three",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (15, 20)),
            SubtaskSpec("place_on_cubeB", "cubeB", "cubeA_on_cubeB", (22, 26)),
            SubtaskSpec("grasp_cubeC", "cubeC", "grasp_cubeC", (15, 20)),
            SubtaskSpec("place_on_cubeA", "cubeA", None),
        ),
        reset_variants={
            "D0": ResetVariant(bounds(OBJECTS, (-0.1, 0.1), (-0.1, 0.1)), min_distance=0.07),
            "D1": ResetVariant(bounds(OBJECTS, (-0.2, 0.2), (-0.2, 0.2)), min_distance=0.07),
        },
        horizon=400,
        paper_task="Stack Three",
    ),
    shapes={"cubeA": cube(RED), "cubeB": cube(GREEN), "cubeC": cube(BLUE)},
    signals=signals,
    success=success,
    demonstrate=demonstrate,
)
